"""Block encoding of the run log's tick rows (numba): the ``/tf``, ``/drone/pose``,
``/drone/pose_ref``, ``/drone/pose_est`` and ``/drone/state`` messages of many ticks in one call.

A tick row (:meth:`ag_uav.record.runlog.RunLog.tick_slot`) holds the raw values of one control
tick; the log keeps the rows of the last flush interval and hands them here at each flush.  Every
message is protobuf wire format:

* ``foxglove.FrameTransform`` / ``PoseInFrame``: the timestamp (field 1, a varint pair, the only
  part whose length varies), the frame ids, then the 67-byte pose (translation or position, then
  the rotation quaternion x, y, z, w), as :func:`ag_uav.record.wire.enc_pose_in_frame` writes
  one at a time;
* ``ag_uav.DroneState``: a :class:`~ag_uav.record.wire.FlatSchema` (every field a double at a
  fixed offset): the template's bytes with the row's values written into their slots.

The derived values (roll, pitch and yaw in degrees by the ZYX convention, tracking and estimate
errors, speed) are computed here per row, in the order of the state schema.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from numkit.geometry import quat_to_euler

from .._jit import njit

#: message kinds in the kernel's output, in the order the log's channels are listed
TF, POSE, REF, EST, STATE = range(5)


@njit(cache=True)
def _varint(out: np.ndarray, o: int, v: int) -> int:
    while v >= 0x80:
        out[o] = (v & 0x7F) | 0x80
        v >>= 7
        o += 1
    out[o] = v
    return o + 1


@njit(cache=True)
def _stamp(out: np.ndarray, o: int, tn: int) -> int:
    """Field 1 (``timestamp``): tag, length, google.protobuf.Timestamp (zero halves omitted)."""
    sec = tn // 1_000_000_000
    nsec = tn - sec * 1_000_000_000
    out[o] = 0x0A
    p = o + 2
    if sec:
        out[p] = 0x08
        p = _varint(out, p + 1, sec)
    if nsec:
        out[p] = 0x10
        p = _varint(out, p + 1, nsec)
    out[o + 1] = p - o - 2
    return p


@njit(cache=True)
def _copy(out: np.ndarray, o: int, src: np.ndarray) -> int:
    for j in range(len(src)):
        out[o + j] = src[j]
    return o + len(src)


@njit(cache=True)
def _fill(out: np.ndarray, o: int, tmpl: np.ndarray, slots: np.ndarray, vals: np.ndarray,
          f8: np.ndarray, b8: np.ndarray) -> int:
    """``tmpl`` at ``o`` with ``vals[j]`` (little-endian double) at ``o + slots[j]``."""
    _copy(out, o, tmpl)
    for j in range(len(slots)):
        f8[0] = vals[j]
        s = o + slots[j]
        for b in range(8):
            out[s + b] = b8[b]
    return o + len(tmpl)


@njit(cache=True)
def _state_values(row: np.ndarray, n_motors: int, ctrl_cols: np.ndarray,
                  v: np.ndarray) -> None:
    """``ag_uav.DroneState``'s values of one tick row, in the schema's field order (element by
    element: numba's slice assignment compiles its error message's string formatting)."""
    px, py, pz = row[2], row[3], row[4]
    qw, qx, qy, qz = row[5], row[6], row[7], row[8]
    vx, vy, vz = row[9], row[10], row[11]
    rx, ry, rz = row[12], row[13], row[14]
    deg = 57.29577951308232
    roll, pitch, yaw = quat_to_euler(qw, qx, qy, qz)
    head = (row[0], px, py, pz, vx, vy, vz, roll * deg, pitch * deg, yaw * deg)
    for j in range(10):
        v[j] = head[j]
    for j in range(7):  # reference x, y, z, vx, vy, vz, yaw
        v[10 + j] = row[12 + j]
    est = (int(row[1]) & 8) != 0
    for j in range(6):
        v[17 + j] = row[19 + j] if est else np.nan
    ex, ey, ez = px - rx, py - ry, pz - rz
    eh = np.sqrt(ex * ex + ey * ey)
    dx, dy, dz = v[17] - px, v[18] - py, v[19] - pz
    errs = (ex, ey, ez, eh, np.sqrt(eh * eh + ez * ez), dx, dy, dz,
            np.sqrt(dx * dx + dy * dy), np.sqrt(vx * vx + vy * vy + vz * vz), row[28], row[25])
    for j in range(12):
        v[23 + j] = errs[j]
    v[35], v[36] = row[26], row[27]
    for j in range(n_motors):
        v[37 + j] = row[29 + j]
    for j in range(len(ctrl_cols)):
        v[37 + n_motors + j] = row[ctrl_cols[j]]


class TickFormat(NamedTuple):
    """How tick rows are encoded (:func:`encode_ticks`): ``n_motors`` rotor columns after the
    head, the raw columns of the ctrl keys (``ctrl_cols``), the state message's byte template
    and value slots (:func:`ag_uav.record.wire.template`), the pose's, the FrameTransform's
    translation and rotation fields (``tf_tmpl``), and the constant bytes between the timestamp
    and the pose (frame ids and the pose's field header) of a transform (``tf_head``) and of a
    pose (``pose_head``).  An empty template: that kind is off."""

    n_motors: int
    ctrl_cols: np.ndarray
    st_tmpl: np.ndarray
    st_slots: np.ndarray
    pose_tmpl: np.ndarray
    pose_slots: np.ndarray
    tf_tmpl: np.ndarray
    tf_head: np.ndarray
    pose_head: np.ndarray


@njit(cache=True)
def encode_ticks(rows: np.ndarray, fmt: TickFormat, out: np.ndarray, starts: np.ndarray,
                 kinds: np.ndarray, tns: np.ndarray) -> int:
    """Encode ``rows`` into ``out`` as ``fmt`` says: message ``m`` is
    ``out[starts[m]:starts[m + 1]]`` of kind ``kinds[m]`` (:data:`TF` ...) at log time
    ``tns[m]`` ns.  Returns the message count.

    A row's group mask (column 1): 1 ``/tf``, 2 the poses, 4 the state, 8 the estimate columns
    hold one (``pose_est`` then too); a kind whose template is empty (its group off) is
    skipped."""
    (n_motors, ctrl_cols, st_tmpl, st_slots, pose_tmpl, pose_slots, tf_tmpl, tf_head,
     pose_head) = fmt
    f8 = np.empty(1)
    b8 = f8.view(np.uint8)
    vals = np.empty(len(st_slots))
    pv = np.empty(7)
    o = np.int64(0)  # not the literal 0: the callees compile once, for int64
    m = 0
    for r in range(rows.shape[0]):
        row = rows[r]
        tn = int(np.rint(row[0] * 1e9))
        tn = tn if tn > 0 else 0
        mask = int(row[1])
        pv[3], pv[4], pv[5], pv[6] = row[6], row[7], row[8], row[5]
        if mask & 1 and len(tf_tmpl):
            starts[m], kinds[m], tns[m] = o, TF, tn
            m += 1
            out[o] = 0x0A  # FrameTransforms.transforms[0], its length after the body
            p = _stamp(out, o + 2, tn)
            p = _copy(out, p, tf_head)
            pv[0], pv[1], pv[2] = row[2], row[3], row[4]
            p = _fill(out, p, tf_tmpl, pose_slots, pv, f8, b8)
            out[o + 1] = p - o - 2
            o = p
        if mask & 2 and len(pose_tmpl):
            for kind in (POSE, REF, EST):
                if kind == EST and not mask & 8:
                    continue
                starts[m], kinds[m], tns[m] = o, kind, tn
                m += 1
                o = _copy(out, _stamp(out, o, tn), pose_head)
                if kind == REF:
                    h = 0.5 * row[18]
                    pr = np.array((row[12], row[13], row[14], 0.0, 0.0, np.sin(h), np.cos(h)))
                    o = _fill(out, o, pose_tmpl, pose_slots, pr, f8, b8)
                else:
                    c = 2 if kind == POSE else 19
                    pv[0], pv[1], pv[2] = row[c], row[c + 1], row[c + 2]
                    o = _fill(out, o, pose_tmpl, pose_slots, pv, f8, b8)
        if mask & 4 and len(st_tmpl):
            starts[m], kinds[m], tns[m] = o, STATE, tn
            m += 1
            _state_values(row, n_motors, ctrl_cols, vals)
            o = _fill(out, o, st_tmpl, st_slots, vals, f8, b8)
    starts[m] = o
    return m


@njit(cache=True)
def encode_flat(rows: np.ndarray, tmpl: np.ndarray, slots: np.ndarray, out: np.ndarray,
                starts: np.ndarray) -> None:
    """Each row of ``rows`` (its values in a :class:`~ag_uav.record.wire.FlatSchema`'s
    order) as one message: ``out[starts[r]:starts[r + 1]]`` (all the same size)."""
    f8 = np.empty(1)
    b8 = f8.view(np.uint8)
    o = np.int64(0)  # not the literal 0: the callees compile once, for int64
    for r in range(rows.shape[0]):
        starts[r] = o
        o = _fill(out, o, tmpl, slots, rows[r], f8, b8)
    starts[rows.shape[0]] = o


@njit(cache=True)
def encode_poses(rows: np.ndarray, pose_tmpl: np.ndarray, pose_slots: np.ndarray,
                 pose_head: np.ndarray, out: np.ndarray, starts: np.ndarray,
                 tns: np.ndarray) -> int:
    """Rows ``(t, x, y, z, …)`` -> ``foxglove.PoseInFrame`` messages at the position with the
    identity orientation (``/gps``): message ``r`` is ``out[starts[r]:starts[r + 1]]`` at log
    time ``tns[r]`` (``t``); its ``timestamp`` is column 8 where the rows have one (the fix's
    measurement time), else ``t``; returns the end of the last."""
    f8 = np.empty(1)
    b8 = f8.view(np.uint8)
    pv = np.array((0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 1.0))
    o = np.int64(0)  # not the literal 0: the callees compile once, for int64
    for r in range(rows.shape[0]):
        tn = int(np.rint(rows[r, 0] * 1e9))
        tn = tn if tn > 0 else 0
        ts = int(np.rint(rows[r, 8] * 1e9)) if rows.shape[1] > 8 else tn
        ts = ts if ts > 0 else 0
        starts[r], tns[r] = o, tn
        pv[0], pv[1], pv[2] = rows[r, 1], rows[r, 2], rows[r, 3]
        o = _fill(out, _copy(out, _stamp(out, o, ts), pose_head), pose_tmpl, pose_slots, pv,
                  f8, b8)
    starts[rows.shape[0]] = o
    return o
