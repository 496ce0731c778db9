"""The run log's wire format: protobuf messages of ``double`` fields (:class:`FlatSchema`), the
hand-encoded Foxglove PoseInFrame / FrameTransform / Grid messages, the byte templates that
:mod:`ag_uav.record.encode` fills in blocks, and the row blocks that wait for the writer.

Field numbers are those of the schemas the Foxglove SDK ships (checked in tests by decoding);
the encoding is protobuf's wire format (https://protobuf.dev/programming-guides/encoding/).
"""

from __future__ import annotations

import struct
import sys
import time
from collections.abc import Sequence
from typing import Any

import numpy as np

NAN = float("nan")
INF = float("inf")


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


def varint(v: int) -> bytes:
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
            tag = len(varint(i << 3))
            if isinstance(v, dict):
                sub = FlatSchema._size(v)
                size += tag + len(varint(sub)) + sub
            elif v == 0:
                size += tag + 8
            else:
                size += tag + len(varint(8 * v)) + 8 * v
        return size

    def _layout(self, node: dict[str, Any], prefixes: list[bytes], head: bytes = b"") -> int:
        """Append one prefix per value; ``head`` = pending headers of groups opened here."""
        pending = head
        for i, (_, v) in enumerate(node.items(), start=1):
            if isinstance(v, dict):
                sub = self._size(v)
                pending += varint((i << 3) | 2) + varint(sub)
                if sub == 0:
                    continue
                self._layout(v, prefixes, pending)
                pending = b""
            elif v == 0:
                prefixes.append(pending + varint((i << 3) | 1))
                pending = b""
            else:
                prefixes.append(pending + varint((i << 3) | 2) + varint(8 * v))
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


def template(prefixes: Sequence[bytes]) -> tuple[np.ndarray, np.ndarray]:
    """:class:`_Packer`'s layout as a byte template (uint8, zeros where the values go) and the
    offset of each value's 8 bytes in it: what :mod:`ag_uav.record.encode` fills."""
    tmpl = bytearray()
    slots: list[int] = []
    for p in prefixes:
        tmpl += p
        slots.append(len(tmpl))
        tmpl += bytes(8)
    return np.frombuffer(bytes(tmpl), dtype=np.uint8).copy(), np.array(slots, dtype=np.int64)


class Rows:
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
POSE_TMPL, POSE_SLOTS = template([b"\x0a\x1b\x09", b"\x11", b"\x19", b"\x12\x24\x09",
                                     b"\x11", b"\x19", b"\x21"])
TF_TMPL = POSE_TMPL.copy()
TF_TMPL[[0, 29]] = (0x22, 0x2A)  # FrameTransform: translation (4), rotation (5)
NO_BYTES = np.zeros(0, dtype=np.uint8)


# Hand-encoded foxglove.PoseInFrame / foxglove.FrameTransform (protobuf wire format; the field
# numbers are those of the schemas the SDK ships, checked in tests by decoding).  ~2x faster than
# building the SDK's message objects, and these are the most frequent messages.

_POSE = struct.Struct("<2sBdBdBd2sBdBdBdBd")  # Pose / translation+rotation: 67 bytes


_TS_SEC: dict[int, bytes] = {}
_TS_NSEC: dict[int, bytes] = {}
_TS_CACHE_MAX = 20_000


def ts_pb(tn: int) -> bytes:
    """google.protobuf.Timestamp body for ``tn`` ns (>= 0); both halves are memoised."""
    sec, nsec = divmod(tn, 1_000_000_000)
    a = _TS_SEC.get(sec)
    if a is None:
        a = b"\x08" + varint(sec) if sec else b""
        if len(_TS_SEC) < _TS_CACHE_MAX:
            _TS_SEC[sec] = a
    b = _TS_NSEC.get(nsec)
    if b is None:
        b = b"\x10" + varint(nsec) if nsec else b""
        if len(_TS_NSEC) < _TS_CACHE_MAX:
            _TS_NSEC[nsec] = b
    return a + b


def _ts_field(tn: int) -> bytes:
    """Field 1 (``timestamp``) of PoseInFrame / FrameTransform: tag, length, Timestamp body."""
    ts = ts_pb(tn)
    return b"\x0a" + _BYTE[len(ts)] + ts  # a Timestamp body is at most 12 bytes


def str_field(num: int, s: str) -> bytes:
    b = s.encode()
    return varint((num << 3) | 2) + varint(len(b)) + b


WORLD2 = str_field(2, "world")
POSE_MID = WORLD2 + b"\x1a\x43"  # PoseInFrame: frame_id "world", then the 67-byte pose
_D = struct.Struct("<d")
_PACKD: dict[int, struct.Struct] = {}


def _f8bytes(a: Any, k: int) -> bytes:
    """``k`` little-endian doubles from ``a`` (NaN-padded / truncated), as a packed vector."""
    if type(a) is np.ndarray and a.size == k and a.dtype.str == "<f8":
        return a.tobytes()  # little-endian doubles: protobuf's packed encoding as they are
    st = _PACKD.get(k)
    if st is None:
        st = _PACKD[k] = struct.Struct(f"<{k}d")
    v = as_floats(a)
    return st.pack(*(v if len(v) == k else fit(v, k)))


def enc_pose_in_frame(ts: bytes, p: Sequence[float], q: Sequence[float]) -> bytes:
    """foxglove.PoseInFrame in frame ``world``; ``ts`` from :func:`ts_pb`, ``q`` = wxyz."""
    body = _POSE.pack(b"\x0a\x1b", 9, p[0], 17, p[1], 25, p[2],
                      b"\x12\x24", 9, q[1], 17, q[2], 25, q[3], 33, q[0])
    return b"\x0a" + varint(len(ts)) + ts + WORLD2 + b"\x1a\x43" + body


def enc_transform(ts: bytes, child3: bytes, p: Sequence[float], q: Sequence[float]) -> bytes:
    """One foxglove.FrameTransform world->child, wrapped as FrameTransforms.transforms[i].

    ``child3`` = ``str_field(3, child)``; concatenate several for one FrameTransforms message.
    """
    body = (b"\x0a" + varint(len(ts)) + ts + WORLD2 + child3
            + _POSE.pack(b"\x22\x1b", 9, p[0], 17, p[1], 25, p[2],
                         b"\x2a\x24", 9, q[1], 17, q[2], 25, q[3], 33, q[0]))
    return b"\x0a" + varint(len(body)) + body


_GRID_FIELD = b"\x0a\x08l_per_ha" + b"\x15" + bytes(4) + b"\x18\x07"  # float32 at offset 0
_U32 = struct.Struct("<I")


def enc_grid(ts: bytes, x0: float, y0: float, z: float, cell: float, values: Any) -> bytes:
    """foxglove.Grid in frame ``world``: ``values`` ((ny, nx), row j at y0 + j·cell) as one
    float32 field ``l_per_ha``, lower-left corner at (x0, y0, z); ``ts`` from :func:`ts_pb`."""
    a = np.ascontiguousarray(values, dtype="<f4")
    nx = a.shape[1]
    data = a.tobytes()
    return (b"\x0a" + varint(len(ts)) + ts + WORLD2 + b"\x1a\x43"
            + _POSE.pack(b"\x0a\x1b", 9, x0, 17, y0, 25, z, b"\x12\x24", 9, 0.0, 17, 0.0, 25, 0.0,
                         33, 1.0)
            + b"\x25" + _U32.pack(nx) + b"\x2a\x12\x09" + _D.pack(cell) + b"\x11" + _D.pack(cell)
            + b"\x35" + _U32.pack(4 * nx) + b"\x3d" + _U32.pack(4)
            + b"\x42" + varint(len(_GRID_FIELD)) + _GRID_FIELD
            + b"\x4a" + varint(len(data)) + data)

class FlatRows:
    """A :class:`FlatSchema` channel whose messages wait as rows of values (column 0 the sim
    time), handed to the writer at the flush and encoded there together
    (:func:`ag_uav.record.encode.encode_flat`)."""

    __slots__ = ("rows", "tmpl", "slots", "lid", "count", "fid", "it")

    def __init__(self, schema: FlatSchema, lid: int):
        self.rows = Rows(schema.n_values, cap=16)
        self.tmpl, self.slots = template(schema.prefixes)
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


class EstChan(FlatRows):
    """One ``/estimator/<name>`` channel: its clock and rows; a row is t, x[n], p_diag[n],
    innovation[m], then the tail (position, truth -> error, extras)."""

    __slots__ = ("topic", "n", "m", "keys", "next_t", "ix", "ip", "ii")

    def __init__(self, schema: FlatSchema, lid: int, topic: str, n: int, m: int,
                 keys: tuple[str, ...]):
        super().__init__(schema, lid)
        self.topic, self.n, self.m, self.keys = topic, n, m, keys
        self.next_t = -INF
        self.ix, self.ip, self.ii, self.it = 1, 1 + n, 1 + 2 * n, 1 + 2 * n + m


class EstBank(FlatRows):
    """The ``/estimator/<name>`` channels of one filter bank (one schema, position first, no
    innovation or extras; :meth:`RunLog.estimator_bank`).  A fix is one compact row (t, the
    k states, the k covariance diagonals, the truth); the writer makes the channels' message
    rows of them (last column: the row's channel index) and encodes them in one call."""

    __slots__ = ("topics", "lids", "n", "m", "k", "next_t", "raw")

    def __init__(self, schema: FlatSchema, lids: list[int], topics: list[str], n: int, m: int):
        self.tmpl, self.slots = template(schema.prefixes)
        self.lid, self.count, self.fid = -1, 0, -1  # count: messages per channel
        self.lids, self.topics = np.array(lids, dtype=float), topics
        self.n, self.m, self.k, self.it = n, m, len(lids), 1 + 2 * n
        self.next_t = -INF
        self.raw = Rows(1 + self.k * (n + m) + 3, cap=16)

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
        each, :func:`ag_uav.record.backend.bank_rows`), or None."""
        return self.raw.take() if self.raw.n else None


_WARMED = False


def warm_encoders() -> None:
    """Load the block encoders (:mod:`ag_uav.record.encode`; compiled on a fresh checkout) now,
    with the argument types the flushes use, so that no loading or compiling lands inside a
    flight's timed loop; a compile says so once."""
    global _WARMED
    if _WARMED:
        return
    from .encode import TickFormat, encode_flat, encode_poses, encode_ticks

    t0 = time.perf_counter()
    rows = np.zeros((2, TICK_HEAD + 4))
    rows[:, 1] = 15.0
    out, idx = np.empty(4096, dtype=np.uint8), np.empty((3, 17), dtype=np.int64)
    st = template([b"\x09"] * 37 + [b"\x12\x20"] + [b"\x09"] * 3)
    fmt = TickFormat(4, np.zeros(0, dtype=np.intp), st[0], st[1], POSE_TMPL, POSE_SLOTS,
                     TF_TMPL, np.frombuffer(WORLD2, dtype=np.uint8).copy(),
                     np.frombuffer(POSE_MID, dtype=np.uint8).copy())
    encode_ticks(rows, fmt, out, idx[0], idx[1], idx[2])
    flat = template([b"\x09"] * 3)
    encode_flat(np.zeros((2, 3)), flat[0], flat[1], out, idx[0])
    encode_poses(np.zeros((2, 4)), POSE_TMPL, POSE_SLOTS,
                 np.frombuffer(POSE_MID, dtype=np.uint8).copy(), out, idx[0], idx[1])
    took = time.perf_counter() - t0
    if took > 1.0:
        print(f"compiling the log's encoders: first run only, ~{took:.0f} s (cached for later "
              "runs)", file=sys.stderr, flush=True)
    _WARMED = True

def as_floats(a: Any) -> list[float]:
    """A flat list of floats from a numpy array, list or tuple (cheap for ndarrays)."""
    if isinstance(a, np.ndarray):
        return a.ravel().tolist()
    if isinstance(a, list):
        return a
    return list(a)


def fit(a: list[float], k: int) -> list[float]:
    """``a`` truncated or NaN-padded to length ``k`` (always a new list)."""
    if len(a) >= k:
        return list(a[:k])
    return list(a) + [NAN] * (k - len(a))


def tree_order(keys: list[str]) -> list[str]:
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
