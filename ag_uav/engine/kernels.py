"""The engine's per-tick kernels over the batch axis (numba, no fastmath; rows never mixed).

Each kernel loops over the vehicles of a batch and touches row ``i`` only, so a vehicle's
results do not depend on its neighbours (bit-identical alone or in any batch).

The long argument lists are declared once, by name, as named tuples (:class:`GuardRows`,
:class:`PoseRows`, :class:`RefRows`, :class:`RecordRow`); a caller passes each as a plain
tuple in field order and the kernel names it again (numba types a plain tuple of arrays on
its fast path: :mod:`ag_uav.navigation.ins_kernels`).
"""

from __future__ import annotations

from typing import Any, NamedTuple

import numpy as np

from numkit import QW, QX, QY, QZ, Layout, X, Y, Z
from numkit.geometry import quat_to_rot9

from .._jit import njit
from .reftable import RF

#: a free joint's slots of a state row (MuJoCo's qpos and qvel of a free body): position,
#: attitude quaternion (w, x, y, z); velocity (world), body rates
FREE_QPOS = Layout("pos:3 quat:4")
FREE_QVEL = Layout("vel:3 omega:3")
FQ, FV = FREE_QPOS.at, FREE_QVEL.at
#: the guard's bounding box per vehicle (:class:`GuardRows` ``box``)
BOUNDS = Layout("x0 y0 x1 y1 z_max")
BX = BOUNDS.at
#: the loop record's row (:data:`~ag_uav.engine.stages.REC_COLUMNS`): p, v, the reference's
#: position, the fed-back position, the segment, the nozzles (0/1), the first four rotor
#: commands, the wind; rotors past the fourth follow it
RECORD = Layout("p:3 v:3 rp:3 p_fb:3 seg spray f:4 wind:3")
RC = RECORD.at
#: the MEMS IMU's record row (:data:`~ag_uav.engine.stages.IMU_KEYS`): measured specific
#: force, gyro, attitude error
IMU_REC = Layout("f:3 om:3 att_err:3")
IR = IMU_REC.at
#: the rotor commands the record holds before the wind
NF = RECORD.width["f"]


def zeros_touched(shape: tuple[int, ...], dtype: Any = np.float64) -> np.ndarray:
    """Zeros whose pages are written now: a per-tick record written one tick-row at a time
    would otherwise take its page faults inside the loop, a few each tick (np.zeros maps
    the memory lazily); written in one pass here they cost a fraction of that."""
    a = np.empty(shape, dtype=dtype)
    a.fill(0.0)
    return a


#: crash codes of :func:`tick_in`
OK, NONFINITE, TILT, BOX = 0, 1, 2, 3
_NONFINITE, _TILT, _BOX = NONFINITE, TILT, BOX
#: :func:`tick_in`'s return bits: some crash code set, some vehicle near the ground, some
#: vehicle active
CRASHED, NEAR_GROUND, ACTIVE = 1, 2, 4


class GuardRows(NamedTuple):
    """The guard's rows (N vehicles): ``act`` the active ones, ``n_ticks`` the ticks each
    flies, ``box`` (N, :data:`BOUNDS`) the bounding box, the crash ``code``, the
    lift-off latch ``airborne``, ``hover_z`` the body height on the skids, ``low`` near the
    ground this tick."""

    act: np.ndarray
    n_ticks: np.ndarray
    box: np.ndarray
    code: np.ndarray
    airborne: np.ndarray
    hover_z: np.ndarray
    low: np.ndarray


class PoseRows(NamedTuple):
    """The pose read from the state rows: ``p``, ``v`` (N, 3), the quaternion ``quat``
    (N, 4; w, x, y, z), ``R`` (N, 9; row-major body → world) and the body rates ``omega``."""

    p: np.ndarray
    v: np.ndarray
    quat: np.ndarray
    R: np.ndarray
    omega: np.ndarray


class RefRows(NamedTuple):
    """The reference: the block of rows ``ref_tab`` (refs, ticks, ``REF``) from ``ref_k0[0]``
    (:class:`~ag_uav.engine.reftable.RefTable`), each vehicle's row of it ``ref_ids``, and the
    tick's ``rp``, ``rv``, ``ra`` (N, 3), ``yaw`` and ``spray`` (N,)."""

    ref_tab: np.ndarray
    ref_k0: np.ndarray
    ref_ids: np.ndarray
    rp: np.ndarray
    rv: np.ndarray
    ra: np.ndarray
    yaw: np.ndarray
    spray: np.ndarray


class RecordRow(NamedTuple):
    """What a tick's record row holds (:data:`~ag_uav.engine.loop.REC_COLUMNS`): ``p``, ``v``,
    the reference ``rp``, the fed-back ``p_fb``, the wind ``w`` (N, 3), the rotor commands
    ``f`` (N, rotors), ``spray`` (N,), and the reference's block ``ref_tab`` from tick
    ``ref_k0[0]`` with each vehicle's ``ref_ids``."""

    p: np.ndarray
    v: np.ndarray
    rp: np.ndarray
    p_fb: np.ndarray
    w: np.ndarray
    f: np.ndarray
    spray: np.ndarray
    ref_tab: np.ndarray
    ref_k0: np.ndarray
    ref_ids: np.ndarray


@njit(cache=True)
def tick_in(k, S, iq, iv, cos_tilt, guard, pose, ref):  # pragma: no cover
    """Start of tick ``k`` for every active vehicle: retire finished ones; state rows (``S``,
    position at column ``iq``, velocity at ``iv``) → p, v, quaternion, R (row-major body →
    world), body rates; crash codes (tilt: ``R₂₂ < cos_tilt``); the lift-off latch; the
    near-ground flag (contacts are checked there); the reference row. ``guard``:
    :class:`GuardRows`, ``pose``: :class:`PoseRows`, ``ref``: :class:`RefRows` (plain tuples).

    Returns :data:`CRASHED` | :data:`NEAR_GROUND` | :data:`ACTIVE` as they hold.
    """
    g, po, rf = GuardRows(*guard), PoseRows(*pose), RefRows(*ref)
    act, n_ticks, box, code, airborne, hover_z, low = (g.act, g.n_ticks, g.box, g.code,
                                                        g.airborne, g.hover_z, g.low)
    p, v, quat, R, omega = po.p, po.v, po.quat, po.R, po.omega
    ref_tab, ref_ids, rp, rv, ra, yaw, spray = (rf.ref_tab, rf.ref_ids, rf.rp, rf.rv, rf.ra,
                                                rf.yaw, rf.spray)
    kr = k - rf.ref_k0[0]
    flags = 0
    for i in range(S.shape[0]):
        if act[i] and n_ticks[i] <= k:
            act[i] = False
        low[i] = False
        if not act[i]:
            continue
        flags |= ACTIVE
        q0, o = iq + FQ.QUAT, iq + FQ.POS
        px, py, pz = S[i, o + X], S[i, o + Y], S[i, o + Z]
        w, x, y, z = S[i, q0 + QW], S[i, q0 + QX], S[i, q0 + QY], S[i, q0 + QZ]
        p[i, X], p[i, Y], p[i, Z] = px, py, pz
        quat[i, QW], quat[i, QX], quat[i, QY], quat[i, QZ] = w, x, y, z
        for j in range(3):
            v[i, j] = S[i, iv + FV.VEL + j]
            omega[i, j] = S[i, iv + FV.OMEGA + j]
        Ri = quat_to_rot9(w, x, y, z)
        for j in range(9):
            R[i, j] = Ri[j]
        if not (np.isfinite(px) and np.isfinite(py) and np.isfinite(pz)):
            code[i] = _NONFINITE
        elif R[i, 3 * Z + Z] < cos_tilt:   # R_zz (row-major) = cos(tilt)
            code[i] = _TILT
        elif (px < box[i, BX.X0] or py < box[i, BX.Y0] or px > box[i, BX.X1]
              or py > box[i, BX.Y1] or pz > box[i, BX.Z_MAX]):
            code[i] = _BOX
        if code[i] != 0:
            flags |= CRASHED
            continue
        if not airborne[i] and pz > hover_z[i] + 0.3:
            airborne[i] = True
        if airborne[i] and pz < hover_z[i] + 1.5:
            low[i] = True
            flags |= NEAR_GROUND
        row = ref_tab[ref_ids[i], kr]
        for j in range(3):
            rp[i, j] = row[RF.P + j]
            rv[i, j] = row[RF.V + j]
            ra[i, j] = row[RF.A + j]
        yaw[i] = row[RF.YAW]
        spray[i] = row[RF.SPRAY] > 0.5
    return flags


@njit(cache=True)
def hold_on_ground(act, airborne, pf, vf, rp, rv, p_out, v_out):  # pragma: no cover
    """The fed-back state; on the skids before lift-off the horizontal part is the reference's
    (no horizontal position control until the vehicle is airborne, as autopilots do)."""
    for i in range(act.shape[0]):
        if not act[i]:
            continue
        for j in range(3):
            p_out[i, j] = pf[i, j]
            v_out[i, j] = vf[i, j]
        if not airborne[i]:
            for j in range(2):
                p_out[i, j] = rp[i, j]
                v_out[i, j] = rv[i, j]


@njit(cache=True)
def tick_out(rec, k, act, flown, row):  # pragma: no cover
    """Row ``k`` of every active vehicle's record ``rec`` (see
    :data:`~ag_uav.engine.loop.REC_COLUMNS`) from ``row`` (:class:`RecordRow`, a plain tuple);
    ``flown`` counts each vehicle's ticks."""
    rr = RecordRow(*row)
    p, v, rp, pfb, w, f, spray = rr.p, rr.v, rr.rp, rr.p_fb, rr.w, rr.f, rr.spray
    ref_tab, ref_ids, kr = rr.ref_tab, rr.ref_ids, k - rr.ref_k0[0]
    for i in range(p.shape[0]):
        if not act[i]:
            continue
        r = rec[k, i]
        for j in range(3):
            r[RC.P + j] = p[i, j]
            r[RC.V + j] = v[i, j]
            r[RC.RP + j] = rp[i, j]
            r[RC.P_FB + j] = pfb[i, j]
            r[RC.WIND + j] = w[i, j]
        r[RC.SEG] = ref_tab[ref_ids[i], kr, RF.SEG]
        r[RC.SPRAY] = 1.0 if spray[i] else 0.0
        for j in range(f.shape[1]):  # rotors past the fourth after the wind
            r[RC.F + j if j < NF else RC.SIZE + j - NF] = f[i, j]
        flown[i] = k + 1


@njit(cache=True)
def imu_record(imu_rec, now, k, act, f_m, om, err):  # pragma: no cover
    """The tick's IMU row (:data:`IMU_REC`) into ``now`` (N, 9) and into the
    record ``imu_rec[k]`` (its dtype: float32 in the engine); an ended vehicle's ``now`` row is
    zero, as its record's rows are."""
    for i in range(act.shape[0]):
        if not act[i]:
            now[i, :] = 0.0
            continue
        for j in range(3):
            now[i, IR.F + j] = f_m[i, j]
            now[i, IR.OM + j] = om[i, j]
            now[i, IR.ATT_ERR + j] = err[i, j]
        for j in range(IR.SIZE):
            imu_rec[k, i, j] = now[i, j]


@njit(cache=True)
def controls(U, f, xf, col, act):  # pragma: no cover
    """Zero-order hold of the rotor commands and the drag force over the control period."""
    for i in range(U.shape[0]):
        if not act[i]:
            continue
        for s in range(U.shape[1]):
            for j in range(f.shape[1]):
                U[i, s, j] = f[i, j]
            for j in range(3):
                U[i, s, col + j] = xf[i, j]
