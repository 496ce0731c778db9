"""The engine: N missions advanced in lockstep, one control period per iteration.

One loop serves one mission and hundreds. :func:`fly` builds the stages
(:mod:`ag_uav.engine.stages`), the physics stepper (:mod:`ag_uav.engine.physics`) and the
observers (:mod:`ag_uav.engine.observers`), then runs every tick as the flow reads:

    guard → sense → feed back → control → spray → disturb → deposit → record → observe → physics

* **guard**: state rows → pose; non-finite, tilt > 80°, bounding box and ground contacts end a
  vehicle's flight with its reason; the reference row;
* **sense**: the MEMS IMU (MuJoCo's accelerometer and gyro at the ``imu`` site) and the
  attitude estimate;
* **feed back**: the true state, the batched estimator bank (GNSS fixes → KF / MCKF / PCA-KF /
  PCA-MCKF) or any other feedback through a per-vehicle adapter (which says so);
* **control**: the batched cascade (IT2/T1-FPID or PID per axis, thrust vectoring, geometric
  attitude loop, X mixer); **spray**: the spray job; **disturb**: wind (mean + Dryden) as a
  drag force, held over the control period; **deposit**: the nozzles, droplets and the dose map
  (:class:`~ag_uav.engine.stages.Depositing`), then the tank draws what the nozzles let out
  (:meth:`~ag_uav.engine.stages.Spraying.settle`: the liquid mass follows the nozzle model's
  valve and pressure lag, so ``spray.deposition = false`` changes the flight slightly);
* **record**: the tick's row (arrays); **observe**: logs, camera frames and tick hooks, all
  through one view of the batch;
* **physics**: one control period of every active vehicle (``mj_step`` for one vehicle,
  ``mujoco.rollout`` for many; one MjModel per vehicle, so payload, motor lag and drag may
  differ; the models of a batch share their sizes, since the field is scenery).

A big batch with no observer flies in **lanes** (:func:`lane_count`): one engine per thread over
its part of the batch, each flying to its end in a thread of its own with a one-thread rollout.
MuJoCo and the kernels release the GIL, so one lane's stages run while another's physics does.

Every law is a numba kernel over the batch axis that never mixes rows, and every random draw
comes from the vehicle's own Generators, so a mission's trajectory does not depend on the batch
it flies in (tested bit for bit). A vehicle leaves the batch when its mission ends, crashes or
diverges (with its reason); the others go on, and finished vehicles are no longer stepped.

The loop runs with the objects that existed before it frozen (``gc.freeze``; unfrozen after):
the garbage collector's full collections then scan what the loop made, not the whole heap of
numba, MuJoCo and the run's set-up (about 45 ms each otherwise, one every few seconds of loop).
"""

from __future__ import annotations

import copy
import gc
import math
import time
from collections.abc import Callable, Sequence
from concurrent.futures import FIRST_COMPLETED, ThreadPoolExecutor, wait
from dataclasses import dataclass, field
from typing import Any

import mujoco
import numpy as np

from numkit import X, Y, Z
from numkit.geometry import yaw_to_quat

from ..config import Config
from ..vehicle.mjcf import Vehicle, build_vehicle
from .compiling import compile_notice, first_tick
from .heap import trim_heap
from .kernels import FQ
from .observers import HookObserver, LogObserver, Observer, TickView, frames_of
from .physics import STATE_SPEC, default_threads, make_stepper, reset_rows, unstable_reason
from .reftable import RefTable
from .stages import (
    REC_COLUMNS,
    Batch,
    Control,
    Depositing,
    Disturbance,
    Failsafe,
    Feedback,
    Guard,
    Recorder,
    Sensing,
    Spraying,
)

__all__ = ["REC_COLUMNS", "Flight", "LoopOutput", "fly"]

#: fewest vehicles per lane for the batch to be split into one lane per thread
LANE_MIN = 8
#: split big batches into lanes unless asked otherwise (``ag-uav bench``: one engine on the
#: rollout's thread pool against lanes, ``batched.one_engine_*``)
LANES_BY_DEFAULT = True
@dataclass
class Flight:
    """One vehicle's job in a :func:`fly` batch: its config, the reference it flies
    (``sample(t)`` / ``sample_all(times)``, as :class:`~ag_uav.world.reference.Reference`) for
    ``duration`` seconds (cut at ``sim.max_time_s``), and what to do with it. ``outline``:
    scenery for the cameras (closed polylines on the ground), never part of the physics."""

    cfg: Config
    reference: Any
    duration: float
    outline: list[np.ndarray] | None = None
    bounds: tuple[float, float, float, float] | None = None
    feedback: Any = None
    log: Any = None
    render: bool = False
    tick_hook: Callable[..., None] | None = None
    streams: dict | None = None
    field: Any = None   # the field (ag_uav.world.field.Field): with it, the dose map


@dataclass
class LoopOutput:
    t: np.ndarray
    rec: np.ndarray              # (n, 21 + rotors past the fourth) see REC_COLUMNS
    crash_reason: str | None
    crash_time: float | None
    wall_loop_s: float
    vehicle: Vehicle
    frames: int = 0
    notes: list[str] = field(default_factory=list)
    imu: np.ndarray | None = None         # (n, 9) measured f (3), gyro (3), attitude error (3)
    imu_bias0: np.ndarray | None = None   # turn-on biases (accel m/s², gyro rad/s)
    sprayer: Any = None
    compile_s: float = 0.0                # kernels compiled on the first tick (not in wall_loop_s)
    cpu_loop_s: float = 0.0               # the process's CPU seconds (all threads) over wall_loop_s
    s0: np.ndarray | None = None          # with capture: the initial full physics state
    controls: np.ndarray | None = None    # with capture: (n, 7) rotor commands (4), force (3)
    dose: Any = None                      # the dose map (ag_uav.world.deposition.DoseMap) or None
    lanes: int = 1                        # the lanes its batch flew in (threads of the engine)
    failsafe: dict | None = None          # the position failsafe's reason and times, if engaged
    gnss_losses: list = field(default_factory=list)  # GNSS loss episodes (stages.GnssLoss)
    rotor_fault: dict | None = None       # vehicle.rotor_fault: when, detected, response, end


# ------------------------------------------------------------------------------------ setup
def _vehicles(flights: Sequence[Flight]) -> list[Vehicle]:
    """One Vehicle (own MjModel) per flight; identical builds are compiled once and copied."""
    out: list[Vehicle] = []
    cache: dict[Any, Vehicle] = {}
    for fl in flights:
        key = (repr(fl.cfg.vehicle), repr(fl.cfg.sim), repr(fl.cfg.spray.enabled))
        base = cache.get(key)
        if base is None:
            base = cache[key] = build_vehicle(fl.cfg)
            out.append(base)
            continue
        veh = Vehicle.__new__(Vehicle)
        veh.__dict__.update(base.__dict__)
        veh.model = copy.copy(base.model)
        out.append(veh)
    return out


def _check_rates(flights: Sequence[Flight]) -> None:
    c0 = flights[0].cfg.sim
    for fl in flights:
        if (fl.cfg.sim.control_hz, fl.cfg.sim.timestep_s) != (c0.control_hz, c0.timestep_s):
            raise ValueError("engine.fly: all flights of a batch must share sim.control_hz and "
                             "sim.timestep_s")


def _initial_state(fl: Flight, veh: Vehicle, S: np.ndarray, sens: np.ndarray) -> None:
    """The vehicle at the reference's start: on its skids (take-off) or hovering."""
    cfg, model = fl.cfg, veh.model
    data = mujoco.MjData(model)
    start = fl.reference.sample(0.0)
    qpos, o = data.qpos, FQ.POS   # the vehicle's free joint (FREE_QPOS)
    qpos[o + X], qpos[o + Y] = start.pos[X], start.pos[Y]
    qpos[o + Z] = veh.hover_z if cfg.sim.takeoff else start.pos[Z]
    yaw_to_quat(start.yaw, qpos[FQ.QUAT:FQ.QUAT_END])   # q = (cos ψ/2, 0, 0, sin ψ/2)
    if not cfg.sim.takeoff:
        data.ctrl[:] = veh.mass * 9.81 / 4
        data.act[:] = veh.mass * 9.81 / 4
    mujoco.mj_forward(model, data)
    mujoco.mj_getState(model, data, S, STATE_SPEC)
    sens[:] = data.sensordata


def _box(fl: Flight) -> tuple[float, ...]:
    """The bounding box a vehicle must stay in: the field's bounds (or 100 m about the start)
    plus 100 m, and 120 m up."""
    b = fl.bounds
    if b is None:
        p0 = fl.reference.sample(0.0).pos
        b = (p0[X] - 100, p0[Y] - 100, p0[X] + 100, p0[Y] + 100)
    x0, y0, x1, y1 = b
    return (x0 - 100.0, y0 - 100.0, x1 + 100.0, y1 + 100.0, 120.0)   # BOUNDS's fields


def _batch(flights: Sequence[Flight], vehs: Sequence[Vehicle], dt: float
           ) -> tuple[Batch, list[dict[str, np.ndarray]]]:
    m0 = vehs[0].model
    N = len(flights)
    S = np.empty((N, mujoco.mj_stateSize(m0, STATE_SPEC)))
    sens = np.zeros((N, m0.nsensordata))
    for i, (fl, veh) in enumerate(zip(flights, vehs, strict=True)):
        _initial_state(fl, veh, S[i], sens[i])
    n_ticks = np.array([int(math.ceil(min(fl.duration, fl.cfg.sim.max_time_s) / dt - 1e-9))
                        for fl in flights], dtype=np.int64)
    ref, ref_ids, job_tabs = RefTable.of(flights, n_ticks, dt)
    b = Batch(dt=dt, S=S, sens=sens, n_ticks=n_ticks,
              airborne=np.array([not fl.cfg.sim.takeoff for fl in flights]),
              hover_z=np.array([v.hover_z for v in vehs]),
              box=np.array([_box(fl) for fl in flights], dtype=float),
              ref=ref, ref_ids=ref_ids, n_max=int(n_ticks.max()), notes=[[] for _ in range(N)],
              n_rot=int(m0.nu))
    return b, job_tabs


def _sensing(b: Batch, flights: Sequence[Flight], fbs: Sequence[Any], m0: Any) -> Sensing:
    from ..seeds import seed_sequences
    from ..vehicle.imu import AttitudeError, ImuSensor
    from ..vehicle.sensors_batched import BatchAttitudeError, BatchImu

    wants = [fb.wants_imu for fb in fbs]
    if any(wants) and not all(wants):
        raise ValueError("engine.fly: a batch mixes flights with and without the MEMS IMU")
    imu = att = None
    if wants[0]:
        imus, atts = [], []
        for fl in flights:
            ss, c = seed_sequences(fl.cfg.seed), fl.cfg
            imus.append(ImuSensor(c.imu, c.sim.control_hz, ss["imu"]))
            atts.append(AttitudeError(c.imu, c.sim.control_hz, ss["attitude"]))
        imu, att = BatchImu.from_sensors(imus), BatchAttitudeError.from_errors(atts)
    inc = imu is not None and flights[0].cfg.imu.sampling == "increments"
    if inc:
        b.sub = np.repeat(b.sens[:, None, :], round(b.dt / m0.opt.timestep), axis=1)
    return Sensing(b, imu, att, int(m0.sensor("accel").adr[0]), int(m0.sensor("gyro").adr[0]),
                   inc)


def _disturbance(b: Batch, flights: Sequence[Flight]) -> Disturbance:
    from ..seeds import rng_streams
    from ..vehicle.sensors_batched import BatchWind
    from ..world.forecast import MEANDER_STEP_S, meander_angles
    from ..world.wind import Wind

    winds, phis = [], []
    for i, fl in enumerate(flights):
        w, streams = fl.cfg.wind, fl.streams or rng_streams(fl.cfg.seed)
        winds.append(Wind(w.speed_mps, w.direction_deg, w.turbulence, rng=streams["wind"]))
        phis.append(meander_angles(streams["meander"], w.meander_deg, w.meander_tau_s,
                                   float(b.n_ticks[i]) * b.dt))
    c_lin = np.array([fl.cfg.vehicle.drag_linear for fl in flights], dtype=float)
    c_quad = np.array([fl.cfg.vehicle.drag_quadratic for fl in flights], dtype=float)
    meander = None
    if any(p.any() for p in phis):
        meander = np.zeros((len(phis), max(len(p) for p in phis)))
        for i, p in enumerate(phis):
            meander[i, :len(p)], meander[i, len(p):] = p, p[-1]
    every = max(1, int(round(MEANDER_STEP_S / b.dt)))
    return Disturbance(b, BatchWind.from_winds(winds), c_lin, c_quad, meander, every)


def _spraying(b: Batch, flights: Sequence[Flight], vehs: Sequence[Vehicle],
              job_tabs: list[dict[str, np.ndarray]], control: Control, m0: Any
              ) -> tuple[Spraying | None, list[Any]]:
    jobs = [getattr(fl.reference, "spray_job", None) for fl in flights]
    if all(j is None for j in jobs):
        return None, [None] * b.n
    if any(j is None for j in jobs):
        raise ValueError("engine.fly: a batch mixes spray jobs and plain flights")
    from .spray_batched import BatchSprayer, MassSink
    from .sprayer import Sprayer

    objs = [Sprayer(fl.cfg, veh, None, MassSink(i, control.set_mass),
                    job_tabs[b.ref_ids[i]], job, int(b.n_ticks[i]), b.dt, fl.log,
                    nozzle_model=fl.field is not None and fl.cfg.spray.deposition)
            for i, (fl, veh, job) in enumerate(zip(flights, vehs, jobs, strict=True))]
    spr = BatchSprayer.from_sprayers(objs, control.set_mass, push_initial=False)
    ia = mujoco.mj_stateSize(m0, mujoco.mjtState.mjSTATE_TIME) + m0.nq + m0.nv
    return Spraying(b, spr, control, ia, m0.na), objs


def _depositing(b: Batch, flights: Sequence[Flight], act_adr: int, n_act: int
                ) -> Depositing | None:
    """The dose maps of the flights that have a field and ``spray.deposition``: one
    :class:`~ag_uav.world.deposition.DepositionBatch` per (deposition config, field bounds)."""
    from ..world.deposition import DepositionBatch, DepositionConfig
    from ..world.pattern import mission_swath

    keyed: dict[str, tuple[list[int], Any, Any]] = {}
    for i, fl in enumerate(flights):
        if fl.field is None or not fl.cfg.spray.deposition:
            continue
        dc = DepositionConfig.from_config(fl.cfg, swath_m=mission_swath(fl.cfg))
        key = repr((dc, tuple(fl.field.bounds)))
        keyed.setdefault(key, ([], dc, fl.field))[0].append(i)
    if not keyed:
        return None
    groups = [(np.array(rows, dtype=np.int64), DepositionBatch(dc, fld, len(rows)))
              for rows, dc, fld in keyed.values()]
    return Depositing(b, groups, act_adr, n_act)


def _observers(b: Batch, flights: Sequence[Flight], vehs: Sequence[Vehicle],
               fbs: Sequence[Any], control: Control, sensing: Sensing,
               depositing: Depositing | None = None) -> list[Observer]:
    obs: list[Observer] = []
    for i, fl in enumerate(flights):
        if fl.log is not None:
            if hasattr(fbs[i], "log"):
                fbs[i].log = fl.log
            obs.append(LogObserver(i, fl.log, _renderer(b, i, fl, vehs[i]), fbs[i], control,
                                   sensing, depositing))
        if fl.tick_hook is not None:
            obs.append(HookObserver(i, fl.tick_hook))
    return obs


def _renderer(b: Batch, i: int, fl: Flight, veh: Vehicle) -> Any:
    if not fl.render:
        return None
    from ..record.render import RenderThread, RenderUnavailable

    c = fl.cfg.log
    try:
        return RenderThread(veh.model, c.width, c.height, tuple(c.cameras),
                            scenery=fl.outline or (), body=veh.body_id)
    except RenderUnavailable as e:
        b.notes[i].append(f"no camera frames: {e}")
        return None


# ------------------------------------------------------------------------------------ engine
@dataclass
class Stages:
    """The built stages of one lane (:class:`Engine`), by name, in the flow's order."""

    b: Batch
    guard: Guard
    sensing: Sensing
    feedback: Feedback
    control: Control
    spraying: Spraying | None
    disturbance: Disturbance
    depositing: Depositing | None
    observers: list[Observer]
    #: the lane's sprayers (None for a plain flight) and vehicles, one per row
    sprayers: list[Any]
    vehicles: list[Vehicle]


class Engine:
    """The built stages of one lane of a :func:`fly` call and its tick, in the flow's order:
    ``stages`` (:class:`Stages`), the observers' ``view`` and the physics ``stepper``;
    ``capture`` keeps the recorder's per-tick capture (the bench's replays)."""

    def __init__(self, stages: Stages, view: TickView, stepper: Any,
                 capture: bool = False) -> None:
        st = stages
        b, observers = st.b, st.observers
        self.b, self.guard, self.sensing, self.feedback = b, st.guard, st.sensing, st.feedback
        self.control, self.spraying, self.disturbance = st.control, st.spraying, st.disturbance
        self.recorder = Recorder(b, capture)
        self.observers, self.view, self.stepper = observers, view, stepper
        self.sprayers, self.vehicles = st.sprayers, st.vehicles
        self.depositing = st.depositing
        self.failsafe: Failsafe | None = None
        self.rotor_faults: Any = None  # ag_uav.engine.rotor_fault.RotorFaults, when a fault is set
        self.pre_obs = [ob for ob in observers if type(ob).tick is not Observer.tick]
        self.post_obs = [ob for ob in observers if type(ob).stepped is not Observer.stepped]
        self._pre_next = -math.inf  # the earliest time a pre-physics observer is due
        self.k = -1  # the last tick flown
        self.halt = False  # set from outside: stop before the next tick
        self.threads = getattr(stepper, "nthread", 0)  # offered from outside (lanes finished)
        self.rows: list[int] = []  # its vehicles' places in the fly() call

    def before_physics(self, k: int, t: float) -> bool:
        """Guard, sense, feed back, control, spray, disturb, deposit, record, observe; False
        when no vehicle of this lane is left to fly."""
        if k >= self.b.n_max or not self.guard.start(k, t):
            return False
        self.sensing.step(k)
        self.feedback.step(k, t)
        if self.failsafe is not None:
            self.failsafe.step(k, t)
        if self.rotor_faults is not None:
            self.rotor_faults.step(k, t)
        self.control.step()
        if self.rotor_faults is not None:
            self.rotor_faults.after_control(t)
        if self.spraying is not None:
            self.spraying.step(k, t)
        self.disturbance.step(k)
        if self.depositing is not None:
            self.depositing.step()
        if self.spraying is not None:
            self.spraying.settle(k, t, self.depositing)
        self.recorder.step(k)
        if self.pre_obs and t >= self._pre_next:
            self._observe(self.pre_obs, "tick", k, t)
            obs = self.pre_obs
            self._pre_next = (obs[0].next_time() if len(obs) == 1
                              else min(ob.next_time() for ob in obs))
        return True

    def physics(self) -> None:
        b = self.b
        t0 = b.S[:, 0].copy()
        self.stepper.step(b.S, b.sens, b.f, b.xf, b.act, b.sub)
        for i in reset_rows(t0, b.S, b.act):   # MuJoCo reset an unstable vehicle
            self.guard.end(i, unstable_reason(float(t0[i])), float(t0[i]))

    def tick(self, k: int) -> bool:
        """Tick ``k`` whole (stages, physics, the observers of the stepped state); False when
        no vehicle of this lane is left to fly."""
        t = k * self.b.dt
        if not self.before_physics(k, t):
            return False
        self.physics()
        self.after_physics(k, t)
        self.k = k
        return True

    def after_physics(self, k: int, t: float) -> None:
        if self.post_obs:
            self._observe(self.post_obs, "stepped", k, t)

    def _observe(self, obs: list[Observer], moment: str, k: int, t: float) -> None:
        view, act = self.view.at(k, t), self.b.act
        for ob in obs:
            if act[ob.i]:
                getattr(ob, moment)(view)

    def close(self) -> None:
        self.stepper.close()
        for ob in self.observers:
            ob.close()

    def finish(self) -> None:
        if self.spraying is not None:
            self.spraying.spr.finish()
        self.feedback.finish()


def _build(flights: Sequence[Flight], nthread: int | None, capture: bool = False) -> Engine:
    from controllers.batched import BatchCascade

    from ..navigation.feedback import TrueFeedback
    from ..vehicle.cascade import make_cascade

    vehs = _vehicles(flights)
    m0 = vehs[0].model
    dt = 1.0 / flights[0].cfg.sim.control_hz
    b, job_tabs = _batch(flights, vehs, dt)
    fbs = [fl.feedback or TrueFeedback() for fl in flights]
    iq = mujoco.mj_stateSize(m0, mujoco.mjtState.mjSTATE_TIME)
    control = Control(b, BatchCascade.from_cascades(
        [make_cascade(fl.cfg, v) for fl, v in zip(flights, vehs, strict=True)]))
    sensing = _sensing(b, flights, fbs, m0)
    spraying, sprayers = _spraying(b, flights, vehs, job_tabs, control, m0)
    if capture:
        for sp in sprayers:
            if sp is not None:
                sp.mass_events = []
    disturbance = _disturbance(b, flights)
    feedback = Feedback(b, fbs, all(isinstance(fb, TrueFeedback) for fb in fbs), sensing.imu)
    depositing = _depositing(b, flights, iq + m0.nq + m0.nv, m0.na)
    observers = _observers(b, flights, vehs, fbs, control, sensing, depositing)
    body = vehs[0].body_id
    stepper = make_stepper([v.model for v in vehs], body, round(dt / m0.opt.timestep), b.S,
                           nthread)
    st = Stages(b, Guard(b, vehs, iq, iq + m0.nq), sensing, feedback, control, spraying,
                disturbance, depositing, observers, sprayers, vehs)
    e = Engine(st, TickView(b, [v.model for v in vehs], body), stepper, capture)
    if hasattr(feedback.bank, "pos_sigma"):
        e.failsafe = Failsafe(b, feedback.bank, [fl.cfg for fl in flights])
    if any(fl.cfg.vehicle.rotor_fault.rotor >= 0 for fl in flights):
        from .rotor_fault import RotorFaults

        e.rotor_faults = RotorFaults(b, [fl.cfg for fl in flights], vehs, control.bc,
                                     _homes(flights))
    return e


def _homes(flights: Sequence[Flight]) -> np.ndarray:
    """Where each vehicle's base is: its spray job's, else where its reference starts."""
    out = np.zeros((len(flights), 2))
    for i, fl in enumerate(flights):
        job = getattr(fl.reference, "spray_job", None)
        out[i] = (job.base_xy if job is not None
                  else np.asarray(fl.reference.sample(0.0).pos, float)[:Z])
    return out


def _run(lanes: list[Engine], bar: Any) -> tuple[float, float, float]:
    """Every tick until no vehicle is left; (loop wall seconds, compile seconds of tick 0, the
    process's CPU seconds over the same span: every thread's, so CPU ÷ wall is the cores kept busy).

    Tick 0 of every lane runs here (on a fresh checkout it compiles the kernels). Then one
    lane flies on in this thread, or several lanes (disjoint parts of the batch, each a whole
    engine over its rows with a one-thread rollout) each fly to the end in a thread of their
    own: MuJoCo and the kernels release the GIL, so one lane's stages run while another's
    physics does, and no lane waits for another at every tick. Rows never mix, so the lanes
    change nothing in the results."""
    freeze = gc.get_freeze_count() == 0  # (a caller's own frozen objects are left as they are)
    if freeze:  # the loop's full collections scan only what the loop made, not the whole heap
        gc.freeze()
    wall, cpu = time.perf_counter(), time.process_time()
    try:
        with compile_notice(bar):
            flying = [e for e in lanes if e.tick(0)]
        compile_s, wall = first_tick(wall)
        if compile_s:
            cpu = time.process_time()
        if len(flying) == 1:
            _fly_on(flying[0], bar)
        elif flying:
            _fly_lanes(flying, bar)
    finally:
        if freeze:
            gc.unfreeze()
    return time.perf_counter() - wall, compile_s, time.process_time() - cpu


def _fly_on(e: Engine, bar: Any = None) -> None:
    """Lane ``e``'s ticks from its next one until none of its vehicles is left (or it is told
    to halt: another lane failed, or the caller was interrupted). Between ticks it takes up
    the threads it is offered (``e.threads``: cores that lanes done before it left idle)."""
    dt, bar_next = e.b.dt, 1.0
    for k in range(e.k + 1, e.b.n_max):
        t = k * dt
        if e.halt:
            return
        if e.threads != e.stepper.nthread:
            e.stepper.set_threads(e.threads)
        if not e.tick(k):
            return
        if bar is not None and t >= bar_next:
            bar.update(1)
            bar_next += 1.0


def _fly_lanes(lanes: list[Engine], bar: Any) -> None:
    """Each lane to its end in a thread of its own; this thread keeps the progress bar and,
    as lanes finish, offers their cores to the lanes still flying (their rollouts widen). A
    lane that raises halts the others, and so does an interrupt here (Ctrl-C)."""
    cores = len(lanes)
    with ThreadPoolExecutor(len(lanes), thread_name_prefix="ag-uav-lane") as pool:
        futs = {pool.submit(_fly_on, e): e for e in lanes}
        pending = set(futs)
        try:
            while pending:
                done, pending = wait(pending, timeout=0.5, return_when=FIRST_COMPLETED)
                if any(fu.exception() is not None for fu in done):
                    break
                if done and pending:
                    left = [futs[fu] for fu in pending]
                    for j, e in enumerate(left):
                        t = cores // len(left) + (j < cores % len(left))
                        e.threads = 0 if t == 1 else t
                if bar is not None:  # the slowest lane still flying
                    flying = [futs[fu] for fu in pending] or lanes
                    flown = int(min(e.k for e in flying) * lanes[0].b.dt)
                    if flown > bar.n:
                        bar.update(flown - bar.n)
        finally:
            for e in lanes:
                e.halt = True
        for fu in futs:
            fu.result()


def _outputs(e: Engine, wall: float, compile_s: float, cpu: float) -> list[LoopOutput]:
    b = e.b
    frames = frames_of(e.observers, b.n)
    imu = e.sensing.imu
    outs = []
    for i in range(b.n):
        n = int(b.flown[i])
        out = LoopOutput(t=np.arange(n) * b.dt, rec=e.recorder.of(i, n),
                         crash_reason=b.crash_reason[i], crash_time=b.crash_time[i],
                         wall_loop_s=wall, cpu_loop_s=cpu, vehicle=e.vehicles[i],
                         frames=int(frames[i]),
                         notes=b.notes[i], sprayer=e.sprayers[i], compile_s=compile_s,
                         dose=e.depositing.dose_map(i) if e.depositing is not None else None,
                         failsafe=None if e.failsafe is None else e.failsafe.info[i],
                         gnss_losses=[] if e.failsafe is None else e.failsafe.loss.losses[i],
                         rotor_fault=(None if e.rotor_faults is None
                                      else e.rotor_faults.info[i]))
        if imu is not None:
            out.imu = np.ascontiguousarray(e.sensing.rec[:n, i])
            out.imu_bias0 = imu.bias0[i].copy()
        if e.recorder.s0 is not None:
            out.s0, out.controls = e.recorder.s0[i], e.recorder.controls[:n, i].copy()
        outs.append(out)
    return outs


def lane_count(flights: Sequence[Flight], nthread: int | None = None,
               lanes: int | None = None) -> int:
    """How many lanes :func:`fly` splits ``flights`` into: ``lanes`` if given, else one per
    thread when each gets at least :data:`LANE_MIN` vehicles and no flight has an observer (a
    log, camera frames or a tick hook are served from the caller's thread), else 1."""
    n = len(flights)
    threads = default_threads(n) if nthread is None else nthread
    if lanes is None:
        watched = any(fl.log is not None or fl.render or fl.tick_hook is not None
                      for fl in flights)
        lanes = (threads if LANES_BY_DEFAULT and not watched and threads > 1
                 and n >= LANE_MIN * threads else 1)
    return max(1, min(lanes, n))


def _lanes(flights: list[Flight], nthread: int | None, lanes: int | None,
           capture: bool = False) -> list[Engine]:
    """The batch as :func:`lane_count` engines, vehicle i in lane i mod L (so a batch ordered
    by field or length spreads its long missions over the lanes), each flying in a thread of
    its own with a one-thread rollout; or one engine whose rollout uses ``nthread`` threads.
    Each engine's ``rows`` are its vehicles' places in ``flights``."""
    n_lanes = lane_count(flights, nthread, lanes)
    if n_lanes == 1:
        threads = default_threads(len(flights)) if nthread is None else nthread
        e = _build(flights, threads, capture)
        e.rows = list(range(len(flights)))
        return [e]
    out = []
    for j in range(n_lanes):
        rows = list(range(j, len(flights), n_lanes))
        e = _build([flights[i] for i in rows], 0, capture)
        e.rows = rows
        out.append(e)
    return out


def fly(flights: Sequence[Flight], *, progress: bool = False, nthread: int | None = None,
        lanes: int | None = None, capture: bool = False) -> list[LoopOutput]:
    """Fly every flight of ``flights`` in lockstep; one :class:`LoopOutput` per flight.

    All flights must share ``sim.control_hz`` and ``sim.timestep_s``. ``nthread``: threads
    (default: ``$AG_UAV_ENGINE_THREADS`` or the machine's cores, at most the batch size; a
    single vehicle is stepped in this thread). ``lanes``: engines the batch is split into, each
    flying in a thread of its own (default: one per thread for batches of at least
    :data:`LANE_MIN` vehicles per thread and no observer; 1: one engine, the rollout on
    ``nthread`` threads).
    ``capture``: each output also holds its initial physics state and the controls the physics
    was handed each tick (``s0``, ``controls``: what ``ag-uav bench`` replays)."""
    flights = list(flights)
    if not flights:
        return []
    _check_rates(flights)
    trim_heap()   # what planning freed goes back to the system (heap.py) ...
    engines = _lanes(flights, nthread, lanes, capture)
    trim_heap()   # ... and what building the engines freed, before the flight
    b0 = engines[0].b
    bar = None
    if progress:
        from .._progress import progress_bar

        n_max = max(e.b.n_max for e in engines)
        bar = progress_bar(total=round(n_max * b0.dt), unit="sim-s", desc="flying",
                           leave=False, dynamic_ncols=True, mininterval=0.5)
    try:
        wall, compile_s, cpu = _run(engines, bar)
    finally:
        for e in engines:
            e.close()
        if bar is not None:
            bar.close()
    trim_heap()   # the loop's freed pages, before the outputs are gathered
    outs: list[Any] = [None] * len(flights)
    for e in engines:
        e.finish()
        for i, o in zip(e.rows, _outputs(e, wall, compile_s, cpu), strict=True):
            o.lanes = len(engines)
            outs[i] = o
    trim_heap()   # and the outputs' freed temporaries, before the caller's summary
    return outs
