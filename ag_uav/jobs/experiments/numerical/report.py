"""The numerical experiment's report: per-case tables with Student-t intervals, the track and
RMSE figures, the CSV files."""

from __future__ import annotations

import csv
import math
from pathlib import Path
from typing import Any

import numpy as np

from .setup import CASES, COLOURS, PAPER_MATLAB


# ---------------------------------------------------------------------------------- report
def t_interval(values: np.ndarray, level: float = 0.95) -> tuple[float, float]:
    """Mean and the half-width of its Student-t interval (nan for fewer than 2 values)."""
    v = np.asarray(values, dtype=float)
    v = v[np.isfinite(v)]
    if v.size == 0:
        return math.nan, math.nan
    if v.size == 1:
        return float(v[0]), math.nan
    from scipy import stats

    h = float(stats.t.ppf(0.5 + level / 2, v.size - 1)) * float(np.std(v, ddof=1))
    return float(np.mean(v)), h / math.sqrt(v.size)


def summarise(rows: list[dict[str, Any]], cases: list[str], ests: list[str]
              ) -> list[dict[str, Any]]:
    """One record per case × estimator (mean RMSE, 95 % t-interval, paired Δ vs KF, µs)."""
    recs = []
    for case in cases:
        by = {e: sorted((r for r in rows if r["case"] == case and r["estimator"] == e),
                        key=lambda r: r["run"]) for e in ["gps", *ests]}
        kf = np.array([r["rmse_m"] for r in by.get("kf", [])])
        for e in ["gps", *ests]:
            v = np.array([r["rmse_m"] for r in by[e]])
            m, h = t_interval(v)
            if kf.size == v.size and kf.size and e != "kf":
                dm, dh = t_interval(v - kf)
            else:
                dm, dh = math.nan, math.nan
            us = np.array([r["update_us"] for r in by[e]], dtype=float)
            us = us[np.isfinite(us)]
            pt, pr = PAPER_MATLAB.get(e, (math.nan, math.nan))
            recs.append({"case": case, "preset": CASES[case], "estimator": e, "runs": v.size,
                         "rmse_m": m, "rmse_ci95_m": h,
                         "rmse_x_m": float(np.mean([r["rmse_x_m"] for r in by[e]])),
                         "rmse_y_m": float(np.mean([r["rmse_y_m"] for r in by[e]])),
                         "delta_vs_kf_m": dm, "delta_ci95_m": dh,
                         "update_us": float(np.mean(us)) if us.size else math.nan,
                         "timed_runs": int(us.size),
                         "paper_matlab_time_s": pt, "paper_matlab_rmse_m": pr})
    return recs


def _f(v: float, fmt: str) -> str:
    return "–" if v is None or not math.isfinite(v) else fmt.format(v)


def _pm(m: float, h: float, fmt: str, signed: bool = False) -> str:
    if not math.isfinite(m):
        return "–"
    s = ("{:+" + fmt[2:]).format(m) if signed else fmt.format(m)
    return s if not math.isfinite(h) else f"{s} ± {fmt.format(h)}"


HEADER = ["estimator", "RMSE (m), mean ± 95 % t", "x / y RMSE (m)", "Δ vs KF (m), paired",
          "update (µs/step)", "paper time (s)", "paper RMSE (m)"]


def table_lines(recs: list[dict[str, Any]], case: str) -> list[list[str]]:
    out = []
    for r in recs:
        if r["case"] != case:
            continue
        out.append([r["estimator"] if r["estimator"] != "gps" else "gps (raw fixes)",
                    _pm(r["rmse_m"], r["rmse_ci95_m"], "{:.3f}"),
                    f"{r['rmse_x_m']:.2f} / {r['rmse_y_m']:.2f}",
                    _pm(r["delta_vs_kf_m"], r["delta_ci95_m"], "{:.3f}", signed=True),
                    _f(r["update_us"], "{:.0f}"), _f(r["paper_matlab_time_s"], "{:.0f}"),
                    _f(r["paper_matlab_rmse_m"], "{:.3f}")])
    return out


def plot_tracks(kept: dict[tuple[str, int], dict[str, np.ndarray]], pos: np.ndarray,
                cases: list[str], ests: list[str], run: int, path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    n = len(cases)
    cols = 2 if n > 1 else 1
    rows_ = math.ceil(n / cols)
    fig, axs = plt.subplots(rows_, cols, figsize=(7 * cols, 4.2 * rows_), squeeze=False)
    for ax, case in zip(axs.flat, cases, strict=False):
        tr = kept.get((case, run))
        if tr is None:
            continue
        ax.plot(tr["fixes"][:, 0], tr["fixes"][:, 1], ".", color="0.7", ms=2,
                label="GPS fixes")
        ax.plot(pos[:, 0], pos[:, 1], "k-", lw=2, label="reference")
        # the coloured-noise baselines are jagged on white noise: draw them first, faint
        for e in sorted(ests, key=lambda e: e in PAPER_MATLAB):
            main_ = e in PAPER_MATLAB
            ax.plot(tr[e][:, 0], tr[e][:, 1], "-", lw=1.0 if main_ else 0.6,
                    alpha=1.0 if main_ else 0.45, color=COLOURS.get(e), label=e)
        span = np.ptp(pos[:, 1])
        ax.set_ylim(pos[:, 1].min() - 0.6 * span - 5, pos[:, 1].max() + 0.6 * span + 5)
        ax.set_title(f"{case} ({CASES[case]}), run {run}", fontsize=9)
        ax.set_xlabel("x (m)")
        ax.set_ylabel("y (m)")
        ax.grid(alpha=0.3)
    for ax in list(axs.flat)[n:]:
        ax.axis("off")
    axs.flat[0].legend(fontsize=7, ncol=2, loc="upper right")
    fig.suptitle("Numerical experiment (Candan & Li eqs 8-11, Fig. 3 style): "
                 "R = diag(10, 100) m², Ts = 0.05 s", fontsize=10)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def plot_rmse(rows: list[dict[str, Any]], cases: list[str], ests: list[str], path: Path
              ) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axs = plt.subplots(1, len(cases), figsize=(3.6 * len(cases) + 1, 4), squeeze=False)
    for ax, case in zip(axs[0], cases, strict=True):
        data = [[r["rmse_m"] for r in rows if r["case"] == case and r["estimator"] == e]
                for e in ests]
        ax.boxplot(data, showmeans=True)
        ax.set_xticks(range(1, len(ests) + 1), ests, rotation=45, fontsize=8)
        paper = [PAPER_MATLAB.get(e, (0, math.nan))[1] for e in ests]
        ax.plot(range(1, len(ests) + 1), paper, "r*", ms=9, label="paper Table II (Matlab)")
        ax.set_title(case, fontsize=9)
        ax.set_ylim(bottom=0)
        ax.grid(alpha=0.3)
    axs[0, 0].set_ylabel("position RMSE per run (m)")
    axs[0, 0].legend(fontsize=7, loc="lower left")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def write_csv(path: Path, recs: list[dict[str, Any]]) -> None:
    with path.open("w", newline="") as f:
        w = csv.DictWriter(f, fieldnames=list(recs[0]))
        w.writeheader()
        for r in recs:
            w.writerow({k: ("" if isinstance(v, float) and math.isnan(v) else
                            (f"{v:.12g}" if isinstance(v, float) else v))
                        for k, v in r.items()})
