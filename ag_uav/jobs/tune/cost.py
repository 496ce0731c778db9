"""The cost of a tuning candidate: each scenario flown with its gains on the spec's seeds (step
responses and cut missions, in engine batches), the error metric, the effort, the dose on the
ground and the crash penalty."""

from __future__ import annotations

import copy
import math
from collections.abc import Sequence
from typing import Any

import numpy as np

from ...config import Config, config_from_dict
from ...engine.stages import rec_motors
from ..batch import (
    exception_line,
    set_dotted,
)
from .spec import Scenario, TuneSpec, is_int_key


def candidate_config(spec: TuneSpec, values: Sequence[float]) -> dict[str, Any]:
    """The base config dict with the parameter values (natural units) set."""
    d = copy.deepcopy(spec.base)
    for p, v in zip(spec.params, values, strict=True):
        set_dotted(d, p.key, round(float(v)) if is_int_key(p.key) else float(v))
    return d



def _error_cost(t: np.ndarray, e: np.ndarray, metric: str, t0: float, dt: float) -> float:
    if metric == "none":
        return 0.0
    mag2 = np.einsum("ij,ij->i", e, e)
    if metric == "ise":
        return float(np.sum(mag2) * dt)
    return float(np.sum((t - t0) * np.sqrt(mag2)) * dt)


def scenario_cost(cfg: Config, sc: Scenario, metric: str, crash_penalty: float,
                  effort_weight: float, details: bool = False,
                  dose_weights: dict[str, float] | None = None) -> dict[str, Any]:
    """Cost of one scenario for one config (and, with ``details``, step metrics / RMSE)."""
    return scenario_costs([cfg], sc, metric, crash_penalty, effort_weight, details,
                          dose_weights)[0]


def scenario_costs(cfgs: list[Config], sc: Scenario, metric: str, crash_penalty: float,
                   effort_weight: float, details: bool = False,
                   dose_weights: dict[str, float] | None = None) -> list[dict[str, Any]]:
    """:func:`scenario_cost` of every config, their flights flown as one engine batch."""
    if sc.kind == "step":
        from ...engine.scenarios import step_responses

        trajs = []
        for t_rel, y, out in step_responses(cfgs, axis=sc.axis, size=sc.size,
                                            duration=sc.duration, t_step=sc.t_step,
                                            wind_speed=sc.wind_speed):
            sel = out.t >= sc.t_step
            trajs.append((out.t[sel], out.rec[sel, 6:9] - out.rec[sel, 0:3], rec_motors(out.rec),
                          out.crash_reason, out.crash_time, sc.duration, (t_rel, y)))
    else:
        runs = _mission_runs([_mission_cfg(c, sc) for c in cfgs])
        trajs = [(t, p_ref - p_true, motors, crash, crash_t, full, dose)
                 for (t, p_true, p_ref, motors, crash, crash_t, full), dose in runs]
    return [_cost(cfgs[0], sc, tr, metric, crash_penalty, effort_weight, details,
                  dose_weights or {}) for tr in trajs]


def _mission_cfg(cfg: Config, sc: Scenario) -> Config:
    c = copy.deepcopy(cfg)
    c.sim.max_time_s = sc.max_time_s
    c.log.enabled = False
    return c


def _dose_cost(dose: dict[str, Any] | None, weights: dict[str, float]) -> float:
    """Σ w_k · m_k over the dose metrics (an undefined one counts as 1)."""
    if not weights:
        return 0.0
    if dose is None:
        return math.inf
    return float(sum(w * (1.0 if dose.get(k) is None else dose[k]) for k, w in weights.items()))


def _cost(cfg: Config, sc: Scenario, traj: tuple, metric: str, crash_penalty: float,
          effort_weight: float, details: bool,
          dose_weights: dict[str, float] | None = None) -> dict[str, Any]:
    t, e, motors, crash, crash_t, full, step = traj
    dose = step if sc.kind == "mission" else None
    dt = 1.0 / cfg.sim.control_hz
    info: dict[str, Any] = {}
    if sc.kind == "step":
        from ...engine.scenarios import step_metrics

        t_rel, y = step
        t0 = sc.t_step
        sign = 1.0 if sc.size > 0 else -1.0
        if details and not crash:
            info = step_metrics(t_rel, sign * y, abs(sc.size))
        over = float(max(0.0, (np.max(sign * y) - abs(sc.size)) / abs(sc.size))) if len(y) else 0.0
    else:
        t0 = 0.0
        if details:
            dh = e[:, :2]
            info = {"tracking_rmse_m": float(np.sqrt(np.mean(np.sum(dh * dh, axis=1))))
                    if len(t) else None,
                    "altitude_rmse_m": float(np.sqrt(np.mean(e[:, 2] ** 2))) if len(t) else None}
    cost = _error_cost(t, e, metric, t0, dt) if len(t) else math.inf
    if sc.kind == "mission" and dose_weights:
        cost += _dose_cost(dose, dose_weights)
        if details and dose is not None:
            info.update(dose)
    if sc.kind == "step" and over > sc.overshoot_max:
        # a soft constraint: every unit fraction of overshoot beyond the bound costs this much
        cost += sc.overshoot_penalty * (over - sc.overshoot_max)
    if effort_weight > 0 and len(motors) > 1:
        cost += effort_weight * float(np.sum(np.diff(motors, axis=0) ** 2))
    if crash or not math.isfinite(cost):
        frac = min(1.0, max(0.0, ((crash_t or 0.0) - t0) / full)) if crash else 0.0
        cost = crash_penalty * (2.0 - frac)
    else:
        cost = min(cost, crash_penalty)
    return {"cost": cost, "crash": crash or "", **info}


def mission_trajectory(cfg: Config) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray,
                                             str | None, float | None, float]:
    """(t, p_true, p_ref, motors, crash_reason, crash_time, duration) of ``cfg``'s mission
    (cut at ``sim.max_time_s``): the engine's loop output on the cached plan and reference,
    without the metrics."""
    return mission_trajectories([cfg])[0]


def mission_trajectories(cfgs: list[Config]) -> list[tuple]:
    """:func:`mission_trajectory` of every config, flown as one engine batch."""
    return [tr for tr, _ in _mission_runs(cfgs)]


def _mission_runs(cfgs: list[Config]) -> list[tuple[tuple, dict[str, Any] | None]]:
    """(:func:`mission_trajectory`'s tuple, the dose metrics or None) of every config, flown as
    one engine batch."""
    from ...engine.missions import DOSE_KEYS, dose_summary, fly_many, mission_setup

    out = []
    for cfg, o in zip(cfgs, fly_many(cfgs), strict=True):
        if isinstance(o, BaseException):
            raise o
        fld, _plan, ref = mission_setup(cfg)
        rec = o.rec
        dose = None
        if o.dose is not None:
            d = dose_summary(cfg, fld, o.dose)
            dose = {k: d[k] for k in DOSE_KEYS}
        out.append(((o.t, rec[:, 0:3], rec[:, 6:9], rec_motors(rec), o.crash_reason,
                     o.crash_time, min(cfg.sim.max_time_s, ref.duration)), dose))
    return out


def evaluate_candidate(task: dict[str, Any]) -> dict[str, Any]:
    """Worker entry point: total cost of one candidate over all scenarios. Never raises."""
    return evaluate_candidates([task])[0]


def evaluate_candidates(tasks: list[dict[str, Any]]) -> list[dict[str, Any]]:
    """Worker entry point: the total cost of every candidate of ``tasks`` (a chunk of one
    population, same spec), each scenario flown by all of them as one engine batch. Never
    raises: a candidate that fails gets the penalty. If the batch itself fails, the chunk falls
    back to one candidate at a time, and each result carries the batch's exception in
    ``engine_fallback`` (:func:`run_tune` warns and counts it)."""
    spec: TuneSpec = tasks[0]["spec"]
    seeds: list[int] = tasks[0].get("seeds") or spec.seeds
    penalty = 2.0 * spec.crash_penalty * sum(s.weight for s in spec.scenarios)
    outs: list[dict[str, Any]] = [{"parts": {}, "crash": "", "cost": 0.0} for _ in tasks]
    cfgs: list[Config | None] = []
    for task, out in zip(tasks, outs, strict=True):
        try:
            cfg = config_from_dict(candidate_config(spec, task["values"]))
            cfg.log.enabled = False
            cfgs.append(cfg)
        except Exception as e:  # noqa: BLE001 - a failing candidate gets the penalty
            out.update(cost=penalty, crash=f"{type(e).__name__}: {e}"[:300])
            cfgs.append(None)
    live = [i for i, c in enumerate(cfgs) if c is not None]
    if not live:
        return outs
    details = tasks[0].get("details", False)
    try:
        for sc in spec.scenarios:
            rs = scenario_costs([_seeded(cfgs[i], s) for i in live for s in seeds], sc,
                                spec.metric, spec.crash_penalty, spec.effort_weight,
                                details=details, dose_weights=spec.dose_weights)
            for j, i in enumerate(live):
                r = _seed_mean(rs[j * len(seeds):(j + 1) * len(seeds)])
                out = outs[i]
                out["parts"][sc.name] = r
                out["cost"] += sc.weight * r["cost"]
                if r["crash"] and not out["crash"]:
                    out["crash"] = f"{sc.name}: {r['crash']}"
    except Exception as e:  # noqa: BLE001 - isolate the failing candidate: one at a time
        if len(tasks) == 1:
            outs[0] = {"parts": {}, "cost": penalty, "crash": exception_line(e)}
            return outs
        # not silent: each result says its engine batch failed; run_tune warns and counts it
        reason = exception_line(e)
        return [{**evaluate_candidates([t])[0], "engine_fallback": reason} for t in tasks]
    return outs


def _seeded(cfg: Config, seed: int) -> Config:
    c = copy.deepcopy(cfg)
    c.seed = seed
    return c


def _seed_mean(rs: list[dict[str, Any]]) -> dict[str, Any]:
    """One scenario's result over the run seeds: the mean of every number (the cost: the mean
    cost over the seeds), the first crash."""
    if len(rs) == 1:
        return rs[0]
    out: dict[str, Any] = {"crash": next((r["crash"] for r in rs if r["crash"]), "")}
    for k, v in rs[0].items():
        if k == "crash":
            continue
        vals = [r.get(k) for r in rs]
        if all(isinstance(x, int | float) and not isinstance(x, bool) for x in vals):
            out[k] = float(np.mean(vals))
        else:
            out[k] = v
    return out


def chunk(items: list[Any], n_chunks: int) -> list[list[int]]:
    """Indices of ``items`` in ``n_chunks`` contiguous, near-equal chunks (none empty)."""
    n_chunks = max(1, min(n_chunks, len(items)))
    bounds = np.linspace(0, len(items), n_chunks + 1).round().astype(int)
    return [list(range(a, b)) for a, b in zip(bounds[:-1], bounds[1:], strict=True) if b > a]
