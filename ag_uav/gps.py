"""GPS position sensor with configurable coloured and non-Gaussian error models.

The paper's measurement model is ``y = C x + omega`` with coloured noise
``omega_t = Gamma omega_{t-1} + xi`` (Candan & Li, eqs 1-2) and Gaussian / non-Gaussian xi
(Weibull, Student-t); the tracking paper (Qin, Xu & Liu, eq 4) adds Gaussian mixtures, and
Laplace / alpha-stable impulsive noise.  Here each axis error is a SUM of components:

==================  =========================================================================
type                model (per fix k)
==================  =========================================================================
``gaussian``        sigma * N(0, 1)
``student-t``       sigma * sqrt((nu-2)/nu) * t_nu                     (nu > 2, variance sigma^2)
``laplace``         Laplace(0, b), b = sigma / sqrt(2)                 (variance sigma^2)
``weibull``         +/- lambda * Weibull(k), lambda = sigma / sqrt(Gamma(1 + 2/k)), random sign
``mixture``         (1-eps) N(0, sigma1^2) + eps N(0, sigma2^2)
``alpha-stable``    S(alpha, beta, scale) by Chambers-Mallows-Stuck (scipy ``levy_stable`` S1
                    parametrisation); infinite variance for alpha < 2
``gauss-markov``    b_{k+1} = e^{-dt/tau} b_k + sigma sqrt(1 - e^{-2 dt/tau}) N(0,1) (exact)
``ar1``             v_k = rho v_{k-1} + g(rho) xi_k with xi from a ``driver`` distribution above;
                    g = sqrt(1 - rho^2) keeps the variance (for an alpha-stable driver
                    g = (1 - |rho|^alpha)^(1/alpha) keeps the scale).  Give rho, or tau_s
                    with rho = e^{-dt/tau}
``spikes``          Bernoulli(prob) * amplitude * random sign (multipath); amplitude uniform in
                    [amplitude, amplitude_max] if ``amplitude_max`` is given
==================  =========================================================================

Outages are a two-state Markov chain (fix available / no fix) with geometric run lengths whose
means are exactly ``mean_up_s`` and ``mean_down_s`` (per-fix switching probability dt / mean).

Randomness: every component draws from its own Generators, derived from the sensor's
``SeedSequence`` and a stable key (component name, axis), so adding, removing or reordering a
component never changes the draws of another.  All components are also *chunk invariant*: drawing
n1 then n2 values gives the same numbers as drawing n1 + n2 at once, which is why
:meth:`GpsSensor.measure` (which pre-generates errors in blocks) and
:meth:`GpsSensor.generate_errors` produce identical error sequences for the same seed.

Config keys (plain dicts; a TOML table can override any of them)
-----------------------------------------------------------------
Sensor: ``rate_hz`` (float > 0, fixes per second), ``latency_s`` (float >= 0, age of the true
position a fix reports), ``axis_scale`` ([sx, sy, sz] >= 0, multiplies the summed error per axis),
``components`` (list of component tables), ``outage`` (table with ``mean_up_s`` > 0,
``mean_down_s`` > 0 and optional bool ``start_in_outage``; an empty table means no outages).
Component: ``type`` (see above), ``name`` (optional, unique, defaults to the type; it keys the
random stream), ``axis_scale`` (optional [3] multiplier for this component only), and per type:
``sigma`` (gaussian, student-t, laplace, weibull, gauss-markov), ``nu`` (student-t), ``k``
(weibull shape), ``eps``, ``sigma1``, ``sigma2`` (mixture), ``alpha``, ``scale``, ``beta``
(alpha-stable, beta default 0), ``tau_s`` (gauss-markov; ar1 alternative to ``rho``), ``rho``
(ar1), ``driver`` (ar1: a component table of an i.i.d. type, without name), ``prob``,
``amplitude``, ``amplitude_max`` (spikes).  When overriding a preset, ``components`` may be a
list (replaces all) or a table keyed by component name (merges keys into those components; a
new name adds a component, an empty table removes one).

Presets (:func:`gps_preset`) are illustrative engineering values, not datasheet figures; see
``_PRESETS`` below for the reasoning behind each number.
"""

from __future__ import annotations

import copy
import math
import zlib
from collections import deque
from collections.abc import Iterable, Mapping, Sequence
from typing import Any

import numpy as np
from scipy.signal import lfilter

__all__ = [
    "AR1",
    "AlphaStable",
    "GaussMarkov",
    "Gaussian",
    "GaussianMixture",
    "GpsSensor",
    "Laplace",
    "MultipathSpikes",
    "NoiseComponent",
    "OutageProcess",
    "StudentT",
    "SymmetricWeibull",
    "available_presets",
    "derive_seed",
    "gps_preset",
    "make_component",
]

SeedLike = np.random.SeedSequence | int


def _as_seedseq(seed: SeedLike) -> np.random.SeedSequence:
    if isinstance(seed, np.random.SeedSequence):
        return seed
    if isinstance(seed, (int, np.integer)) and not isinstance(seed, bool) and seed >= 0:
        return np.random.SeedSequence(int(seed))
    raise ValueError(f"seed = {seed!r} is invalid; must be a numpy SeedSequence or an int >= 0")


def derive_seed(root: SeedLike, *key: str | int) -> np.random.SeedSequence:
    """Child SeedSequence of ``root`` keyed by a stable path (strings hashed with CRC32).

    Unlike ``SeedSequence.spawn`` the child does not depend on how many children were made before,
    so streams keyed by name are independent of the set and order of components.
    """
    ss = _as_seedseq(root)
    parts = tuple(zlib.crc32(k.encode()) if isinstance(k, str) else int(k) for k in key)
    return np.random.SeedSequence(entropy=ss.entropy, spawn_key=tuple(ss.spawn_key) + parts)


def _rngs(seed: SeedLike, n: int) -> list[np.random.Generator]:
    """``n`` independent Generators (one per random role of a component) from ``seed``."""
    ss = _as_seedseq(seed)
    return [
        np.random.Generator(np.random.PCG64(derive_seed(ss, "role", i))) for i in range(n)
    ]


def _bad(who: str, key: str, value: Any, allowed: str) -> ValueError:
    return ValueError(f"{who}: {key} = {value!r} is invalid; {allowed}")


def _check_pos(who: str, key: str, value: Any, *, allow_zero: bool = False) -> float:
    try:
        v = float(value)
    except (TypeError, ValueError):
        raise _bad(who, key, value, "must be a number") from None
    ok = math.isfinite(v) and (v >= 0.0 if allow_zero else v > 0.0)
    if not ok:
        raise _bad(who, key, value, "must be finite and " + (">= 0" if allow_zero else "> 0"))
    return v


def _check_axis_scale(who: str, value: Any) -> tuple[float, float, float]:
    try:
        vals = tuple(float(x) for x in value)
    except (TypeError, ValueError):
        raise _bad(who, "axis_scale", value, "must be 3 numbers >= 0") from None
    if len(vals) != 3 or not all(math.isfinite(v) and v >= 0.0 for v in vals):
        raise _bad(who, "axis_scale", value, "must be 3 finite numbers >= 0")
    return vals  # type: ignore[return-value]


# ---------------------------------------------------------------------------------------------
# components
# ---------------------------------------------------------------------------------------------


class NoiseComponent:
    """Scalar error process.  ``sample(n, dt)`` returns the next ``n`` values (continuing any
    internal state); ``step(dt)`` returns the next single value.  ``dt`` is the time between fixes
    and is ignored by i.i.d. components."""

    #: True for i.i.d. distributions usable as an AR(1) driver
    iid: bool = False

    def sample(self, n: int, dt: float = 0.05) -> np.ndarray:  # pragma: no cover - interface
        raise NotImplementedError

    def step(self, dt: float = 0.05) -> float:
        return float(self.sample(1, dt)[0])

    @property
    def variance(self) -> float:
        """Stationary variance (``inf`` for alpha-stable with alpha < 2)."""
        raise NotImplementedError  # pragma: no cover


class Gaussian(NoiseComponent):
    """White Gaussian noise, std ``sigma``."""

    iid = True

    def __init__(self, sigma: float, seed: SeedLike) -> None:
        self.sigma = _check_pos("gaussian", "sigma", sigma, allow_zero=True)
        (self._rng,) = _rngs(seed, 1)

    def sample(self, n: int, dt: float = 0.05) -> np.ndarray:
        return self.sigma * self._rng.standard_normal(n)

    @property
    def variance(self) -> float:
        return self.sigma**2


class StudentT(NoiseComponent):
    """Student-t with ``nu`` > 2 degrees of freedom scaled to std ``sigma``:
    ``sigma sqrt((nu-2)/nu) t_nu`` (Roth et al. 2013, ref [18] of the core paper)."""

    iid = True

    def __init__(self, sigma: float, nu: float, seed: SeedLike) -> None:
        self.sigma = _check_pos("student-t", "sigma", sigma, allow_zero=True)
        nu_f = _check_pos("student-t", "nu", nu)
        if not nu_f > 2.0:
            raise _bad("student-t", "nu", nu, "must be > 2 (finite variance)")
        self.nu = nu_f
        self._scale = self.sigma * math.sqrt((nu_f - 2.0) / nu_f)
        (self._rng,) = _rngs(seed, 1)

    def sample(self, n: int, dt: float = 0.05) -> np.ndarray:
        return self._scale * self._rng.standard_t(self.nu, n)

    @property
    def variance(self) -> float:
        return self.sigma**2


class Laplace(NoiseComponent):
    """Laplace(0, b) with ``b = sigma / sqrt(2)`` (variance sigma^2)."""

    iid = True

    def __init__(self, sigma: float, seed: SeedLike) -> None:
        self.sigma = _check_pos("laplace", "sigma", sigma, allow_zero=True)
        self.b = self.sigma / math.sqrt(2.0)
        (self._rng,) = _rngs(seed, 1)

    def sample(self, n: int, dt: float = 0.05) -> np.ndarray:
        return self._rng.laplace(0.0, self.b, n)

    @property
    def variance(self) -> float:
        return self.sigma**2


class SymmetricWeibull(NoiseComponent):
    """Weibull(k, lambda) magnitude with a random sign; ``lambda = sigma / sqrt(Gamma(1 + 2/k))``
    so that the variance is ``lambda^2 Gamma(1 + 2/k) = sigma^2``.  k < 1 is heavier-tailed than
    Laplace (k = 1), k = 2 gives a Rayleigh-like, light-tailed, bimodal density."""

    iid = True

    def __init__(self, sigma: float, k: float, seed: SeedLike) -> None:
        self.sigma = _check_pos("weibull", "sigma", sigma, allow_zero=True)
        self.k = _check_pos("weibull", "k", k)
        self.lam = self.sigma / math.sqrt(math.gamma(1.0 + 2.0 / self.k))
        self._rng_mag, self._rng_sign = _rngs(seed, 2)

    def sample(self, n: int, dt: float = 0.05) -> np.ndarray:
        mag = self.lam * self._rng_mag.weibull(self.k, n)
        return np.where(self._rng_sign.random(n) < 0.5, -mag, mag)

    @property
    def variance(self) -> float:
        return self.sigma**2


class GaussianMixture(NoiseComponent):
    """``(1 - eps) N(0, sigma1^2) + eps N(0, sigma2^2)`` (Qin, Xu & Liu eq 4, zero means)."""

    iid = True

    def __init__(self, eps: float, sigma1: float, sigma2: float, seed: SeedLike) -> None:
        e = _check_pos("mixture", "eps", eps, allow_zero=True)
        if e > 1.0:
            raise _bad("mixture", "eps", eps, "must be in [0, 1]")
        self.eps = e
        self.sigma1 = _check_pos("mixture", "sigma1", sigma1, allow_zero=True)
        self.sigma2 = _check_pos("mixture", "sigma2", sigma2, allow_zero=True)
        self._rng_sel, self._rng_val = _rngs(seed, 2)

    def sample(self, n: int, dt: float = 0.05) -> np.ndarray:
        outlier = self._rng_sel.random(n) < self.eps
        return np.where(outlier, self.sigma2, self.sigma1) * self._rng_val.standard_normal(n)

    @property
    def variance(self) -> float:
        return (1.0 - self.eps) * self.sigma1**2 + self.eps * self.sigma2**2


class AlphaStable(NoiseComponent):
    """Alpha-stable S(alpha, beta, scale, 0 location) by Chambers-Mallows-Stuck (1976).

    With U ~ U(-pi/2, pi/2), W ~ Exp(1), for alpha != 1:
    ``X = S sin(alpha(U+B)) / cos(U)^{1/alpha} (cos(U - alpha(U+B)) / W)^{(1-alpha)/alpha}``,
    ``B = arctan(beta tan(pi alpha/2)) / alpha``,
    ``S = (1 + beta^2 tan^2(pi alpha/2))^{1/(2 alpha)}``; for alpha = 1:
    ``X = (2/pi)[(pi/2 + beta U) tan U - beta ln((pi/2) W cos U / (pi/2 + beta U))]``
    and ``Y = scale X + (2/pi) beta scale ln(scale)``.  This is scipy's default (S1)
    parametrisation; alpha = 2 is N(0, 2 scale^2).  Variance is infinite for alpha < 2, so
    ``scale`` is specified instead of sigma.
    """

    iid = True

    def __init__(self, alpha: float, scale: float, seed: SeedLike, beta: float = 0.0) -> None:
        a = _check_pos("alpha-stable", "alpha", alpha)
        if a > 2.0:
            raise _bad("alpha-stable", "alpha", alpha, "must be in (0, 2]")
        try:
            b = float(beta)
        except (TypeError, ValueError):
            raise _bad("alpha-stable", "beta", beta, "must be a number in [-1, 1]") from None
        if not -1.0 <= b <= 1.0:
            raise _bad("alpha-stable", "beta", beta, "must be in [-1, 1]")
        self.alpha = a
        self.beta = b
        self.scale = _check_pos("alpha-stable", "scale", scale, allow_zero=True)
        self._rng_u, self._rng_w = _rngs(seed, 2)

    def sample(self, n: int, dt: float = 0.05) -> np.ndarray:
        a, b, c = self.alpha, self.beta, self.scale
        u = math.pi * (self._rng_u.random(n) - 0.5)
        w = self._rng_w.standard_exponential(n)
        if a == 1.0:
            hp = 0.5 * math.pi
            bu = hp + b * u
            x = (bu * np.tan(u) - b * np.log(hp * w * np.cos(u) / bu)) / hp
            out = c * x
            if b != 0.0 and c > 0.0:
                out += (2.0 / math.pi) * b * c * math.log(c)
            return out
        t = b * math.tan(0.5 * math.pi * a)
        bb = math.atan(t) / a
        s = (1.0 + t * t) ** (1.0 / (2.0 * a))
        au = a * (u + bb)
        x = (
            s
            * np.sin(au)
            / np.cos(u) ** (1.0 / a)
            * (np.cos(u - au) / w) ** ((1.0 - a) / a)
        )
        return c * x

    @property
    def variance(self) -> float:
        return 2.0 * self.scale**2 if self.alpha == 2.0 else math.inf


class GaussMarkov(NoiseComponent):
    """First-order Gauss-Markov bias, exact discretisation:
    ``b_{k+1} = e^{-dt/tau} b_k + sigma sqrt(1 - e^{-2 dt/tau}) xi_k``, stationary std ``sigma``,
    correlation ``e^{-dt/tau}`` per fix (Webots' GPS noise correlation is this with dt = 1 s).
    The initial bias is drawn from the stationary N(0, sigma^2)."""

    def __init__(self, sigma: float, tau_s: float, seed: SeedLike) -> None:
        self.sigma = _check_pos("gauss-markov", "sigma", sigma, allow_zero=True)
        self.tau_s = _check_pos("gauss-markov", "tau_s", tau_s)
        (self._rng,) = _rngs(seed, 1)
        self._state: float | None = None

    def sample(self, n: int, dt: float = 0.05) -> np.ndarray:
        if n <= 0:
            return np.empty(0)
        xi = self._rng.standard_normal(n)
        if self._state is None:
            # first value is the stationary initial bias itself
            first = self.sigma * xi[0]
            rest = self._filter(xi[1:], dt, first)
            out = np.concatenate(([first], rest))
        else:
            out = self._filter(xi, dt, self._state)
        self._state = float(out[-1])
        return out

    def _filter(self, xi: np.ndarray, dt: float, prev: float) -> np.ndarray:
        if xi.size == 0:
            return xi
        rho = math.exp(-dt / self.tau_s)
        g = self.sigma * math.sqrt(-math.expm1(-2.0 * dt / self.tau_s))
        y, _ = lfilter([g], [1.0, -rho], xi, zi=[rho * prev])
        return y

    @property
    def variance(self) -> float:
        return self.sigma**2


class AR1(NoiseComponent):
    """General AR(1) (the paper's eq 2 with scalar Gamma = rho) driven by any i.i.d. component:
    ``v_k = rho v_{k-1} + g xi_k``.  ``g = sqrt(1 - rho^2)`` keeps the driver's variance (scale
    ``(1 - |rho|^alpha)^{1/alpha}`` for an alpha-stable driver keeps its scale).  Give ``rho`` (per
    fix, |rho| < 1) or ``tau_s`` (rho = e^{-dt/tau}, independent of the fix rate).  As rho -> 1 the
    filter Gaussianises the marginal (it averages ~(1+rho)/(1-rho) driver draws): add impulsive
    components after it when both effects are wanted.  The initial state is one driver draw."""

    def __init__(
        self,
        driver: NoiseComponent,
        rho: float | None = None,
        tau_s: float | None = None,
    ) -> None:
        if not (isinstance(driver, NoiseComponent) and driver.iid):
            raise _bad("ar1", "driver", driver, "must be an i.i.d. component "
                       f"({', '.join(sorted(_IID_TYPES))})")
        if (rho is None) == (tau_s is None):
            raise _bad("ar1", "rho/tau_s", (rho, tau_s), "give exactly one of rho or tau_s")
        if rho is not None:
            try:
                r = float(rho)
            except (TypeError, ValueError):
                raise _bad("ar1", "rho", rho, "must be a number in (-1, 1)") from None
            if not -1.0 < r < 1.0:
                raise _bad("ar1", "rho", rho, "must be in (-1, 1)")
            self.rho: float | None = r
            self.tau_s: float | None = None
        else:
            self.rho = None
            self.tau_s = _check_pos("ar1", "tau_s", tau_s)
        self.driver = driver
        self._state: float | None = None

    def rho_at(self, dt: float) -> float:
        return self.rho if self.rho is not None else math.exp(-dt / self.tau_s)  # type: ignore[operator]

    def _gain(self, rho: float) -> float:
        if isinstance(self.driver, AlphaStable):
            a = self.driver.alpha
            return (1.0 - abs(rho) ** a) ** (1.0 / a)
        return math.sqrt(1.0 - rho * rho)

    def sample(self, n: int, dt: float = 0.05) -> np.ndarray:
        if n <= 0:
            return np.empty(0)
        xi = self.driver.sample(n, dt)
        rho = self.rho_at(dt)
        g = self._gain(rho)
        if self._state is None:
            first = float(xi[0])
            xi = xi[1:]
            if xi.size:
                y, _ = lfilter([g], [1.0, -rho], xi, zi=[rho * first])
                out = np.concatenate(([first], y))
            else:
                out = np.array([first])
        else:
            out, _ = lfilter([g], [1.0, -rho], xi, zi=[rho * self._state])
        self._state = float(out[-1])
        return out

    @property
    def variance(self) -> float:
        return self.driver.variance


class MultipathSpikes(NoiseComponent):
    """Multipath spikes: with probability ``prob`` per fix, ``+/- amplitude`` (random sign);
    amplitude uniform in ``[amplitude, amplitude_max]`` when ``amplitude_max`` is given."""

    iid = True

    def __init__(
        self, prob: float, amplitude: float, seed: SeedLike, amplitude_max: float | None = None
    ) -> None:
        p = _check_pos("spikes", "prob", prob, allow_zero=True)
        if p > 1.0:
            raise _bad("spikes", "prob", prob, "must be in [0, 1]")
        self.prob = p
        self.amplitude = _check_pos("spikes", "amplitude", amplitude, allow_zero=True)
        if amplitude_max is not None:
            amax = _check_pos("spikes", "amplitude_max", amplitude_max, allow_zero=True)
            if amax < self.amplitude:
                raise _bad("spikes", "amplitude_max", amplitude_max, "must be >= amplitude")
            self.amplitude_max: float | None = amax
        else:
            self.amplitude_max = None
        self._rng_hit, self._rng_sign, self._rng_amp = _rngs(seed, 3)

    def sample(self, n: int, dt: float = 0.05) -> np.ndarray:
        hit = self._rng_hit.random(n) < self.prob
        sign = np.where(self._rng_sign.random(n) < 0.5, -1.0, 1.0)
        if self.amplitude_max is None:
            amp = self.amplitude
        else:
            amp = self.amplitude + (self.amplitude_max - self.amplitude) * self._rng_amp.random(n)
        return np.where(hit, sign * amp, 0.0)

    @property
    def variance(self) -> float:
        if self.amplitude_max is None:
            return self.prob * self.amplitude**2
        a, b = self.amplitude, self.amplitude_max
        return self.prob * (a * a + a * b + b * b) / 3.0


class OutageProcess:
    """Two-state Markov chain of GPS availability.  Run lengths (in fixes) are geometric with
    success probability ``dt / mean`` (clipped to 1), so the mean time in each state is exactly
    ``mean_up_s`` / ``mean_down_s`` when ``mean >= dt``.  ``sample(n, dt)`` returns a bool array,
    True where the fix is lost; state carries across calls.  Up and down durations come from
    separate streams."""

    def __init__(
        self, mean_up_s: float, mean_down_s: float, seed: SeedLike, start_in_outage: bool = False
    ) -> None:
        self.mean_up_s = _check_pos("outage", "mean_up_s", mean_up_s)
        self.mean_down_s = _check_pos("outage", "mean_down_s", mean_down_s)
        if not isinstance(start_in_outage, (bool, np.bool_)):
            raise _bad("outage", "start_in_outage", start_in_outage, "must be true or false")
        self._rng_up, self._rng_down = _rngs(seed, 2)
        self._down = bool(start_in_outage)
        self._left = 0  # fixes left in the current run; 0 = draw a new run for the current state
        self._fresh = True

    def _draw_run(self, dt: float) -> int:
        if self._down:
            return int(self._rng_down.geometric(min(1.0, dt / self.mean_down_s)))
        return int(self._rng_up.geometric(min(1.0, dt / self.mean_up_s)))

    def sample(self, n: int, dt: float = 0.05) -> np.ndarray:
        out = np.empty(n, dtype=bool)
        i = 0
        while i < n:
            if self._left <= 0:
                if not self._fresh:
                    self._down = not self._down
                self._fresh = False
                self._left = self._draw_run(dt)
            m = min(self._left, n - i)
            out[i : i + m] = self._down
            i += m
            self._left -= m
        return out

    @property
    def availability(self) -> float:
        """Stationary fraction of time with a fix."""
        return self.mean_up_s / (self.mean_up_s + self.mean_down_s)


# ---------------------------------------------------------------------------------------------
# config -> components
# ---------------------------------------------------------------------------------------------

_IID_KEYS: dict[str, tuple[set[str], set[str]]] = {
    # type: (required keys, optional keys)
    "gaussian": ({"sigma"}, set()),
    "student-t": ({"sigma", "nu"}, set()),
    "laplace": ({"sigma"}, set()),
    "weibull": ({"sigma", "k"}, set()),
    "mixture": ({"eps", "sigma1", "sigma2"}, set()),
    "alpha-stable": ({"alpha", "scale"}, {"beta"}),
    "spikes": ({"prob", "amplitude"}, {"amplitude_max"}),
}
_IID_TYPES = set(_IID_KEYS) - {"spikes"}
_COMPONENT_KEYS: dict[str, tuple[set[str], set[str]]] = {
    **_IID_KEYS,
    "gauss-markov": ({"sigma", "tau_s"}, set()),
    "ar1": ({"driver"}, {"rho", "tau_s"}),
}
_COMMON_KEYS = {"type", "name", "axis_scale"}


def _norm_type(t: Any, who: str) -> str:
    if not isinstance(t, str):
        raise _bad(who, "type", t, f"allowed: {', '.join(sorted(_COMPONENT_KEYS))}")
    key = t.strip().lower().replace("_", "-")
    key = {"ar(1)": "ar1", "gm": "gauss-markov", "student": "student-t", "t": "student-t",
           "stable": "alpha-stable", "white": "gaussian", "multipath": "spikes"}.get(key, key)
    if key not in _COMPONENT_KEYS:
        raise _bad(who, "type", t, f"allowed: {', '.join(sorted(_COMPONENT_KEYS))}")
    return key


def make_component(
    cfg: Mapping[str, Any], seed: SeedLike, *, _driver: bool = False
) -> NoiseComponent:
    """Build one scalar component from its config table (see module docstring for keys)."""
    if not isinstance(cfg, Mapping):
        raise _bad("gps component", "table", cfg, "must be a table/dict with a 'type' key")
    who = f"gps component {cfg.get('name', cfg.get('type'))!r}"
    typ = _norm_type(cfg.get("type"), who)
    required, optional = _COMPONENT_KEYS[typ]
    allowed = required | optional | (set() if _driver else _COMMON_KEYS) | {"type"}
    for k in cfg:
        if k not in allowed:
            raise _bad(who, k, cfg[k], f"unknown key for type {typ!r}; allowed: "
                       f"{', '.join(sorted(allowed))}")
    for k in required:
        if k not in cfg:
            raise _bad(who, k, None, f"is required for type {typ!r}")
    if _driver and typ not in _IID_TYPES:
        raise _bad(who, "type", typ,
                   f"an ar1 driver must be one of {', '.join(sorted(_IID_TYPES))}")
    if typ == "gaussian":
        return Gaussian(cfg["sigma"], seed)
    if typ == "student-t":
        return StudentT(cfg["sigma"], cfg["nu"], seed)
    if typ == "laplace":
        return Laplace(cfg["sigma"], seed)
    if typ == "weibull":
        return SymmetricWeibull(cfg["sigma"], cfg["k"], seed)
    if typ == "mixture":
        return GaussianMixture(cfg["eps"], cfg["sigma1"], cfg["sigma2"], seed)
    if typ == "alpha-stable":
        return AlphaStable(cfg["alpha"], cfg["scale"], seed, beta=cfg.get("beta", 0.0))
    if typ == "spikes":
        return MultipathSpikes(cfg["prob"], cfg["amplitude"], seed, cfg.get("amplitude_max"))
    if typ == "gauss-markov":
        return GaussMarkov(cfg["sigma"], cfg["tau_s"], seed)
    # ar1
    driver = make_component(cfg["driver"], derive_seed(seed, "driver"), _driver=True)
    return AR1(driver, rho=cfg.get("rho"), tau_s=cfg.get("tau_s"))


# ---------------------------------------------------------------------------------------------
# presets
# ---------------------------------------------------------------------------------------------

_PAPER_SCALE = [math.sqrt(10.0), 10.0, math.sqrt(10.0)]

# Reasoning behind the numbers (illustrative, not datasheet figures):
# * rtk: cm-level; a small slowly wandering residual plus white noise, ~1 cm horizontal std,
#   vertical 2x (vertical dilution of precision), 20 Hz (RTK receivers output up to 20 Hz).
# * sbas: ~0.6 m horizontal std dominated by a 2-minute Gauss-Markov bias, 0.2 m white, z 1.7x.
# * standalone: ~1.4 m horizontal std, slow bias (tau = 120 s, within "30 s to minutes") plus
#   0.35 m white, z 1.7x, 10 Hz (typical consumer receiver rate).
# * paper-numerical: Candan & Li eqs 8-11: Ts = 0.05 s, R = diag(10, 100) m^2, white Gaussian.
#   The paper's experiment is 2-D; z is given the x variance.
# * distribution presets share paper-numerical's covariance (unit-variance components times
#   axis_scale) so that only the noise SHAPE differs; alpha-stable has no variance, its scale
#   1/sqrt(2) would give unit variance at alpha = 2.  Shape parameters: Student-t nu = 3; Weibull
#   k = 0.8 (heavier than Laplace); mixture eps = 0.1 with a 10x variance ratio as in Qin et al.
#   (0.9 N(0, 0.01) + 0.1 N(0, 0.1)), normalised to unit variance; alpha = 1.5; coloured:
#   Gaussian AR(1) with tau = 1 s (rho = 0.951 at 20 Hz); coloured-impulsive: AR(1) (variance
#   0.36) followed by 4 % spikes of amplitude 4 (variance 0.64), total unit variance.
_MIX_S1 = math.sqrt(1.0 / 1.9)
_PRESETS: dict[str, dict[str, Any]] = {
    "perfect": {
        "rate_hz": 20.0, "latency_s": 0.0, "axis_scale": [1.0, 1.0, 1.0],
        "components": [], "outage": {},
    },
    "rtk": {
        "rate_hz": 20.0, "latency_s": 0.0, "axis_scale": [1.0, 1.0, 2.0],
        "components": [
            {"type": "gauss-markov", "name": "bias", "sigma": 0.006, "tau_s": 30.0},
            {"type": "gaussian", "name": "white", "sigma": 0.008},
        ],
        "outage": {},
    },
    "sbas": {
        "rate_hz": 10.0, "latency_s": 0.0, "axis_scale": [1.0, 1.0, 1.7],
        "components": [
            {"type": "gauss-markov", "name": "bias", "sigma": 0.6, "tau_s": 120.0},
            {"type": "gaussian", "name": "white", "sigma": 0.2},
        ],
        "outage": {},
    },
    "standalone": {
        "rate_hz": 10.0, "latency_s": 0.0, "axis_scale": [1.0, 1.0, 1.7],
        "components": [
            {"type": "gauss-markov", "name": "bias", "sigma": 1.4, "tau_s": 120.0},
            {"type": "gaussian", "name": "white", "sigma": 0.35},
        ],
        "outage": {},
    },
    "paper-numerical": {
        "rate_hz": 20.0, "latency_s": 0.0, "axis_scale": list(_PAPER_SCALE),
        "components": [{"type": "gaussian", "name": "white", "sigma": 1.0}],
        "outage": {},
    },
    "student-t": {
        "rate_hz": 20.0, "latency_s": 0.0, "axis_scale": list(_PAPER_SCALE),
        "components": [{"type": "student-t", "name": "white", "sigma": 1.0, "nu": 3.0}],
        "outage": {},
    },
    "laplace": {
        "rate_hz": 20.0, "latency_s": 0.0, "axis_scale": list(_PAPER_SCALE),
        "components": [{"type": "laplace", "name": "white", "sigma": 1.0}],
        "outage": {},
    },
    "weibull": {
        "rate_hz": 20.0, "latency_s": 0.0, "axis_scale": list(_PAPER_SCALE),
        "components": [{"type": "weibull", "name": "white", "sigma": 1.0, "k": 0.8}],
        "outage": {},
    },
    "mixture": {
        "rate_hz": 20.0, "latency_s": 0.0, "axis_scale": list(_PAPER_SCALE),
        "components": [{"type": "mixture", "name": "white", "eps": 0.1,
                        "sigma1": _MIX_S1, "sigma2": math.sqrt(10.0) * _MIX_S1}],
        "outage": {},
    },
    "alpha-stable": {
        "rate_hz": 20.0, "latency_s": 0.0, "axis_scale": list(_PAPER_SCALE),
        "components": [{"type": "alpha-stable", "name": "white", "alpha": 1.5,
                        "scale": 1.0 / math.sqrt(2.0), "beta": 0.0}],
        "outage": {},
    },
    "coloured": {
        "rate_hz": 20.0, "latency_s": 0.0, "axis_scale": list(_PAPER_SCALE),
        "components": [{"type": "ar1", "name": "coloured", "tau_s": 1.0,
                        "driver": {"type": "gaussian", "sigma": 1.0}}],
        "outage": {},
    },
    "coloured-impulsive": {
        "rate_hz": 20.0, "latency_s": 0.0, "axis_scale": list(_PAPER_SCALE),
        "components": [
            {"type": "ar1", "name": "coloured", "tau_s": 1.0,
             "driver": {"type": "gaussian", "sigma": 0.6}},
            {"type": "spikes", "name": "spikes", "prob": 0.04, "amplitude": 4.0},
        ],
        "outage": {},
    },
}

_SENSOR_KEYS = {"rate_hz", "latency_s", "axis_scale", "components", "outage"}


def available_presets() -> list[str]:
    """Names accepted by :func:`gps_preset` / :meth:`GpsSensor.from_preset`."""
    return list(_PRESETS)


def gps_preset(name: str) -> dict[str, Any]:
    """A deep copy of the named preset's config dict (safe to modify)."""
    if name not in _PRESETS:
        raise _bad("gps_preset", "name", name, f"allowed: {', '.join(_PRESETS)}")
    return copy.deepcopy(_PRESETS[name])


def _merge_components(base: list[dict[str, Any]], override: Any) -> list[dict[str, Any]]:
    if isinstance(override, Mapping):
        out = [copy.deepcopy(c) for c in base]
        names = [c.get("name", c.get("type")) for c in out]
        for name, upd in override.items():
            if not isinstance(upd, Mapping):
                raise _bad("gps config", f"components.{name}", upd, "must be a table")
            if name in names:
                i = names.index(name)
                if len(upd) == 0:
                    out.pop(i)
                    names.pop(i)
                else:
                    out[i].update(copy.deepcopy(dict(upd)))
            elif len(upd):
                new = copy.deepcopy(dict(upd))
                new.setdefault("name", name)
                out.append(new)
                names.append(name)
        return out
    if isinstance(override, (list, tuple)):
        return [copy.deepcopy(dict(c)) if isinstance(c, Mapping) else c for c in override]
    raise _bad("gps config", "components", override, "must be a list of tables or a table by name")


# ---------------------------------------------------------------------------------------------
# sensor
# ---------------------------------------------------------------------------------------------


class GpsSensor:
    """GPS position sensor: fixes at multiples of ``1/rate_hz``, optional latency and outages.

    Args:
        rate_hz: fix rate (paper: Ts = 0.05 s -> 20 Hz).
        latency_s: a fix delivered at time t reports the true position at ``t - latency_s``
            (linear interpolation in a small buffer of past ``measure`` inputs).
        components: component config tables (dicts, see module docstring).  Each gets one
            independent scalar process per axis, seeded by ``(name, axis)``.
        seed: SeedSequence or int; the root of every stream of this sensor (keyword-only).
        axis_scale: per-axis multiplier of the summed error, e.g. vertical 1.5-2x horizontal.
        outage: ``{"mean_up_s": ..., "mean_down_s": ..., "start_in_outage": False}`` or None/{}.
    """

    BLOCK = 1024

    def __init__(
        self,
        rate_hz: float = 20.0,
        latency_s: float = 0.0,
        components: Iterable[Mapping[str, Any]] = (),
        *,
        seed: SeedLike,
        axis_scale: Sequence[float] = (1.0, 1.0, 1.0),
        outage: Mapping[str, Any] | None = None,
    ) -> None:
        self.rate_hz = _check_pos("gps", "rate_hz", rate_hz)
        self.latency_s = _check_pos("gps", "latency_s", latency_s, allow_zero=True)
        self.axis_scale = _check_axis_scale("gps", axis_scale)
        self.dt = 1.0 / self.rate_hz
        self.seed = _as_seedseq(seed)
        if isinstance(components, (str, bytes, Mapping)) or not isinstance(components, Iterable):
            raise _bad("gps", "components", components, "must be a list of component tables")
        self.config_components = [dict(c) if isinstance(c, Mapping) else c for c in components]
        # (name, per-axis processes, per-axis scale)
        self.components: list[tuple[str, list[NoiseComponent], tuple[float, float, float]]] = []
        seen: set[str] = set()
        for cfg in self.config_components:
            if not isinstance(cfg, Mapping):
                raise _bad("gps", "components[]", cfg, "each component must be a table/dict")
            name = cfg.get("name", None)
            if name is None:
                name = _norm_type(cfg.get("type"), f"gps component {cfg.get('type')!r}")
            if not isinstance(name, str) or not name:
                raise _bad("gps component", "name", name, "must be a non-empty string")
            if name in seen:
                raise _bad(f"gps component {name!r}", "name", name,
                           "must be unique within a sensor (it keys the random stream)")
            seen.add(name)
            scale = _check_axis_scale(f"gps component {name!r}", cfg.get("axis_scale", (1, 1, 1)))
            procs = [make_component(cfg, derive_seed(self.seed, "component", name, ax))
                     for ax in range(3)]
            self.components.append((name, procs, scale))
        self.outage: OutageProcess | None = None
        if outage:
            if not isinstance(outage, Mapping):
                raise _bad("gps", "outage", outage, "must be a table with mean_up_s, mean_down_s")
            extra = set(outage) - {"mean_up_s", "mean_down_s", "start_in_outage"}
            if extra:
                k = sorted(extra)[0]
                raise _bad("gps outage", k, outage[k],
                           "unknown key; allowed: mean_up_s, mean_down_s, start_in_outage")
            for k in ("mean_up_s", "mean_down_s"):
                if k not in outage:
                    raise _bad("gps outage", k, None, "is required when outages are enabled")
            self.outage = OutageProcess(
                outage["mean_up_s"], outage["mean_down_s"], derive_seed(self.seed, "outage"),
                start_in_outage=outage.get("start_in_outage", False),
            )
        # measure() state
        self._next_k = 0
        self._block: list[list[float]] = []
        self._block_start = 0
        self._hist: deque[tuple[float, float, float, float]] = deque()
        self.last_fix_time: float | None = None

    # -- construction from config ---------------------------------------------------------
    @classmethod
    def from_config(cls, cfg: Mapping[str, Any], seed: SeedLike) -> GpsSensor:
        """Build from a config dict with the sensor keys documented in the module docstring."""
        if not isinstance(cfg, Mapping):
            raise _bad("gps config", "table", cfg, "must be a table/dict")
        for k in cfg:
            if k not in _SENSOR_KEYS:
                raise _bad("gps config", k, cfg[k], f"unknown key; allowed: "
                           f"{', '.join(sorted(_SENSOR_KEYS))}")
        return cls(
            rate_hz=cfg.get("rate_hz", 20.0),
            latency_s=cfg.get("latency_s", 0.0),
            components=cfg.get("components", ()),
            seed=seed,
            axis_scale=cfg.get("axis_scale", (1.0, 1.0, 1.0)),
            outage=cfg.get("outage") or None,
        )

    @classmethod
    def from_preset(cls, name: str, seed: SeedLike, **overrides: Any) -> GpsSensor:
        """Preset ``name`` with top-level keys replaced by ``overrides``; ``components`` may be a
        list (replace) or a dict keyed by component name (merge, see module docstring)."""
        cfg = gps_preset(name)
        for k, v in overrides.items():
            if k not in _SENSOR_KEYS:
                raise _bad(f"gps preset {name!r}", k, v,
                           f"unknown key; allowed: {', '.join(sorted(_SENSOR_KEYS))}")
            if k == "components":
                cfg[k] = _merge_components(cfg[k], v)
            else:
                cfg[k] = v
        return cls.from_config(cfg, seed)

    # -- error generation -------------------------------------------------------------------
    def generate_errors(self, n: int, dt: float | None = None) -> np.ndarray:
        """Next ``n`` per-fix errors as an (n, 3) array (metres); rows are NaN during outages.

        Vectorised (numpy / lfilter).  Continues this sensor's random streams: use a fresh
        sensor for a reproducible offline series.  ``dt`` defaults to ``1 / rate_hz``.
        """
        n = int(n)
        if n < 0:
            raise _bad("gps.generate_errors", "n", n, "must be >= 0")
        step = self.dt if dt is None else _check_pos("gps.generate_errors", "dt", dt)
        err = np.zeros((n, 3))
        for _name, procs, scale in self.components:
            for ax in range(3):
                if scale[ax] != 0.0:
                    err[:, ax] += scale[ax] * procs[ax].sample(n, step)
                else:
                    procs[ax].sample(n, step)  # keep the stream aligned with the fix index
        err *= np.asarray(self.axis_scale)
        if self.outage is not None:
            err[self.outage.sample(n, step)] = np.nan
        return err

    # -- streaming --------------------------------------------------------------------------
    def _truth_at(self, t: float) -> tuple[float, float, float]:
        hist = self._hist
        while len(hist) >= 2 and hist[1][0] <= t:
            hist.popleft()
        t0, x0, y0, z0 = hist[0]
        if len(hist) == 1 or t <= t0:
            return x0, y0, z0
        t1, x1, y1, z1 = hist[1]
        a = (t - t0) / (t1 - t0)
        return x0 + a * (x1 - x0), y0 + a * (y1 - y0), z0 + a * (z1 - z0)

    def measure(self, t: float, p_true_xyz: Sequence[float]) -> np.ndarray | None:
        """Call at control rate with the current time and true position (ENU, m).

        Returns a fix (np.ndarray(3)) when one is due -- at the first call with t at or after
        k / rate_hz -- otherwise None; also None when the fix is lost to an outage.  Fix k uses
        error row k (skipped epochs consume their rows, so the error series is a function of the
        epoch index only).  Calls must have non-decreasing t.
        """
        if self.latency_s > 0.0:
            self._hist.append((t, float(p_true_xyz[0]), float(p_true_xyz[1]),
                               float(p_true_xyz[2])))
        if t < self._next_k * self.dt - 1e-9:
            return None
        k = int(t * self.rate_hz + 1e-9)
        self._next_k = k + 1
        j = k - self._block_start
        while j >= len(self._block):
            self._block_start += len(self._block)
            j = k - self._block_start
            self._block = self.generate_errors(self.BLOCK).tolist()
        ex, ey, ez = self._block[j]
        if ex != ex:  # NaN: outage
            if self.latency_s > 0.0:
                self._truth_at(t - self.latency_s)  # prune the buffer anyway
            return None
        self.last_fix_time = t
        if self.latency_s > 0.0:
            x, y, z = self._truth_at(t - self.latency_s)
        else:
            x, y, z = p_true_xyz[0], p_true_xyz[1], p_true_xyz[2]
        return np.array((x + ex, y + ey, z + ez))

    @property
    def variance(self) -> tuple[float, float, float]:
        """Per-axis stationary error variance implied by the components (inf for alpha-stable)."""
        v = [0.0, 0.0, 0.0]
        for _name, procs, scale in self.components:
            for ax in range(3):
                if scale[ax]:
                    v[ax] += (scale[ax] * self.axis_scale[ax]) ** 2 * procs[ax].variance
        return v[0], v[1], v[2]
