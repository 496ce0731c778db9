"""Reading a run from its MCAP log alone: the decoded channels as numpy arrays
(:func:`read_run`), the summary only (:func:`read_summary`) and the text of ``ag-uav show``
(:func:`show`).

Everything reads with the ``mcap`` package (+ ``mcap-protobuf-support`` to decode), chunk by
chunk in file order (:mod:`ag_uav.analysis.logscan`): a file that was never finished (no footer),
was cut short or has damaged chunks is read as far as it is intact, and what was skipped is
reported (:func:`skipped_line`); an empty or non-MCAP file raises ``NotMcapError``.
"""

from __future__ import annotations

import json
import math
import struct
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from .logscan import LogError, NotMcapError

__all__ = ["RunData", "Series", "read_run", "read_summary", "run_data", "show", "mcap_path",
           "skipped_line", "summary_json", "sortie_of", "PLOT_POINTS", "LogError",
           "NotMcapError"]


def mcap_path(run: str | Path) -> Path:
    """The ``.mcap`` file of a run folder (``run.mcap``, else the only ``*.mcap``) or file."""
    p = Path(run)
    if p.is_dir():
        if (p / "run.mcap").exists():
            return p / "run.mcap"
        found = sorted(p.glob("*.mcap"))
        if not found:
            raise FileNotFoundError(f"no .mcap file in {p}")
        return found[0]
    if not p.exists():
        raise FileNotFoundError(p)
    return p


# --------------------------------------------------------------------------------------------
# Reading
# --------------------------------------------------------------------------------------------


def _flatten(msg: Any, prefix: str = "", out: dict[str, Any] | None = None) -> dict[str, Any]:
    """Protobuf message -> {dotted field name: value}; nested messages recurse, repeated
    numeric fields become lists; every declared field is present (defaults included)."""
    if out is None:
        out = {}
    for f in msg.DESCRIPTOR.fields:
        v = getattr(msg, f.name)
        key = prefix + f.name
        if f.message_type is not None and not _is_repeated(f):
            _flatten(v, key + ".", out)
        elif _is_repeated(f):
            if f.message_type is None:
                out[key] = list(v)
        else:
            out[key] = v
    return out


def _is_repeated(f: Any) -> bool:
    rep = getattr(f, "is_repeated", None)
    if rep is not None:
        return bool(rep)
    return f.label == f.LABEL_REPEATED


@dataclass
class Series:
    """One numeric channel: ``t`` (s, log time) and ``fields`` {dotted name: array}."""

    t: np.ndarray
    fields: dict[str, np.ndarray]

    def __getitem__(self, key: str) -> np.ndarray:
        return self.fields[key]

    def __contains__(self, key: str) -> bool:
        return key in self.fields


@dataclass
class RunData:
    path: Path
    finished: bool
    metadata: dict[str, dict[str, str]] = field(default_factory=dict)
    attachments: dict[str, bytes] = field(default_factory=dict)
    channels: dict[str, dict[str, Any]] = field(default_factory=dict)  # topic -> info
    series: dict[str, Series] = field(default_factory=dict)  # numeric topics
    scenes: dict[str, Any] = field(default_factory=dict)  # topic -> last decoded SceneUpdate
    grids: dict[str, Any] = field(default_factory=dict)  # topic -> last decoded foxglove.Grid
    images: dict[str, list[tuple[float, bytes]]] = field(default_factory=dict)
    t_start: float = math.nan
    t_end: float = math.nan
    report: Any = None  # logscan.ScanReport: what was skipped
    undecodable: int = 0  # messages in intact chunks that did not decode


_SERIES_TOPICS = ("/drone/state", "/gps", "/gps/error", "/drone/pose", "/drone/pose_est",
                  "/drone/pose_ref", "/drone/spray", "/geo/true")


def summary_json(d: RunData) -> dict[str, Any]:
    """The run's ``summary.json`` attachment ({} if absent)."""

    raw = d.attachments.get("summary.json")
    if not raw:
        return {}
    try:
        return json.loads(raw)
    except ValueError:
        return {}


def sortie_of(st: Series, sp: Series | None) -> np.ndarray | None:
    """Sortie number (1, 2, ...) at each ``/drone/state`` sample, from ``/drone/spray``."""
    if sp is None or not len(sp.t) or "sortie" not in sp:
        return None
    i = np.clip(np.searchsorted(sp.t, st.t, side="right") - 1, 0, len(sp.t) - 1)
    return sp["sortie"][i].astype(int)


def _series(rows: list[tuple[float, dict[str, Any]]]) -> Series:
    """Rows ``(t, {field: value})`` of one topic -> a :class:`Series` in time order."""
    order = np.argsort(np.array([r[0] for r in rows]), kind="stable")
    rows = [rows[i] for i in order]
    fields: dict[str, np.ndarray] = {}
    for k in rows[0][1]:
        col = [r[1].get(k, math.nan) for r in rows]
        try:
            fields[k] = np.asarray(col, dtype=float)
        except (TypeError, ValueError):
            continue
    return Series(np.array([r[0] for r in rows]), fields)


def _note(data: RunData, topic: str, schema: Any, channel: Any, message: Any) -> float:
    """Count ``message`` in ``data.channels``; its log time in s."""
    t = message.log_time * 1e-9
    info = data.channels.get(topic)
    if info is None:
        info = data.channels[topic] = {
            "schema": schema.name if schema is not None else "", "count": 0,
            "encoding": channel.message_encoding, "t0": t, "t1": t, "bytes": 0}
    info["count"] += 1
    info["t0"], info["t1"] = min(info["t0"], t), max(info["t1"], t)
    info["bytes"] += len(message.data)
    return t


#: the most samples a time series keeps when read for plots and videos (:func:`read_run`'s
#: ``max_points``; a 38 ha job logs ~340,000 state rows; a figure is ~1,500 px wide)
PLOT_POINTS = 5_000


class _Thin:
    """Streaming decimation of one topic to at most ``2 * cap`` rows: every ``stride``-th
    message is kept; when the rows reach ``2 * cap``, every other one is dropped and the stride
    doubles (the rows kept are always the messages whose index is a multiple of the stride)."""

    __slots__ = ("cap", "n", "rows", "stride")

    def __init__(self, cap: int | None):
        self.cap, self.n, self.stride = cap, 0, 1
        self.rows: list[tuple[float, dict[str, Any]]] = []

    def wants(self) -> bool:
        keep = self.n % self.stride == 0
        self.n += 1
        return keep

    def add(self, row: tuple[float, dict[str, Any]]) -> None:
        self.rows.append(row)
        if self.cap and len(self.rows) >= 2 * self.cap:
            self.rows = self.rows[::2]
            self.stride *= 2


def read_run(run: str | Path, *, images: bool = True, max_points: int | None = None) -> RunData:
    """Decode a run log: numeric channels to arrays, the last scene and grid of each topic,
    JPEG frames, metadata.

    The file is read chunk by chunk (:class:`~ag_uav.analysis.logscan.LogScan`): damaged chunks
    and a cut tail are skipped and described in ``RunData.report``; an empty or non-MCAP file
    raises :class:`~ag_uav.analysis.logscan.NotMcapError`.  ``max_points``: decimate each
    numeric channel as it streams (:class:`_Thin`; the counts in ``channels`` stay whole); a
    scene or grid is decoded once, the last of its topic.
    """
    from mcap.records import Attachment, Message, Metadata

    from .logscan import LogScan

    path = mcap_path(run)
    scan = LogScan(path)
    data = RunData(path=path, finished=False, report=scan.report)
    dec = _Decoders()
    rows: dict[str, _Thin] = {}
    last: dict[str, tuple[float, Any, Any]] = {}  # scene/grid topic -> (t, channel, message)
    for rec in scan.records():
        if isinstance(rec, Metadata):
            data.metadata[rec.name] = dict(rec.metadata)
        elif isinstance(rec, Attachment):
            data.attachments[rec.name] = bytes(rec.data)
        if not isinstance(rec, Message):
            continue
        channel = scan.channels[rec.channel_id]
        schema = scan.schemas.get(channel.schema_id)
        topic = channel.topic
        t = _note(data, topic, schema, channel, rec)
        if schema is not None and schema.name in ("foxglove.SceneUpdate", "foxglove.Grid"):
            if t >= last.get(topic, (-1.0,))[0]:
                last[topic] = (t, channel, rec)
            continue
        is_img = images and topic.startswith("/camera/") and not topic.endswith("/calibration")
        if is_img:
            msg = dec(data, channel, schema, rec)
            if msg is not None:
                data.images.setdefault(topic, []).append((t, bytes(msg.data)))
        elif topic in _SERIES_TOPICS or topic.startswith("/estimator/"):
            thin = rows.get(topic) or rows.setdefault(topic, _Thin(max_points))
            if thin.wants():
                msg = dec(data, channel, schema, rec)
                if msg is not None:
                    thin.add((t, _flatten(msg)))
    if not (data.metadata or data.attachments or scan.channels):
        why = scan.report.describe(counts=False)
        raise LogError(f"{path}: nothing readable in this MCAP file" + (f" ({why})" if why
                                                                        else ""))
    for topic, (_, channel, rec) in last.items():
        schema = scan.schemas.get(channel.schema_id)
        msg = dec(data, channel, schema, rec)
        if msg is not None:
            kept = data.grids if schema.name == "foxglove.Grid" else data.scenes
            kept[topic] = msg
    data.finished = scan.report.finished
    data.series = {topic: _series(th.rows) for topic, th in rows.items() if th.rows}
    for frames in data.images.values():
        frames.sort(key=lambda f: f[0])
    if data.channels:
        data.t_start = min(i["t0"] for i in data.channels.values())
        data.t_end = max(i["t1"] for i in data.channels.values())
    return data


class _Decoders:
    """Protobuf decoders per channel (mcap_protobuf's factory); a message that does not decode
    despite an intact chunk is counted in ``RunData.undecodable`` and gives None."""

    def __init__(self) -> None:
        from mcap_protobuf.decoder import DecoderFactory

        self.factory, self.by_channel = DecoderFactory(), {}

    def __call__(self, data: RunData, channel: Any, schema: Any, rec: Any) -> Any:
        try:
            d = self.by_channel.get(channel.id)
            if d is None:
                d = self.by_channel[channel.id] = self.factory.decoder_for(
                    channel.message_encoding, schema)
            return d(rec.data)
        except Exception:  # noqa: BLE001 - undecodable despite an intact chunk: skip it
            data.undecodable += 1
            return None


def skipped_line(d: RunData) -> str:
    """What reading the log had to skip, in one line ("" if nothing)."""
    parts = [d.report.describe()] if d.report is not None else []
    if d.undecodable:
        parts.append(f"{d.undecodable} messages could not be decoded")
    return "; ".join(p for p in parts if p)


# --------------------------------------------------------------------------------------------
# show
# --------------------------------------------------------------------------------------------


_MSG_HEAD = 1 + 8 + 2 + 4 + 8 + 8  # a Message record's opcode, length and fixed fields


def _chunk_rows(f: Any, ci: Any) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(channel, log time ns, data bytes) of every message of one chunk, from one read of the
    chunk and its MessageIndex records (the MCAP specification's Chunk record: opcode 0x06,
    start and end times, uncompressed size and CRC-32, compression, records; Message Index:
    opcode 0x07, channel id u16, (log time u64, offset u64) pairs; little-endian).  The chunk is
    decompressed once and checked against its CRC, its messages are not parsed; a damaged
    chunk raises (ValueError, RuntimeError, struct.error)."""
    import zlib

    f.seek(ci.chunk_start_offset)
    buf = f.read(ci.chunk_length + ci.message_index_length)
    if len(buf) < ci.chunk_length or buf[0] != 0x06:
        raise ValueError("not a chunk")
    usize, crc, clen = struct.unpack_from("<QII", buf, 25)
    comp = bytes(buf[41:41 + clen]).decode()
    rlen = struct.unpack_from("<Q", buf, 41 + clen)[0]
    data = buf[49 + clen:49 + clen + rlen]
    if comp == "lz4":
        import lz4.frame

        data = lz4.frame.decompress(data)
    elif comp == "zstd":
        import zstandard

        data = zstandard.ZstdDecompressor().decompress(data, max_output_size=usize)
    elif comp:
        raise ValueError(f"unknown compression {comp!r}")
    if len(data) != usize or (crc and zlib.crc32(data) != crc):
        raise ValueError("chunk CRC mismatch")
    chans, recs, o = [], [], ci.chunk_length
    while o + 9 <= len(buf):
        n = struct.unpack_from("<Q", buf, o + 1)[0]
        if buf[o] == 0x07:
            ch, m = struct.unpack_from("<HI", buf, o + 9)
            chans.append((ch, m // 16))
            recs.append(np.frombuffer(buf, dtype="<u8", count=m // 8, offset=o + 15))
        o += 9 + n
    if not recs:
        z = np.zeros(0, np.int64)
        return z, z, z
    r = np.concatenate(recs).reshape(-1, 2).astype(np.int64)
    ch = np.repeat([c for c, _ in chans], [k for _, k in chans])
    raw = np.frombuffer(data, dtype=np.uint8)
    # each Message record's length field (u64 after its opcode) less its fixed fields
    length = raw[r[:, 1, None] + np.arange(1, 9)].copy().view("<u8").ravel()
    return ch, r[:, 0], length.astype(np.int64) - (_MSG_HEAD - 9)


def read_summary(run: str | Path) -> RunData | None:
    """What :func:`show` prints, from a finished log's summary section, its message indexes,
    metadata and attachments (the MCAP specification's index records), without decompressing or
    decoding one message (each chunk is decompressed once to check its CRC); None for a log
    without them (unfinished, unindexed) or with a damaged chunk: then :func:`read_run` scans
    it and says what it skipped."""
    from mcap.exceptions import McapError
    from mcap.reader import make_reader

    path = mcap_path(run)
    try:
        with open(path, "rb") as f:
            r = make_reader(f)
            s = r.get_summary()
            if s is None or s.statistics is None or not s.chunk_indexes:
                return None
            d = RunData(path=path, finished=True)
            for m in r.iter_metadata():
                d.metadata[m.name] = dict(m.metadata)
            for a in r.iter_attachments():
                d.attachments[a.name] = bytes(a.data)
            _index_channels(d, f, s)
    except (McapError, OSError, ValueError, KeyError, EOFError, StopIteration, RuntimeError,
            struct.error):  # damage (lz4 reports a bad checksum as a RuntimeError)
        return None
    return d


def _index_channels(d: RunData, f: Any, s: Any) -> None:
    """Per-channel counts, times and bytes of ``d`` from the chunks' message indexes."""
    parts = [_chunk_rows(f, ci) for ci in s.chunk_indexes]
    parts = [p for p in parts if len(p[0])]
    if not parts:
        return
    ch, t, size = (np.concatenate(x) for x in zip(*parts, strict=True))
    ids, inv = np.unique(ch, return_inverse=True)
    n, nbytes = np.bincount(inv), np.bincount(inv, weights=size)
    t0 = np.full(len(ids), np.iinfo(np.int64).max)
    t1 = np.full(len(ids), np.iinfo(np.int64).min)
    np.minimum.at(t0, inv, t)
    np.maximum.at(t1, inv, t)
    for j, cid in enumerate(ids.tolist()):
        c = s.channels[cid]
        sch = s.schemas.get(c.schema_id)
        d.channels[c.topic] = {"schema": sch.name if sch is not None else "",
                               "count": int(n[j]), "encoding": c.message_encoding,
                               "t0": int(t0[j]) * 1e-9, "t1": int(t1[j]) * 1e-9,
                               "bytes": int(nbytes[j])}
    d.t_start = min(i["t0"] for i in d.channels.values())
    d.t_end = max(i["t1"] for i in d.channels.values())


def show(run: str | Path) -> str:
    """A text report of a run from its MCAP alone: from the summary section and indexes of a
    finished log (:func:`read_summary`), else by scanning it (:func:`read_run`)."""
    d = read_summary(run) or read_run(run, images=False)
    state = "finished, indexed" if d.finished else "NOT finished (truncated?): try recover"
    lines = [f"run log: {d.path}  ({d.path.stat().st_size / 1e6:.2f} MB, {state})"]
    skipped = skipped_line(d)
    if skipped:
        lines.append(f"damaged: {skipped} (`ag-uav recover` keeps the rest)")
    if d.t_start == d.t_start:
        lines.append(f"sim time: {d.t_start:.2f} .. {d.t_end:.2f} s")
    lines += _geo_lines(d)
    for name in ("run", "versions", "summary"):
        md = d.metadata.get(name)
        if not md:
            continue
        lines.append(f"\n[{name}]")
        w = max(len(k) for k in md)
        lines += [f"  {k:<{w}}  {v}" for k, v in md.items()]
    lines.append("\n[channels]")
    lines.append(f"  {'topic':<32} {'schema':<26} {'count':>7} {'Hz':>7} {'KiB':>8}")
    for topic, info in sorted(d.channels.items()):
        span = info["t1"] - info["t0"]
        hz = (info["count"] - 1) / span if span > 0 and info["count"] > 1 else math.nan
        lines.append(f"  {topic:<32} {info['schema']:<26} {info['count']:>7} {hz:>7.2f} "
                     f"{info['bytes'] / 1024:>8.1f}")
    if d.attachments:
        lines.append("\n[attachments]")
        lines += [f"  {k}  ({len(v)} bytes)" for k, v in d.attachments.items()]
    cfg = d.attachments.get("config.toml")
    if cfg:
        lines.append("\n[config.toml]")
        lines += ["  " + ln for ln in cfg.decode("utf-8", "replace").splitlines()]
    return "\n".join(lines)


def _geo_lines(d: RunData) -> list[str]:
    """The run's geodetic origin (metadata ``geo``) and the lon/lat bounds of its true track
    (metadata ``geo_bounds``, else the ``/geo/true`` messages read); none for a log without
    them."""
    md = d.metadata.get("geo") or {}
    try:
        lat0, lon0 = float(md["origin_lat_deg"]), float(md["origin_lon_deg"])
        h0 = float(md.get("origin_alt_m", "0"))
    except (KeyError, ValueError):
        return []
    out = [f"origin: lat {lat0:.7f}, lon {lon0:.7f} (WGS-84 degrees), height {h0:.1f} m "
           "(local frame: x east, y north, z up)"]
    b = d.metadata.get("geo_bounds") or {}  # a finished log: written by its writer
    s = d.series.get("/geo/true")
    try:
        box = [float(b[k]) for k in ("lat_min", "lat_max", "lon_min", "lon_max")]
        n = int(b["fixes"])
    except (KeyError, ValueError):  # a log cut short: from its messages, where read
        if s is None or not len(s.t) or "latitude" not in s or "longitude" not in s:
            return out
        la, lo = s["latitude"], s["longitude"]
        box, n = [la.min(), la.max(), lo.min(), lo.max()], len(s.t)
    out.append(f"flight bounds: lat {box[0]:.7f} .. {box[1]:.7f}, lon {box[2]:.7f} .. "
               f"{box[3]:.7f} ({n} fixes on /geo/true)")
    return out




def run_data(run: str | Path | RunData, images: bool) -> RunData:
    """``run`` read (a run folder or .mcap file), or ``run`` itself if already read."""
    return run if isinstance(run, RunData) else read_run(run, images=images,
                                                          max_points=PLOT_POINTS)
