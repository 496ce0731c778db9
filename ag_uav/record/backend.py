"""The MCAP file of a run log: foxglove-sdk's writer, its channels and the block encoders
(:class:`Backend`), executing the operations :class:`ag_uav.record.runlog.RunLog` hands over at
each flush (:mod:`ag_uav.record.sink` runs it in the flying process or in a writer process).

The operations (tuples, executed in order):

``("chan", topic, schema_name, schema_encoding, schema_data)``
    a channel; its index (from 0, in order) is the ``lid`` the other operations name.
``("flat", fid, tmpl, slots, lid, it, bank)``
    a flat-schema block format (:func:`ag_uav.record.encode.encode_flat`): ``lid`` < 0 takes
    each row's channel from its last column; ``it`` >= 0: the error columns are derived from
    the position at ``it`` and the truth after it; ``bank`` = (k, n, m, channels): the block's
    rows are a filter bank's compact fix rows, k messages each.
``("posefmt", tmpl, slots, head, tf_head)``
    the pose encoding (``/gps`` and the ticks' poses; ``head``: the bytes between the stamp
    and the pose, ``tf_head`` a transform's).
``("tickfmt", n_motors, ctrl_cols, st_tmpl, st_slots, pose_tmpl, tf_tmpl, kind_lids)``
    the tick rows' encoding (:func:`ag_uav.record.encode.encode_ticks`).
``("geofmt", origin, lid_true, lid_est, lid_gnss)``, ``("fixtype", code, name)``
    the geographic topics (:mod:`ag_uav.record.geo`): the origin and the LocationFix channels
    (< 0: none) the tick rows flagged 16 and the GNSS rows go to; a GNSS fix type's code.
``("msgs", [(lid, bytes, tn), ...])``, ``("block", fid, rows)``, ``("gps", lid, rows)``,
``("ticks", rows)``, ``("geodose", lid, tn, x0, y0, cell, target, grid)``
    messages for the next ``emit`` (all merged by log time).
``("emit",)``, ``("log", lid, bytes, tn)``, ``("flush",)``, ``("meta", name, dict)``,
``("attach", kwargs)``, ``("close",)``.
"""

from __future__ import annotations

import errno
import itertools
import operator
import os
import re
from pathlib import Path
from typing import Any

import numpy as np

__all__ = ["Backend", "bank_rows", "os_error"]

_LOG_TIME = operator.itemgetter(2)
#: the most bytes one tick row's messages take, besides the state message
_ROW_POSE_BYTES = 4 * (2 + 14 + 32 + 67)
#: a LocationFix's ``frame_id`` (field 7): the true position is the body frame's
_BASE_LINK7 = b"\x3a\x09base_link"


def _ns_list(t: np.ndarray) -> list[int]:
    """Sim times (s) -> log times (ns, >= 0) as Python ints."""
    return np.maximum(np.rint(t * 1e9), 0).astype(np.int64).tolist()


def _est_err(r: np.ndarray, it: int) -> None:
    """An estimator row block's tail: position (``it``…), the truth (``it + 3``…) -> ``err`` =
    position − truth in place of the truth, and its horizontal norm at ``it + 6``."""
    d = r[:, it + 3:it + 6]
    np.subtract(r[:, it:it + 3], d, out=d)
    r[:, it + 6] = np.sqrt(d[:, 0] * d[:, 0] + d[:, 1] * d[:, 1])


def bank_rows(r: np.ndarray, k: int, n: int, m: int, lids: list[int]) -> np.ndarray:
    """A filter bank's compact fix rows (t, the k states of n, the k covariance diagonals of
    m, the truth) -> k message rows per fix (t, x[n], p_diag[n] NaN-padded, position, truth,
    NaN, channel index), as :meth:`_block` encodes them."""
    f, it, a = len(r), 1 + 2 * n, 1 + k * n
    x = r[:, 1:a].reshape(f, k, n)
    out = np.full((f, k, it + 8), np.nan)
    out[:, :, 0] = r[:, :1]
    out[:, :, 1:1 + n] = x
    out[:, :, 1 + n:1 + n + m] = r[:, a:a + k * m].reshape(f, k, m)
    out[:, :, it:it + 3] = x[:, :, :3]
    out[:, :, it + 3:it + 6] = r[:, None, -3:]
    out[:, :, it + 7] = lids
    return out.reshape(f * k, it + 8)


def os_error(e: OSError, path: Path) -> OSError:
    """The SDK's OSError (errno only in its text, "... (os error 28)") with errno and path."""
    m = re.search(r"os error (\d+)", str(e))
    code = e.errno if e.errno is not None else (int(m.group(1)) if m else errno.EIO)
    return OSError(code, os.strerror(code), str(path))


class Backend:
    """The MCAP file: foxglove-sdk's writer (LZ4 chunks), its channels and the encoders."""

    def __init__(self, path: str, compression: Any, chunk_size: int):
        import foxglove
        from foxglove.mcap import MCAPCompression, MCAPWriteOptions

        self._fg = foxglove
        self._ctx = foxglove.Context()
        try:
            self._writer = foxglove.open_mcap(
                path, allow_overwrite=True, context=self._ctx,
                writer_options=MCAPWriteOptions(
                    compression=(MCAPCompression.Lz4 if compression == "lz4" else compression),
                    chunk_size=chunk_size, compression_threads=0, profile=""))
        except OSError as e:  # the SDK's: "Read-only file system (os error 30)", no file name
            raise os_error(e, Path(path)) from None
        self._channels: list[Any] = []
        self._logs: list[Any] = []
        self._flats: dict[int, tuple[Any, ...]] = {}
        self._tick: Any = None  # the tick rows' TickFormat
        self._pend: list[tuple[int, bytes, int]] = []
        self._out = np.zeros(0, dtype=np.uint8)
        self._idx = np.zeros((3, 1), dtype=np.int64)
        self._geo: Any = None  # (GeoFrame, lid true, lid est, lid gnss)
        self._geo_stash: list[tuple[Any, ...]] = []  # positions waiting for the emit
        self._geo_bounds: list[float] = []  # lat min, max, lon min, max, fixes of /geo/true
        self._fix_tail: dict[int, tuple[bytes, tuple[float, ...]]] = {}
        self.closed = False

    def run(self, ops: list[tuple[Any, ...]]) -> None:
        """Execute ``ops`` in order (see the module docstring)."""
        for op in ops:
            getattr(self, "_" + op[0])(*op[1:])

    # ------------------------------------------------------------------ declarations
    def _chan(self, topic: str, name: str, encoding: str, data: bytes) -> None:
        fg = self._fg
        ch = fg.Channel(topic, message_encoding="protobuf", context=self._ctx,
                        schema=fg.Schema(name=name, encoding=encoding, data=data))
        self._channels.append(ch)
        self._logs.append(ch.base.log)

    def _flat(self, fid: int, tmpl: np.ndarray, slots: np.ndarray, lid: int, it: int,
              bank: tuple[int, int, int, list[int]] | None = None) -> None:
        self._flats[fid] = (tmpl, slots, lid, it, bank)

    def _posefmt(self, tmpl: np.ndarray, slots: np.ndarray, head: np.ndarray,
                 tf_head: np.ndarray) -> None:
        self._pose = (tmpl, slots, head, tf_head)

    def _tickfmt(self, n_motors: int, ctrl_cols: np.ndarray, st_tmpl: np.ndarray,
                 st_slots: np.ndarray, pose_tmpl: np.ndarray, tf_tmpl: np.ndarray,
                 kind_lids: list[int]) -> None:
        from .encode import TickFormat

        _, slots, head, tf_head = self._pose
        self._tick = TickFormat(n_motors, ctrl_cols, st_tmpl, st_slots, pose_tmpl, slots,
                                tf_tmpl, tf_head, head)
        self._kind_lids = kind_lids
        self._row_bytes = _ROW_POSE_BYTES + len(st_tmpl)

    def _geofmt(self, origin: tuple[float, float, float], lid_true: int, lid_est: int,
                lid_gnss: int) -> None:
        from .geo import GeoFrame

        self._geo = (GeoFrame(origin), lid_true, lid_est, lid_gnss)

    def _fixtype(self, code: int, name: str) -> None:
        from .geo import fix_color, kv_metadata

        self._fix_tail[code] = (kv_metadata("fix_type", name), fix_color(name))

    # ------------------------------------------------------------------ messages
    def _msgs(self, msgs: list[tuple[int, bytes, int]]) -> None:
        self._pend.extend(msgs)

    def _geo_ticks(self, r: np.ndarray) -> None:
        """The tick rows flagged 16 -> ``/geo/true`` (and ``/geo/est`` where the row holds an
        estimate), converted and encoded at the ``emit`` (:meth:`_geo_emit`)."""
        _, lid_true, lid_est, _ = self._geo
        mask = r[:, 1].astype(np.int64)
        on = (mask & 16) != 0
        if not on.any():
            return
        g, tns = r[on], _ns_list(r[on, 0])
        self._geo_stash.append((lid_true, tns, g[:, 2:5], None, None))
        e = (mask[on] & 8) != 0
        if lid_est >= 0 and e.any():
            self._geo_stash.append((lid_est, [tn for tn, k in zip(tns, e, strict=True) if k],
                                    g[e, 19:22], None, None))

    def _geo_gnss(self, r: np.ndarray) -> None:
        """The GNSS rows (t, x, y, z, variances e n u, type code) -> ``/geo/gnss``."""
        self._geo_stash.append((self._geo[3], _ns_list(r[:, 0]), r[:, 1:4], r[:, 4:7],
                                r[:, 7].astype(np.int64).tolist()))

    def _geo_emit(self) -> None:
        """The stashed positions of this hand-over -> LocationFix messages: one conversion to
        lat/lon/altitude for all of them, then one encoding per kind."""
        from .geo import NO_TYPE_COLOR, location_fixes

        stash, self._geo_stash = self._geo_stash, []
        lla = self._geo[0].lla(np.concatenate([x[2] for x in stash]))
        o = 0
        for lid, tns, xyz, var, codes in stash:
            part, o = lla[o:o + len(xyz)], o + len(xyz)
            if codes is None and lid == self._geo[1]:
                msgs = location_fixes(tns, part, head=_BASE_LINK7)
                self._bound(part)
            elif codes is None:
                msgs = location_fixes(tns, part)
            else:
                no = (b"", NO_TYPE_COLOR)
                tails = [self._fix_tail.get(c, no) for c in codes]
                msgs = location_fixes(tns, part, var_enu=var,
                                      rgba=np.array([tl[1] for tl in tails]),
                                      tails=[tl[0] for tl in tails])
            self._pend.extend(zip(itertools.repeat(lid), msgs, tns, strict=False))

    def _bound(self, lla: np.ndarray) -> None:
        """Widen the true track's lat/lon bounds (metadata ``geo_bounds`` at the close)."""
        b = [float(lla[:, 0].min()), float(lla[:, 0].max()), float(lla[:, 1].min()),
             float(lla[:, 1].max()), len(lla)]
        if self._geo_bounds:
            o = self._geo_bounds
            b = [min(o[0], b[0]), max(o[1], b[1]), min(o[2], b[2]), max(o[3], b[3]),
                 o[4] + b[4]]
        self._geo_bounds = b

    def _geodose(self, lid: int, tn: int, x0: float, y0: float, cell: float, target: float,
                 grid: np.ndarray) -> None:
        """``/geo/dose``: the dose map's bands as GeoJSON
        (:func:`ag_uav.record.geo.dose_geojson`)."""
        from .geo import dose_geojson, geojson_message

        text = dose_geojson(self._geo[0], x0, y0, cell, grid, target)
        self._pend.append((lid, geojson_message(text), tn))

    def _block(self, fid: int, r: np.ndarray) -> None:
        from .encode import encode_flat

        tmpl, slots, lid, it, bank = self._flats[fid]
        if bank is not None:
            r = bank_rows(r, *bank)
        if it >= 0:
            _est_err(r, it)
        n, size = len(r), len(tmpl)
        out = np.empty(n * size, dtype=np.uint8)
        encode_flat(r, tmpl, slots, out, np.empty(n + 1, dtype=np.int64))
        buf = out.tobytes()
        lids = itertools.repeat(lid, n) if lid >= 0 else r[:, -1].astype(np.int64).tolist()
        self._pend.extend(zip(lids, [buf[j:j + size] for j in range(0, n * size, size)],
                              _ns_list(r[:, 0]), strict=False))

    def _gps(self, lid: int, r: np.ndarray) -> None:
        from .encode import encode_poses

        if self._geo is not None and self._geo[3] >= 0:
            self._geo_gnss(r)
        tmpl, slots, head, _ = self._pose
        n = len(r)
        out = np.empty(n * (len(head) + 80), dtype=np.uint8)
        starts, tns = np.empty(n + 1, dtype=np.int64), np.empty(n, dtype=np.int64)
        end = encode_poses(r, tmpl, slots, head, out, starts, tns)
        buf, s = out[:end].tobytes(), starts.tolist()
        self._pend.extend(zip(itertools.repeat(lid, n),
                              [buf[a:b] for a, b in zip(s, s[1:], strict=False)], tns.tolist(),
                              strict=False))

    def _ticks(self, r: np.ndarray) -> None:
        """Tick rows -> ``/tf``, the poses and ``/drone/state``; straight to the writer when
        nothing else waits (else merged by the next ``emit``)."""
        from .encode import encode_ticks

        if self._geo is not None:  # first: the tick messages below then merge with them
            self._geo_ticks(r)
        n = len(r)
        if len(self._out) < n * self._row_bytes:
            self._out = np.empty(2 * n * self._row_bytes, dtype=np.uint8)
            self._idx = np.empty((3, 8 * n + 1), dtype=np.int64)
        out, (starts, kinds, tns) = self._out, self._idx
        m = encode_ticks(r, self._tick, out, starts, kinds, tns)
        s = starts[:m + 1].tolist()
        buf = out[:s[-1]].tobytes()
        ids = self._kind_lids
        if self._pend or self._geo_stash:
            self._pend.extend(zip([ids[k] for k in kinds[:m].tolist()],
                                  [buf[a:b] for a, b in zip(s, s[1:], strict=False)],
                                  tns[:m].tolist(), strict=True))
            return
        logs = self._logs
        for j, k, tn in zip(range(m), kinds[:m].tolist(), tns[:m].tolist(), strict=True):
            logs[ids[k]](buf[s[j]:s[j + 1]], tn)

    def _emit(self) -> None:
        if self._geo_stash:
            self._geo_emit()
        pend = self._pend
        if pend:
            pend.sort(key=_LOG_TIME)
            self._pend = []
            logs = self._logs
            for i, msg, tn in pend:
                logs[i](msg, tn)

    def _log(self, lid: int, msg: bytes, tn: int) -> None:
        self._logs[lid](msg, tn)

    # ------------------------------------------------------------------ the file
    def _flush(self) -> None:
        self._writer.flush()

    def _meta(self, name: str, md: dict[str, str]) -> None:
        self._writer.write_metadata(name, md)

    def _attach(self, kw: dict[str, Any]) -> None:
        self._writer.attach(**kw)

    def _close(self) -> None:
        if not self.closed:
            self.closed = True
            if self._geo_bounds:  # what `ag-uav show` prints without reading the messages
                b = self._geo_bounds
                self._writer.write_metadata("geo_bounds", {
                    "lat_min": repr(b[0]), "lat_max": repr(b[1]), "lon_min": repr(b[2]),
                    "lon_max": repr(b[3]), "fixes": str(b[4])})
            self._writer.close()
