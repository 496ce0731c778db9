"""Run log: one MCAP file per run that Foxglove and ``ag_uav.analysis.viewing`` can open.

Usage (the simulation loop calls this; everything is in sim time, seconds -> ns)::

    with RunLog(run_dir / "run.mcap", channels="full", metadata={...}, config_toml=txt) as log:
        log.scene(0.0, outer_xy, holes_xy, plan_segments, swath=6.0, altitude=3.0)
        for each 100 Hz control tick:
            log.tick(t, Tick(p_true=p, q_true_wxyz=q, v_true=v, p_ref=r, v_ref=vr, yaw_ref=psi,
                             p_est=pe, v_est=ve, ctrl={"x.E": .., "x.u": ..}, motors=[..],
                             wind=w, spray=on))
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
first call (all fields ``double``, nested groups, packed vectors; see
:class:`~ag_uav.record.wire.FlatSchema`); they
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
  [gps]       ``/gps``                foxglove.PoseInFrame at each fix (3D + plots): log time
                                      = its arrival, ``timestamp`` = its measurement (arrival
                                      less the receiver's latency)
              ``/gps/error``          ag_uav.GnssError at each fix: t (arrival), t_meas, age,
                                      truth (the true position of the point measured, the
                                      antenna on the INS chain, at t_meas), err = fix - truth
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
the rest.  The rows are handed to the writer every ``LogIO.flush_wall_s`` of wall time or
``LogIO.flush_sim_s`` of sim time, whichever comes first, and the writer finishes its chunk and
flushes it to the OS at each hand-over.  With the writer process (:mod:`ag_uav.record.sink`, the
default) a SIGKILL of the flight loses only the rows not handed over yet (< 0.3 s of flight and
one log tick); the writer then finishes the file.  Killed together (a process group), they lose
also the one hand-over the writer had not written yet;
``ag_uav.analysis.recover.recover`` turns a truncated file into a finished, indexed one.

Cost: between two hand-overs nothing is encoded.  A tick is one row of raw values
(:meth:`RunLog.tick_slot`: the engine copies its arrays into it in one ``np.concatenate``;
:meth:`RunLog.tick` fills one from its arguments), an estimator or spray-state message one row of
its flat schema, a filter bank's fix one compact row; at the hand-over the rows go to the writer,
where :mod:`ag_uav.record.encode` turns them into protobuf messages in one compiled call per
topic group and they are written merged by log time.  A row still
being filled when a signal closes the log is dropped, not written half-done.
"""


from __future__ import annotations

import json
import os
import platform
import time
from collections.abc import Iterable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from . import crash
from .atomic import silent_write_failure
from .log_estimates import EstimateLog
from .log_scene import DOSE_PERIOD_S, GEO_DOSE_PERIOD_S, SceneLog
from .log_ticks import Tick, TickLog
from .sink import WriterLost
from .wire import (
    INF,
    NAN,
    POSE_MID,
    POSE_SLOTS,
    POSE_TMPL,
    TICK_HEAD,
    WORLD2,
    EstBank,
    EstChan,
    FlatRows,
    FlatSchema,
    Rows,
    enc_pose_in_frame,
    enc_transform,
    ns,
    sanitize_name,
    str_field,
    warm_encoders,
)

__all__ = [
    "group_rates",
    "RunLog",
    "LogIO",
    "Tick",
    "FlatSchema",
    "GROUPS",
    "PRESETS",
    "sanitize_name",
    "ns",
    "enc_pose_in_frame",
    "enc_transform",
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

_perf_counter = time.perf_counter


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


@dataclass(frozen=True)
class LogIO:
    """How a :class:`RunLog` reaches the disk.

    :param flush_wall_s: finish the chunk and flush to the OS at least this often (wall time).
    :param flush_sim_s: ... and hand the rows to the writer at least this often in sim time
        (at the first logged tick after it: a SIGKILL loses at most this plus one tick period of
        the log).  Default 0.3 s with the writer process (killed with it, it may also lose the
        one hand-over it had not written yet), else 0.9 s.
    :param chunk_size: the writer's chunk size in bytes (chunks end sooner, at each flush).
    :param compression: chunk compression: ``"lz4"`` (default), a
        ``foxglove.mcap.MCAPCompression`` member, or ``None`` for none.
    """

    flush_wall_s: float = 1.0
    flush_sim_s: float | None = None
    chunk_size: int = 1 << 20
    compression: Any = "lz4"


def group_rates(channels: str | Iterable[str],
                rates: dict[str, float | None] | None) -> dict[str, float | None]:
    """The rate of each group (Hz; ``None`` = every call, ``0`` = off) of a channel set or list
    of groups, with the overrides ``rates``; a bad name raises ValueError naming it."""
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
    return base


class RunLog(TickLog, EstimateLog, SceneLog):
    """MCAP run log (context manager).  See the module docstring for channels and usage.

    :param path: the ``.mcap`` file to write (parent folders are created); a Foxglove layout
        ``layout.json`` is written beside it.
    :param channels: ``"full"``, ``"light"``, ``"none"`` or an iterable of group names
        (:data:`GROUPS`; unnamed groups are off, named ones use the ``full`` rates).
    :param rates: per-group rate overrides in Hz (``None`` = every call, ``0`` = off).
    :param metadata: run metadata (seed, scenario, ...) -> MCAP metadata record ``run``.
    :param config_toml: the resolved config -> attachment ``config.toml``.
    :param layout: write ``layout.json`` beside the log.
    :param writer: ``"process"`` (default): the encoding and the SDK's writer run in a writer
        process forked now (:class:`ag_uav.record.sink.ProcessSink`; in this process where
        ``os.fork`` is missing); ``"inline"``: in this process, at each flush.
    :param io: flush periods, chunk size and compression (:class:`LogIO`).
    """

    def __init__(
        self,
        path: str | os.PathLike[str],
        *,
        channels: str | Iterable[str] = "full",
        rates: dict[str, float | None] | None = None,
        metadata: dict[str, Any] | None = None,
        config_toml: str = "",
        layout: bool = True,
        writer: str = "process",
        io: LogIO = LogIO(),
    ):
        self.path = Path(path)
        self._write_failed = False  # the writer failed once (disk full): close() quietly
        #: the writer process died mid-flight (:class:`~ag_uav.record.sink.WriterLost`): the
        #: log ends there, the flight goes on unlogged
        self.lost: OSError | None = None
        self.lost_at = 0.0  #: the sim time of the last hand-over before the loss
        self.rates = base = group_rates(channels, rates)
        preset = channels if isinstance(channels, str) else ""
        self._dose_period = DOSE_PERIOD_S.get(preset, DOSE_PERIOD_S["full"])
        self._geo_dose_period = GEO_DOSE_PERIOD_S.get(preset, GEO_DOSE_PERIOD_S["full"])
        self._next_geo_dose = -INF
        # period per group: 0.0 = every call, inf = off
        self._period = {
            g: (0.0 if r is None else (INF if r <= 0 else 1.0 / float(r))) for g, r in base.items()
        }
        self.enabled = any(p < INF for p in self._period.values())
        self.closed = not self.enabled
        self._init_state()
        if not self.enabled:
            return
        self._open_writer(writer, io)
        self._declare_run(channels, metadata, config_toml)
        self._layout = layout
        self._write_layout()
        crash.track(self)

    def _init_state(self) -> None:
        """The clocks, counters and channel tables of a log with nothing written yet."""
        self._next_tick = INF
        self._t_last = 0.0
        # next sim time each group is due (inf = off or closed): the hot paths test only this
        self._next = {g: (-INF if self._period[g] < INF and self.enabled else INF)
                      for g in GROUPS}
        self._counts: dict[str, int] = {}  # rare topics; the frequent ones count in _n_*
        self._n_tf = self._n_pose = self._n_pose_est = self._n_state = self._n_gps = 0
        self._n_geo = self._n_geo_est = self._n_geo_gnss = 0
        self._geo: Any = None  # the GeoFrame once geo() has given the origin
        self._geo_ids: dict[str, int] = {}  # geo topic key -> channel index
        self._fix_codes: dict[str, int] = {}  # GNSS fix type -> its code in the gps rows
        self._est: dict[str, EstChan] = {}
        self._banks: dict[tuple[str, ...], EstBank] = {}
        # encoded messages (channel index, bytes, log_time) not yet handed to the writer (the
        # dose maps): they go with the rows at the next flush
        self._pending: list[tuple[int, bytes, int]] = []
        self._ops: list[tuple[Any, ...]] = []  # declarations for the writer's next hand-over
        self._n_chan = 0
        self._flat_rows: list[FlatRows] = []  # estimator and spray channels, encoded at flush
        self._ch_spray: FlatRows | None = None
        self._ch_gps_err: FlatRows | None = None
        self._ch_dose: Any = None
        self._dose_bytes = 0  # bytes of dose maps logged (their period doubles per quota)
        self._next_spray = -INF if self._period["state"] < INF and self.enabled else INF

    def _open_writer(self, writer: str, io: LogIO) -> None:
        """Start the writer, declare the pose channels and set the groups' clocks."""
        import foxglove

        from .sink import open_sink

        self.path.parent.mkdir(parents=True, exist_ok=True)
        warm_encoders()  # before a writer process is forked: it inherits them
        self._sink = open_sink(str(self.path), io.compression, io.chunk_size, writer)
        flush_sim_s = io.flush_sim_s
        if flush_sim_s is None:
            flush_sim_s = 0.3 if self._sink.process else 0.9
        en = {g: self._period[g] < INF for g in GROUPS}
        M = foxglove.messages
        self._M = M
        pose = M.PoseInFrame
        self._tf_id = self._chan("/tf", M.FrameTransforms) if en["tf"] else -1
        if en["pose"]:
            self._pose_ids = [self._chan(tp, pose) for tp in
                              ("/drone/pose", "/drone/pose_est", "/drone/pose_ref")]
        self._gps_id = self._chan("/gps", pose) if en["gps"] else -1
        self._ops.append(("posefmt", POSE_TMPL, POSE_SLOTS,
                          np.frombuffer(POSE_MID, dtype=np.uint8).copy(),
                          np.frombuffer(WORLD2 + str_field(3, "base_link"),
                                        dtype=np.uint8).copy()))
        # (t, x, y, z, var e, n, u, fix type code, t_meas) of the fixes since the last flush
        self._gps_rows = Rows(9, cap=16)
        self._state_schema: FlatSchema | None = None
        self._ctrl_keys: tuple[str, ...] = ()
        self._n_motors = 0
        self._rows = Rows(TICK_HEAD)  # the tick rows to encode (re-made by the state schema)
        self._last_row: np.ndarray | None = None
        self._cam: dict[str, Any] = {}
        self._scene_ch: dict[str, int] = {}
        self._next_est: dict[str, float] = {}  # per-camera clocks
        pe = self._period
        self._p_tf, self._p_pose, self._p_state = (pe["tf"] - 1e-9, pe["pose"] - 1e-9,
                                                   pe["state"] - 1e-9)
        self._p_gps, self._p_est = pe["gps"] - 1e-9, pe["estimator"] - 1e-9
        self._p_geo = pe["geo"] - 1e-9
        self._next["geo"] = INF  # on once geo() gives the origin
        self._tick_groups = [g for g in ("tf", "pose", "state") if en[g]]
        self._next_tick = -INF if self._tick_groups else INF
        self._last_true = (NAN, NAN, NAN)
        self._flush_wall_s = float(io.flush_wall_s)
        self._flush_sim_s = float(flush_sim_s)
        self._last_flush_wall = time.perf_counter()
        self._last_flush_sim = -INF

    def _declare_run(self, channels: str | Iterable[str], metadata: dict[str, Any] | None,
                     config_toml: str) -> None:
        """The metadata records ``run`` and ``versions`` and the attachment ``config.toml``."""
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
        if self._ch_gps_err is not None and self._ch_gps_err.count:
            out["/gps/error"] = self._ch_gps_err.count
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
        crash.untrack(self)
        try:
            self._sink.close()
        except Exception:  # noqa: BLE001 - reaping the dead writer is best effort
            pass

    def _stop_clocks(self) -> None:
        self.closed = True
        self._next_tick = INF
        for g in self._next:
            self._next[g] = INF
        for ec in self._est.values():
            ec.next_t = INF
        for bank in self._banks.values():
            bank.next_t = INF
        self._next_spray = INF

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
        return not self.closed and self._period[group] < INF and t >= self._next[group]

    def want_estimator(self, name: str, t: float) -> bool:
        """Would :meth:`estimator` log ``name`` at sim time ``t``? (no side effects)  Lets a
        caller skip building the arguments (e.g. a covariance diagonal) when it would not."""
        ec = self._est.get(name)
        if ec is not None:
            return t >= ec.next_t
        return not self.closed and self._period["estimator"] < INF

    def due(self, t: float) -> bool:
        """True when :meth:`tick` at sim time ``t`` would log something (no side effects): the
        engine builds a tick's arguments only then."""
        return t >= self._next_tick

    def next_due(self, frames: bool = False) -> float:
        """The earliest sim time at which :meth:`tick` (or, with ``frames``, a camera frame)
        would log something (``inf`` when nothing will): the engine calls the log only then."""
        nxt = self._next_tick
        if frames and not self.closed and self._period["camera"] < INF:
            nxt = min(nxt, self._next["camera"])
        return nxt

    def period(self, group: str) -> float:
        """Sim seconds between two messages of ``group`` (``inf``: the group is not logged)."""
        return self._period[group]

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
            from .layout import write_foxglove_layout

            cams = tuple(self._cam)
            if not cams and not final and self._period["camera"] < INF:
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
            crash.untrack(self)
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
