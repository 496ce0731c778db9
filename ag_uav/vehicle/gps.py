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

Fix-quality episodes (``fix_quality``, :class:`FixQualityChain`): a semi-Markov chain over
solution types (for ``rtk-m350``: RTK fixed, RTK float, DGPS/SBAS) with geometric dwell times of
exactly the configured means and a jump table; each type adds its own error components, blended
in with a first-order ramp when the solution degrades and snapped out when it re-fixes.  The fix
type of every fix is exposed (``GpsSensor.last_fix_type``, ``fix_type_counts``,
``generate_errors(..., with_fix_type=True)``) so the loop can log it; the filters are NOT told it:
their R is built from :attr:`GpsSensor.variance`, the nominal level (the base components; for
``rtk-m350`` the RTK-fixed datasheet accuracy), the robust-filter premise of the core paper.

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
Fix quality: ``fix_quality`` = ``{start = "<mode>", modes = {<mode> = {mean_dwell_s (> 0),
next = {<other mode> = probability, ...} (sums to 1), ramp_s (>= 0, default 0),
components = [...]}}}``; an empty table means no episodes.  Overrides merge by mode name (a
mode's ``components`` merge like the sensor's; an empty mode table removes the mode).

Validation: every value is checked strictly (a string or bool where a number is due, NaN/inf,
out of range, an unknown key or a non-table where a table is due raises ValueError with one line
naming the key, the value and what is allowed); :func:`validate_overrides` runs the same checks
for a preset's overrides without keeping a sensor (for config loading).

Presets (:func:`gps_preset`) are illustrative engineering values, not datasheet figures, except
``rtk-m350``, whose figures cite their sources (datasheets, literature) or say they are
engineering judgement; see ``_PRESETS`` and ``_RTK_M350`` below for the reasoning behind each
number.
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
    "FixQualityChain",
    "GaussMarkov",
    "Gaussian",
    "GaussianMixture",
    "GpsSensor",
    "Laplace",
    "MultipathSpikes",
    "NoiseComponent",
    "OutageProcess",
    "ReceiverReport",
    "StudentT",
    "SymmetricWeibull",
    "available_presets",
    "derive_seed",
    "gps_preset",
    "make_component",
    "validate_overrides",
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


def _real(who: str, key: str, value: Any, allowed: str = "must be a number") -> float:
    """``value`` as a float, strictly: a bool, a string or anything else that is not a real
    number is refused (``float("0.5")`` and ``float(True)`` would silently accept them)."""
    if isinstance(value, (bool, np.bool_)) or not isinstance(value, (int, float, np.integer,
                                                                      np.floating)):
        raise _bad(who, key, value, allowed)
    return float(value)


def _check_pos(
    who: str, key: str, value: Any, *, allow_zero: bool = False, le: float | None = None
) -> float:
    rng = (">= 0" if allow_zero else "> 0") + ("" if le is None else f" and <= {le:g}")
    v = _real(who, key, value, f"must be a finite number {rng}")
    ok = math.isfinite(v) and (v >= 0.0 if allow_zero else v > 0.0)
    if ok and le is not None:
        ok = v <= le
    if not ok:
        raise _bad(who, key, value, f"must be finite and {rng}")
    return v


def _check_axis_scale(who: str, value: Any) -> tuple[float, float, float]:
    allowed = "must be a list of 3 finite numbers >= 0"
    if isinstance(value, (str, bytes, Mapping)) or not isinstance(value, (Sequence, np.ndarray)):
        raise _bad(who, "axis_scale", value, allowed)
    if len(value) != 3:
        raise _bad(who, "axis_scale", value, allowed)
    out = []
    for x in value:
        if isinstance(x, (bool, np.bool_)) or not isinstance(x, (int, float, np.integer,
                                                                 np.floating)):
            raise _bad(who, "axis_scale", value, allowed)
        f = float(x)
        if not (math.isfinite(f) and f >= 0.0):
            raise _bad(who, "axis_scale", value, allowed)
        out.append(f)
    return out[0], out[1], out[2]


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
        b = _real("alpha-stable", "beta", beta, "must be a number in [-1, 1]")
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
            r = _real("ar1", "rho", rho, "must be a number in (-1, 1)")
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


_MODE_KEYS = {"mean_dwell_s", "ramp_s", "next", "components"}
_FIXQ_KEYS = {"start", "modes"}


class FixQualityChain:
    """Fix-quality episodes: a semi-Markov chain over solution types (e.g. RTK fixed, RTK float,
    DGPS/SBAS) and the blending weights of their extra error.

    Dwell: a run in mode ``i`` lasts ``L ~ Geometric(p_i)`` fixes, ``p_i = min(1, dt / T_i)``,
    so ``E[L] dt = T_i`` exactly (``T_i = mean_dwell_s``, for ``T_i >= dt``).  On leaving ``i``
    the next mode is ``j`` with probability ``P_ij`` (``next``; ``P_ii = 0``).  With ``nu`` the
    stationary law of the jump chain (``nu P = nu``), the long-run fraction of fixes in mode ``i``
    is ``pi_i = nu_i T_i / sum_j nu_j T_j`` (renewal-reward; :meth:`occupancy`).

    Transitions: each mode ``i`` has a time constant ``ramp_s = r_i``; while mode ``i`` is active
    the weight vector moves towards the one-hot ``e_i`` at every fix,
    ``w_k = e_i + (w_{k-1} - e_i) a_i``, ``a_i = exp(-dt / r_i)`` (``a_i = 0`` for ``r_i = 0``: a
    snap).  The sensor adds ``sum_i w_{k,i} e^{(i)}_k`` (each mode's own error processes, always
    running) to the base error.  So a degradation grows smoothly (the receiver's navigation
    filter carries the previous solution) while an ambiguity fix snaps back in one epoch, as a
    real receiver's position does when the integers are resolved.

    Randomness: per mode one dwell stream and one next-mode stream, keyed by the mode's name.
    ``sample`` is chunk invariant (the weights are computed in closed form within a run,
    ``w_{k0+j} = e_i + (w_{k0} - e_i) a_i^j``, equal to the recursion to rounding).
    """

    def __init__(
        self, modes: Mapping[str, Mapping[str, Any]], seed: SeedLike, start: str | None = None
    ) -> None:
        who = "gps fix_quality"
        if not isinstance(modes, Mapping) or len(modes) < 2:
            raise _bad(who, "modes", modes, "must be a table of >= 2 mode tables keyed by name")
        names = list(modes)
        for nm in names:
            if not isinstance(nm, str) or not nm:
                raise _bad(who, "modes", nm, "mode names must be non-empty strings")
        self.names: tuple[str, ...] = tuple(names)
        m = len(names)
        self.mean_dwell_s = np.empty(m)
        self.ramp_s = np.empty(m)
        self.P = np.zeros((m, m))
        for i, nm in enumerate(names):
            cfg = modes[nm]
            mw = f"{who} mode {nm!r}"
            if not isinstance(cfg, Mapping):
                raise _bad(who, f"modes.{nm}", cfg, "must be a table with mean_dwell_s, next, "
                           "ramp_s, components")
            for k in cfg:
                if k not in _MODE_KEYS:
                    raise _bad(mw, k, cfg[k],
                               f"unknown key; allowed: {', '.join(sorted(_MODE_KEYS))}")
            for k in ("mean_dwell_s", "next"):
                if k not in cfg:
                    raise _bad(mw, k, None, "is required")
            self.mean_dwell_s[i] = _check_pos(mw, "mean_dwell_s", cfg["mean_dwell_s"])
            self.ramp_s[i] = _check_pos(mw, "ramp_s", cfg.get("ramp_s", 0.0), allow_zero=True)
            nxt = cfg["next"]
            allowed = (f"must be a table of probabilities (>= 0, summing to 1) over the other "
                       f"modes ({', '.join(x for x in names if x != nm)})")
            if not isinstance(nxt, Mapping) or not nxt:
                raise _bad(mw, "next", nxt, allowed)
            for tgt, pr in nxt.items():
                if tgt not in names or tgt == nm:
                    raise _bad(mw, f"next.{tgt}", pr, allowed)
                self.P[i, names.index(tgt)] = _check_pos(mw, f"next.{tgt}", pr, allow_zero=True,
                                                         le=1.0)
            if abs(self.P[i].sum() - 1.0) > 1e-9:
                raise _bad(mw, "next", dict(nxt), allowed)
        if start is None:
            start = names[0]
        if start not in names:
            raise _bad(who, "start", start, f"must be one of the modes: {', '.join(names)}")
        self.start = start
        ss = _as_seedseq(seed)
        self._rng_dwell = [np.random.Generator(np.random.PCG64(derive_seed(ss, "dwell", nm)))
                           for nm in names]
        self._rng_next = [np.random.Generator(np.random.PCG64(derive_seed(ss, "next", nm)))
                          for nm in names]
        self.P /= self.P.sum(axis=1, keepdims=True)
        self._cum = np.cumsum(self.P, axis=1)
        self._last = [int(np.flatnonzero(row > 0.0)[-1]) for row in self.P]
        self._mode = names.index(start)
        self._left = 0
        self._fresh = True
        self._w = np.zeros(m)
        self._w[self._mode] = 1.0

    @property
    def mode(self) -> str:
        """The current mode (that of the last fix sampled; the start mode before any)."""
        return self.names[self._mode]

    def occupancy(self) -> dict[str, float]:
        """Long-run fraction of fixes in each mode: ``pi_i = nu_i T_i / sum_j nu_j T_j``."""
        m = len(self.names)
        a = np.vstack([(self.P.T - np.eye(m)), np.ones((1, m))])
        b = np.zeros(m + 1)
        b[-1] = 1.0
        nu = np.linalg.lstsq(a, b, rcond=None)[0]
        occ = nu * self.mean_dwell_s
        occ = occ / occ.sum()
        return {nm: float(v) for nm, v in zip(self.names, occ, strict=True)}

    def sample(self, n: int, dt: float) -> tuple[np.ndarray, np.ndarray]:
        """Next ``n`` fixes: (mode index per fix (int8), blending weights (n, modes))."""
        m = len(self.names)
        idx = np.empty(n, dtype=np.int8)
        w = np.empty((n, m))
        i = 0
        while i < n:
            if self._left <= 0:
                if not self._fresh:
                    u = self._rng_next[self._mode].random()
                    j = int(np.searchsorted(self._cum[self._mode], u, side="right"))
                    self._mode = min(j, self._last[self._mode])
                self._fresh = False
                p = min(1.0, dt / self.mean_dwell_s[self._mode])
                self._left = int(self._rng_dwell[self._mode].geometric(p))
            k = min(self._left, n - i)
            cur = self._mode
            idx[i : i + k] = cur
            e = np.zeros(m)
            e[cur] = 1.0
            r = self.ramp_s[cur]
            if r > 0.0:
                a = math.exp(-dt / r)
                pw = a ** np.arange(1, k + 1, dtype=float)
                w[i : i + k] = e + (self._w - e)[None, :] * pw[:, None]
            else:
                w[i : i + k] = e
            self._w = w[i + k - 1].copy()
            i += k
            self._left -= k
        return idx, w


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

# --- rtk-m350: a DJI Matrice 350 RTK-class receiver with fix-quality episodes -----------------
# Figures and where they come from ("judgement" marks an engineering judgement, not a datasheet):
# [DJI-M350]  DJI Matrice 350 RTK specifications (dji.com/matrice-350-rtk/specs), GNSS section:
#             "RTK positioning accuracy (RTK FIX): 1 cm + 1 ppm (horizontal), 1.5 cm + 1 ppm
#             (vertical)".  The same horizontal figure is in the D-RTK 2 High Precision GNSS
#             Mobile Station datasheet [D-RTK2], which lists "positioning update rate: 1, 2, 5,
#             10, 20 Hz" and single-point accuracy 1.5 m H / 3.0 m V (RMS).
# [F9P]       u-blox ZED-F9P data sheet (UBX-17051259) and integration manual (UBX-18010802): RTK
#             navigation update rate up to 20 Hz (lower with all four constellations),
#             "convergence time RTK < 10 s", horizontal accuracy "SBAS 1.0 m CEP", "RTK 0.01 m +
#             1 ppm CEP"; carrier solution states none / float / fixed (NMEA GGA quality 2 =
#             DGPS, 5 = RTK float, 4 = RTK fixed).
# [FLOAT]     RTK float: "typically 10 cm to 50 cm horizontally" (diginto.tech, "Float vs Fixed
#             RTK: Understanding Ambiguity Resolution"); "decimetre to sub-metre" (Point One
#             Navigation, "Float RTK"); Takasu & Yasuda 2009 (ION GNSS, RTKLIB) show float
#             errors of decimetres before the fix.
# [GK88]      Georgiadou & Kleusberg 1988, "On carrier signal multipath effects in relative GPS
#             positioning", manuscripta geodaetica 13: carrier-phase multipath is a slowly varying
#             (periods of minutes for a static antenna), centimetre-level error.
#
# * rate 10 Hz: within the 1-20 Hz of [D-RTK2]; 20 Hz is the [F9P] ceiling with few
#   constellations, a multi-constellation RTK engine sustains ~10 Hz (judgement; set rate_hz=20 to
#   test the ceiling).
# * base level (always on) = RTK fixed: horizontal RMS 1 cm + 1 ppm x baseline [DJI-M350], baseline
#   1 km (D-RTK 2 at the field edge; judgement) -> 1.1 cm H RMS -> per axis 1.1/sqrt(2) = 0.78 cm;
#   vertical 1.5 cm + 1 ppm = 1.6 cm (z axis_scale = 1.6 / 0.78 = 2.06).  Split 60 % of the
#   variance coloured (Gauss-Markov, tau = 30 s: carrier multipath is minutes-slow for a static
#   antenna [GK88], faster on a moving one; judgement) and 40 % white Student-t (nu = 4: heavier
#   tails than Gaussian, finite kurtosis only for nu > 4 so outliers are real; judgement).
# * rtk-fixed mode extra: rare glitches (cycle slips, partial re-fixes): spikes with probability
#   0.001 per fix (one per ~100 s at 10 Hz), 5-20 cm (judgement).
# * rtk-float: H RMS 0.3 m (middle of the 0.1-0.5 m of [FLOAT]) -> per axis 0.21 m; 80 % coloured
#   (GM tau = 20 s: float ambiguities drift slowly as they converge; judgement) + 20 % Student-t
#   (nu = 4); code-multipath spikes 1 % of fixes, 0.3-1.0 m (judgement); vertical x 2 (VDOP/HDOP
#   ~ 1.5-2 in open sky; judgement).
# * dgps (DGPS / SBAS): 1.0 m CEP [F9P] -> per axis sigma = CEP / 1.1774 = 0.85 m; 85 % coloured
#   (GM tau = 60 s: residual ionosphere/orbit errors vary over minutes; judgement) + 15 %
#   Student-t (nu = 4); spikes 1 % of fixes, 1-3 m (code multipath; judgement); vertical x 2.83
#   (= the 3.0 m V / (1.5 m H / sqrt(2)) ratio of [D-RTK2]'s single-point figures).
# * episode chain (all judgement, tuned to "degrades for tens of seconds, then recovers"):
#   mean dwell RTK fixed 300 s (an open field with the base <= 1 km: fix is lost to tree lines,
#   masking in banked turns and radio-link drop-outs, a few times an hour), RTK float 20 s
#   (twice the [F9P] open-sky convergence time < 10 s, since the conditions that broke the fix
#   persist a while), DGPS/SBAS 30 s (a correction-link drop-out of tens of seconds).  On leaving
#   fixed: 85 % to float, 15 % straight to DGPS (link loss); float: 80 % re-fixes, 20 % falls to
#   DGPS; DGPS always returns through float (an RTK engine re-converges before it fixes).
#   Occupancy pi_i ~ nu_i T_i with nu ~ (0.8, 1, 0.32): fixed 240/269.6 = 89.0 %, float
#   20/269.6 = 7.4 %, DGPS 9.6/269.6 = 3.6 %.
# * transitions: fixed -> degraded modes ramp with the degraded mode's ramp_s (float 2 s, DGPS
#   3 s: the receiver's navigation filter carries the last solution and drifts off it over a few
#   seconds; judgement); any -> fixed snaps in one epoch (ramp_s = 0): resolving the integers
#   corrects the position at once, a step of the float error (decimetres), as real receivers do.
_M350_BASELINE_M = 1000.0
_M350_FIX_H_RMS = 0.010 + 1e-6 * _M350_BASELINE_M  # [DJI-M350] 1 cm + 1 ppm, horizontal RMS
_M350_FIX_V_RMS = 0.015 + 1e-6 * _M350_BASELINE_M  # [DJI-M350] 1.5 cm + 1 ppm, vertical
_M350_FIX_SIG = _M350_FIX_H_RMS / math.sqrt(2.0)   # per horizontal axis
_M350_FLOAT_SIG = 0.30 / math.sqrt(2.0)            # [FLOAT] 0.3 m H RMS, per axis
_M350_DGPS_SIG = 1.0 / 1.1774                      # [F9P] SBAS 1.0 m CEP, per axis (CEP = 1.1774 s)


def _split(sigma: float, coloured: float, tau_s: float, nu: float = 4.0) -> list[dict[str, Any]]:
    """A Gauss-Markov part with ``coloured`` of the variance ``sigma**2`` plus a Student-t
    white part with the rest (total variance ``sigma**2``)."""
    return [
        {"type": "gauss-markov", "name": "coloured", "sigma": sigma * math.sqrt(coloured),
         "tau_s": tau_s},
        {"type": "student-t", "name": "white", "sigma": sigma * math.sqrt(1.0 - coloured),
         "nu": nu},
    ]


_RTK_M350: dict[str, Any] = {
    "rate_hz": 10.0, "latency_s": 0.0, "axis_scale": [1.0, 1.0, 1.0],
    "components": [{**c, "axis_scale": [1.0, 1.0, _M350_FIX_V_RMS / _M350_FIX_SIG]}
                   for c in _split(_M350_FIX_SIG, 0.6, 30.0)],
    "outage": {},
    "fix_quality": {
        "start": "rtk-fixed",
        "modes": {
            "rtk-fixed": {
                "mean_dwell_s": 300.0, "ramp_s": 0.0,
                "next": {"rtk-float": 0.85, "dgps": 0.15},
                "components": [{"type": "spikes", "name": "glitch", "prob": 0.001,
                                "amplitude": 0.05, "amplitude_max": 0.20}],
            },
            "rtk-float": {
                "mean_dwell_s": 20.0, "ramp_s": 2.0,
                "next": {"rtk-fixed": 0.8, "dgps": 0.2},
                "components": [
                    *({**c, "axis_scale": [1.0, 1.0, 2.0]}
                      for c in _split(_M350_FLOAT_SIG, 0.8, 20.0)),
                    {"type": "spikes", "name": "multipath", "prob": 0.01, "amplitude": 0.3,
                     "amplitude_max": 1.0, "axis_scale": [1.0, 1.0, 2.0]},
                ],
            },
            "dgps": {
                "mean_dwell_s": 30.0, "ramp_s": 3.0,
                "next": {"rtk-float": 1.0},
                "components": [
                    *({**c, "axis_scale": [1.0, 1.0, 2.83]}
                      for c in _split(_M350_DGPS_SIG, 0.85, 60.0)),
                    {"type": "spikes", "name": "multipath", "prob": 0.01, "amplitude": 1.0,
                     "amplitude_max": 3.0, "axis_scale": [1.0, 1.0, 2.83]},
                ],
            },
        },
    },
}

_PRESETS["rtk-m350"] = _RTK_M350

_SENSOR_KEYS = {"rate_hz", "latency_s", "axis_scale", "components", "outage", "fix_quality"}
_OUTAGE_KEYS = {"mean_up_s", "mean_down_s", "start_in_outage"}
#: upper bounds of the sensor keys (no GNSS receiver in this class outputs > 100 Hz, the loop's
#: control rate; a GNSS latency is tens of milliseconds, 1 s is a generous ceiling)
MAX_RATE_HZ = 100.0
MAX_LATENCY_S = 1.0


def available_presets() -> list[str]:
    """Names accepted by :func:`gps_preset` / :meth:`GpsSensor.from_preset`."""
    return list(_PRESETS)


def gps_preset(name: str) -> dict[str, Any]:
    """A deep copy of the named preset's config dict (safe to modify)."""
    if not isinstance(name, str) or name not in _PRESETS:
        raise _bad("gps_preset", "name", name, f"allowed: {', '.join(_PRESETS)}")
    return copy.deepcopy(_PRESETS[name])


def _table(who: str, key: str, value: Any, allowed: str) -> dict[str, Any]:
    """``value`` as a dict with string keys, or a ValueError naming ``key``."""
    if not isinstance(value, Mapping):
        raise _bad(who, key, value, allowed)
    for k in value:
        if not isinstance(k, str) or not k:
            raise _bad(who, f"{key} key", k, "table keys must be non-empty strings")
    return dict(value)


def _merge_components(
    base: list[dict[str, Any]], override: Any, who: str = "gps config", key: str = "components"
) -> list[dict[str, Any]]:
    """Override ``base`` component tables: a list replaces them all; a table keyed by component
    name merges keys into that component (an empty table removes it; a new name adds one)."""
    allowed = "must be a list of component tables or a table of them keyed by name"
    if isinstance(override, Mapping):
        out = [copy.deepcopy(c) for c in base]
        names = [c.get("name", c.get("type")) for c in out]
        for name, upd in _table(who, key, override, allowed).items():
            if not isinstance(upd, Mapping):
                raise _bad(who, f"{key}.{name}", upd, "must be a table of component keys "
                           "(an empty table removes the component)")
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
        out = []
        for i, c in enumerate(override):
            if not isinstance(c, Mapping):
                raise _bad(who, f"{key}[{i}]", c, "must be a component table with a 'type' key")
            out.append(copy.deepcopy(dict(c)))
        return out
    raise _bad(who, key, override, allowed)


def _merge_fix_quality(base: Mapping[str, Any], override: Any) -> dict[str, Any]:
    """Override a ``fix_quality`` table: an empty table disables the episodes; otherwise
    ``start`` is replaced and ``modes`` merge by name (a mode's keys are replaced except
    ``components``, which merge as at sensor level; an empty mode table removes the mode)."""
    who = "gps fix_quality"
    ov = _table("gps config", "fix_quality", override,
                "must be a table with keys start, modes (an empty table disables episodes)")
    if not ov:
        return {}
    for k in ov:
        if k not in _FIXQ_KEYS:
            raise _bad(who, k, ov[k], f"unknown key; allowed: {', '.join(sorted(_FIXQ_KEYS))}")
    out = copy.deepcopy(dict(base)) if base else {}
    if "start" in ov:
        out["start"] = ov["start"]
    if "modes" in ov:
        modes = dict(out.get("modes", {}))
        for nm, upd in _table(who, "modes", ov["modes"], "must be a table of mode tables "
                              "keyed by mode name").items():
            if not isinstance(upd, Mapping):
                raise _bad(who, f"modes.{nm}", upd, "must be a table with mean_dwell_s, next, "
                           "ramp_s, components (an empty table removes the mode)")
            if nm in modes and not upd:
                del modes[nm]
                continue
            cur = copy.deepcopy(dict(modes.get(nm, {})))
            for k, v in upd.items():
                if k == "components":
                    cur[k] = _merge_components(cur.get(k, []), v, who, f"modes.{nm}.components")
                else:
                    cur[k] = copy.deepcopy(v)
            modes[nm] = cur
        out["modes"] = modes
    return out


def _apply_overrides(preset: str, overrides: Any) -> dict[str, Any]:
    """The preset's config dict with ``overrides`` applied (structure checked, values not)."""
    cfg = gps_preset(preset)
    ov = _table(f"gps preset {preset!r}", "overrides", overrides,
                f"must be a table with keys among {', '.join(sorted(_SENSOR_KEYS))}")
    for k, v in ov.items():
        if k not in _SENSOR_KEYS:
            raise _bad(f"gps preset {preset!r}", k, v,
                       f"unknown key; allowed: {', '.join(sorted(_SENSOR_KEYS))}")
        if k == "components":
            cfg[k] = _merge_components(cfg.get(k, []), v)
        elif k == "fix_quality":
            cfg[k] = _merge_fix_quality(cfg.get(k, {}), v)
        elif k == "outage":
            cfg[k] = _table("gps config", "outage", v,
                            "must be a table with mean_up_s, mean_down_s[, start_in_outage] "
                            "(an empty table means no outages)")
        else:
            cfg[k] = v
    return cfg


def validate_overrides(preset: str, overrides: Any) -> None:
    """Check ``gps.overrides`` for preset ``preset`` without keeping a sensor.

    Raises ValueError with a one-line message naming the key, the value and what is allowed for
    any unknown key, wrong type (a string or bool where a number is due, a non-table where a
    table is due), NaN/inf, out-of-range value or badly nested table.  It merges the overrides
    into the preset and builds the sensor's components once (cheap: nothing is drawn), so every
    check the run would make is made here.
    """
    GpsSensor.from_config(_apply_overrides(preset, overrides), 0)


# ---------------------------------------------------------------------------------------------
# sensor
# ---------------------------------------------------------------------------------------------

_Built = list[tuple[str, list[NoiseComponent], tuple[float, float, float]]]


def _build_components(cfgs: Any, root: np.random.SeedSequence, who: str, *key: str) -> _Built:
    """(name, per-axis processes, per-axis scale) for each component table; streams keyed by
    ``(*key, name, axis)`` under ``root``."""
    if isinstance(cfgs, (str, bytes, Mapping)) or not isinstance(cfgs, Iterable):
        raise _bad(who, "components", cfgs, "must be a list of component tables")
    out: _Built = []
    seen: set[str] = set()
    for cfg in cfgs:
        if not isinstance(cfg, Mapping):
            raise _bad(who, "components[]", cfg, "each component must be a table/dict")
        name = cfg.get("name", None)
        if name is None:
            name = _norm_type(cfg.get("type"), f"{who} component {cfg.get('type')!r}")
        if not isinstance(name, str) or not name:
            raise _bad(f"{who} component", "name", name, "must be a non-empty string")
        if name in seen:
            raise _bad(f"{who} component {name!r}", "name", name,
                       "must be unique within a sensor (it keys the random stream)")
        seen.add(name)
        scale = _check_axis_scale(f"{who} component {name!r}", cfg.get("axis_scale", (1, 1, 1)))
        procs = [make_component(cfg, derive_seed(root, *key, name, ax)) for ax in range(3)]
        out.append((name, procs, scale))
    return out


def _sum_components(comps: _Built, n: int, step: float) -> np.ndarray:
    err = np.zeros((n, 3))
    for _name, procs, scale in comps:
        for ax in range(3):
            if scale[ax] != 0.0:
                err[:, ax] += scale[ax] * procs[ax].sample(n, step)
            else:
                procs[ax].sample(n, step)  # keep the stream aligned with the fix index
    return err


def _comp_variance(comps: _Built) -> np.ndarray:
    v = np.zeros(3)
    for _name, procs, scale in comps:
        for ax in range(3):
            if scale[ax]:
                v[ax] += scale[ax] ** 2 * procs[ax].variance
    return v


class GpsSensor:
    """GPS position sensor: fixes at multiples of ``1/rate_hz``, optional latency, outages and
    fix-quality episodes.

    Error of fix k (per axis, before ``axis_scale``):
    ``e_k = sum_c e^{(c)}_k + sum_i w_{k,i} sum_{c in mode i} e^{(c)}_k`` -- the base components
    plus, with ``fix_quality``, every mode's own components weighted by the episode chain's
    blending weights (:class:`FixQualityChain`).

    Args:
        rate_hz: fix rate in (0, 100] Hz (paper: Ts = 0.05 s -> 20 Hz).
        latency_s: in [0, 1] s; a fix delivered at time t reports the true position at
            ``t - latency_s`` (linear interpolation in a small buffer of past ``measure`` inputs).
        components: component config tables (dicts, see module docstring).  Each gets one
            independent scalar process per axis, seeded by ``(name, axis)``.
        seed: SeedSequence or int; the root of every stream of this sensor (keyword-only).
        axis_scale: per-axis multiplier of the summed error, e.g. vertical 1.5-2x horizontal.
        outage: ``{"mean_up_s": ..., "mean_down_s": ..., "start_in_outage": False}`` or None/{}.
        fix_quality: ``{"start": mode, "modes": {name: {"mean_dwell_s", "next", "ramp_s",
            "components"}}}`` or None/{} (no episodes).

    The fix type is exposed (:attr:`last_fix_type`, :attr:`fix_type_counts`,
    ``generate_errors(..., with_fix_type=True)``) for logging only: the filters are not told it.
    Their ``R`` comes from :attr:`variance`, the *nominal* error (the base components: for
    ``rtk-m350`` the RTK-fixed datasheet level) -- the robust-filter premise of the core paper,
    where R is fixed and the filter must cope with whatever the noise does.
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
        fix_quality: Mapping[str, Any] | None = None,
    ) -> None:
        self.rate_hz = _check_pos("gps", "rate_hz", rate_hz, le=MAX_RATE_HZ)
        self.latency_s = _check_pos("gps", "latency_s", latency_s, allow_zero=True,
                                    le=MAX_LATENCY_S)
        self.axis_scale = _check_axis_scale("gps", axis_scale)
        self.dt = 1.0 / self.rate_hz
        self.seed = _as_seedseq(seed)
        if isinstance(components, (str, bytes, Mapping)) or not isinstance(components, Iterable):
            raise _bad("gps", "components", components, "must be a list of component tables")
        self.config_components = [dict(c) if isinstance(c, Mapping) else c for c in components]
        #: (name, per-axis processes, per-axis scale) of the base components
        self.components: _Built = _build_components(self.config_components, self.seed, "gps",
                                                    "component")
        self.outage: OutageProcess | None = None
        if outage is not None and not isinstance(outage, Mapping):
            raise _bad("gps", "outage", outage, "must be a table with mean_up_s, mean_down_s "
                       "(an empty table means no outages)")
        if outage:
            extra = set(outage) - _OUTAGE_KEYS
            if extra:
                k = sorted(extra, key=str)[0]
                raise _bad("gps outage", k, outage[k],
                           "unknown key; allowed: mean_up_s, mean_down_s, start_in_outage")
            for k in ("mean_up_s", "mean_down_s"):
                if k not in outage:
                    raise _bad("gps outage", k, None, "is required when outages are enabled")
            self.outage = OutageProcess(
                outage["mean_up_s"], outage["mean_down_s"], derive_seed(self.seed, "outage"),
                start_in_outage=outage.get("start_in_outage", False),
            )
        self.fix_quality: FixQualityChain | None = None
        #: per mode of the chain, its extra components
        self.mode_components: list[_Built] = []
        if fix_quality is not None and not isinstance(fix_quality, Mapping):
            raise _bad("gps", "fix_quality", fix_quality, "must be a table with start, modes "
                       "(an empty table means no episodes)")
        if fix_quality:
            for k in fix_quality:
                if k not in _FIXQ_KEYS:
                    raise _bad("gps fix_quality", k, fix_quality[k],
                               f"unknown key; allowed: {', '.join(sorted(_FIXQ_KEYS))}")
            if "modes" not in fix_quality:
                raise _bad("gps fix_quality", "modes", None, "is required")
            self.fix_quality = FixQualityChain(
                fix_quality["modes"], derive_seed(self.seed, "fix_quality"),
                start=fix_quality.get("start"))
            for nm in self.fix_quality.names:
                self.mode_components.append(_build_components(
                    fix_quality["modes"][nm].get("components", []), self.seed,
                    f"gps fix_quality mode {nm!r}", "mode", nm))
        # measure() state
        self._next_k = 0
        self._block: list[list[float]] = []
        self._block_types: list[int] = []
        self._block_start = 0
        self._hist: deque[tuple[float, float, float, float]] = deque()
        self.last_fix_time: float | None = None
        #: fix type of the last delivered fix (None without fix_quality or before any fix)
        self.last_fix_type: str | None = None
        #: delivered fixes per fix type (empty without fix_quality)
        self.fix_type_counts: dict[str, int] = dict.fromkeys(self.fix_types, 0)

    @property
    def fix_types(self) -> tuple[str, ...]:
        """Names of the fix types (the modes of ``fix_quality``; empty without it)."""
        return self.fix_quality.names if self.fix_quality is not None else ()

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
            outage=cfg.get("outage"),
            fix_quality=cfg.get("fix_quality"),
        )

    @classmethod
    def from_preset(cls, name: str, seed: SeedLike, **overrides: Any) -> GpsSensor:
        """Preset ``name`` with top-level keys replaced by ``overrides``; ``components`` may be a
        list (replace) or a dict keyed by component name (merge), ``fix_quality`` merges by mode
        (see module docstring).  Every override is checked (see :func:`validate_overrides`)."""
        return cls.from_config(_apply_overrides(name, overrides), seed)

    # -- error generation -------------------------------------------------------------------
    def generate_errors(
        self, n: int, dt: float | None = None, *, with_fix_type: bool = False
    ) -> np.ndarray | tuple[np.ndarray, np.ndarray]:
        """Next ``n`` per-fix errors as an (n, 3) array (metres); rows are NaN during outages.

        With ``with_fix_type`` also the fix type of each fix: an int8 array indexing
        :attr:`fix_types` (-1 everywhere without ``fix_quality``).  Vectorised (numpy / lfilter).
        Continues this sensor's random streams: use a fresh sensor for a reproducible offline
        series.  ``dt`` defaults to ``1 / rate_hz``.
        """
        if isinstance(n, (bool, np.bool_)) or not isinstance(n, (int, np.integer)) or n < 0:
            raise _bad("gps.generate_errors", "n", n, "must be an int >= 0")
        n = int(n)
        step = self.dt if dt is None else _check_pos("gps.generate_errors", "dt", dt)
        err = _sum_components(self.components, n, step)
        types = np.full(n, -1, dtype=np.int8)
        if self.fix_quality is not None:
            types, w = self.fix_quality.sample(n, step)
            for i, comps in enumerate(self.mode_components):
                if comps:
                    err += w[:, i : i + 1] * _sum_components(comps, n, step)
        err *= np.asarray(self.axis_scale)
        if self.outage is not None:
            err[self.outage.sample(n, step)] = np.nan
        return (err, types) if with_fix_type else err

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
        epoch index only).  Calls must have non-decreasing t.  A delivered fix updates
        :attr:`last_fix_type` and :attr:`fix_type_counts`.
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
            err, types = self.generate_errors(self.BLOCK, with_fix_type=True)
            self._block = err.tolist()
            self._block_types = types.tolist()
        ex, ey, ez = self._block[j]
        if ex != ex:  # NaN: outage
            if self.latency_s > 0.0:
                self._truth_at(t - self.latency_s)  # prune the buffer anyway
            return None
        self.last_fix_time = t
        ti = self._block_types[j]
        if ti >= 0:
            ft = self.fix_types[ti]
            self.last_fix_type = ft
            self.fix_type_counts[ft] += 1
        if self.latency_s > 0.0:
            x, y, z = self._truth_at(t - self.latency_s)
        else:
            x, y, z = p_true_xyz[0], p_true_xyz[1], p_true_xyz[2]
        return np.array((x + ex, y + ey, z + ez))

    @property
    def variance(self) -> tuple[float, float, float]:
        """Per-axis *nominal* error variance: that of the base components (inf for
        alpha-stable), times ``axis_scale**2``.  With ``fix_quality`` the episodes' extra error
        is left out on purpose: this is what the estimators' ``R`` is built from
        (``R = r_scale * variance``), and it stands for the accuracy the receiver is specified
        at in its nominal mode (for ``rtk-m350``: RTK fixed, 1 cm + 1 ppm), which is also the
        mode it is in most of the time.  See :meth:`mode_variance` for each mode's level."""
        v = _comp_variance(self.components) * np.asarray(self.axis_scale) ** 2
        return float(v[0]), float(v[1]), float(v[2])

    def mode_variance(self, mode: str) -> tuple[float, float, float]:
        """Per-axis error variance while fully in fix type ``mode`` (after its ramp): base plus
        the mode's own components, times ``axis_scale**2``."""
        if mode not in self.fix_types:
            raise _bad("gps.mode_variance", "mode", mode,
                       f"allowed: {', '.join(self.fix_types) or '(no fix_quality)'}")
        i = self.fix_types.index(mode)
        v = (_comp_variance(self.components) + _comp_variance(self.mode_components[i])) \
            * np.asarray(self.axis_scale) ** 2
        return float(v[0]), float(v[1]), float(v[2])

    def reported_variance(self, mode: str | None) -> tuple[float, float, float]:
        """The per-axis variance a receiver reports with a fix of type ``mode``: the mode's
        (:meth:`mode_variance`), or the nominal :attr:`variance` for no or an unknown type
        (memoised: the run log asks at every fix)."""
        memo = self.__dict__.setdefault("_reported", {})
        v = memo.get(mode)
        if v is None:
            v = memo[mode] = (self.mode_variance(mode) if mode in self.fix_types
                              else self.variance)
        return v


# ---------------------------------------------------------------------------------------------
# what the receiver reports with each fix (an honest receiver)
# ---------------------------------------------------------------------------------------------
class ReceiverReport:
    """What a receiver with fix types reports beside each fix, and its false fixes.

    Called once per delivered fix with the fix type the error chain is in
    (:attr:`GpsSensor.last_fix_type`); returns ``(bias (3), reported type, accuracy scale)``:

    * **False fixes.** While the true type is ``fixed`` (default ``"rtk-fixed"``) a false-fix
      episode starts with probability ``1 − exp(−λ Δt)`` per fix (λ = ``per_hour`` / 3600):
      the receiver resolved wrong integer ambiguities and reports RTK fixed with a constant 3-D
      bias ``b = m u`` (``m ~ U(bias_m)``, ``u`` uniform on the sphere) for ``T ~ Exp(mean_s)``,
      or until the true type leaves fixed. The reported type stays ``fixed`` throughout.
    * **Late fix-type reports.** The reported type is the true type ``lag`` fixes back
      (``lag = round(report_lag_s · rate)``): a receiver declares a loss of fix after its own
      consistency checks fail, not at the first bad epoch.
    * **Accuracy calibration.** Each reported-type episode (a run of one reported type) draws
      ``s = exp(σ_c ξ)``: the reported accuracy is ``s`` times the type's true standard
      deviation (``σ_c`` = ``calibration_sigma``), as a receiver's hAcc is a model, not a
      measurement.

    All figures are engineering judgement (docs/gnss.md). Randomness: three Generators keyed
    ``"false_fix"``, ``"false_fix_shape"``, ``"calibration"`` from ``seed`` (the run's spare
    stream, so no other draw of the run changes).
    """

    def __init__(self, rate_hz: float, seed: SeedLike, *, per_hour: float = 3.0,
                 mean_s: float = 30.0, bias_m: Sequence[float] = (0.1, 0.4),
                 calibration_sigma: float = 0.3, report_lag_s: float = 1.0,
                 fixed: str = "rtk-fixed") -> None:
        ss = _as_seedseq(seed)
        self._rng_ff = np.random.Generator(np.random.PCG64(derive_seed(ss, "false_fix")))
        self._rng_shape = np.random.Generator(np.random.PCG64(derive_seed(ss, "false_fix_shape")))
        self._rng_cal = np.random.Generator(np.random.PCG64(derive_seed(ss, "calibration")))
        self.dt = 1.0 / rate_hz
        self.p_start = 1.0 - math.exp(-per_hour / 3600.0 * self.dt)
        self.mean_s, self.bias_m = float(mean_s), (float(bias_m[0]), float(bias_m[1]))
        self.cal_sigma = float(calibration_sigma)
        self.lag = int(round(report_lag_s * rate_hz))
        self.fixed = fixed
        self._types: deque[str | None] = deque()
        self._left = 0                       # fixes left in the current false fix
        self.bias = np.zeros(3)
        self.reported: str | None = None
        self.scale = 1.0
        self.n_false = 0                     # false-fix episodes started
        self.false_fixes = 0                 # fixes delivered inside one

    def step(self, true_type: str | None) -> tuple[np.ndarray, str | None, float]:
        """One delivered fix: (bias to add, reported type, reported accuracy scale)."""
        if true_type != self.fixed:
            self._left = 0
        elif self._left <= 0 and self._rng_ff.random() < self.p_start:
            u = self._rng_shape.standard_normal(3)
            u /= max(float(np.linalg.norm(u)), 1e-12)
            self.bias = u * self._rng_shape.uniform(*self.bias_m)
            self._left = max(1, int(round(self._rng_shape.exponential(self.mean_s) / self.dt)))
            self.n_false += 1
        in_false = self._left > 0
        if in_false:
            self._left -= 1
            self.false_fixes += 1
        self._types.append(true_type)
        rep = self._types.popleft() if len(self._types) > self.lag else self._types[0]
        if rep != self.reported:
            self.reported = rep
            self.scale = math.exp(self.cal_sigma * self._rng_cal.standard_normal())
        return (self.bias if in_false else _ZERO3), rep, self.scale


_ZERO3 = np.zeros(3)
