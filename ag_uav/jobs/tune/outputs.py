"""What a tuning leaves: the best distinct candidates flown on the held-out seeds, and
``best_gains.toml``, ``convergence.png``, ``before_after.md`` (also printed) and ``tune.json``."""

from __future__ import annotations

import json
import math
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from ...record.atomic import atomic_write_text, savefig
from ..batch import (
    set_dotted,
)
from ..executor import Executor
from .cost import evaluate_candidate
from .spec import TuneSpec


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
    cp = _plot_convergence(spec, res, log_stats, out / "convergence.png")
    header, table = _before_after(spec, res, before, after)
    from ..batch import print_table

    print_table(header, table, f"default vs tuned gains ({spec.metric.upper()}, same scenarios)")
    bp = out / "before_after.md"
    atomic_write_text(bp, _before_after_md(spec, res, executor, header, table))
    jp = out / "tune.json"
    atomic_write_text(jp, json.dumps(_tune_json(spec, res, executor, log_stats, after),
                                     indent=2))
    res.files = [gp, cp, bp, jp]
    res.before_after = table


def _plot_convergence(spec: TuneSpec, res: TuneResult, log_stats: list[dict[str, Any]],
                      path: Path) -> Path:
    """convergence.png: the best so far, each generation's best and median, the default."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

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
    savefig(fig, path, dpi=110)
    plt.close(fig)
    return path


def _before_after(spec: TuneSpec, res: TuneResult, before: dict[str, Any],
                  after: dict[str, Any]) -> tuple[list[str], list[list[str]]]:
    """The default vs tuned table: the gains, each scenario's cost parts, the total."""
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
    return header, table


def _before_after_md(spec: TuneSpec, res: TuneResult, executor: Executor, header: list[str],
                     table: list[list[str]]) -> str:
    """before_after.md: the settings, the default vs tuned table, the validation."""
    from ..batch import markdown_table

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
    return "\n".join(md)


def _tune_json(spec: TuneSpec, res: TuneResult, executor: Executor,
               log_stats: list[dict[str, Any]], after: dict[str, Any]) -> dict[str, Any]:
    """tune.json's content."""
    keys = [p.key for p in spec.params]
    return {
        "name": spec.name, "best": dict(zip(keys, res.best_values, strict=True)),
        "best_cost": res.best_cost, "default": dict(zip(keys, res.default_values, strict=True)),
        "default_cost": res.default_cost, "history": res.history,
        "iterations": log_stats, "wall_s": res.wall_s, "executor": executor.name,
        "engine_fallbacks": res.n_fallback, "noise_seeds": spec.seeds,
        "validation_seeds": spec.validation_seeds, "validation": res.validation,
        "shipped": dict(zip(keys, res.shipped_values, strict=True)),
        "shipped_tune_cost": float(after["cost"]),
        "shipped_validation_cost": res.validation_cost if res.validation else None}


def _validation_table(res: TuneResult) -> tuple[list[str], list[list[str]]]:
    header = ["rank (tuning)", "tuning cost", "validation cost", "shipped"]
    rows = [[str(i + 1), f"{v['tune_cost']:.4g}", f"{v['validation_cost']:.4g}",
             "yes" if i == res.shipped else ""] for i, v in enumerate(res.validation)]
    return header, rows


def _print_validation(spec: TuneSpec, res: TuneResult) -> None:
    from ..batch import print_table

    print_table(*_validation_table(res), f"validation: the {len(res.validation)} best "
                f"candidates on held-out seeds {spec.validation_seeds} (tuning seeds "
                f"{spec.seeds})")


def _f4(v: Any) -> str:
    if v is None:
        return "-"
    if isinstance(v, float):
        return "inf" if math.isinf(v) else f"{v:.4g}"
    return str(v)
