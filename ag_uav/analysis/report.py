"""Human-facing output: the summary table printed after a run."""

from __future__ import annotations

from pathlib import Path
from typing import Any

from rich import box
from rich.console import Console
from rich.table import Table

from ..world.mission import offset_text

#: (summary key, label, format, unit)
ROWS = [
    ("completed", "completed", "{}", ""),
    ("crashed", "crashed", "{}", ""),
    ("crash_reason", "crash reason", "{}", ""),
    ("incomplete_reason", "not completed", "{}", ""),
    ("gnss_loss", "GNSS loss", "{}", ""),
    ("mission_time_s", "mission time", "{:.1f}", "s"),
    ("tracking_rmse_m", "tracking RMSE (horizontal)", "{:.3f}", "m"),
    ("cross_track_rmse_m", "cross-track RMSE", "{:.3f}", "m"),
    ("cross_track_max_m", "cross-track max", "{:.3f}", "m"),
    ("altitude_rmse_m", "altitude RMSE", "{:.3f}", "m"),
    ("coverage_fraction", "spray coverage", "{:.2%}", ""),
    ("overlap_fraction", "double-covered", "{:.2%}", ""),
    ("path_length_m", "path flown", "{:.0f}", "m"),
    ("legs", "sweep legs", "{}", ""),
    ("field_area_m2", "field area", "{:.0f}", "m²"),
    ("sorties", "sorties", "{}", ""),
    ("litres_sprayed_l", "litres sprayed", "{:.2f}", "L"),
    ("energy_wh", "battery energy used", "{:.1f}", "Wh"),
    ("mass_start_kg", "take-off mass", "{:.2f}", "kg"),
    ("mass_end_kg", "mass at the end", "{:.2f}", "kg"),
    ("job_time_s", "job time (with base visits)", "{:.1f}", "s"),
    ("fill_l", "fill per sortie (battery-bound)", "{:.1f}", "L"),
    ("work_rate_ha_per_h", "work rate (with base visits)", "{:.2f}", "ha/h"),
    ("work_rate_stated_ha_per_h", "manufacturer's stated rate", "{:.1f}", "ha/h"),
    ("off_target_m2", "off-target spray", "{:.1f}", "m²"),
    ("dose_mean_l_per_ha", "dose on the field (mean)", "{:.3f}", "L/ha"),
    ("dose_cv", "dose CV", "{:.1%}", ""),
    ("underdosed_fraction", "under-dosed area (< 80 %)", "{:.1%}", ""),
    ("overdosed_fraction", "over-dosed area (> 120 %)", "{:.1%}", ""),
    ("offtarget_deposit_fraction", "deposit off the field", "{:.2%}", "of sprayed"),
    ("drift_fraction", "drift past the buffer", "{:.3%}", "of sprayed"),
    ("nozzle_sprayed_l", "litres out of the nozzles", "{:.3f}", "L"),
    ("battery_below_reserve", "battery below reserve", "{}", ""),
    ("tank_ran_dry", "tank ran dry", "{}", ""),
    ("estimate_rmse_m", "estimate RMSE (horizontal)", "{:.3f}", "m"),
    ("tilt_error_rms_deg", "tilt error RMS (INS, flown)", "{:.3f}", "°"),
    ("tilt_error_max_deg", "tilt error max (INS, flown)", "{:.3f}", "°"),
    ("yaw_error_rms_deg", "yaw error RMS (INS, flown)", "{:.3f}", "°"),
    ("false_fix_episodes", "GNSS false-fix episodes", "{}", ""),
    ("range_aid_fixes", "fixes on radar height", "{}", ""),
    ("sim_time_s", "sim time", "{:.1f}", "s"),
    ("wall_time_s", "wall time", "{:.2f}", "s"),
    ("real_time_factor", "loop speed", "{:.0f}", "× real time"),
    ("frames", "camera frames", "{}", ""),
]


def print_summary(summary: dict[str, Any], run_dir: Path | None = None,
                  console: Console | None = None) -> None:
    console = console or Console()
    t = Table(title="ag-uav run summary", show_header=True, header_style="bold")
    t.add_column("metric")
    t.add_column("value", justify="right")
    for key, label, fmt, unit in ROWS:
        if key not in summary or summary[key] is None:
            continue
        v = summary[key]
        if key == "crash_reason" and not v:
            continue
        try:
            s = fmt.format(v)
        except (ValueError, TypeError):
            s = str(v)
        if key == "completed":
            s = "[green]yes[/]" if v else "[red]no[/]"
        if key in ("battery_below_reserve", "tank_ran_dry"):
            s = "[red]yes[/]" if v else "no"
        if key == "crashed":
            s = "[red]yes[/]" if v else "[green]no[/]"
        t.add_row(label, f"{s} {unit}".strip())
        if key == "legs" and isinstance(summary.get("lanes"), dict):
            t.add_row("lane spacing", _lanes_cell(summary["lanes"]))
        if key == "drift_fraction" and summary.get("drift_fraction_low") is not None:
            t.add_row("  its low – high bounds", f"{summary['drift_fraction_low']:.3%} – "
                      f"{summary['drift_fraction_high']:.3%}")
    console.print(t)
    if isinstance(summary.get("lanes"), dict):
        console.print(summary["lanes"]["text"], markup=False, highlight=False)
        moved = _offset_line(summary)
        if moved:
            console.print(moved, markup=False, highlight=False)
    if isinstance(summary.get("plan_wind"), dict):
        console.print(summary["plan_wind"]["text"], markup=False, highlight=False)
    est = summary.get("estimators")
    if est:
        console.print(estimator_table(est))
    for note in summary.get("notes", []):
        console.print(f"[yellow]note:[/] {note}")
    if run_dir is not None:
        console.print(f"run folder: {run_dir}")


def _offset_line(summary: dict) -> str:
    """The plan's upwind move as the summary records it ("" when not moved)."""
    setting = summary.get("config", {}).get("mission", {}).get("upwind_offset_m", "auto")
    return offset_text(summary["lanes"].get("offset_m", (0.0, 0.0)), setting)


def _lanes_cell(lanes: dict[str, Any]) -> str:
    """``4.75 m (auto; legs 4.51 m apart)``."""
    s = f"{lanes['swath_m']:g} m ({lanes['source']}"
    if lanes.get("leg_spacing_m") is not None:
        s += f"; legs {lanes['leg_spacing_m']:.2f} m apart"
    return s + ")"


def estimator_table(scores: dict[str, dict[str, Any]]) -> Table:
    """Every filter of the bank on the very same fixes: the flown one marked."""
    if any("nees15_mean" in s for s in scores.values()):
        return _ins_table(scores)
    t = Table(title="estimators (ideal-attitude stand-in; same fixes; * = flown)",
              show_header=True, header_style="bold")
    for col in ("filter", "RMSE (m)", "max (m)", "NEES (3 = consistent)", "NIS (3)",
                "update (µs)"):
        t.add_column(col, justify="left" if col == "filter" else "right")

    def f(v: Any, fmt: str) -> str:
        return "–" if v is None else fmt.format(v)

    for name, s in scores.items():
        label = f"[bold]{name} *[/]" if s.get("flown") else name
        t.add_row(label, f(s.get("estimate_rmse_m"), "{:.3f}"),
                  f(s.get("estimate_max_m"), "{:.3f}"), f(s.get("nees_mean"), "{:.2f}"),
                  f(s.get("nis_mean"), "{:.2f}"),
                  f(s.get("update_us"), "{:.0f}"))
    return t


def _ins_table(scores: dict[str, dict[str, Any]]) -> Table:
    """The INS bank (``estimator.nav = "ins"``): position, velocity and attitude errors and the
    NEES of the 15-state error per GNSS update rule, all on the very same IMU samples and
    fixes."""
    flown = next((v for v in scores.values() if v.get("flown")), None)
    caption = ("RMS errors of position (m; max too), velocity (m/s), tilt (RMS/max) and yaw "
               "(°); NEES15 of the 15-state error (15 = consistent")
    if flown and flown.get("nees15_band95"):
        lo, hi = flown["nees15_band95"]
        caption += (f"; 95 % band of the flown filter's mean {lo:.1f}–{hi:.1f}, for "
                    f"{flown['nees15_n_eff']:.0f} effective fixes: successive fixes' NEES are "
                    "correlated, so their mean varies as that of fewer independent ones")
    not_pd = {n: s["nees15_not_pd"] for n, s in scores.items() if s.get("nees15_not_pd")}
    if not_pd:
        caption += ("; fixes left out of the NEES, their P not positive definite: "
                    + ", ".join(f"{n} {k}" for n, k in not_pd.items()))
    if flown and flown.get("nees_pos_mean") is not None:
        caption += ("; the flown filter's NEES per 3-state block (3 = consistent): " + ", ".join(
            f"{lab} {flown[f'nees_{b}_mean']:.1f}" for b, lab in
            (("pos", "position"), ("vel", "velocity"), ("att", "attitude"),
             ("ba", "accel bias"), ("bg", "gyro bias")) if flown.get(f"nees_{b}_mean")
            is not None))
    if flown and flown.get("gate_rejected") is not None:
        caption += (f"; the innovation gate rejected {flown['gate_rejected']} of its fixes "
                    f"({flown.get('gate_latched') or 0} of them held by the step latch and "
                    f"fused relative to the step; {flown.get('gate_resets') or 0} resets)")
    caption += _why_not(scores)
    t = Table(title="estimators (INS; same fixes; * = flown)", caption=caption + ")",
              show_header=True, header_style="bold", box=box.SIMPLE_HEAD)
    for col in ("rule", "pos", "max", "vel", "tilt", "yaw", "NEES15", "NIS (3)"):
        t.add_column(col, justify="left" if col == "rule" else "right", no_wrap=True)

    def f(v: Any, fmt: str) -> str:
        return "–" if v is None else fmt.format(v)

    for name, s in scores.items():
        label = f"[bold]{name} *[/]" if s.get("flown") else name
        nees = f(s.get("nees15_mean"), "{:.1f}")
        t.add_row(label, f(s.get("estimate_rmse_m"), "{:.3f}"),
                  f(s.get("estimate_max_m"), "{:.3f}"), f(s.get("velocity_rmse_mps"), "{:.3f}"),
                  f"{f(s.get('tilt_error_rms_deg'), '{:.2f}')}/"
                  f"{f(s.get('tilt_error_max_deg'), '{:.2f}')}",
                  f(s.get("yaw_error_rms_deg"), "{:.2f}"), nees,
                  f(s.get("nis_mean"), "{:.2f}"))
    return t


def _why_not(scores: dict[str, dict[str, Any]]) -> str:
    """Why the flown filter's NEES15 lies outside its band, where the run says why: the
    false-fix episodes (the share of their fixes the gate rejected, the peak error)."""
    s = next((v for v in scores.values() if v.get("flown")), None)
    if not s or s.get("nees15_mean") is None or not s.get("nees15_band95"):
        return ""
    lo, hi = s["nees15_band95"]
    if lo <= s["nees15_mean"] <= hi:
        return ""
    above = s["nees15_mean"] > hi
    why = f". The flown filter's NEES15 is {'above' if above else 'below'} it"
    if not above:
        why += (": its covariance is conservative here (it claims more error than it makes; "
                "docs/ins.md: consistency)")
    elif s.get("false_fixes_rejected") is not None:
        why += (f": the run had false RTK fixes (the gate rejected "
                f"{s['false_fixes_rejected']:.0%} of them; peak error through them "
                f"{s['false_fix_peak_m']:.2f} m), which no filter's covariance covers")
    else:
        why += " (docs/ins.md: consistency, what is left)"
    return why
