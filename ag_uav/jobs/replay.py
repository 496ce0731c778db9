"""One replayed flight, as ``fly`` leaves a run: read the log, run the INS bank on it
(:mod:`ag_uav.navigation.replay`), write ``run.mcap`` (:mod:`ag_uav.record.replay_log`) and
``summary.json`` into the run folder, and the estimator table for the terminal.

``summary.json``: ``info`` (source, clock lag and its correlation, mounting, the IMU's white
noise, rate, GNSS delay, lever arm, the initial state's sources), ``notes`` (what the reader
did), ``against`` / ``against_label`` (the reference, or the autopilot's estimate where there
is no reference), ``estimators.<rule>`` (:func:`~ag_uav.navigation.replay.score_replay`), the
flown rule's ``reference_tilt_rms_deg`` and ``reference_pos_rms_m`` when a reference exists
(``autopilot_pos_rms_m`` against the autopilot's estimate otherwise), ``gnss_gap`` and the
flown rule's ``gap_drift_m`` when a gap was asked.
"""

from __future__ import annotations

import json
import time
from pathlib import Path

from ..navigation.replay import ReplayOptions, read_log, run_replay, score_replay
from ..record.atomic import atomic_path, atomic_write_text
from ..record.replay_log import write_replay_mcap
from .outdir import check_reuse, hold, unique_run_dir

__all__ = ["replay", "replay_table"]


def replay(path: str, opts: ReplayOptions, out_root: str = "runs", run_id: str | None = None,
           overwrite: bool = False, imu_file: str | None = None,
           mcap: bool = True, uere_m: float | None = None) -> tuple[dict, Path]:
    """Replay ``path`` into a run folder; (summary, folder)."""
    t0 = time.perf_counter()
    log = read_log(path, imu_file, uere_m)
    res = run_replay(log, opts)
    sc = score_replay(res)
    flown = res.rules[0]
    s = {"command": "replay", "info": res.info, "notes": log.notes, **sc,
         "duration_s": round(float(res.t[-1] - res.t[0]), 2), "gnss_fixes": int(res.fix_t.size)}
    f = sc["estimators"][flown]
    if sc["against"] == "reference":
        s["reference_tilt_rms_deg"] = f.get("tilt_rms_deg")
        s["reference_pos_rms_m"] = f.get("pos_h_rms_m")
    elif sc["against"] == "autopilot":
        s["autopilot_pos_rms_m"] = f.get("pos_h_rms_m")
    if res.gap is not None:
        s["gnss_gap"] = [round(res.gap[0], 3), round(res.gap[1], 3)]
        s["gap_drift_m"] = f.get("gap_drift_m")
    base = f"replay-{Path(path).resolve().name.replace('.', '_')}"
    root = Path(out_root)
    run_dir = root / run_id if run_id else unique_run_dir(root, base)
    run_dir.mkdir(parents=True, exist_ok=True)
    with hold(run_dir, "replay", "another ag-uav run writes there"):
        check_reuse(run_dir, overwrite)
        if mcap:
            with atomic_path(run_dir / "run.mcap") as tmp:
                s["mcap_messages"] = write_replay_mcap(tmp, res, s)
        s["wall_s"] = round(time.perf_counter() - t0, 2)
        atomic_write_text(run_dir / "summary.json", json.dumps(s, indent=2) + "\n")
    return s, run_dir


def _f(v, fmt: str = ".3f") -> str:
    return "-" if v is None else format(v, fmt)


def replay_table(s: dict, run_dir: Path | None = None) -> str:
    """The estimator table (and the alignment lines) of a replay summary."""
    info = s["info"]
    lines = [f"replay: {info['source']} {info['path']} ({s['duration_s']:.1f} s, "
             f"{s['gnss_fixes']} fixes, IMU {info['imu_rate_hz']:g} Hz)"]
    if "clock_lag_s" in info:
        lines.append(f"clock lag: IMU + {info['clock_lag_s']:+.3f} s = reference "
                     f"(correlation {info.get('clock_lag_corr', float('nan')):.3f})")
    if "mount_rpy_deg" in info:
        lines.append(f"IMU mounting (roll, pitch, yaw °): {info['mount_rpy_deg']} "
                     f"(rate residual {info['mount_rate_residual_dps']:.2f} °/s)")
    lines.append(f"start: {info['init']['position']}; {info['init']['attitude']}")
    lines += [f"note: {n}" for n in s["notes"]]
    who = s["against_label"] or "nothing (no reference, no autopilot estimate)"
    vs = ("against the autopilot's estimate, " if s["against"] == "autopilot" else "against ")
    lines.append(f"estimators (INS, {vs}{who}):")
    hdr = ("rule", "pos h RMS/max (m)", "with fixes (m)", "pos v (m)", "vel (m/s)",
           "roll/pitch (°)", "tilt (°)", "yaw (°)", "NIS pos", "NIS vel", "rejected",
           "gap drift (m)")
    rows = [hdr]
    for i, (rule, e) in enumerate(s["estimators"].items()):
        rows.append((rule + (" *" if i == 0 else ""),
                     f"{_f(e.get('pos_h_rms_m'))} / {_f(e.get('pos_h_max_m'))}",
                     _f(e.get("pos_h_rms_with_fixes_m")),
                     _f(e.get("pos_v_rms_m")), _f(e.get("vel_rms_mps")),
                     f"{_f(e.get('roll_rms_deg'), '.2f')} / {_f(e.get('pitch_rms_deg'), '.2f')}",
                     _f(e.get("tilt_rms_deg"), ".2f"), _f(e.get("yaw_rms_deg"), ".2f"),
                     _f(e.get("nis_pos_mean"), ".2f"), _f(e.get("nis_vel_mean"), ".2f"),
                     f"{e['gate_rejected']}+{e['gate_latched']}/{e['fixes']}",
                     _f(e.get("gap_drift_m"))))
    w = [max(len(r[j]) for r in rows) for j in range(len(hdr))]
    lines += ["  " + "  ".join(c.ljust(w[j]) for j, c in enumerate(r)) for r in rows]
    lines.append("  (* flown; with fixes: the ticks within 1 s of a fix; rejected = gate "
                 "rejections + fixes held by the latch / fixes)")
    rej = next(iter(s["estimators"].values()))["rejected_t_s"]
    more = f" ... ({len(rej)} in all)" if len(rej) > 30 else ""
    lines.append("fixes the gate rejected (flown rule), t s: "
                 + (", ".join(f"{x:.1f}" for x in rej[:30]) + more if rej else "none"))
    if "gnss_gap" in s:
        g = s["gnss_gap"]
        lines.append(f"GNSS gap {g[0]:.1f}–{g[1]:.1f} s: drift at its end {_f(s['gap_drift_m'])} m")
    if run_dir is not None:
        lines.append(f"run folder: {run_dir}")
    return "\n".join(lines)
