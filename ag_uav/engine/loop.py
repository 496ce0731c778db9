"""The engine: N missions advanced in lockstep, one control period per iteration.

One loop serves one mission and hundreds. Each iteration of :func:`fly`:

1. reads every vehicle's physics state (``mjSTATE_FULLPHYSICS`` rows, one per vehicle) and
   checks it (non-finite, tilt > 80°, bounding box, ground contact);
2. senses: the MEMS IMU (MuJoCo's accelerometer and gyro at the ``imu`` site, batched
   :class:`~ag_uav.vehicle.sensors_batched.BatchImu`) and the attitude estimate;
3. feeds back: the true state, the batched estimator bank (GNSS fixes → KF / MCKF / PCA-KF /
   PCA-MCKF, :class:`~ag_uav.navigation.estimation.BatchEstimatorFeedback`), or any other
   :class:`~ag_uav.navigation.feedback.Feedback` through a per-vehicle adapter (correct, slower);
4. controls: the batched cascade (:class:`controllers.batched.BatchCascade`: IT2/T1-FPID or PID
   per axis, thrust vectoring, geometric attitude loop, X mixer), then the spray job;
5. pushes: wind (mean + Dryden) as a drag force, zero-order hold over the control period;
6. records the tick (arrays, not Python lists: a 256-mission batch stays small) and logs or
   renders per vehicle where asked;
7. steps the physics of every vehicle one control period with ``mujoco.rollout`` on a
   persistent thread pool (one MjModel per vehicle, so mass, payload and drag may differ).

Control, sensing, wind and filters are numba-compiled kernels over the batch axis, so the
per-tick Python cost is paid once per batch, not per vehicle. Every random draw comes from the
vehicle's own Generators (drawn in blocks in Python), and no kernel mixes rows, so a mission's
trajectory does not depend on which batch it flies in (tested to 1e-9 m).

A vehicle leaves the batch when its mission ends, crashes or diverges (with its reason); the
others go on. Finished vehicles are no longer stepped.
"""

from __future__ import annotations

import math
import os
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import Any

import mujoco
import numpy as np
from mujoco import rollout as _rollout

from ..config import Config
from ..vehicle.mjcf import Vehicle, build_vehicle

try:
    from numba import njit
except ImportError:  # pragma: no cover - numba is a dependency; the kernels still run slowly
    def njit(*args, **kwargs):
        if args and callable(args[0]):
            return args[0]
        return lambda f: f

STATE_SPEC = int(mujoco.mjtState.mjSTATE_FULLPHYSICS)
CTRL_SPEC = int(mujoco.mjtState.mjSTATE_CTRL | mujoco.mjtState.mjSTATE_XFRC_APPLIED)

#: the loop record's columns (one row per control tick)
REC_COLUMNS = ("px", "py", "pz", "vx", "vy", "vz", "rx", "ry", "rz", "fx", "fy", "fz", "seg",
               "spray", "f0", "f1", "f2", "f3", "wx", "wy", "wz")
#: crash codes of :func:`_kinematics`
_OK, _NONFINITE, _TILT, _BOX = 0, 1, 2, 3


@dataclass
class Flight:
    """One vehicle's job in a :func:`fly` batch: its config, the reference it flies
    (``sample(t)`` / ``sample_all(times)``, as :class:`~ag_uav.world.reference.Reference`) for
    ``duration`` seconds (cut at ``sim.max_time_s``), and what to do with it."""

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


@dataclass
class LoopOutput:
    t: np.ndarray
    rec: np.ndarray              # (n, 21) see REC_COLUMNS
    crash_reason: str | None
    crash_time: float | None
    wall_loop_s: float
    vehicle: Vehicle
    frames: int = 0
    notes: list[str] = field(default_factory=list)
    imu: np.ndarray | None = None         # (n, 9) measured f (3), gyro (3), attitude error (3)
    imu_bias0: np.ndarray | None = None   # turn-on biases (accel m/s², gyro rad/s)
    sprayer: Any = None


# ------------------------------------------------------------------------------------ kernels
@njit(cache=True)
def _tick_in(k, S, act, n_ticks, iq, iv, p, v, quat, R, omega, box, cos_tilt, code, airborne,
             hover_z, low, ref_tab, ref_ids, rp, rv, ra, yaw, spray):  # pragma: no cover
    """Start of tick ``k`` for every active vehicle: retire finished ones; state rows → p, v,
    quaternion, R (row-major body → world), body rates; crash codes; the lift-off latch; the
    near-ground flag (contacts are checked there); the reference row.

    Returns flags: 1 some crash code set, 2 some vehicle near the ground, 4 some vehicle active.
    """
    flags = 0
    for i in range(S.shape[0]):
        if act[i] and n_ticks[i] <= k:
            act[i] = False
        low[i] = False
        if not act[i]:
            continue
        flags |= 4
        px, py, pz = S[i, iq], S[i, iq + 1], S[i, iq + 2]
        w, x, y, z = S[i, iq + 3], S[i, iq + 4], S[i, iq + 5], S[i, iq + 6]
        p[i, 0], p[i, 1], p[i, 2] = px, py, pz
        quat[i, 0], quat[i, 1], quat[i, 2], quat[i, 3] = w, x, y, z
        for j in range(3):
            v[i, j] = S[i, iv + j]
            omega[i, j] = S[i, iv + 3 + j]
        xx, yy, zz = x * x, y * y, z * z
        xy, xz, yz = x * y, x * z, y * z
        wx, wy, wz = w * x, w * y, w * z
        R[i, 0] = 1.0 - 2.0 * (yy + zz)
        R[i, 1] = 2.0 * (xy - wz)
        R[i, 2] = 2.0 * (xz + wy)
        R[i, 3] = 2.0 * (xy + wz)
        R[i, 4] = 1.0 - 2.0 * (xx + zz)
        R[i, 5] = 2.0 * (yz - wx)
        R[i, 6] = 2.0 * (xz - wy)
        R[i, 7] = 2.0 * (yz + wx)
        R[i, 8] = 1.0 - 2.0 * (xx + yy)
        if not (np.isfinite(px) and np.isfinite(py) and np.isfinite(pz)):
            code[i] = _NONFINITE
        elif R[i, 8] < cos_tilt:
            code[i] = _TILT
        elif (px < box[i, 0] or py < box[i, 1] or px > box[i, 2] or py > box[i, 3]
              or pz > box[i, 4]):
            code[i] = _BOX
        if code[i] != 0:
            flags |= 1
            continue
        if not airborne[i] and pz > hover_z[i] + 0.3:
            airborne[i] = True
        if airborne[i] and pz < hover_z[i] + 1.5:
            low[i] = True
            flags |= 2
        row = ref_tab[ref_ids[i], k]
        for j in range(3):
            rp[i, j] = row[j]
            rv[i, j] = row[3 + j]
            ra[i, j] = row[6 + j]
        yaw[i] = row[9]
        spray[i] = row[11] > 0.5
    return flags


@njit(cache=True)
def _hold_on_ground(act, airborne, pf, vf, rp, rv, p_out, v_out):  # pragma: no cover
    """The fed-back state; on the skids before lift-off the horizontal part is the reference's
    (no horizontal position control until the vehicle is airborne, as autopilots do)."""
    for i in range(act.shape[0]):
        if not act[i]:
            continue
        for j in range(3):
            p_out[i, j] = pf[i, j]
            v_out[i, j] = vf[i, j]
        if not airborne[i]:
            for j in range(2):
                p_out[i, j] = rp[i, j]
                v_out[i, j] = rv[i, j]


@njit(cache=True)
def _tick_out(rec, k, act, p, v, rp, pfb, ref_tab, ref_ids, spray, f, w,
              flown):  # pragma: no cover
    """Row ``k`` of every active vehicle's record (see :data:`REC_COLUMNS`)."""
    for i in range(p.shape[0]):
        if not act[i]:
            continue
        r = rec[i, k]
        for j in range(3):
            r[j] = p[i, j]
            r[3 + j] = v[i, j]
            r[6 + j] = rp[i, j]
            r[9 + j] = pfb[i, j]
            r[18 + j] = w[i, j]
        r[12] = ref_tab[ref_ids[i], k, 10]
        r[13] = 1.0 if spray[i] else 0.0
        for j in range(4):
            r[14 + j] = f[i, j]
        flown[i] = k + 1


@njit(cache=True)
def _imu_record(imu_rec, k, act, f_m, om, err):  # pragma: no cover
    for i in range(act.shape[0]):
        if act[i]:
            for j in range(3):
                imu_rec[i, k, j] = f_m[i, j]
                imu_rec[i, k, 3 + j] = om[i, j]
                imu_rec[i, k, 6 + j] = err[i, j]


@njit(cache=True)
def _controls(U, f, xf, col, act):  # pragma: no cover
    """Zero-order hold of the rotor commands and the drag force over the control period."""
    for i in range(U.shape[0]):
        if not act[i]:
            continue
        for s in range(U.shape[1]):
            for j in range(4):
                U[i, s, j] = f[i, j]
            for j in range(3):
                U[i, s, col + j] = xf[i, j]


# ------------------------------------------------------------------------------- per-vehicle
def _crash_text(code: int, t: float) -> str:
    if code == _NONFINITE:
        return "diverged: non-finite state"
    if code == _TILT:
        return f"tilt > 80 deg at t={t:.2f}s"
    return f"left the bounding box at t={t:.2f}s"


def _vehicles(flights: Sequence[Flight]) -> list[Vehicle]:
    """One Vehicle (own MjModel) per flight; identical builds are compiled once and copied."""
    out: list[Vehicle] = []
    cache: dict[Any, Vehicle] = {}
    for fl in flights:
        key = (repr(fl.cfg.vehicle), repr(fl.cfg.sim), repr(fl.cfg.spray.enabled),
               None if fl.outline is None else tuple(a.tobytes() for a in fl.outline))
        base = cache.get(key)
        if base is None:
            base = cache[key] = build_vehicle(fl.cfg, fl.outline)
            out.append(base)
            continue
        veh = Vehicle.__new__(Vehicle)
        veh.__dict__.update(base.__dict__)
        veh.model = copy_model(base.model)
        out.append(veh)
    return out


def copy_model(model: mujoco.MjModel) -> mujoco.MjModel:
    import copy

    return copy.copy(model)


# -------------------------------------------------------------------------------------- engine
def fly(flights: Sequence[Flight], *, progress: bool = False,
        nthread: int | None = None) -> list[LoopOutput]:
    """Fly every flight of ``flights`` in lockstep; one :class:`LoopOutput` per flight.

    All flights must share ``sim.control_hz`` and ``sim.timestep_s``. ``nthread``: MuJoCo's
    rollout threads (default: ``$AG_UAV_ENGINE_THREADS`` or the machine's cores, at most the
    batch size; a single vehicle is stepped in this thread)."""
    from controllers.batched import BatchCascade

    from ..navigation.feedback import TrueFeedback
    from ..seeds import rng_streams, seed_sequences
    from ..vehicle.cascade import make_cascade
    from ..vehicle.sensors_batched import BatchAttitudeError, BatchImu, BatchWind

    flights = list(flights)
    if not flights:
        return []
    cfg0 = flights[0].cfg
    for fl in flights:
        if (fl.cfg.sim.control_hz, fl.cfg.sim.timestep_s) != (cfg0.sim.control_hz,
                                                              cfg0.sim.timestep_s):
            raise ValueError("engine.fly: all flights of a batch must share sim.control_hz and "
                             "sim.timestep_s")
    N = len(flights)
    vehs = _vehicles(flights)
    models = [v.model for v in vehs]
    m0 = models[0]
    dt = 1.0 / cfg0.sim.control_hz
    nsub = round(dt / m0.opt.timestep)
    ns = mujoco.mj_stateSize(m0, STATE_SPEC)
    nu_in = mujoco.mj_stateSize(m0, CTRL_SPEC)
    iq = mujoco.mj_stateSize(m0, mujoco.mjtState.mjSTATE_TIME)
    iv = iq + m0.nq
    ia = iv + m0.nv
    body = vehs[0].body_id
    xcol = m0.nu + 6 * body
    ias = int(m0.sensor("accel").adr[0])
    igs = int(m0.sensor("gyro").adr[0])

    # ---- per-vehicle setup (Python, once)
    notes: list[list[str]] = [[] for _ in range(N)]
    S = np.empty((N, ns))
    sens = np.zeros((N, m0.nsensordata))
    n_ticks = np.empty(N, dtype=np.int64)
    airborne = np.empty(N, dtype=bool)
    hover_z = np.array([v.hover_z for v in vehs])
    box = np.empty((N, 5))
    c_lin = np.array([fl.cfg.vehicle.drag_linear for fl in flights], dtype=float)
    c_quad = np.array([fl.cfg.vehicle.drag_quadratic for fl in flights], dtype=float)
    fbs, cascades, winds = [], [], []
    imus, atts = [], []
    tables: list[np.ndarray] = []
    job_tabs: list[dict[str, np.ndarray]] = []
    ref_ids = np.empty(N, dtype=np.int64)
    ref_index: dict[int, int] = {}
    sprayers: list[Any] = [None] * N
    from ..world.wind import Wind

    for i, (fl, veh) in enumerate(zip(flights, vehs, strict=True)):
        cfg = fl.cfg
        model = veh.model
        data = mujoco.MjData(model)
        start = fl.reference.sample(0.0)
        data.qpos[0] = start.pos[0]
        data.qpos[1] = start.pos[1]
        data.qpos[2] = veh.hover_z if cfg.sim.takeoff else start.pos[2]
        data.qpos[3] = math.cos(start.yaw / 2)
        data.qpos[6] = math.sin(start.yaw / 2)
        if not cfg.sim.takeoff:
            data.ctrl[:] = veh.mass * 9.81 / 4
            data.act[:] = veh.mass * 9.81 / 4
        mujoco.mj_forward(model, data)
        mujoco.mj_getState(model, data, S[i], STATE_SPEC)
        sens[i] = data.sensordata
        airborne[i] = not cfg.sim.takeoff
        n_ticks[i] = int(math.ceil(min(fl.duration, cfg.sim.max_time_s) / dt - 1e-9))
        b = fl.bounds or (start.pos[0] - 100, start.pos[1] - 100, start.pos[0] + 100,
                          start.pos[1] + 100)
        box[i] = (b[0] - 100.0, b[1] - 100.0, b[2] + 100.0, b[3] + 100.0, 120.0)
        streams = fl.streams or rng_streams(cfg.seed)
        fb = fl.feedback or TrueFeedback()
        fbs.append(fb)
        casc = make_cascade(cfg, veh)
        cascades.append(casc)
        w = cfg.wind
        winds.append(Wind(w.speed_mps, w.direction_deg, w.turbulence, rng=streams["wind"]))
        if fb.wants_imu:
            from ..vehicle.imu import AttitudeError, ImuSensor

            ss = seed_sequences(cfg.seed)
            imus.append(ImuSensor(cfg.imu, cfg.sim.control_hz, ss["imu"]))
            atts.append(AttitudeError(cfg.imu, cfg.sim.control_hz, ss["attitude"]))
        rid = ref_index.get(id(fl.reference))
        if rid is None or len(tables[rid]) < n_ticks[i]:
            tab = fl.reference.sample_all(np.arange(n_ticks[i]) * dt)
            packed = np.column_stack([tab["pos"], tab["vel"], tab["acc"], tab["yaw"],
                                      tab["seg"], tab["spray"]]).astype(float)
            # the spray job's per-tick tables (the same for every vehicle on this reference)
            job_tab = {k: tab[k] for k in ("ground", "sortie") if k in tab}
            if rid is None:
                rid = ref_index[id(fl.reference)] = len(tables)
                tables.append(packed)
                job_tabs.append(job_tab)
            else:
                tables[rid] = packed
                job_tabs[rid] = job_tab
        ref_ids[i] = rid
        if getattr(fl.reference, "spray_job", None) is not None:
            sprayers[i] = (cfg, veh, job_tabs[rid], fl.reference.spray_job, int(n_ticks[i]),
                           fl.log)
    wants_imu = [fb.wants_imu for fb in fbs]
    if any(wants_imu) and not all(wants_imu):
        raise ValueError("engine.fly: a batch mixes flights with and without the MEMS IMU")
    use_imu = wants_imu[0]

    n_max = int(n_ticks.max())
    ref_tab = np.empty((len(tables), n_max, 12))
    for j, t_ in enumerate(tables):
        ref_tab[j, :len(t_)] = t_
        ref_tab[j, len(t_):] = t_[-1] if len(t_) else 0.0

    bc = BatchCascade.from_cascades(cascades)
    wind = BatchWind.from_winds(winds)
    imu = BatchImu.from_sensors(imus) if use_imu else None
    att = BatchAttitudeError.from_errors(atts) if use_imu else None
    imu_rec = np.zeros((N, n_max, 9)) if use_imu else None
    spr = None
    if any(s is not None for s in sprayers):
        from .spray_batched import BatchSprayer, MassSink
        from .sprayer import Sprayer

        objs = []
        set_mass = _mass_setter(bc)
        for i, s in enumerate(sprayers):
            if s is None:
                raise ValueError("engine.fly: a batch mixes spray jobs and plain flights")
            cfg, veh, tab, job, n_i, log = s
            objs.append(Sprayer(cfg, veh, None, MassSink(i, set_mass), tab, job, n_i, dt, log))
        sprayers = objs
        spr = BatchSprayer.from_sprayers(objs, set_mass, push_initial=False)

    # feedback: all true, one batched object (the estimator bank's, Feedback.batch), or
    # per-vehicle
    all_true = all(isinstance(fb, TrueFeedback) for fb in fbs)
    bank = None if all_true else type(fbs[0]).batch(fbs, n_max)
    for fl, fb in zip(flights, fbs, strict=True):
        if fl.log is not None and hasattr(fb, "log"):
            fb.log = fl.log

    # ---- renderers, hooks: per vehicle
    renderers: list[Any] = [None] * N
    scratch: list[mujoco.MjData | None] = [None] * N
    for i, fl in enumerate(flights):
        if fl.log is not None and fl.render:
            from ..record.render import Renderer, RenderUnavailable

            try:
                renderers[i] = Renderer(models[i], fl.cfg.log.width, fl.cfg.log.height,
                                        tuple(fl.cfg.log.cameras))
            except RenderUnavailable as e:
                notes[i].append(f"no camera frames: {e}")
        if renderers[i] is not None or fl.tick_hook is not None:
            scratch[i] = mujoco.MjData(models[i])
    contact_data = [mujoco.MjData(m) for m in models]
    logs = [fl.log for fl in flights]
    any_log = any(lg is not None for lg in logs)
    hooks = [fl.tick_hook for fl in flights]
    any_hook = any(h is not None for h in hooks)
    frames = np.zeros(N, dtype=np.int64)

    # ---- arrays
    rec = np.zeros((N, n_max, len(REC_COLUMNS)))
    p = np.zeros((N, 3))
    v = np.zeros((N, 3))
    quat = np.zeros((N, 4))
    R = np.zeros((N, 9))
    omega = np.zeros((N, 3))
    code = np.zeros(N, dtype=np.int8)
    low = np.zeros(N, dtype=bool)
    rp = np.zeros((N, 3))
    rv = np.zeros((N, 3))
    ra = np.zeros((N, 3))
    yaw = np.zeros(N)
    spray = np.zeros(N, dtype=bool)
    p_fb = np.zeros((N, 3))
    v_fb = np.zeros((N, 3))
    act = np.ones(N, dtype=bool)
    flown = np.zeros(N, dtype=np.int64)
    crash_reason: list[str | None] = [None] * N
    crash_time: list[float | None] = [None] * N
    U = np.zeros((N, nsub, nu_in))
    S_out = np.empty((N, nsub, ns))
    sens_out = np.empty((N, nsub, m0.nsensordata))
    warm = np.zeros((N, m0.nv))
    cos_tilt = math.cos(math.radians(80.0))
    skids = [set(v_.skid_geoms) for v_ in vehs]
    ground = [v_.ground_geom for v_ in vehs]
    if nthread is None:  # worker processes of a pool run one thread each (executor.THREAD_ENV)
        nthread = int(os.environ.get("AG_UAV_ENGINE_THREADS", 0)) or (os.cpu_count() or 1)
        nthread = min(nthread, N) if N > 1 else 0
    if nthread == 1:  # one thread: step in this one (a pool thread's hand-off costs ~20 %)
        nthread = 0
    runner = _rollout.Rollout(nthread=nthread)
    # four contiguous chunks of vehicles per thread: at N = 64 on 2 threads this measured
    # ~1000 vehicle-sim-s/s against 950-985 with one chunk per thread (uneven vehicles: some on
    # the ground, with contacts) and 630 k vs 715 k vehicle-steps/s with the default chunking
    n_chunks = 4 * max(nthread, 1)
    thread_data = [mujoco.MjData(m0) for _ in range(max(nthread, 1))]

    bar = None
    if progress:
        from tqdm import tqdm

        bar = tqdm(total=round(n_max * dt), unit="sim-s", desc="flying", leave=False,
                   dynamic_ncols=True, mininterval=0.5)
    bar_next = 1.0
    idx = np.arange(N)
    # one vehicle: step its MjData directly (bit-identical to the rollout: same state, controls
    # and zero warm start per control period; tested), which saves the rollout's overhead
    direct = xfrc0 = None
    mj_step, mj_getState = mujoco.mj_step, mujoco.mj_getState
    if N == 1:
        direct = mujoco.MjData(m0)
        mujoco.mj_setState(m0, direct, S[0], STATE_SPEC)
        xfrc0 = direct.xfrc_applied[body, :3]
    wall = time.perf_counter()
    try:
        for k in range(n_max):
            t = k * dt
            flags = _tick_in(k, S, act, n_ticks, iq, iv, p, v, quat, R, omega, box, cos_tilt,
                             code, airborne, hover_z, low, ref_tab, ref_ids, rp, rv, ra, yaw,
                             spray)
            if flags & 1:  # ---- crashes
                for i in np.flatnonzero(code):
                    crash_reason[i], crash_time[i] = _crash_text(int(code[i]), t), t
                    act[i] = False
                code[:] = 0
            if flags & 2:  # ---- near the ground: real contacts
                for i in np.flatnonzero(low):
                    why = _ground_contact(models[i], contact_data[i], S[i], ground[i],
                                          skids[i], v[i], t)
                    if why:
                        crash_reason[i], crash_time[i] = why, t
                        act[i] = False
            if not flags & 4 or ((flags & 3) and not act.any()):
                break
            # ---- sensing, feedback
            Rc, om = R, omega
            imu_in = None
            if imu is not None:
                f_m, om = imu.measure(sens[:, ias:ias + 3], sens[:, igs:igs + 3], act)
                Rc = att.apply(R, act)
                _imu_record(imu_rec, k, act, f_m, om, att.last)
                imu_in = (f_m, Rc)
            if all_true:
                pf, vf = p, v
            elif bank is not None:
                pf, vf = bank.update(k, t, p, v, imu_in, act)
            else:
                pf, vf = _per_vehicle_feedback(fbs, t, p, v, imu_in, act)
            # on the skids: no horizontal position control until lift-off (as autopilots do);
            # an estimate a metre off must not tip the vehicle over on the ground
            _hold_on_ground(act, airborne, pf, vf, rp, rv, p_fb, v_fb)
            f = bc.update(p_fb, v_fb, Rc, om, rp, rv, ra, yaw, dt, active=act)
            if spr is not None:
                on, reset = spr.step(k, t, p[:, 2], v[:, 0], v[:, 1], spray, f,
                                     S[:, ia:ia + 4], act)
                spray[:] = on
                if reset.any():
                    bc.reset_rows(np.flatnonzero(reset))
            # ---- wind as a drag force (zero-order hold over the control period)
            w, xf = wind.step_drag(dt, p[:, 2], v, c_lin, c_quad, act)
            _tick_out(rec, k, act, p, v, rp, p_fb, ref_tab, ref_ids, spray, f, w, flown)
            if any_log:
                for i in np.flatnonzero(act):
                    lg = logs[i]
                    if lg is not None and (t >= lg._next_tick or (renderers[i] is not None
                                                                  and lg.want_frame(t))):
                        frames[i] += _log_tick(logs[i], renderers[i], scratch[i], models[i],
                                               S[i], t, p[i], quat[i], v[i], rp[i], rv[i],
                                               yaw[i], p_fb[i], v_fb[i], fbs[i], bc, i, f[i],
                                               w[i], spray[i],
                                               imu_rec[i, k] if imu_rec is not None else None)
            # ---- physics: one control period for every active vehicle
            if direct is not None:
                d0 = direct
                d0.ctrl[:] = f[0]
                xfrc0[:] = xf[0]
                d0.qacc_warmstart[:] = 0.0
                mj_step(m0, d0, nsub)
                mj_getState(m0, d0, S[0], STATE_SPEC)
                if imu is not None:
                    sens[0] = d0.sensordata
            elif act.all():
                _controls(U, f, xf, xcol, act)
                runner.rollout(models, thread_data, S, U,
                               control_spec=CTRL_SPEC, nstep=nsub, initial_warmstart=warm,
                               state=S_out, sensordata=sens_out, skip_checks=True,
                               chunk_size=-(-N // n_chunks))
                S[:] = S_out[:, -1]
                sens[:] = sens_out[:, -1]
            else:
                _controls(U, f, xf, xcol, act)
                ii = idx[act]
                so = S_out[:len(ii)]
                se = sens_out[:len(ii)]
                runner.rollout([models[i] for i in ii], thread_data, S[ii],
                               U[ii], control_spec=CTRL_SPEC, nstep=nsub,
                               initial_warmstart=warm[:len(ii)], state=so, sensordata=se,
                               skip_checks=True, chunk_size=-(-len(ii) // n_chunks))
                S[ii] = so[:, -1]
                sens[ii] = se[:, -1]
            if any_hook:
                if direct is not None:
                    hooks[0](t, direct)  # the live MjData after the step
                else:
                    for i in np.flatnonzero(act):
                        if hooks[i] is not None:
                            mujoco.mj_setState(models[i], scratch[i], S[i], STATE_SPEC)
                            mujoco.mj_setState(models[i], scratch[i], U[i, 0], CTRL_SPEC)
                            hooks[i](t, scratch[i])
            if bar is not None and t >= bar_next:
                bar.update(1)
                bar_next += 1.0
    finally:
        runner.close()
        if bar is not None:
            bar.close()
        for r in renderers:
            if r is not None:
                r.close()
    wall = time.perf_counter() - wall
    if spr is not None:
        spr.finish()
    if bank is not None:
        bank.finish(flown)
    outs = []
    for i in range(N):
        n = int(flown[i])
        out = LoopOutput(t=np.arange(n) * dt, rec=rec[i, :n],
                         crash_reason=crash_reason[i], crash_time=crash_time[i],
                         wall_loop_s=wall, vehicle=vehs[i], frames=int(frames[i]),
                         notes=notes[i], sprayer=sprayers[i] if spr is not None else None)
        if imu is not None:
            out.imu = imu_rec[i, :n]
            out.imu_bias0 = imu.bias0[i].copy()
        outs.append(out)
    return outs


def _mass_setter(bc: Any) -> Callable[[int, float, Sequence[float]], None]:
    def set_mass(i: int, total: float, J: Sequence[float]) -> None:
        bc.mass[i] = total
        bc.J[i] = J

    return set_mass


def _ground_contact(model, data, s, ground: int, skids: set[int], vel, t: float) -> str | None:
    """Ground contact other than the skids, or any at more than 1 m/s (a crash), else None."""
    mujoco.mj_setState(model, data, s, STATE_SPEC)
    mujoco.mj_kinematics(model, data)
    mujoco.mj_collision(model, data)
    if not data.ncon:
        return None
    speed = math.sqrt(float(vel[0]) ** 2 + float(vel[1]) ** 2 + float(vel[2]) ** 2)
    for c in data.contact[:data.ncon]:
        g1, g2 = int(c.geom1), int(c.geom2)
        if ground not in (g1, g2):
            continue
        other = g2 if g1 == ground else g1
        if other not in skids or speed > 1.0:
            return (f"ground contact at {speed:.1f} m/s ({model.geom(other).name}) "
                    f"at t={t:.2f}s")
    return None


def _per_vehicle_feedback(fbs, t, p, v, imu_in, act):
    """The per-vehicle adapter: any :class:`~ag_uav.navigation.feedback.Feedback`, one vehicle at a
    time."""
    p_fb = p.copy()
    v_fb = v.copy()
    for i in np.flatnonzero(act):
        pt = (float(p[i, 0]), float(p[i, 1]), float(p[i, 2]))
        vt = (float(v[i, 0]), float(v[i, 1]), float(v[i, 2]))
        if imu_in is not None:
            f_m, Rc = imu_in
            pf, vf = fbs[i].update(t, pt, vt, (f_m[i].tolist(), tuple(Rc[i].tolist())))
        else:
            pf, vf = fbs[i].update(t, pt, vt)
        p_fb[i] = pf
        v_fb[i] = vf
    return p_fb, v_fb


IMU_KEYS = ("imu.fx", "imu.fy", "imu.fz", "imu.wx", "imu.wy", "imu.wz", "imu.att_err_x",
            "imu.att_err_y", "imu.att_err_z")


def _log_tick(log, renderer, scratch, model, s, t, p, q, v, rp, rv, yaw_ref, pf, vf, fb, bc,
              i, f, w, spray, imu_row) -> int:
    """One vehicle's log record of this tick (and its camera frames); returns frames written."""
    frames = 0
    if t >= log._next_tick:
        ctrl = None
        if log.want("state", t):
            ctrl = bc.internals(i)
            if imu_row is not None:
                ctrl.update(zip(IMU_KEYS, imu_row.tolist(), strict=True))
        log.tick(t, p_true=tuple(p.tolist()), q_true_wxyz=tuple(q.tolist()),
                 v_true=tuple(v.tolist()), p_ref=tuple(rp.tolist()), v_ref=tuple(rv.tolist()),
                 yaw_ref=float(yaw_ref),
                 p_est=tuple(pf.tolist()) if fb.name != "true" else None,
                 v_est=tuple(vf.tolist()), ctrl=ctrl, motors=f.tolist(),
                 wind=tuple(w.tolist()), spray=bool(spray))
    if renderer is not None and log.want_frame(t):
        mujoco.mj_setState(model, scratch, s, STATE_SPEC)
        mujoco.mj_forward(model, scratch)
        for cam in renderer.cameras:
            log.frame(t, cam, renderer.jpeg(scratch, cam), renderer.width, renderer.height,
                      renderer.fovy(cam), pose=renderer.camera_pose(scratch, cam))
            frames += 1
    return frames
