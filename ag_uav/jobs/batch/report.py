"""A batch's results: ``results.csv`` (columns in a fixed order), the summary table (mean ±
95 % CI per group), ``report.md`` and its figures."""

from __future__ import annotations

import csv
import math
from collections.abc import Callable, Iterable, Sequence
from pathlib import Path
from typing import Any

from ...record.atomic import atomic_open, atomic_write_text, savefig
from .spec import BatchSpec
from .worker import EARLY_STATUSES, row_reason

#: columns that lead results.csv, before the axis columns
LEAD_COLUMNS = ("index", "run_id")
#: summary metrics in display order (any other scalar metric follows, sorted by name)
METRIC_ORDER = ("status", "crash_reason", "incomplete_reason", "engine_fallback", "completed",
                "crashed", "crash_time_s", "mission_time_s",
                "tracking_rmse_m", "estimate_rmse_m", "cross_track_rmse_m", "cross_track_max_m",
                "altitude_rmse_m", "coverage_fraction", "overlap_fraction", "path_length_m",
                "planned_path_length_m", "legs", "legs_flown", "final_position_error_m",
                "field_area_m2", "sim_time_s", "wall_time_s", "loop_wall_time_s",
                "real_time_factor")


def is_timing_column(name: str) -> bool:
    """Columns that measure the machine (or how the run was scheduled: ``batch_size``, the size
    of the lockstep chunk it flew in; ``worker_host`` and ``worker_pid``, the process that flew
    it), not the run (excluded from determinism checks)."""
    n = name.lower()
    return ("wall" in n or "cpu_time" in n or "real_time_factor" in n
            or n.endswith(("_per_s", "_us"))
            or "timing" in n or n in ("batch_size", "worker_host", "worker_pid"))


# ------------------------------------------------------------------------------------ results
def ordered_columns(rows: Sequence[dict[str, Any]], axis_names: Sequence[str]) -> list[str]:
    keys: set[str] = set()
    for r in rows:
        keys.update(r)
    cols = [c for c in LEAD_COLUMNS if c in keys] + [a for a in axis_names if a in keys]
    cols += [c for c in METRIC_ORDER if c in keys and c not in cols]
    cols += sorted(k for k in keys if k not in cols)
    return cols


def _csv_value(v: Any) -> str:
    if v is None:
        return ""
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, float):
        return repr(v)
    return str(v)


def write_results_csv(rows: Sequence[dict[str, Any]], path: str | Path,
                      axis_names: Sequence[str] = ()) -> list[str]:
    """Write rows sorted by run index (atomic replace); returns the columns."""
    rows = sorted(rows, key=lambda r: r.get("index", 0))
    cols = ordered_columns(rows, axis_names)

    def write(f: Any) -> None:
        w = csv.writer(f)
        w.writerow(cols)
        for r in rows:
            w.writerow([_csv_value(r.get(c)) for c in cols])

    with atomic_open(path, "w", newline="") as f:
        write(f)
    return cols


def read_results_csv(path: str | Path) -> list[dict[str, str]]:
    with Path(path).open(newline="") as f:
        return list(csv.DictReader(f))


# ------------------------------------------------------------------------------------- stats
def mean_ci(values: Iterable[Any], level: float = 0.95) -> tuple[float, float, int]:
    """Mean and the half-width of its Student-t confidence interval over the finite values."""
    xs = [float(v) for v in values if v is not None and v != "" and math.isfinite(float(v))]
    n = len(xs)
    if n == 0:
        return math.nan, math.nan, 0
    m = sum(xs) / n
    if n == 1:
        return m, math.nan, 1
    from scipy import stats

    s = math.sqrt(sum((x - m) ** 2 for x in xs) / (n - 1))
    return m, float(stats.t.ppf(0.5 + level / 2, n - 1)) * s / math.sqrt(n), n


def group_rows(rows: Sequence[dict[str, Any]], keys: Sequence[str]
               ) -> dict[tuple[Any, ...], list[dict[str, Any]]]:
    out: dict[tuple[Any, ...], list[dict[str, Any]]] = {}
    for r in rows:
        out.setdefault(tuple(r.get(k) for k in keys), []).append(r)
    return out


#: (column, label, scale, format) of the summary table
SUMMARY_METRICS = (
    ("mission_time_s", "mission time (s)", 1.0, "{:.1f}"),
    ("tracking_rmse_m", "tracking RMSE (m)", 1.0, "{:.3f}"),
    ("estimate_rmse_m", "estimate RMSE (m)", 1.0, "{:.3f}"),
    ("cross_track_rmse_m", "cross-track RMSE (m)", 1.0, "{:.3f}"),
    ("coverage_fraction", "coverage (%)", 100.0, "{:.2f}"),
)


def summary_rows(rows: Sequence[dict[str, Any]], group_keys: Sequence[str]
                 ) -> tuple[list[str], list[list[str]]]:
    """The batch summary table: per group, runs, ok, ended early (failsafe, cut, incomplete),
    crashed, error, and mean ± 95 % CI over the ok runs only (the column "ok = in the means"
    says how many; a metric a run lacks is averaged over fewer, marked "(n = k)")."""
    metrics = [m for m in SUMMARY_METRICS if any(r.get(m[0]) not in (None, "") for r in rows)]
    header = list(group_keys) + ["runs", "ok = in the means", "ended early", "crashed",
                                 "error"] + [m[1] for m in metrics]
    table = []
    for key, rs in sorted(group_rows(rows, group_keys).items(), key=lambda kv: _natural(kv[0])):
        n_ok = sum(r.get("status") == "ok" for r in rs)
        line = [str(k) for k in key]
        line += [str(len(rs)), str(n_ok), str(sum(r.get("status") in EARLY_STATUSES for r in rs)),
                 str(sum(r.get("status") == "crashed" for r in rs)),
                 str(sum(r.get("status") == "error" for r in rs))]
        for col, _, scale, fmt in metrics:
            m, h, n = mean_ci(r.get(col) for r in rs if r.get("status") == "ok")
            if n == 0:
                line.append("–")
                continue
            cell = (fmt.format(m * scale) if math.isnan(h)
                    else f"{fmt.format(m * scale)} ± {fmt.format(h * scale)}")
            line.append(cell if n == n_ok else f"{cell} (n = {n})")
        table.append(line)
    return header, table


def status_counts(rows: Sequence[dict[str, Any]]) -> str:
    """``"8 runs: 5 ok, 2 ended early (failsafe 1, cut 1), 1 crashed, 0 error"``."""
    n = {s: sum(r.get("status") == s for r in rows)
         for s in ("ok", *EARLY_STATUSES, "crashed", "error")}
    early = sum(n[s] for s in EARLY_STATUSES)
    why = ", ".join(f"{s} {n[s]}" for s in EARLY_STATUSES if n[s])
    return (f"{len(rows)} runs: {n['ok']} ok, {early} ended early" + (f" ({why})" if why else "")
            + f", {n['crashed']} crashed, {n['error']} error")


def _natural(key: tuple[Any, ...]) -> tuple[tuple[int, float, str], ...]:
    """Sort key: numbers numerically, then strings."""
    out = []
    for k in key:
        x = as_number(k)
        out.append((0, x, "") if x is not None else (1, 0.0, str(k)))
    return tuple(out)


def print_table(header: Sequence[str], table: Sequence[Sequence[str]], title: str) -> None:
    from rich.console import Console
    from rich.table import Table

    t = Table(title=title, header_style="bold")
    for i, h in enumerate(header):
        t.add_column(h, justify="left" if i == 0 else "right")
    for line in table:
        t.add_row(*line)
    import sys

    Console(width=None if sys.stdout.isatty() else 160).print(t)


def markdown_table(header: Sequence[str], table: Sequence[Sequence[str]]) -> str:
    lines = ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
    lines += ["| " + " | ".join(line) + " |" for line in table]
    return "\n".join(lines) + "\n"


# ------------------------------------------------------------------------------------- report
def as_number(v: Any) -> float | None:
    """``v`` as a finite float (a CSV cell, a row value), else None."""
    try:
        x = float(v)
    except (TypeError, ValueError):
        return None
    return x if math.isfinite(x) else None


def _saved(fig: Any, path: Path, plt: Any) -> Path:
    """Lay out, write (110 dpi) and close a report figure; its path."""
    fig.tight_layout()
    savefig(fig, path, dpi=110)
    plt.close(fig)
    return path


def _rmse_figure(ok: list[dict[str, Any]], noise_key: str | None, label: Callable[[dict], str],
                 out: Path, plt: Any) -> Path | None:
    """``rmse.png``: RMSE distributions per group, one column per noise case (None: no data)."""
    metrics = [m for m in ("tracking_rmse_m", "estimate_rmse_m")
               if any(as_number(r.get(m)) is not None for r in ok)]
    cases = sorted({str(r.get(noise_key)) for r in ok}) if noise_key else ["all"]
    if not (metrics and ok):
        return None
    fig, axs = plt.subplots(len(metrics), len(cases), squeeze=False,
                            figsize=(max(5.0, 4.2 * len(cases)), 3.4 * len(metrics)))
    for j, case in enumerate(cases):
        sel = [r for r in ok if not noise_key or str(r.get(noise_key)) == case]
        labels = sorted({label(r) for r in sel})
        for i, m in enumerate(metrics):
            data = [[as_number(r.get(m)) for r in sel if label(r) == lb
                     and as_number(r.get(m)) is not None] for lb in labels]
            ax = axs[i][j]
            if any(data):
                ax.boxplot([d or [math.nan] for d in data], showmeans=True)
                ax.set_xticks(range(1, len(labels) + 1), labels, rotation=20, fontsize=8)
            ax.set_ylabel(m.replace("_m", " (m)").replace("_", " "))
            ax.set_title(f"{noise_key} = {case}" if noise_key else "RMSE distribution",
                         fontsize=9)
            ax.grid(alpha=0.3)
    return _saved(fig, out / "rmse.png", plt)


def _tracking_figure(ok: list[dict[str, Any]], label: Callable[[dict], str], out: Path,
                     plt: Any) -> Path | None:
    """``tracking_vs_estimate.png``: tracking against estimate error per run (None: no data)."""
    pairs = [(r, as_number(r.get("estimate_rmse_m")), as_number(r.get("tracking_rmse_m")))
             for r in ok]
    pairs = [(r, e, t) for r, e, t in pairs if e is not None and t is not None]
    if not pairs:
        return None
    fig, ax = plt.subplots(figsize=(5.5, 4.2))
    for lb in sorted({label(r) for r, _, _ in pairs}):
        xs = [e for r, e, _ in pairs if label(r) == lb]
        ys = [t for r, _, t in pairs if label(r) == lb]
        ax.scatter(xs, ys, s=12, label=lb, alpha=0.7)
    lim = max(max(e for _, e, _ in pairs), max(t for _, _, t in pairs)) * 1.05
    ax.plot([0, lim], [0, lim], "k--", lw=0.8, label="y = x")
    ax.set_xlabel("estimate RMSE (m)")
    ax.set_ylabel("tracking RMSE (m)")
    ax.legend(fontsize=7)
    ax.grid(alpha=0.3)
    return _saved(fig, out / "tracking_vs_estimate.png", plt)


def _coverage_figure(ok: list[dict[str, Any]], label: Callable[[dict], str], out: Path,
                     plt: Any) -> Path | None:
    """``coverage.png``: spray coverage per group (None: no data)."""
    cov = [(label(r), as_number(r.get("coverage_fraction"))) for r in ok]
    cov = [(lb, c) for lb, c in cov if c is not None]
    if not cov:
        return None
    labels = sorted({lb for lb, _ in cov})
    fig, ax = plt.subplots(figsize=(max(5.0, 1.1 * len(labels) + 2), 3.6))
    ax.boxplot([[100 * c for lb2, c in cov if lb2 == lb] for lb in labels], showmeans=True)
    ax.set_xticks(range(1, len(labels) + 1), labels, rotation=20, fontsize=8)
    ax.set_ylabel("spray coverage (%)")
    ax.grid(alpha=0.3)
    return _saved(fig, out / "coverage.png", plt)


def _report_markdown(rows: Sequence[dict[str, Any]], spec: BatchSpec, group_keys: list[str],
                     info: dict[str, Any], figures: list[Path]) -> str:
    """The text of ``report.md``: counts, axes, the summary table, failed runs, the figures."""
    header, table = summary_rows(rows, group_keys)
    md = [f"# Batch `{spec.name}`", ""]
    if spec.description:
        md += [spec.description, ""]
    md += [f"- {status_counts(rows)}"]
    n_fb = sum(bool(r.get("engine_fallback")) for r in rows)
    md += [f"- engine fallbacks: {n_fb} runs flown one at a time after their engine batch "
           "failed (column `engine_fallback`)" if n_fb else "- engine fallbacks: 0"]
    md += ["- axes: " + "; ".join(f"`{a.name}` × {len(a.values)}" for a in spec.axes)]
    for k, v in info.items():
        md.append(f"- {k}: {v}")
    n_ok = sum(r.get("status") == "ok" for r in rows)
    md += ["", f"Mean ± 95 % confidence half-width (Student t) over the {n_ok} of {len(rows)} "
           "runs with status ok (the column \"ok = in the means\"; a mission flown to its end): "
           "the runs that ended early (failsafe, cut by `sim.max_time_s`, incomplete), crashed "
           "or failed are not in the means and are listed below.", "",
           markdown_table(header, table)]
    bad = [r for r in rows if r.get("status") != "ok"]
    if bad:
        md += ["## Crashed / failed runs", "",
               "Every run whose status is not ok: ended early, crashed, or failed.", "",
               markdown_table(["index", "status", "reason"],
                              [[str(r.get("index")), str(r.get("status")),
                                row_reason(r).replace("|", "\\|")] for r in bad[:50]])]
        if len(bad) > 50:
            md.append(f"... and {len(bad) - 50} more (see results.csv)\n")
    for p in figures:
        md += [f"![{p.stem}]({p.name})", ""]
    return "\n".join(md)


def write_report(rows: Sequence[dict[str, Any]], spec: BatchSpec, out_dir: str | Path,
                 info: dict[str, Any] | None = None) -> list[Path]:
    """``report.md`` and PNG figures: RMSE distributions per estimator and noise case, tracking
    vs estimate error, coverage. Returns the files written."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    out = Path(out_dir)
    group_keys = [a.name for a in spec.axes if a.name != "seed" and len(a.values) > 1]
    noise_key = "gps.preset" if "gps.preset" in group_keys else None
    box_keys = [k for k in group_keys if k != noise_key]
    ok = [r for r in rows if r.get("status") == "ok"]

    def label(r: dict[str, Any]) -> str:
        return " / ".join(str(r.get(k)) for k in box_keys) or "all"

    figures = [_rmse_figure(ok, noise_key, label, out, plt), _tracking_figure(ok, label, out, plt),
               _coverage_figure(ok, label, out, plt)]
    written = [p for p in figures if p is not None]
    rp = out / "report.md"
    atomic_write_text(rp, _report_markdown(rows, spec, group_keys, info or {}, written))
    written.insert(0, rp)
    return written
