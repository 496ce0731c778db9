"""What ``ag-uav gnss fit`` prints and draws: the Allan deviation table, the fitted model, the
scatter against the reported accuracy, the preset block, the check of a simulated preset
against the log (:mod:`ag_uav.analysis.gnss_fit`), and the plot of the Allan deviation measured
against the model per axis."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from ..record.atomic import savefig
from .gnss_fit import CHECK_TAU_S, LogFit, preset_toml

__all__ = ["fit_report", "compare_report", "plot_fit"]

_STAT_NAMES = (("std_e", "std east (m)"), ("std_n", "std north (m)"), ("std_u", "std up (m)"),
               ("h_rms", "horizontal RMS about the mean (m)"),
               ("adev60_h", f"horizontal Allan deviation at {CHECK_TAU_S:g} s (m)"))


def fit_report(fit: LogFit, name: str) -> str:
    """The text of a fit: selection, scatter, reported-accuracy ratios, Allan deviation table
    (measured / model), the fitted terms per axis and the preset block."""
    st = fit.stats
    out = [f"{fit.path}: {fit.source}", fit.selection.line,
           f"scatter about the mean: std E {st['std_e']:.4g} m, N {st['std_n']:.4g} m, "
           f"U {st['std_u']:.4g} m; horizontal RMS {st['h_rms']:.4g} m; horizontal Allan "
           f"deviation at {CHECK_TAU_S:g} s {st['adev60_h']:.4g} m"]
    r = fit.ratios
    if r:
        parts = [f"{k} RMS {r[k + '_rms_m']:.4g} m -> actual / reported {r[k]:.2f}"
                 for k in ("hAcc", "vAcc", "pAcc") if k in r]
        out.append("reported accuracy (actual = RMS about the mean, horizontal / vertical / "
                   "3-D): " + "; ".join(parts))
    else:
        out.append("reported accuracy: none in the log")
    out += ["", "Allan deviation (m), measured / model; H = east and north together",
            f"{'tau_s':>7} " + " ".join(f"{ax:>19}" for ax in "ENUH")]
    taus = fit.axes["H"].tau
    for tau in taus:
        cells = []
        for ax in "ENUH":
            a = fit.axes[ax]
            j = np.flatnonzero(np.isclose(a.tau, tau))
            cells.append(f"{a.adev[j[0]]:9.4g} /{a.model_adev[j[0]]:9.4g}" if j.size
                         else f"{'-':>19}")
        out.append(f"{tau:7.0f} " + " ".join(cells))
    out += ["", "fitted model: white (sigma) + Gauss-Markov (sigma, tau) [+ random walk (q per "
            "sample)]",
            f"{'axis':>4} {'scatter_m':>10} {'white_m':>10} {'gm_sigma_m':>11} {'gm_tau_s':>9} "
            f"{'rw_q_m':>9} {'rms_log_err':>11}"]
    for ax in "ENUH":
        a = fit.axes[ax]
        out.append(f"{ax:>4} {a.scatter_std:10.4g} {a.white:10.3g} {a.gm_sigma:11.3g} "
                   f"{a.gm_tau_s:9.4g} {a.rw_q:9.3g} {a.rms_log_err:11.3f}")
    out += ["", "preset block (paste into a run config):", preset_toml(fit, name)]
    return "\n".join(out)


def compare_report(fit: LogFit, label: str, sims: list[dict[str, float]], seeds: range) -> str:
    """The log's scatter figures beside those of ``sims`` (one per seed): seed 0, the median
    and the RMS over seeds (the RMS estimates the model's expected value), and RMS / log."""
    lines = [f"simulated {label} with the product's generator at the log's rate and length: "
             f"{fit.n} fixes at {1 / fit.dt:g} Hz, seeds {seeds.start}-{seeds.stop - 1}",
             f"{'quantity':<42} {'log':>9} {'seed 0':>9} {'median':>9} {'RMS':>9} "
             f"{'RMS/log':>8}"]
    for key, text in _STAT_NAMES:
        v = np.array([s[key] for s in sims])
        rms = float(np.sqrt(np.mean(v**2)))
        lines.append(f"{text:<42} {fit.stats[key]:9.4g} {v[0]:9.4g} {np.median(v):9.4g} "
                     f"{rms:9.4g} {rms / fit.stats[key]:8.2f}")
    return "\n".join(lines)


def plot_fit(fit: LogFit, path: str | Path) -> Path:
    """PNG: per axis (E, N, U) the measured Allan deviation (dots), the axis's fitted model
    (line) and, for E and N, the horizontal model the preset uses (dashed)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axs = plt.subplots(1, 3, figsize=(13, 4), sharex=True)
    for ax, name in zip(axs, "ENU", strict=True):
        a = fit.axes[name]
        ax.loglog(a.tau, a.adev, "o", label="log")
        ax.loglog(a.tau, a.model_adev, "-", label="fitted model")
        if name in "EN":
            h = fit.axes["H"]
            ax.loglog(h.tau, h.model_adev, "--", label="preset (horizontal model)")
        ax.set_title({"E": "east", "N": "north", "U": "up"}[name])
        ax.set_xlabel("tau (s)")
        ax.grid(True, which="both", alpha=0.3)
    axs[0].set_ylabel("Allan deviation (m)")
    axs[0].legend(fontsize=8)
    fig.suptitle(f"{Path(fit.path).name}: {fit.n} epochs ({'/'.join(fit.selection.keep)})",
                 fontsize=10)
    fig.tight_layout()
    try:
        return savefig(fig, path, dpi=110)
    finally:
        plt.close(fig)
