"""The compiled row kernels of the spray deposition: the packed parameter, state and input
layouts, and the valve, flow, release, footprint and splat of one vehicle's tick, called alike
by one vehicle and by the batch (sources in :mod:`ag_uav.world.deposition`)."""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np

from .._jit import njit
from .droplets import N_TAB
from .surface_layer import eddy_k, layer_wind
from .wake import centreline_speed, fall_time, vortex_landing, vortex_pair, wing_share


class DepArrays(NamedTuple):
    """A deposition batch's arrays, declared once: the packed parameters ``par``, the input
    rows ``inp`` (N, INPUT_WIDTH), the state rows ``st``, the dose buffers ``buf`` and the
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

#: columns of one input row: pos 3, vel 3, R 9 (row-major), thrust, wind 3, cmd
INPUT_WIDTH = 20

# header slots of the parameter vector (float64); arrays follow at the offsets stored in it
(P_RATE, P_SWATH, P_VMIN, P_DON, P_DOFF, P_OFFNOW, P_TAU, P_RHOA, P_AREA, P_S0, P_ROTZ, P_IW,
 P_DELTA, P_SIGA, P_SIG0, P_X0, P_Y0, P_CELL, P_NX, P_NY, P_NLEV, P_FLUSHD, P_FLUSHT, P_M, P_K,
 P_MERGE, P_O_NOZ, P_O_SHARE, P_O_VT, P_O_TAUP, P_O_FRAC, P_O_LEV, P_NOZC, P_QMIN, P_ESC,
 P_ELL, P_Z0, P_TMAX, P_O_TT, P_O_H, P_O_R, P_EDGE, P_SM, P_BD0, P_RJ, P_ST50, P_INVL,
 P_WJ, P_HI, P_SPAN, P_VTX, P_WINGV) = range(52)
P_HEADER = 52
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
 F_RLAND, F_RAIR, F_UX, F_UY, F_VORT, F_VX, F_VY, F_VVX, F_VVY, F_VLAND) = range(23)
NFOOT = 23
#: the parts of a class that land apart: the wake (the jet and its outwash), the escaped, and the
#: forward-flight wake's trailing vortex pair (an option, share 0 when off)
NPART = 3


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


@njit(cache=True, inline="always")
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


@njit(cache=True, inline="always")
def _part(f, part: int, vw: float, land_e: float, vv: float):
    """(share, mean x, mean y, variance x, variance y) of a class's part: 0 the wake, 1 the
    escaped part that lands, 2 the trailing vortex pair's."""
    if part == 0:
        return vw, f[F_WX], f[F_WY], f[F_WVAR], f[F_WVAR]
    if part == 1:
        return land_e, f[F_EX], f[F_EY], f[F_EVX], f[F_EVY]
    return vv, f[F_VX], f[F_VY], f[F_VVX], f[F_VVY]


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
            vw, ve, vv = vk * f[F_WAKE], vk * f[F_ESC], vk * f[F_VORT]
            land_e = ve * (1.0 - f[F_PAIR])
            air = ve * f[F_PAIR]
            st[S_AIR] += vtot * air
            st[S_EVAP] += vtot * (vw * (1.0 - f[F_WLAND]) + land_e * (1.0 - f[F_RLAND])
                                  + air * (1.0 - f[F_RAIR]) + vv * (1.0 - f[F_VLAND]))
            for part in range(NPART):
                share, ox, oy, kvx, kvy = _part(f, part, vw, land_e, vv)
                if share <= 0.0:
                    continue
                if math.sqrt(0.5 * (kvx + kvy)) >= merge_r:
                    q = o + m_n * NACC + (NPART * k + part) * NSLOW
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


@njit(cache=True, inline="always")
def _flush_wide(par, st, buf, scratch, force: float) -> None:
    """The wide parts (nozzles merged) gather over several windows: each is splatted once the
    spread of its release points reaches a quarter of its kernel's variance (so the smear
    changes its shape by little; mean and variance are matched exactly), or when ``force`` > 0
    (the end, the vehicle crossing the grid's edge)."""
    m_n, k_n = int(par[P_M]), int(par[P_K])
    drift = st[S_INSIDE] > 0.5
    base = S_ACC + 1 + INPUT_WIDTH + m_n * NACC
    for i in range(NPART * k_n):
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


@njit(cache=True, inline="always")
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


@njit(cache=True, inline="always")
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


@njit(cache=True, inline="always")
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
    wake (speed a, skew, the rotors' core, the merged jet), the wind and the surface layer.
    Laws in the module docstring. Returns (s_n, s_g, a, z0w, tx, ty, wx, wy, vx, vy, u_g, sin χ,
    u*, h_n, f_u, σ_s, s_m cos χ, B D_0 cos χ, the trailing pair: (wing share, w₀, c, U,
    lifetime, lateral unit x, y) of :mod:`ag_uav.world.wake`)."""
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
    # the rotors' jets and the merged jet (ag_uav.world.wake); lengths along the skewed axis
    z0w = par[P_S0] * cos_chi
    zmw, bdw = par[P_SM] * cos_chi, par[P_BD0] * cos_chi
    # the free jet's speed at the ground, or (option) at the top of the impingement region
    u_g = centreline_speed(a, z0w, zmw, bdw, max(s_g - par[P_HI], 0.0))
    # surface layer (Monin–Obukhov; neutral: the log law): u* from the wind at the vehicle's
    # height, f_u the mean of u(z) over the layer below the nozzle as a share of it
    w = math.sqrt(wx * wx + wy * wy)
    ust, fu = layer_wind(w, pz, zn, par[P_Z0], par[P_INVL])
    return (s_n, s_g, a, z0w, tx, ty, wx, wy, vx, vy, u_g, sin_chi, ust, zn, fu,
            par[P_IW] * 2.0 * vi, zmw, bdw, _pair(par, thrust, vx - wx, vy - wy, vh2, s_g))


@njit(cache=True, inline="always")
def _pair(par, thrust: float, ax: float, ay: float, vh2: float, z_r: float):
    """The forward-flight wake's trailing vortex pair (option ``P_VTX`` > 0, its lifetime in
    t*): (wing share, w₀, c, U, lifetime s, lateral unit x, y), :mod:`ag_uav.world.wake`."""
    va = math.sqrt(ax * ax + ay * ay)
    if par[P_VTX] <= 0.0 or va <= 1e-6:
        return 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0
    _, w0, c, u, tstar = vortex_pair(thrust, par[P_RHOA], va, par[P_SPAN], z_r)
    return (wing_share(va, math.sqrt(vh2), par[P_WINGV]), w0, c, u, par[P_VTX] * tstar,
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
def _vortex_part(par, k: int, vt: float, tp: float, h_n: float, wx: float, wy: float,
                 vx: float, vy: float, pair_v):
    """The share carried by the trailing vortex pair (option; :mod:`ag_uav.world.wake`): its
    mean offset (the wind over its landing time, the vehicle's velocity relaxing), its variances
    (the nozzle sheet, ambient turbulence, and the pair's outward run across the airspeed:
    lateral unit lx, ly, projected on the axes) and the volume left on landing."""
    fv, w0, c, u, life, lx, ly = pair_v
    if fv <= 0.0:
        return 0.0, 0.0, 0.0, 0.0, 1.0
    t_v, lat = vortex_landing(vt, par[P_SPAN], h_n, w0, c, u, life)
    rel_v = tp * (1.0 - math.exp(-t_v / tp))
    base = par[P_SIG0] ** 2 + (par[P_SIGA] * t_v) ** 2
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
    vt, tp = par[int(par[P_O_VT]) + k], par[int(par[P_O_TAUP]) + k]
    sig0 = par[P_SIG0]
    # wake: carried down the decaying skewed jet
    tf = fall_time(vt, a, z0w, zmw, bdw, s_n, s_g) if s_g > s_n else 0.0
    if par[P_HI] > 0.0 and s_g > s_n:
        tf = impinging_fall_time(vt, a, z0w, zmw, bdw, s_n, s_g, par[P_HI])
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
    st50 = par[P_ST50]
    ride = 1.0
    lvar = 0.0
    delta = par[P_DELTA]
    ovar = (delta * u_g / vt) ** 2
    if par[P_WJ] > 0.0:
        ride, delta, ovar = wall_jet(par[P_WJ], par[P_RJ], st50, tp, vt, u_g)
    elif st50 > 0.0:
        st_g = tp * u_g / par[P_RJ]
        ride = st50 * st50 / (st_g * st_g + st50 * st50)
    if st50 > 0.0 or par[P_WJ] > 0.0:
        w = math.sqrt(wx * wx + wy * wy)
        z0 = par[P_Z0]
        if w > 0.0 and delta > z0:
            sh = delta / vt * ust / KAPPA * math.log(delta / z0) / w
            wxo += ride * sh * wx
            wyo += ride * sh * wy
            lvar = ride * (1.0 - ride) * sh * sh * w * w
    wvar = (sig0 * sig0 + (par[P_IW] * dw) ** 2 + ride * ovar
            + (par[P_SIGA] * tf) ** 2 + lvar)
    wland = _tab_left(par, k, tf)
    fv = pair_v[0]
    vxo, vyo, vvx, vvy, vland = _vortex_part(par, k, vt, tp, h_n, wx, wy, vx, vy, pair_v)
    # escape at the wake's edge: ε₀ sin χ, damped by the droplet's response 1/(1 + St)
    st_k = tp * sig_s / par[P_ELL]
    esc = par[P_ESC] * sin_chi / (1.0 + st_k)
    # escaped: settles from the nozzle height through the surface layer (first passage)
    mu_t = _tab_time(par, k, h_n)
    kz = eddy_k(ust, h_n, par[P_INVL])
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
    return ((1.0 - esc) * (1.0 - fv), wxo, wyo, wvar, wland, esc, exo, eyo, evx, evy, mu_t,
            lam_t, pair, rland, rair, ux, uy, (1.0 - esc) * fv, vxo, vyo, vvx, vvy, vland)


@njit(cache=True)
def class_footprints(par, inp, out) -> None:
    """Every class's :func:`_class_footprint` at the tick ``inp`` into ``out`` (K, NFOOT): what
    the drift trial evaluates analytically."""
    env = _environment(par, inp)
    for k in range(int(par[P_K])):
        f = _class_footprint(par, k, env)
        for j in range(NFOOT):
            out[k, j] = f[j]


@njit(cache=True, inline="always")
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
        inp[j] = pos[j]
        inp[3 + j] = vel[j]
        inp[16 + j] = wind[j]
    for j in range(9):
        inp[6 + j] = R[j]
    inp[15] = thrust
    inp[19] = 1.0 if cmd else 0.0
    return _row_step(par, inp, st, buf, dt, scratch)
