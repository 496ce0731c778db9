"""``ag-uav show | plot | video | recover``: look at a run after the fact (from its MCAP)."""

from __future__ import annotations

import argparse
import functools
import math
import sys
from collections.abc import Callable
from pathlib import Path


def _tool(fn: Callable[[argparse.Namespace], int]) -> Callable[[argparse.Namespace], int]:
    """A log tool's command: a file it cannot use (empty, not MCAP, nothing to draw, an unknown
    camera, ...) is one line on stderr and exit 2, not a traceback."""
    @functools.wraps(fn)
    def run(args: argparse.Namespace) -> int:
        from ..analysis.logscan import LogError

        try:
            return fn(args)
        except LogError as e:
            print(f"ag-uav {args.cmd}: {e}", file=sys.stderr)
            return 2
    return run


def _warn_skipped(args: argparse.Namespace, d) -> None:
    from ..analysis.viewing import skipped_line

    line = skipped_line(d)
    if line:
        print(f"ag-uav {args.cmd}: warning: {d.path}: {line}", file=sys.stderr)


@_tool
def _show(args: argparse.Namespace) -> int:
    from ..analysis.viewing import show

    print(show(args.run))
    return 0


@_tool
def _plot(args: argparse.Namespace) -> int:
    if args.controller is not None or args.run is None:
        return _plot_controller(args)
    from ..analysis.viewing import PLOT_POINTS, mcap_path, plot, read_run

    out = Path(args.out) if args.out else mcap_path(args.run).parent / "plots"
    d = read_run(args.run, images=False, max_points=PLOT_POINTS)
    _warn_skipped(args, d)
    for p in plot(d, out):
        print(p)
    return 0


def _plot_controller(args: argparse.Namespace) -> int:
    from ..analysis.controller_plots import plot_controller
    from ..config import ConfigError, parse_set_items

    if args.run is not None and args.controller is not None:
        raise ConfigError("plot: give a run or --controller CONFIG, not both")
    cfg = None if args.controller in (None, "default") else args.controller
    paths, stats = plot_controller(cfg, args.out or "plots/controller", parse_set_items(args.set))
    for axis, st in stats.items():
        print(f"{axis}: " + ", ".join(f"{k} = {v:.3g}" for k, v in st.items()))
    for p in paths:
        print(p)
    return 0


@_tool
def _video(args: argparse.Namespace) -> int:
    from ..analysis.logscan import LogError
    from ..analysis.viewing import PLOT_POINTS, read_run, video

    fps = args.fps
    if not (math.isfinite(fps) and fps >= 0):
        raise LogError(f"--fps = {fps:g}: must be > 0 (or 0 for the logged rate)")
    d = read_run(args.run, images=True, max_points=PLOT_POINTS)
    _warn_skipped(args, d)
    print(video(d, args.out, camera=args.camera, fps=fps or None))
    return 0


@_tool
def _recover(args: argparse.Namespace) -> int:
    from ..analysis.viewing import recover

    rep = recover(args.input, args.output)
    line = f"recovered {rep.messages} messages into {args.output}"
    if not rep.intact:
        lost = rep.lost
        line += (f", {lost} lost" if lost is not None else ", the rest lost") + \
            f": {rep.describe(counts=False)}"
    print(line, file=sys.stderr)
    return 0


def register(sub) -> None:
    run_help = "run folder or its run.mcap"
    s = sub.add_parser("show", help="config, metrics, channels and counts of a run (from MCAP)",
                       description="Print a run's config, metrics and channels from its MCAP.")
    s.add_argument("run", help=run_help)
    s.set_defaults(func=_show)

    p = sub.add_parser("plot", help="PNG plots of a run (map, errors, controller, estimators) "
                       "or of a controller config (--controller)",
                       description="Write PNG plots of a run: top-down map (field, path, true "
                                   "and estimated tracks, GPS fixes), errors over time, "
                                   "controller signals, estimator comparison (each GPS "
                                   "fix against the true antenna position at its measurement "
                                   "time, each filter against the true position when logged: "
                                   "the figure's caption says so).")
    p.add_argument("run", nargs="?", help=run_help)
    p.add_argument("-o", "--out", metavar="DIR", help="output folder (default: RUN/plots, or "
                   "plots/controller with --controller)")
    p.add_argument("--controller", metavar="CONFIG", help="instead of a run: figures of a "
                   "controller config (footprints of uncertainty; control surfaces of IT2 with "
                   "each reducer, type-1 and PID, and their differences); \"default\" = the "
                   "shipped config")
    p.add_argument("--set", action="append", default=[], metavar="KEY=VALUE",
                   help="with --controller: override a config key")
    p.set_defaults(func=_plot)

    v = sub.add_parser("video", help="MP4 from the logged camera frames",
                       description="Encode the camera frames logged in a run into an MP4.")
    v.add_argument("run", help=run_help)
    v.add_argument("-o", "--out", required=True, metavar="OUT.mp4")
    v.add_argument("--camera", help="camera name (default: all, side by side)")
    v.add_argument("--fps", type=float, default=20.0,
                   help="frames per second of the video (default 20: with frames logged at "
                        "2 Hz of sim time the video plays 10x faster than the flight); 0 = the "
                        "logged rate, i.e. real time")
    v.set_defaults(func=_video)

    r = sub.add_parser("recover", help="turn a truncated or damaged MCAP into an indexed one",
                       description="Rewrite a truncated (killed run) or damaged MCAP log into a "
                                   "finished, indexed file: every intact chunk is kept "
                                   "(CRC-checked); the messages kept and lost are reported.")
    r.add_argument("input", metavar="IN", help=run_help)
    r.add_argument("output", metavar="OUT", help="the new .mcap file (not IN)")
    r.set_defaults(func=_recover)
