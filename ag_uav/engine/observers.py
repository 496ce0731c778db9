"""Observers: what watches a flight without changing it (logs, camera renders, tick hooks).

Every observer sees the batch through one :class:`TickView`, for one vehicle or many alike:
the engine's per-vehicle arrays (:class:`~ag_uav.engine.stages.Batch`) and, on demand,
:meth:`TickView.data`: a MuJoCo ``MjData`` of vehicle ``i`` set to its current physics state and
this tick's commands, with ``mj_forward`` run (positions, camera poses and sensors up to date).
Nothing is built unless an observer asks for it.

Two moments per tick: :meth:`Observer.tick` before the physics step (the state at ``t`` and the
commands chosen for it: what the log records and the cameras see) and :meth:`Observer.stepped`
after it (the state at ``t + dt``: what a tick hook ``hook(t, data)`` gets).
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from typing import Any

import mujoco
import numpy as np

from ..world.deposition import S_ON, S_Q
from .physics import STATE_SPEC, XF
from .stages import IMU_KEYS, Batch, Control, Sensing

_NAN6 = (np.full(3, np.nan), np.full(3, np.nan))  # no estimate: its position and velocity


class TickView:
    """The batch as observers see it at one moment (see the module docstring)."""

    def __init__(self, b: Batch, models: Sequence[mujoco.MjModel], body: int) -> None:
        self.b, self.models, self.body = b, list(models), body
        self.k, self.t = 0, 0.0
        self._scratch: dict[int, mujoco.MjData] = {}
        self._fresh: set[int] = set()

    def at(self, k: int, t: float) -> TickView:
        self.k, self.t = k, t
        self._fresh.clear()
        return self

    def data(self, i: int) -> mujoco.MjData:
        """Vehicle ``i``'s ``MjData`` now (a scratch copy; changing it changes nothing)."""
        d = self._scratch.get(i)
        if d is None:
            d = self._scratch[i] = mujoco.MjData(self.models[i])
        if i not in self._fresh:
            m = self.models[i]
            mujoco.mj_setState(m, d, self.b.S[i], STATE_SPEC)
            d.ctrl[:] = self.b.f[i]
            d.xfrc_applied[self.body, XF.FORCE:XF.FORCE_END] = self.b.xf[i]
            mujoco.mj_forward(m, d)
            self._fresh.add(i)
        return d


class Observer:
    """Watches vehicle ``i``; both moments are optional. :meth:`next_time` lets the engine skip
    the call on ticks where the observer has nothing to do."""

    i: int

    def next_time(self) -> float:
        """The earliest sim time of a tick :meth:`tick` must see (default: every tick)."""
        return -math.inf

    def tick(self, view: TickView) -> None:
        """Before the physics step of the tick at ``view.t``."""

    def stepped(self, view: TickView) -> None:
        """After the physics step of the tick at ``view.t``."""

    def close(self) -> None:
        """Release what the observer holds (renderers)."""


class HookObserver(Observer):
    """``hook(t, data)`` after every control tick: ``data`` is the vehicle's state after the
    step (``data.time`` = t + dt) with the commands held over it."""

    def __init__(self, i: int, hook: Callable[..., None]) -> None:
        self.i, self.hook = i, hook
        self._data = _LazyData()

    def stepped(self, view: TickView) -> None:
        self.hook(view.t, self._data.bind(view, self.i))


class _LazyData:
    """An ``MjData`` stand-in that builds the view's data on first attribute access, so a hook
    that never looks at ``data`` costs nothing."""

    __slots__ = ("_view", "_i")

    def bind(self, view: TickView, i: int) -> _LazyData:
        self._view, self._i = view, i
        return self

    def __getattr__(self, name: str) -> Any:
        return getattr(self._view.data(self._i), name)

    def unwrap(self) -> mujoco.MjData:
        return self._view.data(self._i)


class LogObserver(Observer):
    """Vehicle ``i``'s run log (:class:`ag_uav.record.runlog.RunLog`): the state, reference,
    estimate, controller internals, motors, wind and spray at the log's rate (with the dose:
    the nozzle model's valve and actual flow as ``ctrl.nozzle.*``, and the dose map on
    ``/dose`` every few seconds), and camera frames when a frame is due. The frames render in
    a thread of their own (:class:`ag_uav.record.render.RenderThread`) while the flight goes on,
    and go into the log, each at its own time, as they are done (the rest at :meth:`close`)."""

    def __init__(self, i: int, log: Any, renderer: Any, feedback: Any, control: Control,
                 sensing: Sensing, depositing: Any = None) -> None:
        self.i, self.log, self.renderer = i, log, renderer
        self.fb, self.control, self.sensing = feedback, control, sensing
        self.frames = 0
        self._est = feedback.name != "true"
        self.dose = depositing.of(i) if depositing is not None else None
        self._dose_f = _dose_factor(self.dose[0].grid) if self.dose is not None else 0
        self._extra: int | None = None  # the log's raw columns after the motors, once bound
        self._imu = False
        #: the next frame's time: the log's camera clock moves only when a frame is logged,
        #: which is later than it is handed to the render thread
        self._frame_next = -math.inf
        self._frame_every = log.period("camera") - 1e-9 if renderer is not None else math.inf

    def next_time(self) -> float:
        return min(self.log.next_due(), self._frame_next if self.renderer is not None
                   else math.inf)

    def tick(self, view: TickView) -> None:
        log, t = self.log, view.t
        if log.due(t):
            self._record(view)
        if self.renderer is not None and t >= self._frame_next:
            self._log_frames(self.renderer.done())
            if log.want_frame(t):
                self._frames(view)
            self._frame_next = t + self._frame_every

    def _record(self, view: TickView) -> None:
        """One tick row of the log (:meth:`~ag_uav.record.runlog.RunLog.tick_slot`): the
        engine's arrays of vehicle ``i`` copied in one go; the log encodes them in blocks."""
        b, i, t, log = view.b, self.i, view.t, self.log
        if self._extra is None:
            self._bind(view)
        row = log.tick_slot(t, self._est)
        if row is not None:
            parts = self._parts
            if b.f is not self._f:  # the controller handed a new thrust buffer
                self._f = b.f
                parts[self._jf] = b.f[i]
            np.concatenate(parts, out=row)
        if self.dose is not None and log.want_dose(t):
            dep, j = self.dose
            g, f = dep.grid, self._dose_f
            log.dose(t, g.x0, g.y0, g.cell * (1 << f), dep.l_per_ha_now(j, f))

    def _bind(self, view: TickView) -> None:
        """The row layout: the controller's state row, the INS's range aid flag, the IMU record,
        the nozzle's valve and flow after the motors; the ctrl keys name their columns in it."""
        bc, i = self.control.bc, self.i
        cols = list(bc.internal_columns(i))
        base = bc.state.shape[1]
        aid = getattr(self.fb, "aid_on", None)  # the INS's range aid flag (a 1-element view)
        if aid is not None:
            cols.append(("nav.range_aid", base))
            base += 1
        self._imu = self.sensing.row(i) is not None
        if self._imu:
            cols += [(k, base + j) for j, k in enumerate(IMU_KEYS)]
            base += len(IMU_KEYS)
        if self.dose is not None:
            cols += [("nozzle.valve", base), ("nozzle.flow_lps", base + S_Q - S_ON)]
            base += S_Q - S_ON + 1
        self._extra = base
        b = view.b
        parts = [b.p[i], b.quat[i], b.v[i], b.rp[i], b.rv[i], b.yaw[i:i + 1]]
        parts += (b.p_fb[i], b.v_fb[i]) if self._est else _NAN6
        self._jf, self._f = len(parts) + 2, b.f
        parts += (b.w[i], b.spray[i:i + 1], b.f[i], bc.state[i])
        if aid is not None:
            parts.append(aid)
        if self._imu:
            parts.append(self.sensing.row(i))
        if self.dose is not None:
            dep, j = self.dose
            parts.append(dep.st[j, S_ON:S_Q + 1])
        self._parts = parts  # views of the engine's arrays (they are written in place)
        self.log.bind_ticks(self.control.b.f.shape[1], [k for k, _ in cols],
                            [c for _, c in cols], base)

    def _frames(self, view: TickView) -> None:
        b, i = view.b, self.i
        self.renderer.submit(view.t, b.S[i], b.f[i], b.xf[i])

    def _log_frames(self, done: list[tuple[float, list]]) -> None:
        r = self.renderer
        for t, shots in done:
            for cam, jpg, pose in shots:
                self.log.frame(t, cam, jpg, r.width, r.height, r.fovy(cam), pose=pose)
                self.frames += 1

    def close(self) -> None:
        """The frames still rendering go into the log (unless it is closed already)."""
        if self.renderer is not None:
            done = self.renderer.close()
            if not self.log.closed:
                self._log_frames(done)
            self.renderer = None


def _dose_factor(g: Any, cell_m: float = 1.0, max_cells: int = 250_000) -> int:
    """Levels by which the live dose map in the log is coarser than the dose map: cells of at
    least ``cell_m`` and at most ``max_cells`` of them (the log's cost stays small)."""
    f = 0
    while f < g.levels - 1 and (g.cell * (1 << f) < cell_m
                                or (g.nx >> f) * (g.ny >> f) > max_cells):
        f += 1
    return f


def frames_of(observers: Sequence[Observer], n: int) -> np.ndarray:
    """Camera frames written per vehicle."""
    out = np.zeros(n, dtype=np.int64)
    for ob in observers:
        if isinstance(ob, LogObserver):
            out[ob.i] += ob.frames
    return out
