"""``ag-uav replay LOG``: the product's INS (the four GNSS rules, the gate and the latch) on a
recorded flight's IMU and GNSS; a bad or truncated log is one line and exit 2."""

from __future__ import annotations

import argparse
import sys


def _floats(text: str, n: int, flag: str) -> tuple[float, ...]:
    from ..config import ConfigError

    try:
        v = tuple(float(x) for x in text.split(","))
        assert len(v) == n
    except (ValueError, AssertionError):
        raise ConfigError(f'{flag} = "{text}": expected {n} comma-separated numbers') from None
    return v


def _gap(text: str) -> tuple[float, float]:
    from ..config import ConfigError

    parts = text.split(",")
    if len(parts) == 2 and parts[0].strip() == "mid":
        try:
            return (-1.0, float(parts[1]))
        except ValueError:
            pass
    else:
        v = _floats(text, 2, "--gnss-gap")
        if v[0] >= 0 and v[1] > 0:
            return v
    raise ConfigError(f'--gnss-gap = "{text}": expected START,DURATION in seconds (START >= 0 '
                      "from the replay's start, or mid; DURATION > 0)")


def _margins(text: str) -> tuple[float, float]:
    from ..config import ConfigError

    v = _floats(text, 2, "--q-margins")
    if not (v[0] > 0 and v[1] > 0):
        raise ConfigError(f'--q-margins = "{text}": both margins must be > 0 (variance factors)')
    return v


def _replay(args: argparse.Namespace) -> int:
    from ..config import ConfigError
    from ..jobs.replay import replay, replay_table
    from ..navigation.replay import ReplayError, ReplayOptions

    if args.uere is not None and not args.uere > 0:
        raise ConfigError(f"--uere = {args.uere:g}: must be > 0 (m per unit of HDOP)")
    opts = ReplayOptions(
        flown=args.rule, gnss_from_reference=args.gnss_from_reference,
        gnss_rate_hz=args.gnss_rate, seed=args.seed,
        gnss_gap=_gap(args.gnss_gap) if args.gnss_gap else None,
        lever_arm=_floats(args.lever_arm, 3, "--lever-arm") if args.lever_arm else None,
        gnss_delay_s=args.gnss_delay, clock_lag_s=args.clock_lag, heading=args.heading,
        gnss_velocity=not args.no_gnss_velocity,
        q_margins=_margins(args.q_margins) if args.q_margins else None,
        coning=False if args.no_coning else None)
    try:
        s, run_dir = replay(args.log, opts, args.out, args.run_id, args.overwrite,
                            args.imu_file, mcap=not args.no_log, uere_m=args.uere)
    except ReplayError as e:
        print(f"ag-uav replay: {e}", file=sys.stderr)
        return 2
    print(replay_table(s, run_dir))
    return 0


def register(sub) -> None:
    from estimators.ins import RULES

    from ..vehicle.gps.presets import available_presets

    p = sub.add_parser("replay", help="run the INS (four GNSS rules, gate, latch) on a recorded "
                       "flight: PX4 ULog, ArduPilot .BIN, a CSV folder or a Phantom 4 RTK path",
                       description=__doc__)
    p.add_argument("log", help="a .ulg, a .BIN, a folder with imu.csv + gnss.csv "
                   "[+ reference.csv], or a Phantom 4 RTK path folder (GT.csv + IMU_avg.csv)")
    p.add_argument("--gnss-from-reference", metavar="PRESET", choices=available_presets(),
                   help="build the GNSS fixes from the reference track with this receiver "
                   "preset's noise (seeded); needed for a Phantom 4 RTK path")
    p.add_argument("--gnss-rate", type=float, default=5.0, metavar="HZ",
                   help="rate of the fixes built from the reference (default 5)")
    p.add_argument("--seed", type=int, default=0, help="seed of the built fixes (default 0)")
    p.add_argument("--gnss-gap", metavar="START,DURATION", help="no fixes from START (s from "
                   "the replay's start, or 'mid': centred) for DURATION s; the drift at the "
                   "gap's end is reported")
    p.add_argument("--rule", choices=RULES, default=None, help="the rule reported as flown "
                   "(default: the config's estimator.name); the other three run beside it")
    p.add_argument("--lever-arm", metavar="X,Y,Z", help="IMU → GNSS antenna, body FLU (m); "
                   "default the log's, else 0")
    p.add_argument("--gnss-delay", type=float, metavar="S", help="age of a fix at its time "
                   "stamp (default: 0.11 ULog, 0.22 DataFlash, 0 CSV / built fixes)")
    p.add_argument("--clock-lag", type=float, metavar="S", help="IMU clock + S = reference "
                   "clock (default: found by cross-correlation on a Phantom path, else 0)")
    p.add_argument("--heading", choices=("auto", "reference", "autopilot", "gnss-course"),
                   default="auto", help="initial heading source (auto: reference, else the "
                   "autopilot's, else the GNSS course once faster than 1 m/s)")
    p.add_argument("--imu-file", metavar="NAME", help="the Phantom path's IMU file (default "
                   "IMU_avg.csv, else IMU_1.csv)")
    p.add_argument("--uere", type=float, metavar="M", help="a DataFlash fix's σ per unit of "
                   "HDOP (m; default 2): those logs report no accuracy")
    p.add_argument("--q-margins", metavar="ACCEL,GYRO", help="process-noise margins on the "
                   "log's white noise, in variance (default: the simulated flight's, "
                   "estimator.ins_q_accel / ins_q_gyro: 1,1)")
    p.add_argument("--no-coning", action="store_true", help="integrate the samples as rates "
                   "held over the step (no coning or sculling correction; default: corrected, "
                   "as the simulated flight's delta-angle IMU)")
    p.add_argument("--no-gnss-velocity", action="store_true", help="fuse GNSS positions only")
    p.add_argument("--out", default="runs", help="root folder of the run folders (default runs)")
    p.add_argument("--run-id", help="run folder name (default replay-<log name>)")
    p.add_argument("--overwrite", action="store_true", help="replace a previous run's outputs")
    p.add_argument("--no-log", action="store_true", help="no MCAP (summary.json only)")
    p.set_defaults(func=_replay, cmd="replay")
