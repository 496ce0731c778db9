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
from collections.abc import Iterable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from . import crash
from .atomic import silent_write_failure
from .channels import Channels
from .log_estimates import EstimateWriter
from .log_geo import GeoWriter
from .log_scene import SceneWriter
from .log_ticks import Tick, TickWriter
from .sink import WriterLost
from .wire import (
    INF,
    FlatSchema,
    enc_pose_in_frame,
    enc_transform,
    ns,
    sanitize_name,
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


class RunLog:
    """MCAP run log (context manager).  See the module docstring for channels and usage.

    It owns four writers, which reach the file only through its :class:`Channels`
    (:attr:`channels`): the tick rows, spray state and GNSS fixes
    (:class:`~ag_uav.record.log_ticks.TickWriter`), the estimators
    (:class:`~ag_uav.record.log_estimates.EstimateWriter`), the scene, dose maps and cameras
    (:class:`~ag_uav.record.log_scene.SceneWriter`) and the geographic topics
    (:class:`~ag_uav.record.log_geo.GeoWriter`); its methods are theirs.

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

    SPRAY_FIELDS = TickWriter.SPRAY_FIELDS
    GPS_ERROR_FIELDS = TickWriter.GPS_ERROR_FIELDS

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
        self.rates = base = group_rates(channels, rates)
        # period per group: 0.0 = every call, inf = off
        period = {g: (0.0 if r is None else (INF if r <= 0 else 1.0 / float(r)))
                  for g, r in base.items()}
        enabled = any(p < INF for p in period.values())
        #: what the writers share: the groups' clocks, the channels, the hand-over
        self.channels = ch = Channels(period, enabled)
        self._geo = GeoWriter(ch)
        self._ticks = TickWriter(ch, self._geo)
        self._est = EstimateWriter(ch, self._ticks)
        self._scene = SceneWriter(ch, self._geo,
                                  channels if isinstance(channels, str) else "")
        ch.sources += [self._ticks, self._est]
        self._layout = _Layout(self.path.parent / "layout.json", layout and enabled,
                               ch.on("camera"), self._ticks, self._est, self._scene, self._geo)
        ch.on_layout = self._layout.write
        if not enabled:
            return
        self._open_writer(writer, io)
        self._declare_run(channels, metadata, config_toml)
        self._layout.write()
        crash.track(self)

    @property
    def enabled(self) -> bool:
        """Whether anything is logged at all."""
        return self.channels.enabled

    @property
    def closed(self) -> bool:
        """Nothing more is logged (closed, or the writer was lost)."""
        return self.channels.closed

    @property
    def lost(self) -> OSError | None:
        """The writer process died mid-flight (:class:`~ag_uav.record.sink.WriterLost`): the
        log ends there, the flight goes on unlogged."""
        return self.channels.lost

    @property
    def lost_at(self) -> float:
        """The sim time of the last hand-over before the loss."""
        return self.channels.lost_at

    def _open_writer(self, writer: str, io: LogIO) -> None:
        """Start the writer, declare the pose channels and set the groups' clocks."""
        from .sink import open_sink

        self.path.parent.mkdir(parents=True, exist_ok=True)
        warm_encoders()  # before a writer process is forked: it inherits them
        sink = open_sink(str(self.path), io.compression, io.chunk_size, writer)
        flush_sim_s = io.flush_sim_s
        if flush_sim_s is None:
            flush_sim_s = 0.3 if sink.process else 0.9
        self.channels.open(sink, io.flush_wall_s, flush_sim_s)
        self._ticks.open()
        self._scene.tf_id = self._ticks.tf_id

    def _declare_run(self, channels: str | Iterable[str], metadata: dict[str, Any] | None,
                     config_toml: str) -> None:
        """The metadata records ``run`` and ``versions`` and the attachment ``config.toml``."""
        md = {k: _meta_str(v) for k, v in (metadata or {}).items()}
        md.setdefault("channels", channels if isinstance(channels, str) else ",".join(channels))
        md.setdefault("rates_hz", json.dumps(self.rates))
        md.setdefault("created_utc", time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime()))
        ops = self.channels.ops
        ops += [("meta", "run", md), ("meta", "versions", _versions())]
        if config_toml:
            ops.append(("attach", {"log_time": 0, "create_time": time.time_ns(),
                                   "name": "config.toml", "media_type": "application/toml",
                                   "data": config_toml.encode("utf-8")}))
        self.channels.send([])

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

    # ---------------------------------------------------------------- what is due
    @property
    def counts(self) -> dict[str, int]:
        """Messages written so far, per topic."""
        out = dict(self.channels.counts)
        self._ticks.counts_into(out)
        self._est.counts_into(out)
        return out

    @property
    def writer_cpu_s(self) -> float:
        """CPU seconds of the writer process once the log is closed (0 with the inline writer,
        whose work is this process's own)."""
        sink = self.channels.sink
        return sink.cpu_s if sink is not None else 0.0

    def flush(self) -> None:
        """Finish the current chunk and hand everything to the OS now (with the writer
        process: hand it to the writer, which does so)."""
        self.channels.flush()

    def want(self, group: str, t: float) -> bool:
        """Would a message of ``group`` at sim time ``t`` be logged? (no side effects)

        For ``"estimator"`` this is the group (any estimator); :meth:`want_estimator` answers
        for one estimator."""
        ch = self.channels
        return not ch.closed and ch.on(group) and t >= ch.next[group]

    def want_estimator(self, name: str, t: float) -> bool:
        """Would :meth:`estimator` log ``name`` at sim time ``t``? (no side effects)  Lets a
        caller skip building the arguments (e.g. a covariance diagonal) when it would not."""
        return self._est.want(name, t)

    def due(self, t: float) -> bool:
        """True when :meth:`tick` at sim time ``t`` would log something (no side effects): the
        engine builds a tick's arguments only then."""
        return self._ticks.due(t)

    def next_due(self, frames: bool = False) -> float:
        """The earliest sim time at which :meth:`tick` (or, with ``frames``, a camera frame)
        would log something (``inf`` when nothing will): the engine calls the log only then."""
        nxt = self._ticks.next_tick
        ch = self.channels
        if frames and not ch.closed and ch.on("camera"):
            nxt = min(nxt, ch.next["camera"])
        return nxt

    def period(self, group: str) -> float:
        """Sim seconds between two messages of ``group`` (``inf``: the group is not logged)."""
        return self.channels.period[group]

    def want_frame(self, t: float) -> bool:
        """True when a camera frame at sim time ``t`` would be logged: render only then."""
        return self.want("camera", t)

    # ---------------------------------------------------------------- the writers' methods
    def tick(self, t: float, v: Tick) -> None:
        """:meth:`TickWriter.tick <ag_uav.record.log_ticks.TickWriter.tick>`."""
        self._ticks.tick(t, v)

    def bind_ticks(self, n_motors: int, ctrl_keys: Sequence[str], ctrl_src: Sequence[int],
                   extra: int) -> None:
        """:meth:`TickWriter.bind_ticks <ag_uav.record.log_ticks.TickWriter.bind_ticks>`."""
        self._ticks.bind_ticks(n_motors, ctrl_keys, ctrl_src, extra)

    def tick_slot(self, t: float, est: bool = False) -> np.ndarray | None:
        """:meth:`TickWriter.tick_slot <ag_uav.record.log_ticks.TickWriter.tick_slot>`."""
        return self._ticks.tick_slot(t, est)

    def spray_state(self, t: float, *, tank_l: float, mass_kg: float, flow_lps: float,
                    nozzles: bool, power_w: float, energy_wh: float, soc: float, sortie: int,
                    ground: bool) -> None:
        """:meth:`TickWriter.spray_state <ag_uav.record.log_ticks.TickWriter.spray_state>`."""
        self._ticks.spray_state(t, tank_l=tank_l, mass_kg=mass_kg, flow_lps=flow_lps,
                                nozzles=nozzles, power_w=power_w, energy_wh=energy_wh, soc=soc,
                                sortie=sortie, ground=ground)

    def spray_row(self, t: float, values: Sequence[float]) -> None:
        """:meth:`TickWriter.spray_row <ag_uav.record.log_ticks.TickWriter.spray_row>`."""
        self._ticks.spray_row(t, values)

    def spray_slot(self, t: float) -> np.ndarray | None:
        """:meth:`TickWriter.spray_slot <ag_uav.record.log_ticks.TickWriter.spray_slot>`."""
        return self._ticks.spray_slot(t)

    def spray_commit(self) -> None:
        """:meth:`TickWriter.spray_commit <ag_uav.record.log_ticks.TickWriter.spray_commit>`."""
        self._ticks.spray_commit()

    def spray_due(self, t: float) -> bool:
        """:meth:`TickWriter.spray_due <ag_uav.record.log_ticks.TickWriter.spray_due>`."""
        return self._ticks.spray_due(t)

    def gps(self, t: float, fix_xyz: Sequence[float], var: Sequence[float] | None = None,
            fix_type: str | None = None, *, t_meas: float | None = None,
            truth: Sequence[float] | None = None) -> None:
        """:meth:`TickWriter.gps <ag_uav.record.log_ticks.TickWriter.gps>`."""
        self._ticks.gps(t, fix_xyz, var, fix_type, t_meas=t_meas, truth=truth)

    def set_truth(self, p_true: Sequence[float]) -> None:
        """The true position at the time of the next ``estimator`` calls (their ``err``): the
        estimator bank calls it before logging a fix's update, so that ``err`` is not measured
        against a pose up to one state period old (at 5 m/s, 50 ms is 0.25 m)."""
        self._ticks.set_truth(p_true)

    def estimator(self, t: float, name: str, x: Sequence[float], p_diag: Sequence[float],
                  innovation: Sequence[float] | None = None,
                  extra: dict[str, float] | None = None, *,
                  pos: Sequence[float] | None = None) -> None:
        """:meth:`EstimateWriter.estimator
        <ag_uav.record.log_estimates.EstimateWriter.estimator>`."""
        self._est.estimator(t, name, x, p_diag, innovation, extra, pos=pos)

    def estimator_bank(self, t: float, names: Sequence[str], x: np.ndarray,
                       p_diag: np.ndarray, p_true: Sequence[float]) -> None:
        """:meth:`EstimateWriter.estimator_bank
        <ag_uav.record.log_estimates.EstimateWriter.estimator_bank>`."""
        self._est.estimator_bank(t, names, x, p_diag, p_true)

    def geo(self, origin: Sequence[float], *, dose_target_l_per_ha: float | None = None) -> None:
        """The run's geodetic origin (lat °, lon °, WGS-84 height m of the local frame's
        origin): turns on the geographic topics (:mod:`ag_uav.record.geo`; group ``geo``):
        LocationFix of the true position, the estimate and the GNSS fixes, and GeoJSON of the
        field, plan, sprayed area and dose (in bands of ``dose_target_l_per_ha``) that
        :meth:`scene`, :meth:`sprayed` and :meth:`dose` log from now on.  Also the metadata
        record ``geo``.  Call once, before :meth:`scene`."""
        if self._geo.start(origin, dose_target_l_per_ha):
            self._ticks.retime()

    def scene(self, t: float, field_outer_xy: Any, field_holes_xy: list[Any],
              plan_segments: list[tuple[str, Any, bool]], swath: float, altitude: float,
              parts: list[tuple[Any, list[Any]]] | None = None) -> None:
        """:meth:`SceneWriter.scene <ag_uav.record.log_scene.SceneWriter.scene>`."""
        self._scene.scene(t, field_outer_xy, field_holes_xy, plan_segments, swath, altitude,
                          parts)

    def sprayed(self, t: float, polygons_xy: list[Any]) -> None:
        """:meth:`SceneWriter.sprayed <ag_uav.record.log_scene.SceneWriter.sprayed>`."""
        self._scene.sprayed(t, polygons_xy)

    def want_dose(self, t: float) -> bool:
        """Would :meth:`dose` log a map at sim time ``t``? (no side effects)"""
        return self._scene.want_dose(t)

    def dose(self, t: float, x0: float, y0: float, cell: float, l_per_ha: Any, *,
             final: bool = False) -> None:
        """:meth:`SceneWriter.dose <ag_uav.record.log_scene.SceneWriter.dose>`."""
        self._scene.dose(t, x0, y0, cell, l_per_ha, final=final)

    def frame(self, t: float, camera: str, jpeg: bytes, width: int, height: int,
              fovy_deg: float, pose: tuple[Sequence[float], Sequence[float]] | None = None
              ) -> None:
        """:meth:`SceneWriter.frame <ag_uav.record.log_scene.SceneWriter.frame>`."""
        self._scene.frame(t, camera, jpeg, width, height, fovy_deg, pose)

    # ---------------------------------------------------------------- end
    def summary(self, summary: dict[str, Any]) -> None:
        """Final metrics -> metadata record ``summary`` and attachment ``summary.json``."""
        ch = self.channels
        if ch.closed:
            return
        ch.drain()
        ch.send([("meta", "summary", {k: _meta_str(v) for k, v in summary.items()}),
                 ("attach", {"log_time": ns(ch.t_last), "create_time": time.time_ns(),
                             "name": "summary.json", "media_type": "application/json",
                             "data": json.dumps(summary, default=str, indent=1).encode()})])

    def close(self, partial: bool = False) -> None:
        """Finish the file (summary, indexes, footer).  Idempotent; safe in signal handlers
        (which pass ``partial``: a tick row still being filled is dropped)."""
        ch = self.channels
        if ch.closed:
            if ch.lost is not None:
                crash.untrack(self)
            return
        ch.stop_clocks()
        try:
            try:
                ch.drain(partial)
            finally:
                if ch.lost is None:
                    ch.sink.close()
        except WriterLost as e:
            ch.lost, ch.lost_at = e, ch.t_last
            raise
        except RuntimeError as e:  # the SDK's writer errors: an OSError naming the file
            err = self.write_error(e)
            if err is None:
                raise
            if not self._write_failed:
                raise err from None
        finally:
            crash.untrack(self)
        self._layout.write(final=True)

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


class _Layout:
    """``layout.json`` beside the log, for the channels seen so far (:meth:`write`)."""

    def __init__(self, path: Path, on: bool, cameras_on: bool, ticks: TickWriter,
                 est: EstimateWriter, scene: SceneWriter, geo: GeoWriter) -> None:
        self.path, self.on, self.cameras_on = path, on, cameras_on
        self.ticks, self.est, self.scene, self.geo = ticks, est, scene, geo

    def write(self, final: bool = False) -> None:
        """Before any frame: with the configured cameras, so that a killed run has a layout; at
        the end (``final``): only the cameras that were logged, so a run whose renders failed
        gets no empty image panels."""
        if not self.on:
            return
        try:
            from .layout import write_foxglove_layout

            cams = self.scene.cameras()
            if not cams and not final and self.cameras_on:
                cams = ("chase", "down")
            write_foxglove_layout(self.path, cameras=cams,
                                  estimators=tuple(sanitize_name(n) for n in self.est.names()),
                                  ctrl_keys=self.ticks.ctrl_keys,
                                  n_motors=self.ticks.n_motors or 4,
                                  spray=self.ticks.has_spray, geo=self.geo.topics())
        except Exception:  # noqa: BLE001 - a missing layout never stops a run
            pass
