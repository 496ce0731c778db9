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

from numkit.geometry import quat_to_rot9

from .._jit import njit


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
    flies, ``box`` (N, 5) the bounding box x0, y0, x1, y1, z_max, the crash ``code``, the
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
    """The reference: the block of rows ``ref_tab`` (refs, ticks, 12) from tick ``ref_k0[0]``
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
        px, py, pz = S[i, iq], S[i, iq + 1], S[i, iq + 2]
        w, x, y, z = S[i, iq + 3], S[i, iq + 4], S[i, iq + 5], S[i, iq + 6]
        p[i, 0], p[i, 1], p[i, 2] = px, py, pz
        quat[i, 0], quat[i, 1], quat[i, 2], quat[i, 3] = w, x, y, z
        for j in range(3):
            v[i, j] = S[i, iv + j]
            omega[i, j] = S[i, iv + 3 + j]
        Ri = quat_to_rot9(w, x, y, z)
        for j in range(9):
            R[i, j] = Ri[j]
        if not (np.isfinite(px) and np.isfinite(py) and np.isfinite(pz)):
            code[i] = _NONFINITE
        elif R[i, 8] < cos_tilt:
            code[i] = _TILT
        elif (px < box[i, 0] or py < box[i, 1] or px > box[i, 2] or py > box[i, 3]
              or pz > box[i, 4]):
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
            rp[i, j] = row[j]
            rv[i, j] = row[3 + j]
            ra[i, j] = row[6 + j]
        yaw[i] = row[9]
        spray[i] = row[11] > 0.5
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
            r[j] = p[i, j]
            r[3 + j] = v[i, j]
            r[6 + j] = rp[i, j]
            r[9 + j] = pfb[i, j]
            r[18 + j] = w[i, j]
        r[12] = ref_tab[ref_ids[i], kr, 10]
        r[13] = 1.0 if spray[i] else 0.0
        for j in range(f.shape[1]):  # rotors past the fourth after the wind
            r[14 + j if j < 4 else 17 + j] = f[i, j]
        flown[i] = k + 1


@njit(cache=True)
def imu_record(imu_rec, now, k, act, f_m, om, err):  # pragma: no cover
    """The tick's IMU row (measured f, gyro, attitude error) into ``now`` (N, 9) and into the
    record ``imu_rec[k]`` (its dtype: float32 in the engine); an ended vehicle's ``now`` row is
    zero, as its record's rows are."""
    for i in range(act.shape[0]):
        if not act[i]:
            now[i, :] = 0.0
            continue
        for j in range(3):
            now[i, j] = f_m[i, j]
            now[i, 3 + j] = om[i, j]
            now[i, 6 + j] = err[i, j]
        for j in range(9):
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
