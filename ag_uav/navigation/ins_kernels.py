"""The compiled kernels of the INS feedback (:mod:`ag_uav.navigation.ins_feedback`): the truth
ring the sensor models read, the tick's inputs of the bank, and the outputs and score records.

Each kernel's arguments are declared once, by name, as the named tuples below (:class:`Truth`,
:class:`SensorRows`, :class:`BankView`, :class:`Pose`, :class:`Scores`, :class:`Outputs`),
each holding just what its kernel reads. A caller passes each as a plain tuple in field order,
and the kernel names it again (``Truth(*truth)``, no cost in compiled code): numba's
dispatcher types a named tuple of arrays on a slower path than a plain one (about a
microsecond and a half more a call on the 2-core development machine, 2026-11-27), and every
array passed costs its typing at each call, so a group carries no array its kernel does not
read."""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np

from estimators.ins.layout import DG, ERR, GIN, IMU, RIN, STATE
from numkit import Layout, X, Y, Z
from numkit.geometry import (
    RXX,
    RXY,
    RXZ,
    RYX,
    RYY,
    RYZ,
    RZX,
    RZY,
    RZZ,
    quat_log_err,
    quat_to_rot,
    quat_to_rot_flat,
    rot_to_quat,
    rot_to_yaw,
)

from .._jit import njit

__all__ = ["BLOCKS", "ERRORS", "FIX_DUE", "NEES_REC", "NOT_INITIALISED", "NREC", "RING",
           "RING_WIDTH", "SENSOR_PRM", "BankView", "Outputs", "Pose", "Scores", "SensorRows",
           "Truth", "outputs",
           "quad_inv", "quad_inv_at", "radar_rows", "ring_write", "tick_in"]

#: the per-fix score record's columns (``BatchInsFeedback.nees[i, fix, :, row]``): NEES15,
#: the NEES of the position, velocity, attitude, accel-bias and gyro-bias blocks (3 dof each),
#: 1 where the core P was not positive definite (no NEES), the NIS of the fix's position,
#: velocity and heading updates, the gate's verdict on the position (0 fused, 1 rejected,
#: 2 rejected and reset to the receiver)
NEES_REC = Layout("nees15 pos vel att ba bg notpd nisp nisv nisy gate")
NR = NEES_REC.at
NREC = NEES_REC.size
#: the NEES blocks' names (summary keys nees_<name>_mean), in record order from ``NR.POS``
BLOCKS = ("pos", "vel", "att", "ba", "bg")
#: the per-tick error record's columns (``BatchInsFeedback.err[k, i, :, row]``): horizontal
#: position, 3-D velocity, tilt and yaw errors
ERRORS = Layout("herr verr tilt yaw")
ER = ERRORS.at

#: the INS's nominal state and its 15-state error (the order of ``P``) and the bank's IMU input
#: row: the bank's own layouts (:mod:`estimators.ins.layout` ``STATE``, ``ERR``, ``IMU``)
XN, XE, IM = STATE.at, ERR.at, IMU.at

#: the truth ring's row per tick: antenna position, antenna velocity, heading, R (row-major),
#: slant range, p, v, the walked IMU biases (accel, gyro; contiguous, as the IMU walks them)
RING = Layout("ant_p:3 ant_v:3 yaw R:9 range p:3 v:3 ba:3 bg:3")
RG = RING.at
RING_WIDTH = RING.size
#: the sensor offsets (``SensorRows.prm``): antenna, radar, heading baseline (body axes, m),
#: the radar's cos(max tilt) and its max range (m)
SENSOR_PRM = Layout("r_ant:3 r_rad:3 r_b:3 cos_max r_max")
SP = SENSOR_PRM.at


#: the bank's GNSS and radar input rows and its diagnostics (:mod:`estimators.ins.layout`;
#: ``BatchINS.nis`` is the diagnostics' head: the last NIS of position, velocity, heading)
GN, RN, DN = GIN.at, RIN.at, DG.at

#: :func:`tick_in`'s return: a bit set when some vehicle has a fix due (its receiver runs)
FIX_DUE = 1
#: :func:`tick_in`'s return: a bit set when an active vehicle is not initialised yet
NOT_INITIALISED = 2


class Truth(NamedTuple):
    """The engine's state of the tick (N vehicles), read by the sensor models and the scores
    only: position ``p`` (N, 3), velocity ``v`` (N, 3), attitude ``R`` (N, 9, row-major), body
    rate ``w`` (N, 3), ``act`` (N,) the active vehicles, and the IMU's reading: specific force
    ``f_m`` (N, 3) and rate ``om`` (N, 3)."""

    p: np.ndarray
    v: np.ndarray
    R: np.ndarray
    w: np.ndarray
    act: np.ndarray
    f_m: np.ndarray
    om: np.ndarray


class SensorRows(NamedTuple):
    """The feedback's per-vehicle sensor state: the truth ``ring`` (N, D + 1,
    :data:`RING_WIDTH`), the sensor offsets ``prm`` (antenna, radar, heading baseline, the
    radar's cos(max tilt) and range), the walked IMU biases of the block ``btru`` (N, blk, 6),
    the bank's inputs of the tick ``imu`` (N, 6), ``gnss`` (N, 15) and ``radar`` (N, 3), each
    receiver's next fix time ``next_t`` (N,), ``init`` (N,) the initialised vehicles and
    ``due`` (N,) those with a fix due."""

    ring: np.ndarray
    prm: np.ndarray
    btru: np.ndarray
    imu: np.ndarray
    gnss: np.ndarray
    radar: np.ndarray
    next_t: np.ndarray
    init: np.ndarray
    due: np.ndarray


class BankView(NamedTuple):
    """What :func:`outputs` reads of the bank (:class:`estimators.ins.BatchINS`, rows =
    vehicles × rules): the output nominal ``x_out`` (rows, 16), the core ``x_core`` and ``P`` at
    the fusion horizon, the last fix's NIS ``nis`` (rows, 4: position, velocity, heading,
    radar), the gate's verdict on its position ``gate`` (rows,) and each row's core tick
    ``core_tick``."""

    x_out: np.ndarray
    x_core: np.ndarray
    P: np.ndarray
    nis: np.ndarray
    gate: np.ndarray
    core_tick: np.ndarray


class Pose(NamedTuple):
    """What :func:`outputs` reads of the engine's state: ``p``, ``v``, ``R`` and ``act`` as in
    :class:`Truth`."""

    p: np.ndarray
    v: np.ndarray
    R: np.ndarray
    act: np.ndarray


class Scores(NamedTuple):
    """What :func:`outputs` reads and writes of the feedback's rows: ``ring``, ``init``,
    ``gnss`` and ``imu`` as in :class:`SensorRows`, the considered GNSS variance ``cvar``
    (N, 3), and the score records: the errors ``err`` (ticks, N, 4, rules: horizontal,
    velocity, tilt, yaw), each fix's tick ``fix_k`` (N, fixes), the per-fix record ``nees``
    (N, fixes, :data:`NREC`, rules; :data:`NEES_REC`), the fixes recorded ``n_fix`` (N,) and
    the tick before each vehicle's initialisation ``k0`` (N,)."""

    ring: np.ndarray
    init: np.ndarray
    gnss: np.ndarray
    imu: np.ndarray
    cvar: np.ndarray
    err: np.ndarray
    fix_k: np.ndarray
    nees: np.ndarray
    n_fix: np.ndarray
    k0: np.ndarray


class Outputs(NamedTuple):
    """What the controller flies on, per vehicle: ``p``, ``v`` (N, 3), ``R`` (N, 9) and the
    bias-corrected body rate ``w`` (N, 3)."""

    p: np.ndarray
    v: np.ndarray
    R: np.ndarray
    w: np.ndarray


@njit(cache=True)
def ring_write(tr, s, k, j):  # pragma: no cover
    """Tick k's sensor truth per vehicle (row ``k % B``): the antenna position p + R r_ant
    (0:3), the antenna velocity v + R(ω × r_ant) (3:6), the dual-antenna heading
    ψ = atan2(b_y, b_x) − atan2(r_b,y, r_b,x) with b = R r_b (6), R (7:16), the radar's slant
    range ρ = s_z / R₂₂ with s = p + R r_rad over the ground z = 0 (NaN beyond the radar's
    cone or range), p, v, the IMU's walked biases ``btru[i, j]`` (:data:`RING`'s fields);
    ``tr``: :class:`Truth`, ``s``: :class:`SensorRows`."""
    p, v, R, w, act = tr.p, tr.v, tr.R, tr.w, tr.act
    ring, prm, bt = s.ring, s.prm, s.btru
    B = ring.shape[1]
    ra = prm[SP.R_ANT:SP.R_ANT_END]
    rr = prm[SP.R_RAD:SP.R_RAD_END]
    rb = prm[SP.R_B:SP.R_B_END]
    psi_b = math.atan2(rb[Y], rb[X])   # the baseline's body azimuth
    for i in range(p.shape[0]):
        if not act[i]:
            continue
        r = ring[i, k % B]
        wx = w[i, Y] * ra[Z] - w[i, Z] * ra[Y]   # ω × r_ant
        wy = w[i, Z] * ra[X] - w[i, X] * ra[Z]
        wz = w[i, X] * ra[Y] - w[i, Y] * ra[X]
        for a in range(3):
            R0, R1, R2 = R[i, RXX + 3 * a], R[i, RXY + 3 * a], R[i, RXZ + 3 * a]  # row a
            r[RG.ANT_P + a] = p[i, a] + R0 * ra[X] + R1 * ra[Y] + R2 * ra[Z]   # p + R r_ant
            r[RG.ANT_V + a] = v[i, a] + R0 * wx + R1 * wy + R2 * wz   # v + R(ω × r_ant)
            r[RG.P + a] = p[i, a]
            r[RG.V + a] = v[i, a]
        # b = R r_b (its x and y rows)
        bx = R[i, RXX] * rb[X] + R[i, RXY] * rb[Y] + R[i, RXZ] * rb[Z]
        by = R[i, RYX] * rb[X] + R[i, RYY] * rb[Y] + R[i, RYZ] * rb[Z]
        psi = math.atan2(by, bx) - psi_b
        r[RG.YAW] = math.atan2(math.sin(psi), math.cos(psi))
        for m in range(9):
            r[RG.R + m] = R[i, m]
        for m in range(6):   # b_a then b_g
            r[RG.BA + m] = bt[i, j, m]
        c = R[i, RZZ]
        # s_z = (p + R r_rad)_z
        sz = p[i, Z] + R[i, RZX] * rr[X] + R[i, RZY] * rr[Y] + R[i, RZZ] * rr[Z]
        rho = sz / c if c > 0 else np.nan
        r[RG.RANGE] = rho if (c >= prm[SP.COS_MAX] and rho <= prm[SP.R_MAX]) else np.nan


@njit(cache=True)
def tick_in(truth, rows, k, t, j):  # pragma: no cover
    """The tick's truth ring row (:func:`ring_write`), the IMU rows (f̃, ω̃), no fix and no
    radar yet, the vehicles with a fix due (``truth``: :class:`Truth`, ``rows``:
    :class:`SensorRows`, as plain tuples; ``j``: the tick's place in the bias block); returns
    :data:`FIX_DUE` if any fix is due | :data:`NOT_INITIALISED` if an active vehicle is not
    initialised."""
    tr = Truth(*truth)
    s = SensorRows(*rows)
    ring_write(tr, s, k, j)
    act, imu, gnss, radar, due = tr.act, s.imu, s.gnss, s.radar, s.due
    flags = 0
    for i in range(act.shape[0]):
        for a in range(3):
            imu[i, IM.F + a] = tr.f_m[i, a]
            imu[i, IM.W + a] = tr.om[i, a]
        gnss[i, GN.AGE] = np.nan
        radar[i, RN.RANGE] = np.nan
        due[i] = act[i] and t >= s.next_t[i] - 1e-9
        if due[i]:
            flags |= FIX_DUE
        if act[i] and not s.init[i]:
            flags |= NOT_INITIALISED
    return flags


@njit(cache=True)
def radar_rows(ring, slot, act, noise, noise_i, sig, radar, range_last):  # pragma: no cover
    """The radar's slant range of every active vehicle: the truth ring's range (``RG.RANGE``
    of row ``slot``) plus ``sig`` times the vehicle's next standard normal, ``noise[i,
    noise_i[i]]`` (its own stream's block), into ``radar[i] = (range, sig², age 0)`` and
    ``range_last[i]`` (NaN: a dropout). Returns 0, or (nothing done) the number of active
    vehicles whose block is used up (the caller draws the next block and calls again)."""
    need = 0
    for i in range(act.shape[0]):
        if act[i] and noise_i[i] >= noise.shape[1]:
            need += 1
    if need:
        return need
    for i in range(act.shape[0]):
        if not act[i]:
            continue
        j = noise_i[i]
        noise_i[i] = j + 1
        z = ring[i, slot, RG.RANGE] + sig * noise[i, j]   # ρ̃ = ρ + σ n
        radar[i, RN.RANGE] = z
        radar[i, RN.VAR] = sig * sig
        radar[i, RN.AGE] = 0.0
        range_last[i] = z
    return 0


@njit(cache=True)
def nees15(x, P, tr, q_t, dth, e, L, y):  # pragma: no cover
    """eᵀ P⁻¹ e of one row's core state against the truth ``tr`` (a ring row): e = [p, v,
    Log(q̂* ⊗ q), b_a, b_g] true − estimated, bias truth = the IMU's walked biases of that
    tick (the ring's ``ba``, ``bg``)."""
    if not np.isfinite(tr[RG.P]):
        e[XE.POS] = np.nan
        return np.nan
    rot_to_quat(tr[RG.R:RG.R_END], q_t)
    quat_log_err(x[XN.QUAT:XN.QUAT_END], q_t, dth)
    for a in range(3):
        e[XE.POS + a] = tr[RG.P + a] - x[XN.POS + a]
        e[XE.VEL + a] = tr[RG.V + a] - x[XN.VEL + a]
        e[XE.THETA + a] = dth[a]
        e[XE.BA + a] = tr[RG.BA + a] - x[XN.BA + a]
        e[XE.BG + a] = tr[RG.BG + a] - x[XN.BG + a]
    return quad_inv(P, e, e.shape[0], L, y)


@njit(cache=True)
def quad_inv_at(P, e, o, n, L, y, Pb, eb):  # pragma: no cover
    """:func:`quad_inv` of the diagonal block ``P[o:o+n, o:o+n]`` with ``e[o:o+n]`` (the
    block's own NEES: its marginal covariance); ``Pb`` (≥ n, ≥ n), ``eb`` (≥ n): scratch."""
    for a in range(n):
        eb[a] = e[o + a]
        for b in range(n):
            Pb[a, b] = P[o + a, o + b]
    return quad_inv(Pb, eb, n, L, y)


@njit(cache=True)
def quad_inv(P, e, n, L, y):  # pragma: no cover
    """eᵀ P⁻¹ e over the leading ``n`` × ``n`` block of a symmetric positive definite ``P``:
    Cholesky P = L Lᵀ into the scratch ``L``, forward substitution L y = e (scratch ``y``),
    then yᵀ y. Allocates nothing; NaN when the block is not positive definite."""
    for j in range(n):
        d = P[j, j]
        for m in range(j):
            d -= L[j, m] * L[j, m]
        if not d > 0.0:
            return np.nan
        L[j, j] = math.sqrt(d)
        for i in range(j + 1, n):
            s = P[i, j]
            for m in range(j):
                s -= L[i, m] * L[j, m]
            L[i, j] = s / L[j, j]
    q = 0.0
    for i in range(n):
        s = e[i]
        for m in range(i):
            s -= L[i, m] * y[m]
        y[i] = s / L[i, i]
        q += y[i] * y[i]
    return q


@njit(cache=True)
def row_errors(x, p, v, Rt, yaw_t, Re, out):  # pragma: no cover
    """Horizontal position, 3-D velocity, tilt (angle between the body z axes) and yaw errors
    of one row's output against the truth of the tick (``Rt`` row-major, its yaw
    ``yaw_t = atan2(R₁₀, R₀₀)``, the same for every row of a vehicle); ``Re`` (3, 3):
    scratch; ``out``: :data:`ERRORS`."""
    quat_to_rot(x[XN.QUAT:XN.QUAT_END], Re)
    dx, dy = x[XN.POS + X] - p[X], x[XN.POS + Y] - p[Y]
    out[ER.HERR] = math.sqrt(dx * dx + dy * dy)
    s = 0.0
    for a in range(3):
        s += (x[XN.VEL + a] - v[a]) ** 2
    out[ER.VERR] = math.sqrt(s)   # |v̂ − v|
    # cos tilt = ẑ_b · z_b: the third columns of R̂ and R
    cz = Re[X, Z] * Rt[RXZ] + Re[Y, Z] * Rt[RYZ] + Re[Z, Z] * Rt[RZZ]
    out[ER.TILT] = math.acos(min(1.0, max(-1.0, cz)))
    ye = math.atan2(Re[Y, X], Re[X, X]) - yaw_t
    out[ER.YAW] = abs(math.atan2(math.sin(ye), math.cos(ye)))


@njit(cache=True, nogil=True)
def outputs(bank, pose, scores, out, k, nr, flown):  # pragma: no cover
    """The flown row's (p, v, R) per vehicle and the bias-corrected rates ω̃ − b̂_g (the raw
    gyro before the filter is initialised); per row the tick's errors (:func:`row_errors`)
    and, at a fix, the record ``nees[i, fix, :, row]`` (:data:`NEES_REC`): the NEES of the
    core's 15-state error against the truth of the core's tick (:func:`nees15`), of each
    3-state block on its marginal covariance, and the fix's NIS (position, velocity, heading;
    NaN for a part not in the fix). The covariance scored is the one the INS reports: its P
    plus the considered GNSS variance ``cvar`` on the position (zero unless "consider").
    ``bank``: :class:`BankView`, ``pose``: :class:`Pose`, ``scores``: :class:`Scores`,
    ``out``: :class:`Outputs` (plain tuples); ``nr`` rules a vehicle, ``flown`` the flown
    rule's index (< 0: none)."""
    bk, po, sc, o = BankView(*bank), Pose(*pose), Scores(*scores), Outputs(*out)
    xo, xc, P, nis, gate, core = bk.x_out, bk.x_core, bk.P, bk.nis, bk.gate, bk.core_tick
    act, p, v, Rt = po.act, po.p, po.v, po.R
    ring, init, gnss, imu, cvar = sc.ring, sc.init, sc.gnss, sc.imu, sc.cvar
    err, fix_k, nees, n_fix, k0 = sc.err, sc.fix_k, sc.nees, sc.n_fix, sc.k0
    p_out, v_out, R_out, w_out = o.p, o.v, o.R, o.w
    B = ring.shape[1]
    Re = np.empty((3, 3))
    q_t = np.empty(4)
    dth = np.empty(3)
    e = np.empty(XE.SIZE)
    oe = np.empty(ER.SIZE)
    L, y = np.empty((15, 15)), np.empty(15)
    Pb, eb = np.empty((3, 3)), np.empty(3)
    Pc = np.empty((15, 15))
    for i in range(act.shape[0]):
        if not act[i]:
            continue
        for a in range(3):
            w_out[i, a] = imu[i, IM.W + a]
        if not init[i]:
            continue
        if flown >= 0:
            x = xo[i * nr + flown]
            for a in range(3):
                p_out[i, a] = x[XN.POS + a]
                v_out[i, a] = x[XN.VEL + a]
                w_out[i, a] = imu[i, IM.W + a] - x[XN.BG + a]   # ω̃ − b̂_g
            quat_to_rot_flat(x[XN.QUAT:XN.QUAT_END], R_out[i])
        rec = n_fix[i]
        at_fix = np.isfinite(gnss[i, GN.AGE]) and rec < fix_k.shape[1]
        if at_fix:
            fix_k[i, rec] = k
            n_fix[i] = rec + 1
        yaw_t = rot_to_yaw(Rt[i])
        for j in range(nr):
            row = i * nr + j
            row_errors(xo[row], p[i], v[i], Rt[i], yaw_t, Re, oe)
            for c in range(ER.SIZE):
                err[k, i, c, j] = oe[c]
            if at_fix:
                tr = ring[i, (k0[i] + core[row]) % B]
                rc = nees[i, rec, :, j]
                for a in range(15):  # loops: numba's slice assignment compiles slowly
                    for b in range(15):
                        Pc[a, b] = P[row, a, b]
                for a in range(3):
                    Pc[a, a] += cvar[i, a]
                rc[NR.NEES15] = nees15(xc[row], Pc, tr, q_t, dth, e, L, y)
                rc[NR.NISP] = nis[row, DN.NISP]
                rc[NR.NISV] = nis[row, DN.NISV]
                rc[NR.NISY] = nis[row, DN.NISY]
                rc[NR.GATE] = gate[row]
                if np.isfinite(e[XE.POS]):   # each 3-state block alone (3 dof)
                    for b in range(5):   # block b of the error state: δp, δv, δθ, δb_a, δb_g
                        rc[NR.POS + b] = quad_inv_at(Pc, e, 3 * b, eb.shape[0], L, y, Pb, eb)
                    rc[NR.NOTPD] = 0.0 if np.isfinite(rc[NR.NEES15]) else 1.0
