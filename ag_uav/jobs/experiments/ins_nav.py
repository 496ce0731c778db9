"""``ag-uav experiment ins-nav``: the measurements of the drone flying on the INS (docs/ins.md).

``--what``:

* ``recovery``: MCKF's lock-out recovery (none / inflate / kf) × kernel σ (1, 2, 4, 10⁶ ≈ ∞)
  in the loop, false-fix episodes on (``--set`` raises their rate so that short missions hold
  some); per rule the horizontal position error RMS over the mission, mean ± 95 % CI over
  seeds;
* ``consistency``: every NEES block (the 15 states; position, velocity, attitude, the
  accelerometer and gyro biases) and every sensor's NIS over its dimension, per rule, in four
  conditions (:data:`CONDITIONS`: clean fixes or false fixes, with or without the gate); the
  gate's share of the false-fix epochs and the peak error through them, paired; ``nees.png``
  the NEES15 over time with the 95 % band;
* ``outage``: a forced ``--duration`` s GNSS outage 2 s into the first long sweep leg, flown on
  the KF: the INS (``nav = ins``) against the ideal-attitude stand-in; drift of the estimate at
  the end of the outage, peak estimate error and peak cross-track inside it;
* ``falsefix``: the in-loop table with false fixes on: per rule the position error RMS, and the
  paired difference to the KF (mean ± 95 % CI over seeds);
* ``rules``: the four rules on each GNSS preset of ``--presets`` (default the presets
  fitted on real u-blox M8P logs) with R from the receiver's report and from the generator
  (``--r-sources``): NEES/NIS per dimension, RMSE, crashes, each rule paired against the KF,
  and reported − truth paired per rule;
* ``replay``: the four rules on recorded flights (``--logs``; the GNSS built from their
  reference per seed with ``--gnss-from-reference``): per rule the median position and tilt
  RMS and position NIS, and the paired difference to the KF of the same run;
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
HELP = ("the INS in the loop: MCKF recovery × σ, NEES consistency, a GNSS outage with the "
        "INS vs the ideal-attitude stand-in, the false-fix in-loop table, the MCKF kernel "
        "sweep, the four rules per GNSS preset and R source")
RULES = ("pca-mckf", "kf", "mckf", "pca-kf")


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--what", choices=("recovery", "consistency", "outage", "falsefix", "sweep",
                                      "rules", "replay"), required=True)
    p.add_argument("--logs", default="", help="replay: recorded flights (comma-separated: a "
                   "Phantom 4 RTK path folder, a ULog, a DataFlash log, a CSV folder)")
    p.add_argument("--gnss-from-reference", default=None, metavar="PRESET",
                   help="replay: GNSS built from the reference with this preset, per seed")
    p.add_argument("--presets", default="m8p-rtk-static,m8p-standalone",
                   help="rules: the GNSS presets (comma-separated)")
    p.add_argument("--r-sources", default="reported,truth",
                   help="rules: estimator.ins_r_source values (comma-separated)")
    p.add_argument("--sigmas", default="1,2,4,8,inf", help="sweep: fixed-kernel σ values")
    p.add_argument("--kernels", default="adaptive,multi",
                   help="sweep: estimator.mckf_kernel variants flown at σ = 2")
    p.add_argument("--runs", type=int, default=10, help="seeds seed0..seed0+runs-1")
    p.add_argument("--conditions", default="", help="consistency: the conditions to fly "
                   "(names separated by ';'; default all four)")
    p.add_argument("--seed0", type=int, default=0, help="the first seed (consistency; the "
                   "process-noise calibration used seeds from 100, which the comparisons do "
                   "not use)")
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


#: the consistency experiment's conditions: (name, config overrides); "clean" is the rtk
#: preset (no fix types, so no false fixes), "false fixes" the rtk-m350 receiver with its
#: honest reports and 30 false-fix episodes per hour of RTK fixed; "no latch" the gate alone,
#: as PX4 EKF2's (the step latch off)
CONDITIONS = (
    ("clean, gate", {"gps.preset": "rtk"}),
    ("clean, no gate", {"gps.preset": "rtk", "estimator.ins_gate_sigma": 0.0}),
    ("false fixes, gate", {"gps.false_fix_per_hour": 30.0}),
    ("false fixes, gate, no latch", {"gps.false_fix_per_hour": 30.0,
                                     "estimator.ins_gate_latch_s": 0.0}),
    ("false fixes, no gate", {"gps.false_fix_per_hour": 30.0, "estimator.ins_gate_sigma": 0.0}),
)
#: (score key, its dimension) per NEES block and sensor NIS
DIMS = (("nees15_mean", 15), ("nees_pos_mean", 3), ("nees_vel_mean", 3), ("nees_att_mean", 3),
        ("nees_ba_mean", 3), ("nees_bg_mean", 3), ("nis_mean", 3), ("nis_vel_mean", 3),
        ("nis_yaw_mean", 1), ("nis_radar_mean", 1))


def _fly_seeds(cfg: Any, seeds: list[int], over: dict[str, Any]) -> list[Any]:
    """One engine batch of ``seeds`` with the config overrides ``over``."""
    import copy

    from ...engine.missions import simulate_many

    cfgs = []
    for seed in seeds:
        c = copy.deepcopy(cfg)
        c.seed = seed
        for k, v in over.items():
            sec, key = k.split(".")
            setattr(getattr(c, sec), key, v)
        cfgs.append(c)
    return simulate_many(cfgs)


def consistency(args: argparse.Namespace) -> list[dict[str, Any]]:
    """Per condition (:data:`CONDITIONS`) over ``--runs`` seeds: every NEES block and sensor
    NIS divided by its dimension (1 = consistent; mean ± 95 % CI over seeds), the gate's
    rejections, the share of false-fix epochs it rejects and the peak error through the
    episodes; ``nees.png``: the seeds' mean NEES15 over time with the 95 % band of the mean of
    N χ²(15) (Bar-Shalom, Li & Kirubarajan 2001, §5.4)."""

    cfg = _base(args, {})
    seeds = list(range(args.seed0, args.seed0 + args.runs))
    rows, series = [], {}
    only = [c.strip() for c in args.conditions.split(";") if c.strip()]
    for name, over in CONDITIONS:
        if only and name not in only:
            continue
        res = _fly_seeds(cfg, seeds, over)
        series[name] = [r.extra.get("nav_series") for r in res]
        rows += _score_rows(name, seeds, res)
        _print_condition(name, [x for x in rows if x["condition"] == name])
    _print_false_fix([x for x in rows if x["condition"].startswith("false")])
    _print_verdict(rows)
    _plot_nees(series, Path(args.out) / "nees.png")
    return rows


def _score_rows(name: str, seeds: list[int], res: list[Any]) -> list[dict[str, Any]]:
    """One row per seed and rule of a condition's flights: the NEES blocks, NIS, errors and
    the gate's counts."""
    rows = []
    for seed, r in zip(seeds, res, strict=True):
        s = r.summary
        for rule, e in s["estimators"].items():
            rows.append({"condition": name, "seed": seed, "rule": rule,
                         "flown": e["flown"], "crashed": s["crashed"],
                         "false_fix_fixes": s.get("false_fix_fixes") or 0,
                         **{k: e.get(k) for k, _ in DIMS},
                         **{k: e.get(k) for k in ("estimate_rmse_m", "estimate_max_m",
                                                  "gate_rejected", "gate_resets",
                                                  "false_fixes_rejected",
                                                  "false_fix_peak_m")},
                         "cross_track_rmse_m": s.get("cross_track_rmse_m")})
    return rows


def rules(args: argparse.Namespace) -> list[dict[str, Any]]:
    """The four rules on each GNSS preset of ``--presets`` with each R source of
    ``--r-sources`` (``estimator.ins_r_source``), the same seeds for all: per condition the
    NEES/NIS per dimension and RMSE (:func:`_print_condition`), the crashes, each rule paired
    against the KF of the same flights (:func:`_print_verdict`), and per preset each rule's
    reported − truth difference paired on the seeds (:func:`_print_sources`)."""
    cfg = _base(args, {})
    seeds = list(range(args.seed0, args.seed0 + args.runs))
    presets = [x.strip() for x in args.presets.split(",") if x.strip()]
    sources = [x.strip() for x in args.r_sources.split(",") if x.strip()]
    from ...config import ConfigError
    from ...vehicle.gps import available_presets

    for flag, got, allowed in (("--presets", presets, available_presets()),
                               ("--r-sources", sources, ["reported", "truth"])):
        bad = [x for x in got if x not in allowed] if got else ["(none)"]
        if bad:
            raise ConfigError(f"{flag} = {', '.join(bad)}: allowed {', '.join(allowed)}")
    rows: list[dict[str, Any]] = []
    for preset in presets:
        for src in sources:
            name = f"{preset}, R {src}"
            res = _fly_seeds(cfg, seeds, {"gps.preset": preset, "estimator.ins_r_source": src})
            new = _score_rows(name, seeds, res)
            rows += new
            crashed = [x["seed"] for x in new if x["flown"] and x["crashed"]]
            _print_condition(name, new)
            print(f"   crashed: {len(crashed)} of {len(seeds)} {crashed}", flush=True)
        if len(sources) == 2:
            _print_sources(preset, sources, rows)
    _print_verdict(rows)
    return rows


#: the replay comparison's scores: (summary key, label, scale to the printed unit, unit)
REPLAY_KEYS = (("pos_h_rms_m", "pos h RMS", 1e3, "mm"),
               ("pos_h_rms_with_fixes_m", "with fixes", 1e3, "mm"),
               ("tilt_rms_deg", "tilt RMS", 1.0, "°"), ("nis_pos_mean", "NIS pos", 1.0, ""))


def replay_rules(args: argparse.Namespace) -> list[dict[str, Any]]:
    """The four rules on recorded flights (``--logs``, :mod:`ag_uav.navigation.replay`, the
    very bank ``ag-uav replay`` runs): with ``--gnss-from-reference PRESET`` each log once per
    seed (``--runs`` from ``--seed0``), else once with the log's own GNSS. Per log and seed
    each rule's horizontal position RMS, tilt RMS, position NIS and gate counts (against the
    reference, else the autopilot's estimate); then per rule its median over the runs and its
    difference to the KF of the same run, paired (mean ± 95 % CI, runs where it is lower)."""
    from ...config import ConfigError
    from ...navigation.replay import ReplayOptions, read_log, run_replay, score_replay
    from ...navigation.replay.data import ReplayError

    logs = [x for x in args.logs.split(",") if x.strip()]
    if not logs:
        raise ConfigError("--logs: give the flights to replay (comma-separated paths)")
    seeds = (list(range(args.seed0, args.seed0 + args.runs)) if args.gnss_from_reference
             else [None])
    rows: list[dict[str, Any]] = []
    for path in logs:
        for seed in seeds:
            try:
                res = run_replay(read_log(path), ReplayOptions(
                    gnss_from_reference=args.gnss_from_reference, seed=seed or 0))
            except ReplayError as e:
                raise ConfigError(f"--logs: {e}") from None
            sc = score_replay(res)
            for rule, e in sc["estimators"].items():
                rows.append({"log": path, "seed": seed, "rule": rule, "against": sc["against"],
                             **{k: e.get(k) for k, *_ in REPLAY_KEYS},
                             **{k: e.get(k) for k in ("gate_rejected", "gate_latched",
                                                      "gate_resets")}})
            kf = next(x for x in rows[-len(sc["estimators"]):] if x["rule"] == "kf")
            print(f"{Path(path).name} seed {seed}: " + "; ".join(
                f"{x['rule']} {x['pos_h_rms_m']} m, tilt {x['tilt_rms_deg']}°, NIS "
                f"{x['nis_pos_mean']}, rejected {x['gate_rejected']}"
                for x in rows[-len(sc["estimators"]):]) + f" (vs {kf['against']})", flush=True)
    _print_replay_verdict(rows)
    return rows


def _print_replay_verdict(rows: list[dict[str, Any]]) -> None:
    """Per rule: the median of each score over the runs, and its difference to the KF of the
    same run (mean ± 95 % CI; the runs where it is lower)."""
    import numpy as np

    runs = sorted({(x["log"], x["seed"]) for x in rows}, key=str)
    by = {(x["log"], x["seed"], x["rule"]): x for x in rows}
    print(f"-- {len(runs)} runs ({len({r[0] for r in runs})} logs)")
    for rule in RULES:
        parts = []
        for key, label, sc, unit in REPLAY_KEYS:
            v = [by[(lg, sd, rule)][key] for lg, sd in runs if (lg, sd, rule) in by
                 and by[(lg, sd, rule)][key] is not None]
            if not v:
                continue
            part = f"{label} median {np.median(v) * sc:.3g} {unit}"
            d = [sc * (by[(lg, sd, rule)][key] - by[(lg, sd, "kf")][key]) for lg, sd in runs
                 if (lg, sd, rule) in by and (lg, sd, "kf") in by
                 and by[(lg, sd, rule)][key] is not None
                 and by[(lg, sd, "kf")][key] is not None]
            if rule != "kf" and d:
                part += (f", − kf {_ci(d)} {unit} (median {np.median(d):.3g}; "
                         f"{sum(x < 0 for x in d)} of {len(d)} lower)")
            parts.append(part)
        print(f"{rule}: " + "; ".join(parts), flush=True)


def _print_sources(preset: str, sources: list[str], rows: list[dict[str, Any]]) -> None:
    """Per rule, the first R source less the second on the same seeds (mean ± 95 % CI):
    position RMSE (mm), NEES15/15, position NIS/3."""
    a, b = (f"{preset}, R {s}" for s in sources)
    for rule in RULES:
        on = {x["seed"]: x for x in rows if x["condition"] == a and x["rule"] == rule}
        off = {x["seed"]: x for x in rows if x["condition"] == b and x["rule"] == rule}
        parts = []
        for key, d, label in (("estimate_rmse_m", 1e-3, "RMSE (mm)"),
                              ("nees15_mean", 15, "NEES15/15"), ("nis_mean", 3, "NIS/3")):
            dd = [(on[k][key] - off[k][key]) / d for k in on
                  if k in off and on[k][key] is not None and off[k][key] is not None]
            if dd:
                parts.append(f"{label} {_ci(dd)} ({sum(x < 0 for x in dd)} of {len(dd)} "
                             "lower)")
        print(f"{preset}: {rule} {sources[0]} − {sources[1]}: " + "; ".join(parts), flush=True)


def _print_condition(name: str, rows: list[dict[str, Any]]) -> None:
    print(f"-- {name} ({len({x['seed'] for x in rows})} seeds)")
    for rule in RULES:
        sel = [x for x in rows if x["rule"] == rule]
        if not sel:
            continue
        parts = []
        for k, d in DIMS:
            v = [x[k] / d for x in sel if x[k] is not None]
            if v:
                parts.append(f"{k.replace('_mean', '')}/{d} {_ci(v)}")
        rej = sum(x["gate_rejected"] or 0 for x in sel)
        print(f"{rule}: " + "; ".join(parts) + f"; RMSE {_ci([x['estimate_rmse_m'] for x in sel])}"
              f" m; gate rejections {rej} (resets {sum(x['gate_resets'] or 0 for x in sel)})",
              flush=True)


def _print_false_fix(rows: list[dict[str, Any]]) -> None:
    """Per gated condition: the gate's share of the false-fix epochs, and the peak error
    through the episodes paired against the same seeds without the gate (seeds that had
    episodes)."""

    gated = sorted({x["condition"] for x in rows if not x["condition"].endswith("no gate")})
    for cond in gated:
        print(f"-- {cond} against no gate")
        for rule in RULES:
            on = {x["seed"]: x for x in rows if x["rule"] == rule and x["condition"] == cond}
            off = {x["seed"]: x for x in rows if x["rule"] == rule
                   and x["condition"].endswith("no gate")}
            both = [k for k in on if k in off and on[k]["false_fix_peak_m"] is not None
                    and off[k]["false_fix_peak_m"] is not None]
            if both:
                _print_pair(rule, [on[k] for k in both], [off[k] for k in both])


def _print_pair(rule: str, on: list[dict[str, Any]], off: list[dict[str, Any]]) -> None:
    """One rule's false-fix line: rejected share and the paired peak error."""
    import numpy as np

    w = np.array([x["false_fix_fixes"] for x in on], float)
    rej = np.array([x["false_fixes_rejected"] for x in on], float)
    pk_on = [x["false_fix_peak_m"] for x in on]
    pk_off = [x["false_fix_peak_m"] for x in off]
    print(f"{rule}: the gate rejects {np.sum(rej * w) / np.sum(w):.1%} of "
          f"{int(w.sum())} false-fix epochs ({len(on)} seeds with episodes); peak error "
          f"through them {_ci(pk_on)} m with the gate, {_ci(pk_off)} m without; ratio of "
          f"the means {np.mean(pk_off) / np.mean(pk_on):.2f}; paired "
          f"{_ci([b - a for a, b in zip(pk_on, pk_off, strict=True)])} m", flush=True)


#: the verdict's scores: (row key, label)
VERDICT = (("estimate_rmse_m", "position RMSE"), ("estimate_max_m", "max error"),
           ("false_fix_peak_m", "peak through the false fixes"))


def _print_verdict(rows: list[dict[str, Any]]) -> None:
    """Per condition and score, each rule paired against the KF of the same flight: the KF's
    mean ± 95 % CI (m) and each other rule's difference (mm), with the seeds where it is
    lower."""
    for cond in dict.fromkeys(x["condition"] for x in rows):
        kf = {x["seed"]: x for x in rows if x["condition"] == cond and x["rule"] == "kf"}
        for key, label in VERDICT:
            seeds = [k for k, x in kf.items() if x[key] is not None]
            if not seeds:
                continue
            parts = [f"kf {_ci([kf[k][key] for k in seeds])} m ({len(seeds)})"]
            for rule in ("mckf", "pca-kf", "pca-mckf"):
                o = {x["seed"]: x[key] for x in rows
                     if x["condition"] == cond and x["rule"] == rule}
                d = [1e3 * (o[k] - kf[k][key]) for k in seeds if o.get(k) is not None]
                if d:
                    m, h = _ci(d).partition(" ± ")[::2]
                    parts.append(f"{rule} − kf {float(m):+.1f} ± {float(h or 0):.1f} mm "
                                 f"({sum(x < 0 for x in d)} of {len(d)} lower)")
            print(f"{cond}: {label}: " + "; ".join(parts), flush=True)


def _plot_nees(series: dict[str, list[Any]], path: Path) -> None:
    """The seeds' mean NEES15 of the flown rule per fix time, with the 95 % band."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    import numpy as np
    from scipy.stats import chi2

    fig, ax = plt.subplots(figsize=(9, 4))
    n = 1
    for name, ser in series.items():
        ser = [s for s in ser if s is not None]
        if not ser or name.startswith("false"):
            continue
        rule = next(k for k in ser[0] if k not in ("tick", "dt"))
        common = ser[0]["tick"]
        for s in ser[1:]:
            common = np.intersect1d(common, s["tick"])
        m = np.nanmean([s[rule][np.isin(s["tick"], common)] for s in ser], axis=0)
        ax.plot(common * ser[0]["dt"], m, lw=0.6, label=f"{name} ({rule}, {len(ser)} seeds)")
        n = len(ser)
    lo, hi = chi2.ppf([0.025, 0.975], 15 * n) / n
    ax.axhspan(lo, hi, color="g", alpha=0.2, label=f"95 % band of the mean ({lo:.1f}-{hi:.1f})")
    ax.set_yscale("log")
    ax.set_xlabel("time (s)")
    ax.set_ylabel("mean NEES15 over seeds")
    ax.legend(fontsize=8)
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=120, bbox_inches="tight")
    plt.close(fig)
    print(f"wrote {path}")


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

                prep = M.prepare_run(c)
                prep.fb.outages = [window]
                out = M.fly([prep.flight])[0]
                res = M.finish_run(prep, out)
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
    from ...config import ConfigError
    from . import number_axis

    sigmas = (number_axis("--sigmas", args.sigmas, lo=0.0, lo_open=True, inf=True)
              if args.sigmas.strip(", ") else [])
    settings = [("fixed", x) for x in sigmas]
    settings += [(k.strip(), 2.0) for k in args.kernels.split(",") if k.strip()]
    if not settings:
        raise ConfigError(f"--sigmas = {args.sigmas!r}, --kernels = {args.kernels!r}: both "
                          "empty; the sweep needs at least one σ or one kernel")
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
            "falsefix": falsefix, "sweep": sweep, "rules": rules,
            "replay": replay_rules}[args.what](args)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    write_csv(out / f"{args.what}.csv", rows)
    return 0
