"""Run log: one MCAP file per run that Foxglove and ``ag_uav.analysis.viewing`` can open.

Usage (the simulation loop calls this; everything is in sim time, seconds -> ns)::

    with RunLog(run_dir / "run.mcap", channels="full", metadata={...}, config_toml=txt) as log:
        log.scene(0.0, outer_xy, holes_xy, plan_segments, swath=6.0, altitude=3.0)
        for each 100 Hz control tick:
            log.tick(t, p_true=p, q_true_wxyz=q, v_true=v, p_ref=r, v_ref=vr, yaw_ref=psi,
                     p_est=pe, v_est=ve, ctrl={"x.E": .., "x.u": ..}, motors=[..], wind=w,
                     spray=on)
            if a GPS fix arrived:
                log.gps(t, fix)
                log.estimator(t, "mckf", x, p_diag, innovation, pos=x[:3])
            if log.want_frame(t):                         # renders are costly: ask first
                log.frame(t, "chase", r.jpeg(d, "chase"), r.width, r.height, r.fovy("chase"),
                          pose=r.camera_pose(d, "chase"))
        log.sprayed(t_end, sprayed_polygons)
        log.summary({"rmse_m": ..})
    # -> run.mcap and layout.json (Foxglove app-export layout) beside it

Writer, chosen by measurement (figures in docs/speed.md; ``ag-uav bench`` measures the logging
cost): ``foxglove-sdk`` (Rust MCAP writer, LZ4 chunks) fed pre-encoded protobuf bytes through
``BaseChannel.log``, in a writer process of its own (:mod:`ag_uav.record.sink`; ``writer="inline"``
keeps it in this process); the pure-Python ``mcap`` writer and the SDK's typed message objects
cost several times more per message.  The frequent messages are hand-encoded in blocks
(:mod:`ag_uav.record.encode`): PoseInFrame / FrameTransform, and our own numeric channels
(``/drone/state``, ``/estimator/<name>``), protobuf messages whose schema is generated at the
first call (all fields ``double``, nested groups, packed vectors; see :class:`FlatSchema`); they
decode with any protobuf reader.  The rows of the per-tick channels wait in this process and
reach the writer in one hand-over (and before any frame, scene or metadata write), so the control
loop does not interleave with the writer's bookkeeping.

Channels (Foxglove well-known schemas where one fits; groups in brackets):
  [tf]        ``/tf``                 foxglove.FrameTransforms world->base_link
                                      (and world->cam_<name> with each frame)
  [pose]      ``/drone/pose``, ``/drone/pose_est``, ``/drone/pose_ref``  foxglove.PoseInFrame
  [state]     ``/drone/state``        ag_uav.DroneState: pos, vel, rpy, ref, est, err, est_err,
                                      speed, spray, wind, motors[], ctrl{...} (plots)
              ``/drone/spray``        ag_uav.SprayState (spray jobs, ag_uav.world.spray_job):
              tank_l, mass_kg,
                                      flow_lps, nozzles, power_w, energy_wh, battery_frac, sortie,
                                      ground
  [gps]       ``/gps``                foxglove.PoseInFrame at each fix (3D + plots)
  [estimator] ``/estimator/<name>``   ag_uav.EstimatorState: x[], p_diag[], innovation[], pos,
                                      err (pos - last true position), extra{...}
  [scene]     ``/field`` (field polygon + planned path), ``/sprayed`` (sprayed area),
              foxglove.SceneUpdate (separate topics so a seek shows both);
              ``/dose`` foxglove.Grid: the dose on the ground (L/ha), every 5 s (light: 30 s;
              the period doubles after each 8 MB of maps) and at the end
  [camera]    ``/camera/<name>`` foxglove.CompressedImage (JPEG) and
              ``/camera/<name>/calibration`` foxglove.CameraCalibration
  [geo]       ``/geo/true``, ``/geo/est``, ``/geo/gnss`` foxglove.LocationFix (the GNSS fixes
              at the ``gps`` group's rate) and ``/geo/field``, ``/geo/plan``, ``/geo/sprayed``,
              ``/geo/dose`` foxglove.GeoJSON (with the ``scene`` group), once :meth:`RunLog.geo`
              has given the run's geodetic origin (:mod:`ag_uav.record.geo`)
  always      metadata records ``run`` and ``versions`` (and ``summary``), attachments
              ``config.toml`` (and ``summary.json``)

Channel sets: ``"full"`` (all groups; tf/pose 10 Hz, state 20 Hz, every GPS fix, each estimator at
<= 10 Hz, camera 10 Hz, geo 5 Hz), ``"light"`` (batch/tuning: pose/tf/state 5 Hz, GPS, estimators
and geo 1 Hz, no camera), ``"none"`` (no file; every method returns at once), or an iterable of
group names.
``rates`` overrides per group in Hz (``None`` = every call, ``0`` = group off).

Crash safety: use ``with`` (or call :meth:`RunLog.close`); SIGTERM/SIGINT close every open log
and then behave as before (KeyboardInterrupt / exit status 128+signal); an ``atexit`` hook closes
the rest.  The rows are handed to the writer every ``flush_wall_s`` of wall time or
``flush_sim_s`` of sim time, whichever comes first, and the writer finishes its chunk and
flushes it to the OS at each hand-over.  With the writer process (:mod:`ag_uav.record.sink`, the
default) a SIGKILL of the flight loses only the rows not handed over yet (< 0.3 s of flight and
one log tick); the writer then finishes the file.  Killed together (a process group), they lose
also the one hand-over the writer had not written yet;
``ag_uav.analysis.viewing.recover`` turns a truncated file into a finished, indexed one.

Cost: between two hand-overs nothing is encoded.  A tick is one row of raw values
(:meth:`RunLog.tick_slot`: the engine copies its arrays into it in one ``np.concatenate``;
:meth:`RunLog.tick` fills one from its arguments), an estimator or spray-state message one row of
its flat schema, a filter bank's fix one compact row; at the hand-over the rows go to the writer,
where :mod:`ag_uav.record.encode` turns them into protobuf messages in one compiled call per
topic group and they are written merged by log time.  A row still
being filled when a signal closes the log is dropped, not written half-done.
"""

from __future__ import annotations

import atexit
import json
import math
import os
import platform
import signal
import struct
import sys
import threading
import time
import weakref
from collections.abc import Iterable, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from .atomic import silent_write_failure
from .sink import WriterLost

__all__ = [
    "RunLog",
    "FlatSchema",
    "GROUPS",
    "PRESETS",
    "sanitize_name",
    "ns",
]

GROUPS = ("tf", "pose", "state", "gps", "estimator", "scene", "camera", "geo")

#: Default rates per channel set, Hz (None = every call).
PRESETS: dict[str, dict[str, float | None]] = {
    "full": {"tf": 10.0, "pose": 10.0, "state": 20.0, "gps": None, "estimator": 10.0,
             "scene": None, "camera": 10.0, "geo": 5.0},
    "light": {"tf": 5.0, "pose": 5.0, "state": 5.0, "gps": 1.0, "estimator": 1.0,
              "scene": None, "camera": 0.0, "geo": 1.0},
    "none": {g: 0.0 for g in GROUPS},
}

_NAN = float("nan")
_INF = float("inf")
#: sim seconds between two dose maps on ``/dose`` during a flight (and one at the end), per
#: channel set: a map sums the whole fine dose grid, the light set's budget takes one in six
DOSE_PERIOD_S = {"full": 5.0, "light": 30.0}
#: bytes of dose maps after which their period doubles (and again after each as many more): a
#: long job over a big field logs O(log duration) quotas of maps instead of one map every period
#: (the 38 ha job's 3,377 whole maps were 1.36 GB of its log); the final map is always logged
DOSE_QUOTA_B = 8_000_000
#: sim seconds between two of those maps that also go to ``/geo/dose`` as GeoJSON bands (and
#: the one at the end): contouring a map costs the writer ~10 ms, three times ``/dose``'s grid
GEO_DOSE_PERIOD_S = {"full": 15.0, "light": 60.0}


def ns(t: float) -> int:
    """Sim time in seconds -> integer nanoseconds (the MCAP log time; clamped at 0)."""
    v = round(t * 1e9)
    return v if v > 0 else 0


def sanitize_name(key: str) -> str:
    """A protobuf-safe field name: letters, digits and ``_``; not starting with a digit."""
    out = "".join(c if (c.isascii() and (c.isalnum() or c == "_")) else "_" for c in key)
    if not out or out[0].isdigit():
        out = "f_" + out
    return out


# --------------------------------------------------------------------------------------------
# Fixed-layout protobuf messages (all doubles) encoded with one struct.pack
# --------------------------------------------------------------------------------------------


_BYTE = [bytes((i,)) for i in range(128)]


def _varint(v: int) -> bytes:
    """Protobuf base-128 varint of a non-negative int."""
    if v < 0x80:
        return _BYTE[v]
    out = []
    while v >= 0x80:
        out.append((v & 0x7F) | 0x80)
        v >>= 7
    out.append(v)
    return bytes(out)


class FlatSchema:
    """A protobuf message of ``double`` fields, nested groups and fixed-length packed vectors.

    ``fields`` is a list of ``(path, n)``: ``path`` is dotted (``"ref.x"`` makes a nested message
    ``ref`` with field ``x``), ``n`` is ``0`` for a scalar ``double`` or the length of a packed
    ``repeated double``.  Fields of one group must be contiguous.  Every field is always written
    (proto3 readers accept explicit defaults), so the encoded size is fixed and the whole message
    is one ``struct`` with constant byte prefixes (tag, nested-message headers) before each value:
    ``encode(values)`` takes the flat list of values (vectors expanded) in field order.
    """

    def __init__(self, full_name: str, fields: Sequence[tuple[str, int]]):
        self.full_name = full_name
        self.fields = [(p, int(n)) for p, n in fields]
        # Tree of groups: dict name -> (subtree | n)
        tree: dict[str, Any] = {}
        closed: set[tuple[str, ...]] = set()
        open_path: tuple[str, ...] = ()
        for path, n in self.fields:
            parts = tuple(sanitize_name(p) for p in path.split("."))
            grp = parts[:-1]
            # close groups that are no longer a prefix
            common = 0
            while common < min(len(open_path), len(grp)) and open_path[common] == grp[common]:
                common += 1
            for k in range(common + 1, len(open_path) + 1):
                closed.add(open_path[:k])
            for k in range(1, len(grp) + 1):
                if grp[:k] in closed:
                    raise ValueError(f"fields of group {'.'.join(grp[:k])!r} are not contiguous")
            open_path = grp
            node = tree
            for g in grp:
                node = node.setdefault(g, {})
                if not isinstance(node, dict):
                    raise ValueError(f"{path!r}: {g!r} is both a field and a group")
            if parts[-1] in node:
                raise ValueError(f"duplicate field {path!r}")
            node[parts[-1]] = n
        self.tree = tree
        prefixes: list[bytes] = []
        self.size = self._layout(tree, prefixes)
        self.n_values = len(prefixes)
        #: the constant bytes before each value (tags, nested-message headers; ``b""`` inside a
        #: packed vector): the encoded message is prefix_0, value_0, prefix_1, value_1, ...
        self.prefixes = prefixes
        self._packer = _Packer(prefixes)
        self.schema_data = self._descriptor_set()

    @staticmethod
    def _size(node: dict[str, Any]) -> int:
        size = 0
        for i, (_, v) in enumerate(node.items(), start=1):
            tag = len(_varint(i << 3))
            if isinstance(v, dict):
                sub = FlatSchema._size(v)
                size += tag + len(_varint(sub)) + sub
            elif v == 0:
                size += tag + 8
            else:
                size += tag + len(_varint(8 * v)) + 8 * v
        return size

    def _layout(self, node: dict[str, Any], prefixes: list[bytes], head: bytes = b"") -> int:
        """Append one prefix per value; ``head`` = pending headers of groups opened here."""
        pending = head
        for i, (_, v) in enumerate(node.items(), start=1):
            if isinstance(v, dict):
                sub = self._size(v)
                pending += _varint((i << 3) | 2) + _varint(sub)
                if sub == 0:
                    continue
                self._layout(v, prefixes, pending)
                pending = b""
            elif v == 0:
                prefixes.append(pending + _varint((i << 3) | 1))
                pending = b""
            else:
                prefixes.append(pending + _varint((i << 3) | 2) + _varint(8 * v))
                prefixes.extend([b""] * (v - 1))
                pending = b""
        if pending:  # only empty groups here: cannot hold the header; disallowed
            raise ValueError("empty group in schema")
        return self._size(node)

    def _descriptor_set(self) -> bytes:
        from google.protobuf import descriptor_pb2

        pkg, _, name = self.full_name.rpartition(".")
        fdp = descriptor_pb2.FileDescriptorProto(
            name=f"{self.full_name.replace('.', '/')}.proto", package=pkg, syntax="proto3"
        )
        fdp_msg = fdp.message_type.add(name=name)
        F = descriptor_pb2.FieldDescriptorProto

        def fill(msg: Any, node: dict[str, Any], type_name: str) -> None:
            for i, (key, v) in enumerate(node.items(), start=1):
                if isinstance(v, dict):
                    sub_name = "".join(w.capitalize() for w in key.split("_")) + "Msg"
                    sub = msg.nested_type.add(name=sub_name)
                    fill(sub, v, f"{type_name}.{sub_name}")
                    msg.field.add(name=key, number=i, label=F.LABEL_OPTIONAL,
                                  type=F.TYPE_MESSAGE, type_name=f"{type_name}.{sub_name}")
                elif v == 0:
                    msg.field.add(name=key, number=i, label=F.LABEL_OPTIONAL,
                                  type=F.TYPE_DOUBLE)
                else:
                    msg.field.add(name=key, number=i, label=F.LABEL_REPEATED,
                                  type=F.TYPE_DOUBLE)

        fill(fdp_msg, self.tree, f".{self.full_name}")
        return descriptor_pb2.FileDescriptorSet(file=[fdp]).SerializeToString()

    def encode(self, values: Sequence[float]) -> bytes:
        """Encode the flat value list (length :attr:`n_values`)."""
        return self._packer.pack(values)


class _Packer:
    """``pack(values)`` -> prefix_0 + double(value_0) + prefix_1 + ... in one ``struct.pack``."""

    __slots__ = ("_struct", "_args")

    def __init__(self, prefixes: Sequence[bytes]):
        self._struct = struct.Struct("<" + "".join(f"{len(p)}sd" for p in prefixes))
        self._args: list[Any] = [None] * (2 * len(prefixes))
        self._args[0::2] = prefixes

    def pack(self, values: Sequence[float]) -> bytes:
        args = self._args
        args[1::2] = values
        return self._struct.pack(*args)


def _template(prefixes: Sequence[bytes]) -> tuple[np.ndarray, np.ndarray]:
    """:class:`_Packer`'s layout as a byte template (uint8, zeros where the values go) and the
    offset of each value's 8 bytes in it: what :mod:`ag_uav.record.encode` fills."""
    tmpl = bytearray()
    slots: list[int] = []
    for p in prefixes:
        tmpl += p
        slots.append(len(tmpl))
        tmpl += bytes(8)
    return np.frombuffer(bytes(tmpl), dtype=np.uint8).copy(), np.array(slots, dtype=np.int64)


class _Rows:
    """A growing (n, width) float64 block of rows to encode at the next flush.  A row handed
    out by :meth:`open_row` counts once :meth:`commit` is called (a signal arriving while the
    caller fills it must not write a half-filled row)."""

    __slots__ = ("a", "n", "open")

    def __init__(self, width: int, cap: int = 64):
        self.a = np.empty((cap, width))
        self.n = 0
        self.open = False

    def open_row(self) -> np.ndarray:
        if self.n == len(self.a):
            self.a = np.concatenate([self.a, np.empty_like(self.a)])
        self.open = True
        return self.a[self.n]

    def open_block(self, k: int) -> np.ndarray:
        """The next ``k`` rows (committed together by ``commit(k)``)."""
        while self.n + k > len(self.a):
            self.a = np.concatenate([self.a, np.empty_like(self.a)])
        self.open = True
        return self.a[self.n:self.n + k]

    def commit(self, k: int = 1) -> None:
        self.n += k
        self.open = False

    def take(self) -> np.ndarray:
        """The committed rows (a view, valid until the next :meth:`open_row`); empties."""
        r = self.a[:self.n]
        self.n = 0
        return r


#: the tick row's columns (:meth:`RunLog.tick_slot`): t, group mask (1 tf, 2 pose, 4 state,
#: 8 an estimate is given), true position, attitude (w, x, y, z), velocity, reference
#: position, velocity and yaw, estimated position and velocity, wind, spray; then the motors
TICK_P, TICK_Q, TICK_V, TICK_PREF, TICK_VREF, TICK_YAW = 2, 5, 9, 12, 15, 18
TICK_PEST, TICK_VEST, TICK_WIND, TICK_SPRAY, TICK_HEAD = 19, 22, 25, 28, 29
_POSE_TMPL, _POSE_SLOTS = _template([b"\x0a\x1b\x09", b"\x11", b"\x19", b"\x12\x24\x09",
                                     b"\x11", b"\x19", b"\x21"])
_TF_TMPL = _POSE_TMPL.copy()
_TF_TMPL[[0, 29]] = (0x22, 0x2A)  # FrameTransform: translation (4), rotation (5)
_NO_BYTES = np.zeros(0, dtype=np.uint8)


# --------------------------------------------------------------------------------------------
# Small geometry helpers (plain floats: faster than numpy for 3-vectors)
# --------------------------------------------------------------------------------------------


def _rpy_deg(w: float, x: float, y: float, z: float) -> tuple[float, float, float]:
    """ZYX Euler angles (roll, pitch, yaw) in degrees from a unit quaternion (w, x, y, z)."""
    sr = 2.0 * (w * x + y * z)
    cr = 1.0 - 2.0 * (x * x + y * y)
    sp = 2.0 * (w * y - z * x)
    sp = 1.0 if sp > 1.0 else (-1.0 if sp < -1.0 else sp)
    sy = 2.0 * (w * z + x * y)
    cy = 1.0 - 2.0 * (y * y + z * z)
    d = 57.29577951308232
    return math.atan2(sr, cr) * d, math.asin(sp) * d, math.atan2(sy, cy) * d


# Hand-encoded foxglove.PoseInFrame / foxglove.FrameTransform (protobuf wire format; the field
# numbers are those of the schemas the SDK ships, checked in tests by decoding).  ~2x faster than
# building the SDK's message objects, and these are the most frequent messages.
_POSE = struct.Struct("<2sBdBdBd2sBdBdBdBd")  # Pose / translation+rotation: 67 bytes


_TS_SEC: dict[int, bytes] = {}
_TS_NSEC: dict[int, bytes] = {}
_TS_CACHE_MAX = 20_000


def _ts_pb(tn: int) -> bytes:
    """google.protobuf.Timestamp body for ``tn`` ns (>= 0); both halves are memoised."""
    sec, nsec = divmod(tn, 1_000_000_000)
    a = _TS_SEC.get(sec)
    if a is None:
        a = b"\x08" + _varint(sec) if sec else b""
        if len(_TS_SEC) < _TS_CACHE_MAX:
            _TS_SEC[sec] = a
    b = _TS_NSEC.get(nsec)
    if b is None:
        b = b"\x10" + _varint(nsec) if nsec else b""
        if len(_TS_NSEC) < _TS_CACHE_MAX:
            _TS_NSEC[nsec] = b
    return a + b


def _ts_field(tn: int) -> bytes:
    """Field 1 (``timestamp``) of PoseInFrame / FrameTransform: tag, length, Timestamp body."""
    ts = _ts_pb(tn)
    return b"\x0a" + _BYTE[len(ts)] + ts  # a Timestamp body is at most 12 bytes


def _str_field(num: int, s: str) -> bytes:
    b = s.encode()
    return _varint((num << 3) | 2) + _varint(len(b)) + b


_WORLD2 = _str_field(2, "world")
_POSE_MID = _WORLD2 + b"\x1a\x43"  # PoseInFrame: frame_id "world", then the 67-byte pose
_DEG = 57.29577951308232
_D = struct.Struct("<d")
_perf_counter = time.perf_counter
_PACKD: dict[int, struct.Struct] = {}


def _f8bytes(a: Any, k: int) -> bytes:
    """``k`` little-endian doubles from ``a`` (NaN-padded / truncated), as a packed vector."""
    if type(a) is np.ndarray and a.size == k and a.dtype.str == "<f8":
        return a.tobytes()  # little-endian doubles: protobuf's packed encoding as they are
    st = _PACKD.get(k)
    if st is None:
        st = _PACKD[k] = struct.Struct(f"<{k}d")
    v = _flat(a)
    return st.pack(*(v if len(v) == k else _fit(v, k)))


def enc_pose_in_frame(ts: bytes, p: Sequence[float], q: Sequence[float]) -> bytes:
    """foxglove.PoseInFrame in frame ``world``; ``ts`` from :func:`_ts_pb`, ``q`` = wxyz."""
    body = _POSE.pack(b"\x0a\x1b", 9, p[0], 17, p[1], 25, p[2],
                      b"\x12\x24", 9, q[1], 17, q[2], 25, q[3], 33, q[0])
    return b"\x0a" + _varint(len(ts)) + ts + _WORLD2 + b"\x1a\x43" + body


def enc_transform(ts: bytes, child3: bytes, p: Sequence[float], q: Sequence[float]) -> bytes:
    """One foxglove.FrameTransform world->child, wrapped as FrameTransforms.transforms[i].

    ``child3`` = ``_str_field(3, child)``; concatenate several for one FrameTransforms message.
    """
    body = (b"\x0a" + _varint(len(ts)) + ts + _WORLD2 + child3
            + _POSE.pack(b"\x22\x1b", 9, p[0], 17, p[1], 25, p[2],
                         b"\x2a\x24", 9, q[1], 17, q[2], 25, q[3], 33, q[0]))
    return b"\x0a" + _varint(len(body)) + body


_GRID_FIELD = b"\x0a\x08l_per_ha" + b"\x15" + bytes(4) + b"\x18\x07"  # float32 at offset 0
_U32 = struct.Struct("<I")


def enc_grid(ts: bytes, x0: float, y0: float, z: float, cell: float, values: Any) -> bytes:
    """foxglove.Grid in frame ``world``: ``values`` ((ny, nx), row j at y0 + j·cell) as one
    float32 field ``l_per_ha``, lower-left corner at (x0, y0, z); ``ts`` from :func:`_ts_pb`."""
    a = np.ascontiguousarray(values, dtype="<f4")
    nx = a.shape[1]
    data = a.tobytes()
    return (b"\x0a" + _varint(len(ts)) + ts + _WORLD2 + b"\x1a\x43"
            + _POSE.pack(b"\x0a\x1b", 9, x0, 17, y0, 25, z, b"\x12\x24", 9, 0.0, 17, 0.0, 25, 0.0,
                         33, 1.0)
            + b"\x25" + _U32.pack(nx) + b"\x2a\x12\x09" + _D.pack(cell) + b"\x11" + _D.pack(cell)
            + b"\x35" + _U32.pack(4 * nx) + b"\x3d" + _U32.pack(4)
            + b"\x42" + _varint(len(_GRID_FIELD)) + _GRID_FIELD
            + b"\x4a" + _varint(len(data)) + data)


# --------------------------------------------------------------------------------------------
# Open-log registry: close on SIGTERM/SIGINT and at exit
# --------------------------------------------------------------------------------------------

_OPEN: weakref.WeakSet[RunLog] = weakref.WeakSet()
_PREV_HANDLERS: dict[int, Any] = {}
_HANDLERS_INSTALLED = False


class _FlatRows:
    """A :class:`FlatSchema` channel whose messages wait as rows of values (column 0 the sim
    time), handed to the writer at the flush and encoded there together
    (:func:`ag_uav.record.encode.encode_flat`)."""

    __slots__ = ("rows", "tmpl", "slots", "lid", "count", "fid", "it")

    def __init__(self, schema: FlatSchema, lid: int):
        self.rows = _Rows(schema.n_values, cap=16)
        self.tmpl, self.slots = _template(schema.prefixes)
        self.lid = lid  # the channel's index; < 0: each row's, in its last column
        self.count = 0
        self.fid = -1  # the writer's index of this block format
        self.it = -1  # >= 0: the error columns are derived from the position at it

    def put(self, values: Any) -> None:
        """One message's values (the schema's order)."""
        self.rows.open_row()[:] = values
        self.rows.commit()
        self.count += 1

    def take(self) -> np.ndarray | None:
        """The rows since the last flush, or None."""
        return self.rows.take() if self.rows.n else None


class _EstChan(_FlatRows):
    """One ``/estimator/<name>`` channel: its clock and rows; a row is t, x[n], p_diag[n],
    innovation[m], then the tail (position, truth -> error, extras)."""

    __slots__ = ("topic", "n", "m", "keys", "next_t", "ix", "ip", "ii")

    def __init__(self, schema: FlatSchema, lid: int, topic: str, n: int, m: int,
                 keys: tuple[str, ...]):
        super().__init__(schema, lid)
        self.topic, self.n, self.m, self.keys = topic, n, m, keys
        self.next_t = -_INF
        self.ix, self.ip, self.ii, self.it = 1, 1 + n, 1 + 2 * n, 1 + 2 * n + m


class _EstBank(_FlatRows):
    """The ``/estimator/<name>`` channels of one filter bank (one schema, position first, no
    innovation or extras; :meth:`RunLog.estimator_bank`).  A fix is one compact row (t, the
    k states, the k covariance diagonals, the truth); the writer makes the channels' message
    rows of them (last column: the row's channel index) and encodes them in one call."""

    __slots__ = ("topics", "lids", "n", "m", "k", "next_t", "raw")

    def __init__(self, schema: FlatSchema, lids: list[int], topics: list[str], n: int, m: int):
        self.tmpl, self.slots = _template(schema.prefixes)
        self.lid, self.count, self.fid = -1, 0, -1  # count: messages per channel
        self.lids, self.topics = np.array(lids, dtype=float), topics
        self.n, self.m, self.k, self.it = n, m, len(lids), 1 + 2 * n
        self.next_t = -_INF
        self.raw = _Rows(1 + self.k * (n + m) + 3, cap=16)

    def put_fix(self, t: float, x: np.ndarray, p_diag: np.ndarray, p_true: Any) -> None:
        row = self.raw.open_row()
        row[0] = t
        a = 1 + self.k * self.n
        row[1:a] = x.ravel()
        row[a:-3] = p_diag.ravel()
        row[-3:] = p_true
        self.raw.commit()
        self.count += 1

    def take(self) -> np.ndarray | None:
        """The fixes since the last flush (compact rows: the writer makes the k messages of
        each, :func:`ag_uav.record.sink._bank_rows`), or None."""
        return self.raw.take() if self.raw.n else None


_WARMED = False


def _warm_encoders() -> None:
    """Load the block encoders (:mod:`ag_uav.record.encode`; compiled on a fresh checkout) now,
    with the argument types the flushes use, so that no loading or compiling lands inside a
    flight's timed loop; a compile says so once."""
    global _WARMED
    if _WARMED:
        return
    from .encode import encode_flat, encode_poses, encode_ticks

    t0 = time.perf_counter()
    rows = np.zeros((2, TICK_HEAD + 4))
    rows[:, 1] = 15.0
    out, idx = np.empty(4096, dtype=np.uint8), np.empty((3, 17), dtype=np.int64)
    st = _template([b"\x09"] * 37 + [b"\x12\x20"] + [b"\x09"] * 3)
    encode_ticks(rows, 4, np.zeros(0, dtype=np.intp), st[0], st[1], _POSE_TMPL, _POSE_SLOTS,
                 _TF_TMPL, np.frombuffer(_WORLD2, dtype=np.uint8).copy(),
                 np.frombuffer(_POSE_MID, dtype=np.uint8).copy(), out, idx[0], idx[1], idx[2])
    flat = _template([b"\x09"] * 3)
    encode_flat(np.zeros((2, 3)), flat[0], flat[1], out, idx[0])
    encode_poses(np.zeros((2, 4)), _POSE_TMPL, _POSE_SLOTS,
                 np.frombuffer(_POSE_MID, dtype=np.uint8).copy(), out, idx[0], idx[1])
    took = time.perf_counter() - t0
    if took > 1.0:
        print(f"compiling the log's encoders: first run only, ~{took:.0f} s (cached for later "
              "runs)", file=sys.stderr, flush=True)
    _WARMED = True


def _close_all(partial: bool = False) -> None:
    for log in list(_OPEN):
        try:
            log.close(partial=partial)
        except Exception:  # noqa: BLE001 - closing the others matters more
            pass


def _on_signal(signum: int, frame: Any) -> None:
    _close_all(partial=True)  # a tick row being filled when the signal came is dropped
    prev = _PREV_HANDLERS.get(signum)
    if callable(prev):
        prev(signum, frame)
        return
    if signum == signal.SIGINT:
        raise KeyboardInterrupt
    raise SystemExit(128 + signum)


def _install_handlers() -> None:
    global _HANDLERS_INSTALLED
    if _HANDLERS_INSTALLED or threading.current_thread() is not threading.main_thread():
        return
    for sig in (signal.SIGTERM, signal.SIGINT):
        try:
            prev = signal.getsignal(sig)
            if prev is _on_signal:
                continue
            signal.signal(sig, _on_signal)
            _PREV_HANDLERS[sig] = prev
        except (ValueError, OSError):  # not allowed here: rely on context manager / atexit
            pass
    atexit.register(_close_all)
    _HANDLERS_INSTALLED = True


# --------------------------------------------------------------------------------------------
# RunLog
# --------------------------------------------------------------------------------------------


def _versions() -> dict[str, str]:
    out = {"python": platform.python_version(), "platform": platform.platform()}
    from importlib.metadata import PackageNotFoundError, version

    for pkg in ("ag-uav", "mujoco", "numpy", "scipy", "foxglove-sdk", "mcap"):
        try:
            out[pkg] = version(pkg)
        except PackageNotFoundError:
            pass
    return out


def _meta_str(v: Any) -> str:
    if isinstance(v, str):
        return v
    try:
        return json.dumps(v, default=str)
    except (TypeError, ValueError):
        return str(v)


class RunLog:
    """MCAP run log (context manager).  See the module docstring for channels and usage.

    :param path: the ``.mcap`` file to write (parent folders are created); a Foxglove layout
        ``layout.json`` is written beside it.
    :param channels: ``"full"``, ``"light"``, ``"none"`` or an iterable of group names
        (:data:`GROUPS`; unnamed groups are off, named ones use the ``full`` rates).
    :param rates: per-group rate overrides in Hz (``None`` = every call, ``0`` = off).
    :param metadata: run metadata (seed, scenario, ...) -> MCAP metadata record ``run``.
    :param config_toml: the resolved config -> attachment ``config.toml``.
    :param flush_wall_s: finish the chunk and flush to the OS at least this often (wall time).
    :param flush_sim_s: ... and hand the rows to the writer at least this often in sim time
        (at the first logged tick after it: a SIGKILL loses at most this plus one tick period of
        the log).  Default 0.3 s with the writer process (killed with it, it may also lose the
        one hand-over it had not written yet), else 0.9 s.
    :param layout: write ``layout.json`` beside the log.
    :param chunk_size: the writer's chunk size in bytes (chunks end sooner, at each flush).
    :param compression: chunk compression: ``"lz4"`` (default), a
        ``foxglove.mcap.MCAPCompression`` member, or ``None`` for none.
    :param writer: ``"process"`` (default): the encoding and the SDK's writer run in a writer
        process forked now (:class:`ag_uav.record.sink.ProcessSink`; in this process where
        ``os.fork`` is missing); ``"inline"``: in this process, at each flush.
    """

    def __init__(
        self,
        path: str | os.PathLike[str],
        *,
        channels: str | Iterable[str] = "full",
        rates: dict[str, float | None] | None = None,
        metadata: dict[str, Any] | None = None,
        config_toml: str = "",
        flush_wall_s: float = 1.0,
        flush_sim_s: float | None = None,
        layout: bool = True,
        chunk_size: int = 1 << 20,
        compression: Any = "lz4",
        writer: str = "process",
    ):
        self.path = Path(path)
        self._write_failed = False  # the writer failed once (disk full): close() quietly
        #: the writer process died mid-flight (:class:`~ag_uav.record.sink.WriterLost`): the
        #: log ends there, the flight goes on unlogged
        self.lost: OSError | None = None
        self.lost_at = 0.0  #: the sim time of the last hand-over before the loss
        if isinstance(channels, str):
            if channels not in PRESETS:
                raise ValueError(f"channels must be one of {list(PRESETS)} or a list of groups")
            base = dict(PRESETS[channels])
        else:
            names = set(channels)
            bad = names - set(GROUPS)
            if bad:
                raise ValueError(f"unknown channel groups {sorted(bad)}; known: {GROUPS}")
            base = {g: (PRESETS["full"][g] if g in names else 0.0) for g in GROUPS}
        for g, r in (rates or {}).items():
            if g not in GROUPS:
                raise ValueError(f"unknown channel group {g!r}; known: {GROUPS}")
            base[g] = r
        self.rates = base
        preset = channels if isinstance(channels, str) else ""
        self._dose_period = DOSE_PERIOD_S.get(preset, DOSE_PERIOD_S["full"])
        self._geo_dose_period = GEO_DOSE_PERIOD_S.get(preset, GEO_DOSE_PERIOD_S["full"])
        self._next_geo_dose = -_INF
        # period per group: 0.0 = every call, inf = off
        self._period = {
            g: (0.0 if r is None else (_INF if r <= 0 else 1.0 / float(r))) for g, r in base.items()
        }
        self.enabled = any(p < _INF for p in self._period.values())
        self.closed = not self.enabled
        self._next_tick = _INF
        self._t_last = 0.0
        # next sim time each group is due (inf = off or closed): the hot paths test only this
        self._next = {g: (-_INF if self._period[g] < _INF and self.enabled else _INF)
                      for g in GROUPS}
        self._counts: dict[str, int] = {}  # rare topics; the frequent ones count in _n_*
        self._n_tf = self._n_pose = self._n_pose_est = self._n_state = self._n_gps = 0
        self._n_geo = self._n_geo_est = self._n_geo_gnss = 0
        self._geo: Any = None  # the GeoFrame once geo() has given the origin
        self._geo_ids: dict[str, int] = {}  # geo topic key -> channel index
        self._fix_codes: dict[str, int] = {}  # GNSS fix type -> its code in the gps rows
        self._est: dict[str, _EstChan] = {}
        self._banks: dict[tuple[str, ...], _EstBank] = {}
        # encoded messages (channel index, bytes, log_time) not yet handed to the writer (the
        # dose maps): they go with the rows at the next flush
        self._pending: list[tuple[int, bytes, int]] = []
        self._ops: list[tuple[Any, ...]] = []  # declarations for the writer's next hand-over
        self._n_chan = 0
        self._flat_rows: list[_FlatRows] = []  # estimator and spray channels, encoded at flush
        self._ch_spray: _FlatRows | None = None
        self._ch_dose: Any = None
        self._dose_bytes = 0  # bytes of dose maps logged (their period doubles per quota)
        self._next_spray = -_INF if self._period["state"] < _INF and self.enabled else _INF
        if not self.enabled:
            return

        import foxglove

        from .sink import open_sink

        self.path.parent.mkdir(parents=True, exist_ok=True)
        _warm_encoders()  # before a writer process is forked: it inherits them
        self._sink = open_sink(str(self.path), compression, chunk_size, writer)
        if flush_sim_s is None:
            flush_sim_s = 0.3 if self._sink.process else 0.9
        en = {g: self._period[g] < _INF for g in GROUPS}
        M = foxglove.messages
        self._M = M
        pose = M.PoseInFrame
        self._tf_id = self._chan("/tf", M.FrameTransforms) if en["tf"] else -1
        if en["pose"]:
            self._pose_ids = [self._chan(tp, pose) for tp in
                              ("/drone/pose", "/drone/pose_est", "/drone/pose_ref")]
        self._gps_id = self._chan("/gps", pose) if en["gps"] else -1
        self._ops.append(("posefmt", _POSE_TMPL, _POSE_SLOTS,
                          np.frombuffer(_POSE_MID, dtype=np.uint8).copy(),
                          np.frombuffer(_WORLD2 + _str_field(3, "base_link"),
                                        dtype=np.uint8).copy()))
        # (t, x, y, z, var e, n, u, fix type code) of the fixes since the last flush
        self._gps_rows = _Rows(8, cap=16)
        self._state_schema: FlatSchema | None = None
        self._ctrl_keys: tuple[str, ...] = ()
        self._n_motors = 0
        self._rows = _Rows(TICK_HEAD)  # the tick rows to encode (re-made by the state schema)
        self._last_row: np.ndarray | None = None
        self._cam: dict[str, Any] = {}
        self._scene_ch: dict[str, int] = {}
        self._next_est: dict[str, float] = {}  # per-camera clocks
        pe = self._period
        self._p_tf, self._p_pose, self._p_state = (pe["tf"] - 1e-9, pe["pose"] - 1e-9,
                                                   pe["state"] - 1e-9)
        self._p_gps, self._p_est = pe["gps"] - 1e-9, pe["estimator"] - 1e-9
        self._p_geo = pe["geo"] - 1e-9
        self._next["geo"] = _INF  # on once geo() gives the origin
        self._tick_groups = [g for g in ("tf", "pose", "state") if en[g]]
        self._next_tick = -_INF if self._tick_groups else _INF
        self._last_true = (_NAN, _NAN, _NAN)
        self._flush_wall_s = float(flush_wall_s)
        self._flush_sim_s = float(flush_sim_s)
        self._last_flush_wall = time.perf_counter()
        self._last_flush_sim = -_INF

        md = {k: _meta_str(v) for k, v in (metadata or {}).items()}
        md.setdefault("channels", channels if isinstance(channels, str) else ",".join(channels))
        md.setdefault("rates_hz", json.dumps(self.rates))
        md.setdefault("created_utc", time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime()))
        self._ops += [("meta", "run", md), ("meta", "versions", _versions())]
        if config_toml:
            self._ops.append(("attach", {"log_time": 0, "create_time": time.time_ns(),
                                         "name": "config.toml", "media_type": "application/toml",
                                         "data": config_toml.encode("utf-8")}))
        self._send([])
        self._layout = layout
        self._write_layout()
        _OPEN.add(self)
        _install_handlers()

    # ---------------------------------------------------------------- context manager
    def __enter__(self) -> RunLog:
        return self

    def __exit__(self, *exc: Any) -> None:
        self.close()

    def __del__(self) -> None:  # last resort; close() is idempotent
        try:
            self.close()
        except Exception:  # noqa: BLE001
            pass

    # ---------------------------------------------------------------- helpers
    def _count(self, topic: str) -> None:
        self._counts[topic] = self._counts.get(topic, 0) + 1

    @property
    def counts(self) -> dict[str, int]:
        """Messages written so far, per topic."""
        out = dict(self._counts)
        n_pose = self._n_pose  # the tick rows count when they are handed out
        for topic, n in (("/tf", self._n_tf), ("/drone/pose", n_pose),
                         ("/drone/pose_ref", n_pose), ("/drone/pose_est", self._n_pose_est),
                         ("/drone/state", self._n_state), ("/gps", self._n_gps),
                         ("/geo/true", self._n_geo), ("/geo/est", self._n_geo_est),
                         ("/geo/gnss", self._n_geo_gnss)):
            if n:
                out[topic] = out.get(topic, 0) + n
        for ec in self._est.values():
            if ec.count:
                out[ec.topic] = ec.count
        for bank in self._banks.values():
            if bank.count:
                out.update(dict.fromkeys(bank.topics, bank.count))
        if self._ch_spray is not None and self._ch_spray.count:
            out["/drone/spray"] = self._ch_spray.count
        return out

    @property
    def writer_cpu_s(self) -> float:
        """CPU seconds of the writer process once the log is closed (0 with the inline writer,
        whose work is this process's own)."""
        sink = getattr(self, "_sink", None)
        return sink.cpu_s if sink is not None else 0.0

    def _send(self, ops: list[tuple[Any, ...]]) -> None:
        """Hand the declarations made since the last hand-over, then ``ops``, to the writer."""
        if self._ops:
            ops = self._ops + ops
            self._ops = []
        try:
            self._sink.send(ops)
        except WriterLost as e:  # the flight goes on unlogged; its summary names the loss
            self._stop_writing(e)

    def _stop_writing(self, err: OSError) -> None:
        """The writer is gone: record ``err`` in :attr:`lost`, log nothing more (every group's
        clock goes to infinity), reap the writer."""
        self.lost, self.lost_at = err, self._t_last
        self._stop_clocks()
        _OPEN.discard(self)
        try:
            self._sink.close()
        except Exception:  # noqa: BLE001 - reaping the dead writer is best effort
            pass

    def _stop_clocks(self) -> None:
        self.closed = True
        self._next_tick = _INF
        for g in self._next:
            self._next[g] = _INF
        for ec in self._est.values():
            ec.next_t = _INF
        for bank in self._banks.values():
            bank.next_t = _INF
        self._next_spray = _INF

    def _drain(self, partial: bool = False, flush: bool = False) -> None:
        """Hand the rows and messages waiting since the last hand-over to the writer (it
        encodes them and writes them merged by log time; ``flush``: then finishes the chunk and
        writes it to the OS).  ``partial``: a row still being filled (a signal arrived
        mid-tick) is dropped, not written half-done."""
        rows = self._rows
        if rows.open and not partial:
            rows.commit()
        elif rows.open:  # dropped: uncounted
            m = int(rows.a[rows.n, 1])
            self._n_tf -= m & 1
            self._n_pose -= (m & 2) >> 1
            self._n_pose_est -= (m & 10) == 10
            self._n_state -= (m & 4) >> 2
            self._n_geo -= (m & 16) >> 4
            self._n_geo_est -= (m & 24) == 24
        rows.open = False
        ops: list[tuple[Any, ...]] = []
        if self._pending:
            ops.append(("msgs", self._pending))
            self._pending = []  # swapped first: a signal handler's close() sends only the rest
        for fr in self._flat_rows:
            r = fr.take()
            if r is not None:
                ops.append(("block", fr.fid, r))
        if self._gps_rows.n:
            ops.append(("gps", self._gps_id, self._gps_rows.take()))
        if rows.n:
            ops.append(("ticks", rows.take()))
        ops.append(("emit",))
        if flush:
            ops.append(("flush",))
        self._send(ops)

    def _maybe_flush(self, t: float) -> None:
        now = _perf_counter()
        if now - self._last_flush_wall >= self._flush_wall_s or (
            t - self._last_flush_sim >= self._flush_sim_s
        ):
            self._drain(flush=True)
            self._last_flush_wall = now
            self._last_flush_sim = t

    def flush(self) -> None:
        """Finish the current chunk and hand everything to the OS now (with the writer
        process: hand it to the writer, which does so)."""
        if not self.closed:
            self._drain(flush=True)
            self._last_flush_wall = time.perf_counter()

    def want(self, group: str, t: float) -> bool:
        """Would a message of ``group`` at sim time ``t`` be logged? (no side effects)

        For ``"estimator"`` this is the group (any estimator); :meth:`want_estimator` answers
        for one estimator."""
        return not self.closed and self._period[group] < _INF and t >= self._next[group]

    def want_estimator(self, name: str, t: float) -> bool:
        """Would :meth:`estimator` log ``name`` at sim time ``t``? (no side effects)  Lets a
        caller skip building the arguments (e.g. a covariance diagonal) when it would not."""
        ec = self._est.get(name)
        if ec is not None:
            return t >= ec.next_t
        return not self.closed and self._period["estimator"] < _INF

    def due(self, t: float) -> bool:
        """True when :meth:`tick` at sim time ``t`` would log something (no side effects): the
        engine builds a tick's arguments only then."""
        return t >= self._next_tick

    def next_due(self, frames: bool = False) -> float:
        """The earliest sim time at which :meth:`tick` (or, with ``frames``, a camera frame)
        would log something (``inf`` when nothing will): the engine calls the log only then."""
        nxt = self._next_tick
        if frames and not self.closed and self._period["camera"] < _INF:
            nxt = min(nxt, self._next["camera"])
        return nxt

    def want_frame(self, t: float) -> bool:
        """True when a camera frame at sim time ``t`` would be logged: render only then."""
        return self.want("camera", t)

    def _chan(self, topic: str, schema: Any, data: bytes | None = None) -> int:
        """A new channel on ``topic`` -> its index, which the writer's operations name.
        ``schema``: a foxglove message class (its well-known schema), or the schema's name
        with ``data`` (a protobuf FileDescriptorSet)."""
        if data is None:
            sc = schema.get_schema()
            name, enc, data = sc.name, sc.encoding, bytes(sc.data)
        else:
            name, enc = schema, "protobuf"
        self._ops.append(("chan", topic, name, enc, data))
        self._n_chan += 1
        return self._n_chan - 1

    def _ts(self, t_ns: int) -> Any:
        return self._M.Timestamp(sec=t_ns // 1_000_000_000, nsec=t_ns % 1_000_000_000)

    # ---------------------------------------------------------------- per-tick data
    def _make_state_schema(self, ctrl_keys: Sequence[str], n_motors: int,
                           ctrl_src: Sequence[int] | None = None, extra: int | None = None,
                           ) -> None:
        """Fix ``/drone/state``'s schema (ctrl keys in tree order, ``n_motors`` rotor values)
        and the tick rows' layout: :data:`TICK_HEAD` columns, the motors, then ``extra`` raw
        columns of which ``ctrl_src[j]`` holds the j-th ctrl key of ``ctrl_keys`` as given
        (default: the ctrl values themselves, in the order given)."""
        fields: list[tuple[str, int]] = [("t", 0)]
        fields += [(f"pos.{a}", 0) for a in "xyz"]
        fields += [(f"vel.{a}", 0) for a in "xyz"]
        fields += [("rpy.roll", 0), ("rpy.pitch", 0), ("rpy.yaw", 0)]
        fields += [(f"ref.{a}", 0) for a in ("x", "y", "z", "vx", "vy", "vz", "yaw")]
        fields += [(f"est.{a}", 0) for a in ("x", "y", "z", "vx", "vy", "vz")]
        fields += [(f"err.{a}", 0) for a in ("x", "y", "z", "horiz", "norm")]
        fields += [(f"est_err.{a}", 0) for a in ("x", "y", "z", "horiz")]
        fields += [("speed", 0), ("spray", 0)]
        fields += [(f"wind.{a}", 0) for a in "xyz"]
        if n_motors:
            fields.append(("motors", n_motors))
        given = list(ctrl_keys)
        # ctrl keys: dots make nested groups (kept contiguous, first-appearance order)
        self._ctrl_keys = tuple(_tree_order(given))
        try:
            schema = FlatSchema("ag_uav.DroneState",
                                fields + [(f"ctrl.{k}", 0) for k in self._ctrl_keys])
        except ValueError:  # e.g. "a" and "a.b" both given: flatten the names
            schema = FlatSchema("ag_uav.DroneState",
                                fields + [(f"ctrl.{k.replace('.', '_')}", 0)
                                          for k in self._ctrl_keys])
        self._n_motors = n_motors
        self._state_schema = schema
        src = list(range(len(given))) if ctrl_src is None else [int(c) for c in ctrl_src]
        pos = {k: src[j] for j, k in enumerate(given)}
        base = TICK_HEAD + n_motors
        self._ctrl_cols = np.array([base + pos[k] for k in self._ctrl_keys], dtype=np.intp)
        self._rows = _Rows(base + (len(given) if extra is None else int(extra)))
        on = self._period["state"] < _INF
        state_id = self._chan("/drone/state", "ag_uav.DroneState", schema.schema_data) if on else -1
        st = _template(schema.prefixes) if on else (_NO_BYTES, np.zeros(0, dtype=np.int64))
        pose_on = self._period["pose"] < _INF
        pose_ids = self._pose_ids if pose_on else [-1] * 3
        # kinds (encode.TF, POSE, REF, EST, STATE) -> channels
        kind_ids = [self._tf_id, pose_ids[0], pose_ids[2], pose_ids[1], state_id]
        self._ops.append(("tickfmt", n_motors, self._ctrl_cols, st[0], st[1],
                          _POSE_TMPL if pose_on else _NO_BYTES,
                          _TF_TMPL if self._tf_id >= 0 else _NO_BYTES, kind_ids))

    def bind_ticks(self, n_motors: int, ctrl_keys: Sequence[str], ctrl_src: Sequence[int],
                   extra: int) -> None:
        """The row layout :meth:`tick_slot` hands out (once, before the first slot): the
        :data:`TICK_HEAD` columns, ``n_motors`` rotor commands, then ``extra`` raw columns;
        ``ctrl_keys[j]`` is logged from raw column ``ctrl_src[j]``."""
        if self._state_schema is None and not self.closed:
            self._make_state_schema(ctrl_keys, n_motors, ctrl_src, extra)

    def tick_slot(self, t: float, est: bool = False) -> np.ndarray | None:
        """The row to fill for a tick at sim time ``t`` (None when nothing is due), from its
        true position on: the columns from :data:`TICK_P` to :data:`TICK_HEAD`, the motors,
        then the raw columns bound by :meth:`bind_ticks` (which must come first).  ``est``: the
        estimate's columns hold one (else they are ignored).  The row is encoded at the next
        flush, so the caller fills it now; :meth:`tick` does the same from one call's
        arguments."""
        if t < self._next_tick:
            return None
        self._t_last = t
        rows = self._rows
        if rows.open:
            rows.commit()
        self._maybe_flush(t)
        nx = self._next
        mask = 0
        if t >= nx["tf"]:
            nx["tf"] = t + self._p_tf
            mask = 1
            self._n_tf += 1
        if t >= nx["pose"]:
            nx["pose"] = t + self._p_pose
            mask |= 2
            self._n_pose += 1
            if est:
                self._n_pose_est += 1
        if t >= nx["state"]:
            nx["state"] = t + self._p_state
            mask |= 4
            self._n_state += 1
        if t >= nx["geo"]:
            nx["geo"] = t + self._p_geo
            mask |= 16
            self._n_geo += 1
            if est:
                self._geo_est()
        self._next_tick = self._tick_clock()
        row = rows.open_row()
        row[0] = t
        row[1] = mask | 8 if est else mask
        self._last_row = row
        self._last_true = None
        return row[TICK_P:]

    def _tick_clock(self) -> float:
        """The next sim time a tick row is due: the earliest of the per-tick groups' clocks."""
        nx = self._next
        nt = nx["tf"]
        if nx["pose"] < nt:
            nt = nx["pose"]
        if nx["state"] < nt:
            nt = nx["state"]
        if nx["geo"] < nt:
            nt = nx["geo"]
        return nt

    def tick(
        self,
        t: float,
        *,
        p_true: Sequence[float],
        q_true_wxyz: Sequence[float],
        v_true: Sequence[float],
        p_ref: Sequence[float],
        v_ref: Sequence[float],
        yaw_ref: float,
        p_est: Sequence[float] | None = None,
        v_est: Sequence[float] | None = None,
        ctrl: dict[str, float] | None = None,
        motors: Sequence[float] = (),
        wind: Sequence[float] = (0.0, 0.0, 0.0),
        spray: bool = False,
    ) -> None:
        """Call every control tick; decimates internally (cheap when nothing is due).  One
        row of :meth:`tick_slot`, filled from the arguments (``p_est`` None: no estimate)."""
        if t < self._next_tick:
            return
        if self._state_schema is None:
            self._make_state_schema(list(ctrl or {}), len(motors))
        self.tick_slot(t, est=p_est is not None)
        row = self._last_row
        row[TICK_P:TICK_Q] = _fit(_flat(p_true), 3)
        row[TICK_Q:TICK_V] = _fit(_flat(q_true_wxyz), 4)
        row[TICK_V:TICK_PREF] = _fit(_flat(v_true), 3)
        row[TICK_PREF:TICK_VREF] = _fit(_flat(p_ref), 3)
        row[TICK_VREF:TICK_YAW] = _fit(_flat(v_ref), 3)
        row[TICK_YAW] = yaw_ref
        if p_est is None:
            row[TICK_PEST:TICK_WIND] = _NAN
        else:
            row[TICK_PEST:TICK_VEST] = _fit(_flat(p_est), 3)
            row[TICK_VEST:TICK_WIND] = _NAN if v_est is None else _fit(_flat(v_est), 3)
        row[TICK_WIND:TICK_SPRAY] = _fit(_flat(wind), 3)
        row[TICK_SPRAY] = 1.0 if spray else 0.0
        nm = self._n_motors
        row[TICK_HEAD:TICK_HEAD + nm] = _fit(_flat(motors), nm)
        g = (ctrl or {}).get
        row[TICK_HEAD + nm:] = [g(k, _NAN) for k in self._ctrl_keys]
        self._rows.commit()

    SPRAY_FIELDS = ("t", "tank_l", "mass_kg", "flow_lps", "nozzles", "power_w", "energy_wh",
                    "battery_frac", "sortie", "ground")

    def spray_state(self, t: float, *, tank_l: float, mass_kg: float, flow_lps: float,
                    nozzles: bool, power_w: float, energy_wh: float, soc: float, sortie: int,
                    ground: bool) -> None:
        """Spray job state (ag_uav.world.spray_job) -> ``/drone/spray`` (``ag_uav.SprayState``:
        tank, vehicle mass, flow, nozzles on, electrical power, energy used, battery fraction left,
        sortie number, on the ground at the base). Logged at the ``state`` group's rate."""
        self.spray_row(t, (tank_l, mass_kg, flow_lps, 1.0 if nozzles else 0.0, power_w,
                           energy_wh, soc, sortie, 1.0 if ground else 0.0))

    def spray_row(self, t: float, values: Sequence[float]) -> None:
        """:meth:`spray_state` with its values as one sequence in :data:`SPRAY_FIELDS` order
        after ``t`` (nozzles and ground as 1.0 / 0.0)."""
        row = self.spray_slot(t)
        if row is not None:
            row[1:] = values
            self.spray_commit()

    def spray_slot(self, t: float) -> np.ndarray | None:
        """The ``/drone/spray`` row to fill at sim time ``t`` (None when none is due): column 0
        holds ``t``, the caller fills the :data:`SPRAY_FIELDS` after it and calls
        :meth:`spray_commit` (the engine's way)."""
        if t < self._next_spray:  # inf when off or closed
            return None
        self._next_spray = t + self._p_state
        if self._ch_spray is None:
            schema = FlatSchema("ag_uav.SprayState", [(k, 0) for k in self.SPRAY_FIELDS])
            self._ch_spray = self._flat(_FlatRows(schema, self._chan(
                "/drone/spray", "ag_uav.SprayState", schema.schema_data)))
            self._write_layout()
        row = self._ch_spray.rows.open_row()
        row[0] = t
        return row

    def spray_commit(self) -> None:
        """The row of the last :meth:`spray_slot` is complete."""
        self._ch_spray.rows.commit()
        self._ch_spray.count += 1

    def spray_due(self, t: float) -> bool:
        """Would :meth:`spray_state` log at sim time ``t``? (no side effects)"""
        return t >= self._next_spray


    def gps(self, t: float, fix_xyz: Sequence[float], var: Sequence[float] | None = None,
            fix_type: str | None = None) -> None:
        """A GPS fix (local ENU metres) -> ``/gps`` PoseInFrame and, once :meth:`geo` gave the
        origin, ``/geo/gnss`` LocationFix with the receiver's reported variances ``var`` (east,
        north, up, m²) and its ``fix_type`` (a colour and metadata ``fix_type``)."""
        if t < self._next["gps"]:  # inf when off or closed
            return
        self._next["gps"] = t + self._p_gps
        row = self._gps_rows.open_row()
        row[0] = t
        row[1], row[2] = fix_xyz[0], fix_xyz[1]
        row[3] = fix_xyz[2] if len(fix_xyz) > 2 else 0.0
        if var is None:
            row[4:7] = _NAN
        else:
            row[4], row[5], row[6] = var[0], var[1], var[2]
        code = 0
        if fix_type is not None:
            code = self._fix_codes.get(fix_type, 0)
            if not code:
                code = self._fix_code(fix_type)
        row[7] = code
        self._gps_rows.commit()
        self._n_gps += 1
        if self._geo is not None and "gnss" in self._geo_ids:
            self._n_geo_gnss += 1

    def _fix_code(self, fix_type: str) -> int:
        """The code of a GNSS fix type in the gps rows (declared to the writer once)."""
        code = self._fix_codes[fix_type] = len(self._fix_codes) + 1
        self._ops.append(("fixtype", code, str(fix_type)))
        return code

    # ---------------------------------------------------------------- geographic topics
    def geo(self, origin: Sequence[float], *, dose_target_l_per_ha: float | None = None) -> None:
        """The run's geodetic origin (lat °, lon °, WGS-84 height m of the local frame's
        origin): turns on the geographic topics (:mod:`ag_uav.record.geo`; group ``geo``):
        LocationFix of the true position, the estimate and the GNSS fixes, and GeoJSON of the
        field, plan, sprayed area and dose (in bands of ``dose_target_l_per_ha``) that
        :meth:`scene`, :meth:`sprayed` and :meth:`dose` log from now on.  Also the metadata
        record ``geo``.  Call once, before :meth:`scene`."""
        if self.closed or self._period["geo"] == _INF or self._geo is not None:
            return
        from .geo import GeoFrame

        self._geo = frame = GeoFrame(origin)
        self._dose_target = float(dose_target_l_per_ha or 0.0)
        M = self._M
        ids = self._geo_ids
        ids["true"] = self._chan("/geo/true", M.LocationFix)
        if self._period["gps"] < _INF:
            ids["gnss"] = self._chan("/geo/gnss", M.LocationFix)
        self._ops.append(("geofmt", frame.origin, ids["true"], -1, ids.get("gnss", -1)))
        lat, lon, h = frame.origin
        self._ops.append(("meta", "geo", {
            "origin_lat_deg": repr(lat), "origin_lon_deg": repr(lon), "origin_alt_m": repr(h),
            "frame": "local ENU metres (x east, y north, z up) about the origin, WGS-84"}))
        self._next["geo"] = -_INF
        self._next_tick = self._tick_clock()

    def _geo_est(self) -> None:
        """``/geo/est``: declared at the first tick row with an estimate (a run without one
        has no such topic)."""
        self._n_geo_est += 1
        if "est" not in self._geo_ids:
            ids = self._geo_ids
            ids["est"] = self._chan("/geo/est", self._M.LocationFix)
            self._ops.append(("geofmt", self._geo.origin, ids["true"], ids["est"],
                              ids.get("gnss", -1)))

    def _geo_json(self, key: str, t: float, text: str) -> None:
        """A GeoJSON message on ``/geo/<key>`` (declared at its first), sent with the next
        hand-over."""
        lid = self._geo_ids.get(key)
        if lid is None:
            from .geo import GEO_TOPICS

            lid = self._geo_ids[key] = self._chan(GEO_TOPICS[key], self._M.GeoJson)
        tn = ns(t)
        self._pending.append((lid, _str_field(1, text), tn))  # foxglove.GeoJSON.geojson
        self._count(f"/geo/{key}")

    def set_truth(self, p_true: Sequence[float]) -> None:
        """The true position at the time of the next ``estimator`` calls (their ``err``): the
        estimator bank calls it before logging a fix's update, so that ``err`` is not measured
        against a pose up to one state period old (at 5 m/s, 50 ms is 0.25 m)."""
        self._last_true = (float(p_true[0]), float(p_true[1]), float(p_true[2]))

    def _truth(self) -> tuple[float, float, float]:
        """The last true position given to :meth:`set_truth` or a tick row."""
        lt = self._last_true
        if lt is None:
            r = self._last_row
            lt = self._last_true = (float(r[TICK_P]), float(r[TICK_P + 1]), float(r[TICK_P + 2]))
        return lt

    def estimator(
        self,
        t: float,
        name: str,
        x: Sequence[float],
        p_diag: Sequence[float],
        innovation: Sequence[float] | None = None,
        extra: dict[str, float] | None = None,
        *,
        pos: Sequence[float] | None = None,
    ) -> None:
        """One estimator's state after an update -> ``/estimator/<name>``.

        ``pos`` is the estimator's position estimate (2 or 3 values); default ``x[:3]`` (pass it
        when the state is not ordered position-first).  ``err`` = pos - the last true position
        given to :meth:`tick`.  The schema is fixed at the first call per name (vector lengths,
        ``extra`` keys); later missing values are written as NaN.  float64 numpy vectors are
        copied into the message as they are (a packed ``repeated double`` is their raw bytes).
        """
        ec = self._est.get(name)
        if ec is None:
            if self.closed or self._period["estimator"] == _INF:
                return
            xs = _flat(x)
            ec = self._est[name] = self._make_est(name, len(xs), innovation, extra)
        elif t < ec.next_t:  # inf once closed
            return
        ec.next_t = t + self._p_est
        n = ec.n
        xa = type(x) is np.ndarray and x.ndim == 1 and x.size == n
        if pos is None:
            pl = x[:3].tolist() if xa else _flat(x)[:3]
        else:
            pl = pos if len(pos) == 3 else _flat(pos)
        tx, ty, tz = self._truth()
        if len(pl) == 3:
            px, py, pz = pl
        else:
            pf = _fit(list(pl), 2)
            px, py, pz = pf[0], pf[1], (tz if len(pl) == 2 else _NAN)
        row = ec.rows.open_row()
        row[0] = t
        row[ec.ix:ec.ip] = x if xa else _fit(_flat(x), n)
        if type(p_diag) is np.ndarray and p_diag.ndim == 1 and p_diag.size <= n:
            k = ec.ip + p_diag.size  # shorter (an error-state covariance): NaN-padded
            row[ec.ip:k] = p_diag
            row[k:ec.ii] = _NAN
        else:
            row[ec.ip:ec.ii] = _fit(_flat(p_diag), n)
        if ec.m:
            row[ec.ii:ec.it] = _NAN if innovation is None else _fit(_flat(innovation), ec.m)
        row[ec.it:ec.it + 7] = (px, py, pz, tx, ty, tz, _NAN)  # err: at the flush (_EstChan)
        if ec.keys:
            g = (extra or {}).get
            row[ec.it + 7:] = [g(k, _NAN) for k in ec.keys]
        ec.rows.commit()
        ec.count += 1

    def estimator_bank(self, t: float, names: Sequence[str], x: np.ndarray,
                       p_diag: np.ndarray, p_true: Sequence[float]) -> None:
        """:meth:`estimator` for a bank of filters of one vehicle at once (no innovation, no
        extras; position first in the state): row j of ``x`` (k, n) and of ``p_diag`` (k, m ≤ n,
        NaN-padded to n; the shapes of the bank's first call) is filter ``names[j]`` on
        ``/estimator/<name>``, ``err`` against ``p_true``.  A fix is one compact row of the
        bank (:class:`_EstBank`); the writer makes the messages of a flush's rows in one call."""
        key = tuple(names)
        bank = self._banks.get(key)
        if bank is None:
            if self.closed or self._period["estimator"] == _INF:
                return
            bank = self._banks[key] = self._make_bank(key, x.shape[1], p_diag.shape[1])
        if t < bank.next_t:  # inf once closed
            return
        bank.next_t = t + self._p_est
        bank.put_fix(t, x, p_diag, p_true)

    def _make_bank(self, names: tuple[str, ...], n: int, m: int) -> _EstBank:
        schema = FlatSchema("ag_uav.EstimatorState", [("t", 0), ("x", n), ("p_diag", n)]
                            + [(f"pos.{a}", 0) for a in "xyz"]
                            + [(f"err.{a}", 0) for a in ("x", "y", "z", "horiz")])
        topics = [f"/estimator/{sanitize_name(nm)}" for nm in names]
        lids = [self._chan(tp, "ag_uav.EstimatorState", schema.schema_data) for tp in topics]
        return self._flat(_EstBank(schema, lids, topics, n, m))

    def _make_est(self, name: str, n: int, innovation: Any, extra: Any) -> _EstChan:
        m = len(_flat(innovation)) if innovation is not None else 0
        keys = tuple(extra or {})
        fields = [("t", 0), ("x", n), ("p_diag", n)]
        if m:
            fields.append(("innovation", m))
        fields += [(f"pos.{a}", 0) for a in "xyz"]
        fields += [(f"err.{a}", 0) for a in ("x", "y", "z", "horiz")]
        fields += [(f"extra.{k}", 0) for k in keys]
        try:
            schema = FlatSchema("ag_uav.EstimatorState", fields)
        except ValueError:
            keys = ()
            schema = FlatSchema("ag_uav.EstimatorState", [f for f in fields
                                                           if not f[0].startswith("extra.")])
        topic = f"/estimator/{sanitize_name(name)}"
        lid = self._chan(topic, "ag_uav.EstimatorState", schema.schema_data)
        return self._flat(_EstChan(schema, lid, topic, n, m, keys))

    def _flat(self, fr: _FlatRows) -> Any:
        """Register a flat-schema channel's row block with the writer (its encoding)."""
        fr.fid = len(self._flat_rows)
        bank = ((fr.k, fr.n, fr.m, fr.lids.astype(int).tolist()) if isinstance(fr, _EstBank)
                else None)
        self._ops.append(("flat", fr.fid, fr.tmpl, fr.slots, fr.lid, fr.it, bank))
        self._flat_rows.append(fr)
        return fr

    # ---------------------------------------------------------------- scene
    def _scene_entities(self, t: float, entities: list[Any], topic: str) -> None:
        if self.closed or self._period["scene"] == _INF:
            return
        lid = self._scene_ch.get(topic)
        if lid is None:
            lid = self._scene_ch[topic] = self._chan(topic, self._M.SceneUpdate)
        self._drain()
        self._send([("log", lid, self._M.SceneUpdate(entities=entities).encode(), ns(t)),
                    ("flush",)])
        self._count(topic)

    def _triangles(self, polys: list[Any], z: float, rgba: tuple[float, ...]) -> list[Any]:
        """Fill shapely polygons with a TriangleListPrimitive (constrained Delaunay)."""
        import shapely

        M = self._M
        pts: list[Any] = []
        for poly in polys:
            if poly.is_empty:
                continue
            tris = shapely.constrained_delaunay_triangles(poly)
            for tri in getattr(tris, "geoms", [tris]):
                if tri.is_empty:
                    continue
                c = list(tri.exterior.coords)[:3]
                pts += [M.Point3(x=float(a), y=float(b), z=z) for a, b in c]
        if not pts:
            return []
        return [M.TriangleListPrimitive(points=pts, color=M.Color(r=rgba[0], g=rgba[1],
                                                                  b=rgba[2], a=rgba[3]))]

    def _loops(self, rings: list[np.ndarray], z: float, rgba: tuple[float, ...],
               thickness: float = 3.0) -> list[Any]:
        M = self._M
        out = []
        for ring in rings:
            ring = np.asarray(ring, dtype=float)
            if len(ring) < 2:
                continue
            out.append(M.LinePrimitive(
                type=M.LinePrimitiveLineType.LineLoop, thickness=thickness, scale_invariant=True,
                points=[M.Point3(x=float(a), y=float(b), z=z) for a, b in ring[:, :2]],
                color=M.Color(r=rgba[0], g=rgba[1], b=rgba[2], a=rgba[3])))
        return out

    def scene(
        self,
        t: float,
        field_outer_xy: Any,
        field_holes_xy: list[Any],
        plan_segments: list[tuple[str, Any, bool]],
        swath: float,
        altitude: float,
        parts: list[tuple[Any, list[Any]]] | None = None,
    ) -> None:
        """Field polygon (filled + outline, holes as obstacles) and planned path -> ``/field``.

        ``plan_segments``: ``(kind, Nx2|Nx3 points, spray)``; spraying segments are drawn green,
        the others (transits) grey.  ``parts``: ``[(outer, holes), ...]`` of a multi-part field
        (replaces ``field_outer_xy`` / ``field_holes_xy``).  Call once at the start.
        """
        if self.closed or self._period["scene"] == _INF:
            return
        import shapely

        M = self._M
        if parts is None:
            parts = [(field_outer_xy, field_holes_xy or [])]
        outers = [np.asarray(o, dtype=float)[:, :2] for o, _ in parts]
        holes = [np.asarray(h, dtype=float)[:, :2] for _, hs in parts for h in hs]
        polys = [shapely.Polygon(o, [np.asarray(h, dtype=float)[:, :2] for h in hs])
                 for o, (_, hs) in zip(outers, parts, strict=True)]
        poly = shapely.union_all(polys)
        ts = self._ts(ns(t))
        field = M.SceneEntity(
            timestamp=ts, frame_id="world", id="field",
            triangles=self._triangles(polys, -0.02, (0.55, 0.45, 0.25, 0.6)),
            lines=self._loops(outers, 0.0, (0.9, 0.8, 0.3, 1.0))
            + self._loops(holes, 0.0, (0.9, 0.2, 0.2, 1.0)),
            metadata=[M.KeyValuePair(key="swath_m", value=str(swath)),
                      M.KeyValuePair(key="altitude_m", value=str(altitude)),
                      M.KeyValuePair(key="area_m2", value=f"{poly.area:.1f}")],
        )
        lines = []
        for _kind, pts, spray in plan_segments:
            pts = np.asarray(pts, dtype=float)
            if len(pts) < 2:
                continue
            z = pts[:, 2] if pts.shape[1] > 2 else np.full(len(pts), float(altitude))
            col = (0.1, 0.85, 0.2, 1.0) if spray else (0.6, 0.6, 0.6, 0.8)
            lines.append(M.LinePrimitive(
                type=M.LinePrimitiveLineType.LineStrip, thickness=2.0, scale_invariant=True,
                points=[M.Point3(x=float(a), y=float(b), z=float(c))
                        for (a, b), c in zip(pts[:, :2], z, strict=True)],
                color=M.Color(r=col[0], g=col[1], b=col[2], a=col[3])))
        plan = M.SceneEntity(timestamp=ts, frame_id="world", id="plan", lines=lines)
        if self._geo is not None:
            from .geo import field_geojson, plan_geojson

            rings = [(o, [np.asarray(h, float) for h in hs])
                     for o, (_, hs) in zip(outers, parts, strict=True)]
            self._geo_json("field", t, field_geojson(self._geo, rings))
            self._geo_json("plan", t, plan_geojson(self._geo, plan_segments))
        self._scene_entities(t, [field, plan], "/field")
        if self._geo is not None:
            self._write_layout()  # with its Map panel, should the run be cut short

    def sprayed(self, t: float, polygons_xy: list[Any]) -> None:
        """Sprayed area (shapely Polygon/MultiPolygon or Nx2 rings) -> ``/sprayed``."""
        if self.closed or self._period["scene"] == _INF:
            return
        import shapely

        polys: list[Any] = []
        for p in polygons_xy:
            if isinstance(p, shapely.MultiPolygon):
                polys += list(p.geoms)
            elif isinstance(p, shapely.Polygon):
                polys.append(p)
            else:
                polys.append(shapely.Polygon(np.asarray(p, dtype=float)[:, :2]))
        ent = self._M.SceneEntity(
            timestamp=self._ts(ns(t)), frame_id="world", id="sprayed",
            triangles=self._triangles(polys, 0.0, (0.1, 0.7, 1.0, 0.45)),
            lines=self._loops([np.asarray(p.exterior.coords) for p in polys], 0.01,
                              (0.1, 0.7, 1.0, 1.0), 1.0),
        )
        if self._geo is not None:
            from .geo import sprayed_geojson

            self._geo_json("sprayed", t, sprayed_geojson(self._geo, polys))
        self._scene_entities(t, [ent], "/sprayed")

    # ---------------------------------------------------------------- dose map
    def want_dose(self, t: float) -> bool:
        """Would :meth:`dose` log a map at sim time ``t``? (no side effects)"""
        return (not self.closed and self._period["scene"] < _INF
                and t >= getattr(self, "_next_dose", -_INF))

    def dose(self, t: float, x0: float, y0: float, cell: float, l_per_ha: Any, *,
             final: bool = False) -> None:
        """The dose map on the ground (L/ha, (ny, nx), row j at y0 + j·cell) -> ``/dose``
        foxglove.Grid (one float32 field ``l_per_ha``, lower-left corner at (x0, y0), 2 cm above
        the ground), at most every :data:`DOSE_PERIOD_S` of sim time, doubled after each
        :data:`DOSE_QUOTA_B` of maps (``final``: always). Part of the ``scene`` group.  With
        :meth:`geo`, a logged map at least :data:`GEO_DOSE_PERIOD_S` after the last (and the
        final one) also goes to ``/geo/dose``: the map in bands of the target rate, made by the
        writer."""
        if self.closed or self._period["scene"] == _INF:
            return
        if not final and t < getattr(self, "_next_dose", -_INF):
            return
        if self._ch_dose is None:
            self._ch_dose = self._chan("/dose", self._M.Grid)
        tn = ns(t)
        msg = enc_grid(_ts_pb(tn), float(x0), float(y0), 0.02, float(cell), l_per_ha)
        self._pending.append((self._ch_dose, msg, tn))
        self._count("/dose")
        self._dose_bytes += len(msg)
        self._next_dose = t + self._dose_period * 2 ** (self._dose_bytes // DOSE_QUOTA_B) - 1e-9
        if (self._geo is not None and self._dose_target > 0
                and (final or t >= self._next_geo_dose)):  # the bands: in the writer
            self._next_geo_dose = t + self._geo_dose_period - 1e-9
            lid = self._geo_ids.get("dose")
            if lid is None:
                lid = self._geo_ids["dose"] = self._chan("/geo/dose", self._M.GeoJson)
            self._ops.append(("geodose", lid, tn, float(x0), float(y0), float(cell),
                              self._dose_target,
                              np.ascontiguousarray(l_per_ha, dtype=np.float64)))
            self._count("/geo/dose")

    # ---------------------------------------------------------------- camera
    def frame(
        self,
        t: float,
        camera: str,
        jpeg: bytes,
        width: int,
        height: int,
        fovy_deg: float,
        pose: tuple[Sequence[float], Sequence[float]] | None = None,
    ) -> None:
        """A JPEG frame -> ``/camera/<camera>`` (+ its CameraCalibration each frame, so a seek
        always finds one).  ``pose`` = (position, quaternion wxyz) of the camera's optical frame
        (z forward, x right, y down; :meth:`ag_uav.record.render.Renderer.camera_pose`) ->
        ``/tf``."""
        if self.closed or not self._due_cam(camera, t):
            return
        M = self._M
        tn = ns(t)
        ts = self._ts(tn)
        frame_id = f"cam_{sanitize_name(camera)}"
        ch = self._cam.get(camera)
        if ch is None:
            base = f"/camera/{sanitize_name(camera)}"
            ch = self._cam[camera] = (self._chan(base, M.CompressedImage),
                                      self._chan(base + "/calibration", M.CameraCalibration),
                                      base)
        img, cal, base = ch
        self._drain()
        fy = 0.5 * height / math.tan(math.radians(fovy_deg) / 2.0)
        fx = fy
        cx, cy = 0.5 * width, 0.5 * height
        ops = [("log", img, M.CompressedImage(timestamp=ts, frame_id=frame_id, data=bytes(jpeg),
                                               format="jpeg").encode(), tn),
               ("log", cal, M.CameraCalibration(
                   timestamp=ts, frame_id=frame_id, width=int(width), height=int(height),
                   distortion_model="plumb_bob", D=[0.0] * 5,
                   K=[fx, 0.0, cx, 0.0, fy, cy, 0.0, 0.0, 1.0],
                   R=[1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0],
                   P=[fx, 0.0, cx, 0.0, 0.0, fy, cy, 0.0, 0.0, 0.0, 1.0, 0.0]).encode(), tn)]
        self._count(base)
        self._count(base + "/calibration")
        if pose is not None and self._tf_id >= 0:
            ops.append(("log", self._tf_id, enc_transform(_ts_pb(tn), _str_field(3, frame_id),
                                                          pose[0], pose[1]), tn))
            self._count("/tf")
        self._send(ops)
        self._maybe_flush(t)

    def _due_cam(self, camera: str, t: float) -> bool:
        """Camera rate is per camera; ``want_frame`` checks the group clock."""
        p = self._period["camera"]
        if p == _INF:
            return False
        key = "camera:" + camera
        if t < self._next_est.get(key, -_INF):
            return False
        self._next_est[key] = t + p - 1e-9
        # the group clock is the earliest of the cameras' clocks
        self._next["camera"] = min(v for k, v in self._next_est.items()
                                   if k.startswith("camera:"))
        return True

    # ---------------------------------------------------------------- end
    def summary(self, summary: dict[str, Any]) -> None:
        """Final metrics -> metadata record ``summary`` and attachment ``summary.json``."""
        if self.closed:
            return
        self._drain()
        self._send([("meta", "summary", {k: _meta_str(v) for k, v in summary.items()}),
                    ("attach", {"log_time": ns(self._t_last), "create_time": time.time_ns(),
                                "name": "summary.json", "media_type": "application/json",
                                "data": json.dumps(summary, default=str, indent=1).encode()})])

    def _write_layout(self, final: bool = False) -> None:
        """``layout.json`` beside the log, for the channels seen so far (before any frame: the
        configured cameras, so that a killed run has a layout; at the end: only the cameras
        that were logged, so a run whose renders failed gets no empty image panels)."""
        if not self._layout:
            return
        try:
            from ..analysis.viewing import write_foxglove_layout

            cams = tuple(self._cam)
            if not cams and not final and self._period["camera"] < _INF:
                cams = ("chase", "down")
            write_foxglove_layout(self.path.parent / "layout.json", cameras=cams,
                                  estimators=tuple(sanitize_name(n) for n in
                                                   [*self._est, *(n for b in self._banks
                                                                  for n in b)]),
                                  ctrl_keys=self._ctrl_keys, n_motors=self._n_motors or 4,
                                  spray=self._ch_spray is not None,
                                  geo=self._geo_topics())
        except Exception:  # noqa: BLE001 - a missing layout never stops a run
            pass

    def _geo_topics(self) -> tuple[str, ...]:
        """The geographic topics declared so far (what the layout's Map panel names)."""
        from .geo import GEO_TOPICS

        return tuple(GEO_TOPICS[k] for k in GEO_TOPICS if k in self._geo_ids)

    def close(self, partial: bool = False) -> None:
        """Finish the file (summary, indexes, footer).  Idempotent; safe in signal handlers
        (which pass ``partial``: a tick row still being filled is dropped)."""
        if self.closed:
            return
        self._stop_clocks()
        try:
            try:
                self._drain(partial)
            finally:
                if self.lost is None:
                    self._sink.close()
        except WriterLost as e:
            self.lost, self.lost_at = e, self._t_last
            raise
        except RuntimeError as e:  # the SDK's writer errors: an OSError naming the file
            err = self.write_error(e)
            if err is None:
                raise
            if not self._write_failed:
                raise err from None
        finally:
            _OPEN.discard(self)
        self._write_layout(final=True)

    def write_error(self, exc: BaseException) -> OSError | None:
        """``exc`` as an :class:`OSError` naming the log if it is the MCAP writer failing to
        write, else None.  The SDK reports an I/O failure as ``RuntimeError("FoxgloveError:
        MCAP error: I/O error ...")`` without the OS error
        (:func:`~ag_uav.record.atomic.silent_write_failure` tells a full disk from the rest).
        After this the log is marked failed: :meth:`close` then finishes quietly, leaving the
        file as written so far (every complete chunk is readable; ``ag-uav recover`` indexes
        it)."""
        if not isinstance(exc, RuntimeError) or "FoxgloveError" not in str(exc):
            return None
        self._write_failed = True
        return silent_write_failure(self.path, "the run log stops at its last complete chunk; "
                                               "`ag-uav recover` indexes it")


def _flat(a: Any) -> list[float]:
    """A flat list of floats from a numpy array, list or tuple (cheap for ndarrays)."""
    if isinstance(a, np.ndarray):
        return a.ravel().tolist()
    if isinstance(a, list):
        return a
    return list(a)


def _fit(a: list[float], k: int) -> list[float]:
    """``a`` truncated or NaN-padded to length ``k`` (always a new list)."""
    if len(a) >= k:
        return list(a[:k])
    return list(a) + [_NAN] * (k - len(a))


def _tree_order(keys: list[str]) -> list[str]:
    """Order dotted keys so that every group is contiguous (first-appearance order)."""
    tree: dict[str, Any] = {}
    for k in keys:
        node = tree
        for part in k.split(".")[:-1]:
            node = node.setdefault(part + ".", {})
        node[k.split(".")[-1]] = k
    out: list[str] = []

    def walk(node: dict[str, Any]) -> None:
        for v in node.values():
            if isinstance(v, dict):
                walk(v)
            else:
                out.append(v)

    walk(tree)
    return out


# --------------------------------------------------------------------------------------------
# Synthetic run (tests, demos, benchmarks): a drone flying a lawnmower over a small field
# --------------------------------------------------------------------------------------------


def lawnmower_plan(
    width: float = 60.0, height: float = 40.0, swath: float = 8.0, altitude: float = 3.0
) -> list[tuple[str, np.ndarray, bool]]:
    """Boustrophedon legs along x over ``[0, width] x [0, height]`` with transits between."""
    segs: list[tuple[str, np.ndarray, bool]] = []
    ys = np.arange(swath / 2, height, swath)
    prev = None
    for i, y in enumerate(ys):
        xa, xb = (2.0, width - 2.0) if i % 2 == 0 else (width - 2.0, 2.0)
        leg = np.array([[xa, y, altitude], [xb, y, altitude]])
        if prev is not None:
            segs.append(("transit", np.array([prev, leg[0]]), False))
        segs.append(("leg", leg, True))
        prev = leg[1]
    return segs


def synthetic_run(
    log: RunLog,
    duration: float = 30.0,
    *,
    dt: float = 0.01,
    gps_hz: float = 10.0,
    speed: float = 4.0,
    seed: int = 0,
    estimators: Sequence[str] = ("kf", "mckf"),
    on_tick: Any = None,
    origin: Sequence[float] | None = None,
) -> int:
    """Drive ``log`` like the simulation would: ticks at ``1/dt``, GPS fixes (RTK fixed, one
    in five RTK float), estimators.

    ``on_tick(t, p, q_wxyz)`` is called after each tick (e.g. to pose a body and render).
    ``origin`` (lat, lon, h): the geographic topics too (:meth:`RunLog.geo`).  Returns the tick
    count.  Deterministic for a given ``seed``.
    """
    rng = np.random.default_rng(seed)
    plan = lawnmower_plan()
    outer = np.array([[0, 0], [60, 0], [60, 40], [0, 40]], dtype=float)
    hole = np.array([[28, 18], [32, 18], [32, 22], [28, 22]], dtype=float)
    if origin is not None:
        log.geo(origin, dose_target_l_per_ha=1.0)
    log.scene(0.0, outer, [hole], plan, swath=8.0, altitude=3.0)
    pts = np.concatenate([s[1] for s in plan])
    seg_len = np.linalg.norm(np.diff(pts, axis=0), axis=1)
    s_cum = np.concatenate([[0.0], np.cumsum(seg_len)])
    n = int(round(duration / dt))
    gps_every = max(1, int(round(1.0 / (gps_hz * dt))))
    lag = np.zeros(3)
    est = {name: np.zeros(6) for name in estimators}
    wind = np.array([2.0, 0.5, 0.0])
    for k in range(n):
        t = k * dt
        s = min(speed * t, s_cum[-1] - 1e-6)
        i = int(np.searchsorted(s_cum, s, side="right") - 1)
        i = min(i, len(seg_len) - 1)
        u = (s - s_cum[i]) / max(seg_len[i], 1e-9)
        d = (pts[i + 1] - pts[i]) / max(seg_len[i], 1e-9)
        p_ref = pts[i] + u * (pts[i + 1] - pts[i])
        v_ref = speed * d
        yaw = math.atan2(d[1], d[0])
        lag = 0.97 * lag + 0.03 * rng.normal(0.0, 0.3, 3)
        p = p_ref + lag
        v = v_ref + rng.normal(0.0, 0.05, 3)
        q = (math.cos(yaw / 2), 0.02, -0.03, math.sin(yaw / 2))
        qn = math.sqrt(sum(c * c for c in q))
        q = tuple(c / qn for c in q)
        e = p_ref - p
        ctrl = {}
        for ax, ev in zip(("x", "y", "z"), e, strict=True):
            ctrl[f"{ax}.E"] = float(np.clip(0.3 * ev, -1, 1))
            ctrl[f"{ax}.dE"] = float(np.clip(0.1 * ev, -1, 1))
            ctrl[f"{ax}.U"] = 0.5 * ctrl[f"{ax}.E"]
            ctrl[f"{ax}.I"] = 0.01 * t
            ctrl[f"{ax}.u"] = 2.0 * ev
        motors = [0.5 + 0.01 * math.sin(t + j) for j in range(4)]
        p_est = next(iter(est.values()))[:3] if est else None
        log.tick(t, p_true=p, q_true_wxyz=q, v_true=v, p_ref=p_ref, v_ref=v_ref, yaw_ref=yaw,
                 p_est=p_est, v_est=v, ctrl=ctrl, motors=motors, wind=wind,
                 spray=plan[min(i, len(plan) - 1)][2])
        if k % gps_every == 0:
            fix = p + rng.normal(0.0, 0.8, 3) * np.array([1, 1, 0.5])
            float_ = k % (5 * gps_every) == 0
            log.gps(t, fix, (0.64, 0.64, 0.16) if float_ else (0.01, 0.01, 0.02),
                    "rtk-float" if float_ else "rtk-fixed")
            for j, (name, x) in enumerate(est.items()):
                a = 0.3 + 0.2 * j
                innov = fix - x[:3]
                x[:3] += a * innov
                x[3:] = v
                log.estimator(t, name, x, np.full(6, 0.5 / (1 + j)), innov,
                              {"nis": float(innov @ innov)}, pos=x[:3])
        if on_tick is not None:
            on_tick(t, p, q)
    return n
