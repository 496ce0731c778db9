"""The tuning campaign of ``ag-uav experiment controllers --tunings N``: every controller tuned
N times (optimiser seeds 1..N) with the same spec and budget, and the median tuning picked.

Each controller's spec is ``examples/tune_*.toml`` (:data:`TUNE_SPECS`; the realistic loop:
default navigation chain, GNSS preset and turbulence, several noise seeds per candidate, held-out
validation of the best candidates, see :mod:`ag_uav.jobs.tune`). Tuning ``k`` of a controller is
that spec with ``seed = k``, an ordinary :func:`~ag_uav.jobs.tune.run_tune` in
``OUT/tunings/LABEL/seedK`` (its own checkpoint and evaluation journal), so that a killed
campaign resumes: a tuning whose ``tune.json`` holds its validation is finished and skipped, an
unfinished one resumes from its checkpoint.

The pick: each controller's tuning of median *validation* cost (the held-out seeds; the lower
median for an even count), so that the comparison flies a typical tuning, not a lucky one.
Writes ``tunings.csv`` (one row per tuning), ``tunings.md`` (the spread table),
``tunings.png`` (tuning and validation cost of every tuning) and ``presets/controller_*.toml``
(the picked gains, the presets the comparison flies).
"""

from __future__ import annotations

import json
import math
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

#: controller label -> (tune spec, preset file name)
TUNE_SPECS = {
    "PID": ("tune_pid.toml", "controller_pid.toml"),
    "T1-FPID": ("tune_t1.toml", "controller_t1.toml"),
    "IT2-KM": ("tune_it2_km.toml", "controller_it2_km.toml"),
    "IT2-NT": ("tune_it2_nt.toml", "controller_it2_nt.toml"),
    "IT2-BMM": ("tune_it2_bmm.toml", "controller_it2_bmm.toml"),
    "IT2-zeta": ("tune_it2_zeta.toml", "controller_it2_zeta.toml"),
}


def tuning_dir(out: Path, label: str, seed: int) -> Path:
    return out / "tunings" / label / f"seed{seed}"


def finished(d: Path) -> dict[str, Any] | None:
    """The ``tune.json`` of a finished tuning (outputs written, validation done), else None."""
    p = d / "tune.json"
    if not p.is_file():
        return None
    try:
        rec = json.loads(p.read_text())
    except (OSError, json.JSONDecodeError):
        return None
    return rec if rec.get("shipped_validation_cost") is not None else None


def run_campaign(labels: list[str], seeds: list[int], spec_dir: Path, out: Path, executor: Any,
                 say: Callable[[str], None] = print) -> list[dict[str, Any]]:
    """Tune every controller of ``labels`` once per optimiser seed (resumably); one row per
    tuning: label, seed, tuning and validation cost of the shipped gains, wall time, gains."""
    from ..tune import load_spec, run_tune

    rows = []
    for label in labels:
        spec_file = spec_dir / TUNE_SPECS[label][0]
        for seed in seeds:
            d = tuning_dir(out, label, seed)
            rec = finished(d)
            if rec is None:
                spec = load_spec(spec_file)
                spec.seed = seed
                t0 = time.perf_counter()
                run_tune(spec, d, executor, resume=True, progress=False)
                rec = finished(d)
                assert rec is not None, f"{d}: tuning left no validation"
                # the whole tuning (optimisation, validation, outputs) as this call measured it
                (d / "wall_total_s.txt").write_text(f"{time.perf_counter() - t0:.1f}\n")
                say(f"tuned {label} seed {seed}: tuning cost {rec['shipped_tune_cost']:.4g}, "
                    f"validation {rec['shipped_validation_cost']:.4g} "
                    f"({time.perf_counter() - t0:.0f} s)")
            else:
                say(f"tuned {label} seed {seed}: finished earlier (skipped)")
            rows.append({"controller": label, "seed": seed, "spec": str(spec_file),
                         "tune_cost": rec["shipped_tune_cost"],
                         "validation_cost": rec["shipped_validation_cost"],
                         "best_tune_cost": rec["best_cost"], "default_cost": rec["default_cost"],
                         "wall_s": _wall_total(d, rec), "gains": rec["shipped"]})
    return rows


def _wall_total(d: Path, rec: dict[str, Any]) -> float:
    """Wall time of the whole tuning (optimisation + validation + outputs) when one call ran
    it all, else the optimisation's own (``tune.json``)."""
    try:
        return float((d / "wall_total_s.txt").read_text())
    except (OSError, ValueError):
        return float(rec["wall_s"])


def median_pick(rows: list[dict[str, Any]]) -> dict[str, dict[str, Any]]:
    """Each controller's tuning of median validation cost (lower median for an even count;
    ties broken by the seed)."""
    by: dict[str, list[dict[str, Any]]] = {}
    for r in rows:
        by.setdefault(r["controller"], []).append(r)
    out = {}
    for label, rs in by.items():
        ranked = sorted(rs, key=lambda r: (r["validation_cost"], r["seed"]))
        out[label] = ranked[(len(ranked) - 1) // 2]
    return out


def preset_toml(label: str, row: dict[str, Any], base: dict[str, Any]) -> str:
    """The picked tuning as a controller preset (``[controller]`` type/reducer + gains)."""
    import tomli_w

    from ..batch import set_dotted

    d: dict[str, Any] = {}
    for k, v in base.items():
        if k.startswith("controller."):
            set_dotted(d, k, v)
    for k, v in row["gains"].items():
        set_dotted(d, k, float(f"{v:.4g}"))
    head = (f"# {label}: the median (by held-out validation cost) of the tunings of "
            f"{Path(row['spec']).name}\n# (optimiser seed {row['seed']}: tuning cost "
            f"{row['tune_cost']:.4g}, validation cost {row['validation_cost']:.4g}; "
            "gains rounded to 4 significant digits).\n# ag-uav experiment controllers --tunings "
            "5 --workers 2\n")
    return head + tomli_w.dumps(d)


def write_presets(picks: dict[str, dict[str, Any]], spec_dir: Path, dest: Path) -> None:
    from ...record.atomic import atomic_write_text
    from ..tune import load_spec

    dest.mkdir(parents=True, exist_ok=True)
    for label, row in picks.items():
        spec = load_spec(spec_dir / TUNE_SPECS[label][0])
        flat = _flat(spec.base)
        atomic_write_text(dest / TUNE_SPECS[label][1], preset_toml(label, row, flat))


def _flat(d: dict[str, Any], pre: str = "") -> dict[str, Any]:
    out: dict[str, Any] = {}
    for k, v in d.items():
        if isinstance(v, dict):
            out.update(_flat(v, f"{pre}{k}."))
        else:
            out[pre + k] = v
    return out


def spread_table(rows: list[dict[str, Any]], picks: dict[str, dict[str, Any]]
                 ) -> tuple[list[str], list[list[str]]]:
    header = ["controller", "tunings", "tuning cost: median [min, max]",
              "validation cost: median [min, max]", "spread (max/min − 1, validation)",
              "picked (seed: tuning / validation)", "wall per tuning (s)"]
    lines = []
    for label, pick in picks.items():
        rs = [r for r in rows if r["controller"] == label]
        tc = sorted(r["tune_cost"] for r in rs)
        vc = sorted(r["validation_cost"] for r in rs)
        wall = sorted(r["wall_s"] for r in rs)
        lines.append([label, str(len(rs)), _mmm(tc), _mmm(vc),
                      f"{100 * (vc[-1] / vc[0] - 1):.1f} %" if vc[0] > 0 else "–",
                      f"{pick['seed']}: {pick['tune_cost']:.4g} / {pick['validation_cost']:.4g}",
                      f"{_median(wall):.0f} [{wall[0]:.0f}, {wall[-1]:.0f}]"])
    return header, lines


def _median(v: list[float]) -> float:
    n = len(v)
    return (v[n // 2] if n % 2 else 0.5 * (v[n // 2 - 1] + v[n // 2])) if n else math.nan


def _mmm(v: list[float]) -> str:
    return f"{_median(v):.4g} [{v[0]:.4g}, {v[-1]:.4g}]"


def plot_spread(rows: list[dict[str, Any]], picks: dict[str, dict[str, Any]], path: Path
                ) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    labels = list(picks)
    fig, ax = plt.subplots(figsize=(7.5, 3.6))
    for i, label in enumerate(labels):
        rs = [r for r in rows if r["controller"] == label]
        ax.plot([i - 0.12] * len(rs), [r["tune_cost"] for r in rs], "o", ms=4, color="C0",
                label="tuning cost (tuning seeds)" if i == 0 else None)
        ax.plot([i + 0.12] * len(rs), [r["validation_cost"] for r in rs], "s", ms=4,
                color="C1", label="validation cost (held-out seeds)" if i == 0 else None)
        ax.plot([i + 0.12], [picks[label]["validation_cost"]], "k*", ms=10,
                label="picked (median)" if i == 0 else None)
    ax.set_xticks(range(len(labels)), labels, fontsize=8)
    ax.set_ylabel("cost (ISE + effort)")
    ax.set_title("every tuning of every controller (optimiser seeds)", fontsize=10)
    ax.grid(alpha=0.3)
    ax.legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)


def campaign(labels: list[str], n: int, spec_dir: Path, out: Path, executor: Any,
             say: Callable[[str], None] = print) -> tuple[Path, list[dict[str, Any]], float]:
    """Run (or resume) the campaign, write its tables and plot and the picked presets; returns
    the presets folder, the rows and the wall time of this call."""
    from ..batch import markdown_table, print_table
    from . import write_csv

    t0 = time.perf_counter()
    rows = run_campaign(labels, list(range(1, n + 1)), spec_dir, out, executor, say)
    wall = time.perf_counter() - t0
    picks = median_pick(rows)
    write_csv(out / "tunings.csv", [{k: v for k, v in r.items() if k != "gains"}
                                    | {f"gain:{k}": v for k, v in r["gains"].items()}
                                    for r in rows])
    header, lines = spread_table(rows, picks)
    total = sum(r["wall_s"] for r in rows)
    title = (f"tuning spread: {n} tunings per controller (optimiser seeds 1..{n}); "
             f"{total:.0f} s of tuning in all")
    print_table(header, lines, title)
    plot_spread(rows, picks, out / "tunings.png")
    presets = out / "presets"
    write_presets(picks, spec_dir, presets)
    (out / "tunings.md").write_text("\n".join([
        f"# {title}", "", markdown_table(header, lines), "![tunings](tunings.png)", ""]))
    return presets, rows, wall


def fly_every_tuning(rows: list[dict[str, Any]], spec_dir: Path, out: Path, executor: Any,
                     seeds: list[int], base: dict[str, Any], *, resume: bool = True
                     ) -> tuple[list[str], list[list[str]], list[dict[str, Any]]]:
    """Every tuning of the campaign flown on the whole mission (``base``: the experiment's
    nominal condition) on ``seeds``, a batch in ``OUT/every-tuning``: how far apart the
    *flown* results of one controller's tunings are. One table row per controller: the
    tracking RMSE (mm, mean over the seeds) of each tuning, median [min, max], and the picked
    tuning's."""
    from ..batch import BatchOptions, mean_ci, run_batch, spec_from_dict

    d = out / "every-tuning"
    pdir = d / "presets"
    pdir.mkdir(parents=True, exist_ok=True)
    presets = {}
    for r in rows:
        label = f"{r['controller']}#{r['seed']}"
        spec = load_spec_cached(spec_dir / TUNE_SPECS[r["controller"]][0])
        p = pdir / f"{r['controller']}_seed{r['seed']}.toml"
        p.write_text(preset_toml(r["controller"], r, _flat(spec.base)))
        presets[label] = {"config": str(p.resolve())}
    bspec = spec_from_dict({"name": "every-tuning", "base": base,
                            "presets": {"controller": presets},
                            "axes": {"controller": list(presets), "seed": seeds}},
                           base_dir=Path.cwd())
    res = run_batch(bspec, d, executor, BatchOptions(resume=resume, progress=False,
                                                      report=False))
    picks = median_pick(rows)
    header = ["controller", "tracking RMSE (mm) per tuning: median [min, max]",
              "spread (max − min, mm)", "picked tuning (mm)", "crashed flights"]
    lines, recs = [], []
    for label in picks:
        per = {}
        crashed = 0
        for r in rows:
            if r["controller"] != label:
                continue
            fl = [x for x in res.rows if x.get("controller") == f"{label}#{r['seed']}"]
            # a flight cut by sim.max_time_s (``base``'s window) measured its tracking; any
            # other status (crashed, failsafe, error, ...) is counted, not averaged
            crashed += sum(x.get("status") not in ("ok", "cut") for x in fl)
            m, _, n = mean_ci(x.get("tracking_rmse_m") for x in fl
                              if x.get("status") in ("ok", "cut"))
            per[r["seed"]] = 1000.0 * m if n else math.nan
            recs.append({"controller": label, "seed": r["seed"], "tracking_mm": per[r["seed"]],
                         "validation_cost": r["validation_cost"], "flights": len(fl)})
        v = sorted(x for x in per.values() if math.isfinite(x))
        lines.append([label, f"{_median(v):.1f} [{v[0]:.1f}, {v[-1]:.1f}]" if v else "–",
                      f"{v[-1] - v[0]:.1f}" if v else "–",
                      f"{per[picks[label]['seed']]:.1f}", str(crashed)])
    return header, lines, recs


_SPECS: dict[Path, Any] = {}


def load_spec_cached(path: Path) -> Any:
    from ..tune import load_spec

    if path not in _SPECS:
        _SPECS[path] = load_spec(path)
    return _SPECS[path]
