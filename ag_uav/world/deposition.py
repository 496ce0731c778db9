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
wake blows along −ẑ_body): a skewed wake decays within a shorter depth. With
``jet_merge_lengths`` > 0 the rotors' jets merge, beyond that many wheelbases (2 ×
``rotor_arm_m``), into one round jet of the whole vehicle, u = B u₀ D₀ / (s − s_v) with
D₀ = √n D/√2 (:mod:`ag_uav.world.wake`: Bauersfeld et al. 2024, arXiv 2403.13321; off by
default).

**The wake part** of a class falls from the nozzle depth s_n to the ground depth s_g at
ds/dt = v_t + u(s), in closed form::

    t(s₁→s₂) = (s₂ − s₁) / (v_t + a)                                  (s < z₀)
    t(s₁→s₂) = [(s₂ − s₁) − (a z₀ / v_t) ln((v_t s₂ + a z₀) / (v_t s₁ + a z₀))] / v_t   (s ≥ z₀)

lands about x = x_nozzle + W t_f + (ẑ-tilt) D_w / c + (v − W) τ_p (1 − e^{−t_f/τ_p}) (D_w =
(s_g − s_n) − v_t t_f the wake's share of the fall, W the wind at the vehicle) with the variance
σ² = σ₀² + (i_w D_w)² + (δ u_g / v_t)² + (σ_a t_f)² (σ₀ the nozzle sheet, to which a rotary
atomiser adds its throw r_t(d)² / 2 per class, :mod:`~ag_uav.world.atomiser`; i_w ≈ 0.25 the jet's
turbulence intensity, δ u_g / v_t the ground outwash of speed u_g in a layer δ, σ_a ambient
turbulence not in the per-tick wind samples). δ = 0.17 m is calibrated (docs: DJI's 11 m T40
swath). With ``outwash_impaction_st50`` > 0 only the share St₅₀² / (St_g² + St₅₀²) of a class
rides the outwash (St_g = τ_p u_g / r_j, r_j = √n D/2: a round impinging jet's impactor cut,
Marple & Liu 1974, Environ. Sci. Technol. 8(7):648), drifting with the log-law wind at δ for
δ / v_t (the mixture's mean and variance; off by default).

**The trailing vortex pair** (option ``vortex_life_tstar`` > 0; the law ``wake``). In forward
flight a share f = 3x² − 2x³, x = V_a / (``wing_speed_vh`` v_h) ≤ 1, of the wake part rolls up
as a lifting wing's: a vortex pair of separation b₀ = (π/4) b (b the rotors' width),
circulation Γ = T / (ρ V_a b₀) and descent w₀ = Γ / (2π b₀) (Prandtl's lifting line; the rotor
as a wing, Leishman §2.14), which near the ground runs apart at Γ / (4π c) (the image vortices;
Lamb, *Hydrodynamics* §155) and carries a droplet outward while it settles out of the pair's
layer. It is a third part of each class (its own mean and axis variances), laws in
:mod:`ag_uav.world.wake`; 0 when the option is off.

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
landed after ``airborne_after_s`` (P(T > T_max)) is **airborne**; the water lost on the way
is **evaporated** (at the mean fall time). The map and the bookkeeping count the **tank mix** (its
tracer, or active ingredient, as a deposition trial's collectors and a label's rate do):
evaporation shrinks a droplet, and so its fall and its drift, but not the mix it carries; the
water it loses is booked apart. In the dose grid the escaped part is splatted as the
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
construction: sprayed = in grid + deposited outside the grid + drift + airborne (tank mix),
where the part landing outside the grid counts as **drift** (carried past the buffer) if it was
released over the grid and as **deposited outside** otherwise.

**Memory.** Dense float64 levels over the field's bounding box plus the buffer (≈ 1.33 × the
fine cells); a grid above ``max_cells`` fine cells coarsens the cell (doubling) until it fits,
and says so (:attr:`Deposition.cell_m`).

**Modules.** The parameters in :mod:`~ag_uav.world.deposition_config`, the droplet physics in
:mod:`~ag_uav.world.droplets`, the compiled row kernels and their packed layouts in
:mod:`~ag_uav.world.deposition_kernels`; the grid, the dose map and the API here.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np

from .._jit import HAVE_NUMBA
from .atomiser import throw_variances
from .deposition_config import DepositionConfig
from .deposition_kernels import (
    batch_flush,
    batch_step,
    class_footprints,
    engine_step,
    levels_sum,
    row_step_args,
)
from .deposition_layout import (
    FOOTPRINT,
    INPUT,
    INPUT_WIDTH,
    NACC,
    NFOOT,
    NPART,
    NSLOW,
    P_AREA,
    P_BD0,
    P_CELL,
    P_DELTA,
    P_DOFF,
    P_DON,
    P_EDGE,
    P_ELL,
    P_ESC,
    P_FLUSHD,
    P_FLUSHT,
    P_HEADER,
    P_HI,
    P_INVL,
    P_IW,
    P_K,
    P_M,
    P_MERGE,
    P_NLEV,
    P_NOZC,
    P_NX,
    P_NY,
    P_O_FRAC,
    P_O_H,
    P_O_LEV,
    P_O_NOZ,
    P_O_R,
    P_O_SHARE,
    P_O_TAUP,
    P_O_THR,
    P_O_TT,
    P_O_VT,
    P_OFFNOW,
    P_QMIN,
    P_RATE,
    P_RHOA,
    P_RJ,
    P_ROTZ,
    P_S0,
    P_SIG0,
    P_SIGA,
    P_SM,
    P_SPAN,
    P_ST50,
    P_SWATH,
    P_TAU,
    P_TMAX,
    P_VMIN,
    P_VTX,
    P_WINGV,
    P_WJ,
    P_X0,
    P_Y0,
    P_Z0,
    S_ACC,
    S_AIR,
    S_DRIFT,
    S_EVAP,
    S_INC,
    S_INSIDE,
    S_ON,
    S_OUTSIDE,
    S_Q,
    S_SPRAYED,
    SCRATCH,
)
from .droplets import (
    Air,
    G,
    droplet_classes,
    evaporation,
    fall_tables,
    terminal_velocity,
    wet_bulb_c,
)

if HAVE_NUMBA:
    from numba.core.errors import TypingError as NumbaTypingError
else:  # pragma: no cover
    NumbaTypingError = TypeError

__all__ = ["DepositionConfig", "Deposition", "DepositionBatch", "DoseMap", "droplet_classes",
           "terminal_velocity", "dose_metrics", "INPUT_WIDTH", "GridSpec", "pack_input",
           "pack_params", "footprints", "evaporation", "wet_bulb_c", "Air", "fall_tables"]



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


def rotor_span(n_rotors: int, arm_m: float, rotor_d_m: float) -> float:
    """The rotors' width across the flight direction: 2 × arm × max |sin θ_k| + D, the hubs at
    θ_k = (k + ½) 360°/n (an X layout: √2 × arm + D for four)."""
    s = max(abs(math.sin((k + 0.5) * 2.0 * math.pi / n_rotors)) for k in range(n_rotors))
    return 2.0 * arm_m * s + rotor_d_m


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
    thr = throw_variances(d, c.throw_speed_mps, c.throw_air_mps, c.liquid_density,
                          c.air_density, c.air_viscosity)
    arrays = [noz.ravel(), share, vt, vt / G, frac, np.asarray(g.offsets[:-1], float), tt,
              hh.ravel(), rr.ravel(), thr]
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
            P_EDGE: float(np.max(np.hypot(noz[:, 0], noz[:, 1]))) + 0.5 * c.rotor_diameter_m,
            P_SM: (c.jet_merge_lengths * 2.0 * c.rotor_arm_m if c.jet_merge_lengths > 0
                   else 1e30),
            P_BD0: c.jet_decay_b * math.sqrt(c.n_rotors) * c.rotor_diameter_m / math.sqrt(2.0),
            P_RJ: 0.5 * math.sqrt(c.n_rotors) * c.rotor_diameter_m,
            P_ST50: c.outwash_impaction_st50, P_INVL: c.obukhov_inv_m,
            P_WJ: c.wall_jet_growth,
            P_HI: c.impingement_diameters * math.sqrt(c.n_rotors / 2.0) * c.rotor_diameter_m,
            P_SPAN: 0.25 * math.pi * rotor_span(c.n_rotors, c.rotor_arm_m, c.rotor_diameter_m),
            P_VTX: c.vortex_life_tstar, P_WINGV: c.wing_speed_vh}
    for k, v in head.items():
        par[k] = v
    o = P_HEADER
    for slot, arr in zip((P_O_NOZ, P_O_SHARE, P_O_VT, P_O_TAUP, P_O_FRAC, P_O_LEV, P_O_TT,
                          P_O_H, P_O_R, P_O_THR), arrays, strict=True):
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
    ``pair``, ``rland``, ``rair``, ``ux``, ``uy``, and the trailing vortex pair's part
    ``vort``, ``vx``, ``vy``, ``vvx``, ``vvy``, ``vland``, and ``throw``, the variance a
    rotary atomiser's throw adds to each axis of the class's release); offsets are from the
    nozzle centroid."""
    if par is None:
        par = pack_params(cfg, GridSpec(0.0, 0.0, 1.0, 1, 1, 1, (0, 1)))
    out = np.zeros((int(par[P_K]), NFOOT))
    class_footprints(par, np.asarray(inp, float).reshape(-1)[:INPUT_WIDTH], out)
    d, frac = droplet_classes(cfg.dv10_um, cfg.dv50_um, cfg.dv90_um, cfg.n_classes)
    res = {n: out[:, i].copy() for n, i in FOOTPRINT.offset.items()}
    o = int(par[P_O_THR])
    res.update(d_m=d, frac=frac, throw=par[o:o + len(d)].copy())
    return res


def pack_input(pos, vel, R, thrust, wind, cmd, out: np.ndarray | None = None) -> np.ndarray:
    """Rows of the kernel input (N, INPUT_WIDTH) from per-vehicle arrays (any of them may be a
    single row for N = 1)."""
    pos = np.atleast_2d(np.asarray(pos, float))
    n = pos.shape[0]
    inp = np.empty((n, INPUT_WIDTH)) if out is None else out
    inp[:, INPUT.slice("pos")] = pos
    inp[:, INPUT.slice("vel")] = np.atleast_2d(vel)
    inp[:, INPUT.slice("r")] = np.asarray(R, float).reshape(n, INPUT.width["r"])
    inp[:, INPUT.offset["thrust"]] = thrust
    inp[:, INPUT.slice("wind")] = np.atleast_2d(wind)
    inp[:, INPUT.offset["cmd"]] = np.asarray(cmd, float).reshape(n) if np.ndim(cmd) else float(cmd)
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
    evaporated_l: float = 0.0     # water evaporated on the way down (not in the balance)

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
                # each fine cell of a coarse one gets its share, added through a view of the
                # fine grid as (ny/f, f, nx/f, f) blocks: no fine-sized temporaries
                blocks = out.reshape(g.ny >> lev, f, g.nx >> lev, f)
                blocks += (a / (f * f))[:, None, :, None]
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
        xc, yc = self.centres()   # broadcast (ny, 1) against (1, nx): no meshgrid copies
        return shapely.contains_xy(poly, xc[None, :], yc[:, None])

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
    the sprayed litres; ``evaporated_fraction``: water evaporated on the way down over sprayed
    (the map and the other volumes count the tank mix, which evaporation does not remove);
    ``mass_balance_error``: sprayed − all destinations of the mix, over sprayed."""
    inside = dm.field_mask(fld, 0.0)
    interior = inside if margin_m <= 0 else dm.field_mask(fld, margin_m)
    rate = dm.litres[interior] / (dm.grid.cell ** 2 * 1e-4)   # l_per_ha of those cells only
    mean = float(rate.mean()) if rate.size else 0.0
    sprayed = max(dm.sprayed_l, 1e-300)
    off = float(dm.litres[~inside].sum()) + dm.outside_grid_l
    total = float(dm.litres.sum()) + dm.outside_grid_l + dm.drift_l + dm.airborne_l
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
               + NPART * int(self.par[P_K]) * NSLOW)
        self.st = np.zeros((n, nst))
        self.st[:, S_INC] = -1.0
        self.st[:, S_INSIDE] = -1.0
        self.buf = np.zeros((n, self.grid.size))
        self.out = np.zeros(n)
        self.inp = np.zeros((n, INPUT_WIDTH))
        self.scratch = np.zeros((SCRATCH.size, max(self.grid.nx, self.grid.ny, INPUT_WIDTH) + 2))
        self._arrays = (self.par, self.inp, self.st, self.buf, self.scratch)  # DepArrays

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
        batch_step(self.par, inp, self.st, self.buf, float(dt), self.out, self.scratch)
        return self.out

    def step_rows(self, dt: float, rows: np.ndarray, vehicles: tuple, ia: int,
                  na: int) -> np.ndarray:
        """One tick from the engine's per-vehicle arrays (``vehicles``: a
        :class:`~ag_uav.world.deposition_kernels.VehicleRows`, or a plain tuple in its field
        order): this batch's row j is the engine's vehicle ``rows[j]`` (see
        :func:`engine_step`); litres per row (a view)."""
        engine_step(self._arrays, self.out, float(dt), rows, tuple(vehicles), ia, na)
        return self.out

    def l_per_ha_now(self, i: int, factor: int = 0) -> np.ndarray:
        """Row ``i``'s applied rate (L/ha) so far on cells 2^factor fine cells wide, without
        splatting what is pending (so reading it changes nothing): for a live display."""
        g = self.grid
        f = max(0, min(int(factor), g.levels - 1))
        out = np.empty((g.ny >> f, g.nx >> f))
        levels_sum(self.buf[i], np.asarray(g.offsets, np.int64), g.nx, g.ny, g.levels, f, out)
        return out / ((g.cell * (1 << f)) ** 2 * 1e-4)

    def finish(self) -> None:
        """Splat whatever is pending (call at the end of the flight; idempotent)."""
        batch_flush(self.par, self.st, self.buf, self.scratch)

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
        self._row0 = (self.par, self.inp[0], self.st[0], self.buf[0], self.scratch)  # DepArrays

    def step(self, dt: float, pos, vel, R, thrust: float, wind, cmd: bool) -> float:  # type: ignore[override]
        try:
            return row_step_args(self._row0, float(dt), pos, vel, R, float(thrust), wind,
                                 bool(cmd))
        except NumbaTypingError:   # sequences of mixed int/float: convert (slow path)
            return row_step_args(self._row0, float(dt), _f64(pos), _f64(vel), _f64(R),
                                 float(thrust), _f64(wind), bool(cmd))
