"""The simulation loop: physics ↔ control ↔ sensors → estimator, then metrics.

Data flow (one way): config → plan (:mod:`ag_uav.plan`) → reference (:mod:`ag_uav.reference`) →
simulate (this module: MuJoCo physics at ``sim.timestep_s``, control at ``sim.control_hz``) →
metrics (:mod:`ag_uav.metrics`) and log (:mod:`ag_uav.runlog`).

The **feedback seam** is :class:`Feedback`: each control tick it gets the true state and returns
the position and velocity the controller flies on. :class:`TrueFeedback` passes the truth through;
the estimator bank plugs in with the same interface (GPS fixes → filter → estimate).

Every random draw comes from a Generator spawned from the run seed (:func:`rng_streams`), one
stream per consumer, so the same config and seed give the same run, serial or parallel.
"""

from __future__ import annotations

import dataclasses
import math
import time
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import mujoco
import numpy as np

from controllers.attitude import GeometricAttitudeController, XMixer, quat_to_rot
from controllers.cascade import PositionCascade
from controllers.factory import make_controller

from .config import AxisGains, Config
from .field import Field, load_field
from .plan import plan_coverage
from .reference import Reference
from .vehicle import G, Vehicle, build_vehicle
from .wind import Wind

#: Names of the seeded random streams; appending a name never changes the others' draws.
STREAMS = ("wind", "gps", "estimator", "altimeter", "imu", "attitude", "spare4", "spare5")


def seed_sequences(seed: int) -> dict[str, np.random.SeedSequence]:
    """One independent SeedSequence per consumer, spawned from ``SeedSequence(seed)``."""
    children = np.random.SeedSequence(seed).spawn(len(STREAMS))
    return dict(zip(STREAMS, children, strict=True))


def rng_streams(seed: int) -> dict[str, np.random.Generator]:
    """One independent Generator per consumer (see :func:`seed_sequences`)."""
    return {name: np.random.default_rng(s) for name, s in seed_sequences(seed).items()}


# ------------------------------------------------------------------------------ feedback seam
class Feedback:
    """What the controller flies on. ``update`` is called once per control tick.

    A feedback with ``wants_imu`` gets the MEMS IMU's reading each tick as
    ``imu = (f̃, R̂)``: the measured specific force (body frame, m/s²) and the attitude estimate
    (row-major 3×3), see :mod:`ag_uav.imu`; the controller then flies on ``R̂`` and the gyro.
    """

    name = "base"
    wants_imu = False

    def update(self, t: float, p_true: tuple[float, float, float],
               v_true: tuple[float, float, float], imu: tuple | None = None,
               ) -> tuple[tuple[float, ...], tuple[float, ...]]:
        raise NotImplementedError

    def summary(self) -> dict[str, Any]:
        return {}


class TrueFeedback(Feedback):
    """Perfect state feedback (the baseline and the tuning default)."""

    name = "true"

    def update(self, t, p_true, v_true, imu=None):
        return p_true, v_true


# ------------------------------------------------------------------------------------ building
def make_axis_controller(kind: str, g: AxisGains) -> Any:
    """The per-axis position controller named by ``controller.type`` with its gains."""
    if kind == "pid":
        return make_controller("pid", Kp=g.kp, Ki=g.ki, Kd=g.kdd, i_limit=g.i_limit)
    if kind == "t1-fpid":
        return make_controller("t1-fpid", Ke=g.ke, Kd=g.kd, K0=g.k0, K1=g.k1, cm=g.cm,
                               i_limit=g.i_limit)
    return make_controller("it2-fpid", Ke=g.ke, Kd=g.kd, K0=g.k0, K1=g.k1, alpha=g.alpha,
                           zeta=g.zeta, cm=g.cm, reducer=g.reducer, i_limit=g.i_limit)


def make_cascade(cfg: Config, veh: Vehicle) -> PositionCascade:
    c = cfg.controller
    axes = [make_axis_controller(c.type, c.xy), make_axis_controller(c.type, c.xy),
            make_axis_controller(c.type, c.z)]
    att = GeometricAttitudeController(veh.inertia, wn=c.attitude.wn, zeta=c.attitude.zeta)
    mixer = XMixer(veh.rotor_xy, veh.spin, veh.k_yaw, veh.f_max)
    return PositionCascade(axes, veh.mass, G, att, mixer, tilt_max=math.radians(c.tilt_max_deg),
                           accel_feedforward=c.accel_feedforward)


def build_field(cfg: Config) -> Field:
    try:
        return load_field(cfg.mission.field)
    except ValueError as e:
        from .config import ConfigError

        raise ConfigError(f'mission.field = "{cfg.mission.field}": {e}') from None


def build_plan(cfg: Config, fld: Field):
    from .config import ConfigError

    m = cfg.mission
    direction = None if m.direction_deg == "auto" else float(m.direction_deg)
    try:
        return plan_coverage(fld, swath=m.swath_m, headland=m.headland_m,
                             direction_deg=direction)
    except ValueError as e:
        raise ConfigError(f"mission.swath_m = {m.swath_m}: {e}") from None


def build_reference(cfg: Config, plan, *, spray: bool = True) -> Any:
    """The time-parameterised reference ``simulate`` flies along ``plan``. With
    ``spray.enabled`` (and ``spray``) it carries the spray job (``.spray_job``: tank, battery,
    sorties; :func:`ag_uav.spray.plan_job`), split into sorties where one tank or battery does
    not do the job."""
    m = cfg.mission
    ref = Reference(plan, speed=m.speed_mps, altitude=m.altitude_m, a_max=m.accel_max_mps2,
                    takeoff=cfg.sim.takeoff, hover_time=cfg.sim.hover_after_s,
                    rate=cfg.sim.control_hz)
    if spray and cfg.spray.enabled:
        from .spray import plan_job

        ref, _job = plan_job(cfg, plan, ref, plan.field, dry_mass_kg=cfg.vehicle.mass_kg
                             + cfg.vehicle.payload_kg, z_land=build_vehicle(cfg).hover_z - 0.08)
    return ref


def field_outline(fld: Field) -> list[np.ndarray]:
    """Closed rings of the field: every part's boundary and its holes (local metres)."""
    return [np.asarray(r) for outer, holes in fld.rings() for r in (outer, *holes)]


# -------------------------------------------------------------------------------------- result
@dataclass
class RunResult:
    summary: dict[str, Any]
    t: np.ndarray                # (n,) control-tick times (s)
    p_true: np.ndarray           # (n, 3)
    v_true: np.ndarray           # (n, 3)
    p_ref: np.ndarray            # (n, 3)
    p_fb: np.ndarray             # (n, 3) position the controller flew on
    seg: np.ndarray              # (n,) active plan segment
    spray: np.ndarray            # (n,) sprayer on
    motors: np.ndarray           # (n, 4) rotor thrust commands (N)
    field: Field | None = None
    plan: Any = None
    extra: dict[str, Any] = dataclasses.field(default_factory=dict)


# -------------------------------------------------------------------------------------- the loop
@dataclass
class LoopOutput:
    t: np.ndarray
    rec: np.ndarray              # (n, 21) see REC_COLUMNS
    crash_reason: str | None
    crash_time: float | None
    wall_loop_s: float
    vehicle: Vehicle
    frames: int = 0
    notes: list[str] = dataclasses.field(default_factory=list)
    imu: np.ndarray | None = None         # (n, 9) measured f (3), gyro (3), attitude error (3)
    imu_bias0: np.ndarray | None = None   # turn-on biases (accel m/s², gyro rad/s)
    sprayer: Any = None


REC_COLUMNS = ("px", "py", "pz", "vx", "vy", "vz", "rx", "ry", "rz", "fx", "fy", "fz", "seg",
               "spray", "f0", "f1", "f2", "f3", "wx", "wy", "wz")


def fly_reference(cfg: Config, reference: Any, duration: float, *,
                  outline: list[np.ndarray] | None = None,
                  bounds: tuple[float, float, float, float] | None = None,
                  feedback: Feedback | None = None, progress: bool = False,
                  tick_hook: Callable[..., None] | None = None, log: Any = None,
                  render: bool = False, streams: dict | None = None) -> LoopOutput:
    """Fly the vehicle along ``reference`` (``sample_all(times)`` → dict of pos, vel, acc, yaw,
    seg, spray arrays, as :meth:`ag_uav.reference.Reference.sample_all`) for
    ``duration`` seconds of sim time. The core loop shared by missions and test scenarios."""
    streams = streams or rng_streams(cfg.seed)
    notes: list[str] = []
    veh = build_vehicle(cfg, outline)
    model = veh.model
    data = mujoco.MjData(model)
    start = reference.sample(0.0)
    data.qpos[0] = start.pos[0]
    data.qpos[1] = start.pos[1]
    data.qpos[2] = veh.hover_z if cfg.sim.takeoff else start.pos[2]
    data.qpos[3] = math.cos(start.yaw / 2)
    data.qpos[6] = math.sin(start.yaw / 2)
    if not cfg.sim.takeoff:
        data.ctrl[:] = veh.mass * G / 4
        data.act[:] = veh.mass * G / 4
    mujoco.mj_forward(model, data)

    fb = feedback or TrueFeedback()
    cascade = make_cascade(cfg, veh)
    imu = att = None
    if fb.wants_imu:
        from .imu import AttitudeError, ImuSensor

        ss = seed_sequences(cfg.seed)
        imu = ImuSensor(cfg.imu, cfg.sim.control_hz, ss["imu"])
        att = AttitudeError(cfg.imu, cfg.sim.control_hz, ss["attitude"])
        ia, ig = int(model.sensor("accel").adr[0]), int(model.sensor("gyro").adr[0])
        sensordata = data.sensordata
    imu_rec: list[tuple] = []
    w = cfg.wind
    wind = Wind(w.speed_mps, w.direction_deg, w.turbulence, rng=streams["wind"])
    wmx, wmy, _ = wind.mean  # airspeed for the Dryden time scales: relative to the mean wind
    c_lin = tuple(cfg.vehicle.drag_linear)
    c_quad = tuple(cfg.vehicle.drag_quadratic)

    dt = 1.0 / cfg.sim.control_hz
    nsub = round(dt / model.opt.timestep)
    n_ticks = int(math.ceil(min(duration, cfg.sim.max_time_s) / dt - 1e-9))
    body = veh.body_id
    xfrc = data.xfrc_applied[body]
    qpos, qvel, ctrl = data.qpos, data.qvel, data.ctrl
    ground, skids = veh.ground_geom, set(veh.skid_geoms)
    cos_tilt_crash = math.cos(math.radians(80.0))
    if bounds is None:
        bounds = (start.pos[0] - 100, start.pos[1] - 100, start.pos[0] + 100,
                  start.pos[1] + 100)
    box = (bounds[0] - 100.0, bounds[1] - 100.0, bounds[2] + 100.0, bounds[3] + 100.0, 120.0)

    rec: list[tuple] = []
    crash_reason: str | None = None
    crash_time: float | None = None
    airborne = not cfg.sim.takeoff
    frames = 0
    renderer = None
    if log is not None and render:
        from .render import Renderer, RenderUnavailable

        try:
            renderer = Renderer(model, cfg.log.width, cfg.log.height, tuple(cfg.log.cameras))
        except RenderUnavailable as e:
            notes.append(f"no camera frames: {e}")
            renderer = None

    bar = None
    if progress:
        from tqdm import tqdm

        bar = tqdm(total=round(n_ticks * dt), unit="sim-s", desc="flying", leave=False,
                   dynamic_ncols=True, mininterval=0.5)
    bar_next = 1.0
    # the reference on the control grid, precomputed as Python lists (cheap to index per tick)
    tab = reference.sample_all(np.arange(n_ticks) * dt)
    ref_p, ref_v, ref_a = tab["pos"].tolist(), tab["vel"].tolist(), tab["acc"].tolist()
    ref_yaw, ref_seg = tab["yaw"].tolist(), tab["seg"].tolist()
    ref_spray = tab["spray"].tolist()
    sprayer = None  # spray job: tank, mass and energy per tick (ag_uav.spray)
    if getattr(reference, "spray_job", None) is not None:
        from .spray import Sprayer

        sprayer = Sprayer(cfg, veh, data, cascade, tab, reference.spray_job, n_ticks, dt, log)
    wall_loop = time.perf_counter()
    for k in range(n_ticks):
        t = k * dt
        px, py, pz, qw, qx, qy, qz = qpos.tolist()
        vx, vy, vz, wbx, wby, wbz = qvel.tolist()
        R = quat_to_rot(qw, qx, qy, qz)
        omega = (wbx, wby, wbz)
        # ---- safety / crash detection
        if not (math.isfinite(px) and math.isfinite(py) and math.isfinite(pz)):
            crash_reason, crash_time = "diverged: non-finite state", t
            break
        if R[8] < cos_tilt_crash:
            crash_reason, crash_time = f"tilt > 80 deg at t={t:.2f}s", t
            break
        if px < box[0] or py < box[1] or px > box[2] or py > box[3] or pz > box[4]:
            crash_reason, crash_time = f"left the bounding box at t={t:.2f}s", t
            break
        if pz > veh.hover_z + 0.3:
            airborne = True
        if airborne and data.ncon:
            for i in range(data.ncon):
                c = data.contact[i]
                g1, g2 = int(c.geom1), int(c.geom2)
                if ground not in (g1, g2):
                    continue
                other = g2 if g1 == ground else g1
                speed = math.sqrt(vx * vx + vy * vy + vz * vz)
                if other not in skids or speed > 1.0:
                    crash_reason = (f"ground contact at {speed:.1f} m/s "
                                    f"({model.geom(other).name}) at t={t:.2f}s")
                    crash_time = t
                    break
            if crash_reason:
                break
        # ---- reference, feedback, control
        rp, rv, yaw_ref, spray = ref_p[k], ref_v[k], ref_yaw[k], ref_spray[k]
        if imu is not None:
            sd = sensordata.tolist()
            f_m, omega = imu.measure(sd[ia:ia + 3], sd[ig:ig + 3])
            R = att.apply(R)
            imu_rec.append((*f_m, *omega, *att.last))
            p_fb, v_fb = fb.update(t, (px, py, pz), (vx, vy, vz), (f_m, R))
        else:
            p_fb, v_fb = fb.update(t, (px, py, pz), (vx, vy, vz))
        if not airborne:
            # on the skids: no horizontal position control until lift-off (as autopilots do);
            # an estimate that is off by a metre must not tip the vehicle over on the ground
            p_fb = (rp[0], rp[1], p_fb[2])
            v_fb = (rv[0], rv[1], v_fb[2])
        f = cascade.update(p_fb, v_fb, R, omega, rp, rv, ref_a[k], yaw_ref, dt)
        if sprayer is not None:
            f, spray = sprayer.step(k, t, pz, vx, vy, spray, f)
        ctrl[0], ctrl[1], ctrl[2], ctrl[3] = f
        # ---- wind as a drag force (zero-order hold over the control period)
        ax_, ay_ = vx - wmx, vy - wmy
        wx, wy, wz = wind.step(dt, pz if pz > 0.0 else 0.0, math.sqrt(ax_ * ax_ + ay_ * ay_))
        rx, ry, rz = vx - wx, vy - wy, vz - wz
        xfrc[0] = -c_lin[0] * rx - c_quad[0] * abs(rx) * rx
        xfrc[1] = -c_lin[1] * ry - c_quad[1] * abs(ry) * ry
        xfrc[2] = -c_lin[2] * rz - c_quad[2] * abs(rz) * rz
        rec.append((px, py, pz, vx, vy, vz, rp[0], rp[1], rp[2], p_fb[0], p_fb[1], p_fb[2],
                    ref_seg[k], spray, f[0], f[1], f[2], f[3], wx, wy, wz))
        if log is not None:
            if t >= log._next_tick:
                log.tick(t, p_true=(px, py, pz), q_true_wxyz=(qw, qx, qy, qz),
                         v_true=(vx, vy, vz), p_ref=rp, v_ref=rv, yaw_ref=yaw_ref,
                         p_est=p_fb if fb.name != "true" else None, v_est=v_fb,
                         ctrl=(_with_imu(cascade.internals(), imu_rec[-1] if imu_rec else None)
                               if log.want("state", t) else None),
                         motors=f, wind=(wx, wy, wz), spray=spray)
            if renderer is not None and log.want_frame(t):
                for cam in renderer.cameras:
                    log.frame(t, cam, renderer.jpeg(data, cam), renderer.width, renderer.height,
                              renderer.fovy(cam), pose=renderer.camera_pose(data, cam))
                    frames += 1
        mujoco.mj_step(model, data, nstep=nsub)
        if tick_hook is not None:
            tick_hook(t, data)
        if bar is not None and t >= bar_next:
            bar.update(1)
            bar_next += 1.0
    if bar is not None:
        bar.close()
    wall_loop = time.perf_counter() - wall_loop
    if renderer is not None:
        renderer.close()
    arr = np.asarray(rec, dtype=float).reshape(-1, len(REC_COLUMNS))
    out = LoopOutput(t=np.arange(len(arr)) * dt, rec=arr, crash_reason=crash_reason,
                     crash_time=crash_time, wall_loop_s=wall_loop, vehicle=veh, frames=frames,
                     notes=notes, sprayer=sprayer)
    if imu is not None:
        out.imu = np.asarray(imu_rec[:len(arr)], dtype=float).reshape(-1, 9)
        out.imu_bias0 = imu.bias0
    return out


IMU_KEYS = ("imu.fx", "imu.fy", "imu.fz", "imu.wx", "imu.wy", "imu.wz", "imu.att_err_x",
            "imu.att_err_y", "imu.att_err_z")


def _with_imu(ctrl: dict[str, float], rec: tuple | None) -> dict[str, float]:
    """The controller internals plus the IMU's reading (specific force m/s², gyro rad/s) and
    the attitude estimate's error (rad) for the ``/drone/state`` log."""
    if rec is not None:
        ctrl.update(zip(IMU_KEYS, rec, strict=True))
    return ctrl


def _cut_by_max_time(cfg: Config, ref: Reference, out: LoopOutput,
                     summ: dict[str, Any]) -> str | None:
    """The one-line reason when ``sim.max_time_s`` cut the mission short (else None)."""
    if out.crash_reason is not None or ref.duration <= cfg.sim.max_time_s:
        return None
    return (f"cut by sim.max_time_s = {cfg.sim.max_time_s:g} s after "
            f"{summ.get('legs_flown', 0)} of {summ.get('legs', 0)} legs; the plan needs "
            f"{ref.duration:.0f} s (raise sim.max_time_s)")


def simulate(cfg: Config, *, feedback: Feedback | None = None, progress: bool = False,
             tick_hook: Callable[..., None] | None = None, log: Any = None) -> RunResult:
    """Fly ``cfg``'s mission once and return the trajectory and the summary metrics.

    ``feedback``: the feedback seam (default: the config's estimator, or the true state).
    ``log``: an open :class:`~ag_uav.runlog.RunLog` or None; with ``cfg.log.render`` camera
    frames go into it. ``tick_hook(t, data)`` is called after every control tick.
    """
    from . import metrics

    wall0 = time.perf_counter()
    streams = rng_streams(cfg.seed)
    fld = build_field(cfg)
    plan = build_plan(cfg, fld)
    m = cfg.mission
    ref = build_reference(cfg, plan)
    bounds = fld.bounds
    job = getattr(ref, "spray_job", None)
    if job is not None:  # the base may lie outside the field
        bx, by = (float(v) for v in job.base_xy)
        bounds = (min(bounds[0], bx), min(bounds[1], by), max(bounds[2], bx), max(bounds[3], by))
    outline = field_outline(fld)
    if log is not None:
        log.scene(0.0, outline[0], outline[1:],
                  [(s.kind, np.asarray(s.points), s.spray) for s in plan.segments],
                  m.swath_m, m.altitude_m,
                  parts=[(np.asarray(o), [np.asarray(h) for h in hs]) for o, hs in fld.rings()])
    if feedback is None and cfg.estimator.source == "bearings":
        from .bearing import BearingFeedback

        e = cfg.estimator
        feedback = BearingFeedback.for_config(cfg, filter=e.bearing_filter,
                                              noise_scale=e.bearing_noise_scale)
    if feedback is None and (cfg.estimator.name != "true" or cfg.estimator.shadow):
        from .estimation import EstimatorFeedback

        ss = seed_sequences(cfg.seed)
        feedback = EstimatorFeedback(cfg, ss["gps"], ss["altimeter"], ss["imu"])
    fb = feedback or TrueFeedback()
    if log is not None and hasattr(fb, "log"):
        fb.log = log
    out = fly_reference(cfg, ref, ref.duration, outline=outline,
                        bounds=bounds, feedback=fb, progress=progress, tick_hook=tick_hook,
                        log=log, render=cfg.log.render, streams=streams)
    arr = out.rec
    res = RunResult(
        summary={}, t=out.t, p_true=arr[:, 0:3], v_true=arr[:, 3:6], p_ref=arr[:, 6:9],
        p_fb=arr[:, 9:12], seg=arr[:, 12].astype(int), spray=arr[:, 13].astype(bool),
        motors=arr[:, 14:18], field=fld, plan=plan,
        extra={"wind": arr[:, 18:21], "reference": ref, "vehicle": out.vehicle.info(),
               "imu": out.imu, "imu_bias0": out.imu_bias0},
    )
    sim_time = float(len(out.t) / cfg.sim.control_hz)
    summ = metrics.summarise(res, cfg, crash_reason=out.crash_reason, crash_time=out.crash_time,
                             reference=ref)
    cut = _cut_by_max_time(cfg, ref, out, summ)
    if cut:
        summ["incomplete_reason"] = cut
    if out.sprayer is not None:
        summ.update(out.sprayer.summary(sim_time))
        res.extra["spray"] = out.sprayer.series(len(out.t))
        from .spray import add_sortie_areas

        add_sortie_areas(summ, res, m.swath_m)
    if hasattr(fb, "scores"):
        sp = np.flatnonzero(res.spray)
        mission = slice(int(sp[0]), int(sp[-1]) + 1) if sp.size else slice(0, len(res.t))
        scores = fb.scores(res.p_true, res.p_ref, mission)
        summ["estimators"] = scores
        if fb.name in scores:
            summ["estimate_rmse_m"] = scores[fb.name]["estimate_rmse_m"]
            summ["estimate_update_us"] = scores[fb.name]["update_us"]
    wall = time.perf_counter() - wall0
    summ.update({
        "sim_time_s": round(sim_time, 3),
        "wall_time_s": round(wall, 3),
        "loop_wall_time_s": round(out.wall_loop_s, 3),
        "real_time_factor": round(sim_time / out.wall_loop_s, 1) if out.wall_loop_s > 0 else None,
        "frames": out.frames,
        "notes": out.notes,
        "seed": cfg.seed,
        "feedback": fb.name,
        **fb.summary(),
        "config": cfg.to_dict(),
    })
    res.summary = summ
    if log is not None:
        from .metrics import contiguous_runs

        tracks = [res.p_true[a:b, :2] for a, b in contiguous_runs(res.spray) if b - a >= 2]
        if tracks:
            import shapely

            foot = shapely.union_all([shapely.LineString(tr).simplify(0.1).buffer(
                0.5 * m.swath_m, cap_style="flat") for tr in tracks])
            log.sprayed(sim_time, [foot])
        log.summary(summ)
    return res
