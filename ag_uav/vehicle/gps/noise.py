"""Noise components of a GPS error (the table in :mod:`ag_uav.vehicle.gps`), building them
from their config tables, and summing a sensor's components per axis."""

from __future__ import annotations

import math
from collections.abc import Iterable, Mapping
from typing import Any

import numpy as np

from ..ar1 import ar1_filter
from .checks import SeedLike, bad, check_axis_scale, check_pos, derive_seed, real, rngs


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

    @property
    def spread(self) -> float:
        """A finite measure of the spread in variance units: :attr:`variance` where it is
        finite (every component but alpha-stable, whose override says what it uses)."""
        return self.variance


class Gaussian(NoiseComponent):
    """White Gaussian noise, std ``sigma``."""

    iid = True

    def __init__(self, sigma: float, seed: SeedLike) -> None:
        self.sigma = check_pos("gaussian", "sigma", sigma, allow_zero=True)
        (self._rng,) = rngs(seed, 1)

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
        self.sigma = check_pos("student-t", "sigma", sigma, allow_zero=True)
        nu_f = check_pos("student-t", "nu", nu)
        if not nu_f > 2.0:
            raise bad("student-t", "nu", nu, "must be > 2 (finite variance)")
        self.nu = nu_f
        self._scale = self.sigma * math.sqrt((nu_f - 2.0) / nu_f)
        (self._rng,) = rngs(seed, 1)

    def sample(self, n: int, dt: float = 0.05) -> np.ndarray:
        return self._scale * self._rng.standard_t(self.nu, n)

    @property
    def variance(self) -> float:
        return self.sigma**2


class Laplace(NoiseComponent):
    """Laplace(0, b) with ``b = sigma / sqrt(2)`` (variance sigma^2)."""

    iid = True

    def __init__(self, sigma: float, seed: SeedLike) -> None:
        self.sigma = check_pos("laplace", "sigma", sigma, allow_zero=True)
        self.b = self.sigma / math.sqrt(2.0)
        (self._rng,) = rngs(seed, 1)

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
        self.sigma = check_pos("weibull", "sigma", sigma, allow_zero=True)
        self.k = check_pos("weibull", "k", k)
        self.lam = self.sigma / math.sqrt(math.gamma(1.0 + 2.0 / self.k))
        self._rng_mag, self._rng_sign = rngs(seed, 2)

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
        e = check_pos("mixture", "eps", eps, allow_zero=True)
        if e > 1.0:
            raise bad("mixture", "eps", eps, "must be in [0, 1]")
        self.eps = e
        self.sigma1 = check_pos("mixture", "sigma1", sigma1, allow_zero=True)
        self.sigma2 = check_pos("mixture", "sigma2", sigma2, allow_zero=True)
        self._rng_sel, self._rng_val = rngs(seed, 2)

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
        a = check_pos("alpha-stable", "alpha", alpha)
        if a > 2.0:
            raise bad("alpha-stable", "alpha", alpha, "must be in (0, 2]")
        b = real("alpha-stable", "beta", beta, "must be a number in [-1, 1]")
        if not -1.0 <= b <= 1.0:
            raise bad("alpha-stable", "beta", beta, "must be in [-1, 1]")
        self.alpha = a
        self.beta = b
        self.scale = check_pos("alpha-stable", "scale", scale, allow_zero=True)
        self._rng_u, self._rng_w = rngs(seed, 2)

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

    @property
    def spread(self) -> float:
        """``2 scale²``: the variance of the Gaussian with this scale's interquartile range,
        to within 10 % for alpha in [1, 2] (the IQR is 1.91 scale at alpha = 2, where the law
        is N(0, 2 scale²), and 2 scale at alpha = 1, the Cauchy law; Gaussian sigma = IQR /
        1.349), and exact at alpha = 2."""
        return 2.0 * self.scale**2


class GaussMarkov(NoiseComponent):
    """First-order Gauss-Markov bias, exact discretisation:
    ``b_{k+1} = e^{-dt/tau} b_k + sigma sqrt(1 - e^{-2 dt/tau}) xi_k``, stationary std ``sigma``,
    correlation ``e^{-dt/tau}`` per fix (Webots' GPS noise correlation is this with dt = 1 s).
    The initial bias is drawn from the stationary N(0, sigma^2)."""

    def __init__(self, sigma: float, tau_s: float, seed: SeedLike) -> None:
        self.sigma = check_pos("gauss-markov", "sigma", sigma, allow_zero=True)
        self.tau_s = check_pos("gauss-markov", "tau_s", tau_s)
        (self._rng,) = rngs(seed, 1)
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
        return ar1_filter(xi, g, rho, rho * prev)

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
            raise bad("ar1", "driver", driver, "must be an i.i.d. component "
                       f"({', '.join(sorted(_IID_TYPES))})")
        if (rho is None) == (tau_s is None):
            raise bad("ar1", "rho/tau_s", (rho, tau_s), "give exactly one of rho or tau_s")
        if rho is not None:
            r = real("ar1", "rho", rho, "must be a number in (-1, 1)")
            if not -1.0 < r < 1.0:
                raise bad("ar1", "rho", rho, "must be in (-1, 1)")
            self.rho: float | None = r
            self.tau_s: float | None = None
        else:
            self.rho = None
            self.tau_s = check_pos("ar1", "tau_s", tau_s)
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
                y = ar1_filter(xi, g, rho, rho * first)
                out = np.concatenate(([first], y))
            else:
                out = np.array([first])
        else:
            out = ar1_filter(xi, g, rho, rho * self._state)
        self._state = float(out[-1])
        return out

    @property
    def variance(self) -> float:
        return self.driver.variance

    @property
    def spread(self) -> float:
        return self.driver.spread


class MultipathSpikes(NoiseComponent):
    """Multipath spikes: with probability ``prob`` per fix, ``+/- amplitude`` (random sign);
    amplitude uniform in ``[amplitude, amplitude_max]`` when ``amplitude_max`` is given."""

    iid = True

    def __init__(
        self, prob: float, amplitude: float, seed: SeedLike, amplitude_max: float | None = None
    ) -> None:
        p = check_pos("spikes", "prob", prob, allow_zero=True)
        if p > 1.0:
            raise bad("spikes", "prob", prob, "must be in [0, 1]")
        self.prob = p
        self.amplitude = check_pos("spikes", "amplitude", amplitude, allow_zero=True)
        if amplitude_max is not None:
            amax = check_pos("spikes", "amplitude_max", amplitude_max, allow_zero=True)
            if amax < self.amplitude:
                raise bad("spikes", "amplitude_max", amplitude_max, "must be >= amplitude")
            self.amplitude_max: float | None = amax
        else:
            self.amplitude_max = None
        self._rng_hit, self._rng_sign, self._rng_amp = rngs(seed, 3)

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
        raise bad(who, "type", t, f"allowed: {', '.join(sorted(_COMPONENT_KEYS))}")
    key = t.strip().lower().replace("_", "-")
    key = {"ar(1)": "ar1", "gm": "gauss-markov", "student": "student-t", "t": "student-t",
           "stable": "alpha-stable", "white": "gaussian", "multipath": "spikes"}.get(key, key)
    if key not in _COMPONENT_KEYS:
        raise bad(who, "type", t, f"allowed: {', '.join(sorted(_COMPONENT_KEYS))}")
    return key


def make_component(
    cfg: Mapping[str, Any], seed: SeedLike, *, _driver: bool = False
) -> NoiseComponent:
    """Build one scalar component from its config table (see module docstring for keys)."""
    if not isinstance(cfg, Mapping):
        raise bad("gps component", "table", cfg, "must be a table/dict with a 'type' key")
    who = f"gps component {cfg.get('name', cfg.get('type'))!r}"
    typ = _norm_type(cfg.get("type"), who)
    required, optional = _COMPONENT_KEYS[typ]
    allowed = required | optional | (set() if _driver else _COMMON_KEYS) | {"type"}
    for k in cfg:
        if k not in allowed:
            raise bad(who, k, cfg[k], f"unknown key for type {typ!r}; allowed: "
                       f"{', '.join(sorted(allowed))}")
    for k in required:
        if k not in cfg:
            raise bad(who, k, None, f"is required for type {typ!r}")
    if _driver and typ not in _IID_TYPES:
        raise bad(who, "type", typ,
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


Built = list[tuple[str, list[NoiseComponent], tuple[float, float, float]]]


def build_components(cfgs: Any, root: np.random.SeedSequence, who: str, *key: str) -> Built:
    """(name, per-axis processes, per-axis scale) for each component table; streams keyed by
    ``(*key, name, axis)`` under ``root``."""
    if isinstance(cfgs, (str, bytes, Mapping)) or not isinstance(cfgs, Iterable):
        raise bad(who, "components", cfgs, "must be a list of component tables")
    out: Built = []
    seen: set[str] = set()
    for cfg in cfgs:
        if not isinstance(cfg, Mapping):
            raise bad(who, "components[]", cfg, "each component must be a table/dict")
        name = cfg.get("name", None)
        if name is None:
            name = _norm_type(cfg.get("type"), f"{who} component {cfg.get('type')!r}")
        if not isinstance(name, str) or not name:
            raise bad(f"{who} component", "name", name, "must be a non-empty string")
        if name in seen:
            raise bad(f"{who} component {name!r}", "name", name,
                       "must be unique within a sensor (it keys the random stream)")
        seen.add(name)
        scale = check_axis_scale(f"{who} component {name!r}", cfg.get("axis_scale", (1, 1, 1)))
        procs = [make_component(cfg, derive_seed(root, *key, name, ax)) for ax in range(3)]
        out.append((name, procs, scale))
    return out


def sum_components(comps: Built, n: int, step: float) -> np.ndarray:
    err = np.zeros((n, 3))
    for _name, procs, scale in comps:
        for ax in range(3):
            if scale[ax] != 0.0:
                err[:, ax] += scale[ax] * procs[ax].sample(n, step)
            else:
                procs[ax].sample(n, step)  # keep the stream aligned with the fix index
    return err


def comp_variance(comps: Built, spread: bool = False) -> np.ndarray:
    """Per-axis variance of the summed components (``spread``: each component's finite
    :attr:`NoiseComponent.spread` instead, where alpha-stable's variance is infinite)."""
    v = np.zeros(3)
    for _name, procs, scale in comps:
        for ax in range(3):
            if scale[ax]:
                p = procs[ax]
                v[ax] += scale[ax] ** 2 * (p.spread if spread else p.variance)
    return v
