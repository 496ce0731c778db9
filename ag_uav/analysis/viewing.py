"""Looking at a run after the fact, from its MCAP log alone.

    show(run)            -> str          metadata, config, metrics, channels with counts and rates
    plot(run, out_dir)   -> list[Path]   map.png (field, plan, sprayed area, true and estimated
                                         tracks, GPS fixes), dose.png (the dose on the ground,
                                         from dose.npz beside the log or the last ``/dose``
                                         grid), errors.png, controller.png, estimators.png
    video(run, out_mp4, camera=None) -> Path   MP4 from the logged JPEG frames (imageio-ffmpeg)
    recover(in_path, out_path) -> ScanReport   rewrite a truncated or damaged log into a
                                         finished, indexed MCAP; messages kept and lost
    write_foxglove_layout(path, ...)     Foxglove layout (app-export JSON: Layouts -> Import from
                                         file) with 3D, camera images and plots
    read_run(run)        -> RunData      decoded channels as numpy arrays (what the above use)

``run`` is a run folder (``runs/<id>/``, containing ``run.mcap``) or the ``.mcap`` file itself.
Everything reads with the ``mcap`` package (+ ``mcap-protobuf-support`` to decode), chunk by
chunk in file order (:mod:`ag_uav.analysis.logscan`): a file that was never finished (no footer),
was cut short or has damaged chunks is read as far as it is intact, and what was skipped is
reported (:func:`skipped_line`); an empty or non-MCAP file raises ``NotMcapError``.  Every output
(plots, video, recovered log, layout) is written atomically (:mod:`ag_uav.record.atomic`).
"""

from __future__ import annotations

import io
import json
import math
import os
import struct
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from .logscan import LogError, NotMcapError

__all__ = [
    "RunData",
    "read_run",
    "show",
    "plot",
    "video",
    "recover",
    "write_foxglove_layout",
    "mcap_path",
    "skipped_line",
    "LogError",
    "NotMcapError",
]


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


_SERIES_TOPICS = ("/drone/state", "/gps", "/drone/pose", "/drone/pose_est", "/drone/pose_ref",
                  "/drone/spray", "/geo/true")


def _summary_json(d: RunData) -> dict[str, Any]:
    """The run's ``summary.json`` attachment ({} if absent)."""
    import json

    raw = d.attachments.get("summary.json")
    if not raw:
        return {}
    try:
        return json.loads(raw)
    except ValueError:
        return {}


def _sortie_of(st: Series, sp: Series | None) -> np.ndarray | None:
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


# --------------------------------------------------------------------------------------------
# plot
# --------------------------------------------------------------------------------------------


def _scene_lines(scene: Any, entity_id: str) -> list[tuple[np.ndarray, tuple[float, ...]]]:
    out = []
    for e in getattr(scene, "entities", []):
        if e.id != entity_id:
            continue
        for ln in e.lines:
            pts = np.array([[p.x, p.y] for p in ln.points]) if ln.points else np.zeros((0, 2))
            closed = ln.type == 1  # LINE_LOOP
            if closed and len(pts):
                pts = np.vstack([pts, pts[:1]])
            out.append((pts, (ln.color.r, ln.color.g, ln.color.b, ln.color.a)))
    return out


def _scene_triangles(scene: Any, entity_id: str) -> list[np.ndarray]:
    out = []
    for e in getattr(scene, "entities", []):
        if e.id != entity_id:
            continue
        for tri in e.triangles:
            pts = np.array([[p.x, p.y] for p in tri.points])
            out += [pts[i:i + 3] for i in range(0, len(pts) - 2, 3)]
    return out


def _grid(axs: Any) -> None:
    for a in np.atleast_1d(axs).ravel():
        a.grid(alpha=0.3)


def _save(fig: Any, path: Path, dpi: int) -> Path:
    """Write ``fig`` to ``path`` (tight bounding box) and close it; the path."""
    import matplotlib.pyplot as plt

    from ..record.atomic import atomic_path

    try:
        with atomic_path(path) as tmp:
            fig.savefig(tmp, dpi=dpi, bbox_inches="tight", format=path.suffix[1:] or "png")
    finally:
        plt.close(fig)
    return path


def _data(run: str | Path | RunData, images: bool) -> RunData:
    """``run`` read (a run folder or .mcap file), or ``run`` itself if already read."""
    return run if isinstance(run, RunData) else read_run(run, images=images,
                                                          max_points=PLOT_POINTS)


def plot(run: str | Path | RunData, out_dir: str | Path) -> list[Path]:
    """PNG figures of a run: map, errors, controller, estimators (those with data).

    ``run``: a run folder, its ``.mcap`` or a :class:`RunData` already read.  Each figure is
    written atomically; a log with nothing to draw raises
    :class:`~ag_uav.analysis.logscan.LogError`."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.collections import PolyCollection

    from .logscan import LogError

    d = _data(run, images=False)
    if not d.series and not d.scenes:
        raise LogError(f"{d.path}: nothing to plot (no readable state, GPS, estimator or scene "
                       "messages)")
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    paths: list[Path] = []
    st = d.series.get("/drone/state")
    gps = d.series.get("/gps")
    ests = {k.split("/")[-1]: v for k, v in d.series.items() if k.startswith("/estimator/")}

    # --- map
    fig, ax = plt.subplots(figsize=(9, 7))
    field_scene = d.scenes.get("/field")
    sprayed_scene = d.scenes.get("/sprayed")
    if field_scene is not None:
        tris = _scene_triangles(field_scene, "field")
        if tris:
            tan = (0.85, 0.78, 0.6)
            ax.add_collection(PolyCollection(tris, facecolor=tan, edgecolor=tan, lw=0.5,
                                             zorder=0))
    if sprayed_scene is not None:
        tris = _scene_triangles(sprayed_scene, "sprayed")
        if tris:
            ax.add_collection(PolyCollection(tris, facecolor=(0.3, 0.75, 1.0, 0.35),
                                             edgecolor="none", zorder=1))
            ax.plot([], [], color=(0.3, 0.75, 1.0), lw=6, alpha=0.5, label="sprayed area")
    if field_scene is not None:
        first_field = first_hole = True
        for pts, col in _scene_lines(field_scene, "field"):
            is_hole = col[0] > 0.8 and col[1] < 0.5   # the scene draws holes red, parts gold
            lbl = None
            if is_hole and first_hole:
                lbl, first_hole = "obstacle", False
            elif not is_hole and first_field:
                lbl, first_field = "field", False
            ax.plot(pts[:, 0], pts[:, 1], color="darkgoldenrod" if not is_hole else "firebrick",
                    lw=2, zorder=2, label=lbl)
        spray_lbl = transit_lbl = True
        for pts, col in _scene_lines(field_scene, "plan"):
            spray = col[1] > 0.7 and col[0] < 0.3
            lbl = None
            if spray and spray_lbl:
                lbl, spray_lbl = "planned path (spray)", False
            elif not spray and transit_lbl:
                lbl, transit_lbl = "planned path (transit)", False
            ax.plot(pts[:, 0], pts[:, 1], color="forestgreen" if spray else "grey",
                    ls="-" if spray else ":", lw=1.0, zorder=3, label=lbl)
    if gps is not None and len(gps.t):
        ax.scatter(gps["pose.position.x"], gps["pose.position.y"], s=4, color="orange",
                   alpha=0.6, zorder=4, label="GPS fixes")
    spr = d.series.get("/drone/spray")
    summ = _summary_json(d)
    sortie = _sortie_of(st, spr) if st is not None else None
    if sprayed_scene is not None and field_scene is not None and summ.get("off_target_m2"):
        _plot_off_target(ax, field_scene, sprayed_scene, summ)
    if st is not None and sortie is not None and sortie.max() > 1:
        # one colour per sortie; the track on the ground at the base is not drawn
        ns = int(sortie.max())
        cmap = plt.get_cmap("tab10" if ns <= 10 else "tab20")
        for k in range(1, ns + 1):
            m = sortie == k
            x = np.where(m, st["pos.x"], np.nan)
            y = np.where(m, st["pos.y"], np.nan)
            ax.plot(x, y, color=cmap((k - 1) % cmap.N), lw=1.0, zorder=5,
                    label=f"sortie {k}" if k <= 20 else None)
    elif st is not None:
        ax.plot(st["pos.x"], st["pos.y"], color="black", lw=1.2, zorder=5, label="true track")
    if summ.get("base_xy") and (summ.get("sorties") or 0) > 1:
        bx, by = summ["base_xy"]
        ax.scatter([bx], [by], marker="*", s=260, color="crimson", edgecolor="k", zorder=8,
                   label="base (refill, battery swap)")
    if st is not None:
        if np.isfinite(st["est.x"]).any():
            ax.plot(st["est.x"], st["est.y"], color="royalblue", lw=1.0, ls="--", zorder=6,
                    label="estimated track")
    ax.set_aspect("equal")
    ax.autoscale_view()
    ax.set_xlabel("east x [m]")
    ax.set_ylabel("north y [m]")
    title = f"Top-down map: {d.path.parent.name}"
    if summ.get("sorties"):
        ns_ = int(summ["sorties"])
        title += (f"\n{ns_} sortie{'s' if ns_ != 1 else ''}, "
                  f"{summ.get('litres_sprayed_l', 0):.1f} L, "
                  f"{summ.get('energy_wh', 0):.0f} Wh, coverage "
                  f"{100 * (summ.get('coverage_fraction') or 0):.1f} %, off-target "
                  f"{summ.get('off_target_m2') or 0:.0f} m²")
    ax.set_title(title)
    if sortie is not None and sortie.max() > 1:
        ax.legend(loc="upper left", bbox_to_anchor=(1.01, 1.0), fontsize=8, framealpha=0.85,
                  ncol=2 if sortie.max() > 10 else 1)
    else:
        ax.legend(loc="upper right", fontsize=8, framealpha=0.85)
    ax.grid(alpha=0.3)
    paths.append(_save(fig, out / "map.png", 110))
    dose = _dose_of(d)
    if dose is not None:
        paths.append(_plot_dose(dose, field_scene, summ, out / "dose.png"))

    # --- spray job: tank, mass, battery, power
    if spr is not None and len(spr.t):
        fig, axs = plt.subplots(3, 1, figsize=(10, 7), sharex=True)
        axs[0].plot(spr.t, spr["tank_l"], color="tab:blue", lw=1.0, label="tank [L]")
        axs[0].plot(spr.t, spr["mass_kg"], color="k", lw=1.0, label="vehicle mass [kg]")
        axs[0].legend(fontsize=8)
        axs[1].plot(spr.t, 100 * spr["battery_frac"], color="tab:green", lw=1.0,
                    label="battery left [%]")
        res = summ.get("config", {}).get("battery", {}).get("reserve_frac")
        if res is not None:
            axs[1].axhline(100 * float(res), color="firebrick", ls="--", lw=0.8, label="reserve")
        axs[1].legend(fontsize=8)
        axs[2].plot(spr.t, spr["power_w"], color="tab:orange", lw=0.6, label="power [W]")
        axs[2].legend(fontsize=8)
        axs[2].set_xlabel("sim time [s]")
        _grid(axs)
        fig.suptitle("Spray job: tank and mass, battery, electrical power")
        paths.append(_save(fig, out / "spray.png", 100))

    # --- errors over time
    if st is not None:
        fig, axs = plt.subplots(2, 1, figsize=(10, 6), sharex=True)
        t = st.t
        for k, c in (("err.x", "tab:red"), ("err.y", "tab:green"), ("err.z", "tab:blue")):
            axs[0].plot(t, st[k], color=c, lw=0.9, label=k.replace("err.", "") + " (true - ref)")
        axs[0].plot(t, st["err.horiz"], color="k", lw=1.2, label="horizontal")
        axs[0].set_ylabel("tracking error [m]")
        axs[0].legend(fontsize=8, ncol=4)
        if np.isfinite(st["est_err.horiz"]).any():
            axs[1].plot(t, st["est_err.horiz"], color="royalblue", lw=1.0,
                        label="in-loop estimate (horizontal)")
        for name, s in ests.items():
            axs[1].plot(s.t, s["err.horiz"], lw=0.8, label=name)
        axs[1].set_ylabel("estimation error [m]")
        axs[1].set_xlabel("sim time [s]")
        if axs[1].lines:
            axs[1].legend(fontsize=8, ncol=4)
        _grid(axs)
        paths.append(_save(fig, out / "errors.png", 110))

    # --- controller signals
    if st is not None:
        groups: dict[str, list[str]] = {}
        for k in st.fields:
            if k.startswith("ctrl."):
                rest = k[5:]
                g = rest.split(".")[0] if "." in rest else "ctrl"
                groups.setdefault(g, []).append(k)
        motors = sorted(k for k in st.fields if k == "motors")
        n = len(groups) + 2
        fig, axs = plt.subplots(n, 1, figsize=(10, 2.0 * n), sharex=True, squeeze=False)
        axs = axs[:, 0]
        for a, (g, keys) in zip(axs, groups.items(), strict=False):
            for k in keys:
                a.plot(st.t, st[k], lw=0.8, label=k[5:])
            a.set_ylabel(g)
            a.legend(fontsize=7, ncol=min(len(keys), 6), loc="upper right")
        a = axs[len(groups)]
        if motors:
            m = _motor_matrix(d)
            for j in range(m.shape[1]):
                a.plot(st.t, m[:, j], lw=0.8, label=f"motor {j}")
            a.legend(fontsize=7, ncol=4, loc="upper right")
        a.set_ylabel("motors")
        a = axs[-1]
        for k, c in (("wind.x", "tab:red"), ("wind.y", "tab:green"), ("wind.z", "tab:blue")):
            a.plot(st.t, st[k], color=c, lw=0.8, label=k)
        a.plot(st.t, st["spray"], color="k", lw=0.8, ls=":", label="spray on")
        a.set_ylabel("wind [m/s]")
        a.legend(fontsize=7, ncol=4, loc="upper right")
        a.set_xlabel("sim time [s]")
        _grid(axs)
        fig.suptitle("Controller internals, motor commands, wind")
        paths.append(_save(fig, out / "controller.png", 100))

    # --- estimator comparison
    if ests or gps is not None:
        fig, axs = plt.subplots(1, 2, figsize=(12, 4.5), gridspec_kw={"width_ratios": [3, 1]})
        names, rmse = [], []
        if gps is not None and st is not None and len(gps.t):
            gx = gps["pose.position.x"] - np.interp(gps.t, st.t, st["pos.x"])
            gy = gps["pose.position.y"] - np.interp(gps.t, st.t, st["pos.y"])
            gh = np.hypot(gx, gy)
            axs[0].plot(gps.t, gh, color="orange", lw=0.6, alpha=0.7, label="GPS fix")
            names.append("GPS")
            rmse.append(float(np.sqrt(np.nanmean(gh ** 2))))
        for name, s in ests.items():
            axs[0].plot(s.t, s["err.horiz"], lw=0.9, label=name)
            names.append(name)
            rmse.append(float(np.sqrt(np.nanmean(s["err.horiz"] ** 2))))
        axs[0].set_xlabel("sim time [s]")
        axs[0].set_ylabel("horizontal position error [m]")
        axs[0].legend(fontsize=8)
        axs[0].grid(alpha=0.3)
        axs[1].bar(range(len(names)), rmse,
                   color=["orange" if n == "GPS" else "tab:blue" for n in names])
        axs[1].set_xticks(range(len(names)), names, rotation=30)
        axs[1].set_ylabel("RMSE [m]")
        for i, v in enumerate(rmse):
            axs[1].text(i, v, f"{v:.2f}" if v >= 0.1 else f"{v:.3f}", ha="center",
                        va="bottom", fontsize=8)
        fig.suptitle("Estimator comparison (error against the true position)")
        paths.append(_save(fig, out / "estimators.png", 110))
    return paths


def _dose_of(d: RunData) -> tuple[np.ndarray, float, float, float] | None:
    """(L/ha (ny, nx), x0, y0, cell) of the run's dose map: ``dose.npz`` beside the log, else
    the last ``/dose`` grid of the log; None without one."""
    npz = d.path.parent / "dose.npz"
    if npz.is_file():
        try:
            with np.load(npz) as z:
                return (np.asarray(z["l_per_ha"], float), float(z["x0"]), float(z["y0"]),
                        float(z["cell"]))
        except (OSError, KeyError, ValueError):
            pass
    g = d.grids.get("/dose")
    if g is None or not g.column_count:
        return None
    a = np.frombuffer(g.data, dtype="<f4").astype(float)
    a = a.reshape(-1, g.column_count)
    return a, g.pose.position.x, g.pose.position.y, g.cell_size.x


def _plot_dose(dose: tuple[np.ndarray, float, float, float], field_scene: Any,
               summ: dict[str, Any], path: Path) -> Path:
    """The dose on the ground as a share of the target rate (0-200 %), the field's outline and
    holes over it, the dose metrics in the title."""
    import matplotlib.pyplot as plt

    a, x0, y0, cell = dose
    target = float(summ.get("config", {}).get("spray", {}).get("rate_l_per_ha", 0.0) or 0.0)
    if target <= 0:
        target = float(np.max(a)) / 2 or 1.0
    fig, ax = plt.subplots(figsize=(9, 7))
    ny, nx = a.shape
    cmap = plt.get_cmap("RdYlBu").with_extremes(bad="white")  # below 0.5 %: (next to) none
    im = ax.imshow(np.ma.masked_less(100.0 * a / target, 0.5), origin="lower", cmap=cmap,
                   vmin=0.0, vmax=200.0,
                   extent=(x0, x0 + nx * cell, y0, y0 + ny * cell), interpolation="nearest")
    fig.colorbar(im, ax=ax, shrink=0.8, label=f"dose [% of {target:g} L/ha]")
    if field_scene is not None:
        for pts, _col in _scene_lines(field_scene, "field"):
            ax.plot(pts[:, 0], pts[:, 1], color="k", lw=1.2)
    ax.set_aspect("equal")
    ax.set_xlabel("east x [m]")
    ax.set_ylabel("north y [m]")

    def pct(k: str) -> str:
        v = summ.get(k)
        return "–" if v is None else f"{100 * v:.1f} %"

    ax.set_title(f"Dose on the ground: CV {pct('dose_cv')}, under-dosed "
                 f"{pct('underdosed_fraction')}, over-dosed {pct('overdosed_fraction')}\n"
                 "off the field "
                 f"{pct('offtarget_deposit_fraction')} of sprayed, drift {pct('drift_fraction')}")
    return _save(fig, path, 110)


def _plot_off_target(ax: Any, field_scene: Any, sprayed_scene: Any,
                     summ: dict[str, Any]) -> None:
    """Shade the sprayed area beyond the field (and its buffer) or over holes, in red."""
    import shapely

    sprayed = shapely.union_all([shapely.Polygon(t) for t in
                                 _scene_triangles(sprayed_scene, "sprayed")]).buffer(0)
    field = shapely.union_all([shapely.Polygon(t) for t in
                               _scene_triangles(field_scene, "field")]).buffer(0)
    buf = float(summ.get("config", {}).get("spray", {}).get("offtarget_buffer_m", 0.0) or 0.0)
    rings = _scene_lines(field_scene, "field")
    outer = shapely.Polygon(rings[0][0][:, :2]) if rings else field
    off = sprayed.difference(outer.buffer(buf, join_style="mitre"))
    for pts, _c in rings[1:]:
        hole = shapely.Polygon(pts[:, :2]).buffer(-buf, join_style="mitre")
        off = off.union(sprayed.intersection(hole))
    geoms = getattr(off, "geoms", [off])
    first = True
    for g in geoms:
        if g.is_empty or g.geom_type != "Polygon":
            continue
        x, y = g.exterior.xy
        ax.fill(x, y, color="red", alpha=0.7, zorder=7, lw=0,
                label="off-target spray" if first else None)
        first = False


def _motor_matrix(d: RunData) -> np.ndarray:
    """Motor commands as (N, n_motors) (the flattened list column holds lists)."""
    st = d.series["/drone/state"]
    m = st.fields.get("motors")
    if m is None:
        return np.zeros((len(st.t), 0))
    return np.atleast_2d(np.asarray(m, dtype=float)).reshape(len(st.t), -1)


# --------------------------------------------------------------------------------------------
# video
# --------------------------------------------------------------------------------------------


def _frames(d: RunData, camera: str | None) -> list[tuple[float, bytes]]:
    """The logged frames of ``camera`` (default the first camera); LogError if none."""
    from .logscan import LogError

    if not d.images:
        raise LogError(f"{d.path}: no camera frames in this log (flown with --no-render, "
                       "log.render = false or a channel set without cameras)")
    names = sorted(t.removeprefix("/camera/") for t in d.images)
    topic = f"/camera/{camera}" if camera else f"/camera/{names[0]}"
    if topic not in d.images:
        raise LogError(f"--camera = {camera!r}: no frames of that camera in {d.path}; "
                       f"cameras: {', '.join(names)}")
    return d.images[topic]


def video(run: str | Path | RunData, out_mp4: str | Path, camera: str | None = None,
          fps: float | None = None) -> Path:
    """Encode the logged JPEG frames of one camera into an MP4 (H.264 via imageio-ffmpeg).

    ``camera``: the name used when logging (``/camera/<name>``); default the first camera.
    ``fps``: default the logged frame rate in sim time (so the video plays in real time).
    The MP4 is written atomically.  No frames, an unknown camera or ``fps`` not > 0 raise
    :class:`~ag_uav.analysis.logscan.LogError`.
    """
    import imageio.v2 as imageio
    from PIL import Image

    from ..record.atomic import atomic_path, silent_write_failure
    from .logscan import LogError

    if fps is not None and not (math.isfinite(fps) and fps > 0):
        raise LogError(f"--fps = {fps:g}: must be > 0 (or 0 for the logged rate)")
    frames = _frames(_data(run, images=True), camera)
    if fps is None:
        ts = np.array([f[0] for f in frames])
        fps = (len(ts) - 1) / (ts[-1] - ts[0]) if len(ts) > 1 and ts[-1] > ts[0] else 10.0
    out = Path(out_mp4)
    first = np.asarray(Image.open(io.BytesIO(frames[0][1])).convert("RGB"))
    h, w = first.shape[:2]
    # H.264 wants even sizes; macro_block_size=1 keeps the size (pad if odd)
    pad_h, pad_w = h % 2, w % 2
    with atomic_path(out) as tmp:
        writer = imageio.get_writer(str(tmp), fps=float(fps), codec="libx264", quality=7,
                                    macro_block_size=1, pixelformat="yuv420p",
                                    ffmpeg_log_level="quiet")
        try:
            for _, jpg in frames:
                img = np.asarray(Image.open(io.BytesIO(jpg)).convert("RGB"))
                if pad_h or pad_w:
                    img = np.pad(img, ((0, pad_h), (0, pad_w), (0, 0)), mode="edge")
                writer.append_data(img)
        finally:
            writer.close()
        if not _mp4_complete(tmp):  # ffmpeg's exit status is not reported: check the file
            raise silent_write_failure(out, "ffmpeg did not finish the video")
    return out


def _mp4_complete(path: Path) -> bool:
    """Whether ``path`` is a whole MP4: top-level boxes (32-bit big-endian size, then the
    4-character type; size 1 = a 64-bit size follows; ISO/IEC 14496-12 section 4.2) that tile
    the file exactly, with an ``mdat`` and the ``moov`` ffmpeg writes last."""
    import struct

    seen, pos = set(), 0
    size = path.stat().st_size if path.exists() else 0
    if size == 0:
        return False
    with open(path, "rb") as f:
        while pos + 8 <= size:
            f.seek(pos)
            n, kind = struct.unpack(">I4s", f.read(8))
            if n == 1:
                (n,) = struct.unpack(">Q", f.read(8))
            if n < 8:
                return False
            seen.add(kind)
            pos += n
    return pos == size > 0 and {b"moov", b"mdat"} <= seen


# --------------------------------------------------------------------------------------------
# recover
# --------------------------------------------------------------------------------------------


def recover(in_path: str | Path, out_path: str | Path) -> Any:
    """Rewrite a truncated or damaged MCAP (or a run folder's) into a finished, indexed one.

    Every intact chunk survives (CRC-checked, read by
    :class:`~ag_uav.analysis.logscan.LogScan`); a damaged chunk and the partial chunk at a cut
    are lost.  Schemas, channels, metadata and attachments are copied; message order is kept.
    The output is written atomically.  Returns the scan's
    :class:`~ag_uav.analysis.logscan.ScanReport` (``messages`` kept, ``lost``, what was
    skipped).  An output equal to the input or a folder, a non-MCAP input, or a log with no
    intact message raise :class:`~ag_uav.analysis.logscan.LogError`.
    """
    from ..record.atomic import atomic_path
    from .logscan import LogError, LogScan

    src, out = mcap_path(in_path), Path(out_path)
    if out.is_dir():
        raise LogError(f"OUT = {out} is a folder; give the new file's name, e.g. "
                       f"{out / 'recovered.mcap'}")
    if out.exists() and os.path.samefile(out, src):
        raise LogError(f"OUT must differ from IN ({src}); the input is kept as it is")
    scan = LogScan(src)
    with atomic_path(out) as tmp:
        with open(tmp, "wb") as g:
            _copy_records(scan, g)
        if scan.report.messages == 0:
            tmp.unlink()
            why = scan.report.describe(counts=False)
            raise LogError(f"no intact message in {src}; nothing written"
                           + (f" ({why})" if why else ""))
    return scan.report


def _copy_records(scan: Any, g: Any) -> None:
    """Write what ``scan`` reads into a new MCAP on ``g`` (channels as their messages come)."""
    from mcap.records import Attachment, Message, Metadata
    from mcap.writer import CompressionType, Writer

    w = Writer(g, compression=CompressionType.ZSTD)
    w.start(profile="", library="ag_uav.recover")
    schema_map: dict[int, int] = {}
    channel_map: dict[int, int] = {}
    for rec in scan.records():
        if isinstance(rec, Message):
            cid = channel_map.get(rec.channel_id)
            if cid is None:
                ch = scan.channels[rec.channel_id]
                sch = scan.schemas.get(ch.schema_id)
                if sch is not None and sch.id not in schema_map:
                    schema_map[sch.id] = w.register_schema(sch.name, sch.encoding, sch.data)
                cid = channel_map[ch.id] = w.register_channel(
                    ch.topic, ch.message_encoding, schema_map.get(ch.schema_id, 0),
                    dict(ch.metadata))
            w.add_message(cid, rec.log_time, rec.data, rec.publish_time, rec.sequence)
        elif isinstance(rec, Metadata):
            w.add_metadata(rec.name, dict(rec.metadata))
        elif isinstance(rec, Attachment):
            w.add_attachment(rec.create_time, rec.log_time, rec.name, rec.media_type, rec.data)
    w.finish()


# --------------------------------------------------------------------------------------------
# Foxglove layout
# --------------------------------------------------------------------------------------------


def _plot_cfg(title: str, paths: list[tuple[str, str]]) -> dict[str, Any]:
    return {
        "title": title,
        "paths": [{"value": v, "enabled": True, "timestampMethod": "receiveTime", "label": lbl}
                  for v, lbl in paths],
        "showXAxisLabels": True, "showYAxisLabels": True, "showLegend": True,
        "legendDisplay": "floating", "showPlotValuesInLegend": False, "isSynced": True,
        "xAxisVal": "timestamp", "sidebarDimension": 240,
    }


#: the Map panel's look per geographic topic: line colour (LocationFix topics; a GNSS fix is
#: drawn in its fix type's colour, :data:`ag_uav.record.geo.FIX_COLORS`) and which messages it
#: shows (``all`` the whole track, ``none`` the latest at the playback time)
_MAP_TOPICS = {
    "/geo/true": ({"historyMode": "all", "pointDisplayMode": "dot", "pointSize": 3},
                  "#ffffff"),
    "/geo/est": ({"historyMode": "all", "pointDisplayMode": "dot", "pointSize": 3}, "#4169e1"),
    "/geo/gnss": ({"historyMode": "all", "pointDisplayMode": "cross", "pointSize": 5}, None),
    "/geo/field": ({"historyMode": "all"}, None),
    "/geo/plan": ({"historyMode": "all"}, None),
    "/geo/sprayed": ({"historyMode": "none"}, None),
    "/geo/dose": ({"historyMode": "none"}, None),
}


def _map_cfg(geo: tuple[str, ...]) -> dict[str, Any]:
    """Foxglove's Map panel (``foxglove.layouts.MapConfig``'s keys) over the satellite layer,
    following the true position, naming only the geographic topics ``geo`` the log holds."""
    topics = [t for t in _MAP_TOPICS if t in geo]
    colors = {t: _MAP_TOPICS[t][1] for t in topics if _MAP_TOPICS[t][1]}
    return {"layer": "satellite", "zoomLevel": 18, "maxNativeZoom": 18,
            "followTopic": "/geo/true" if "/geo/true" in topics else "",
            "disabledTopics": [], "topicColors": colors,
            "topicConfig": {t: dict(_MAP_TOPICS[t][0], order=k) for k, t in enumerate(topics)}}


def write_foxglove_layout(
    path: str | Path,
    *,
    cameras: tuple[str, ...] | list[str] = ("chase", "down"),
    estimators: tuple[str, ...] | list[str] = (),
    ctrl_keys: tuple[str, ...] | list[str] = (),
    n_motors: int = 4,
    center: tuple[float, float] = (0.0, 0.0),
    spray: bool = False,
    geo: tuple[str, ...] | list[str] = (),
) -> Path:
    """Write a Foxglove layout in app-export JSON (import with Layouts -> Import from file).

    With ``geo`` (the run's geographic topics, :mod:`ag_uav.record.geo`) a Map panel first
    (:func:`_map_cfg`), then a 3D panel (field, plan, sprayed area, true/estimated/reference
    poses, GPS fixes, world frame), one Image panel per camera, and plots: tracking and
    estimation errors, controller outputs (``ctrl_keys`` ending in ``.u`` / ``.U`` first, up to
    8), motor commands.
    """
    cfg: dict[str, Any] = {}
    if geo:
        cfg["Map!aguavmap"] = _map_cfg(tuple(geo))
    cfg["3D!aguav3d"] = {
        "cameraState": {"distance": 80, "perspective": True, "phi": 55, "thetaOffset": 35,
                        "targetOffset": [center[0], center[1], 0], "target": [0, 0, 0],
                        "targetOrientation": [0, 0, 0, 1], "fovy": 45, "near": 0.5,
                        "far": 5000},
        "followMode": "follow-none",
        "followTf": "world",
        "scene": {"transforms": {"showLabel": False, "axisScale": 1.5}},
        "transforms": {},
        "topics": {
            "/field": {"visible": True},
            "/sprayed": {"visible": True},
            "/drone/pose": {"visible": True, "type": "arrow", "color": "#ffffffff",
                            "arrowScale": [1.5, 0.25, 0.25]},
            "/drone/pose_est": {"visible": True, "type": "arrow", "color": "#4169e1ff",
                                "arrowScale": [1.2, 0.2, 0.2]},
            "/drone/pose_ref": {"visible": True, "type": "arrow", "color": "#22cc44ff",
                                "arrowScale": [1.0, 0.15, 0.15]},
            "/gps": {"visible": True, "type": "axis", "axisScale": 0.3},
            **{f"/camera/{c}": {"visible": False} for c in cameras},
        },
        "layers": {"grid": {"visible": True, "layerId": "foxglove.Grid", "frameId": "world",
                            "size": 200, "divisions": 40, "lineWidth": 1,
                            "color": "#248eff33", "position": [center[0], center[1], -0.05],
                            "rotation": [0, 0, 0], "order": 1}},
        "publish": {"type": "point"},
        "imageMode": {},
    }
    for c in cameras:
        cfg[f"Image!cam{c}"] = {
            "cameraState": {}, "followMode": "follow-pose", "scene": {}, "transforms": {},
            "topics": {}, "layers": {}, "publish": {}, "imageMode": {
                "imageTopic": f"/camera/{c}", "calibrationTopic": f"/camera/{c}/calibration"},
        }
    err_paths = [("/drone/state.err.horiz", "tracking error (horiz) [m]"),
                 ("/drone/state.err.z", "tracking error z [m]"),
                 ("/drone/state.est_err.horiz", "in-loop estimate error [m]")]
    err_paths += [(f"/estimator/{e}.err.horiz", f"{e} error [m]") for e in estimators]
    cfg["Plot!errors"] = _plot_cfg("errors", err_paths)
    keys = sorted(ctrl_keys, key=lambda k: (not k.lower().endswith((".u",)), k))[:8]
    cfg["Plot!ctrl"] = _plot_cfg("controller", [(f"/drone/state.ctrl.{k}", k) for k in keys]
                                 or [("/drone/state.speed", "speed [m/s]")])
    cfg["Plot!motors"] = _plot_cfg("motors", [(f"/drone/state.motors[{i}]", f"motor {i}")
                                              for i in range(n_motors)])
    cfg["Plot!pos"] = _plot_cfg("position vs reference", [
        ("/drone/state.pos.x", "x"), ("/drone/state.ref.x", "x ref"),
        ("/drone/state.pos.y", "y"), ("/drone/state.ref.y", "y ref"),
        ("/drone/state.pos.z", "z"), ("/drone/state.ref.z", "z ref")])

    def chain(items: list[Any], direction: str) -> Any:
        if len(items) == 1:
            return items[0]
        return {"direction": direction, "first": items[0],
                "second": chain(items[1:], direction),
                "splitPercentage": 100.0 / len(items)}

    cams = [f"Image!cam{c}" for c in cameras]
    top: Any = "3D!aguav3d"
    if geo:  # the map first, beside the 3D scene
        top = {"direction": "row", "first": "Map!aguavmap", "second": top,
               "splitPercentage": 50}
    left = chain([top, chain(cams, "row")], "column") if cams else top
    if isinstance(left, dict):
        left["splitPercentage"] = 62
    plots = ["Plot!errors", "Plot!pos", "Plot!ctrl", "Plot!motors"]
    if spray:  # spray job (ag_uav.world.spray_job): tank, mass, battery
        cfg["Plot!spray"] = _plot_cfg("spray job", [
            ("/drone/spray.tank_l", "tank [L]"), ("/drone/spray.mass_kg", "mass [kg]"),
            ("/drone/spray.battery_frac", "battery left"), ("/drone/spray.sortie", "sortie")])
        plots.append("Plot!spray")
    right = chain(plots, "column")
    layout = {
        "configById": cfg,
        "globalVariables": {},
        "userNodes": {},
        "playbackConfig": {"speed": 1.0},
        "layout": {"direction": "row", "first": left, "second": right, "splitPercentage": 58},
    }
    from ..record.atomic import atomic_write_text

    return atomic_write_text(path, json.dumps(layout, indent=1), fsync=False)
