"""``ag-uav`` command line.

Every command has ``--help``. A bad config prints one line naming the key, the value and what is
allowed, and exits with code 2 (no traceback).  A file that cannot be written (a full disk, no
permission) prints one line naming it and exits with code 1; outputs are written atomically
(:mod:`ag_uav.record.atomic`), so a failed write leaves no partial file.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import sys
import time
from pathlib import Path

from ..config import ConfigError


def _add_config_args(p: argparse.ArgumentParser) -> None:
    p.add_argument("--config", "-c", metavar="FILE.toml", help="run config (TOML); defaults if "
                   "omitted (see `ag-uav config`)")
    p.add_argument("--seed", metavar="N", help="override the config's seed (an integer >= 0; "
                   "checked like --set seed=N)")
    p.add_argument("--set", action="append", default=[], metavar="KEY=VALUE",
                   help="override one config key, e.g. --set wind.speed_mps=5 (TOML value)")


def _overrides(args: argparse.Namespace) -> dict:
    from ..config import parse_set_items

    out = parse_set_items(args.set)
    if getattr(args, "seed", None) is not None:  # read as TOML and checked by the config
        out["seed"] = parse_set_items([f"seed={args.seed}"])["seed"]
    return out


def _load(args: argparse.Namespace):
    from ..config import load_config

    return load_config(args.config, _overrides(args))


# -------------------------------------------------------------------------------------- commands
def cmd_config(args: argparse.Namespace) -> int:
    from ..config import config_toml_with_comments

    cfg = _load(args)
    if args.model_info:
        from ..vehicle.mjcf import build_vehicle

        print(json.dumps(build_vehicle(cfg).info(), indent=2))
        return 0
    print(config_toml_with_comments(cfg), end="")
    return 0


def cmd_fly(args: argparse.Namespace) -> int:
    if args.run_id is not None:  # a name, not a path: refused before anything is loaded
        from ..jobs.outdir import check_run_id

        check_run_id(args.run_id)
    cfg = _load(args)  # before importing the simulator: a bad config fails fast
    from ..jobs.run import fly

    if args.no_render:
        cfg.log.render = False
    if args.no_log:
        cfg.log.enabled = False
    from ..analysis.report import print_summary
    from ..jobs.run import RunOutputError

    try:
        res, run_dir = fly(cfg, out_root=args.out, run_id=args.run_id, progress=not args.quiet,
                           overwrite=args.overwrite)
    except RunOutputError as e:  # flown, but an output failed: the summary goes to the terminal
        print_summary(e.result.summary, e.run_dir)
        if not e.summary_written:
            from ..jobs.run import summary_json

            print("summary.json could not be written; here it is:")
            print(summary_json(e.result.summary))
        raise
    print_summary(res.summary, run_dir)
    return 0


def cmd_plan(args: argparse.Namespace) -> int:
    from ..config import load_config
    from ..engine.missions import build_field, build_plan
    from ..world.forecast import plan_wind
    from ..world.mission import offset_text
    from ..world.plan_export import nozzle_leads, write_plan

    if not (math.isfinite(args.simplify) and args.simplify >= 0):
        raise ConfigError(f"--simplify = {args.simplify:g}: must be a tolerance >= 0 (metres; "
                          "0 keeps every point)")
    ov = _overrides(args)
    if args.field:
        ov["mission.field"] = args.field
    cfg = load_config(args.config, ov)
    fld = build_field(cfg)
    if args.origin:
        cfg = _plan_origin(args, cfg, ov)
        fld = build_field(cfg)
    plan = build_plan(cfg, fld)
    m, sp = cfg.mission, cfg.spray
    leads = nozzle_leads(m.speed_mps, sp.nozzle_on_delay_s, sp.nozzle_off_delay_s,
                         sp.cmd_off_immediate)
    kw = {"altitude": m.altitude_m, "speed": m.speed_mps, "simplify_m": args.simplify,
          "leads": leads}
    try:
        info = write_plan(plan, args.output, **kw)
    except ValueError as e:
        raise ConfigError(f'-o = "{args.output}": {e}') from None
    items = f", {info['items']} mission items" if "items" in info else ""
    print(f"{args.output}: {info['format']}, {info['waypoints']} waypoints{items}, "
          f"{info['spray_switches']} nozzle switches; {plan.summary()}")
    print(plan.meta["lanes"].text())
    moved = offset_text(plan.meta.get("offset_m", (0.0, 0.0)), cfg.mission.upwind_offset_m)
    if moved:
        print(moved)
    print(plan_wind(cfg).text())
    _write_sorties(cfg, Path(args.output), kw)
    return 0


def _plan_origin(args: argparse.Namespace, cfg, ov: dict):
    """``--origin LAT,LON[,H]``: exactly ``mission.origin_*`` (the config with them set), for a
    field in local metres only.  A lon/lat field already lies where its coordinates say; an
    origin would move every waypoint of a plan an autopilot flies, so it is refused."""
    from ..config import load_config
    from ..world.field import load_field

    try:
        origin = tuple(float(v) for v in args.origin.split(","))
        assert len(origin) in (2, 3) and all(math.isfinite(v) for v in origin)
        assert abs(origin[0]) < 90 and abs(origin[1]) <= 180
    except (ValueError, AssertionError):
        raise ConfigError(f'--origin = "{args.origin}": expected LAT,LON[,H] in degrees '
                          "(-90 < LAT < 90, -180 <= LON <= 180) and metres") from None
    if load_field(cfg.mission.field).origin is not None:  # already loaded once: no error here
        raise ConfigError(f'--origin = "{args.origin}": field "{cfg.mission.field}" is '
                          "georeferenced (lon/lat); its plan lies where the field is, and "
                          "--origin places only a field in local metres (to project about "
                          "another point, --set mission.origin_lat_deg/_lon_deg)")
    keys = ("mission.origin_lat_deg", "mission.origin_lon_deg", "mission.origin_alt_m")
    return load_config(args.config, {**ov, **dict(zip(keys, origin, strict=False))})


def _write_sorties(cfg, out: Path, kw: dict) -> None:
    """A job that needs several sorties (tank or battery, :mod:`ag_uav.world.spray_job`): one
    mission per sortie beside ``out`` (``NAME-sortie01.EXT``, ...: take-off at the base,
    transit to the resume point, the legs, transit home), and a line that says so; ``out``
    keeps the whole coverage path for reference."""
    from ..engine.missions import mission_setup
    from ..world.plan_export import write_plan

    if not cfg.spray.enabled:
        return
    _, _, ref = mission_setup(cfg)
    pieces = getattr(ref, "pieces", None)
    if not pieces or len(pieces) < 2:
        return
    paths = []
    for i, (r, _) in enumerate(pieces, 1):
        p = out.with_name(f"{out.stem}-sortie{i:02d}{out.suffix}")
        write_plan(r.plan, p, **kw)
        paths.append(p)
    print(f"the job needs {len(pieces)} sorties (spray.tank_l = {cfg.spray.tank_l:g} L, "
          f"battery.capacity_wh = {cfg.battery.capacity_wh:g} Wh): {out} is the whole path "
          f"without sortie breaks; one mission per sortie: {paths[0]} ... {paths[-1].name}")


def cmd_bench(args: argparse.Namespace) -> int:
    from ..jobs.bench.suite import run_bench

    cfg = _load(args)
    out = run_bench(cfg, repeats=args.repeats, quick=args.quick)
    if args.json:
        print(json.dumps(out, indent=2))
    else:
        from ..jobs.bench.suite import print_bench

        print_bench(out)
    return 0


# ------------------------------------------------------------------------------------- parser
def build_parser(experiments: bool = True) -> argparse.ArgumentParser:
    """The ``ag-uav`` parser; ``experiments=False`` registers ``experiment`` without importing
    the experiment modules (what ``main`` does unless the command is ``experiment``: some of
    them import scipy.stats, half a second and ~60 MB for every other command)."""
    p = argparse.ArgumentParser(
        prog="ag-uav",
        description="Agricultural UAV simulator: fly coverage missions in MuJoCo under an "
                    "interval type-2 fuzzy PID, with wind, noisy GPS and robust Kalman filters.")
    sub = p.add_subparsers(dest="cmd", required=True, metavar="COMMAND")

    f = sub.add_parser("fly", help="fly one mission; writes runs/<run-id>/summary.json (+ MCAP)",
                       description="Fly the configured field once, print a summary table and "
                                   "write runs/<run-id>/summary.json and run.mcap. The summary "
                                   "names the code that flew it (ag_uav_version, source_hash). "
                                   "On an empty kernel cache a helper process compiles on a "
                                   "second core; it dies with the run (SIGKILL included), and "
                                   "the folder a killed run leaves in the temporary directory is "
                                   "removed by the next run.")
    _add_config_args(f)
    f.add_argument("--out", default="runs", metavar="DIR", help="parent folder of the run "
                   "folder (default: runs)")
    f.add_argument("--run-id", help="run folder name inside --out, not a path: '/', '\\', "
                   "'.', '..' and absolute paths are refused (exit 2); default: "
                   "time-field-seed, with a -2, -3, ... suffix where that folder exists")
    f.add_argument("--overwrite", action="store_true", help="replace the outputs of a previous "
                   "run in the --run-id folder (removed first; without it such a folder is "
                   "refused)")
    f.add_argument("--no-render", action="store_true", help="no camera frames in the log")
    f.add_argument("--no-log", action="store_true", help="no MCAP log (summary.json only)")
    f.add_argument("--quiet", "-q", action="store_true", help="no progress bar")
    f.set_defaults(func=cmd_fly)

    c = sub.add_parser("config", help="print the full default config (TOML, commented)",
                       description="Print the resolved config (defaults, or --config with "
                                   "overrides) as commented TOML.")
    _add_config_args(c)
    c.add_argument("--model-info", action="store_true",
                   help="print the compiled vehicle's mass, inertia, rotor layout instead")
    c.set_defaults(func=cmd_config)

    pl = sub.add_parser("plan", help="write the coverage plan (lon/lat) without flying: "
                        ".geojson, .kml or QGroundControl .plan",
                        description="Plan coverage of FIELD (a built-in name or a .geojson/"
                                    ".kml/.kmz/.shp file; PATH#name=VALUE picks one feature) "
                                    "with the config's swath, headland and direction, and write "
                                    "it in the format OUT's extension names. A field file over "
                                    "64 MiB (a .kmz: once inflated) is refused before it is "
                                    "read, a file in local metres is refused as such, and a "
                                    "field across longitude 180 is planned where it is.")
    pl.add_argument("field", nargs="?", metavar="FIELD",
                    help="field (default: the config's mission.field)")
    _add_config_args(pl)
    pl.add_argument("-o", "--output", required=True, metavar="OUT",
                    help="output file: .geojson, .kml or .plan (QGroundControl)")
    pl.add_argument("--origin", metavar="LAT,LON[,H]", help="where a field given in local "
                    "metres lies (the built-in default): the same as --set "
                    "mission.origin_lat_deg/_lon_deg[/_alt_m]; refused (exit 2) for a lon/lat "
                    "field, whose plan always lies where its coordinates say (a southern "
                    "latitude: --origin=-35.3,149.1)")
    pl.add_argument("--simplify", type=float, default=0.2, metavar="M",
                    help="thin turn and transit polylines to this tolerance (m; default 0.2)")
    pl.set_defaults(func=cmd_plan)

    b = sub.add_parser("bench", help="measure closed-loop sim speed against raw MuJoCo stepping",
                       description="Measure, in one process and one run, the closed-loop speed "
                                   "of the default mission (sim-s per wall-s) and raw MuJoCo "
                                   "stepping of the same model, and their ratio.")
    _add_config_args(b)
    b.add_argument("--json", action="store_true", help="machine-readable output")
    b.add_argument("--repeats", type=int, default=3, help="repeats per measurement (median)")
    b.add_argument("--quick", action="store_true", help="shorter measurements")
    b.set_defaults(func=cmd_bench)

    _register_optional(sub, experiments)
    return p


def _register_optional(sub, experiments: bool = True) -> None:
    """Commands that live in other modules register themselves here (logging, batch, tuning);
    ``experiments``: with each experiment's own arguments (see :func:`build_parser`)."""
    import importlib

    for mod in ("ag_uav.cli.view", "ag_uav.cli.experiments", "ag_uav.cli.batch",
                "ag_uav.cli.replay", "ag_uav.cli.gnss"):
        try:
            m = importlib.import_module(mod)
        except ModuleNotFoundError as e:
            if e.name != mod:
                raise
            continue
        if mod == "ag_uav.cli.experiments":
            m.register(sub, load=experiments)
        else:
            m.register(sub)


def _sigterm_handler(signum: int, frame: object) -> None:
    from .batch import Terminated

    raise Terminated()


def _install_sigterm() -> object:
    """SIGTERM raises :class:`~ag_uav.cli.batch.Terminated` in the main thread (so ``finally``
    blocks close the log and the line below is printed); returns the previous handler."""
    import signal

    try:
        return signal.signal(signal.SIGTERM, _sigterm_handler)
    except ValueError:  # not the main thread
        return None


def main(argv: list[str] | None = None) -> int:
    os.environ.setdefault("MUJOCO_GL", "egl")
    argv = sys.argv[1:] if argv is None else list(argv)
    parser = build_parser(experiments="experiment" in argv)
    args = parser.parse_args(argv)
    t0 = time.perf_counter()
    prev = _install_sigterm()
    try:
        return _dispatch(args, t0)
    finally:
        if prev is not None:
            import signal

            signal.signal(signal.SIGTERM, prev)


def _dispatch(args: argparse.Namespace, t0: float) -> int:
    from ..jobs.outdir import FolderInUse, RunFolderExists
    from .batch import Terminated

    try:
        return int(args.func(args) or 0)
    except ConfigError as e:
        print(f"ag-uav: config error: {e}", file=sys.stderr)
        return 2
    except RunFolderExists as e:
        print(f"ag-uav: {e}", file=sys.stderr)
        return 2
    except FolderInUse as e:
        print(f"ag-uav: {e}", file=sys.stderr)
        return 1
    except KeyboardInterrupt:
        print(f"ag-uav: interrupted after {time.perf_counter() - t0:.1f} s", file=sys.stderr)
        return 130
    except Terminated:
        print(f"ag-uav: terminated (SIGTERM) after {time.perf_counter() - t0:.1f} s",
              file=sys.stderr)
        return 143
    except BrokenPipeError as e:
        if e.filename is None:  # standard output closed early (`ag-uav show | head`): done
            return 0
        from ..record.atomic import disk_error_line

        print(f"ag-uav: {disk_error_line(e)}", file=sys.stderr)
        return 1
    except FileNotFoundError as e:
        print(f"ag-uav: {e}", file=sys.stderr)
        return 2
    except OSError as e:  # a full disk, no permission, a read-only folder: one line naming it
        from ..record.atomic import disk_error_line

        print(f"ag-uav: {disk_error_line(e)}", file=sys.stderr)
        return 1
    except RuntimeError as e:  # a batch or tune stopped (workers or scheduler lost): one line
        from ..jobs.batch import BatchStopped
        from ..jobs.executor import ExecutorLost
        from ..jobs.tune import TuneStopped

        if not isinstance(e, BatchStopped | ExecutorLost | TuneStopped):
            raise
        print(f"ag-uav: {e}", file=sys.stderr)
        return 1


__all__ = ["main", "build_parser", "Path"]
