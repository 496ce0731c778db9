"""A tuning spec (``ag-uav tune SPEC.toml``): its parameters, scenarios and settings, read and
checked (one ConfigError line naming the key on anything wrong)."""

from __future__ import annotations

import copy
import hashlib
import json
import math
import tomllib
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

from ...config import Config, ConfigError, config_from_dict
from ...config import toml_repr as _fmt
from ..batch import (
    file_digest,
    get_dotted,
    referenced_files,
    resolve_fragment,
    set_dotted,
)

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
    if not isinstance(kind, str) or kind not in allowed:
        raise ConfigError(f"{where}.kind = {_fmt(kind)}: allowed: step, mission")
    for k in s:
        if k not in allowed[kind]:
            raise ConfigError(f"{where}.{k} = {_fmt(s[k])}: unknown key for a {kind} scenario; "
                              f"allowed: {', '.join(sorted(allowed[kind]))}")
    weight = _num(s.get("weight", 1.0), f"{where}.weight", ge=0.0)
    if kind == "step":
        ax = s.get("axis", "x")
        if not isinstance(ax, str) or ax not in AXES:
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
            set_dotted(d, key, round(v) if is_int_key(key) else v)
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
    from ...engine.missions import DOSE_KEYS

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




def is_int_key(key: str) -> bool:
    """Whether the config key ``key`` (dotted) is an integer field (e.g. ``estimator.window``):
    the optimisers search reals, the candidate gets the nearest integer."""
    import dataclasses
    import typing

    from ...config import Config

    cls: Any = Config
    for part in key.split("."):
        hints = typing.get_type_hints(cls)
        if part not in hints:
            return False
        cls = hints[part]
        if not dataclasses.is_dataclass(cls):
            break
    return cls is int
