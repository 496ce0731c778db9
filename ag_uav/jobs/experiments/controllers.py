"""``ag-uav experiment controllers``: which controller should the vehicle ship, and does
interval type-2 earn its keep in flight?

PID, the type-1 fuzzy PID (T1-FPID) and the IT2-FPID with each type reducer (KM, NT, BMM,
zeta), each tuned by the same BB-BC budget and cost on the realistic loop
(``examples/tune_*.toml``: the default navigation chain, GNSS preset and turbulence, several
noise seeds per candidate, held-out validation; ``--tunings N`` first tunes every controller N
times and flies each one's median tuning, see :mod:`.controller_tunings`), plus the controls
that separate the type-2 *shape* from the *gain level*: ``T1@KM`` .. ``T1@zeta``, the type-1
FPID at each IT2 variant's linearised gains (:func:`t1_at_linearised`), fly the default mission
(1.05 ha field, ~485 s of sim time) under four conditions:

- ``nominal``: 3 m/s mean wind from 240° with light Dryden turbulence (as tuned) on the default
  navigation chain (INS/GNSS with the default estimator and GNSS preset; only the flown filter,
  no shadow filters, so that the flights fit the time budget);
- ``unknown-model-error`` (never seen by the tuning, never told to the controller): 1.0 kg the
  controller's model leaves out (``vehicle.unknown_payload_kg``) sitting off-centre at
  (0.15, 0.10, 0) m, which moves the centre of gravity by ~2 cm, with the tank at 1.7 L so
  that the take-off mass stays 9.17 kg (the M350's maximum take-off mass is 9.2 kg; the
  controller believes 8.17 kg), motor time constant ×2 and mean wind ×2 (6 m/s);
- ``motor-failure``: the front-right rotor delivers 25 % less thrust than commanded
  (``vehicle.rotor_thrust_loss``; the controller does not know), nominal wind;
- ``weak-rotor``: the same weak rotor as the autopilot meets it, with the failure detector and
  response on (``vehicle.rotor_fault``: rotor 0 keeps 75 % of its thrust from take-off,
  ``response = "auto"``; :mod:`ag_uav.engine.rotor_fault`), nominal wind.

Every controller flies the same seeds (``--seed0`` .. ``--seed0 + --runs - 1``, disjoint from the
tuning and validation seeds), so each seed's wind and GNSS draws are common to all controllers
and the comparisons are paired. The flights go through the batch machinery
(:func:`ag_uav.jobs.batch.run_batch`; ``--resume`` continues an interrupted run).

Scores per flight (from the run summary): horizontal tracking RMSE and cross-track RMSE on the
spray legs (mm), motor effort (RMS rate of the rotor-thrust commands, N/s), and the dose on the
ground: its coefficient of variation and the under-dosed fraction of the field (%). Tables: mean
± 95 % Student-t half-width per controller and condition; paired differences (per seed, 95 %
t-interval; called only when the interval excludes zero) of every controller against the winner
and against T1-FPID, and of each IT2 variant against its type-1 control.

The verdict (:func:`verdict`): a controller that lost a flight in any flown condition (the
failing motor included) is out; in each judged condition (``nominal``, ``unknown-model-error``)
the remaining controllers whose tracking RMSE is not worse than the best remaining one's (paired
interval) qualify; among those that qualify in both, the simplest (PID, then type-1, then
type-2) wins, ties broken by the mean tracking RMSE over the judged conditions.

Writes ``results.csv`` (one row per flight), ``controllers.md``, ``controllers.csv``,
``verdict.json``, ``controllers_box.png`` and ``controllers_paired.png`` in ``--out``.
"""

from __future__ import annotations

import argparse
import math
from pathlib import Path
from typing import Any

NAME = "controllers"
HELP = ("PID vs T1-FPID vs IT2-FPID (KM, NT, BMM, zeta) and type-1 at the IT2 linearised gains, "
        "median of N BB-BC tunings each, nominal / unknown model error / failing motor / weak "
        "rotor with the failure response; paired over seeds; the verdict picks the default")

#: controller label -> preset file (in --presets)
CONTROLLERS = {
    "PID": "controller_pid.toml",
    "T1-FPID": "controller_t1.toml",
    "IT2-KM": "controller_it2_km.toml",
    "IT2-NT": "controller_it2_nt.toml",
    "IT2-BMM": "controller_it2_bmm.toml",
    "IT2-zeta": "controller_it2_zeta.toml",
}
#: shape-vs-gain controls: label -> the IT2 controller whose linearised gains the type-1 flies
CONTROLS = {"T1@KM": "IT2-KM", "T1@NT": "IT2-NT", "T1@BMM": "IT2-BMM", "T1@zeta": "IT2-zeta"}
ALL = [*CONTROLLERS, *CONTROLS]
#: simplicity rank (the verdict's tie-break): PID, then type-1 (also the controls), then type-2
SIMPLICITY = {"PID": 0, "T1-FPID": 1, **dict.fromkeys(CONTROLS, 1)}
MOTOR_TAU_S = 0.04
WIND_MPS = 3.0
MTOW_KG = 9.2  # DJI M350 RTK maximum take-off mass
#: conditions: name -> config fragment (dotted keys) on top of the base
CONDITIONS: dict[str, dict[str, Any]] = {
    "nominal": {},
    "unknown-model-error": {"vehicle.unknown_payload_kg": 1.0,
                            "vehicle.unknown_payload_pos_m": [0.15, 0.10, 0.0],
                            "spray.tank_l": 1.7,
                            "vehicle.motor_tau_s": 2.0 * MOTOR_TAU_S,
                            "wind.speed_mps": 2.0 * WIND_MPS},
    "motor-failure": {"vehicle.rotor_thrust_loss": [0.25, 0.0, 0.0, 0.0]},
    "weak-rotor": {"vehicle.rotor_fault.rotor": 0, "vehicle.rotor_fault.at_s": 0.0,
                   "vehicle.rotor_fault.efficiency": 0.75, "vehicle.rotor_fault.response": "auto"},
}
#: the conditions the verdict judges (the failing or weak motor is reported beside them)
JUDGED = ("nominal", "unknown-model-error")
#: (column, label, scale, format, lower is better)
METRICS = (
    ("tracking_rmse_m", "tracking RMSE (mm)", 1000.0, "{:.1f}", True),
    ("cross_track_rmse_m", "cross-track RMSE (mm)", 1000.0, "{:.1f}", True),
    ("motor_rate_rms_nps", "motor effort (N/s)", 1.0, "{:.2f}", True),
    ("dose_cv", "dose CV (%)", 100.0, "{:.2f}", True),
    ("underdosed_fraction", "under-dosed area (%)", 100.0, "{:.2f}", True),
)


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--runs", type=int, default=15, help="seeds per controller and condition")
    p.add_argument("--seed0", type=int, default=100, help="first seed (the tuning uses 1-3, its "
                   "validation 11-16)")
    p.add_argument("--controllers", default=",".join(ALL),
                   help="comma-separated labels (" + ", ".join(ALL) + "); T1@X needs X")
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
    p.add_argument("--tuning-flights", type=int, default=0, metavar="K",
                   help="with --tunings: also fly every tuning (not only the picks) on K seeds "
                        "of the nominal condition: the spread of the flown tracking across "
                        "tunings (OUT/every-tuning, tunings_flown.md)")
    p.add_argument("--gps-preset", default=None, help="GPS noise preset (default: the config's)")
    p.add_argument("--estimator", default=None,
                   help="GNSS estimator flown on (default: the config's; no shadows)")
    from . import add_batch_arguments

    add_batch_arguments(p, "runs/experiment-controllers")


def _split(s: str, allowed: dict[str, Any] | list[str], what: str) -> list[str]:
    from ...config import ConfigError

    out = [x.strip() for x in s.split(",") if x.strip()]
    for x in out:
        if x not in allowed:
            raise ConfigError(f"--{what} = {x!r}: allowed: {', '.join(allowed)}")
    if not out:
        raise ConfigError(f"--{what}: give at least one")
    return out


def t1_at_linearised(it2: dict[str, Any]) -> dict[str, Any]:
    """The type-1 FPID with the linearised gains of the IT2-FPID preset ``it2`` (a config dict
    with ``[controller]``).

    Near the origin a fuzzy PID is the PID (:func:`controllers.fpid.equivalent_pid`)
    ``Kp = K0 Ke G_E + K1 Kd G_dE, Ki = K1 Ke G_E, Kd = K0 Kd G_dE`` with ``G`` the core's
    small-signal slope; the type-1 core's slope is its ``c_m``. So the type-1 with the IT2's
    ``Ke, Kd, K0, K1`` and ``c_m = G_IT2`` (the IT2 core's slope at the origin, central
    differences: :meth:`controllers.fpid.IT2FPID.small_signal_gains`) has the very same
    linearisation; only the shape away from the origin differs. Where ``G_IT2 > 1`` (beyond the
    type-1's ``c_m`` range) ``c_m = 1`` and ``K0, K1`` are scaled by ``G_IT2``, which keeps
    ``Kp, Ki, Kd``."""
    from controllers.fpid import IT2FPID

    c = it2["controller"]
    out: dict[str, Any] = {"controller": {"type": "t1-fpid"}}
    for ax in ("xy", "z"):
        g = {k: v for k, v in c.get(ax, {}).items()}
        ctl = IT2FPID(g["ke"], g["kd"], g["k0"], g["k1"], alpha=g["alpha"], cm=g["cm"],
                      reducer=g["reducer"], zeta=g.get("zeta", 0.5))
        ge, gde = ctl.small_signal_gains()
        slope = 0.5 * (ge + gde)  # equal heights on both inputs: G_E = G_dE
        t1 = {"ke": g["ke"], "kd": g["kd"], "k0": g["k0"], "k1": g["k1"], "cm": slope}
        if slope > 1.0:
            t1.update(cm=1.0, k0=g["k0"] * slope, k1=g["k1"] * slope)
        if "i_limit" in g:
            t1["i_limit"] = g["i_limit"]
        out["controller"][ax] = {k: float(f"{v:.6g}") for k, v in t1.items()}
    return out


def write_controls(pdir: Path, labels: list[str], dest: Path) -> dict[str, Path]:
    """The T1@X presets of ``labels`` (from ``pdir``'s IT2 presets), written to ``dest``."""
    import tomllib

    import tomli_w

    from ...config import ConfigError

    dest.mkdir(parents=True, exist_ok=True)
    paths = {}
    for label in labels:
        src = pdir / CONTROLLERS[CONTROLS[label]]
        if not src.is_file():
            raise ConfigError(f'--presets = "{pdir}": no {src.name} (preset of '
                              f"{CONTROLS[label]}, whose linearised gains {label} flies)")
        d = t1_at_linearised(tomllib.loads(src.read_text()))
        p = dest / f"controller_t1_at_{CONTROLS[label].split('-', 1)[1].lower()}.toml"
        p.write_text(f"# {label}: type-1 FPID at the linearised gains of {src}\n"
                     + tomli_w.dumps(d))
        paths[label] = p
    return paths


def build_spec(args: argparse.Namespace):
    """The batch spec: condition × controller × seed over the experiment's base config."""
    from ...config import ConfigError, parse_set_items
    from ..batch import spec_from_dict

    if args.runs < 2:
        raise ConfigError(f"--runs = {args.runs}: must be >= 2 (paired intervals)")
    if args.seed0 < 20:
        raise ConfigError(f"--seed0 = {args.seed0}: must be >= 20 (seeds below are the "
                          "tuning's and its validation's)")
    ctrls = _split(args.controllers, ALL, "controllers")
    conds = _split(args.conditions, CONDITIONS, "conditions")
    pdir = Path(args.presets)
    paths = {}
    for c in ctrls:
        if c in CONTROLLERS:
            if not (pdir / CONTROLLERS[c]).is_file():
                raise ConfigError(f'--presets = "{pdir}": no {CONTROLLERS[c]} (preset of {c})')
            paths[c] = (pdir / CONTROLLERS[c]).resolve()
    paths.update({k: v.resolve() for k, v in write_controls(
        pdir, [c for c in ctrls if c in CONTROLS], Path(args.out) / "controls").items()})
    base: dict[str, Any] = {"estimator.shadow": [], "wind.speed_mps": WIND_MPS,
                            "wind.turbulence": "light", "log.enabled": False}
    if args.gps_preset:
        base["gps.preset"] = args.gps_preset
    if args.estimator:
        base["estimator.name"] = args.estimator
    base.update(parse_set_items(args.set))
    presets = {"controller": {c: {"config": str(paths[c])} for c in ctrls},
               "condition": {k: dict(CONDITIONS[k]) for k in conds}}
    return spec_from_dict({"name": "controllers", "base": base, "presets": presets,
                           "axes": {"condition": conds, "controller": ctrls,
                                    "seed": list(range(args.seed0, args.seed0 + args.runs))}},
                          base_dir=Path.cwd()), ctrls, conds


def _ok(r: dict[str, Any]) -> bool:
    return r.get("status") == "ok"


def _val(r: dict[str, Any], col: str) -> float | None:
    from ..batch import as_number

    return as_number(r.get(col))


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


def paired_table(rows: list[dict[str, Any]], ctrls: list[str], conds: list[str],
                 winner: str | None = None
                 ) -> tuple[list[str], list[list[str]], list[dict[str, Any]]]:
    """Paired differences per condition and metric: every controller against the winner and
    against T1-FPID, and each IT2 variant against its type-1 control (shape vs gain)."""
    header = ["condition", "controller", "vs"] + [m[1] for m in METRICS]
    pairs: list[tuple[str, str]] = []
    for ref in dict.fromkeys(r for r in (winner, "T1-FPID") if r in ctrls):
        pairs += [(c, ref) for c in ctrls if c != ref]
    pairs += [(it2, t1) for t1, it2 in CONTROLS.items() if t1 in ctrls and it2 in ctrls]
    lines, recs = [], []
    for cond in conds:
        for c, ref in pairs:
            line = [cond, c, ref]
            for col, _, scale, fmt, lower in METRICS:
                m, h, mb, n, better = paired(rows, cond, c, ref, col)
                if n < 2 or not math.isfinite(h):
                    line.append("–")
                    continue
                sig = ""
                if abs(m) > h:
                    sig = " better" if (m < 0) == lower else " worse"
                pct = 100.0 * m / mb if mb else math.nan
                line.append(f"{fmt.format(m * scale)} ± {fmt.format(h * scale)}{sig} "
                            f"({pct:+.1f} %, {better}/{n})")
                recs.append({"condition": cond, "controller": c, "vs": ref, "metric": col,
                             "diff": m * scale, "diff_ci95": h * scale,
                             "ref_mean": mb * scale, "pct": pct,
                             "pct_ci95": 100.0 * h / abs(mb) if mb else math.nan, "n": n,
                             "better": better})
            lines.append(line)
    return header, lines, recs


def verdict(rows: list[dict[str, Any]], ctrls: list[str], conds: list[str],
            col: str = "tracking_rmse_m") -> tuple[str | None, list[str]]:
    """The winner and the reasoning (lines), see the module docstring.

    A default must not lose the vehicle: a controller that lost a flight in any flown condition
    (the failing motor included) is out. In each judged condition (:data:`JUDGED`) the
    remaining controllers whose ``col`` is not worse than the best remaining one's (paired 95 %
    interval) qualify; among those qualifying in every judged condition the simplest wins, then
    the lowest mean ``col`` over the judged conditions."""
    judged = [c for c in JUDGED if c in conds]
    lost = {c: [cond for cond in conds if any(
        r.get("condition") == cond and r.get("controller") == c and not _ok(r) for r in rows)]
        for c in ctrls}
    live = [c for c in ctrls if not lost[c]]
    why = ["lost flights (out): " + ("; ".join(f"{c} in {', '.join(v)}" for c, v in lost.items()
                                                if v) or "none")]
    if not live:
        return None, [*why, "every controller lost flights; no verdict"]
    ok_all, means = set(live), dict.fromkeys(live, 0.0)
    for cond in judged:
        mean = {}
        for c in live:
            v = [x for r in rows if r.get("condition") == cond and r.get("controller") == c
                 and (x := _val(r, col)) is not None]
            mean[c] = sum(v) / len(v) if v else math.inf
            means[c] += mean[c]
        best = min(live, key=lambda c: mean[c])
        qual = {best}
        for c in live:
            m, h, _, n, _ = paired(rows, cond, c, best, col)
            if c != best and n >= 2 and math.isfinite(h) and m - h <= 0.0:  # not worse
                qual.add(c)
        why.append(f"{cond}: best {best} ({mean[best] * 1000:.1f} mm); not worse than it: "
                   + ", ".join(c for c in live if c in qual))
        ok_all &= qual
    if not ok_all:
        return None, [*why, "no controller qualifies in every judged condition"]
    win = min(ok_all, key=lambda c: (SIMPLICITY.get(c, 2), means[c]))
    why.append(f"qualify in {' and '.join(judged)}: {', '.join(c for c in live if c in ok_all)}"
               f"; the simplest (then lowest mean) wins: {win}")
    return win, why


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
            labelled: set[str] = set()
            for k, cond in enumerate(conds):
                for n_i, name in enumerate(names):
                    r = next((x for x in rs if x["controller"] == name
                              and x["condition"] == cond), None)
                    if r is None:
                        continue
                    y = n_i + (k - (len(conds) - 1) / 2) * 0.25
                    ax.errorbar(r["pct"], y, xerr=r["pct_ci95"], fmt="o", ms=3, capsize=2,
                                color=f"C{k}", label=None if cond in labelled else cond)
                    labelled.add(cond)
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
    import json
    import time

    from ...config import ConfigError
    from ..batch import BatchOptions, expand, print_table, run_batch
    from ..executor import make_executor

    if args.resume and args.fresh:
        raise ConfigError("--resume and --fresh: choose one")
    out = Path(args.out)
    if args.tunings:
        from .controller_tunings import TUNE_SPECS, campaign

        if args.tunings < 1:
            raise ConfigError(f"--tunings = {args.tunings}: must be >= 1")
        labels = [c for c in _split(args.controllers, ALL, "controllers") if c in TUNE_SPECS]
        with make_executor(args.workers, args.dask) as ex:
            presets, trows, wall = campaign(labels, args.tunings, Path(args.tune_specs), out, ex)
            print(f"campaign: {wall:.0f} s (this call); presets in {presets}")
            if args.tuning_flights:
                _fly_every_tuning(args, trows, out, ex)
        if args.no_fly:
            return 0
        args.presets = str(presets)
    spec, ctrls, conds = build_spec(args)
    tasks = expand(spec)
    out.mkdir(parents=True, exist_ok=True)
    t0 = time.perf_counter()
    with make_executor(args.workers, args.dask) as ex:
        res = run_batch(spec, out, ex, BatchOptions(
            resume=args.resume, fresh=args.fresh, progress=not args.quiet, report=False),
            tasks=tasks)
    wall = time.perf_counter() - t0
    rows = res.rows
    header, lines, recs = summary(rows, ctrls, conds)
    title = (f"controllers: {args.runs} seeds × {len(ctrls)} controllers × {len(conds)} "
             f"conditions ({len(rows)} flights, {res.n_run} flown now in {wall:.0f} s on "
             f"{res.executor})")
    print_table(header, lines, title)
    win, why = verdict(rows, ctrls, conds)
    ph, pl, precs = paired_table(rows, ctrls, conds, win)
    print_table(ph, pl, "paired differences (controller − reference, per seed; 95 % "
                        "t-interval; (% of the reference, seeds where better / pairs))")
    print("verdict: " + "\n  ".join(why))
    from . import write_csv

    write_csv(out / "controllers.csv", recs)
    (out / "verdict.json").write_text(json.dumps({"winner": win, "why": why,
                                                  "paired": precs}, indent=1))
    plot_box(rows, ctrls, conds, out / "controllers_box.png")
    if precs:
        plot_paired([r for r in precs if r["vs"] in (win, "T1-FPID")], conds,
                    out / "controllers_paired.png")
    (out / "controllers.md").write_text(_report(args, ctrls, conds, rows, res, wall,
                                                (header, lines), (ph, pl), why))
    print(f"wrote {out / 'results.csv'}, {out / 'controllers.md'}, {out / 'controllers.csv'}, "
          f"{out / 'verdict.json'}, {out / 'controllers_box.png'}, "
          f"{out / 'controllers_paired.png'}")
    return 0


def _fly_every_tuning(args: argparse.Namespace, trows: list[dict[str, Any]], out: Path,
                      ex: Any) -> None:
    """``--tuning-flights K``: every tuning flown on K nominal seeds (see
    :func:`.controller_tunings.fly_every_tuning`); prints and writes ``tunings_flown.md``."""
    import time

    from ...config import parse_set_items
    from ..batch import markdown_table, print_table
    from . import write_csv
    from .controller_tunings import fly_every_tuning

    base: dict[str, Any] = {"estimator.shadow": [], "wind.speed_mps": WIND_MPS,
                            "wind.turbulence": "light", "log.enabled": False,
                            **parse_set_items(args.set)}
    seeds = list(range(args.seed0, args.seed0 + args.tuning_flights))
    t0 = time.perf_counter()
    h, lines, recs = fly_every_tuning(trows, Path(args.tune_specs), out, ex, seeds, base)
    title = (f"every tuning flown: nominal, seeds {seeds[0]}..{seeds[-1]} "
             f"({time.perf_counter() - t0:.0f} s this call)")
    print_table(h, lines, title)
    write_csv(out / "tunings_flown.csv", recs)
    (out / "tunings_flown.md").write_text(f"# {title}\n\n{markdown_table(h, lines)}\n")


def _report(args: argparse.Namespace, ctrls: list[str], conds: list[str], rows: list[Any],
            res: Any, wall: float, table: tuple, ptable: tuple, why: list[str]) -> str:
    from ..batch import markdown_table

    me = CONDITIONS["unknown-model-error"]
    md = ["# Controllers: PID vs T1-FPID vs IT2-FPID in flight", "",
          f"- {len(rows)} flights of the default mission: {args.runs} seeds "
          f"({args.seed0}..{args.seed0 + args.runs - 1}, common to every controller) × "
          f"{len(ctrls)} controllers × {len(conds)} conditions",
          f"- every condition: the default navigation chain (no shadow filters), {WIND_MPS:g} "
          "m/s mean wind from 240° + light Dryden turbulence",
          f"- `unknown-model-error`: {me['vehicle.unknown_payload_kg']} kg unknown to the "
          f"controller at {me['vehicle.unknown_payload_pos_m']} m, tank "
          f"{me['spray.tank_l']} L (take-off 9.17 kg ≤ {MTOW_KG} kg), motor τ "
          f"{me['vehicle.motor_tau_s']} s (×2), mean wind {me['wind.speed_mps']:g} m/s (×2)",
          "- `motor-failure`: rotor thrust loss "
          f"{CONDITIONS['motor-failure']['vehicle.rotor_thrust_loss']} (fr, fl, rl, rr)",
          "- `weak-rotor`: rotor 0 (fr) keeps 75 % of its thrust from take-off, the failure "
          "detector and response on (`vehicle.rotor_fault`, response `auto`)",
          f"- presets: `{args.presets}`; T1@X: type-1 at X's linearised gains",
          f"- wall time: {wall:.0f} s on {res.executor} ({res.n_run} flown now, "
          f"{res.n_skipped} resumed)",
          "- mean ± 95 % Student-t half-width over the flights that did not crash", "",
          markdown_table(*table),
          "Paired differences (controller − reference, per seed, ± 95 % t-interval; "
          "\"better\"/\"worse\" only where the interval excludes zero; in brackets: % of the "
          "reference's mean, seeds where the controller is better / pairs):", "",
          markdown_table(*ptable), "Verdict:", "", *[f"- {w}" for w in why], "",
          "![distributions](controllers_box.png)", "",
          "![paired differences](controllers_paired.png)", ""]
    return "\n".join(md)
