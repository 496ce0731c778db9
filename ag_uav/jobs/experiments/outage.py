"""``ag-uav experiment outage``: a GPS outage on a sweep leg, bridged by the coverage path.

Zhou et al.'s route-constrained filter in the loop (:mod:`ag_uav.navigation.route`): the default
field, ``--gps`` noise (default ``sbas``), and a forced ``--duration`` s outage (default 10 s)
starting 2 s into the first sweep leg long enough to hold it (:func:`leg_outage`). For each
seed, the drone flies the mission three times, on ``kf``, ``mckf`` and ``route-kf`` (the KF of
the bank plus virtual measurements "on the planned segment" during the outage); every flight gets
the same fixes (common random numbers). The mission is cut 5 s after the outage. Scores inside
the outage window: peak and RMS distance of the true track from the planned path, and the peak
estimate error. A second pass flies on the KF with ``route-kf`` as a shadow (monitor), which
isolates the estimator's part from the closed loop's.

Navigation: these flights run the bank of position filters (``RouteConstrainedFeedback``, the
``estimator.nav = "ideal-attitude"`` stand-in: true attitude × a Gauss–Markov error, fixes
without latency) whatever ``estimator.nav`` says: the route constraint is a position-filter
measurement.  The same outage flown on the error-state INS, side by side with this stand-in, is
``ag-uav experiment ins-nav --what outage`` (docs/ins.md).
"""

from __future__ import annotations

import argparse
import math
from pathlib import Path
from typing import Any

NAME = "outage"
HELP = ("GPS outage on a sweep leg: KF, MCKF and the route-constrained KF (Zhou et al.) in the "
        "loop; peak cross-track error inside the outage")
FLY_ON = ("kf", "mckf", "route-kf")


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--runs", type=int, default=10, help="seeds 0..runs-1")
    p.add_argument("--duration", type=float, default=10.0, help="outage length (s)")
    p.add_argument("--gps", default="sbas", help="GPS preset outside the outage")
    p.add_argument("--out", default="runs/experiment-outage", help="output folder")
    p.add_argument("--workers", "-j", type=int, default=None, help="worker processes")
    p.add_argument("--set", action="append", default=[], metavar="KEY=VALUE",
                   help="config override for every flight, e.g. imu.model=ideal (repeatable)")


def leg_outage(cfg: Any, duration_s: float = 10.0, lead_s: float = 2.0,
               leg: int | None = None) -> tuple[float, float]:
    """An outage window of ``duration_s`` starting ``lead_s`` into a sweep leg long enough to
    hold it (the first such leg, or leg index ``leg`` among them), from the mission reference."""
    import numpy as np

    from ...engine.missions import build_reference
    from ...navigation.route import plan_for

    plan = plan_for(cfg)
    ref = build_reference(cfg, plan)
    dt = 1.0 / cfg.sim.control_hz
    t = np.arange(0.0, ref.duration, dt)
    seg = ref.sample_all(t)["seg"]
    cands = []
    for i, s in enumerate(plan.segments):
        if s.kind != "leg":
            continue
        ts = t[seg == i]
        if ts.size and ts[-1] - ts[0] >= duration_s + lead_s + 1.0:
            cands.append((float(ts[0]) + lead_s, float(ts[0]) + lead_s + duration_s))
    if not cands:
        raise ValueError(f"no sweep leg lasts {duration_s + lead_s + 1.0:g} s; use a larger field")
    return cands[0 if leg is None else leg]


def _one(task: tuple[dict, str, tuple[float, float], bool]) -> dict[str, Any]:
    import numpy as np

    from ...config import config_from_dict
    from ...engine.missions import simulate
    from ...navigation.route import ROUTE_NAME, RouteConstrainedFeedback, outage_cross_track

    cfg_d, fly_on, window, monitor = task
    cfg = config_from_dict(cfg_d)
    primary = ROUTE_NAME if fly_on == ROUTE_NAME else None
    fb = RouteConstrainedFeedback.for_config(cfg, primary=primary, outages=[window])
    res = simulate(cfg, feedback=fb)
    out: dict[str, Any] = {"seed": cfg.seed, "fly_on": fly_on, "monitor": monitor,
                           "crashed": res.summary["crashed"]}
    names = [fly_on] if not monitor else ["kf", ROUTE_NAME]
    for name in names:
        est = np.full((len(res.t), 3), np.nan)
        e = np.asarray(fb.est[name], dtype=float).reshape(-1, 3)
        est[len(res.t) - len(e):] = e[-len(res.t):]
        sc = outage_cross_track(res, window, est=est)
        key = "" if not monitor else f"{name}."
        for k, v in sc.items():
            out[key + k] = v
    return out


def main(args: argparse.Namespace) -> int:
    from rich.console import Console
    from rich.table import Table

    from ...config import ConfigError, load_config, parse_set_items
    from ...navigation.route import ROUTE_NAME
    from ..batch import mean_ci
    from ..executor import make_executor
    from . import write_csv

    if args.runs < 1:
        raise ConfigError(f"--runs = {args.runs}: must be >= 1")
    if not (0 < args.duration < 1e6):
        raise ConfigError(f"--duration = {args.duration:g}: must be > 0 s")
    base = load_config(None, {"gps.preset": args.gps, "estimator.name": "kf",
                              "estimator.shadow": ["mckf"], **parse_set_items(args.set)})
    base.log.enabled = False
    try:
        window = leg_outage(base, duration_s=args.duration)
    except ValueError as e:
        raise ConfigError(f"--duration = {args.duration:g}: {e}") from None
    base.sim.max_time_s = window[1] + 5.0
    tasks = []
    for seed in range(args.runs):
        d = base.to_dict()
        d["seed"] = seed
        for fly_on in FLY_ON:
            dd = dict(d, estimator=dict(d["estimator"], name="kf" if fly_on == ROUTE_NAME
                                        else fly_on))
            tasks.append((dd, fly_on, window, False))
        tasks.append((d, "kf", window, True))
    with make_executor(args.workers) as ex:
        rows = ex.map(_one, tasks)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    write_csv(out / "results.csv", rows)
    t = Table(title=f"{args.duration:g} s GPS outage on a sweep leg ({args.gps}, "
                    f"imu {base.imu.model}, "
                    f"window {window[0]:.1f}-{window[1]:.1f} s, {args.runs} seeds; mean ± 95 % CI)")
    for c in ("flies on", "peak cross-track [m]", "RMS cross-track [m]",
              "peak estimate error [m]", "crashes"):
        t.add_column(c, justify="right")
    md = ["| flies on | peak cross-track [m] | RMS cross-track [m] | peak estimate error [m] |",
          "|---|---|---|---|"]

    def fmt(vals: list[float]) -> str:
        m, h, _ = mean_ci(vals)
        return f"{m:.2f} ± {h:.2f}" if math.isfinite(h) else f"{m:.2f}"

    for fly_on in FLY_ON:
        rs = [r for r in rows if r["fly_on"] == fly_on and not r["monitor"]]
        cells = [fmt([r["peak_cross_track_m"] for r in rs]),
                 fmt([r["rms_cross_track_m"] for r in rs]),
                 fmt([r["peak_estimate_error_m"] for r in rs])]
        t.add_row(fly_on, *cells, str(sum(bool(r["crashed"]) for r in rs)))
        md.append(f"| {fly_on} | " + " | ".join(cells) + " |")
    mon = [r for r in rows if r["monitor"]]
    md += ["", "Monitor (flies on kf; both filters fed the same fixes): peak estimate error "
           f"kf {fmt([r['kf.peak_estimate_error_m'] for r in mon])} m, route-kf "
           f"{fmt([r[ROUTE_NAME + '.peak_estimate_error_m'] for r in mon])} m."]
    Console().print(t)
    Console().print(md[-1])
    (out / "table.md").write_text("\n".join(md) + "\n")
    print(f"wrote {out / 'results.csv'} and {out / 'table.md'}")
    return 0
