"""``ag-uav experiment optimisers``: BB-BC, PSO and CMA-ES at an equal evaluation budget.

One tuning problem (default: ``examples/tune.toml``'s — its parameters, bounds, scenarios, cost,
noise seed and default gains in the first population) is tuned by each optimiser
(:mod:`controllers.optim`: :class:`~controllers.optim.BBBC`, :class:`~controllers.optim.PSO`,
:class:`~controllers.optim.CMAES`) with ``--seeds`` optimiser seeds (``seed0``, ``seed0 + 1``, ...;
the same seeds for every optimiser), every tuning with the same budget ``pop × iters``
evaluations. Each tuning is an ordinary :func:`~ag_uav.jobs.tune.run_tune` in its own folder
(``OUT/runs/<optimizer>-s<seed>/``, checkpointed, so ``--resume`` continues an interrupted
experiment), its candidates flown through the tuner's engine batches on the executor. The
spec's ``optimizer_options`` are kept for the spec's own optimizer; the others run with their
defaults (PSO: Clerc–Kennedy constants; CMA-ES: σ₀ = 0.3 of the box).

From each tuning's iteration log: the best-so-far cost after ``k·pop`` evaluations. Per
optimiser: median and min–max over seeds of the final best cost; evaluations to reach within
5 % of the best cost any tuning found (median over seeds; a tuning that never gets there counts
as not reached); the Mann–Whitney U test (two-sided) of the final costs against BB-BC's; the
median wall time of a tuning.

Writes (``--out``): ``optimisers.csv`` (one row per tuning and iteration), ``optimisers.md``
(the table) and ``optimisers.png`` (median best-so-far against evaluations, min–max band).
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import math
from pathlib import Path
from typing import Any

import numpy as np

NAME = "optimisers"
HELP = ("BB-BC, PSO and CMA-ES on the same tuning problem at an equal evaluation budget over "
        "several optimiser seeds: best-so-far cost against evaluations, table and plot")
OPTIMISERS = ("bbbc", "pso", "cmaes")
LABEL = {"bbbc": "BB-BC", "pso": "PSO", "cmaes": "CMA-ES"}
WITHIN = 0.05  # "reached": best-so-far <= (1 + WITHIN) x the best cost any tuning found


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--spec", default="examples/tune.toml", metavar="SPEC.toml",
                   help="the tuning problem (a tune spec; its optimizer, pop, iters and seed "
                        "are replaced)")
    p.add_argument("--optimizers", default=",".join(OPTIMISERS),
                   help="comma-separated, from " + ", ".join(OPTIMISERS))
    p.add_argument("--pop", type=int, default=10, help="population size of every optimiser")
    p.add_argument("--iters", type=int, default=30, help="iterations of every tuning")
    p.add_argument("--seeds", type=int, default=5, help="optimiser seeds per optimiser")
    p.add_argument("--seed0", type=int, default=1, help="first optimiser seed")
    p.add_argument("--out", default="runs/experiment-optimisers", help="output folder")
    p.add_argument("--workers", "-j", type=int, default=None,
                   help="worker processes (default: CPU count)")
    p.add_argument("--dask", default=None, metavar="ADDR", help='"local" or tcp://host:port')
    p.add_argument("--resume", action="store_true", help="continue an interrupted run")
    p.add_argument("--fresh", action="store_true", help="discard an earlier run in --out")
    p.add_argument("--quiet", "-q", action="store_true", help="no progress bars")


def _check(args: argparse.Namespace) -> list[str]:
    from ...config import ConfigError

    opts = [o.strip() for o in args.optimizers.split(",") if o.strip()]
    bad = [o for o in opts if o not in OPTIMISERS]
    if bad or not opts:
        raise ConfigError(f"--optimizers = {args.optimizers!r}: allowed: {', '.join(OPTIMISERS)}")
    if args.pop < (4 if "cmaes" in opts else 2):
        raise ConfigError(f"--pop = {args.pop}: must be >= 4 (CMA-ES) or >= 2")
    for k in ("iters", "seeds"):
        if getattr(args, k) < 1:
            raise ConfigError(f"--{k} = {getattr(args, k)}: must be >= 1")
    if args.resume and args.fresh:
        raise ConfigError("--resume and --fresh: choose one")
    return opts


def tune_one(spec: Any, opt: str, seed: int, out: Path, ex: Any,
             args: argparse.Namespace) -> list[dict[str, Any]]:
    """One tuning of ``spec`` by ``opt`` with optimiser seed ``seed``; its iteration log as
    rows (evaluations so far, best-so-far cost, generation min/median, wall time)."""
    from ..tune import run_tune

    oo = spec.optimizer_options if opt == spec.optimizer else {}
    sp = dataclasses.replace(spec, optimizer=opt, optimizer_options=dict(oo), pop=args.pop,
                             iters=args.iters, seed=seed)
    d = out / "runs" / f"{opt}-s{seed}"
    resume = args.resume and (d / "checkpoint.json").exists()
    run_tune(sp, d, ex, resume=resume, fresh=args.fresh or not resume,
             progress=not args.quiet, outputs=False)
    its = json.loads((d / "checkpoint.json").read_text())["iterations"]
    return [{"optimizer": opt, "seed": seed, "iteration": s["iteration"],
             "evaluations": s["iteration"] * args.pop, "best_so_far": s["best_so_far"],
             "gen_min": s["gen_min"], "gen_median": s["gen_median"], "crashes": s["crashes"],
             "wall_s": s["wall_s"]} for s in its[:args.iters]]


def curves(rows: list[dict[str, Any]], opt: str) -> tuple[np.ndarray, np.ndarray]:
    """(evaluations, best-so-far per seed × iteration) of one optimiser."""
    seeds = sorted({r["seed"] for r in rows if r["optimizer"] == opt})
    by = {s: [r for r in rows if r["optimizer"] == opt and r["seed"] == s] for s in seeds}
    evals = np.array([r["evaluations"] for r in by[seeds[0]]])
    return evals, np.array([[r["best_so_far"] for r in by[s]] for s in seeds])


def evals_to_reach(evals: np.ndarray, best: np.ndarray, target: float) -> list[float]:
    """Per seed: the first evaluation count whose best-so-far is <= target (inf: never)."""
    out = []
    for b in best:
        hit = np.nonzero(b <= target)[0]
        out.append(float(evals[hit[0]]) if hit.size else math.inf)
    return out


def summary(rows: list[dict[str, Any]], opts: list[str]) -> tuple[list[str], list[list[str]],
                                                                  float]:
    """The table (header, lines) and the best cost any tuning found."""
    from scipy.stats import mannwhitneyu

    finals = {o: curves(rows, o)[1][:, -1] for o in opts}
    overall = min(float(f.min()) for f in finals.values())
    target = overall * (1.0 + WITHIN) if overall > 0 else overall + WITHIN * abs(overall)
    header = ["optimiser", "seeds", "final best: median", "min–max", "evals to ≤ best +5 %: "
              "median", "reached", "Mann–Whitney p vs BB-BC", "wall / tuning (s): median"]
    lines = []
    for o in opts:
        ev, best = curves(rows, o)
        reach = evals_to_reach(ev, best, target)
        med = float(np.median(reach))
        walls = [sum(r["wall_s"] for r in rows if r["optimizer"] == o and r["seed"] == s)
                 for s in sorted({r["seed"] for r in rows if r["optimizer"] == o})]
        p = "—"
        if o != "bbbc" and "bbbc" in finals:
            p = f"{mannwhitneyu(finals[o], finals['bbbc'], alternative='two-sided').pvalue:.3f}"
        f = finals[o]
        lines.append([LABEL[o], str(f.size), f"{np.median(f):.4g}",
                      f"{f.min():.4g}–{f.max():.4g}",
                      f"{med:.0f}" if math.isfinite(med) else f"> {ev[-1]}",
                      f"{sum(map(math.isfinite, reach))}/{len(reach)}", p,
                      f"{np.median(walls):.1f}"])
    return header, lines, overall


def plot(rows: list[dict[str, Any]], opts: list[str], path: Path, title: str) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from ...record.atomic import savefig

    fig, ax = plt.subplots(figsize=(7.0, 4.2))
    for o, c in zip(opts, ("tab:blue", "tab:orange", "tab:green"), strict=False):
        ev, best = curves(rows, o)
        ax.fill_between(ev, best.min(0), best.max(0), color=c, alpha=0.18, lw=0)
        ax.plot(ev, np.median(best, 0), color=c, lw=2,
                label=f"{LABEL[o]} (median, min–max of {best.shape[0]} seeds)")
    ax.set_xlabel("evaluations")
    ax.set_ylabel("best-so-far cost")
    ax.set_title(title, fontsize=10)
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8)
    fig.tight_layout()
    savefig(fig, path, dpi=120)
    plt.close(fig)


def main(args: argparse.Namespace) -> int:
    import time

    from ..batch import markdown_table, print_table
    from ..executor import make_executor
    from ..tune import load_spec
    from . import write_csv

    opts = _check(args)
    spec = load_spec(args.spec)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    seeds = list(range(args.seed0, args.seed0 + args.seeds))
    rows: list[dict[str, Any]] = []
    t0 = time.perf_counter()
    with make_executor(args.workers, args.dask) as ex:
        for seed in seeds:  # seed-major: an interrupted run has every optimiser's early seeds
            for o in opts:
                rows += tune_one(spec, o, seed, out, ex, args)
                if not args.quiet:
                    print(f"{o} seed {seed}: best {rows[-1]['best_so_far']:.6g}")
        where = ex.name
    wall = time.perf_counter() - t0
    rows.sort(key=lambda r: (opts.index(r["optimizer"]), r["seed"], r["iteration"]))
    header, lines, overall = summary(rows, opts)
    budget = args.pop * args.iters
    title = (f"optimisers on {spec.name}: {budget} evaluations ({args.pop} × {args.iters}) × "
             f"{args.seeds} seeds each")
    print_table(header, lines, title)
    write_csv(out / "optimisers.csv", rows)
    plot(rows, opts, out / "optimisers.png", title)
    md = [f"# Optimisers: {', '.join(LABEL[o] for o in opts)} at an equal budget", "",
          f"- problem: `{args.spec}` ({len(spec.params)} parameters, "
          f"{len(spec.scenarios)} scenarios, noise seed {spec.noise_seed}, metric "
          f"{spec.metric}; default gains in every first population: {spec.include_default})",
          f"- budget: population {args.pop} × {args.iters} iterations = {budget} evaluations "
          f"per tuning; optimiser seeds {seeds[0]}..{seeds[-1]} for each optimiser",
          f"- best cost any tuning found: {overall:.6g}; \"reached\": best-so-far ≤ that "
          f"+{WITHIN:.0%}",
          f"- wall time: {wall:.0f} s in all on {where}", "",
          markdown_table(header, lines), "![best-so-far](optimisers.png)", ""]
    (out / "optimisers.md").write_text("\n".join(md))
    print(f"wrote {out / 'optimisers.csv'}, {out / 'optimisers.md'}, {out / 'optimisers.png'} "
          f"in {wall:.0f} s")
    return 0
