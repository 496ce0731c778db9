"""``ag-uav experiment controllers``: does interval type-2 earn its keep in flight?

PID, the type-1 fuzzy PID (T1-FPID) and the IT2-FPID with each type reducer (KM, NT, BMM,
zeta), each tuned by the same BB-BC budget and cost (``examples/tune_*.toml``, one spec per
controller; the results ship as ``examples/controller_*.toml``), fly the default mission
(1.05 ha field, 14 legs, ~485 s of sim time) under two conditions:

- ``nominal``: 3 m/s mean wind from 240° with light Dryden turbulence (as tuned) and GPS noise:
  the ``rtk`` preset with the PCA-MCKF estimator in the loop (only the flown filter, no shadow
  filters, so that the flights fit the time budget);
- ``model-error`` (one combined perturbation the tuning never saw): payload +30 % of the dry
  mass, motor time constant ×2 and mean wind ×2 (6 m/s), same GPS and estimator.

Every controller flies the same seeds (``--seed0`` .. ``--seed0 + --runs - 1``; the tuning used
seed 0 and no GPS noise), so each seed's wind and GPS draws are common to all controllers and the
comparisons are paired. The flights go through the batch machinery
(:func:`ag_uav.jobs.batch.run_batch` on a process pool or Dask; ``--resume`` continues an
interrupted run).

Scores per flight (from the run summary): horizontal tracking RMSE, cross-track RMSE on the
spray legs, spray coverage, and motor effort (RMS rate of the rotor-thrust commands, N/s).
Tables: mean ± 95 % Student-t half-width per controller and condition, and paired differences of
every fuzzy controller against T1-FPID and against PID (mean of the per-seed difference with its
95 % t-interval; a difference is called only when the interval excludes zero).

Writes ``results.csv`` (one row per flight), ``controllers.md`` and ``controllers.csv``,
``controllers_box.png`` (distributions) and ``controllers_paired.png`` (paired differences) in
``--out``.
"""

from __future__ import annotations

import argparse
import math
from pathlib import Path
from typing import Any

NAME = "controllers"
HELP = ("PID vs T1-FPID vs IT2-FPID (KM, NT, BMM, zeta), each BB-BC tuned, on the default mission "
        "under wind + GPS noise and under unseen model error; paired over seeds")

#: controller label -> preset file (in --presets)
CONTROLLERS = {
    "PID": "controller_pid.toml",
    "T1-FPID": "controller_t1.toml",
    "IT2-KM": "controller_it2_km.toml",
    "IT2-NT": "controller_it2_nt.toml",
    "IT2-BMM": "controller_it2_bmm.toml",
    "IT2-zeta": "controller_it2_zeta.toml",
}
DRY_MASS_KG = 6.47
MOTOR_TAU_S = 0.04
WIND_MPS = 3.0
#: conditions: name -> config fragment (dotted keys) on top of the base
CONDITIONS: dict[str, dict[str, Any]] = {
    "nominal": {},
    "model-error": {"vehicle.payload_kg": round(0.3 * DRY_MASS_KG, 4),
                    "vehicle.motor_tau_s": 2.0 * MOTOR_TAU_S,
                    "wind.speed_mps": 2.0 * WIND_MPS},
}
#: (column, label, scale, format, lower is better)
METRICS = (
    ("tracking_rmse_m", "tracking RMSE (m)", 1.0, "{:.4f}", True),
    ("cross_track_rmse_m", "cross-track RMSE (m)", 1.0, "{:.4f}", True),
    ("coverage_fraction", "coverage (%)", 100.0, "{:.2f}", False),
    ("motor_rate_rms_nps", "motor effort (N/s)", 1.0, "{:.2f}", True),
)


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--runs", type=int, default=30, help="seeds per controller and condition")
    p.add_argument("--seed0", type=int, default=100, help="first seed")
    p.add_argument("--controllers", default=",".join(CONTROLLERS),
                   help="comma-separated labels (" + ", ".join(CONTROLLERS) + ")")
    p.add_argument("--conditions", default=",".join(CONDITIONS),
                   help="comma-separated conditions (" + ", ".join(CONDITIONS) + ")")
    p.add_argument("--presets", default="examples", metavar="DIR",
                   help="folder holding the controller_*.toml presets")
    p.add_argument("--tunings", type=int, default=0, metavar="N",
                   help="first tune every controller N times (optimiser seeds 1..N, the specs "
                        "in --tune-specs; resumable) and fly each one's median tuning (by "
                        "held-out validation cost) instead of the --presets")
    p.add_argument("--tune-specs", default="examples", metavar="DIR",
                   help="folder holding the tune_*.toml specs (with --tunings)")
    p.add_argument("--no-fly", action="store_true",
                   help="with --tunings: the campaign only (tables, plot, presets), no flights")
    p.add_argument("--gps-preset", default="rtk", help="GPS noise preset")
    p.add_argument("--estimator", default="pca-mckf", help="estimator flown on (no shadows)")
    from . import add_batch_arguments

    add_batch_arguments(p, "runs/experiment-controllers")


def _split(s: str, allowed: dict[str, Any], what: str) -> list[str]:
    from ...config import ConfigError

    out = [x.strip() for x in s.split(",") if x.strip()]
    for x in out:
        if x not in allowed:
            raise ConfigError(f"--{what} = {x!r}: allowed: {', '.join(allowed)}")
    if not out:
        raise ConfigError(f"--{what}: give at least one")
    return out


def build_spec(args: argparse.Namespace):
    """The batch spec: condition × controller × seed over the experiment's base config."""
    from ...config import ConfigError, parse_set_items
    from ..batch import spec_from_dict

    if args.runs < 2:
        raise ConfigError(f"--runs = {args.runs}: must be >= 2 (paired intervals)")
    if args.seed0 < 0:
        raise ConfigError(f"--seed0 = {args.seed0}: must be >= 0")
    ctrls = _split(args.controllers, CONTROLLERS, "controllers")
    conds = _split(args.conditions, CONDITIONS, "conditions")
    pdir = Path(args.presets)
    for c in ctrls:
        if not (pdir / CONTROLLERS[c]).is_file():
            raise ConfigError(f'--presets = "{pdir}": no {CONTROLLERS[c]} (preset of {c})')
    base: dict[str, Any] = {"gps.preset": args.gps_preset, "estimator.name": args.estimator,
                            "estimator.shadow": [], "wind.speed_mps": WIND_MPS,
                            "wind.turbulence": "light", "log.enabled": False}
    base.update(parse_set_items(args.set))
    presets = {"controller": {c: {"config": str((pdir / CONTROLLERS[c]).resolve())}
                              for c in ctrls},
               "condition": {k: dict(CONDITIONS[k]) for k in conds}}
    return spec_from_dict({"name": "controllers", "base": base, "presets": presets,
                           "axes": {"condition": conds, "controller": ctrls,
                                    "seed": list(range(args.seed0, args.seed0 + args.runs))}},
                          base_dir=Path.cwd()), ctrls, conds


def _ok(r: dict[str, Any]) -> bool:
    return r.get("status") == "ok"


def _val(r: dict[str, Any], col: str) -> float | None:
    from ..batch import _num

    return _num(r.get(col))


def paired(rows: list[dict[str, Any]], cond: str, a: str, b: str, col: str
           ) -> tuple[float, float, float, int, int]:
    """Paired difference a − b of ``col`` over the seeds both flew without a crash.

    Returns (mean difference, 95 % t half-width, mean of b, n pairs, seeds where a is better)."""
    from ..batch import mean_ci

    lower_better = next(m[4] for m in METRICS if m[0] == col)
    by = {}
    for r in rows:
        if r.get("condition") == cond and _ok(r):
            by.setdefault(r.get("controller"), {})[r.get("seed")] = _val(r, col)
    ra, rb = by.get(a, {}), by.get(b, {})
    seeds = [s for s in ra if s in rb and ra[s] is not None and rb[s] is not None]
    d = [ra[s] - rb[s] for s in seeds]
    m, h, n = mean_ci(d)
    mb = sum(rb[s] for s in seeds) / len(seeds) if seeds else math.nan
    better = sum((x < 0) if lower_better else (x > 0) for x in d)
    return m, h, mb, n, better


def summary(rows: list[dict[str, Any]], ctrls: list[str], conds: list[str]
            ) -> tuple[list[str], list[list[str]], list[dict[str, Any]]]:
    from ..batch import mean_ci

    header = ["condition", "controller", "runs", "crashed"] + [m[1] for m in METRICS]
    lines, recs = [], []
    for cond in conds:
        for c in ctrls:
            rs = [r for r in rows if r.get("condition") == cond and r.get("controller") == c]
            ok = [r for r in rs if _ok(r)]
            line = [cond, c, str(len(rs)), str(len(rs) - len(ok))]
            rec: dict[str, Any] = {"condition": cond, "controller": c, "runs": len(rs),
                                   "crashed": len(rs) - len(ok)}
            for col, _, scale, fmt, _ in METRICS:
                m, h, n = mean_ci(_val(r, col) for r in ok)
                rec[col] = m * scale
                rec[col + "_ci95"] = h * scale
                line.append("–" if n == 0 else fmt.format(m * scale) if math.isnan(h)
                            else f"{fmt.format(m * scale)} ± {fmt.format(h * scale)}")
            lines.append(line)
            recs.append(rec)
    return header, lines, recs


def paired_table(rows: list[dict[str, Any]], ctrls: list[str], conds: list[str]
                 ) -> tuple[list[str], list[list[str]], list[dict[str, Any]]]:
    """Every fuzzy controller against T1-FPID and against PID, per condition and metric."""
    header = ["condition", "controller", "vs"] + [m[1] for m in METRICS]
    lines, recs = [], []
    refs = [r for r in ("T1-FPID", "PID") if r in ctrls]
    for cond in conds:
        for ref in refs:
            for c in ctrls:
                if c == ref or c == "PID":
                    continue
                line = [cond, c, ref]
                for col, _, _, _, lower in METRICS:
                    m, h, mb, n, better = paired(rows, cond, c, ref, col)
                    if n < 2 or not math.isfinite(h) or mb == 0:
                        line.append("–")
                        continue
                    pct, hp = 100.0 * m / mb, 100.0 * h / abs(mb)
                    sig = ""
                    if abs(m) > h:
                        sig = " better" if (m < 0) == lower else " worse"
                    nd = 3 if col == "coverage_fraction" else 1  # coverage differs by ~0.01 %
                    line.append(f"{pct:+.{nd}f} ± {hp:.{nd}f} %{sig} ({better}/{n})")
                    recs.append({"condition": cond, "controller": c, "vs": ref, "metric": col,
                                 "diff": m, "diff_ci95": h, "ref_mean": mb, "pct": pct,
                                 "pct_ci95": hp, "n": n, "better": better})
                lines.append(line)
    return header, lines, recs


def plot_box(rows: list[dict[str, Any]], ctrls: list[str], conds: list[str], path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axs = plt.subplots(len(conds), len(METRICS), figsize=(3.4 * len(METRICS),
                                                              2.9 * len(conds)), squeeze=False)
    for i, cond in enumerate(conds):
        for j, (col, label, scale, _, _) in enumerate(METRICS):
            ax = axs[i, j]
            data = []
            for c in ctrls:
                v = [x * scale for r in rows if r.get("condition") == cond
                     and r.get("controller") == c and _ok(r) and (x := _val(r, col)) is not None]
                data.append(v or [math.nan])
            ax.boxplot(data, showmeans=True, widths=0.6)
            ax.set_xticks(range(1, len(ctrls) + 1), ctrls, rotation=45, fontsize=7)
            ax.set_title(f"{cond}: {label}", fontsize=8)
            ax.tick_params(axis="y", labelsize=7)
            ax.grid(alpha=0.3)
    fig.tight_layout()
    fig.savefig(path, dpi=90)
    plt.close(fig)


def plot_paired(recs: list[dict[str, Any]], conds: list[str], path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    refs = sorted({r["vs"] for r in recs}, reverse=True)
    fig, axs = plt.subplots(len(refs), len(METRICS), figsize=(3.4 * len(METRICS),
                                                              2.9 * max(1, len(refs))),
                            squeeze=False)
    for i, ref in enumerate(refs):
        for j, (col, label, _, _, _) in enumerate(METRICS):
            ax = axs[i, j]
            rs = [r for r in recs if r["vs"] == ref and r["metric"] == col]
            names = list(dict.fromkeys(r["controller"] for r in rs))
            for k, cond in enumerate(conds):
                for n_i, name in enumerate(names):
                    r = next((x for x in rs if x["controller"] == name
                              and x["condition"] == cond), None)
                    if r is None:
                        continue
                    y = n_i + (k - (len(conds) - 1) / 2) * 0.25
                    ax.errorbar(r["pct"], y, xerr=r["pct_ci95"], fmt="o", ms=3, capsize=2,
                                color=f"C{k}", label=cond if n_i == 0 else None)
            ax.axvline(0, color="k", lw=0.8)
            ax.set_yticks(range(len(names)), names, fontsize=7)
            ax.set_title(f"{label} vs {ref} (%)", fontsize=8)
            ax.tick_params(axis="x", labelsize=7)
            ax.grid(alpha=0.3)
            if i == 0 and j == 0:
                ax.legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(path, dpi=90)
    plt.close(fig)


def main(args: argparse.Namespace) -> int:
    import csv
    import time

    from ...config import ConfigError
    from ..batch import expand, markdown_table, print_table, run_batch
    from ..executor import make_executor

    if args.resume and args.fresh:
        raise ConfigError("--resume and --fresh: choose one")
    out = Path(args.out)
    if args.tunings:
        from .controller_tunings import TUNE_SPECS, campaign

        if args.tunings < 1:
            raise ConfigError(f"--tunings = {args.tunings}: must be >= 1")
        labels = [c for c in _split(args.controllers, CONTROLLERS, "controllers")
                  if c in TUNE_SPECS]
        with make_executor(args.workers, args.dask) as ex:
            presets, _rows, wall = campaign(labels, args.tunings, Path(args.tune_specs), out, ex)
        print(f"campaign: {wall:.0f} s (this call); presets in {presets}")
        if args.no_fly:
            return 0
        args.presets = str(presets)
    spec, ctrls, conds = build_spec(args)
    tasks = expand(spec)
    out.mkdir(parents=True, exist_ok=True)
    t0 = time.perf_counter()
    with make_executor(args.workers, args.dask) as ex:
        res = run_batch(spec, out, ex, resume=args.resume, fresh=args.fresh,
                        progress=not args.quiet, report=False, tasks=tasks)
    wall = time.perf_counter() - t0
    rows = res.rows
    header, lines, recs = summary(rows, ctrls, conds)
    title = (f"controllers: {args.runs} seeds × {len(ctrls)} controllers × {len(conds)} "
             f"conditions ({len(rows)} flights, {res.n_run} flown now in {wall:.0f} s on "
             f"{res.executor})")
    print_table(header, lines, title)
    ph, pl, precs = paired_table(rows, ctrls, conds)
    print_table(ph, pl, "paired differences (controller − reference) / reference mean, "
                        "95 % t-interval; (seeds where better / pairs)")
    with (out / "controllers.csv").open("w", newline="") as f:
        w = csv.DictWriter(f, fieldnames=list(recs[0]))
        w.writeheader()
        w.writerows(recs)
    plot_box(rows, ctrls, conds, out / "controllers_box.png")
    if precs:
        plot_paired(precs, conds, out / "controllers_paired.png")
    me = CONDITIONS["model-error"]
    md = ["# Controllers: PID vs T1-FPID vs IT2-FPID in flight", "",
          f"- {len(rows)} flights of the default mission: {args.runs} seeds "
          f"({args.seed0}..{args.seed0 + args.runs - 1}, common to every controller) × "
          f"{len(ctrls)} controllers × {len(conds)} conditions",
          f"- every condition: GPS `{args.gps_preset}` with `{args.estimator}` in the loop (no "
          f"shadow filters), {WIND_MPS:g} m/s mean wind from 240° + light Dryden turbulence",
          f"- `model-error` (never seen by the tuning): payload {me['vehicle.payload_kg']} kg "
          f"(+30 % of {DRY_MASS_KG} kg), motor τ {me['vehicle.motor_tau_s']} s (×2), mean wind "
          f"{me['wind.speed_mps']:g} m/s (×2), all at once",
          "- presets: " + ", ".join(f"{c} `{CONTROLLERS[c]}`" for c in ctrls),
          f"- wall time: {wall:.0f} s on {res.executor} ({res.n_run} flown now, "
          f"{res.n_skipped} resumed)",
          "- mean ± 95 % Student-t half-width over the flights that did not crash; motor effort "
          "= RMS rate of the rotor-thrust commands on the spray part (N/s)", "",
          markdown_table(header, lines),
          "Paired differences (controller − reference, per seed; % of the reference's mean, "
          "± 95 % t-interval; \"better\"/\"worse\" only where the interval excludes zero; "
          "in brackets: seeds where the controller is better / pairs):", "",
          markdown_table(ph, pl),
          "![distributions](controllers_box.png)", "",
          "![paired differences](controllers_paired.png)", ""]
    (out / "controllers.md").write_text("\n".join(md))
    print(f"wrote {out / 'results.csv'}, {out / 'controllers.md'}, {out / 'controllers.csv'}, "
          f"{out / 'controllers_box.png'}, {out / 'controllers_paired.png'}")
    return 0
