"""Controller tuning: BB-BC (or PSO, or CMA-ES) over IT2-FPID gains on simulated scenarios.

``ag-uav tune SPEC.toml`` (see ``examples/tune.toml``) minimises

    J(x) = Σ_s w_s · J_s(x)

over a box of config keys (``[params]``, e.g. ``"controller.xy.ke" = {lo = 0.1, hi = 10,
log = true}``: ``log`` searches log10 of the value). Each scenario ``s`` is flown with the
candidate's gains and the *same* run seeds for every candidate (common random numbers):
``noise_seed`` (one) or ``noise_seeds = [..]`` (several; ``J_s`` is the mean over them, so that
the tuning does not fit one wind and GNSS draw):

- ``kind = "step"``: hover at 3 m, step of ``size`` m on ``axis`` (x, y or z) at ``t_step``
  (:func:`ag_uav.engine.scenarios.step_response`); error e(t) = p_ref − p over the 3 axes after the
  step;
- ``kind = "mission"``: the base config's mission, cut at ``max_time_s`` of sim time (take-off and
  the first leg(s)); error e(t) = p_ref − p_true over every tick.

with ``J_s = ∫|e|² dt`` (ISE), ``∫ (t − t0)|e| dt`` (ITAE) or 0 (``metric = "none"``), plus
``effort_weight · Σ|Δf|²`` (rotor-thrust increments, N²) and, for mission scenarios, the dose on
the ground: ``[dose_weights]`` (e.g. ``dose_cv = 1.0, underdosed_fraction = 2.0``) adds
``Σ_k w_k · m_k`` over the mission's dose metrics (:data:`ag_uav.engine.missions.DOSE_KEYS`, the
names of its summary; a metric that is undefined, nothing having landed on the field, counts
as 1). A crash (or a non-finite cost) costs
``crash_penalty · (2 − t_crash / duration)`` — finite, and worse the earlier it happens — and
every scenario cost is capped at ``crash_penalty``.

Population members are evaluated in parallel on the :mod:`~ag_uav.jobs.executor` seam. After every
iteration the optimiser state is checkpointed atomically (``checkpoint.json``); every evaluation is
also appended to ``evals.jsonl`` (flushed per line), so ``--resume`` continues exactly where a
killed run stopped — finished iterations and finished evaluations of the current one are not
re-run, and the result equals an uninterrupted run (the optimiser RNG state is checkpointed; the
cost is deterministic). The configured default gains are put in the initial population (member 0)
so the tuned cost can never be worse than the default's.

Held-out validation (``validation_seeds = [..]``, disjoint from the tuning seeds, checked):
after the optimisation the ``validate_top`` (3) distinct candidates of lowest tuning cost (from
the evaluation journal) are flown on the validation seeds with the same scenarios and cost; the
one of lowest validation cost is shipped, and its validation cost is reported beside its tuning
cost (printed, ``before_after.md``, ``tune.json``: ``validation``, ``shipped_*``).

Outputs in ``--out``: ``best_gains.toml`` (a config fragment ``[controller.xy] ke = ...`` that
``fly --config`` and batch presets accept), ``convergence.png``, ``before_after.md`` (default vs
tuned on the same scenarios, also printed) and ``tune.json``.
"""

from __future__ import annotations

import contextlib
import copy
import hashlib
import json
import math
import os
import time
import tomllib
from collections.abc import Callable, Sequence
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from ..config import Config, ConfigError, config_from_dict
from ..record.atomic import atomic_write_text, savefig
from .batch import (
    exception_line,
    file_digest,
    get_dotted,
    read_jsonl,
    referenced_files,
    repair_jsonl,
    resolve_fragment,
    set_dotted,
)
from .executor import Executor, SerialExecutor

SPEC_KEYS = ("name", "description", "optimizer", "pop", "iters", "seed", "noise_seed", "metric",
             "crash_penalty", "effort_weight", "include_default", "base", "params", "scenarios",
             "optimizer_options", "dose_weights", "noise_seeds", "validation_seeds",
             "validate_top")
AXES = {"x": 0, "y": 1, "z": 2}
OPTIMIZERS = ("bbbc", "pso", "cmaes")
METRICS = ("ise", "itae", "none")


@dataclass
class Param:
    key: str
    lo: float
    hi: float
    log: bool = False

    def to_internal(self, v: float) -> float:
        return math.log10(v) if self.log else v

    def from_internal(self, u: float) -> float:
        return float(10.0 ** u) if self.log else float(u)

    @property
    def bounds(self) -> tuple[float, float]:
        return self.to_internal(self.lo), self.to_internal(self.hi)


@dataclass
class Scenario:
    kind: str                      # "step" | "mission"
    name: str
    axis: int = 0
    size: float = 1.0
    duration: float = 6.0          # step: seconds after the step
    t_step: float = 1.0
    wind_speed: float = 0.0
    max_time_s: float = 40.0       # mission: sim-time cut
    weight: float = 1.0
    overshoot_max: float = math.inf  # step: soft bound on the overshoot (fraction of the step)
    overshoot_penalty: float = 0.0   # step: cost per unit fraction of overshoot beyond the bound


@dataclass
class TuneSpec:
    name: str
    base: dict[str, Any]
    params: list[Param]
    scenarios: list[Scenario]
    optimizer: str = "bbbc"
    pop: int = 20
    iters: int = 20
    seed: int = 0
    noise_seed: int = 0
    metric: str = "ise"
    crash_penalty: float = 1000.0
    effort_weight: float = 0.0
    include_default: bool = True
    optimizer_options: dict[str, Any] = field(default_factory=dict)
    dose_weights: dict[str, float] = field(default_factory=dict)
    noise_seeds: list[int] = field(default_factory=list)       # [] = [noise_seed]
    validation_seeds: list[int] = field(default_factory=list)  # [] = no validation
    validate_top: int = 3
    description: str = ""
    source: str | None = None

    @property
    def seeds(self) -> list[int]:
        """The run seeds every candidate is flown with (common random numbers)."""
        return list(self.noise_seeds) or [self.noise_seed]

    def hash(self) -> str:
        """What a checkpoint must match to be resumed (``iters`` and the validation may
        change)."""
        d = asdict(self)
        for k in ("iters", "description", "source", "name", "validation_seeds", "validate_top"):
            d.pop(k)
        for k in ("dose_weights", "noise_seeds"):  # a spec without them resumes older checkpoints
            if not d[k]:
                d.pop(k)
        blob = json.dumps(d, sort_keys=True, default=str)
        files = referenced_files(self.base)  # a field file changed in place: another tune
        if files:
            blob += json.dumps({str(f): file_digest(f) for f in files}, sort_keys=True)
        return hashlib.sha256(blob.encode()).hexdigest()[:16]


def _fmt(v: Any) -> str:
    if isinstance(v, str):
        return f'"{v}"'
    if isinstance(v, dict):
        return "{" + ", ".join(f"{k} = {_fmt(x)}" for k, x in v.items()) + "}"
    return repr(v)


def _num(v: Any, where: str, *, gt: float | None = None, ge: float | None = None) -> float:
    if isinstance(v, bool) or not isinstance(v, int | float) or not math.isfinite(v):
        raise ConfigError(f"{where} = {_fmt(v)}: expected a finite number")
    if gt is not None and not v > gt:
        raise ConfigError(f"{where} = {_fmt(v)}: must be > {gt}")
    if ge is not None and not v >= ge:
        raise ConfigError(f"{where} = {_fmt(v)}: must be >= {ge}")
    return float(v)


#: the largest population: every member is flown on every scenario each iteration, and the
#: optimiser holds pop × params arrays (a population of 10^8 filled GBs before its first run)
MAX_POP = 10_000


def check_pop(v: Any, where: str = "pop") -> int:
    """``pop`` as an integer in [2, :data:`MAX_POP`] (else one ConfigError line)."""
    if isinstance(v, bool) or not isinstance(v, int) or not 2 <= v <= MAX_POP:
        raise ConfigError(f"{where} = {_fmt(v)}: expected an integer in [2, {MAX_POP}] (each "
                          "member is flown on every scenario each iteration)")
    return v


def _int(v: Any, where: str, lo: int) -> int:
    if isinstance(v, bool) or not isinstance(v, int) or v < lo:
        raise ConfigError(f"{where} = {_fmt(v)}: expected an integer >= {lo}")
    return v


def _parse_scenario(i: int, s: Any) -> Scenario:
    where = f"scenarios[{i}]"
    if not isinstance(s, dict):
        raise ConfigError(f"{where} = {_fmt(s)}: expected a table")
    kind = s.get("kind")
    allowed = {"step": {"kind", "name", "axis", "size", "duration", "t_step", "wind_speed",
                        "weight", "overshoot_max", "overshoot_penalty"},
               "mission": {"kind", "name", "max_time_s", "weight"}}
    if kind not in allowed:
        raise ConfigError(f"{where}.kind = {_fmt(kind)}: allowed: step, mission")
    for k in s:
        if k not in allowed[kind]:
            raise ConfigError(f"{where}.{k} = {_fmt(s[k])}: unknown key for a {kind} scenario; "
                              f"allowed: {', '.join(sorted(allowed[kind]))}")
    weight = _num(s.get("weight", 1.0), f"{where}.weight", ge=0.0)
    if kind == "step":
        ax = s.get("axis", "x")
        if ax not in AXES:
            raise ConfigError(f"{where}.axis = {_fmt(ax)}: allowed: x, y, z")
        size = _num(s.get("size", 1.0), f"{where}.size")
        if size == 0.0:
            raise ConfigError(f"{where}.size = 0.0: must be non-zero")
        dur = _num(s.get("duration", 6.0), f"{where}.duration", gt=0.0)
        ts = _num(s.get("t_step", 1.0), f"{where}.t_step", ge=0.0)
        ws = _num(s.get("wind_speed", 0.0), f"{where}.wind_speed", ge=0.0)
        name = s.get("name", f"step-{ax}")
        om = (math.inf if "overshoot_max" not in s
              else _num(s["overshoot_max"], f"{where}.overshoot_max", ge=0.0))
        op = _num(s.get("overshoot_penalty", 0.0), f"{where}.overshoot_penalty", ge=0.0)
        return Scenario("step", str(name), AXES[ax], size, dur, ts, ws, weight=weight,
                        overshoot_max=om, overshoot_penalty=op)
    mt = _num(s.get("max_time_s", 40.0), f"{where}.max_time_s", gt=0.0)
    return Scenario("mission", str(s.get("name", "mission")), max_time_s=mt, weight=weight)


def spec_from_dict(data: dict[str, Any], *, base_dir: str | Path = ".", name: str = "tune",
                   source: str | None = None) -> TuneSpec:
    """Validate a tune spec (TOML-shaped dict); one-line ConfigError on anything wrong."""
    base_dir = Path(base_dir)
    for k in data:
        if k not in SPEC_KEYS:
            raise ConfigError(f"{k} = {_fmt(data[k])}: unknown key in a tune spec; allowed: "
                              f"{', '.join(SPEC_KEYS)}")
    base = resolve_fragment(data.get("base", {}), "base", base_dir)
    try:
        base_cfg = config_from_dict(base)
    except ConfigError as e:
        raise ConfigError(f"base: {e}") from None
    opt = data.get("optimizer", "bbbc")
    if opt not in OPTIMIZERS:
        raise ConfigError(f"optimizer = {_fmt(opt)}: allowed: {', '.join(OPTIMIZERS)}")
    metric = data.get("metric", "ise")
    if metric not in METRICS:
        raise ConfigError(f"metric = {_fmt(metric)}: allowed: {', '.join(METRICS)}")
    params_raw = data.get("params")
    if not isinstance(params_raw, dict) or not params_raw:
        raise ConfigError(f"params = {_fmt(params_raw)}: expected a table of "
                          '"config.key" = {lo = .., hi = ..} (at least one)')
    params: list[Param] = []
    for key, b in params_raw.items():
        where = f'params."{key}"'
        if isinstance(b, list):
            b = {"lo": b[0], "hi": b[1]} if len(b) == 2 else {"lo": None}
        if not isinstance(b, dict) or set(b) - {"lo", "hi", "log"} or not {"lo", "hi"} <= set(b):
            raise ConfigError(f"{where} = {_fmt(b)}: expected [lo, hi] or {{lo, hi, log}}")
        lo = _num(b["lo"], f"{where}.lo")
        hi = _num(b["hi"], f"{where}.hi")
        if not hi > lo:
            raise ConfigError(f"{where} = {_fmt(b)}: need lo < hi")
        log = b.get("log", False)
        if not isinstance(log, bool):
            raise ConfigError(f"{where}.log = {_fmt(log)}: expected true or false")
        if log and lo <= 0:
            raise ConfigError(f"{where}.lo = {lo}: must be > 0 with log = true")
        cur = get_dotted(base_cfg.to_dict(), key)
        if isinstance(cur, bool) or not isinstance(cur, int | float):
            raise ConfigError(f"{where}: not a numeric config key")
        for v in (lo, hi):  # the config's own range checks, with the key's name
            d = copy.deepcopy(base)
            set_dotted(d, key, round(v) if _is_int_key(key) else v)
            config_from_dict(d)
        params.append(Param(key, lo, hi, log))
    sc_raw = data.get("scenarios")
    if not isinstance(sc_raw, list) or not sc_raw:
        raise ConfigError(f"scenarios = {_fmt(sc_raw)}: expected at least one [[scenarios]]")
    scenarios = [_parse_scenario(i, s) for i, s in enumerate(sc_raw)]
    names = [s.name for s in scenarios]
    if len(set(names)) != len(names):
        raise ConfigError(f"scenarios: duplicate names {names}; give each a distinct name")
    oo = data.get("optimizer_options", {})
    if not isinstance(oo, dict):
        raise ConfigError(f"optimizer_options = {_fmt(oo)}: expected a table")
    allowed_oo = {"bbbc": {"spread", "centre", "elitism"},
                  "pso": {"inertia", "c1", "c2", "v_max"}, "cmaes": {"sigma"}}[opt]
    for k in oo:
        if k not in allowed_oo:
            raise ConfigError(f"optimizer_options.{k} = {_fmt(oo[k])}: unknown for {opt}; "
                              f"allowed: {', '.join(sorted(allowed_oo))}")
    inc = data.get("include_default", True)
    if not isinstance(inc, bool):
        raise ConfigError(f"include_default = {_fmt(inc)}: expected true or false")
    nm = data.get("name", name)
    return TuneSpec(
        name=str(nm), base=base, params=params, scenarios=scenarios, optimizer=opt,
        pop=check_pop(data.get("pop", 20), "pop"), iters=_int(data.get("iters", 20), "iters", 1),
        seed=_int(data.get("seed", 0), "seed", 0),
        noise_seed=_int(data.get("noise_seed", 0), "noise_seed", 0), metric=metric,
        crash_penalty=_num(data.get("crash_penalty", 1000.0), "crash_penalty", gt=0.0),
        effort_weight=_num(data.get("effort_weight", 0.0), "effort_weight", ge=0.0),
        include_default=inc, optimizer_options=dict(oo),
        dose_weights=_dose_weights(data.get("dose_weights", {}), base_cfg),
        **_seed_lists(data), description=str(data.get("description", "")), source=source)


def _seed_list(raw: Any, where: str) -> list[int]:
    if not isinstance(raw, list) or not raw:
        raise ConfigError(f"{where} = {_fmt(raw)}: expected a non-empty list of seeds (integers "
                          ">= 0)")
    out = [_int(v, f"{where}[{i}]", 0) for i, v in enumerate(raw)]
    if len(set(out)) != len(out):
        raise ConfigError(f"{where} = {_fmt(raw)}: duplicate seeds")
    return out


def _seed_lists(data: dict[str, Any]) -> dict[str, Any]:
    """``noise_seeds`` (the tuning's run seeds, common to every candidate; replaces
    ``noise_seed``), ``validation_seeds`` (held out: disjoint from the tuning's) and
    ``validate_top`` (how many of the best distinct candidates are flown on them)."""
    out: dict[str, Any] = {}
    if "noise_seeds" in data:
        if "noise_seed" in data:
            raise ConfigError("noise_seed and noise_seeds: give one (noise_seeds = [..] flies "
                              "every candidate on each of them)")
        out["noise_seeds"] = _seed_list(data["noise_seeds"], "noise_seeds")
    if "validation_seeds" in data:
        val = _seed_list(data["validation_seeds"], "validation_seeds")
        tune = out.get("noise_seeds") or [data.get("noise_seed", 0)]
        common = sorted(set(val) & set(tune))
        if common:
            raise ConfigError(f"validation_seeds = {_fmt(val)}: seeds {common} are also tuning "
                              "seeds; held-out seeds must be disjoint from noise_seed(s)")
        out["validation_seeds"] = val
    out["validate_top"] = _int(data.get("validate_top", 3), "validate_top", 1)
    return out


def _dose_weights(raw: Any, base_cfg: Config) -> dict[str, float]:
    """``[dose_weights]``: dose metric name → weight >= 0 (the base must model the dose)."""
    from ..engine.missions import DOSE_KEYS

    if not isinstance(raw, dict):
        raise ConfigError(f"dose_weights = {_fmt(raw)}: expected a table of metric = weight")
    out = {}
    for k, v in raw.items():
        if k not in DOSE_KEYS:
            raise ConfigError(f"dose_weights.{k} = {_fmt(v)}: unknown dose metric; allowed: "
                              f"{', '.join(DOSE_KEYS)}")
        out[k] = _num(v, f"dose_weights.{k}", ge=0.0)
    if out and not base_cfg.spray.deposition:
        raise ConfigError("dose_weights: the base config has spray.deposition = false (no dose "
                          "to weigh)")
    return out


def load_spec(path: str | Path) -> TuneSpec:
    p = Path(path)
    if not p.is_file():
        raise ConfigError(f'tune spec = "{p}": no such file')
    try:
        data = tomllib.loads(p.read_text())
    except tomllib.TOMLDecodeError as e:
        raise ConfigError(f'tune spec = "{p}": not valid TOML ({e})') from None
    return spec_from_dict(data, base_dir=p.parent, name=p.stem, source=str(p))


# ------------------------------------------------------------------------------------ the cost
def candidate_config(spec: TuneSpec, values: Sequence[float]) -> dict[str, Any]:
    """The base config dict with the parameter values (natural units) set."""
    d = copy.deepcopy(spec.base)
    for p, v in zip(spec.params, values, strict=True):
        set_dotted(d, p.key, round(float(v)) if _is_int_key(p.key) else float(v))
    return d


def _is_int_key(key: str) -> bool:
    """Whether the config key ``key`` (dotted) is an integer field (e.g. ``estimator.window``):
    the optimisers search reals, the candidate gets the nearest integer."""
    import dataclasses
    import typing

    from ..config import Config

    cls: Any = Config
    for part in key.split("."):
        hints = typing.get_type_hints(cls)
        if part not in hints:
            return False
        cls = hints[part]
        if not dataclasses.is_dataclass(cls):
            break
    return cls is int


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
        from ..engine.scenarios import step_responses

        trajs = []
        for t_rel, y, out in step_responses(cfgs, axis=sc.axis, size=sc.size,
                                            duration=sc.duration, t_step=sc.t_step,
                                            wind_speed=sc.wind_speed):
            sel = out.t >= sc.t_step
            trajs.append((out.t[sel], out.rec[sel, 6:9] - out.rec[sel, 0:3], out.rec[:, 14:18],
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
        from ..engine.scenarios import step_metrics

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
    from ..engine.missions import DOSE_KEYS, dose_summary, fly_many, mission_setup

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
        out.append(((o.t, rec[:, 0:3], rec[:, 6:9], rec[:, 14:18], o.crash_reason,
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


def default_values(spec: TuneSpec) -> list[float]:
    """The base config's current values of the tuned keys (the "before" gains)."""
    d = config_from_dict(spec.base).to_dict()
    return [float(get_dotted(d, p.key)) for p in spec.params]


def _make_optimizer(spec: TuneSpec) -> Any:
    from controllers.optim import BBBC, CMAES, PSO

    lo = [p.bounds[0] for p in spec.params]
    hi = [p.bounds[1] for p in spec.params]
    oo = dict(spec.optimizer_options)
    if spec.optimizer == "pso":
        if isinstance(oo.get("inertia"), list):
            oo["inertia"] = tuple(oo["inertia"])
            oo["max_iter"] = spec.iters
        return PSO(lo, hi, pop=spec.pop, rng=spec.seed, **oo)
    if spec.optimizer == "cmaes":
        return CMAES(lo, hi, pop=spec.pop, rng=spec.seed, **oo)
    return BBBC(lo, hi, pop=spec.pop, rng=spec.seed, **oo)


def _opt_from_state(state: dict[str, Any]) -> Any:
    from controllers.optim import BBBC, CMAES, PSO

    return {"pso": PSO, "cmaes": CMAES}.get(state["kind"], BBBC).from_state(state)


def _population(opt: Any) -> np.ndarray:
    return opt.ask()


def _set_member(opt: Any, i: int, u: np.ndarray) -> None:
    if hasattr(opt, "population"):
        opt.population[i] = u
    else:
        opt.x[i] = u


def _xkey(u: Sequence[float]) -> str:
    return json.dumps([float(v) for v in u])


def top_candidates(spec: TuneSpec, cache: dict[str, dict[str, Any]], k: int
                   ) -> list[tuple[list[float], float]]:
    """The ``k`` distinct evaluated candidates of lowest tuning cost (natural units, cost),
    best first; ties broken by the candidate's coordinates (deterministic)."""
    ranked = sorted((float(r["cost"]), key) for key, r in cache.items()
                    if math.isfinite(float(r["cost"])))
    return [([p.from_internal(v) for p, v in zip(spec.params, json.loads(key), strict=True)], c)
            for c, key in ranked[:k]]


def validate(spec: TuneSpec, top: list[tuple[list[float], float]], executor: Executor
             ) -> list[dict[str, Any]]:
    """Each candidate of ``top`` flown on the held-out ``validation_seeds`` (the same
    scenarios and cost): ``{"values", "tune_cost", "validation_cost", "crash"}``, in ``top``'s
    order. Empty when the spec names no validation seeds."""
    if not spec.validation_seeds or not top:
        return []
    tasks = [{"spec": spec, "values": v, "seeds": list(spec.validation_seeds)} for v, _ in top]
    outs = executor.map(evaluate_candidate, tasks)
    return [{"values": list(v), "tune_cost": c, "validation_cost": float(o["cost"]),
             "crash": o["crash"]} for (v, c), o in zip(top, outs, strict=True)]


@dataclass
class TuneResult:
    best_values: list[float]
    best_cost: float
    default_values: list[float]
    default_cost: float
    history: list[float]
    iterations: int
    n_evals: int               # evaluations run in this call (cache hits and resumed excluded)
    wall_s: float
    out_dir: Path
    files: list[Path] = field(default_factory=list)
    before_after: list[list[str]] = field(default_factory=list)
    n_fallback: int = 0        # evaluations (this call) flown alone after their batch failed
    top: list[tuple[list[float], float]] = field(default_factory=list)  # best distinct evals
    validation: list[dict[str, Any]] = field(default_factory=list)  # top on held-out seeds
    shipped: int = -1          # index in validation of the shipped gains (-1: best = shipped)

    @property
    def shipped_values(self) -> list[float]:
        """The gains written to best_gains.toml: the lowest validation cost among the top
        candidates when the spec validates, else the lowest tuning cost."""
        return self.validation[self.shipped]["values"] if self.shipped >= 0 else self.best_values

    @property
    def validation_cost(self) -> float:
        return (self.validation[self.shipped]["validation_cost"] if self.shipped >= 0
                else math.nan)


class TuneStopped(RuntimeError):
    """Evaluations were lost to the machinery after the retries (one line); the checkpoint of the
    last finished iteration and the evaluation journal are kept, ``--resume`` continues."""


#: times a chunk of evaluations whose worker died is resubmitted before the tune stops
LOST_RETRIES = 2


def run_tune(spec: TuneSpec, out_dir: str | Path, executor: Executor | None = None, *,
             resume: bool = False, fresh: bool = False, iters: int | None = None,
             progress: bool = True, outputs: bool = True,
             on_iteration: Callable[[int, dict[str, Any]], None] | None = None,
             warn: Callable[[str], None] | None = None) -> TuneResult:
    """Run (or resume) the optimisation; see the module docstring.

    Nothing is silent: a chunk whose engine batch failed and was evaluated one candidate at a
    time is a warning (``warn``, default one line on stderr) and counted (``engine_fallbacks``
    per iteration, :attr:`TuneResult.n_fallback`, ``tune.json``); evaluations lost to a dead
    worker are resubmitted :data:`LOST_RETRIES` times, then :class:`TuneStopped` (a lost
    executor: :class:`~ag_uav.jobs.executor.ExecutorLost`) ends the call, never a made-up cost.
    ``out_dir`` belongs to this tune while it runs (:func:`ag_uav.jobs.outdir.hold`).
    """
    from .outdir import hold

    with hold(out_dir, "tune", "wait for it to finish, or choose another --out"):
        return _run_tune(spec, Path(out_dir), executor, resume=resume, fresh=fresh, iters=iters,
                         progress=progress, outputs=outputs, on_iteration=on_iteration,
                         warn=warn)


def _run_tune(spec: TuneSpec, out: Path, executor: Executor | None, *, resume: bool,
              fresh: bool, iters: int | None, progress: bool, outputs: bool,
              on_iteration: Callable[[int, dict[str, Any]], None] | None,
              warn: Callable[[str], None] | None) -> TuneResult:
    ck_path, ev_path = out / "checkpoint.json", out / "evals.jsonl"
    if (ck_path.exists() or ev_path.exists()) and not (resume or fresh):
        raise ConfigError(f'--out = "{out}": already holds a tuning checkpoint; use --resume to '
                          "continue it or --fresh to start over")
    out.mkdir(parents=True, exist_ok=True)
    executor = executor or SerialExecutor()
    n_iter = iters if iters is not None else spec.iters
    h = spec.hash()
    x0 = default_values(spec)
    opt, log_stats = _start(spec, ck_path, ev_path, h, x0, resume, fresh)
    ev = _EvalLog(ev_path, h, spec, progress, n_iter, opt.iteration, warn)
    t_start = time.perf_counter()
    try:
        while opt.iteration < n_iter:
            t_it = time.perf_counter()
            U = _population(opt)
            k = opt.iteration + 1
            results, n_fb = ev.evaluate(executor, U, k)
            costs = [r["cost"] for r in results]
            opt.tell(costs)
            fin = np.array([c for c in costs if math.isfinite(c)])
            stat = {"iteration": k, "best_so_far": opt.best_f, "gen_min": float(fin.min()),
                    "gen_median": float(np.median(fin)),
                    "crashes": sum(bool(r["crash"]) for r in results),
                    "engine_fallbacks": n_fb, "wall_s": round(time.perf_counter() - t_it, 3)}
            log_stats.append(stat)
            atomic_write_text(ck_path, json.dumps({
                "version": 1, "spec_hash": h, "spec_name": spec.name,
                "optimizer": opt.state_dict(), "iterations": log_stats, "default_values": x0}))
            if ev.bar is not None:
                ev.bar.set_postfix(best=f"{opt.best_f:.4g}", refresh=False)
            if on_iteration is not None:
                on_iteration(k, stat)
    finally:
        ev.close()
    best = [p.from_internal(v) for p, v in zip(spec.params, opt.best_x, strict=True)]
    res = TuneResult(best_values=best, best_cost=float(opt.best_f), default_values=x0,
                     default_cost=math.nan, history=list(opt.history), iterations=opt.iteration,
                     n_evals=ev.n_new, wall_s=time.perf_counter() - t_start, out_dir=out,
                     n_fallback=ev.n_fallback)
    res.top = top_candidates(spec, ev.cache, spec.validate_top)
    if outputs:
        write_outputs(spec, res, executor, log_stats)
    return res


def _start(spec: TuneSpec, ck_path: Path, ev_path: Path, h: str, x0: list[float],
           resume: bool, fresh: bool) -> tuple[Any, list[dict[str, Any]]]:
    """The optimiser and the iteration log: from the checkpoint (``resume``), or new (with the
    default gains as member 0)."""
    if resume and ck_path.exists():
        try:
            ck = json.loads(ck_path.read_bytes().decode("utf-8"))
            state, its, ck_hash = ck["optimizer"], ck.get("iterations", []), ck.get("spec_hash")
        except (UnicodeDecodeError, json.JSONDecodeError, KeyError, TypeError):
            raise ConfigError(f'--resume: "{ck_path}" is damaged (not a tuning checkpoint); '
                              "use --fresh") from None
        if ck_hash != h:
            raise ConfigError(f'--resume: "{ck_path}" was written for a different spec '
                              "(params, scenarios, optimizer or a field file changed); use "
                              "--fresh")
        return _opt_from_state(state), its
    if fresh:
        for p in (ck_path, ev_path):
            p.unlink(missing_ok=True)
    opt = _make_optimizer(spec)
    if spec.include_default:
        u0 = np.array([p.to_internal(v) for p, v in zip(spec.params, x0, strict=True)])
        lo = np.array([p.bounds[0] for p in spec.params])
        hi = np.array([p.bounds[1] for p in spec.params])
        _set_member(opt, 0, np.clip(u0, lo, hi))
    return opt, []


class _EvalLog:
    """The evaluations of one :func:`run_tune` call: the journal (``evals.jsonl``, a cache of
    finished evaluations), the progress bar, warnings and counters."""

    def __init__(self, path: Path, h: str, spec: TuneSpec, progress: bool, n_iter: int,
                 it0: int, warn: Callable[[str], None] | None) -> None:
        self.h, self.spec, self._warn = h, spec, warn
        self.cache: dict[str, dict[str, Any]] = {}
        self.bar = None
        if progress:
            from .._progress import progress_bar

            self.bar = progress_bar(total=n_iter * spec.pop, initial=it0 * spec.pop,
                                    unit="eval", desc=f"tune {spec.name}", dynamic_ncols=True,
                                    smoothing=0.05)
        if path.exists():  # finished evaluations (resume: those of the current iteration)
            repair_jsonl(path)
            recs, bad = read_jsonl(path)
            if bad:
                self.warn(f"{path}: skipped {bad} unreadable line(s); those evaluations are "
                          "run again")
            for rec in recs:
                if rec.get("h") == h and isinstance(rec.get("result"), dict):
                    self.cache[_xkey(rec["u"])] = rec["result"]
        self.path = path
        self.f = path.open("a")
        self.n_new = self.n_fallback = 0

    def warn(self, msg: str) -> None:
        if self._warn is not None:
            return self._warn(msg)
        import sys

        line = f"ag-uav: warning: {msg}"
        if self.bar is not None:
            self.bar.write(line, file=sys.stderr)
        else:
            print(line, file=sys.stderr)

    def evaluate(self, executor: Executor, U: np.ndarray, k: int
                 ) -> tuple[list[dict[str, Any]], int]:
        """Every member's result (cached ones reused); and how many fell back to one at a time."""
        results: list[dict[str, Any] | None] = [None] * len(U)
        for i, u in enumerate(U):
            results[i] = self.cache.get(_xkey(u))
        todo = [i for i, r in enumerate(results) if r is None]
        if self.bar is not None:
            self.bar.update(len(U) - len(todo))
        n_fb = 0
        for attempt in range(LOST_RETRIES + 1):
            lost: list[int] = []
            tasks = [{"spec": self.spec, "values": [p.from_internal(v) for p, v in
                                                    zip(self.spec.params, U[i], strict=True)]}
                     for i in todo]
            chunks = chunk(tasks, executor.workers)
            for c, rs in executor.map_unordered(
                    evaluate_candidates, [[tasks[j] for j in ch] for ch in chunks],
                    return_exceptions=True):
                if isinstance(rs, BaseException):
                    lost += [todo[j] for j in chunks[c]]
                    last = exception_line(rs)
                    continue
                n_fb += self._record(k, U, [todo[j] for j in chunks[c]], rs, results)
            if not lost:
                return results, n_fb  # type: ignore[return-value]
            self.warn(f"iteration {k}: {len(lost)} evaluations lost to the machinery ({last})"
                      + ("; resubmitting" if attempt < LOST_RETRIES else ""))
            todo = lost
        raise TuneStopped(f"tune {self.spec.name}: {len(todo)} evaluations of iteration {k} lost "
                          f"to the machinery {LOST_RETRIES + 1} times ({last}); the checkpoint "
                          f"of iteration {k - 1} is kept, --resume continues")

    def _record(self, k: int, U: np.ndarray, idx: list[int], rs: list[dict[str, Any]],
                results: list[dict[str, Any] | None]) -> int:
        fb = next((r["engine_fallback"] for r in rs if r.get("engine_fallback")), "")
        if fb:
            self.warn(f"iteration {k}: an engine batch of {len(rs)} candidates failed ({fb}); "
                      "evaluated one at a time")
            self.n_fallback += len(rs)
        for i, r in zip(idx, rs, strict=True):
            results[i] = r
            self.cache[_xkey(U[i])] = r
            try:
                self.f.write(json.dumps({"h": self.h, "iter": k, "i": i, "u": U[i].tolist(),
                                         "result": r}) + "\n")
                self.f.flush()
                os.fsync(self.f.fileno())
            except OSError as e:
                raise OSError(e.errno, e.strerror or str(e), str(self.path)) from None
            self.n_new += 1
            if self.bar is not None:
                self.bar.update(1)
        return len(rs) if fb else 0

    def close(self) -> None:
        with contextlib.suppress(OSError):
            self.f.close()
        if self.bar is not None:
            self.bar.close()


# ------------------------------------------------------------------------------------ outputs
def gains_toml(spec: TuneSpec, values: Sequence[float], comment: str = "") -> str:
    """The tuned keys as a TOML config fragment (``[controller.xy]`` ``ke = ...``)."""
    import tomli_w

    d: dict[str, Any] = {}
    for p, v in zip(spec.params, values, strict=True):
        set_dotted(d, p.key, float(v))
    head = "".join(f"# {line}\n" for line in comment.splitlines()) if comment else ""
    return head + tomli_w.dumps(d)


def write_outputs(spec: TuneSpec, res: TuneResult, executor: Executor,
                  log_stats: list[dict[str, Any]]) -> None:
    """best_gains.toml, convergence.png, before_after.md (printed), tune.json."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    out = res.out_dir
    res.validation = validate(spec, res.top, executor)
    if res.validation:
        res.shipped = min(range(len(res.validation)),
                          key=lambda i: res.validation[i]["validation_cost"])
        _print_validation(spec, res)
    # before/after on the same scenarios, with details
    tasks = [{"spec": spec, "values": res.default_values, "details": True},
             {"spec": spec, "values": res.shipped_values, "details": True}]
    before, after = executor.map(evaluate_candidate, tasks)
    res.default_cost = float(before["cost"])
    val = (f"; held-out validation cost {res.validation_cost:.6g} on seeds "
           f"{spec.validation_seeds} (best of the top {len(res.validation)} by it)"
           if res.validation else "")
    gp = out / "best_gains.toml"
    atomic_write_text(gp, gains_toml(spec, res.shipped_values, comment=(
        f"ag-uav tune {spec.source or spec.name}: {spec.optimizer.upper()} {spec.pop} x "
        f"{res.iterations}, {spec.metric.upper()} cost {after['cost']:.6g} on seeds "
        f"{spec.seeds} (default gains: {res.default_cost:.6g}){val}\n"
        "use: ag-uav fly --config best_gains.toml, or a batch preset {config = \"...\"}")))
    # convergence
    fig, ax = plt.subplots(figsize=(6, 3.8))
    its = [s["iteration"] for s in log_stats]
    ax.plot(its, [s["best_so_far"] for s in log_stats], "o-", ms=3, label="best so far")
    ax.plot(its, [s["gen_min"] for s in log_stats], ".", ms=4, label="generation best")
    ax.plot(its, [s["gen_median"] for s in log_stats], "--", lw=0.8, label="generation median")
    ax.axhline(res.default_cost, color="k", lw=0.8, ls=":", label="default gains")
    ax.set_yscale("log")
    ax.set_xlabel("iteration")
    ax.set_ylabel(f"cost ({spec.metric.upper()})")
    ax.set_title(f"{spec.optimizer.upper()} convergence: {spec.name}", fontsize=10)
    ax.grid(alpha=0.3, which="both")
    ax.legend(fontsize=8)
    fig.tight_layout()
    cp = out / "convergence.png"
    savefig(fig, cp, dpi=110)
    plt.close(fig)
    # before/after table
    header = ["scenario", "quantity", "default", "tuned"]
    table: list[list[str]] = []
    for p, a, b in zip(spec.params, res.default_values, res.best_values, strict=True):
        table.append(["gains", p.key, f"{a:.4g}", f"{b:.4g}"])
    for sc in spec.scenarios:
        pb, pa = before["parts"].get(sc.name, {}), after["parts"].get(sc.name, {})
        for key, val in pb.items():
            if key == "crash":
                if val or pa.get("crash"):
                    table.append([sc.name, "crash", str(val or "-"), str(pa.get("crash") or "-")])
                continue
            table.append([sc.name, key, _f4(val), _f4(pa.get(key))])
    table.append(["total", "cost", _f4(before["cost"]), _f4(after["cost"])])
    from .batch import markdown_table, print_table

    print_table(header, table, f"default vs tuned gains ({spec.metric.upper()}, same scenarios)")
    md = [f"# Tuning `{spec.name}`", "",
          f"- optimizer: {spec.optimizer.upper()}, population {spec.pop}, "
          f"iterations {res.iterations}, seed {spec.seed}",
          f"- cost: {spec.metric.upper()}, crash penalty {spec.crash_penalty:g}, "
          f"noise seeds {spec.seeds} (every candidate; the cost is their mean)",
          f"- executor: {executor.name}; wall time (this call) {res.wall_s:.1f} s",
          f"- best cost {res.best_cost:.6g}; default gains {res.default_cost:.6g}", "",
          markdown_table(header, table), "![convergence](convergence.png)", ""]
    if res.validation:
        md += [f"Held-out validation (seeds {spec.validation_seeds}, disjoint from the tuning's "
               f"{spec.seeds}) of the {len(res.validation)} best distinct candidates; the shipped "
               "gains (the tuned column above) are the lowest validation cost:", "",
               markdown_table(*_validation_table(res)), ""]
    bp = out / "before_after.md"
    atomic_write_text(bp, "\n".join(md))
    jp = out / "tune.json"
    atomic_write_text(jp, json.dumps({
        "name": spec.name, "best": dict(zip([p.key for p in spec.params], res.best_values,
                                            strict=True)),
        "best_cost": res.best_cost, "default": dict(zip([p.key for p in spec.params],
                                                        res.default_values, strict=True)),
        "default_cost": res.default_cost, "history": res.history,
        "iterations": log_stats, "wall_s": res.wall_s, "executor": executor.name,
        "engine_fallbacks": res.n_fallback, "noise_seeds": spec.seeds,
        "validation_seeds": spec.validation_seeds, "validation": res.validation,
        "shipped": dict(zip([p.key for p in spec.params], res.shipped_values, strict=True)),
        "shipped_tune_cost": float(after["cost"]),
        "shipped_validation_cost": res.validation_cost if res.validation else None},
        indent=2))
    res.files = [gp, cp, bp, jp]
    res.before_after = table


def _validation_table(res: TuneResult) -> tuple[list[str], list[list[str]]]:
    header = ["rank (tuning)", "tuning cost", "validation cost", "shipped"]
    rows = [[str(i + 1), f"{v['tune_cost']:.4g}", f"{v['validation_cost']:.4g}",
             "yes" if i == res.shipped else ""] for i, v in enumerate(res.validation)]
    return header, rows


def _print_validation(spec: TuneSpec, res: TuneResult) -> None:
    from .batch import print_table

    print_table(*_validation_table(res), f"validation: the {len(res.validation)} best "
                f"candidates on held-out seeds {spec.validation_seeds} (tuning seeds "
                f"{spec.seeds})")


def _f4(v: Any) -> str:
    if v is None:
        return "-"
    if isinstance(v, float):
        return "inf" if math.isinf(v) else f"{v:.4g}"
    return str(v)


__all__ = ["Param", "Scenario", "TuneSpec", "TuneResult", "load_spec", "spec_from_dict",
           "run_tune", "evaluate_candidate", "scenario_cost", "candidate_config", "gains_toml",
           "default_values", "TuneStopped", "LOST_RETRIES", "top_candidates", "validate"]
