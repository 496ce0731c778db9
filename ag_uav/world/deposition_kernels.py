"""The compiled row kernels of the spray deposition: the packed parameter, state and input
layouts, and the valve, flow, release, footprint and splat of one vehicle's tick, called alike
by one vehicle and by the batch (sources in :mod:`ag_uav.world.deposition`)."""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np

from numkit import X, Y, Z
from numkit.geometry import RXX, RXY, RXZ, RYX, RYY, RYZ, RZX, RZY, RZZ

from .._jit import njit
from .deposition_layout import (
    DEP_PARAMS,
    DEP_STATE,
    FOOTPRINT,
    INPUT,
    MOMENTS,
    NPART,
    SCRATCH,
    WIDE,
)
from .droplets import N_TAB
from .surface_layer import eddy_k, layer_wind
from .wake import centreline_speed, fall_time, vortex_landing, vortex_pair, wing_share


class DepArrays(NamedTuple):
    """A deposition batch's arrays, declared once: the packed parameters ``par``, the input
    rows ``inp`` (N, _I.SIZE), the state rows ``st``, the dose buffers ``buf`` and the
    splat's ``scratch``; or one row's (``inp``, ``st``, ``buf`` 1-D). Passed to a kernel as a
    plain tuple in field order and named again inside (as :mod:`ag_uav.engine.kernels` does)."""

    par: np.ndarray
    inp: np.ndarray
    st: np.ndarray
    buf: np.ndarray
    scratch: np.ndarray


class VehicleRows(NamedTuple):
    """The engine's per-vehicle arrays that the deposition reads: position ``p`` and velocity
    ``v`` (N, 3), ``R`` (N, 9; row-major body → world), the physics state ``S``, the wind ``w``
    (N, 3), the nozzle command ``cmd`` and the active vehicles ``act`` (N,)."""

    p: np.ndarray
    v: np.ndarray
    R: np.ndarray
    S: np.ndarray
    w: np.ndarray
    cmd: np.ndarray
    act: np.ndarray

#: a wide part is splatted once its release points' variance reaches this share of its kernel's
WIDE_SPREAD = 0.25
#: von Kármán's constant; σ_v / u* of the neutral surface layer (Panofsky & Dutton 1984,
#: *Atmospheric Turbulence*, §7: σ_u, σ_v, σ_w ≈ 2.4, 1.9, 1.25 u*)
KAPPA = 0.41
SIGV_USTAR = 1.9
#: slots of the per-tick environment (:func:`_environment`) and of one class's footprint
#: (:func:`_class_footprint`)
NENV = 16
#: the layouts' offsets, by field name (numba freezes them into the compiled code)
_P, _S, _F = DEP_PARAMS.at, DEP_STATE.at, FOOTPRINT.at
_I, _M, _W, _SC = INPUT.at, MOMENTS.at, WIDE.at, SCRATCH.at


@njit(cache=True, inline="always")
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
    x0, y0, cell = par[_P.X0], par[_P.Y0], par[_P.CELL]
    nx, ny, nlev = int(par[_P.NX]), int(par[_P.NY]), int(par[_P.NLEV])
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
    wx, wy = scratch[_SC.WX], scratch[_SC.WY]
    tx = _cell_weights(x0, c, mx, rx, i0, i1, wx)
    ty = _cell_weights(y0, c, my, ry, j0, j1, wy)
    if tx * ty <= 0.0:
        return 0.0
    put = vol * px * py
    scale = put / (tx * ty)
    base0 = int(par[int(par[_P.O_LEV]) + lev])
    for j in range(j0, j1 + 1):
        wj = wy[j - j0] * scale
        base = base0 + j * nxl
        for i in range(i0, i1 + 1):
            buf[base + i] += wj * wx[i - i0]
    return put


@njit(cache=True, inline="always")
def _splat_part(par, st, buf, scratch, vol, mx, my, vx, vy, drift) -> None:
    """Splat one Gaussian and book what misses the grid (drift or deposited outside)."""
    if vol <= 0.0:
        return
    put = _splat(par, buf, vol, mx, my, vx, vy, scratch)
    st[_S.INGRID] += put
    if drift:
        st[_S.DRIFT] += vol - put
    else:
        st[_S.OUTSIDE] += vol - put


@njit(cache=True, inline="always")
def _part(f, part: int, vw: float, land_e: float, vv: float):
    """(share, mean x, mean y, variance x, variance y) of a class's part: 0 the wake, 1 the
    escaped part that lands, 2 the trailing vortex pair's."""
    if part == 0:
        return vw, f[_F.WX], f[_F.WY], f[_F.WVAR], f[_F.WVAR]
    if part == 1:
        return land_e, f[_F.EX], f[_F.EY], f[_F.EVX], f[_F.EVY]
    return vv, f[_F.VX], f[_F.VY], f[_F.VVX], f[_F.VVY]


@njit(cache=True)
def _flush(par, st, buf, scratch, force: float) -> None:
    """The window's landing law, once: every class's footprint (:func:`_class_footprint`) at
    the window's litre-weighted mean input row, convolved with each nozzle's release moments
    (the along-track smear exactly); the wake and the escaped part of each (nozzle, class)
    splatted (nozzles merged where the class's kernel is wider than ``merge_ratio`` × the
    nozzle radius); airborne volume and evaporated water booked. Volumes are of the tank mix
    (its tracer, as a deposition trial's collectors measure it): evaporation shrinks a droplet
    but not the mix it carries, so the splatted and airborne shares are the whole class's, and
    the water it loses on the way is booked apart."""
    m_n, k_n = int(par[_P.M]), int(par[_P.K])
    o_fr = int(par[_P.O_FRAC])
    merge_r = par[_P.MERGE] * par[_P.NOZC]
    drift = st[_S.INSIDE] > 0.5
    vtot = st[_S.SIZE]
    if vtot > 0.0:
        row = scratch[_SC.ROW]
        for j in range(_I.SIZE):
            row[j] = st[_S.SIZE + 1 + j] / vtot
        env = _environment(par, row)
        o = _S.SIZE + 1 + _I.SIZE
        V = Sx = Sy = Sxx = Syy = 0.0
        for m in range(m_n):
            a = o + m * _M.SIZE
            V += st[a + _M.V]
            Sx += st[a + _M.SX]
            Sy += st[a + _M.SY]
            Sxx += st[a + _M.SXX]
            Syy += st[a + _M.SYY]
        for k in range(k_n):
            f = _class_footprint(par, k, env)
            vk = par[o_fr + k]
            vw, ve, vv = vk * f[_F.WAKE], vk * f[_F.ESC], vk * f[_F.VORT]
            land_e = ve * (1.0 - f[_F.PAIR])
            air = ve * f[_F.PAIR]
            st[_S.AIR] += vtot * air
            st[_S.EVAP] += vtot * (vw * (1.0 - f[_F.WLAND]) + land_e * (1.0 - f[_F.RLAND])
                                  + air * (1.0 - f[_F.RAIR]) + vv * (1.0 - f[_F.VLAND]))
            for part in range(NPART):
                share, ox, oy, kvx, kvy = _part(f, part, vw, land_e, vv)
                if share <= 0.0:
                    continue
                if math.sqrt(0.5 * (kvx + kvy)) >= merge_r:
                    q = o + m_n * _M.SIZE + (NPART * k + part) * _W.SIZE
                    w = share * V
                    st[q + _W.V] += w
                    st[q + _W.SX] += share * (Sx + ox * V)
                    st[q + _W.SY] += share * (Sy + oy * V)
                    st[q + _W.SXX] += share * (Sxx + 2.0 * ox * Sx + ox * ox * V)
                    st[q + _W.SYY] += share * (Syy + 2.0 * oy * Sy + oy * oy * V)
                    st[q + _W.VKX] += w * kvx
                    st[q + _W.VKY] += w * kvy
                    continue
                for m in range(m_n):
                    a = o + m * _M.SIZE
                    v = st[a + _M.V]
                    if v <= 0.0:
                        continue
                    mx, my = st[a + _M.SX] / v, st[a + _M.SY] / v
                    _splat_part(par, st, buf, scratch, share * v, mx + ox, my + oy,
                                max(st[a + _M.SXX] / v - mx * mx, 0.0) + kvx,
                                max(st[a + _M.SYY] / v - my * my, 0.0) + kvy, drift)
        for j in range(_S.SIZE, o + m_n * _M.SIZE):
            st[j] = 0.0
    _flush_wide(par, st, buf, scratch, force)
    st[_S.PENDING] = 0.0
    st[_S.TRAVEL] = 0.0
    st[_S.TICKS] = 0.0


@njit(cache=True, inline="always")
def _flush_wide(par, st, buf, scratch, force: float) -> None:
    """The wide parts (nozzles merged) gather over several windows: each is splatted once the
    spread of its release points reaches a quarter of its kernel's variance (so the smear
    changes its shape by little; mean and variance are matched exactly), or when ``force`` > 0
    (the end, the vehicle crossing the grid's edge)."""
    m_n, k_n = int(par[_P.M]), int(par[_P.K])
    drift = st[_S.INSIDE] > 0.5
    base = _S.SIZE + 1 + _I.SIZE + m_n * _M.SIZE
    for i in range(NPART * k_n):
        q = base + i * _W.SIZE
        w = st[q + _W.V]
        if w <= 0.0:
            continue
        mx, my = st[q + _W.SX] / w, st[q + _W.SY] / w
        px = max(st[q + _W.SXX] / w - mx * mx, 0.0)
        py = max(st[q + _W.SYY] / w - my * my, 0.0)
        kx, ky = st[q + _W.VKX] / w, st[q + _W.VKY] / w
        if force > 0.0 or px + py >= WIDE_SPREAD * (kx + ky):
            _splat_part(par, st, buf, scratch, w, mx, my, px + kx, py + ky, drift)
            for j in range(_W.SIZE):
                st[q + j] = 0.0


@njit(cache=True, inline="always")
def _valve(par, st, dt: float, cmd: bool, speed: float) -> None:
    """ArduPilot AC_Sprayer's state machine on want = cmd ∧ speed ≥ v_min (module docstring)."""
    on = st[_S.ON] > 0.5
    want = cmd and speed >= par[_P.VMIN]
    if on and not cmd and par[_P.OFFNOW] > 0.5:
        st[_S.ON] = 0.0
        st[_S.INC] = -1.0
        return
    if want == on:
        st[_S.INC] = -1.0
        return
    st[_S.INC] = 0.0 if st[_S.INC] < 0.0 else st[_S.INC] + dt
    delay = par[_P.DOFF] if on else par[_P.DON]
    if st[_S.INC] >= delay - 1e-9:
        st[_S.ON] = 0.0 if on else 1.0
        st[_S.INC] = -1.0


@njit(cache=True, inline="always")
def _flow(par, st, dt: float, speed: float) -> float:
    """Litres out this tick: the first-order pressure lag toward q* = max(R·w·v/10⁴, q_min),
    exactly."""
    qs = max(par[_P.RATE] * par[_P.SWATH] * speed * 1e-4, par[_P.QMIN]) if st[_S.ON] > 0.5 else 0.0
    q0, tau = st[_S.Q], par[_P.TAU]
    if tau <= 0.0:
        st[_S.Q] = qs
        return qs * dt
    e = math.exp(-dt / tau)
    st[_S.Q] = qs + (q0 - qs) * e
    return qs * dt + (q0 - qs) * tau * (1.0 - e)


@njit(cache=True, inline="always")
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


@njit(cache=True, inline="always")
def _tab_time(par, k: int, h: float) -> float:
    """Still-air fall time (s) of class ``k`` through ``h`` metres, evaporating (the table of
    :func:`fall_tables`, linear between its points, the last speed beyond it)."""
    n, o_t = N_TAB, int(par[_P.O_TT])
    o = int(par[_P.O_H]) + k * n
    if h <= 0.0:
        return 0.0
    if h >= par[o + n - 1]:
        j = n - 1  # the table's last point
        v = (par[o + j] - par[o + j - 1]) / (par[o_t + j] - par[o_t + j - 1])
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


@njit(cache=True, inline="always")
def _tab_left(par, k: int, t: float) -> float:
    """Share of class ``k``'s volume left after ``t`` s of evaporation (table, linear)."""
    n, o_t = N_TAB, int(par[_P.O_TT])
    o = int(par[_P.O_R]) + k * n
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
    wake (speed a, skew, the rotors' core, the merged jet), the wind and the surface layer.
    Laws in the module docstring. Returns (s_n, s_g, a, z0w, tx, ty, wx, wy, vx, vy, u_g, sin χ,
    u*, h_n, f_u, σ_s, s_m cos χ, B D_0 cos χ, the trailing pair: (wing share, w₀, c, U,
    lifetime, lateral unit x, y) of :mod:`ag_uav.world.wake`)."""
    m_n = int(par[_P.M])
    o_noz, o_share = int(par[_P.O_NOZ]), int(par[_P.O_SHARE])
    pz, vx, vy = inp[_I.POS + Z], inp[_I.VEL + X], inp[_I.VEL + Y]
    r = inp[_I.R:_I.R_END]
    thrust, wx, wy = inp[_I.THRUST], inp[_I.WIND + X], inp[_I.WIND + Y]
    cz = r[RZZ] if r[RZZ] > 0.3 else 0.3           # cosine of the tilt; wake along -z_body
    tx, ty = -r[RXZ] / cz, -r[RYZ] / cz            # horizontal wake drift per metre of fall
    zr = pz + r[RZZ] * par[_P.ROTZ]
    zn = 0.0
    for m in range(m_n):
        b = o_noz + 3 * m
        # the nozzle's height, z + (R n_b)_z
        zn += par[o_share + m] * (pz + r[RZX] * par[b + X] + r[RZY] * par[b + Y]
                                  + r[RZZ] * par[b + Z])
    zn = max(zn, 0.0)
    s_n, s_g = max(zr - zn, 0.0), max(zr, 0.0)
    # momentum theory (Glauert in forward flight) and the wake skew tan χ = V_a / v_i
    vh2 = max(thrust, 0.0) / (2.0 * par[_P.RHOA] * par[_P.AREA])
    va2 = (vx - wx) ** 2 + (vy - wy) ** 2
    vi = math.sqrt(0.5 * (-va2 + math.sqrt(va2 * va2 + 4.0 * vh2 * vh2)))
    hyp = math.sqrt(va2 + vi * vi)
    cos_chi = vi / hyp if hyp > 0.0 else 1.0
    sin_chi = math.sqrt(va2) / hyp if hyp > 0.0 else 0.0
    a = 2.0 * vi * cz
    # the rotors' jets and the merged jet (ag_uav.world.wake); lengths along the skewed axis
    z0w = par[_P.S0] * cos_chi
    zmw, bdw = par[_P.SM] * cos_chi, par[_P.BD0] * cos_chi
    # the free jet's speed at the ground, or (option) at the top of the impingement region
    u_g = centreline_speed(a, z0w, zmw, bdw, max(s_g - par[_P.HI], 0.0))
    # surface layer (Monin–Obukhov; neutral: the log law): u* from the wind at the vehicle's
    # height, f_u the mean of u(z) over the layer below the nozzle as a share of it
    w = math.sqrt(wx * wx + wy * wy)
    ust, fu = layer_wind(w, pz, zn, par[_P.Z0], par[_P.INVL])
    return (s_n, s_g, a, z0w, tx, ty, wx, wy, vx, vy, u_g, sin_chi, ust, zn, fu,
            par[_P.IW] * 2.0 * vi, zmw, bdw, _pair(par, thrust, vx - wx, vy - wy, vh2, s_g))


@njit(cache=True, inline="always")
def _pair(par, thrust: float, ax: float, ay: float, vh2: float, z_r: float):
    """The forward-flight wake's trailing vortex pair (option ``_P.VTX`` > 0, its lifetime in
    t*): (wing share, w₀, c, U, lifetime s, lateral unit x, y), :mod:`ag_uav.world.wake`."""
    va = math.sqrt(ax * ax + ay * ay)
    if par[_P.VTX] <= 0.0 or va <= 1e-6:
        return 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0
    _, w0, c, u, tstar = vortex_pair(thrust, par[_P.RHOA], va, par[_P.SPAN], z_r)
    return (wing_share(va, math.sqrt(vh2), par[_P.WINGV]), w0, c, u, par[_P.VTX] * tstar,
            -ay / va, ax / va)


@njit(cache=True, inline="always")
def impinging_fall_time(vt: float, a: float, s_r: float, s_m: float, bd0: float, s1: float,
                        s2: float, h_i: float) -> float:
    """Fall time from depth s1 to the ground at s2 through a jet that impinges on it: the free
    jet (:func:`fall_time`) down to the impingement region's top s_i = s2 − h_i, then the
    region's stagnation flow, whose downward speed falls linearly from the free jet's u_i to 0 at
    the ground (w = u_i z / h over the region's height h = s2 − max(s_i, s1) above it), so
    dz/dt = −(v_t + u_i z / h), so t = (h / u_i) ln(1 + u_i / v_t) from z = h (a nozzle inside
    the region: u_i scaled by h / h_i). The region's height h_i ≈ 1.2 jet diameters
    (the deflection zone of an impinging round jet: Zuckerman & Lior 2006, Adv. Heat Transfer
    39:565, after Viskanta 1993)."""
    si = s2 - h_i
    t = 0.0
    if si > s1:
        t = fall_time(vt, a, s_r, s_m, bd0, s1, si)
    else:
        si = s1
    h = s2 - si
    ui = centreline_speed(a, s_r, s_m, bd0, max(s2 - h_i, 0.0)) * h / h_i
    if ui <= 1e-9:
        return t + h / vt
    return t + h / ui * math.log1p(ui / vt)


@njit(cache=True, inline="always")
def wall_jet(beta: float, r_j: float, st50: float, tp: float, vt: float, u_g: float
             ) -> tuple[float, float, float]:
    """The radial wall jet of the impinging jet (Glauert 1956; Poreh, Tsuei & Cermak 1967):
    thickness δ(r) = β r (β ≈ 0.098, the half-velocity thickness's growth), speed u_g r_j / r
    beyond the impingement radius r_j (the merged jet's, √n D / 2). A droplet that
    turns with it (share St₅₀² / (St_g² + St₅₀²), St_g = τ_p u_g / r_j, Marple & Liu 1974)
    settles through the layer δ_j = β r_j in t_s = δ_j / v_t while riding dr/dt = u_g r_j / r,
    so it travels r_s = √(r_j² + 2 u_g r_j t_s) − r_j; its ring projected on a line has the
    variance r_s²/2. Returns (ride share, δ_j, variance)."""
    ride = 1.0
    if st50 > 0.0:
        st_g = tp * u_g / r_j
        ride = st50 * st50 / (st_g * st_g + st50 * st50)
    dj = beta * r_j
    rs = math.sqrt(r_j * r_j + 2.0 * u_g * r_j * dj / vt) - r_j
    return ride, dj, 0.5 * rs * rs


@njit(cache=True, inline="always")
def _release_var(par, k: int) -> float:
    """Class ``k``'s release variance on each horizontal axis: the nozzle sheet's σ₀² and a
    rotary atomiser's throw to a ring of radius r_t, r_t² / 2 (0 for nozzles;
    :mod:`ag_uav.world.atomiser`)."""
    return par[_P.SIG0] ** 2 + par[int(par[_P.O_THR]) + k]


@njit(cache=True, inline="always")
def _vortex_part(par, k: int, vt: float, tp: float, h_n: float, wx: float, wy: float,
                 vx: float, vy: float, pair_v):
    """The share carried by the trailing vortex pair (option; :mod:`ag_uav.world.wake`): its
    mean offset (the wind over its landing time, the vehicle's velocity relaxing), its variances
    (the nozzle sheet, ambient turbulence, and the pair's outward run across the airspeed:
    lateral unit lx, ly, projected on the axes) and the volume left on landing."""
    fv, w0, c, u, life, lx, ly = pair_v
    if fv <= 0.0:
        return 0.0, 0.0, 0.0, 0.0, 1.0
    t_v, lat = vortex_landing(vt, par[_P.SPAN], h_n, w0, c, u, life)
    rel_v = tp * (1.0 - math.exp(-t_v / tp))
    base = _release_var(par, k) + (par[_P.SIGA] * t_v) ** 2
    return (wx * t_v + (vx - wx) * rel_v, wy * t_v + (vy - wy) * rel_v, base + lat * lx * lx,
            base + lat * ly * ly, _tab_left(par, k, t_v))


@njit(cache=True)
def _class_footprint(par, k: int, env):
    """Class ``k``'s landing law at one tick (offsets from the nozzle; laws in the module
    docstring): the wake part (share, mean, variance, volume left on landing) and the escaped
    part (share, mean, axis variances, fall-time law IG(μ_T, λ_T), airborne share, volume left
    on landing and when counted airborne, mean wind). Slots F_*."""
    (s_n, s_g, a, z0w, tx, ty, wx, wy, vx, vy, u_g, sin_chi, ust, h_n, fu, sig_s, zmw,
     bdw, pair_v) = env
    vt, tp = par[int(par[_P.O_VT]) + k], par[int(par[_P.O_TAUP]) + k]
    s02 = _release_var(par, k)
    # wake: carried down the decaying skewed jet
    tf = fall_time(vt, a, z0w, zmw, bdw, s_n, s_g) if s_g > s_n else 0.0
    if par[_P.HI] > 0.0 and s_g > s_n:
        tf = impinging_fall_time(vt, a, z0w, zmw, bdw, s_n, s_g, par[_P.HI])
    dw = max((s_g - s_n) - vt * tf, 0.0)
    relax = tp * (1.0 - math.exp(-tf / tp))
    wxo = wx * tf + tx * dw + (vx - wx) * relax
    wyo = wy * tf + ty * dw + (vy - wy) * relax
    # optional (St₅₀ > 0), the outwash layer: only what turns with the ground jet rides it; a
    # droplet of impaction Stokes number St_g = τ_p u_g / r_j (r_j the merged jet's radius)
    # strikes the ground with the share η = St_g² / (St_g² + St₅₀²) (round-jet impactor:
    # St₅₀ = 0.24, Marple & Liu 1974, Environ. Sci. Technol. 8(7):648); the share that rides
    # settles through the layer δ in δ / v_t, carried by the log-law wind at δ; the mean and
    # variance are the mixture's
    st50 = par[_P.ST50]
    ride = 1.0
    lvar = 0.0
    delta = par[_P.DELTA]
    ovar = (delta * u_g / vt) ** 2
    if par[_P.WJ] > 0.0:
        ride, delta, ovar = wall_jet(par[_P.WJ], par[_P.RJ], st50, tp, vt, u_g)
    elif st50 > 0.0:
        st_g = tp * u_g / par[_P.RJ]
        ride = st50 * st50 / (st_g * st_g + st50 * st50)
    if st50 > 0.0 or par[_P.WJ] > 0.0:
        w = math.sqrt(wx * wx + wy * wy)
        z0 = par[_P.Z0]
        if w > 0.0 and delta > z0:
            sh = delta / vt * ust / KAPPA * math.log(delta / z0) / w
            wxo += ride * sh * wx
            wyo += ride * sh * wy
            lvar = ride * (1.0 - ride) * sh * sh * w * w
    wvar = (s02 + (par[_P.IW] * dw) ** 2 + ride * ovar
            + (par[_P.SIGA] * tf) ** 2 + lvar)
    wland = _tab_left(par, k, tf)
    fv = pair_v[0]
    vxo, vyo, vvx, vvy, vland = _vortex_part(par, k, vt, tp, h_n, wx, wy, vx, vy, pair_v)
    # escape at the wake's edge: ε₀ sin χ, damped by the droplet's response 1/(1 + St)
    st_k = tp * sig_s / par[_P.ELL]
    esc = par[_P.ESC] * sin_chi / (1.0 + st_k)
    # escaped: settles from the nozzle height through the surface layer (first passage)
    mu_t = _tab_time(par, k, h_n)
    kz = eddy_k(ust, h_n, par[_P.INVL])
    lam_t = h_n * h_n / (2.0 * kz) if kz > 1e-12 else 1e30
    tmax = par[_P.TMAX]
    pair = 1.0 - _ig_cdf(tmax, mu_t, lam_t) if mu_t > 0.0 else 0.0
    ux, uy = fu * wx, fu * wy
    erel = tp * (1.0 - math.exp(-mu_t / tp)) if mu_t > 0.0 else 0.0
    exo = (vx - wx) * erel + ux * mu_t
    eyo = (vy - wy) * erel + uy * mu_t
    u2 = ux * ux + uy * uy
    val = u2 * mu_t ** 3 / lam_t                     # along the wind: X = ū·T, T ~ IG
    vlat = (SIGV_USTAR * ust * mu_t) ** 2            # across it: σ_v·t (Taylor, short times)
    s0e = s02 + 0.5 * par[_P.EDGE] ** 2                # leaves from the wake's edge (a ring)
    if u2 > 0.0:
        ex2 = ux * ux / u2
        evx = s0e + val * ex2 + vlat * (1.0 - ex2)
        evy = s0e + val * (1.0 - ex2) + vlat * ex2
    else:
        evx = evy = s0e + vlat
    rland = _tab_left(par, k, mu_t)
    rair = _tab_left(par, k, tmax)
    return ((1.0 - esc) * (1.0 - fv), wxo, wyo, wvar, wland, esc, exo, eyo, evx, evy, mu_t,
            lam_t, pair, rland, rair, ux, uy, (1.0 - esc) * fv, vxo, vyo, vvx, vvy, vland)


@njit(cache=True)
def class_footprints(par, inp, out) -> None:
    """Every class's :func:`_class_footprint` at the tick ``inp`` into ``out`` (K, _F.SIZE): what
    the drift trial evaluates analytically."""
    env = _environment(par, inp)
    for k in range(int(par[_P.K])):
        f = _class_footprint(par, k, env)
        for j in range(_F.SIZE):
            out[k, j] = f[j]


@njit(cache=True, inline="always")
def _release(par, st, inp, litres: float) -> None:
    """This tick's litres into the window: the litre-weighted input row and each nozzle's
    release moments (the landing law is applied once per window, in :func:`_flush`)."""
    m_n = int(par[_P.M])
    o_noz, o_share = int(par[_P.O_NOZ]), int(par[_P.O_SHARE])
    px, py = inp[0], inp[1]
    st[_S.SIZE] += litres
    for j in range(_I.SIZE):
        st[_S.SIZE + 1 + j] += litres * inp[j]
    o = _S.SIZE + 1 + _I.SIZE
    for m in range(m_n):
        b = o_noz + 3 * m
        # the nozzle's position, p + R n_b (x and y)
        ro = _I.R
        x = (px + inp[ro + RXX] * par[b + X] + inp[ro + RXY] * par[b + Y]
             + inp[ro + RXZ] * par[b + Z])
        y = (py + inp[ro + RYX] * par[b + X] + inp[ro + RYY] * par[b + Y]
             + inp[ro + RYZ] * par[b + Z])
        v = litres * par[o_share + m]
        a = o + m * _M.SIZE
        st[a + _M.V] += v
        st[a + _M.SX] += v * x
        st[a + _M.SY] += v * y
        st[a + _M.SXX] += v * x * x
        st[a + _M.SYY] += v * y * y


@njit(cache=True)
def _row_step(par, inp, st, buf, dt: float, scratch) -> float:
    """One vehicle, one control tick: valve, flow, release, and a flush when the window is full
    or the vehicle crosses the grid's edge. Returns the litres sprayed in the tick."""
    vx, vy = inp[_I.VEL + X], inp[_I.VEL + Y]
    speed = math.sqrt(vx * vx + vy * vy)
    _valve(par, st, dt, inp[_I.CMD] > 0.5, speed)
    litres = _flow(par, st, dt, speed)
    st[_S.LITRES_TICK] = litres
    x0, y0, cell = par[_P.X0], par[_P.Y0], par[_P.CELL]
    inside = (inp[0] >= x0 and inp[0] <= x0 + par[_P.NX] * cell
              and inp[1] >= y0 and inp[1] <= y0 + par[_P.NY] * cell)
    flag = 1.0 if inside else 0.0
    if flag != st[_S.INSIDE] and st[_S.INSIDE] >= 0.0:
        _flush(par, st, buf, scratch, 1.0)       # what was released inside stays inside
    st[_S.INSIDE] = flag
    if litres > 0.0:
        st[_S.SPRAYED] += litres
        _release(par, st, inp, litres)
        st[_S.PENDING] += litres
        if st[_S.TICKS] > 0.0:
            st[_S.TRAVEL] += math.hypot(inp[0] - st[_S.LX], inp[1] - st[_S.LY])
        st[_S.TICKS] += 1.0
        st[_S.LX], st[_S.LY] = inp[0], inp[1]
        if st[_S.TRAVEL] >= par[_P.FLUSHD] or st[_S.TICKS] >= par[_P.FLUSHT]:
            _flush(par, st, buf, scratch, 0.0)
    elif st[_S.PENDING] > 0.0:
        _flush(par, st, buf, scratch, 0.0)
    return litres


@njit(cache=True)
def batch_step(par, inp, st, buf, dt: float, out, scratch) -> None:
    """N vehicles: the row function on every row (bit-identical to N single calls)."""
    for n in range(inp.shape[0]):
        out[n] = _row_step(par, inp[n], st[n], buf[n], dt, scratch)


@njit(cache=True)
def engine_step(arrays, out, dt, rows, vehicles, ia, na) -> None:
    """The engine's rows: row j of this batch (``arrays``: :class:`DepArrays`, ``out`` the
    litres per row) is vehicle ``rows[j]`` of the engine's arrays (``vehicles``:
    :class:`VehicleRows`; the total thrust is the sum of the ``na`` actuator states at column
    ``ia`` of the physics state S). Inactive vehicles are not stepped (as alone, where the
    flight has ended). Both tuples are plain tuples in field order, named again here."""
    d, e = DepArrays(*arrays), VehicleRows(*vehicles)
    par, inp, st, buf, scratch = d.par, d.inp, d.st, d.buf, d.scratch
    p, v, R, S, w, cmd, act = e.p, e.v, e.R, e.S, e.w, e.cmd, e.act
    for j in range(rows.shape[0]):
        i = rows[j]
        out[j] = 0.0
        if not act[i]:
            continue
        r = inp[j]
        for c in range(3):
            r[_I.POS + c] = p[i, c]
            r[_I.VEL + c] = v[i, c]
            r[_I.WIND + c] = w[i, c]
        for c in range(9):
            r[_I.R + c] = R[i, c]
        th = 0.0
        for c in range(na):
            th += S[i, ia + c]
        r[_I.THRUST] = th
        r[_I.CMD] = 1.0 if cmd[i] else 0.0
        out[j] = _row_step(par, r, st[j], buf[j], dt, scratch)


@njit(cache=True)
def levels_sum(buf, offs, nx, ny, nlev, f, out) -> None:
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
def batch_flush(par, st, buf, scratch) -> None:
    for n in range(st.shape[0]):
        _flush(par, st[n], buf[n], scratch, 1.0)



@njit(cache=True)
def row_step_args(arrays, dt, pos, vel, R, thrust, wind, cmd) -> float:
    """:func:`_row_step` from unpacked arrays (fills the packed input row in compiled code);
    ``arrays``: one row's :class:`DepArrays` (a plain tuple in field order)."""
    d = DepArrays(*arrays)
    par, inp, st, buf, scratch = d.par, d.inp, d.st, d.buf, d.scratch
    for j in range(3):
        inp[_I.POS + j] = pos[j]
        inp[_I.VEL + j] = vel[j]
        inp[_I.WIND + j] = wind[j]
    for j in range(9):
        inp[_I.R + j] = R[j]
    inp[_I.THRUST] = thrust
    inp[_I.CMD] = 1.0 if cmd else 0.0
    return _row_step(par, inp, st, buf, dt, scratch)
