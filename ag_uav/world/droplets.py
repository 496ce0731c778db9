"""Droplet physics of the spray: drag and terminal velocity, the droplet classes of a volume
spectrum, evaporation by the d² law and the per-class fall tables (sources in
:mod:`ag_uav.world.deposition`)."""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from .deposition_config import DepositionConfig

G = 9.81


def drag_cd(re: float) -> float:
    """Schiller–Naumann drag coefficient of a sphere (0.44 above Re = 1000)."""
    if re <= 0.0:
        return math.inf
    return 24.0 / re * (1.0 + 0.15 * re ** 0.687) if re <= 1000.0 else 0.44


def terminal_velocity(d_m: float, rho_l: float = 1000.0, rho_a: float = 1.225,
                      mu: float = 1.81e-5) -> float:
    """Terminal velocity (m/s) of a droplet of diameter ``d_m`` from the drag balance (bisection
    on the monotone residual weight − drag)."""
    w = math.pi / 6.0 * d_m ** 3 * (rho_l - rho_a) * G
    lo, hi = 0.0, 30.0
    for _ in range(80):
        v = 0.5 * (lo + hi)
        re = rho_a * v * d_m / mu
        drag = drag_cd(re) * 0.5 * rho_a * v * v * math.pi * d_m * d_m / 4.0
        lo, hi = (v, hi) if drag < w else (lo, v)
    return 0.5 * (lo + hi)


#: the standard-normal range of ln D that the class bins split evenly (the lower tail, where the
#: drift is, gets more room); the two end bins run on to ∓∞
Z_LO, Z_HI = -3.5, 2.0


def droplet_classes(dv10_um: float, dv50_um: float, dv90_um: float,
                    k: int) -> tuple[np.ndarray, np.ndarray]:
    """``k`` classes of a split log-normal volume spectrum through Dv10/Dv50/Dv90 (ln D normal
    with its own spread on each side of Dv50, so all three are matched): (diameters in m, volume
    fractions). The bins split z = Φ⁻¹(volume share) evenly over [Z_LO, Z_HI] (end bins open),
    so the fine tail that drifts has its own classes; each class sits at its bin's volume
    median. ``k = 1``: Dv50."""
    if not 0 < dv10_um < dv50_um < dv90_um:
        raise ValueError("droplet spectrum: need 0 < Dv10 < Dv50 < Dv90")
    from scipy.special import ndtr, ndtri  # Φ and Φ⁻¹ (what scipy.stats.norm calls)

    z9 = ndtri(0.9)
    s_lo, s_hi = math.log(dv50_um / dv10_um) / z9, math.log(dv90_um / dv50_um) / z9
    if k == 1:
        return np.array([dv50_um * 1e-6]), np.ones(1)
    edges = np.concatenate([[-np.inf], np.linspace(Z_LO, Z_HI, k + 1)[1:-1], [np.inf]])
    cdf = ndtr(edges)
    frac = np.diff(cdf)
    z = ndtri(0.5 * (cdf[:-1] + cdf[1:]))
    d = dv50_um * np.exp(np.where(z < 0, s_lo, s_hi) * z) * 1e-6
    return d, frac / frac.sum()


def wet_bulb_c(t_c: float, rh_percent: float) -> float:
    """Wet-bulb temperature (°C) at sea-level pressure from the air temperature and relative
    humidity: Stull (2011, J. Appl. Meteor. Climatol. 50:2267, eq. 1; within 1 °C for 5–99 % RH
    and −20–50 °C)."""
    t, rh = t_c, rh_percent
    return (t * math.atan(0.151977 * math.sqrt(rh + 8.313659)) + math.atan(t + rh)
            - math.atan(rh - 1.676331) + 0.00391838 * rh ** 1.5 * math.atan(0.023101 * rh)
            - 4.686035)


#: d² law evaporation constant per °C of wet-bulb depression (µm²/s): λ = 84.76·ΔT (Goering et
#: al. 1972, Trans. ASAE 15(2):220, as used in AGDISP, Teske et al. 2002)
EVAP_K_UM2 = 84.76


def _vt_array(d: np.ndarray, rho_l: float, rho_a: float, mu: float) -> np.ndarray:
    """:func:`terminal_velocity` of many diameters at once (the same drag balance, vectorised
    bisection)."""
    d = np.asarray(d, float)
    w = math.pi / 6.0 * d ** 3 * (rho_l - rho_a) * G
    lo, hi = np.zeros_like(d), np.full_like(d, 30.0)
    for _ in range(60):
        v = 0.5 * (lo + hi)
        re = rho_a * v * d / mu
        with np.errstate(divide="ignore", invalid="ignore"):
            cd = np.where(re <= 1000.0, 24.0 / re * (1.0 + 0.15 * re ** 0.687), 0.44)
        drag = cd * 0.5 * rho_a * v * v * math.pi * d * d / 4.0
        low = drag < w
        lo, hi = np.where(low, v, lo), np.where(low, hi, v)
    return 0.5 * (lo + hi)


@dataclass(frozen=True)
class Air:
    """What the evaporation and the fall need of the air and the mix."""

    t_c: float = 20.0
    rh_percent: float = 60.0
    nonvolatile: float = 0.05
    rho_l: float = 1000.0
    rho_a: float = 1.225
    mu: float = 1.81e-5

    @classmethod
    def of(cls, c: DepositionConfig) -> Air:
        return cls(c.temperature_c, c.rh_percent, c.nonvolatile_fraction, c.liquid_density,
                   c.air_density, c.air_viscosity)

    @property
    def lam_m2(self) -> float:
        """λ of the d² law (m²/s) without ventilation."""
        return EVAP_K_UM2 * max(self.t_c - wet_bulb_c(self.t_c, self.rh_percent), 0.0) * 1e-12


def evaporation(d0_m: np.ndarray, t_s: np.ndarray, air: Air, ventilation: bool = True,
                substeps: int = 40) -> tuple[np.ndarray, np.ndarray]:
    """Diameters (len(d0), len(t)) and still-air fall distances of droplets falling at their
    terminal velocity while they evaporate: the d² law d(d²)/dt = −λ·(1 + 0.27·Re^½) (Williamson
    & Threadgill 1974, Trans. ASAE 17(2):254, ventilation factor; Re = ρ_a v_t d / μ), λ =
    84.76·ΔT µm²/s, ΔT the wet-bulb depression; a droplet stops shrinking at the diameter of its
    non-volatile share d₀·f^⅓. Integrated by RK4 with ``substeps`` steps between the times
    ``t_s`` (increasing, t_s[0] = 0); the fall distance by the trapezoid rule on the same steps.
    Without ventilation the law is d² = d₀² − λ t exactly (the test oracle)."""
    d0 = np.atleast_1d(np.asarray(d0_m, float))
    lam = air.lam_m2
    dmin2 = (d0 * air.nonvolatile ** (1.0 / 3.0)) ** 2
    grid = np.geomspace(0.1e-6, 3e-3, 400)
    vgrid = _vt_array(grid, air.rho_l, air.rho_a, air.mu)
    lg, lv = np.log(grid), np.log(vgrid)

    def vt(d2):
        return np.exp(np.interp(0.5 * np.log(np.maximum(d2, 1e-18)), lg, lv))

    def rate(d2):
        if not ventilation:
            return np.where(d2 > dmin2, -lam, 0.0)
        d = np.sqrt(np.maximum(d2, 1e-18))
        re = air.rho_a * vt(d2) * d / air.mu
        return np.where(d2 > dmin2, -lam * (1.0 + 0.27 * np.sqrt(re)), 0.0)

    n = len(t_s)
    dd = np.empty((len(d0), n))
    fall = np.zeros((len(d0), n))
    d2 = d0 * d0
    dd[:, 0] = d0
    for j in range(1, n):
        h = (t_s[j] - t_s[j - 1]) / substeps
        f = fall[:, j - 1].copy()
        for _ in range(substeps):
            v0 = vt(d2)
            k1 = rate(d2)
            k2 = rate(d2 + 0.5 * h * k1)
            k3 = rate(d2 + 0.5 * h * k2)
            k4 = rate(d2 + h * k3)
            d2 = np.maximum(d2 + h / 6.0 * (k1 + 2 * k2 + 2 * k3 + k4), dmin2)
            f += 0.5 * h * (v0 + vt(d2))
        dd[:, j] = np.sqrt(d2)
        fall[:, j] = f
    return dd, fall


#: the time grid of the per-class fall and evaporation tables: 0, then geometric
N_TAB = 48


def fall_tables(c: DepositionConfig, d: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Per class (rows): still-air fall distance H(t) and remaining volume share (d/d₀)³ on the
    time grid t (0 and geometric 0.02 s … ``airborne_after_s``), built once per config."""
    t = np.concatenate([[0.0], np.geomspace(0.02, c.airborne_after_s, N_TAB - 1)])
    dd, fall = evaporation(d, t, Air.of(c))
    return t, fall, (dd / d[:, None]) ** 3
