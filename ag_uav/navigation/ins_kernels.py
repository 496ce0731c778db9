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

from numkit.geometry import quat_log_err, quat_to_rot, quat_to_rot_flat, rot_to_quat, rot_to_yaw

from .._jit import njit

__all__ = ["BLOCKS", "FIX_DUE", "NOT_INITIALISED", "NREC", "RING_WIDTH", "BankView", "Outputs",
           "Pose", "Scores", "SensorRows", "Truth", "outputs", "quad_inv", "quad_inv_at",
           "radar_rows", "ring_write", "tick_in"]

#: the per-fix score record's columns (``BatchInsFeedback.nees[i, fix, :, row]``): NEES15,
#: the NEES of the position, velocity, attitude, accel-bias and gyro-bias blocks (3 dof each),
#: 1 where the core P was not positive definite (no NEES), the NIS of the fix's position,
#: velocity and heading updates, the gate's verdict on the position (0 fused, 1 rejected,
#: 2 rejected and reset to the receiver)
(N_NEES15, N_POS, N_VEL, N_ATT, N_BA, N_BG, N_NOTPD, N_NISP, N_NISV, N_NISY,
 N_GATE) = range(11)
NREC = 11
#: the NEES blocks' names (summary keys nees_<name>_mean), in record order from N_POS
BLOCKS = ("pos", "vel", "att", "ba", "bg")

#: ring layout per tick: antenna position, antenna velocity, heading, R, slant range, p, v,
#: the walked IMU biases (accel, gyro)
RING_WIDTH = 29

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
    (N, fixes, :data:`NREC`, rules; columns ``N_*``), the fixes recorded ``n_fix`` (N,) and
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
    range ρ = s_z / R₂₂ with s = p + R r_rad over the ground z = 0 (16; NaN beyond the radar's
    cone or range), p (17:20), v (20:23), the IMU's walked biases ``btru[i, j]`` (23:29);
    ``tr``: :class:`Truth`, ``s``: :class:`SensorRows`."""
    p, v, R, w, act = tr.p, tr.v, tr.R, tr.w, tr.act
    ring, prm, bt = s.ring, s.prm, s.btru
    B = ring.shape[1]
    ra = prm[0:3]
    rr = prm[3:6]
    rb = prm[6:9]
    psi_b = math.atan2(rb[1], rb[0])   # the baseline's body azimuth
    for i in range(p.shape[0]):
        if not act[i]:
            continue
        r = ring[i, k % B]
        wx = w[i, 1] * ra[2] - w[i, 2] * ra[1]
        wy = w[i, 2] * ra[0] - w[i, 0] * ra[2]
        wz = w[i, 0] * ra[1] - w[i, 1] * ra[0]
        for a in range(3):
            R0, R1, R2 = R[i, 3 * a], R[i, 3 * a + 1], R[i, 3 * a + 2]
            r[a] = p[i, a] + R0 * ra[0] + R1 * ra[1] + R2 * ra[2]
            r[3 + a] = v[i, a] + R0 * wx + R1 * wy + R2 * wz
            r[17 + a] = p[i, a]
            r[20 + a] = v[i, a]
        bx = R[i, 0] * rb[0] + R[i, 1] * rb[1] + R[i, 2] * rb[2]
        by = R[i, 3] * rb[0] + R[i, 4] * rb[1] + R[i, 5] * rb[2]
        psi = math.atan2(by, bx) - psi_b
        r[6] = math.atan2(math.sin(psi), math.cos(psi))
        for m in range(9):
            r[7 + m] = R[i, m]
        for m in range(6):
            r[23 + m] = bt[i, j, m]
        c = R[i, 8]
        sz = p[i, 2] + R[i, 6] * rr[0] + R[i, 7] * rr[1] + R[i, 8] * rr[2]
        rho = sz / c if c > 0 else np.nan
        r[16] = rho if (c >= prm[9] and rho <= prm[10]) else np.nan


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
            imu[i, a] = tr.f_m[i, a]
            imu[i, 3 + a] = tr.om[i, a]
        gnss[i, 0] = np.nan
        radar[i, 0] = np.nan
        due[i] = act[i] and t >= s.next_t[i] - 1e-9
        if due[i]:
            flags |= FIX_DUE
        if act[i] and not s.init[i]:
            flags |= NOT_INITIALISED
    return flags


@njit(cache=True)
def radar_rows(ring, slot, act, noise, noise_i, sig, radar, range_last):  # pragma: no cover
    """The radar's slant range of every active vehicle: the truth ring's range (column 16 of
    row ``slot``) plus ``sig`` times the vehicle's next standard normal, ``noise[i,
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
        z = ring[i, slot, 16] + sig * noise[i, j]
        radar[i, 0] = z
        radar[i, 1] = sig * sig
        radar[i, 2] = 0.0
        range_last[i] = z
    return 0


@njit(cache=True)
def nees15(x, P, tr, q_t, dth, e, L, y):  # pragma: no cover
    """eᵀ P⁻¹ e of one row's core state against the truth ``tr`` (a ring row): e = [p, v,
    Log(q̂* ⊗ q), b_a, b_g] true − estimated, bias truth = the IMU's walked biases of that
    tick (ring 23:29)."""
    if not np.isfinite(tr[17]):
        e[0] = np.nan
        return np.nan
    rot_to_quat(tr[7:16], q_t)
    quat_log_err(x[6:10], q_t, dth)
    for a in range(3):
        e[a] = tr[17 + a] - x[a]
        e[3 + a] = tr[20 + a] - x[3 + a]
        e[6 + a] = dth[a]
        e[9 + a] = tr[23 + a] - x[10 + a]
        e[12 + a] = tr[26 + a] - x[13 + a]
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
    scratch."""
    quat_to_rot(x[6:10], Re)
    dx, dy = x[0] - p[0], x[1] - p[1]
    out[0] = math.sqrt(dx * dx + dy * dy)
    s = 0.0
    for a in range(3):
        s += (x[3 + a] - v[a]) ** 2
    out[1] = math.sqrt(s)
    cz = Re[0, 2] * Rt[2] + Re[1, 2] * Rt[5] + Re[2, 2] * Rt[8]
    out[2] = math.acos(min(1.0, max(-1.0, cz)))
    ye = math.atan2(Re[1, 0], Re[0, 0]) - yaw_t
    out[3] = abs(math.atan2(math.sin(ye), math.cos(ye)))


@njit(cache=True, nogil=True)
def outputs(bank, pose, scores, out, k, nr, flown):  # pragma: no cover
    """The flown row's (p, v, R) per vehicle and the bias-corrected rates ω̃ − b̂_g (the raw
    gyro before the filter is initialised); per row the tick's errors (:func:`row_errors`)
    and, at a fix, the record ``nees[i, fix, :, row]`` (columns ``N_*``): the NEES of the
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
    e = np.empty(15)
    oe = np.empty(4)
    L, y = np.empty((15, 15)), np.empty(15)
    Pb, eb = np.empty((3, 3)), np.empty(3)
    Pc = np.empty((15, 15))
    for i in range(act.shape[0]):
        if not act[i]:
            continue
        for a in range(3):
            w_out[i, a] = imu[i, 3 + a]
        if not init[i]:
            continue
        if flown >= 0:
            x = xo[i * nr + flown]
            for a in range(3):
                p_out[i, a] = x[a]
                v_out[i, a] = x[3 + a]
                w_out[i, a] = imu[i, 3 + a] - x[13 + a]
            quat_to_rot_flat(x[6:10], R_out[i])
        rec = n_fix[i]
        at_fix = np.isfinite(gnss[i, 0]) and rec < fix_k.shape[1]
        if at_fix:
            fix_k[i, rec] = k
            n_fix[i] = rec + 1
        yaw_t = rot_to_yaw(Rt[i])
        for j in range(nr):
            row = i * nr + j
            row_errors(xo[row], p[i], v[i], Rt[i], yaw_t, Re, oe)
            for c in range(4):
                err[k, i, c, j] = oe[c]
            if at_fix:
                tr = ring[i, (k0[i] + core[row]) % B]
                rc = nees[i, rec, :, j]
                for a in range(15):  # loops: numba's slice assignment compiles slowly
                    for b in range(15):
                        Pc[a, b] = P[row, a, b]
                for a in range(3):
                    Pc[a, a] += cvar[i, a]
                rc[N_NEES15] = nees15(xc[row], Pc, tr, q_t, dth, e, L, y)
                rc[N_NISP] = nis[row, 0]
                rc[N_NISV] = nis[row, 1]
                rc[N_NISY] = nis[row, 2]
                rc[N_GATE] = gate[row]
                if np.isfinite(e[0]):   # each 3-state block alone (3 dof)
                    for b in range(5):
                        rc[N_POS + b] = quad_inv_at(Pc, e, 3 * b, eb.shape[0], L, y, Pb, eb)
                    rc[N_NOTPD] = 0.0 if np.isfinite(rc[N_NEES15]) else 1.0
