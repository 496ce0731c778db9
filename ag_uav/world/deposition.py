"""Spray deposition: nozzles, droplets, rotor downwash, drift, and the dose on the ground.

One :class:`Deposition` per vehicle (or one :class:`DepositionBatch` for N vehicles) is stepped
once per control tick with the vehicle's true state; it returns the litres that left the nozzles
in the tick and splats them onto an application map (L/ha on a ground grid over the field and a
buffer around it). Both forms call the one compiled row function :func:`_row_step` (the
project's rule: each law written once). Pure numpy/numba; no MuJoCo. The full derivation with
figures is in ``docs/spray_deposition.md``.

**Nozzle control** (ArduPilot ``libraries/AC_Sprayer``, ``AC_Sprayer.h`` / ``.cpp``). The valve
is a state machine on the condition *want = command ∧ ground speed ≥ v_min*
(``AC_SPRAYER_DEFAULT_SPEED_MIN`` = 100 cm/s): when *want* differs from the valve state for
``nozzle_on_delay_s`` (opening, ``AC_SPRAYER_DEFAULT_TURN_ON_DELAY`` = 100 ms) or
``nozzle_off_delay_s`` (closing, ``AC_SPRAYER_DEFAULT_SHUT_OFF_DELAY`` = 1,000 ms) the valve
toggles (``update_sprayer_state``). In ArduPilot a command *off* (``AC_Sprayer::run(false)``)
stops the pump at once and the 1,000 ms applies to the speed gate only: ``cmd_off_immediate``
(default true) keeps that; false delays a command off as well. The target flow follows the
ground speed v (constant rate per area, as ``SPRAY_PUMP_RATE`` scales the pump with speed),
floored at ``flow_min_l_per_s`` (``SPRAY_PUMP_MIN``, default 0)::

    q* = max(R · w · v / 10⁴, q_min)   (L/s; R = rate L/ha, w = swath m)

and the line pressure (hence the flow) lags it as a first-order system of time constant τ
(``pressure_tau_s``; an assumption: "a few hundred milliseconds" to settle, 3τ = 0.45 s),
integrated exactly over the tick (piecewise-constant target): the volume of a tick is
∫ q dt = q*·dt + (q₀ − q*)·τ·(1 − e^{−dt/τ}).

**Droplet classes.** The volume spectrum is log-normal through the nozzle's Dv10 / Dv50 / Dv90
(ASABE S572 reports a spectrum by these; S572 classes are relative to reference nozzles, so
figures, not a category name, define it): ln D split-normal about ln Dv50 with s_lo =
ln(Dv50/Dv10)/1.2816 below and s_hi = ln(Dv90/Dv50)/1.2816 above (all three matched). The
``n_classes`` (10) bins split the normal score z evenly over [−3.5, 2] (end bins open), so the
fine tail that drifts has classes of its own (default: 41, 57, 77 µm … 516 µm; the 5.5 % of the
volume below 100 µm is carried by the classes below 105 µm); each class sits at its bin's
volume median. The default (120 / 250 / 420 µm) is a *medium* spray by the GRDC's reading of
S572.

**Terminal velocity** from the drag balance (π/6) d³ (ρ_l − ρ_a) g = C_D · ½ ρ_a v_t² · π d²/4
with Schiller & Naumann (1933, Z. Ver. Dtsch. Ing. 77:318) C_D = 24/Re · (1 + 0.15 Re^0.687) for
Re = ρ_a v_t d / μ ≤ 1000 (0.44 above), solved by bisection. Relaxation time τ_p = v_t / g.

**Evaporation** (:func:`evaporation`): the d² law d(d²)/dt = −λ (1 + 0.27 Re^½), λ = 84.76 ΔT
µm²/s (Goering et al. 1972, as in AGDISP), ΔT the wet-bulb depression from the temperature and
RH (Stull 2011, :func:`wet_bulb_c`), the ventilation factor of Williamson & Threadgill (1974); a
droplet stops at the diameter of its non-volatile share d₀ f^⅓. Per class, once per config,
:func:`fall_tables` integrates the still-air fall distance H(t) and the volume left (d/d₀)³ on
a 48-point time grid to ``airborne_after_s``; the kernels read them by interpolation.

**Downwash** (momentum theory, Leishman, *Principles of Helicopter Aerodynamics* §2.3, §2.14):
hover induced velocity v_h = sqrt(T / (2 ρ A)), A = n_rotors · π D²/4, from the *actual* total
thrust T; in forward flight at horizontal airspeed V_a (wind included; Glauert) v_i⁴ + V_a² v_i²
= v_h⁴. The wake skews back by χ, tan χ = V_a / v_i (≈ 50° at 5 m/s for the M350 class). The far
wake reaches 2 v_i and then decays as a round turbulent jet along its skewed axis: u = 2 v_i for
axial distance s < s₀ and 2 v_i s₀ / s beyond, s₀ = B · D/√2 (B ≈ 6, Abdel-Rahman et al., Mech.
Res. Commun. 23(3):313, 1996). At depth z below the rotor the axial distance is z / cos χ, so the
wake's vertical speed is a = 2 v_i c for z < z₀ = s₀ cos χ and a z₀ / z beyond (c = R₂₂: the
wake blows along −ẑ_body): a skewed wake decays within a shorter depth.

**The wake part** of a class falls from the nozzle depth s_n to the ground depth s_g at
ds/dt = v_t + u(s), in closed form::

    t(s₁→s₂) = (s₂ − s₁) / (v_t + a)                                  (s < z₀)
    t(s₁→s₂) = [(s₂ − s₁) − (a z₀ / v_t) ln((v_t s₂ + a z₀) / (v_t s₁ + a z₀))] / v_t   (s ≥ z₀)

lands about x = x_nozzle + W t_f + (ẑ-tilt) D_w / c + (v − W) τ_p (1 − e^{−t_f/τ_p}) (D_w =
(s_g − s_n) − v_t t_f the wake's share of the fall, W the wind at the vehicle) with the variance
σ² = σ₀² + (i_w D_w)² + (δ u_g / v_t)² + (σ_a t_f)² (σ₀ the nozzle sheet, i_w ≈ 0.25 the jet's
turbulence intensity, δ u_g / v_t the ground outwash of speed u_g in a layer δ, σ_a ambient
turbulence not in the per-tick wind samples). δ = 0.17 m is calibrated (docs: DJI's 11 m T40
swath).

**The escaped part.** At the wake's edge the shear layer's eddies (velocity σ_s = i_w 2 v_i,
size ℓ = ``shear_eddy_m``) carry droplets out as the wake skews; a droplet follows them by the
response 1 / (1 + St), St = τ_p σ_s / ℓ (Stokes number). The escaped share of class k is ε =
ε₀ sin χ / (1 + St) (ε₀ = ``wake_escape``, an assumed constant: 0 in hover, most for the fines).
It then settles from the nozzle height h through the surface layer: a log-law wind
u(z) = (u*/κ) ln(z/z₀) (u* from the wind at the vehicle's height, z₀ = ``roughness_m``) whose
mean over the layer below h advects it, and a vertical eddy diffusivity K = κ u* h/2; the first
passage of a settling droplet through a diffusing layer is the inverse Gaussian IG(μ_T, λ_T)
(Chhikara & Folks 1989), μ_T the still-air fall time from the table (evaporating), λ_T = h²/(2K).
The landing distance is ū·T along the wind; across it the spread is σ_v T (σ_v = 1.9 u*,
Panofsky & Dutton 1984; Taylor's short-time limit), plus the wake's edge ring. What has not
landed after ``airborne_after_s`` (P(T > T_max)) is **airborne**; the volume lost on the way
is **evaporated** (at the mean fall time). In the dose grid the escaped part is splatted as the
Gaussian of the same mean and variance; the drift trial (:mod:`ag_uav.jobs.experiments.drift`)
evaluates the inverse-Gaussian law itself, so the far field has no cut-off.

**Windows and splatting.** A tick adds its litres, the litre-weighted input row and each
nozzle's release moments (volume, first and second moments) to a window of at most
``flush_cells`` cells of travel (or ``flush_ticks`` ticks). At the window's end
(:func:`_flush`) the landing law above is evaluated once, at the window's mean input row, for
every class; each (nozzle, class, wake / escaped) part is one axis-aligned Gaussian: the release
moments convolved with the class's kernel (mean and variance exact, the along-track smear
included). Parts whose kernel is wider than ``merge_ratio`` × the nozzle radius merge their
nozzles and gather over several windows (:func:`_flush_wide`) until their release points'
variance reaches WIDE_SPREAD of the kernel's, then are splatted (always at the end and when the
vehicle crosses the grid's edge). Cell weights are exact cell integrals (erf differences),
truncated at ±4σ and rescaled so that the grid receives exactly the analytic in-grid
probability; wide kernels go to coarser levels (cells 2^l larger, at most ~17×17
cells touched), summed into the fine map on read. Mass bookkeeping is exact by
construction: sprayed = in grid + deposited outside the grid + drift + airborne + evaporated,
where the part landing outside the grid counts as **drift** (carried past the buffer) if it was
released over the grid and as **deposited outside** otherwise.

**Memory.** Dense float64 levels over the field's bounding box plus the buffer (≈ 1.33 × the
fine cells); a grid above ``max_cells`` fine cells coarsens the cell (doubling) until it fits,
and says so (:attr:`Deposition.cell_m`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from .._jit import HAVE_NUMBA, njit

if HAVE_NUMBA:
    from numba.core.errors import TypingError as NumbaTypingError
else:  # pragma: no cover
    NumbaTypingError = TypeError

__all__ = ["DepositionConfig", "Deposition", "DepositionBatch", "DoseMap", "droplet_classes",
           "terminal_velocity", "dose_metrics", "INPUT_WIDTH", "GridSpec", "pack_input",
           "pack_params", "footprints", "evaporation", "wet_bulb_c", "Air", "fall_tables"]

G = 9.81
#: columns of one input row: pos 3, vel 3, R 9 (row-major), thrust, wind 3, cmd
INPUT_WIDTH = 20
_M350_NOZZLES = ((0.3164, -0.3164, -0.15), (0.3164, 0.3164, -0.15),
                 (-0.3164, 0.3164, -0.15), (-0.3164, -0.3164, -0.15))


#: (key, low, high) of the air and tank-mix keys (Stull's wet-bulb fit holds for −20–50 °C and
#: 5–99 % RH)
_LIMITS = (("temperature_c", -20.0, 50.0), ("rh_percent", 5.0, 99.0),
           ("nonvolatile_fraction", 1e-4, 1.0), ("roughness_m", 1e-4, 2.0),
           ("wake_escape", 0.0, 1.0), ("shear_eddy_m", 1e-3, 10.0),
           ("airborne_after_s", 1.0, 1e5), ("n_classes", 1, 40))


@dataclass(frozen=True)
class DepositionConfig:
    """Deposition parameters (defaults: the M350-class quad of ``models/quad.xml``, one nozzle
    under each rotor). Sources in the module docstring."""

    rate_l_per_ha: float = 1.0
    swath_m: float = 6.0
    nozzle_xyz_m: tuple = _M350_NOZZLES           # body frame (m), about the body origin
    nozzle_share: tuple = (0.25, 0.25, 0.25, 0.25)
    dv10_um: float = 120.0
    dv50_um: float = 250.0
    dv90_um: float = 420.0
    n_classes: int = 10                           # tail-weighted classes (droplet_classes)
    nozzle_on_delay_s: float = 0.1                # AC_SPRAYER_DEFAULT_TURN_ON_DELAY
    nozzle_off_delay_s: float = 1.0               # AC_SPRAYER_DEFAULT_SHUT_OFF_DELAY
    cmd_off_immediate: bool = True                # AC_Sprayer::run(false) stops at once
    speed_min_mps: float = 1.0                    # AC_SPRAYER_DEFAULT_SPEED_MIN
    flow_min_l_per_s: float = 0.0                 # AC_SPRAYER_DEFAULT_PUMP_MIN = 0 %
    pressure_tau_s: float = 0.15
    rotor_diameter_m: float = 0.533
    n_rotors: int = 4
    rotor_z_m: float = 0.08                       # rotor plane above the body origin
    air_density: float = 1.225
    air_viscosity: float = 1.81e-5
    liquid_density: float = 1000.0
    jet_decay_b: float = 6.0
    wake_turbulence: float = 0.25
    outwash_layer_m: float = 0.17
    release_sigma_m: float = 0.1
    ambient_sigma_mps: float = 0.0
    temperature_c: float = 20.0                   # air temperature (°C)
    rh_percent: float = 60.0                      # relative humidity (%)
    nonvolatile_fraction: float = 0.05            # volume share of the mix that never evaporates
    roughness_m: float = 0.05                     # z0 of the log-law wind profile (m)
    wake_escape: float = 0.3                      # ε₀: share of the sheet at the wake's edge
    shear_eddy_m: float = 0.05                    # eddy length of the wake's shear layer (m)
    airborne_after_s: float = 600.0               # still aloft after this: counted airborne
    cell_m: float = 0.5
    buffer_m: float = 10.0
    max_cells: int = 4_000_000
    flush_cells: float = 2.0
    flush_ticks: int = 50
    levels: int = 6
    merge_ratio: float = 2.0
    extra: dict = field(default_factory=dict)

    def __post_init__(self) -> None:
        for key, lo, hi in _LIMITS:
            v = getattr(self, key)
            if not lo <= v <= hi:
                raise ValueError(f"{key} = {v}: must be within [{lo:g}, {hi:g}]")

    @classmethod
    def from_config(cls, cfg: Any, **over: Any) -> DepositionConfig:
        """From the product's :class:`ag_uav.config.Config`: rate, swath, rotor diameter, air and
        liquid density; any ``[spray]`` key that names a field here overrides it."""
        kw: dict[str, Any] = {
            "rate_l_per_ha": cfg.spray.rate_l_per_ha, "swath_m": cfg.mission.swath_m,
            "rotor_diameter_m": cfg.battery.rotor_diameter_m,
            "air_density": cfg.battery.air_density_kgm3,
            "liquid_density": 1000.0 * cfg.spray.density_kg_per_l}
        names = set(cls.__dataclass_fields__)
        for k, v in vars(cfg.spray).items():
            if k in names and k not in kw:
                kw[k] = tuple(v) if isinstance(v, list) else v
        xyz = kw.get("nozzle_xyz_m")
        if xyz is not None and xyz and not isinstance(xyz[0], tuple | list):  # flat x, y, z, ..
            kw["nozzle_xyz_m"] = tuple(tuple(xyz[i:i + 3]) for i in range(0, len(xyz), 3))
        if kw.get("nozzle_share") == ():  # [] in the config: equal shares
            m = len(kw.get("nozzle_xyz_m", _M350_NOZZLES))
            kw["nozzle_share"] = tuple([1.0 / m] * m)
        kw.update(over)
        return cls(**kw)


# ------------------------------------------------------------------------------ droplets
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
    from scipy.stats import norm

    z9 = norm.ppf(0.9)
    s_lo, s_hi = math.log(dv50_um / dv10_um) / z9, math.log(dv90_um / dv50_um) / z9
    if k == 1:
        return np.array([dv50_um * 1e-6]), np.ones(1)
    edges = np.concatenate([[-np.inf], np.linspace(Z_LO, Z_HI, k + 1)[1:-1], [np.inf]])
    cdf = norm.cdf(edges)
    frac = np.diff(cdf)
    z = norm.ppf(0.5 * (cdf[:-1] + cdf[1:]))
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


# ------------------------------------------------------------------------------ packed params
# header slots of the parameter vector (float64); arrays follow at the offsets stored in it
(P_RATE, P_SWATH, P_VMIN, P_DON, P_DOFF, P_OFFNOW, P_TAU, P_RHOA, P_AREA, P_S0, P_ROTZ, P_IW,
 P_DELTA, P_SIGA, P_SIG0, P_X0, P_Y0, P_CELL, P_NX, P_NY, P_NLEV, P_FLUSHD, P_FLUSHT, P_M, P_K,
 P_MERGE, P_O_NOZ, P_O_SHARE, P_O_VT, P_O_TAUP, P_O_FRAC, P_O_LEV, P_NOZC, P_QMIN, P_ESC,
 P_ELL, P_Z0, P_TMAX, P_O_TT, P_O_H, P_O_R, P_EDGE) = range(42)
P_HEADER = 48
# state slots per row; the window's accumulators follow at S_ACC: the litres, the litre-weighted
# sum of the input row (INPUT_WIDTH), then per nozzle (NACC: V, Sx, Sy, Sxx, Syy)
(S_ON, S_INC, S_Q, S_TRAVEL, S_TICKS, S_INSIDE, S_LX, S_LY, S_SPRAYED, S_INGRID, S_OUTSIDE,
 S_DRIFT, S_PENDING, S_LITRES_TICK, S_AIR, S_EVAP) = range(16)
S_ACC = 16
NACC = 5
#: per (class, wake/escaped) a wide part's gathered moments: V, Sx, Sy, Sxx, Syy, V·σx², V·σy²
NSLOW = 7
#: a wide part is splatted once its release points' variance reaches this share of its kernel's
WIDE_SPREAD = 0.25
#: von Kármán's constant; σ_v / u* of the neutral surface layer (Panofsky & Dutton 1984,
#: *Atmospheric Turbulence*, §7: σ_u, σ_v, σ_w ≈ 2.4, 1.9, 1.25 u*)
KAPPA = 0.41
SIGV_USTAR = 1.9
#: slots of the per-tick environment (:func:`_environment`) and of one class's footprint
#: (:func:`_class_footprint`)
NENV = 16
(F_WAKE, F_WX, F_WY, F_WVAR, F_WLAND, F_ESC, F_EX, F_EY, F_EVX, F_EVY, F_MUT, F_LAMT, F_PAIR,
 F_RLAND, F_RAIR, F_UX, F_UY) = range(17)
NFOOT = 17


@njit(cache=True)
def _fall_time(vt: float, a: float, s0: float, s1: float, s2: float) -> float:
    """Time to fall from depth s1 to s2 at ds/dt = vt + u(s), u = a (s < s0), a·s0/s (s ≥ s0)."""
    t = 0.0
    if s1 < s0:
        e = min(s2, s0)
        t += (e - s1) / (vt + a)
        s1 = e
    if s2 > s1:
        c = a * s0
        t += ((s2 - s1) - c / vt * math.log1p(vt * (s2 - s1) / (vt * s1 + c))) / vt
    return t


@njit(cache=True)
def _cell_weights(lo, c, m, r, i0, i1, w) -> float:
    """Cells ``i0..i1`` (of size ``c`` from ``lo``) of a 1-D Gaussian of mean ``m`` and
    ``r = 1/(√2 σ)``: twice each cell's share into ``w`` (erf differences); their sum."""
    e0 = math.erf((lo + i0 * c - m) * r)
    tot = 0.0
    for i in range(i0, i1 + 1):
        e1 = math.erf((lo + (i + 1) * c - m) * r)
        w[i - i0] = e1 - e0
        tot += e1 - e0
        e0 = e1
    return tot


@njit(cache=True)
def _splat(par, buf, vol, mx, my, vx, vy, scratch) -> float:
    """Add ``vol`` litres as an axis-aligned Gaussian (mean mx, my; variances vx, vy) to the
    level buffers; returns the litres put on the grid (exactly the analytic in-grid share)."""
    x0, y0, cell = par[P_X0], par[P_Y0], par[P_CELL]
    nx, ny, nlev = int(par[P_NX]), int(par[P_NY]), int(par[P_NLEV])
    sx, sy = math.sqrt(vx), math.sqrt(vy)
    s = max(sx, sy)
    lev = 0
    while lev < nlev - 1 and s > 2.0 * cell * (1 << lev):
        lev += 1
    c = cell * (1 << lev)
    nxl, nyl = nx >> lev, ny >> lev
    rx, ry = 1.0 / (math.sqrt(2.0) * sx), 1.0 / (math.sqrt(2.0) * sy)
    px = 0.5 * (math.erf((x0 + nx * cell - mx) * rx) - math.erf((x0 - mx) * rx))
    py = 0.5 * (math.erf((y0 + ny * cell - my) * ry) - math.erf((y0 - my) * ry))
    if px * py <= 0.0:
        return 0.0
    i0 = max(0, int(math.floor((mx - 4.0 * sx - x0) / c)))
    i1 = min(nxl - 1, int(math.floor((mx + 4.0 * sx - x0) / c)))
    j0 = max(0, int(math.floor((my - 4.0 * sy - y0) / c)))
    j1 = min(nyl - 1, int(math.floor((my + 4.0 * sy - y0) / c)))
    if i1 < i0 or j1 < j0 or i1 - i0 >= scratch.shape[1] or j1 - j0 >= scratch.shape[1]:
        return 0.0
    wx, wy = scratch[0], scratch[1]
    tx = _cell_weights(x0, c, mx, rx, i0, i1, wx)
    ty = _cell_weights(y0, c, my, ry, j0, j1, wy)
    if tx * ty <= 0.0:
        return 0.0
    put = vol * px * py
    scale = put / (tx * ty)
    base0 = int(par[int(par[P_O_LEV]) + lev])
    for j in range(j0, j1 + 1):
        wj = wy[j - j0] * scale
        base = base0 + j * nxl
        for i in range(i0, i1 + 1):
            buf[base + i] += wj * wx[i - i0]
    return put


@njit(cache=True)
def _splat_part(par, st, buf, scratch, vol, mx, my, vx, vy, drift) -> None:
    """Splat one Gaussian and book what misses the grid (drift or deposited outside)."""
    if vol <= 0.0:
        return
    put = _splat(par, buf, vol, mx, my, vx, vy, scratch)
    st[S_INGRID] += put
    if drift:
        st[S_DRIFT] += vol - put
    else:
        st[S_OUTSIDE] += vol - put


@njit(cache=True)
def _flush(par, st, buf, scratch, force: float) -> None:
    """The window's landing law, once: every class's footprint (:func:`_class_footprint`) at
    the window's litre-weighted mean input row, convolved with each nozzle's release moments
    (the along-track smear exactly); the wake and the escaped part of each (nozzle, class)
    splatted (nozzles merged where the class's kernel is wider than ``merge_ratio`` × the
    nozzle radius); airborne and evaporated volume booked."""
    m_n, k_n = int(par[P_M]), int(par[P_K])
    o_fr = int(par[P_O_FRAC])
    merge_r = par[P_MERGE] * par[P_NOZC]
    drift = st[S_INSIDE] > 0.5
    vtot = st[S_ACC]
    if vtot > 0.0:
        row = scratch[2]
        for j in range(INPUT_WIDTH):
            row[j] = st[S_ACC + 1 + j] / vtot
        env = _environment(par, row)
        o = S_ACC + 1 + INPUT_WIDTH
        V = Sx = Sy = Sxx = Syy = 0.0
        for m in range(m_n):
            a = o + m * NACC
            V += st[a]
            Sx += st[a + 1]
            Sy += st[a + 2]
            Sxx += st[a + 3]
            Syy += st[a + 4]
        for k in range(k_n):
            f = _class_footprint(par, k, env)
            vk = par[o_fr + k]
            vw, ve = vk * f[F_WAKE], vk * f[F_ESC]
            land_e = ve * (1.0 - f[F_PAIR]) * f[F_RLAND]
            air = ve * f[F_PAIR] * f[F_RAIR]
            st[S_AIR] += vtot * air
            st[S_EVAP] += vtot * (vw * (1.0 - f[F_WLAND]) + (ve - land_e - air))
            for part in range(2):
                share = vw * f[F_WLAND] if part == 0 else land_e
                if share <= 0.0:
                    continue
                ox = f[F_WX] if part == 0 else f[F_EX]
                oy = f[F_WY] if part == 0 else f[F_EY]
                kvx = f[F_WVAR] if part == 0 else f[F_EVX]
                kvy = f[F_WVAR] if part == 0 else f[F_EVY]
                if math.sqrt(0.5 * (kvx + kvy)) >= merge_r:
                    q = o + m_n * NACC + (2 * k + part) * NSLOW
                    w = share * V
                    st[q] += w
                    st[q + 1] += share * (Sx + ox * V)
                    st[q + 2] += share * (Sy + oy * V)
                    st[q + 3] += share * (Sxx + 2.0 * ox * Sx + ox * ox * V)
                    st[q + 4] += share * (Syy + 2.0 * oy * Sy + oy * oy * V)
                    st[q + 5] += w * kvx
                    st[q + 6] += w * kvy
                    continue
                for m in range(m_n):
                    a = o + m * NACC
                    v = st[a]
                    if v <= 0.0:
                        continue
                    mx, my = st[a + 1] / v, st[a + 2] / v
                    _splat_part(par, st, buf, scratch, share * v, mx + ox, my + oy,
                                max(st[a + 3] / v - mx * mx, 0.0) + kvx,
                                max(st[a + 4] / v - my * my, 0.0) + kvy, drift)
        for j in range(S_ACC, o + m_n * NACC):
            st[j] = 0.0
    _flush_wide(par, st, buf, scratch, force)
    st[S_PENDING] = 0.0
    st[S_TRAVEL] = 0.0
    st[S_TICKS] = 0.0


@njit(cache=True)
def _flush_wide(par, st, buf, scratch, force: float) -> None:
    """The wide parts (nozzles merged) gather over several windows: each is splatted once the
    spread of its release points reaches a quarter of its kernel's variance (so the smear
    changes its shape by little; mean and variance are matched exactly), or when ``force`` > 0
    (the end, the vehicle crossing the grid's edge)."""
    m_n, k_n = int(par[P_M]), int(par[P_K])
    drift = st[S_INSIDE] > 0.5
    base = S_ACC + 1 + INPUT_WIDTH + m_n * NACC
    for i in range(2 * k_n):
        q = base + i * NSLOW
        w = st[q]
        if w <= 0.0:
            continue
        mx, my = st[q + 1] / w, st[q + 2] / w
        px = max(st[q + 3] / w - mx * mx, 0.0)
        py = max(st[q + 4] / w - my * my, 0.0)
        kx, ky = st[q + 5] / w, st[q + 6] / w
        if force > 0.0 or px + py >= WIDE_SPREAD * (kx + ky):
            _splat_part(par, st, buf, scratch, w, mx, my, px + kx, py + ky, drift)
            for j in range(NSLOW):
                st[q + j] = 0.0


@njit(cache=True)
def _valve(par, st, dt: float, cmd: bool, speed: float) -> None:
    """ArduPilot AC_Sprayer's state machine on want = cmd ∧ speed ≥ v_min (module docstring)."""
    on = st[S_ON] > 0.5
    want = cmd and speed >= par[P_VMIN]
    if on and not cmd and par[P_OFFNOW] > 0.5:
        st[S_ON] = 0.0
        st[S_INC] = -1.0
        return
    if want == on:
        st[S_INC] = -1.0
        return
    st[S_INC] = 0.0 if st[S_INC] < 0.0 else st[S_INC] + dt
    delay = par[P_DOFF] if on else par[P_DON]
    if st[S_INC] >= delay - 1e-9:
        st[S_ON] = 0.0 if on else 1.0
        st[S_INC] = -1.0


@njit(cache=True)
def _flow(par, st, dt: float, speed: float) -> float:
    """Litres out this tick: the first-order pressure lag toward q* = max(R·w·v/10⁴, q_min),
    exactly."""
    qs = max(par[P_RATE] * par[P_SWATH] * speed * 1e-4, par[P_QMIN]) if st[S_ON] > 0.5 else 0.0
    q0, tau = st[S_Q], par[P_TAU]
    if tau <= 0.0:
        st[S_Q] = qs
        return qs * dt
    e = math.exp(-dt / tau)
    st[S_Q] = qs + (q0 - qs) * e
    return qs * dt + (q0 - qs) * tau * (1.0 - e)


@njit(cache=True)
def _ig_cdf(t: float, mu: float, lam: float) -> float:
    """CDF of the inverse Gaussian IG(μ, λ) (first-passage time of a drifting Brownian motion;
    Chhikara & Folks 1989, eq. 2.3), its second term in log space (no overflow of e^{2λ/μ})."""
    if t <= 0.0:
        return 0.0
    r = math.sqrt(lam / t)
    c1 = 0.5 * math.erfc(-r * (t / mu - 1.0) / math.sqrt(2.0))
    x = r * (t / mu + 1.0) / math.sqrt(2.0)
    if x < 5.0:
        c2 = math.exp(2.0 * lam / mu) * 0.5 * math.erfc(x)
    else:  # erfc(x) ~ e^{-x²}/(x√π)(1 − 1/(2x²) + 3/(4x⁴)); exponent combined: −λ(t−μ)²/(2tμ²)
        e = -lam * (t - mu) ** 2 / (2.0 * t * mu * mu)
        c2 = 0.5 * math.exp(e) / (x * math.sqrt(math.pi)) * (1.0 - 0.5 / x ** 2 + 0.75 / x ** 4)
    return min(max(c1 + c2, 0.0), 1.0)


@njit(cache=True)
def _tab_time(par, k: int, h: float) -> float:
    """Still-air fall time (s) of class ``k`` through ``h`` metres, evaporating (the table of
    :func:`fall_tables`, linear between its points, the last speed beyond it)."""
    n, o_t = N_TAB, int(par[P_O_TT])
    o = int(par[P_O_H]) + k * n
    if h <= 0.0:
        return 0.0
    if h >= par[o + n - 1]:
        v = (par[o + n - 1] - par[o + n - 2]) / (par[o_t + n - 1] - par[o_t + n - 2])
        return par[o_t + n - 1] + (h - par[o + n - 1]) / max(v, 1e-12)
    lo, hi = 0, n - 1
    while hi - lo > 1:
        mid = (lo + hi) >> 1
        if par[o + mid] <= h:
            lo = mid
        else:
            hi = mid
    f = (h - par[o + lo]) / max(par[o + hi] - par[o + lo], 1e-300)
    return par[o_t + lo] + f * (par[o_t + hi] - par[o_t + lo])


@njit(cache=True)
def _tab_left(par, k: int, t: float) -> float:
    """Share of class ``k``'s volume left after ``t`` s of evaporation (table, linear)."""
    n, o_t = N_TAB, int(par[P_O_TT])
    o = int(par[P_O_R]) + k * n
    if t >= par[o_t + n - 1]:
        return par[o + n - 1]
    if t <= 0.0:
        return 1.0
    lo, hi = 0, n - 1
    while hi - lo > 1:
        mid = (lo + hi) >> 1
        if par[o_t + mid] <= t:
            lo = mid
        else:
            hi = mid
    f = (t - par[o_t + lo]) / (par[o_t + hi] - par[o_t + lo])
    return par[o + lo] + f * (par[o + hi] - par[o + lo])


@njit(cache=True)
def _environment(par, inp):
    """What every class of one tick shares: nozzle and ground depths below the rotor plane, the
    wake (speed a, skew, decay depth), the wind and the surface layer. Laws in the module
    docstring. Returns (s_n, s_g, a, z0w, tx, ty, wx, wy, vx, vy, u_g, sin χ, u*, h_n, f_u,
    σ_s)."""
    m_n = int(par[P_M])
    o_noz, o_share = int(par[P_O_NOZ]), int(par[P_O_SHARE])
    pz, vx, vy = inp[2], inp[3], inp[4]
    r = inp[6:15]
    thrust, wx, wy = inp[15], inp[16], inp[17]
    cz = r[8] if r[8] > 0.3 else 0.3                 # cosine of the tilt; wake along -z_body
    tx, ty = -r[2] / cz, -r[5] / cz                  # horizontal wake drift per metre of fall
    zr = pz + r[8] * par[P_ROTZ]
    zn = 0.0
    for m in range(m_n):
        b = o_noz + 3 * m
        zn += par[o_share + m] * (pz + r[6] * par[b] + r[7] * par[b + 1] + r[8] * par[b + 2])
    zn = max(zn, 0.0)
    s_n, s_g = max(zr - zn, 0.0), max(zr, 0.0)
    # momentum theory (Glauert in forward flight) and the wake skew tan χ = V_a / v_i
    vh2 = max(thrust, 0.0) / (2.0 * par[P_RHOA] * par[P_AREA])
    va2 = (vx - wx) ** 2 + (vy - wy) ** 2
    vi = math.sqrt(0.5 * (-va2 + math.sqrt(va2 * va2 + 4.0 * vh2 * vh2)))
    hyp = math.sqrt(va2 + vi * vi)
    cos_chi = vi / hyp if hyp > 0.0 else 1.0
    sin_chi = math.sqrt(va2) / hyp if hyp > 0.0 else 0.0
    a = 2.0 * vi * cz
    z0w = par[P_S0] * cos_chi                        # the jet's core ends s₀ along the skewed axis
    u_g = a if s_g < z0w else a * z0w / max(s_g, 1e-9)
    # log-law surface layer: u* from the wind at the vehicle's height
    z0 = par[P_Z0]
    w = math.sqrt(wx * wx + wy * wy)
    ust, fu = 0.0, 0.0
    if pz > 1.01 * z0:
        lnv = math.log(pz / z0)
        ust = KAPPA * w / lnv
        if zn > z0:                                  # mean of u(z) over the layer below the nozzle
            fu = (zn * math.log(zn / z0) - zn + z0) / ((zn - z0) * lnv)
    return (s_n, s_g, a, z0w, tx, ty, wx, wy, vx, vy, u_g, sin_chi, ust, zn, fu,
            par[P_IW] * 2.0 * vi)


@njit(cache=True)
def _class_footprint(par, k: int, env):
    """Class ``k``'s landing law at one tick (offsets from the nozzle; laws in the module
    docstring): the wake part (share, mean, variance, volume left on landing) and the escaped
    part (share, mean, axis variances, fall-time law IG(μ_T, λ_T), airborne share, volume left
    on landing and when counted airborne, mean wind). Slots F_*."""
    (s_n, s_g, a, z0w, tx, ty, wx, wy, vx, vy, u_g, sin_chi, ust, h_n, fu, sig_s) = env
    vt, tp = par[int(par[P_O_VT]) + k], par[int(par[P_O_TAUP]) + k]
    sig0 = par[P_SIG0]
    # wake: carried down the decaying skewed jet
    tf = _fall_time(vt, a, z0w, s_n, s_g) if s_g > s_n else 0.0
    dw = max((s_g - s_n) - vt * tf, 0.0)
    relax = tp * (1.0 - math.exp(-tf / tp))
    wxo = wx * tf + tx * dw + (vx - wx) * relax
    wyo = wy * tf + ty * dw + (vy - wy) * relax
    wvar = (sig0 * sig0 + (par[P_IW] * dw) ** 2 + (par[P_DELTA] * u_g / vt) ** 2
            + (par[P_SIGA] * tf) ** 2)
    wland = _tab_left(par, k, tf)
    # escape at the wake's edge: ε₀ sin χ, damped by the droplet's response 1/(1 + St)
    st_k = tp * sig_s / par[P_ELL]
    esc = par[P_ESC] * sin_chi / (1.0 + st_k)
    # escaped: settles from the nozzle height through the surface layer (first passage)
    mu_t = _tab_time(par, k, h_n)
    kz = KAPPA * ust * 0.5 * h_n
    lam_t = h_n * h_n / (2.0 * kz) if kz > 1e-12 else 1e30
    tmax = par[P_TMAX]
    pair = 1.0 - _ig_cdf(tmax, mu_t, lam_t) if mu_t > 0.0 else 0.0
    ux, uy = fu * wx, fu * wy
    erel = tp * (1.0 - math.exp(-mu_t / tp)) if mu_t > 0.0 else 0.0
    exo = (vx - wx) * erel + ux * mu_t
    eyo = (vy - wy) * erel + uy * mu_t
    u2 = ux * ux + uy * uy
    val = u2 * mu_t ** 3 / lam_t                     # along the wind: X = ū·T, T ~ IG
    vlat = (SIGV_USTAR * ust * mu_t) ** 2            # across it: σ_v·t (Taylor, short times)
    s0e = sig0 * sig0 + 0.5 * par[P_EDGE] ** 2        # leaves from the wake's edge (a ring)
    if u2 > 0.0:
        ex2 = ux * ux / u2
        evx = s0e + val * ex2 + vlat * (1.0 - ex2)
        evy = s0e + val * (1.0 - ex2) + vlat * ex2
    else:
        evx = evy = s0e + vlat
    rland = _tab_left(par, k, mu_t)
    rair = _tab_left(par, k, tmax)
    return (1.0 - esc, wxo, wyo, wvar, wland, esc, exo, eyo, evx, evy, mu_t, lam_t, pair,
            rland, rair, ux, uy)


@njit(cache=True)
def _footprints(par, inp, out) -> None:
    """Every class's :func:`_class_footprint` at the tick ``inp`` into ``out`` (K, NFOOT): what
    the drift trial evaluates analytically."""
    env = _environment(par, inp)
    for k in range(int(par[P_K])):
        f = _class_footprint(par, k, env)
        for j in range(NFOOT):
            out[k, j] = f[j]


@njit(cache=True)
def _release(par, st, inp, litres: float) -> None:
    """This tick's litres into the window: the litre-weighted input row and each nozzle's
    release moments (the landing law is applied once per window, in :func:`_flush`)."""
    m_n = int(par[P_M])
    o_noz, o_share = int(par[P_O_NOZ]), int(par[P_O_SHARE])
    px, py = inp[0], inp[1]
    st[S_ACC] += litres
    for j in range(INPUT_WIDTH):
        st[S_ACC + 1 + j] += litres * inp[j]
    o = S_ACC + 1 + INPUT_WIDTH
    for m in range(m_n):
        b = o_noz + 3 * m
        x = px + inp[6] * par[b] + inp[7] * par[b + 1] + inp[8] * par[b + 2]
        y = py + inp[9] * par[b] + inp[10] * par[b + 1] + inp[11] * par[b + 2]
        v = litres * par[o_share + m]
        a = o + m * NACC
        st[a] += v
        st[a + 1] += v * x
        st[a + 2] += v * y
        st[a + 3] += v * x * x
        st[a + 4] += v * y * y


@njit(cache=True)
def _row_step(par, inp, st, buf, dt: float, scratch) -> float:
    """One vehicle, one control tick: valve, flow, release, and a flush when the window is full
    or the vehicle crosses the grid's edge. Returns the litres sprayed in the tick."""
    vx, vy = inp[3], inp[4]
    speed = math.sqrt(vx * vx + vy * vy)
    _valve(par, st, dt, inp[19] > 0.5, speed)
    litres = _flow(par, st, dt, speed)
    st[S_LITRES_TICK] = litres
    x0, y0, cell = par[P_X0], par[P_Y0], par[P_CELL]
    inside = (inp[0] >= x0 and inp[0] <= x0 + par[P_NX] * cell
              and inp[1] >= y0 and inp[1] <= y0 + par[P_NY] * cell)
    flag = 1.0 if inside else 0.0
    if flag != st[S_INSIDE] and st[S_INSIDE] >= 0.0:
        _flush(par, st, buf, scratch, 1.0)       # what was released inside stays inside
    st[S_INSIDE] = flag
    if litres > 0.0:
        st[S_SPRAYED] += litres
        _release(par, st, inp, litres)
        st[S_PENDING] += litres
        if st[S_TICKS] > 0.0:
            st[S_TRAVEL] += math.hypot(inp[0] - st[S_LX], inp[1] - st[S_LY])
        st[S_TICKS] += 1.0
        st[S_LX], st[S_LY] = inp[0], inp[1]
        if st[S_TRAVEL] >= par[P_FLUSHD] or st[S_TICKS] >= par[P_FLUSHT]:
            _flush(par, st, buf, scratch, 0.0)
    elif st[S_PENDING] > 0.0:
        _flush(par, st, buf, scratch, 0.0)
    return litres


@njit(cache=True)
def _batch_step(par, inp, st, buf, dt: float, out, scratch) -> None:
    """N vehicles: the row function on every row (bit-identical to N single calls)."""
    for n in range(inp.shape[0]):
        out[n] = _row_step(par, inp[n], st[n], buf[n], dt, scratch)


@njit(cache=True)
def _engine_step(par, st, buf, inp, out, scratch, dt, rows, p, v, R, S, ia, na, w, cmd,
                 act) -> None:
    """The engine's rows: row j of this batch is vehicle ``rows[j]`` of the engine's arrays
    (pos p, velocity v, R row-major, wind w, nozzle command cmd; the total thrust is the sum of
    the ``na`` actuator states at column ``ia`` of the physics state S). Inactive vehicles are
    not stepped (as alone, where the flight has ended)."""
    for j in range(rows.shape[0]):
        i = rows[j]
        out[j] = 0.0
        if not act[i]:
            continue
        r = inp[j]
        for c in range(3):
            r[c] = p[i, c]
            r[3 + c] = v[i, c]
            r[16 + c] = w[i, c]
        for c in range(9):
            r[6 + c] = R[i, c]
        th = 0.0
        for c in range(na):
            th += S[i, ia + c]
        r[15] = th
        r[19] = 1.0 if cmd[i] else 0.0
        out[j] = _row_step(par, r, st[j], buf[j], dt, scratch)


@njit(cache=True)
def _levels_sum(buf, offs, nx, ny, nlev, f, out) -> None:
    """All levels of one row's buffer summed onto a grid of cells 2^f fine cells wide (``out``
    (ny >> f, nx >> f), litres; a coarser level's litres spread evenly, mass-exact)."""
    out[:, :] = 0.0
    for lev in range(nlev):
        nxl, nyl = nx >> lev, ny >> lev
        o = int(offs[lev])
        if lev <= f:
            sh = f - lev
            for j in range(nyl):
                for i in range(nxl):
                    out[j >> sh, i >> sh] += buf[o + j * nxl + i]
        else:
            sh = lev - f
            k = 1 << sh
            share = 1.0 / (k * k)
            for j in range(nyl):
                for i in range(nxl):
                    a = buf[o + j * nxl + i]
                    if a != 0.0:
                        a *= share
                        for jj in range(j * k, j * k + k):
                            for ii in range(i * k, i * k + k):
                                out[jj, ii] += a


@njit(cache=True)
def _batch_flush(par, st, buf, scratch) -> None:
    for n in range(st.shape[0]):
        _flush(par, st[n], buf[n], scratch, 1.0)


# ------------------------------------------------------------------------------ grid and params
@dataclass(frozen=True)
class GridSpec:
    """The fine ground grid: origin (x0, y0) of its lower-left corner, cell (m), nx × ny cells
    (multiples of 2^(levels-1)), and the level offsets in the flat buffer."""

    x0: float
    y0: float
    cell: float
    nx: int
    ny: int
    levels: int
    offsets: tuple

    @property
    def size(self) -> int:
        return int(self.offsets[-1])

    @classmethod
    def around(cls, bounds: tuple[float, float, float, float], buffer_m: float, cell: float,
               levels: int, max_cells: int) -> GridSpec:
        """Cover ``bounds`` (xmin, ymin, xmax, ymax) plus ``buffer_m``; the cell doubles until the
        fine grid has at most ``max_cells`` cells."""
        xmin, ymin, xmax, ymax = bounds
        blk = 1 << (levels - 1)
        while True:
            nx = int(math.ceil((xmax - xmin + 2 * buffer_m) / cell / blk)) * blk
            ny = int(math.ceil((ymax - ymin + 2 * buffer_m) / cell / blk)) * blk
            if nx * ny <= max_cells:
                break
            cell *= 2.0
        cx, cy = 0.5 * (xmin + xmax), 0.5 * (ymin + ymax)
        offs = [0]
        for lev in range(levels):
            offs.append(offs[-1] + (nx >> lev) * (ny >> lev))
        return cls(cx - 0.5 * nx * cell, cy - 0.5 * ny * cell, cell, nx, ny, levels, tuple(offs))


def pack_params(c: DepositionConfig, g: GridSpec) -> np.ndarray:
    """The flat parameter vector of the compiled kernels (layout: the P_* slots)."""
    noz = np.asarray(c.nozzle_xyz_m, float).reshape(-1, 3)
    share = np.asarray(c.nozzle_share, float)
    if len(share) != len(noz) or np.any(share < 0) or abs(share.sum() - 1.0) > 1e-9:
        raise ValueError("nozzle_share: one non-negative share per nozzle, summing to 1")
    d, frac = droplet_classes(c.dv10_um, c.dv50_um, c.dv90_um, c.n_classes)
    vt = np.array([terminal_velocity(x, c.liquid_density, c.air_density, c.air_viscosity)
                   for x in d])
    tt, hh, rr = fall_tables(c, d)
    arrays = [noz.ravel(), share, vt, vt / G, frac, np.asarray(g.offsets[:-1], float), tt,
              hh.ravel(), rr.ravel()]
    par = np.zeros(P_HEADER + sum(len(a) for a in arrays))
    head = {P_RATE: c.rate_l_per_ha, P_SWATH: c.swath_m, P_VMIN: c.speed_min_mps,
            P_DON: c.nozzle_on_delay_s, P_DOFF: c.nozzle_off_delay_s,
            P_OFFNOW: float(c.cmd_off_immediate), P_TAU: c.pressure_tau_s,
            P_RHOA: c.air_density, P_AREA: c.n_rotors * math.pi * c.rotor_diameter_m ** 2 / 4,
            P_S0: c.jet_decay_b * c.rotor_diameter_m / math.sqrt(2.0), P_ROTZ: c.rotor_z_m,
            P_IW: c.wake_turbulence, P_DELTA: c.outwash_layer_m, P_SIGA: c.ambient_sigma_mps,
            P_SIG0: c.release_sigma_m, P_X0: g.x0, P_Y0: g.y0, P_CELL: g.cell, P_NX: g.nx,
            P_NY: g.ny, P_NLEV: g.levels, P_FLUSHD: c.flush_cells * g.cell,
            P_FLUSHT: c.flush_ticks, P_M: len(noz), P_K: len(d), P_MERGE: c.merge_ratio,
            P_NOZC: float(np.max(np.hypot(noz[:, 0], noz[:, 1]))), P_QMIN: c.flow_min_l_per_s,
            P_ESC: c.wake_escape, P_ELL: c.shear_eddy_m, P_Z0: c.roughness_m,
            P_TMAX: c.airborne_after_s,
            P_EDGE: float(np.max(np.hypot(noz[:, 0], noz[:, 1]))) + 0.5 * c.rotor_diameter_m}
    for k, v in head.items():
        par[k] = v
    o = P_HEADER
    for slot, arr in zip((P_O_NOZ, P_O_SHARE, P_O_VT, P_O_TAUP, P_O_FRAC, P_O_LEV, P_O_TT,
                          P_O_H, P_O_R), arrays, strict=True):
        par[slot] = o
        par[o:o + len(arr)] = arr
        o += len(arr)
    return par


def footprints(cfg: DepositionConfig, inp: np.ndarray, par: np.ndarray | None = None
               ) -> dict[str, np.ndarray]:
    """Every droplet class's landing law for one input row (:func:`pack_input` layout), as the
    loop computes it (the same compiled :func:`_class_footprint`): a dict of arrays over the
    classes, keys ``d_m``, ``frac`` and the F_* names in lower case (``wake``, ``wx``, ``wy``,
    ``wvar``, ``wland``, ``esc``, ``ex``, ``ey``, ``evx``, ``evy``, ``mut``, ``lamt``,
    ``pair``, ``rland``, ``rair``, ``ux``, ``uy``); offsets are from the nozzle centroid."""
    if par is None:
        par = pack_params(cfg, GridSpec(0.0, 0.0, 1.0, 1, 1, 1, (0, 1)))
    out = np.zeros((int(par[P_K]), NFOOT))
    _footprints(par, np.asarray(inp, float).reshape(-1)[:INPUT_WIDTH], out)
    d, frac = droplet_classes(cfg.dv10_um, cfg.dv50_um, cfg.dv90_um, cfg.n_classes)
    names = ("wake", "wx", "wy", "wvar", "wland", "esc", "ex", "ey", "evx", "evy", "mut",
             "lamt", "pair", "rland", "rair", "ux", "uy")
    res = {n: out[:, i].copy() for i, n in enumerate(names)}
    res.update(d_m=d, frac=frac)
    return res


def pack_input(pos, vel, R, thrust, wind, cmd, out: np.ndarray | None = None) -> np.ndarray:
    """Rows of the kernel input (N, INPUT_WIDTH) from per-vehicle arrays (any of them may be a
    single row for N = 1)."""
    pos = np.atleast_2d(np.asarray(pos, float))
    n = pos.shape[0]
    inp = np.empty((n, INPUT_WIDTH)) if out is None else out
    inp[:, 0:3] = pos
    inp[:, 3:6] = np.atleast_2d(vel)
    inp[:, 6:15] = np.asarray(R, float).reshape(n, 9)
    inp[:, 15] = thrust
    inp[:, 16:19] = np.atleast_2d(wind)
    inp[:, 19] = np.asarray(cmd, float).reshape(n) if np.ndim(cmd) else float(cmd)
    return inp


# ------------------------------------------------------------------------------ the dose map
@dataclass
class DoseMap:
    """Litres per fine cell (levels summed), the grid, and the volume bookkeeping."""

    grid: GridSpec
    litres: np.ndarray            # (ny, nx)
    sprayed_l: float
    outside_grid_l: float
    drift_l: float
    airborne_l: float = 0.0       # still aloft after ``airborne_after_s``
    evaporated_l: float = 0.0     # water evaporated on the way down

    @classmethod
    def from_buffer(cls, g: GridSpec, buf: np.ndarray, st: np.ndarray) -> DoseMap:
        """Sum the levels into the fine grid (a coarse cell's litres spread evenly over its
        2^l × 2^l fine cells: mass-exact)."""
        out = np.zeros((g.ny, g.nx))
        for lev in range(g.levels):
            a = buf[g.offsets[lev]:g.offsets[lev + 1]].reshape(g.ny >> lev, g.nx >> lev)
            if lev == 0:
                out += a
            elif a.any():
                f = 1 << lev
                out += np.repeat(np.repeat(a, f, axis=0), f, axis=1) / (f * f)
        return cls(g, out, float(st[S_SPRAYED]), float(st[S_OUTSIDE]), float(st[S_DRIFT]),
                   float(st[S_AIR]), float(st[S_EVAP]))

    @property
    def l_per_ha(self) -> np.ndarray:
        """Applied rate per cell (L/ha)."""
        return self.litres / (self.grid.cell ** 2 * 1e-4)

    def centres(self) -> tuple[np.ndarray, np.ndarray]:
        g = self.grid
        return (g.x0 + (np.arange(g.nx) + 0.5) * g.cell, g.y0 + (np.arange(g.ny) + 0.5) * g.cell)

    def field_mask(self, fld: Any, margin_m: float = 0.0) -> np.ndarray:
        """Cells whose centre lies in the field (holes excluded), optionally ``margin_m`` inside
        its boundary (shapely ``contains_xy`` on the cell centres)."""
        import shapely

        poly = fld.polygon if margin_m <= 0 else fld.polygon.buffer(-margin_m)
        xc, yc = self.centres()
        xx, yy = np.meshgrid(xc, yc)
        return shapely.contains_xy(poly, xx, yy)

    def metrics(self, fld: Any, target_l_per_ha: float, margin_m: float = 0.0) -> dict:
        """The summary metrics; see :func:`dose_metrics`."""
        return dose_metrics(self, fld, target_l_per_ha, margin_m)

    def arrays(self) -> dict[str, Any]:
        """What ``dose.npz`` holds (:func:`ag_uav.jobs.run.fly` writes it): ``litres`` (ny, nx),
        ``l_per_ha``, the grid's ``x0, y0, cell`` (lower-left corner, m) and the volume
        bookkeeping."""
        g = self.grid
        return {"litres": self.litres, "l_per_ha": self.l_per_ha, "x0": g.x0, "y0": g.y0,
                "cell": g.cell, "sprayed_l": self.sprayed_l,
                "outside_grid_l": self.outside_grid_l, "drift_l": self.drift_l,
                "airborne_l": self.airborne_l, "evaporated_l": self.evaporated_l}

    @classmethod
    def load(cls, path: Any) -> DoseMap:
        """A map from ``dose.npz`` (:meth:`arrays`; one level)."""
        with np.load(path) as z:
            lit = np.asarray(z["litres"], float)
            ny, nx = lit.shape
            g = GridSpec(float(z["x0"]), float(z["y0"]), float(z["cell"]), nx, ny, 1,
                         (0, nx * ny))
            extra = [float(z[k]) if k in z.files else 0.0
                     for k in ("airborne_l", "evaporated_l")]
            return cls(g, lit, float(z["sprayed_l"]), float(z["outside_grid_l"]),
                       float(z["drift_l"]), *extra)


def dose_metrics(dm: DoseMap, fld: Any, target: float, margin_m: float = 0.0) -> dict:
    """``dose_mean_l_per_ha`` and ``dose_cv`` over the field cells (centre in the field, holes
    out, ``margin_m`` inside the boundary); ``underdosed_fraction`` / ``overdosed_fraction``:
    share of those cells below 80 % / above 120 % of ``target``;
    ``offtarget_deposit_fraction``: litres on grid cells outside the field or over holes plus
    litres deposited outside the grid, over the sprayed litres; ``drift_fraction``: litres carried
    airborne past the buffer (landing beyond it, or still aloft after ``airborne_after_s``) over
    the sprayed litres; ``evaporated_fraction``: water evaporated on the way down over sprayed;
    ``mass_balance_error``: sprayed − all destinations, over sprayed."""
    inside = dm.field_mask(fld, 0.0)
    interior = inside if margin_m <= 0 else dm.field_mask(fld, margin_m)
    rate = dm.l_per_ha[interior]
    mean = float(rate.mean()) if rate.size else 0.0
    sprayed = max(dm.sprayed_l, 1e-300)
    off = float(dm.litres[~inside].sum()) + dm.outside_grid_l
    total = (float(dm.litres.sum()) + dm.outside_grid_l + dm.drift_l + dm.airborne_l
             + dm.evaporated_l)
    return {
        "dose_mean_l_per_ha": mean,
        "dose_cv": float(rate.std() / mean) if mean > 0 else math.nan,
        "underdosed_fraction": float(np.mean(rate < 0.8 * target)) if rate.size else math.nan,
        "overdosed_fraction": float(np.mean(rate > 1.2 * target)) if rate.size else math.nan,
        "offtarget_deposit_fraction": off / sprayed if dm.sprayed_l > 0 else 0.0,
        "drift_fraction": ((dm.drift_l + dm.airborne_l) / sprayed if dm.sprayed_l > 0
                           else 0.0),
        "evaporated_fraction": dm.evaporated_l / sprayed if dm.sprayed_l > 0 else 0.0,
        "sprayed_l": dm.sprayed_l,
        "mass_balance_error": (dm.sprayed_l - total) / sprayed if dm.sprayed_l > 0 else 0.0,
    }


# ------------------------------------------------------------------------------ the API
class DepositionBatch:
    """N vehicles' nozzles and dose maps (row n = vehicle n). ``step`` once per control tick;
    ``finish`` at the end (splats what is pending); ``dose_map(n)`` reads one map."""

    def __init__(self, cfg: DepositionConfig, fld: Any = None, n: int = 1,
                 bounds: tuple[float, float, float, float] | None = None):
        if fld is None and bounds is None:
            raise ValueError("Deposition: give a field or grid bounds")
        self.cfg = cfg
        self.field = fld
        self.grid = GridSpec.around(fld.bounds if fld is not None else bounds, cfg.buffer_m,
                                    cfg.cell_m, cfg.levels, cfg.max_cells)
        self.par = pack_params(cfg, self.grid)
        nst = (S_ACC + 1 + INPUT_WIDTH + int(self.par[P_M]) * NACC
               + 2 * int(self.par[P_K]) * NSLOW)
        self.st = np.zeros((n, nst))
        self.st[:, S_INC] = -1.0
        self.st[:, S_INSIDE] = -1.0
        self.buf = np.zeros((n, self.grid.size))
        self.out = np.zeros(n)
        self.inp = np.zeros((n, INPUT_WIDTH))
        self.scratch = np.zeros((3, max(self.grid.nx, self.grid.ny, INPUT_WIDTH) + 2))

    @property
    def n(self) -> int:
        return self.st.shape[0]

    @property
    def cell_m(self) -> float:
        """The fine cell actually used (coarser than configured if the grid hit max_cells)."""
        return self.grid.cell

    @property
    def valve_on(self) -> np.ndarray:
        return self.st[:, S_ON] > 0.5

    @property
    def flow_lps(self) -> np.ndarray:
        """Actual flow at the end of the last tick (L/s)."""
        return self.st[:, S_Q]

    def step(self, dt: float, pos, vel, R, thrust, wind, cmd) -> np.ndarray:
        """One tick for every row: pos (N,3), vel (N,3), R (N,9) body→world row-major, thrust
        (N,) total N, wind (N,3) air velocity at the vehicle, cmd (N,) bool. Returns the litres
        sprayed per row in the tick (a view, overwritten next tick)."""
        pack_input(pos, vel, R, thrust, wind, cmd, self.inp)
        return self.step_packed(dt, self.inp)

    def step_packed(self, dt: float, inp: np.ndarray) -> np.ndarray:
        """As :meth:`step` from a packed (N, INPUT_WIDTH) input (:func:`pack_input` layout)."""
        _batch_step(self.par, inp, self.st, self.buf, float(dt), self.out, self.scratch)
        return self.out

    def step_rows(self, dt: float, rows: np.ndarray, p, v, R, S, ia: int, na: int, w, cmd,
                  act) -> np.ndarray:
        """One tick from the engine's per-vehicle arrays: this batch's row j is the engine's
        vehicle ``rows[j]`` (see :func:`_engine_step`); litres per row (a view)."""
        _engine_step(self.par, self.st, self.buf, self.inp, self.out, self.scratch, float(dt),
                     rows, p, v, R, S, ia, na, w, cmd, act)
        return self.out

    def l_per_ha_now(self, i: int, factor: int = 0) -> np.ndarray:
        """Row ``i``'s applied rate (L/ha) so far on cells 2^factor fine cells wide, without
        splatting what is pending (so reading it changes nothing): for a live display."""
        g = self.grid
        f = max(0, min(int(factor), g.levels - 1))
        out = np.empty((g.ny >> f, g.nx >> f))
        _levels_sum(self.buf[i], np.asarray(g.offsets, np.int64), g.nx, g.ny, g.levels, f, out)
        return out / ((g.cell * (1 << f)) ** 2 * 1e-4)

    def finish(self) -> None:
        """Splat whatever is pending (call at the end of the flight; idempotent)."""
        _batch_flush(self.par, self.st, self.buf, self.scratch)

    def dose_map(self, i: int = 0) -> DoseMap:
        self.finish()
        return DoseMap.from_buffer(self.grid, self.buf[i], self.st[i])

    def metrics(self, i: int = 0, target_l_per_ha: float | None = None,
                margin_m: float = 0.0) -> dict:
        """The summary metrics of row ``i`` over the field."""
        if self.field is None:
            raise ValueError("metrics need a field")
        t = self.cfg.rate_l_per_ha if target_l_per_ha is None else target_l_per_ha
        return self.dose_map(i).metrics(self.field, t, margin_m)


def _f64(a) -> np.ndarray:
    """A float64 1-D array (arrays pass through without a copy)."""
    if isinstance(a, np.ndarray) and a.dtype == np.float64 and a.ndim == 1:
        return a
    return np.ascontiguousarray(a, dtype=np.float64).ravel()


class Deposition(DepositionBatch):
    """One vehicle: :meth:`step` takes that vehicle's arrays and returns the litres as a float;
    it runs the same compiled row function as the batch."""

    def __init__(self, cfg: DepositionConfig, fld: Any = None,
                 bounds: tuple[float, float, float, float] | None = None):
        super().__init__(cfg, fld, 1, bounds)
        self._inp0, self._st0, self._buf0 = self.inp[0], self.st[0], self.buf[0]

    def step(self, dt: float, pos, vel, R, thrust: float, wind, cmd: bool) -> float:  # type: ignore[override]
        try:
            return _row_step_args(self.par, self._inp0, self._st0, self._buf0, float(dt),
                                  self.scratch, pos, vel, R, float(thrust), wind, bool(cmd))
        except NumbaTypingError:   # sequences of mixed int/float: convert (slow path)
            return _row_step_args(self.par, self._inp0, self._st0, self._buf0, float(dt),
                                  self.scratch, _f64(pos), _f64(vel), _f64(R), float(thrust),
                                  _f64(wind), bool(cmd))


@njit(cache=True)
def _row_step_args(par, inp, st, buf, dt, scratch, pos, vel, R, thrust, wind, cmd) -> float:
    """:func:`_row_step` from unpacked arrays (fills the packed input row in compiled code)."""
    for j in range(3):
        inp[j] = pos[j]
        inp[3 + j] = vel[j]
        inp[16 + j] = wind[j]
    for j in range(9):
        inp[6 + j] = R[j]
    inp[15] = thrust
    inp[19] = 1.0 if cmd else 0.0
    return _row_step(par, inp, st, buf, dt, scratch)
