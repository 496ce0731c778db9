"""``ag-uav experiment ins-nav``: the measurements of issue 19 phase 2 (docs/ins.md).

``--what``:

* ``recovery``: MCKF's lock-out recovery (none / inflate / kf) × kernel σ (1, 2, 4, 10⁶ ≈ ∞)
  in the loop, false-fix episodes on (``--set`` raises their rate so that short missions hold
  some); per rule the horizontal position error RMS over the mission, mean ± 95 % CI over
  seeds;
* ``consistency``: the NEES of the 15-state error per rule on the ``rtk`` preset (no fix
  types, so no fix-quality episodes) against the 95 % band of χ²(15);
* ``outage``: a forced ``--duration`` s GNSS outage 2 s into the first long sweep leg, flown on
  the KF: the INS (``nav = ins``) against the ideal-attitude stand-in; drift of the estimate at
  the end of the outage, peak estimate error and peak cross-track inside it;
* ``falsefix``: the in-loop table with false fixes on: per rule the position error RMS, and the
  paired difference to the KF (mean ± 95 % CI over seeds);
* ``sweep``: the MCKF kernel in the loop, false fixes on (30 per hour of RTK fixed unless
  ``--set`` says otherwise): the fixed kernel at each σ of ``--sigmas`` (``inf``: every weight
  1, the KF), then each variant of ``--kernels`` (``estimator.mckf_kernel``) at σ = 2; per
  setting the KF's position error RMS and the paired MCKF − KF and PCA-MCKF − KF differences
  (mean ± 95 % CI over seeds).  σ = ∞ is set on the config object directly (the config file
  takes finite σ only).

Every flight of a seed gets the same fixes (common random numbers); the shadows share the
flown filter's fixes and IMU samples.
"""

from __future__ import annotations

import argparse
from pathlib import Path
from typing import Any

NAME = "ins-nav"
HELP = ("issue 19 measurements: MCKF recovery × σ, NEES consistency, a GNSS outage with the "
        "INS vs the ideal-attitude stand-in, the false-fix in-loop table, the MCKF kernel sweep")
RULES = ("pca-mckf", "kf", "mckf", "pca-kf")


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--what", choices=("recovery", "consistency", "outage", "falsefix", "sweep"),
                   required=True)
    p.add_argument("--sigmas", default="1,2,4,8,inf", help="sweep: fixed-kernel σ values")
    p.add_argument("--kernels", default="adaptive,multi",
                   help="sweep: estimator.mckf_kernel variants flown at σ = 2")
    p.add_argument("--runs", type=int, default=10, help="seeds 0..runs-1")
    p.add_argument("--duration", type=float, default=10.0, help="outage length (s)")
    p.add_argument("--max-time", type=float, default=None, help="sim.max_time_s")
    p.add_argument("--out", default="runs/experiment-ins-nav", help="output folder")
    p.add_argument("--set", action="append", default=[], metavar="KEY=VALUE",
                   help="config override for every flight (repeatable)")


def _base(args: argparse.Namespace, extra: dict[str, Any]) -> Any:
    from ...config import load_config, parse_set_items

    cfg = load_config(None, {**extra, **parse_set_items(args.set)})
    cfg.log.enabled = False
    cfg.log.render = False
    if args.max_time:
        cfg.sim.max_time_s = args.max_time
    return cfg


def _fly(cfg: Any, seed: int, **over: Any) -> dict[str, Any]:
    import copy

    from ...engine.missions import simulate

    c = copy.deepcopy(cfg)
    c.seed = seed
    for k, v in over.items():
        sec, key = k.split(".")
        setattr(getattr(c, sec), key, v)
    return simulate(c).summary


def _ci(vals: list[float]) -> str:
    from ..batch import mean_ci

    m, h, n = mean_ci(vals)
    return f"{m:.4f} ± {h:.4f}" if n > 1 else f"{m:.4f}"


def recovery(args: argparse.Namespace) -> list[dict[str, Any]]:
    cfg = _base(args, {"gps.false_fix_per_hour": 60.0})
    rows = []
    for rec in ("none", "inflate", "kf"):
        for sig in (1.0, 2.0, 4.0, 1e6):
            for seed in range(args.runs):
                s = _fly(cfg, seed, **{"estimator.ins_recovery": rec, "estimator.sigma": sig})
                rows.append({"recovery": rec, "sigma": sig, "seed": seed,
                             "false_fixes": s.get("false_fix_fixes"),
                             **{r: s["estimators"][r]["estimate_rmse_m"] for r in RULES}})
            sel = [r for r in rows if r["recovery"] == rec and r["sigma"] == sig]
            print(f"recovery={rec:8s} sigma={sig:g}: " + "  ".join(
                f"{r} {_ci([x[r] for x in sel])}" for r in RULES), flush=True)
    return rows


def consistency(args: argparse.Namespace) -> list[dict[str, Any]]:
    cfg = _base(args, {"gps.preset": "rtk"})
    rows = []
    for seed in range(args.runs):
        s = _fly(cfg, seed)
        rows.append({"seed": seed, **{f"{r}.nees15": s["estimators"][r]["nees15_mean"]
                                      for r in RULES},
                     **{f"{r}.nis": s["estimators"][r]["nis_mean"] for r in RULES},
                     **{f"{r}.nees_pos": s["estimators"][r]["nees_pos_mean"] for r in RULES},
                     **{f"{r}.rmse": s["estimators"][r]["estimate_rmse_m"] for r in RULES},
                     "band": s["estimators"]["kf"]["nees15_band95"],
                     "updates": s["estimators"]["kf"]["updates"]})
    from scipy.stats import chi2

    n = sum(r["updates"] for r in rows)
    lo, hi = chi2.ppf(0.025, 15 * n) / n, chi2.ppf(0.975, 15 * n) / n
    for r in RULES:
        v = [x[f"{r}.nees15"] for x in rows]
        print(f"{r}: mean NEES15 over {len(rows)} seeds {_ci(v)} (95 % band of the mean over "
              f"{n} updates {lo:.2f}-{hi:.2f}); NIS {_ci([x[f'{r}.nis'] for x in rows])}; "
              f"NEES pos (3) {_ci([x[f'{r}.nees_pos'] for x in rows])}; RMSE "
              f"{_ci([x[f'{r}.rmse'] for x in rows])}")
    return rows


def outage(args: argparse.Namespace) -> list[dict[str, Any]]:
    import numpy as np

    from ...engine.missions import simulate
    from ...navigation.route import RouteConstrainedFeedback, outage_cross_track
    from .outage import leg_outage

    cfg = _base(args, {"estimator.name": "kf", "estimator.shadow": ["mckf"],
                       "gps.receiver": "ideal"})
    window = leg_outage(cfg, duration_s=args.duration)
    cfg.sim.max_time_s = window[1] + 5.0
    rows = []
    for seed in range(args.runs):
        for nav in ("ins", "ideal-attitude"):
            import copy

            c = copy.deepcopy(cfg)
            c.seed, c.estimator.nav = seed, nav
            if nav == "ins":
                from ...engine import missions as M

                prep = M._prepare(c, None, None, None)
                prep.fb.outages = [window]
                out = M.fly([prep.flight])[0]
                res = M._finish(prep, out, 1)
                herr = prep.fb.rec["herr"][:, 0]
            else:
                fb = RouteConstrainedFeedback.for_config(c, primary=None, outages=[window])
                res = simulate(c, feedback=fb)
                est = np.asarray(fb.est["kf"], dtype=float).reshape(-1, 3)
                full = np.full((len(res.t), 3), np.nan)
                full[len(res.t) - len(est):] = est[-len(res.t):]
                herr = np.hypot(*(full[:, :2] - res.p_true[:, :2]).T)
            sel = (res.t >= window[0]) & (res.t < window[1])
            sc = outage_cross_track(res, window)
            rows.append({"seed": seed, "nav": nav, "crashed": res.summary["crashed"],
                         "drift_end_m": float(herr[sel][-1]),
                         "peak_estimate_error_m": float(np.nanmax(herr[sel])), **sc})
        for nav in ("ins", "ideal-attitude"):
            sel = [r for r in rows if r["nav"] == nav]
            print(f"{nav}: drift at the end {_ci([r['drift_end_m'] for r in sel])}, peak "
                  f"estimate error {_ci([r['peak_estimate_error_m'] for r in sel])}, peak "
                  f"cross-track {_ci([r['peak_cross_track_m'] for r in sel])}", flush=True)
    print(f"window {window[0]:.1f}-{window[1]:.1f} s")
    return rows


def falsefix(args: argparse.Namespace) -> list[dict[str, Any]]:
    cfg = _base(args, {})
    rows = []
    for seed in range(args.runs):
        s = _fly(cfg, seed)
        rows.append({"seed": seed, "false_fix_episodes": s.get("false_fix_episodes"),
                     "false_fixes": s.get("false_fix_fixes"),
                     "cross_track_rmse_m": s.get("cross_track_rmse_m"),
                     **{r: s["estimators"][r]["estimate_rmse_m"] for r in RULES},
                     **{f"{r}.max": s["estimators"][r]["estimate_max_m"] for r in RULES}})
    for r in RULES:
        d = [x[r] - x["kf"] for x in rows]
        print(f"{r}: RMSE {_ci([x[r] for x in rows])} m, max {_ci([x[r + '.max'] for x in rows])}"
              f" m, paired − kf {_ci(d)} m")
    print(f"episodes per run {[x['false_fix_episodes'] for x in rows]}")
    return rows


def sweep(args: argparse.Namespace) -> list[dict[str, Any]]:
    cfg = _base(args, {"gps.false_fix_per_hour": 30.0})
    settings = [("fixed", float(x)) for x in args.sigmas.split(",") if x.strip()]
    settings += [(k.strip(), 2.0) for k in args.kernels.split(",") if k.strip()]
    rows = []
    for kernel, sig in settings:
        for seed in range(args.runs):
            s = _fly(cfg, seed, **{"estimator.mckf_kernel": kernel, "estimator.sigma": sig})
            e = s["estimators"]
            rows.append({"kernel": kernel, "sigma": sig, "seed": seed,
                         "false_fix_episodes": s.get("false_fix_episodes"),
                         "cross_track_rmse_m": s.get("cross_track_rmse_m"),
                         **{r: e[r]["estimate_rmse_m"] for r in RULES},
                         **{f"{r}.max": e[r]["estimate_max_m"] for r in RULES}})
        sel = [r for r in rows if r["kernel"] == kernel and r["sigma"] == sig]
        print(f"kernel={kernel:8s} sigma={sig:g}: kf {_ci([x['kf'] for x in sel])} m; " +
              "  ".join(f"{r} − kf {_ci([x[r] - x['kf'] for x in sel])}"
                        for r in ("mckf", "pca-mckf", "pca-kf")) +
              f"; cross-track {_ci([x['cross_track_rmse_m'] for x in sel])}", flush=True)
    return rows


def main(args: argparse.Namespace) -> int:
    from . import write_csv

    rows = {"recovery": recovery, "consistency": consistency, "outage": outage,
            "falsefix": falsefix, "sweep": sweep}[args.what](args)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    write_csv(out / f"{args.what}.csv", rows)
    return 0
