"""The engine's per-tick kernels over the batch axis (numba, no fastmath; rows never mixed).

Each kernel loops over the vehicles of a batch and touches row ``i`` only, so a vehicle's
results do not depend on its neighbours (bit-identical alone or in any batch).
"""

from __future__ import annotations

import numpy as np

from .._jit import njit


def zeros_touched(shape: tuple[int, ...]) -> np.ndarray:
    """Zeros whose pages are written now: a per-tick record written one tick-row at a time
    would otherwise take its page faults inside the loop, a few each tick (np.zeros maps
    the memory lazily); written in one pass here they cost a fraction of that."""
    a = np.empty(shape)
    a.fill(0.0)
    return a


#: crash codes of :func:`tick_in`
OK, NONFINITE, TILT, BOX = 0, 1, 2, 3
_NONFINITE, _TILT, _BOX = NONFINITE, TILT, BOX

@njit(cache=True)
def tick_in(k, S, act, n_ticks, iq, iv, p, v, quat, R, omega, box, cos_tilt, code, airborne,
             hover_z, low, ref_tab, ref_ids, rp, rv, ra, yaw, spray):  # pragma: no cover
    """Start of tick ``k`` for every active vehicle: retire finished ones; state rows → p, v,
    quaternion, R (row-major body → world), body rates; crash codes; the lift-off latch; the
    near-ground flag (contacts are checked there); the reference row.

    Returns flags: 1 some crash code set, 2 some vehicle near the ground, 4 some vehicle active.
    """
    flags = 0
    for i in range(S.shape[0]):
        if act[i] and n_ticks[i] <= k:
            act[i] = False
        low[i] = False
        if not act[i]:
            continue
        flags |= 4
        px, py, pz = S[i, iq], S[i, iq + 1], S[i, iq + 2]
        w, x, y, z = S[i, iq + 3], S[i, iq + 4], S[i, iq + 5], S[i, iq + 6]
        p[i, 0], p[i, 1], p[i, 2] = px, py, pz
        quat[i, 0], quat[i, 1], quat[i, 2], quat[i, 3] = w, x, y, z
        for j in range(3):
            v[i, j] = S[i, iv + j]
            omega[i, j] = S[i, iv + 3 + j]
        xx, yy, zz = x * x, y * y, z * z
        xy, xz, yz = x * y, x * z, y * z
        wx, wy, wz = w * x, w * y, w * z
        R[i, 0] = 1.0 - 2.0 * (yy + zz)
        R[i, 1] = 2.0 * (xy - wz)
        R[i, 2] = 2.0 * (xz + wy)
        R[i, 3] = 2.0 * (xy + wz)
        R[i, 4] = 1.0 - 2.0 * (xx + zz)
        R[i, 5] = 2.0 * (yz - wx)
        R[i, 6] = 2.0 * (xz - wy)
        R[i, 7] = 2.0 * (yz + wx)
        R[i, 8] = 1.0 - 2.0 * (xx + yy)
        if not (np.isfinite(px) and np.isfinite(py) and np.isfinite(pz)):
            code[i] = _NONFINITE
        elif R[i, 8] < cos_tilt:
            code[i] = _TILT
        elif (px < box[i, 0] or py < box[i, 1] or px > box[i, 2] or py > box[i, 3]
              or pz > box[i, 4]):
            code[i] = _BOX
        if code[i] != 0:
            flags |= 1
            continue
        if not airborne[i] and pz > hover_z[i] + 0.3:
            airborne[i] = True
        if airborne[i] and pz < hover_z[i] + 1.5:
            low[i] = True
            flags |= 2
        row = ref_tab[ref_ids[i], k]
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
def tick_out(rec, k, act, p, v, rp, pfb, ref_tab, ref_ids, spray, f, w,
              flown):  # pragma: no cover
    """Row ``k`` of every active vehicle's record (see :data:`REC_COLUMNS`)."""
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
        r[12] = ref_tab[ref_ids[i], k, 10]
        r[13] = 1.0 if spray[i] else 0.0
        for j in range(4):
            r[14 + j] = f[i, j]
        flown[i] = k + 1


@njit(cache=True)
def imu_record(imu_rec, k, act, f_m, om, err):  # pragma: no cover
    for i in range(act.shape[0]):
        if act[i]:
            for j in range(3):
                imu_rec[k, i, j] = f_m[i, j]
                imu_rec[k, i, 3 + j] = om[i, j]
                imu_rec[k, i, 6 + j] = err[i, j]


@njit(cache=True)
def controls(U, f, xf, col, act):  # pragma: no cover
    """Zero-order hold of the rotor commands and the drag force over the control period."""
    for i in range(U.shape[0]):
        if not act[i]:
            continue
        for s in range(U.shape[1]):
            for j in range(4):
                U[i, s, j] = f[i, j]
            for j in range(3):
                U[i, s, col + j] = xf[i, j]
