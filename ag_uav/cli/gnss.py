"""``ag-uav gnss fit LOG``: a GNSS noise model fitted from a static receiver's log
(:mod:`ag_uav.analysis.gnss_fit`)."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

FIX_CHOICES = ("auto", "rtk-fixed", "rtk", "differential", "3d")
#: :data:`ag_uav.analysis.gnss_fit.MODELS` (not imported: every command builds this parser)
MODEL_CHOICES = ("auto", "white+gm", "white+gm+rw")


def _stem(path: str) -> str:
    name = Path(path).name
    for suf in (".gz", ".ubx", ".nmea", ".csv", ".txt", ".log"):
        name = name.removesuffix(suf)
    return name or "gnss"


def _fit(args: argparse.Namespace) -> int:
    from ..analysis.gnss_fit import fit_log, preset_components, simulate_stats
    from ..analysis.gnss_log import GnssLogError, read_gnss_log, select_epochs
    from ..analysis.gnss_report import compare_report, fit_report, plot_fit
    from ..record.atomic import atomic_write_text
    from ..vehicle.gps import available_presets, gps_preset

    if args.seeds < 1:
        print(f"ag-uav gnss fit: --seeds = {args.seeds} is invalid; must be >= 1",
              file=sys.stderr)
        return 2
    for name in args.compare:
        if name not in available_presets():
            print(f"ag-uav gnss fit: --compare = {name!r} is invalid; allowed: "
                  f"{', '.join(available_presets())}", file=sys.stderr)
            return 2
    try:
        log = read_gnss_log(args.log)
        sel = select_epochs(log, args.fix)
        fit = fit_log(log, sel, args.model)
    except GnssLogError as e:
        print(f"ag-uav gnss fit: {e}", file=sys.stderr)
        return 2
    name = args.name or _stem(args.log)
    print(fit_report(fit, name))
    seeds = range(args.seeds)
    runs = [(preset_components(fit), "the fitted model")]
    runs += [(gps_preset(c), f"preset {c!r}") for c in args.compare]
    for cfg, label in runs:
        print()
        print(compare_report(fit, label, simulate_stats(cfg, fit.n, fit.dt, seeds), seeds))
    out = Path(args.out)
    if not args.no_files:
        from ..analysis.gnss_fit import preset_toml

        png = plot_fit(fit, out / f"{name}-allan.png")
        toml = atomic_write_text(out / f"{name}-preset.toml", preset_toml(fit, name))
        print(f"wrote {png} and {toml}")
    return 0


def register(sub) -> None:
    """``ag-uav gnss fit``."""
    p = sub.add_parser("gnss", help="GNSS tools: fit a noise model to a receiver's log",
                       description="GNSS tools.")
    gsub = p.add_subparsers(dest="gnss_cmd", required=True, metavar="TOOL")
    f = gsub.add_parser(
        "fit", help="Allan deviation and a white + Gauss-Markov noise model from a static "
        "receiver's log, with a preset block for a run config",
        description="Read a static receiver's log (u-blox UBX NAV-PVT or NAV-SOL, with NMEA "
                    "GGA for the RTK state; NMEA GGA/GST; or a CSV of fixes: time_s, lat_deg, "
                    "lon_deg, height_m or e_m, n_m, u_m, optional fix, h_acc_m, v_acc_m, "
                    "p_acc_m; .gz accepted), keep the epochs of one fix type, and print per "
                    "axis (east, north, up about the mean) the overlapping Allan deviation at "
                    "octave taus, the fitted model, the scatter against the accuracy the "
                    "receiver reported, a [gps] preset block, and the same scatter figures "
                    "simulated by the product's generator. See docs/gnss.md.",
        formatter_class=argparse.ArgumentDefaultsHelpFormatter)
    f.add_argument("log", metavar="LOG", help="the receiver's log (.ubx, .nmea, .csv, .gz)")
    f.add_argument("--fix", default="auto", choices=FIX_CHOICES,
                   help="epochs kept: auto = the most frequent of 3d / dgps / rtk-float / "
                        "rtk-fixed; rtk = fixed or float; differential = dgps or RTK")
    f.add_argument("--model", default="auto", choices=MODEL_CHOICES,
                   help="terms fitted (auto adds a random walk where it halves the residual)")
    f.add_argument("--name", help="preset name in the block and the files (default: the "
                   "log's name)")
    f.add_argument("--compare", metavar="PRESET", action="append", default=[],
                   help="also simulate this preset (at the log's rate and length) against the "
                        "log; repeatable")
    f.add_argument("--seeds", type=int, default=20, help="seeds of the simulated check")
    f.add_argument("--out", default=".", metavar="DIR", help="folder of NAME-allan.png and "
                   "NAME-preset.toml")
    f.add_argument("--no-files", action="store_true", help="print only (no plot, no TOML)")
    f.set_defaults(func=_fit)
