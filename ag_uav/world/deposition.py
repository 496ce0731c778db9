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
ln(Dv50/Dv10)/1.2816 below and s_hi = ln(Dv90/Dv50)/1.2816 above (all three matched);
``n_classes`` classes of equal volume at the quantiles (k + ½)/K. The default (120 / 250 /
420 µm) puts 19 % of the volume below 150 µm, a *medium* spray by the GRDC's reading of S572
(medium: up to 20 % below 150 µm; coarse < 10 %); DJI's AGRAS T40 quotes 50–300 µm droplets.

**Terminal velocity** from the drag balance (π/6) d³ (ρ_l − ρ_a) g = C_D · ½ ρ_a v_t² · π d²/4
with Schiller & Naumann (1933, Z. Ver. Dtsch. Ing. 77:318) C_D = 24/Re · (1 + 0.15 Re^0.687) for
Re = ρ_a v_t d / μ ≤ 1000 (0.44 above; Stokes' law is its Re → 0 limit), solved by bisection
once per class. Relaxation time τ_p = v_t / g. Evaporation is **not** modelled (AGDISP does it;
fines would shrink and drift further in warm dry air).

**Downwash** (momentum theory, Leishman, *Principles of Helicopter Aerodynamics* §2.3, §2.14):
hover induced velocity v_h = sqrt(T / (2 ρ A)), A = n_rotors · π D²/4, from the *actual* total
thrust T; in forward flight at horizontal airspeed V (Glauert, wake nearly horizontal-disc
approximation) v_i⁴ + V² v_i² = v_h⁴, so v_i² = (−V² + sqrt(V⁴ + 4 v_h⁴)) / 2. The far wake
reaches 2 v_i in a contracted tube of diameter D/√2 and then decays as a round turbulent jet:
u(s) = 2 v_i for s < s₀ and 2 v_i · s₀ / s beyond, s₀ = B · D/√2 (depth s below the rotor plane;
B ≈ 6, the centre-line decay constant of a round jet, 6.11 at Re = 19,400 in Abdel-Rahman et
al., Mech. Res. Commun. 23(3):313, 1996). The wake blows along −ẑ_body (cosine c = R₂₂).

**Fall and drift** (Lagrangian parcel; droplets follow the air plus their settling velocity, as
τ_p ≪ fall time). A droplet falls from the nozzle depth s_n to the ground depth s_g at
ds/dt = v_t + c·u(s), in closed form::

    t(s₁→s₂) = (s₂ − s₁) / (v_t + a)                                  (s < s₀, a = c·2v_i)
    t(s₁→s₂) = [(s₂ − s₁) − (a s₀ / v_t) ln((v_t s₂ + a s₀) / (v_t s₁ + a s₀))] / v_t   (s ≥ s₀)

The wake carries it D_w = (s_g − s_n) − v_t t_f of the way down. Its mean landing point is::

    x = x_nozzle + W t_f + (ẑ-tilt) D_w / c + (v − W) τ_p (1 − e^{−t_f/τ_p})

(W: the wind at the vehicle, gusts included, frozen over the fall; v: vehicle velocity, which
the droplet sheds over τ_p). The footprint is Gaussian about it with the variance::

    σ² = σ₀² + (i_w D_w)² + (δ u_g / v_t)² + (σ_a t_f)²

σ₀: nozzle sheet at release (``release_sigma_m``); i_w D_w: the wake's turbulence (axial
intensity i_w ≈ 0.25 on a round jet's axis); δ u_g / v_t: the ground outwash, where the wake
arriving with speed u_g turns radially in a layer of thickness δ (``outwash_layer_m``) that a
droplet crosses in δ / v_t (the fines go furthest); σ_a t_f: ambient turbulence not already in
the per-tick wind samples (``ambient_sigma_mps``, default 0: the engine's wind carries the Dryden
gusts, so successive ticks sample them). δ is the one calibrated constant (docs: against DJI's
published 11 m effective swath of the T40 at 2.5 m and 7 m/s).

**Splatting.** Per (nozzle, class) the released volume and its landing moments (volume, first
and second moments) are accumulated over a window of at most ``flush_cells`` cells of travel
(or ``flush_ticks`` ticks), then splatted as one axis-aligned Gaussian whose mean and variance
match the window's (the along-track smear adds its Δ²/12 exactly). Cell weights are exact cell
integrals (erf differences), truncated at ±4σ and rescaled so that the grid receives exactly the
analytic in-grid probability; wide kernels go to coarser levels (cells 2^l larger, at most ~17×17
cells touched), summed into the fine map on read. Classes whose kernel is wider than twice the
nozzle radius merge their nozzles into one Gaussian (same moments). Mass bookkeeping is exact by
construction: sprayed = in grid + deposited outside the grid + drift, where the part landing
outside the grid counts as **drift** (airborne past the buffer) if it was released over the grid
and as **deposited outside** otherwise.

**Memory.** Dense float64 levels over the field's bounding box plus the buffer (≈ 1.33 × the
fine cells); a grid above ``max_cells`` fine cells coarsens the cell (doubling) until it fits,
and says so (:attr:`Deposition.cell_m`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from statistics import NormalDist
from typing import Any

import numpy as np

from .._jit import HAVE_NUMBA, njit

if HAVE_NUMBA:
    from numba.core.errors import TypingError as NumbaTypingError
else:  # pragma: no cover
    NumbaTypingError = TypeError

__all__ = ["DepositionConfig", "Deposition", "DepositionBatch", "DoseMap", "droplet_classes",
           "terminal_velocity", "dose_metrics", "INPUT_WIDTH", "GridSpec", "pack_input",
           "pack_params"]

G = 9.81
#: columns of one input row: pos 3, vel 3, R 9 (row-major), thrust, wind 3, cmd
INPUT_WIDTH = 20
_M350_NOZZLES = ((0.3164, -0.3164, -0.15), (0.3164, 0.3164, -0.15),
                 (-0.3164, 0.3164, -0.15), (-0.3164, -0.3164, -0.15))


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
    n_classes: int = 5
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
    outwash_layer_m: float = 0.155
    release_sigma_m: float = 0.1
    ambient_sigma_mps: float = 0.0
    cell_m: float = 0.5
    buffer_m: float = 10.0
    max_cells: int = 4_000_000
    flush_cells: float = 1.0
    flush_ticks: int = 50
    levels: int = 6
    merge_ratio: float = 2.0
    extra: dict = field(default_factory=dict)

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


def droplet_classes(dv10_um: float, dv50_um: float, dv90_um: float,
                    k: int) -> tuple[np.ndarray, np.ndarray]:
    """``k`` equal-volume classes of a split log-normal volume spectrum through Dv10/Dv50/Dv90
    (ln D normal with its own spread on each side of Dv50, so all three are matched):
    (diameters in m at the volume quantiles (i + ½)/k, volume fractions)."""
    if not 0 < dv10_um < dv50_um < dv90_um:
        raise ValueError("droplet spectrum: need 0 < Dv10 < Dv50 < Dv90")
    nd = NormalDist()
    z9 = nd.inv_cdf(0.9)
    s_lo, s_hi = math.log(dv50_um / dv10_um) / z9, math.log(dv90_um / dv50_um) / z9
    zs = [nd.inv_cdf((i + 0.5) / k) for i in range(k)]
    d = np.array([dv50_um * math.exp((s_lo if z < 0 else s_hi) * z) for z in zs]) * 1e-6
    return d, np.full(k, 1.0 / k)


# ------------------------------------------------------------------------------ packed params
# header slots of the parameter vector (float64); arrays follow at the offsets stored in it
(P_RATE, P_SWATH, P_VMIN, P_DON, P_DOFF, P_OFFNOW, P_TAU, P_RHOA, P_AREA, P_S0, P_ROTZ, P_IW,
 P_DELTA, P_SIGA, P_SIG0, P_X0, P_Y0, P_CELL, P_NX, P_NY, P_NLEV, P_FLUSHD, P_FLUSHT, P_M, P_K,
 P_MERGE, P_O_NOZ, P_O_SHARE, P_O_VT, P_O_TAUP, P_O_FRAC, P_O_LEV, P_NOZC, P_QMIN) = range(34)
P_HEADER = 40
# state slots per row; accumulators (M·K × 6: V, Sx, Sy, Sxx, Syy, Svar) follow at S_ACC
(S_ON, S_INC, S_Q, S_TRAVEL, S_TICKS, S_INSIDE, S_LX, S_LY, S_SPRAYED, S_INGRID, S_OUTSIDE,
 S_DRIFT, S_PENDING, S_LITRES_TICK) = range(14)
S_ACC = 16
NACC = 6


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
def _flush(par, st, buf, scratch) -> None:
    """Splat every pending (nozzle, class) footprint; book what misses the grid."""
    m_n, k_n = int(par[P_M]), int(par[P_K])
    merge_r = par[P_MERGE] * par[P_NOZC]
    drift = st[S_INSIDE] > 0.5
    for k in range(k_n):
        # merged moments over nozzles of class k
        V = Sx = Sy = Sxx = Syy = Svar = 0.0
        for m in range(m_n):
            a = S_ACC + (m * k_n + k) * NACC
            V += st[a]
            Sx += st[a + 1]
            Sy += st[a + 2]
            Sxx += st[a + 3]
            Syy += st[a + 4]
            Svar += st[a + 5]
        if V <= 0.0:
            continue
        merge = math.sqrt(Svar / V) >= merge_r
        for m in range(m_n if not merge else 1):
            if merge:
                v, sx, sy, sxx, syy = V, Sx, Sy, Sxx, Syy
            else:
                a = S_ACC + (m * k_n + k) * NACC
                v, sx, sy, sxx, syy = st[a], st[a + 1], st[a + 2], st[a + 3], st[a + 4]
            if v <= 0.0:
                continue
            mx, my = sx / v, sy / v
            vx = max(sxx / v - mx * mx, 1e-12)
            vy = max(syy / v - my * my, 1e-12)
            put = _splat(par, buf, v, mx, my, vx, vy, scratch)
            st[S_INGRID] += put
            if drift:
                st[S_DRIFT] += v - put
            else:
                st[S_OUTSIDE] += v - put
        for m in range(m_n):
            a = S_ACC + (m * k_n + k) * NACC
            for q in range(NACC):
                st[a + q] = 0.0
    st[S_PENDING] = 0.0
    st[S_TRAVEL] = 0.0
    st[S_TICKS] = 0.0


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
def _release(par, st, inp, litres: float) -> None:
    """Landing moments of this tick's litres, accumulated per (nozzle, class)."""
    m_n, k_n = int(par[P_M]), int(par[P_K])
    o_noz, o_share = int(par[P_O_NOZ]), int(par[P_O_SHARE])
    o_vt, o_tp, o_fr = int(par[P_O_VT]), int(par[P_O_TAUP]), int(par[P_O_FRAC])
    px, py, pz = inp[0], inp[1], inp[2]
    vx, vy = inp[3], inp[4]
    r = inp[6:15]
    thrust, wx, wy = inp[15], inp[16], inp[17]
    cz = r[8] if r[8] > 0.3 else 0.3                 # cosine of the tilt; wake along -z_body
    tx, ty = -r[2] / cz, -r[5] / cz                  # horizontal wake drift per metre of fall
    # rotor-plane height and mean nozzle height above the ground (z = 0)
    zr = pz + r[8] * par[P_ROTZ]
    zn = 0.0
    for m in range(m_n):
        b = o_noz + 3 * m
        zn += par[o_share + m] * (pz + r[6] * par[b] + r[7] * par[b + 1] + r[8] * par[b + 2])
    zn = max(zn, 0.0)
    s_n, s_g = max(zr - zn, 0.0), max(zr, 0.0)
    # momentum theory (Glauert in forward flight)
    vh2 = max(thrust, 0.0) / (2.0 * par[P_RHOA] * par[P_AREA])
    va2 = (vx - wx) ** 2 + (vy - wy) ** 2
    vi = math.sqrt(0.5 * (-va2 + math.sqrt(va2 * va2 + 4.0 * vh2 * vh2)))
    a = 2.0 * vi * cz
    s0 = par[P_S0]
    u_g = a if s_g < s0 else a * s0 / max(s_g, 1e-9)
    sig0, iw, delta, siga = par[P_SIG0], par[P_IW], par[P_DELTA], par[P_SIGA]
    for k in range(k_n):
        vt, tp = par[o_vt + k], par[o_tp + k]
        tf = _fall_time(vt, a, s0, s_n, s_g) if s_g > s_n else 0.0
        dw = max((s_g - s_n) - vt * tf, 0.0)
        relax = tp * (1.0 - math.exp(-tf / tp))
        ox = wx * tf + tx * dw + (vx - wx) * relax
        oy = wy * tf + ty * dw + (vy - wy) * relax
        var = sig0 * sig0 + (iw * dw) ** 2 + (delta * u_g / vt) ** 2 + (siga * tf) ** 2
        vk = litres * par[o_fr + k]
        for m in range(m_n):
            b = o_noz + 3 * m
            x = px + r[0] * par[b] + r[1] * par[b + 1] + r[2] * par[b + 2] + ox
            y = py + r[3] * par[b] + r[4] * par[b + 1] + r[5] * par[b + 2] + oy
            v = vk * par[o_share + m]
            q = S_ACC + (m * k_n + k) * NACC
            st[q] += v
            st[q + 1] += v * x
            st[q + 2] += v * y
            st[q + 3] += v * (x * x + var)
            st[q + 4] += v * (y * y + var)
            st[q + 5] += v * var


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
    if st[S_PENDING] > 0.0 and flag != st[S_INSIDE]:
        _flush(par, st, buf, scratch)
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
            _flush(par, st, buf, scratch)
    elif st[S_PENDING] > 0.0:
        _flush(par, st, buf, scratch)
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
        if st[n, S_PENDING] > 0.0:
            _flush(par, st[n], buf[n], scratch)


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
    arrays = [noz.ravel(), share, vt, vt / G, frac, np.asarray(g.offsets[:-1], float)]
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
            P_NOZC: float(np.max(np.hypot(noz[:, 0], noz[:, 1]))), P_QMIN: c.flow_min_l_per_s}
    for k, v in head.items():
        par[k] = v
    o = P_HEADER
    for slot, arr in zip((P_O_NOZ, P_O_SHARE, P_O_VT, P_O_TAUP, P_O_FRAC, P_O_LEV), arrays,
                         strict=True):
        par[slot] = o
        par[o:o + len(arr)] = arr
        o += len(arr)
    return par


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
        return cls(g, out, float(st[S_SPRAYED]), float(st[S_OUTSIDE]), float(st[S_DRIFT]))

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
        """The summary metrics (names fixed by issue 18); see :func:`dose_metrics`."""
        return dose_metrics(self, fld, target_l_per_ha, margin_m)

    def arrays(self) -> dict[str, Any]:
        """What ``dose.npz`` holds (:func:`ag_uav.jobs.run.fly` writes it): ``litres`` (ny, nx),
        ``l_per_ha``, the grid's ``x0, y0, cell`` (lower-left corner, m) and the volume
        bookkeeping."""
        g = self.grid
        return {"litres": self.litres, "l_per_ha": self.l_per_ha, "x0": g.x0, "y0": g.y0,
                "cell": g.cell, "sprayed_l": self.sprayed_l,
                "outside_grid_l": self.outside_grid_l, "drift_l": self.drift_l}

    @classmethod
    def load(cls, path: Any) -> DoseMap:
        """A map from ``dose.npz`` (:meth:`arrays`; one level)."""
        with np.load(path) as z:
            lit = np.asarray(z["litres"], float)
            ny, nx = lit.shape
            g = GridSpec(float(z["x0"]), float(z["y0"]), float(z["cell"]), nx, ny, 1,
                         (0, nx * ny))
            return cls(g, lit, float(z["sprayed_l"]), float(z["outside_grid_l"]),
                       float(z["drift_l"]))


def dose_metrics(dm: DoseMap, fld: Any, target: float, margin_m: float = 0.0) -> dict:
    """``dose_mean_l_per_ha`` and ``dose_cv`` over the field cells (centre in the field, holes
    out, ``margin_m`` inside the boundary); ``underdosed_fraction`` / ``overdosed_fraction``:
    share of those cells below 80 % / above 120 % of ``target``;
    ``offtarget_deposit_fraction``: litres on grid cells outside the field or over holes plus
    litres deposited outside the grid, over the sprayed litres; ``drift_fraction``: litres carried
    airborne past the buffer over the sprayed litres; ``mass_balance_error``: sprayed − all
    destinations, over sprayed."""
    inside = dm.field_mask(fld, 0.0)
    interior = inside if margin_m <= 0 else dm.field_mask(fld, margin_m)
    rate = dm.l_per_ha[interior]
    mean = float(rate.mean()) if rate.size else 0.0
    sprayed = max(dm.sprayed_l, 1e-300)
    off = float(dm.litres[~inside].sum()) + dm.outside_grid_l
    total = float(dm.litres.sum()) + dm.outside_grid_l + dm.drift_l
    return {
        "dose_mean_l_per_ha": mean,
        "dose_cv": float(rate.std() / mean) if mean > 0 else math.nan,
        "underdosed_fraction": float(np.mean(rate < 0.8 * target)) if rate.size else math.nan,
        "overdosed_fraction": float(np.mean(rate > 1.2 * target)) if rate.size else math.nan,
        "offtarget_deposit_fraction": off / sprayed if dm.sprayed_l > 0 else 0.0,
        "drift_fraction": dm.drift_l / sprayed if dm.sprayed_l > 0 else 0.0,
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
        nst = S_ACC + int(self.par[P_M]) * int(self.par[P_K]) * NACC
        self.st = np.zeros((n, nst))
        self.st[:, S_INC] = -1.0
        self.st[:, S_INSIDE] = -1.0
        self.buf = np.zeros((n, self.grid.size))
        self.out = np.zeros(n)
        self.inp = np.zeros((n, INPUT_WIDTH))
        self.scratch = np.zeros((2, max(self.grid.nx, self.grid.ny) + 2))

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
        """The issue-18 summary metrics of row ``i`` over the field."""
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
