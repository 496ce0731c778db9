"""Missions end to end: config → world (field, plan, reference) → the engine → metrics (and the
log).

Data flow (one way): config → field and plan (:mod:`ag_uav.world.mission`) → reference
(:mod:`ag_uav.world.reference`, with the spray job of :mod:`ag_uav.world.spray_job`) → the engine
(:mod:`ag_uav.engine.loop`: N missions in lockstep, MuJoCo physics at ``sim.timestep_s``, control
at ``sim.control_hz``) → metrics (:mod:`ag_uav.analysis.metrics`) and log
(:mod:`ag_uav.record.runlog`). :func:`simulate` is the engine with one vehicle,
:func:`simulate_many` with many.

The **feedback seam** is :class:`~ag_uav.navigation.feedback.Feedback`: each control tick it gets
the true state and returns the position and velocity the controller flies on.
:class:`~ag_uav.navigation.feedback.TrueFeedback` passes the truth through; the estimator bank
plugs in with the same interface (GPS fixes → filter → estimate); the engine runs a batch's
estimator banks together (:class:`ag_uav.navigation.estimation.BatchEstimatorFeedback`, through
:meth:`~ag_uav.navigation.feedback.Feedback.batch`) and any other feedback one vehicle at a time.

Every random draw comes from a Generator spawned from the run seed
(:func:`ag_uav.seeds.rng_streams`), one stream per consumer, so the same config and seed give
the same run, serial or parallel.
"""

from __future__ import annotations

import dataclasses
import hashlib
import math
import sys
import time
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np

from numkit import Z

from ..config import Config, ConfigError
from ..navigation.feedback import Feedback, TrueFeedback
from ..seeds import rng_streams, seed_sequences
from ..vehicle.cascade import cascade_time_scale
from ..vehicle.mjcf import build_vehicle
from ..world.field import Field
from ..world.forecast import plan_wind
from ..world.mission import build_field, build_plan, field_outline
from ..world.pattern import lane_choice, mission_swath
from ..world.reference import Reference
from .heap import trim_heap
from .kernels import RC
from .loop import REC_COLUMNS, Flight, LoopOutput, fly  # noqa: F401
from .stages import failsafe_warning, rec_motors

# ------------------------------------------------------------------------------------ building
#: Bytes one vehicle's run holds per control tick, for the memory budget
#: (``sim.memory_budget_mb``): the reference grid (~100 B: pos, vel, acc, yaw, yaw rate, segment,
#: spray) and its build (the arc-length grid, ~300 B a tick at 5 m/s), and the engine's records
#: (~0.6 KB: the recorded columns, the IMU, the estimators' errors and scores, the sprayer's
#: series). An estimate of the order of magnitude, not a measurement of every config.
TABLE_BYTES_PER_TICK = 1536


@dataclass
class PlanCut:
    """How far a mission cut by ``sim.max_time_s`` was planned (:func:`build_reference`)."""

    path_m: float          # the whole coverage path
    planned_m: float       # the head of it that was densified into the reference
    needs_min_s: float     # the whole path at cruise speed: a lower bound on the mission's time


def reach_m(cfg: Config, horizon_s: float) -> float:
    """Path length (m) that bounds how far a mission can get along its plan in ``horizon_s``
    seconds, with room for what the reference looks ahead: the cruise speed v (the plan's own
    segments are capped at it; transits to the base and climbs make no progress along the
    plan) over the horizon plus slack for the smoothing window, plus twice the braking distance
    v²/(2 a_t) at the tangential acceleration a_t = a·sqrt(1 − 0.7²) of curves (so that the end
    of the head does not slow the part flown), plus four swaths and 20 m."""
    m = cfg.mission
    v = m.speed_mps
    a_t = m.accel_max_mps2 * math.sqrt(1.0 - 0.7**2)
    return v * (horizon_s + 5.0) + v * v / a_t + 4.0 * mission_swath(cfg) + 20.0


def build_reference(cfg: Config, plan, *, spray: bool = True,
                    horizon_s: float | None = None) -> Any:
    """The time-parameterised reference ``simulate`` flies along ``plan``. With
    ``spray.enabled`` (and ``spray``) it carries the spray job (``.spray_job``: tank, battery,
    sorties; :func:`ag_uav.world.spray_job.plan_job`), split into sorties where one tank or battery
    does not do the job.

    ``horizon_s`` (``simulate`` passes ``sim.max_time_s``): a plan longer than the mission can
    fly in that time (:func:`reach_m`) is cut to its head before it is densified, so that the
    reference, the sortie plan and the engine's tables grow with what is flown, not with the
    field; the reference then has ``plan_cut`` (:class:`PlanCut`), else ``plan_cut`` is None.
    Up to the horizon the head's reference is the whole plan's."""
    m = cfg.mission
    fly_plan = plan if horizon_s is None else plan.head(reach_m(cfg, horizon_s))
    ref = Reference(fly_plan, speed=m.speed_mps, altitude=m.altitude_m, a_max=m.accel_max_mps2,
                    takeoff=cfg.sim.takeoff, hover_time=cfg.sim.hover_after_s,
                    rate=cfg.sim.control_hz)
    if spray and cfg.spray.enabled:
        from ..world.spray_job import plan_job

        ref, _job = plan_job(cfg, fly_plan, ref, plan.field, dry_mass_kg=cfg.vehicle.mass_kg
                             + cfg.vehicle.payload_kg, z_land=build_vehicle(cfg).hover_z - 0.08,
                             truncated=fly_plan is not plan,
                             plan_s=plan.length / m.speed_mps)
    ref.plan_cut = None if fly_plan is plan else PlanCut(plan.length, fly_plan.length,
                                                         plan.length / m.speed_mps)
    return ref


def _plan_needs(ref: Any) -> str:
    """How long the plan takes: the reference's duration, or a lower bound for a cut plan."""
    cut = getattr(ref, "plan_cut", None)
    if cut is None:
        return f"{ref.duration:.0f} s"
    return f"at least {cut.needs_min_s:.0f} s ({cut.path_m / 1000:.1f} km of path)"


def preflight_notice(cfg: Config, ref: Any) -> str | None:
    """The one line said before flying a mission that ``sim.max_time_s`` will cut (else None)."""
    if ref.duration <= cfg.sim.max_time_s:
        return None
    return (f"the plan needs {_plan_needs(ref)}, more than sim.max_time_s = "
            f"{cfg.sim.max_time_s:g} s: flying the first {cfg.sim.max_time_s:g} s "
            "(raise sim.max_time_s to fly it all)")


def dose_map_mb(cfg: Config, fld: Field | None) -> float:
    """MB one vehicle's dose map holds (``spray.deposition`` over a field): the level buffer
    (:class:`~ag_uav.world.deposition.GridSpec`, ≈ 1.33 × the fine cells, float64), the fine map
    summed from it at the end and the copy the log encodes (two fine grids more)."""
    if fld is None or not cfg.spray.deposition:
        return 0.0
    from ..world.deposition import DepositionConfig, GridSpec

    dc = DepositionConfig.from_config(cfg)
    g = GridSpec.around(fld.bounds, dc.buffer_m, dc.cell_m, dc.levels, dc.max_cells)
    return (g.size + 2 * g.nx * g.ny) * 8 / 2**20


def check_memory_budget(cfg: Config, duration_s: float, what: str,
                        fld: Field | None = None) -> None:
    """Refuse (:class:`ConfigError`, one line) a run whose tables for ``duration_s`` of flight
    (cut at ``sim.max_time_s``; :data:`TABLE_BYTES_PER_TICK` a control tick) and dose map over
    ``fld`` (:func:`dose_map_mb`) would exceed ``sim.memory_budget_mb``."""
    s = cfg.sim
    flown = min(duration_s, s.max_time_s)
    ticks = int(math.ceil(flown * s.control_hz))
    tables = ticks * TABLE_BYTES_PER_TICK / 2**20
    dose = dose_map_mb(cfg, fld)
    if tables + dose > s.memory_budget_mb:
        parts = f"{tables:.0f} MB of tables ({ticks} control ticks: {flown:.0f} s at " \
                f"{s.control_hz:g} Hz)"
        if dose:
            parts += f" and {dose:.0f} MB of dose map (spray.cell_m = {cfg.spray.cell_m:g})"
        raise ConfigError(f"sim.memory_budget_mb = {s.memory_budget_mb:g}: {what} needs about "
                          f"{tables + dose:.0f} MB: {parts}; raise sim.memory_budget_mb or lower "
                          "sim.max_time_s" + (" (or coarsen spray.cell_m)" if dose else ""))


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
    motors: np.ndarray           # (n, rotors) rotor thrust commands (N)
    field: Field | None = None
    plan: Any = None
    extra: dict[str, Any] = dataclasses.field(default_factory=dict)


# -------------------------------------------------------------------------------------- the loop
def fly_reference(cfg: Config, reference: Any, duration: float, *, progress: bool = False,
                  **flight: Any) -> LoopOutput:
    """Fly the vehicle along ``reference`` (``sample_all(times)`` → dict of pos, vel, acc, yaw,
    seg, spray arrays, as :meth:`ag_uav.world.reference.Reference.sample_all`) for
    ``duration`` seconds of sim time: the engine (:func:`ag_uav.engine.loop.fly`) with one
    vehicle. ``flight``: any other :class:`~ag_uav.engine.loop.Flight` field by name
    (``outline``, ``bounds``, ``feedback``, ``log``, ``render``, ``tick_hook``, ``streams``;
    an unknown name is a TypeError)."""
    return fly([Flight(cfg, reference, duration, **flight)], progress=progress)[0]


def _cut_by_max_time(cfg: Config, ref: Reference, out: LoopOutput,
                     summ: dict[str, Any]) -> str | None:
    """The one-line reason when ``sim.max_time_s`` cut the mission short (else None)."""
    if out.crash_reason is not None or ref.duration <= cfg.sim.max_time_s:
        return None
    return (f"cut by sim.max_time_s = {cfg.sim.max_time_s:g} s after "
            f"{summ.get('legs_flown', 0)} of {summ.get('legs', 0)} legs; the plan needs "
            f"{_plan_needs(ref)} (raise sim.max_time_s)")


@dataclass
class Prepared:
    """One run ready to fly (:func:`prepare_run`): its config, flight, field, plan, reference,
    feedback, log, the wall clock at its start and the pre-flight notice."""

    cfg: Config
    flight: Flight
    fld: Field
    plan: Any
    ref: Any
    fb: Feedback
    log: Any
    wall0: float
    notice: str | None = None


_SETUP_CACHE: dict[str, tuple[Field, Any, Any]] = {}


def mission_setup(cfg: Config) -> tuple[Field, Any, Any]:
    """(field, plan, reference) of ``cfg``'s mission, cached: they depend on the mission keys
    only (field, planner, lanes, speeds, spray job, vehicle mass), not on seeds, gains or
    filters, so a batch of many runs on one field builds them once."""
    import json
    from dataclasses import asdict

    key = json.dumps([asdict(cfg.mission), cfg.sim.takeoff, cfg.sim.hover_after_s,
                      cfg.sim.control_hz, cfg.sim.max_time_s, asdict(cfg.spray),
                      asdict(cfg.battery), asdict(cfg.vehicle), repr(lane_choice(cfg))],
                     default=str, sort_keys=True)
    hit = _SETUP_CACHE.get(key)
    if hit is None:
        fld = build_field(cfg)
        plan = build_plan(cfg, fld)
        # refused before the reference is built (the whole path at cruise speed: a lower bound)
        check_memory_budget(cfg, plan.length / cfg.mission.speed_mps, "the plan", fld)
        ref = build_reference(cfg, plan, horizon_s=cfg.sim.max_time_s)
        if len(_SETUP_CACHE) > 8:
            _SETUP_CACHE.clear()
        hit = _SETUP_CACHE[key] = (fld, plan, ref)
    else:  # the budget is no mission key: the same check on a cached setup
        check_memory_budget(cfg, hit[1].length / cfg.mission.speed_mps, "the plan", hit[0])
    return hit


def prepare_run(cfg: Config, feedback: Feedback | None = None,
                tick_hook: Callable[..., None] | None = None, log: Any = None) -> Prepared:
    """Everything one run needs before it flies: plan, reference, feedback, the flight
    (:func:`simulate` is ``prepare_run``, :func:`~ag_uav.engine.loop.fly` of its flight, then
    :func:`finish_run`; a caller that adjusts the feedback in between runs the three)."""
    wall0 = time.perf_counter()
    streams = rng_streams(cfg.seed)
    fld, plan, ref = mission_setup(cfg)
    check_memory_budget(cfg, ref.duration, "the reference", fld)
    m = cfg.mission
    bounds = fld.bounds
    job = getattr(ref, "spray_job", None)
    if job is not None:  # the base may lie outside the field
        bx, by = (float(v) for v in job.base_xy)
        x0, y0, x1, y1 = bounds
        bounds = (min(x0, bx), min(y0, by), max(x1, bx), max(y1, by))
    outline = field_outline(fld)
    if log is not None:
        log.geo(fld.origin, dose_target_l_per_ha=cfg.spray.rate_l_per_ha)
        log.scene(0.0, outline[0], outline[1:],
                  [(s.kind, np.asarray(s.points), s.spray) for s in plan.segments],
                  plan.swath, m.altitude_m,
                  parts=[(np.asarray(o), [np.asarray(h) for h in hs]) for o, hs in fld.rings()])
    if feedback is None and cfg.estimator.source == "bearings":
        from ..navigation.bearing import BearingFeedback

        e = cfg.estimator
        feedback = BearingFeedback.for_config(cfg, filter=e.bearing_filter,
                                              noise_scale=e.bearing_noise_scale)
    if feedback is None and (cfg.estimator.name != "true" or cfg.estimator.shadow):
        ss = seed_sequences(cfg.seed)
        if cfg.estimator.nav == "ins":
            from ..navigation.ins_feedback import InsFeedback

            feedback = InsFeedback(cfg, ss)
        else:
            from ..navigation.estimation import EstimatorFeedback

            feedback = EstimatorFeedback(cfg, ss["gps"], ss["altimeter"], ss["imu"])
    fb = feedback or TrueFeedback()
    if log is not None and hasattr(fb, "log"):
        fb.log = log
    flight = Flight(cfg, ref, ref.duration, outline=outline, bounds=bounds, feedback=fb,
                    log=log, render=cfg.log.render, tick_hook=tick_hook, streams=streams,
                    field=fld)
    return Prepared(cfg, flight, fld, plan, ref, fb, log, wall0,
                     notice=preflight_notice(cfg, ref))


_SAID: set[str] = set()


def _preflight(cfg: Config) -> RunResult | None:
    """The run of a vehicle the pre-flight check keeps on the ground
    (:func:`ag_uav.navigation.receiver.preflight_gnss`): no flight, not completed, the reason
    in ``incomplete_reason`` and ``preflight``; None when the check passes."""
    from ..navigation.receiver import preflight_gnss

    why = preflight_gnss(cfg)
    if why is None:
        return None
    z = np.zeros((0, 3))
    summ = {"completed": False, "crashed": False, "crash_reason": None,
            "incomplete_reason": why, "preflight": why, "sim_time_s": 0.0,
            "mission_time_s": None, "path_length_m": 0.0, "legs_flown": 0,
            "coverage_fraction": 0.0, "seed": cfg.seed}
    return RunResult(summary=summ, t=np.zeros(0), p_true=z, v_true=z, p_ref=z, p_fb=z,
                     seg=np.zeros(0, int), spray=np.zeros(0, bool),
                     motors=np.zeros((0, len(cfg.vehicle.rotor_thrust_loss))))


def simulate(cfg: Config, *, feedback: Feedback | None = None, progress: bool = False,
             tick_hook: Callable[..., None] | None = None, log: Any = None) -> RunResult:
    """Fly ``cfg``'s mission once and return the trajectory and the summary metrics: the
    engine (:func:`ag_uav.engine.loop.fly`) with one vehicle.

    ``feedback``: the feedback seam (default: the config's estimator, or the true state).
    ``log``: an open :class:`~ag_uav.record.runlog.RunLog` or None; with ``cfg.log.render`` camera
    frames go into it. ``tick_hook(t, data)`` is called after every control tick.
    """
    grounded = _preflight(cfg) if feedback is None else None
    if grounded is not None:
        print(f"ag-uav: {grounded.summary['preflight']}", file=sys.stderr, flush=True)
        if log is not None:
            log.summary(grounded.summary)
        return grounded
    prep = prepare_run(cfg, feedback, tick_hook, log)
    for notice in (prep.notice, failsafe_warning(cfg)):
        if notice and notice not in _SAID:  # once per process: loops of runs repeat it
            _SAID.add(notice)
            print(f"ag-uav: {notice}", file=sys.stderr, flush=True)
    out = fly([prep.flight], progress=progress)[0]
    return finish_run(prep, out, batch=1)


def simulate_many(cfgs: list[Config], *, progress: bool = False, errors: str = "raise",
                  reduce: Callable[[int, RunResult], Any] | None = None) -> list[Any]:
    """Fly every config's mission in one lockstep batch (:func:`ag_uav.engine.loop.fly`); the same
    results as ``[simulate(c) for c in cfgs]`` (a run depends only on its config and seed).
    All configs must share :func:`batch_key`.

    ``errors="return"``: a run that cannot be set up (bad field, …) gives its exception in its
    place instead of raising, and the others fly. ``reduce(i, result)``: what to keep of run
    ``i`` (e.g. its summary row), applied as soon as its metrics are done so that a big batch
    does not hold every trajectory at once."""
    preps: list[Any] = []
    for c in cfgs:
        try:
            preps.append(_preflight(c) or prepare_run(c, None, None, None))
        except Exception as e:  # noqa: BLE001 - reported per run
            if errors == "raise":
                raise
            preps.append(e)
    ok = [p for p in preps if isinstance(p, Prepared)]
    outs = iter(fly([p.flight for p in ok], progress=progress)) if ok else iter(())
    res: list[Any] = []
    for i, p in enumerate(preps):
        if isinstance(p, RunResult):  # grounded by the pre-flight check
            res.append(reduce(i, p) if reduce is not None else p)
            continue
        if not isinstance(p, Prepared):
            res.append(p)
            continue
        out = next(outs)
        try:
            r = finish_run(p, out, batch=len(ok))
            res.append(reduce(i, r) if reduce is not None else r)
        except Exception as e:  # noqa: BLE001
            if errors == "raise":
                raise
            res.append(e)
        del out
    return res


def fly_many(cfgs: list[Config], *, progress: bool = False, capture: bool = False,
             lanes: int | None = None) -> list[Any]:
    """The loop outputs (:class:`~ag_uav.engine.loop.LoopOutput`, no metrics) of every config's
    mission flown as one engine batch, or the exception of a run that could not be set up.
    ``capture``: with the initial states and controls; ``lanes``: as
    :func:`ag_uav.engine.loop.fly`'s."""
    preps: list[Any] = []
    for c in cfgs:
        try:
            preps.append(_preflight(c) or prepare_run(c, None, None, None))
        except Exception as e:  # noqa: BLE001 - reported per run
            preps.append(e)
    ok = [p for p in preps if isinstance(p, Prepared)]
    flown = fly([p.flight for p in ok], progress=progress, capture=capture, lanes=lanes)
    outs = iter(flown)
    return [next(outs) if isinstance(p, Prepared) else p for p in preps]


def batch_key(cfg: Config) -> tuple:
    """Configs with equal keys can fly in one engine batch (same control and physics rates,
    same sensing and spray-job structure)."""
    from ..navigation.receiver import gnss_latency_s

    e = cfg.estimator
    imu = ((e.source == "bearings" or e.name != "true" or bool(e.shadow))
           and e.imu and cfg.imu.model == "mems")
    # the same filters (names, flown one first) share the batched bank
    filters = (e.source, e.name, tuple(s for s in e.shadow if s != e.name), e.model, e.nav,
               round(gnss_latency_s(cfg) * cfg.sim.control_hz) if e.nav == "ins" else 0,
               _ins_key(cfg) if e.nav == "ins" and imu else None)
    sampling = cfg.imu.sampling if imu else None   # one IMU sampling per batch
    return (cfg.sim.control_hz, cfg.sim.timestep_s, imu, sampling, cfg.spray.enabled, filters,
            model_layout(cfg))


def _ins_key(cfg: Config) -> tuple:
    from ..navigation.ins_feedback import ins_bank_key

    return ins_bank_key(cfg)


_LAYOUTS: dict[str, str] = {}
#: the hex digits of a model signature's hash that key a layout
_SIG_DIGITS = 12


def model_layout(cfg: Config) -> str:
    """The sizes of ``cfg``'s compiled physics model (:func:`ag_uav.engine.physics.
    model_signature`; it depends on the vehicle and sim keys, not the field): one engine batch
    steps models of one layout only."""
    from .physics import model_signature

    key = repr(cfg.vehicle) + repr(cfg.sim)
    if key not in _LAYOUTS:
        sig = repr(model_signature(build_vehicle(cfg).model)).encode()
        _LAYOUTS[key] = hashlib.sha1(sig).hexdigest()[:_SIG_DIGITS]
    return _LAYOUTS[key]


#: the summary keys of the dose on the ground (names fixed: summaries and tests read them)
DOSE_KEYS = ("dose_mean_l_per_ha", "dose_cv", "underdosed_fraction", "overdosed_fraction",
             "offtarget_deposit_fraction", "drift_fraction")


def dose_summary(cfg: Config, fld: Field, dose: Any, tank_l: float | None = None
                 ) -> dict[str, Any]:
    """The summary keys of a flight's dose map (:func:`ag_uav.world.deposition.dose_metrics`
    over the field, ``spray.dose_margin_m`` inside it, against ``spray.rate_l_per_ha``):
    :data:`DOSE_KEYS`, the litres that left the nozzles by the nozzle model
    (``nozzle_sprayed_l``: valve delays, pressure lag, minimum speed) and, with the litres the
    tank gave ``tank_l`` (``litres_sprayed_l`` unrounded), the difference
    ``nozzle_minus_tank_l``: the tank draws what the nozzle model lets out (at most what is in
    it), so it is 0 unless the tank ran dry while the line pressure was still falling.
    ``drift_fraction_low`` / ``_high``: the drift past the buffer scaled by the low and high
    bounds of the uncertain inputs (:func:`drift_bounds`). Undefined values (nothing sprayed
    on the field) are None."""
    m = dose.metrics(fld, cfg.spray.rate_l_per_ha, cfg.spray.dose_margin_m)
    out: dict[str, Any] = {k: (None if math.isnan(m[k]) else m[k]) for k in DOSE_KEYS}
    out["nozzle_sprayed_l"] = m["sprayed_l"]
    if tank_l is not None:
        out["nozzle_minus_tank_l"] = m["sprayed_l"] - tank_l
    if out["drift_fraction"] is not None:
        r = drift_bounds(cfg)
        out["drift_fraction_low"] = out["drift_fraction"] * r["low"]
        out["drift_fraction_high"] = out["drift_fraction"] * r["high"]
    out["dose_cell_m"] = dose.grid.cell
    out["dose_mass_balance_error"] = m["mass_balance_error"]
    out["evaporated_fraction"] = m["evaporated_fraction"]
    return out


_DRIFT_RATIOS: dict[str, dict[str, float]] = {}


def drift_bounds(cfg: Config) -> dict[str, float]:
    """The low / central and high / central ratios of the drift past the buffer
    (:func:`ag_uav.world.drift_bounds.drift_ratios`) for ``cfg``'s mission: a strip of its
    lanes at its height and speed, the flown mean wind taken wholly across them, a full tank;
    cached per those inputs."""
    from ..world.deposition import DepositionConfig
    from ..world.drift_bounds import drift_ratios

    v, sp = cfg.vehicle, cfg.spray
    lane = mission_swath(cfg)
    dep = DepositionConfig.from_config(cfg, swath_m=lane)
    mass = v.mass_kg + v.payload_kg + v.unknown_payload_kg + sp.tank_l * sp.density_kg_per_l
    args = (dep, float(cfg.wind.speed_mps), float(cfg.mission.altitude_m),
            float(cfg.mission.speed_mps), lane, mass, dep.buffer_m)
    key = repr(args)
    if key not in _DRIFT_RATIOS:
        _DRIFT_RATIOS[key] = drift_ratios(*args)
    return _DRIFT_RATIOS[key]


def _cut_reason(cfg: Config, ref: Any, out: LoopOutput, summ: dict[str, Any],
                why: str | None) -> str | None:
    """Why the mission was cut, in one line (None: it was not): the position failsafe (its
    reason and landing; a crash in it says so in ``crash_reason``), else the reason a flight
    is incomplete and the cut by ``sim.max_time_s``."""
    cut = _cut_by_max_time(cfg, ref, out, summ)
    if why is not None and (cut is None or why.startswith("never took off")):
        cut = f"{why}; {cut}" if cut else why
    if out.failsafe is None:
        return cut
    summ.update(out.failsafe)
    if summ.get("crashed"):
        summ["crash_reason"] = f"{summ['crash_reason']} (in the GNSS failsafe)"
        return cut
    landed = out.failsafe["failsafe_landed_s"]
    return out.failsafe["failsafe"] + ("" if landed is None else f"; landed at t={landed}s")


def work_rate(cfg: Config, summ: dict[str, Any]) -> dict[str, Any]:
    """A job with base visits: the area covered per hour of job time (flight, transits and the
    time on the ground at the base), ``field_area × coverage / job_time`` (ha/h), and the
    manufacturer's stated rate of the vehicle preset where its sheet gives one
    (:data:`ag_uav.config.vehicles.STATED_WORK_RATE`). Empty for a one-sortie job."""
    from ..config.vehicles import STATED_WORK_RATE

    if (summ.get("sorties") or 0) < 2 or not summ.get("job_time_s"):
        return {}
    area_ha = float(summ.get("field_area_m2") or 0.0) * float(summ.get("coverage_fraction")
                                                             or 0.0) / 1e4
    out: dict[str, Any] = {"work_rate_ha_per_h": round(area_ha / (summ["job_time_s"] / 3600.0),
                                                        3)}
    stated = STATED_WORK_RATE.get(cfg.vehicle.preset)
    if stated is not None:
        out["work_rate_stated_ha_per_h"] = stated[0]
        out["work_rate_stated_source"] = stated[1]
    return out


def _fault_cut(out: LoopOutput, summ: dict, cut: str | None) -> str | None:
    """The rotor fault into the summary; a landing it caused ends the mission early."""
    rf = out.rotor_fault
    if rf is None:
        return cut
    summ["rotor_fault"] = rf
    if rf["landed_s"] is not None and not summ.get("crashed"):
        return f"rotor {rf['rotor']} failed: {rf['action']}; landed at t={rf['landed_s']}s"
    return cut


def _say_lag_scale(cfg: Config, summ: dict, notes: list[str]) -> None:
    """The cascade slowed for the motor lag (:func:`~ag_uav.vehicle.cascade.cascade_time_scale`
    below 1): said where the user looks, the summary's ``cascade_time_scale`` and a note."""
    ts = cascade_time_scale(cfg)
    if ts < 1.0:
        summ["cascade_time_scale"] = round(ts, 3)
        notes.append(f"controller slowed x{ts:.3f} for the motor lag (vehicle.motor_tau_s = "
                     f"{cfg.vehicle.motor_tau_s:g} s), to keep the attitude loop damped")


def finish_run(prep: Prepared, out: LoopOutput, batch: int = 1) -> RunResult:
    """Metrics and the summary of one flown run (``batch``: the size of the engine batch it
    flew in)."""
    from ..analysis import metrics

    cfg, fld, plan, ref, fb, log = prep.cfg, prep.fld, prep.plan, prep.ref, prep.fb, prep.log
    arr = out.rec
    res = RunResult(
        summary={}, t=out.t, p_true=arr[:, RC.P:RC.P_END], v_true=arr[:, RC.V:RC.V_END],
        p_ref=arr[:, RC.RP:RC.RP_END], p_fb=arr[:, RC.P_FB:RC.P_FB_END],
        seg=arr[:, RC.SEG].astype(np.int32), spray=arr[:, RC.SPRAY].astype(bool),
        motors=rec_motors(arr), field=fld, plan=plan,
        extra={"wind": arr[:, RC.WIND:RC.WIND_END], "reference": ref, "vehicle": out.vehicle.info(),
               "imu": out.imu, "imu_bias0": out.imu_bias0},
    )
    sim_time = float(len(out.t) / cfg.sim.control_hz)
    summ = metrics.summarise(res, cfg, crash_reason=out.crash_reason, crash_time=out.crash_time,
                             reference=ref)
    trim_heap()   # each phase's freed temporaries go back before the next (engine/heap.py)
    loss = metrics.gnss_loss_summary(res, cfg, out.gnss_losses, plan)
    if loss:
        summ.update(loss)
        out.notes.append(f"GNSS loss: {loss['gnss_loss_off_target_m2']:.1f} m² sprayed off "
                         "target while the fix was lost")
    _say_lag_scale(cfg, summ, out.notes)
    cut = _fault_cut(out, summ, _cut_reason(cfg, ref, out, summ,
                                            metrics.incomplete_reason(summ, res, cfg)))
    if cut:
        summ["incomplete_reason"] = cut
    if not summ["legs_flown"]:  # the end of a mission never flown is no mission time
        summ["mission_time_s"] = None
    if getattr(ref, "plan_cut", None) is not None:  # the sortie plan covers this much path
        summ["planned_to_m"] = round(ref.plan_cut.planned_m, 1)
    if "lanes" in plan.meta:
        summ["lanes"] = plan.meta["lanes"].summary(plan.spacing)
        summ["lanes"]["offset_m"] = list(plan.meta.get("offset_m", (0.0, 0.0)))
    summ["plan_wind"] = plan_wind(cfg).summary()
    if out.sprayer is not None:
        summ.update(out.sprayer.summary(sim_time))
        res.extra["spray"] = out.sprayer.series(len(out.t))
        from ..analysis.metrics import add_sortie_areas

        add_sortie_areas(summ, res, plan.swath)
        summ.update(work_rate(cfg, summ))
    if out.dose is not None:
        tank_l = None if out.sprayer is None else out.sprayer.litres_total
        summ.update(dose_summary(cfg, fld, out.dose, tank_l))
        res.extra["dose"] = out.dose
        trim_heap()
    if hasattr(fb, "scores"):
        sp = np.flatnonzero(res.spray)
        mission = slice(int(sp[0]), int(sp[-1]) + 1) if sp.size else slice(0, len(res.t))
        scores = fb.scores(res.p_true, res.p_ref, mission)
        summ["estimators"] = scores
        if getattr(fb, "series", None) is not None:   # per-fix score series (INS)
            res.extra["nav_series"] = fb.series
        summ["nav"] = cfg.estimator.nav if cfg.estimator.source == "gps" else "bearings"
        if fb.name in scores:
            summ["estimate_rmse_m"] = scores[fb.name]["estimate_rmse_m"]
            summ["estimate_update_us"] = scores[fb.name]["update_us"]
    wall = time.perf_counter() - prep.wall0
    loop_wall = out.wall_loop_s / batch  # this run's share of the batch's loop
    summ.update({
        "sim_time_s": round(sim_time, 3),
        "wall_time_s": round(wall, 3),
        "loop_wall_time_s": round(loop_wall, 3),
        "loop_cpu_time_s": round(out.cpu_loop_s / batch, 3),
        "real_time_factor": round(sim_time / loop_wall, 1) if loop_wall > 0 else None,
        "batch_size": batch,
        "frames": out.frames,
        "notes": out.notes,
        "seed": cfg.seed,
        "feedback": fb.name,
        **fb.summary(),
        "config": cfg.to_dict(),
    })
    res.summary = summ
    if log is not None:
        _log_outputs(log, res, out, plan.swath, sim_time)
    return res


def _log_outputs(log: Any, res: RunResult, out: LoopOutput, swath: float, sim_time: float
                 ) -> None:
    """The run's end in its log: the sprayed footprint, the final dose map and the summary,
    each after the heap's freed pages went back (:func:`trim_heap`)."""
    from ..analysis.metrics import contiguous_runs

    trim_heap()
    tracks = [res.p_true[a:b, :Z] for a, b in contiguous_runs(res.spray) if b - a >= 2]
    if tracks:
        import shapely

        foot = shapely.union_all([shapely.LineString(tr).simplify(0.1).buffer(
            0.5 * swath, cap_style="flat") for tr in tracks])
        log.sprayed(sim_time, [foot])
    if out.dose is not None:
        trim_heap()
        g = out.dose.grid
        log.dose(sim_time, g.x0, g.y0, g.cell, out.dose.l_per_ha, final=True)
    trim_heap()
    log.summary(res.summary)
