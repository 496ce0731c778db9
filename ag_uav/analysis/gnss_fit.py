"""Fitting a GNSS error model to a static receiver's log: Allan deviation per axis, a
white + first-order Gauss–Markov (+ random walk) model, the scatter against the accuracy the
receiver reported, and a preset block for :mod:`ag_uav.vehicle.gps`.

Per axis (east, north, up about the mean of the kept epochs, :meth:`GnssLog.enu`) the position
error ``y_k`` is fitted with the sum of independent terms

    y_k = w_k + b_k (+ r_k),   w white (σ_w),  b Gauss–Markov (σ_g, T),  r random walk (q)

by least squares on the logarithm of the overlapping Allan variance at octave-spaced τ
(:mod:`ag_uav.analysis.allan`: the analytic variance of each term adds, the terms being
independent), plus one more residual: the expected variance about the mean over the log's
length ``E[s²]`` against the measured one, weighted 10 √(number of τ): in effect a constraint
that the model's expected scatter about the mean over the log's length is the log's, with the
Allan variance fitted within it (a Gauss–Markov term with T not much shorter than the log hides
part of its variance in the mean, which this accounts for).  Where the log's Allan deviation
rises faster than τ^{1/2} (a receiver whose navigation filter smooths its output: slope +1, as
the standalone M8P log shows up to ~60 s), no first-order term can follow it, and the fit
keeps the scatter and the long-τ level at the cost of overstating the short-τ deviation; the
RMS log error of the fit (``rms_log_err``) says by how much.  The GM analytic form is
IEEE Std 952-1997 Annex C and El-Sheimy, Hou & Niu 2008 (IEEE Trans. Instrum. Meas. 57(1),
correlated noise); see :func:`~ag_uav.analysis.allan.avar_gm_continuous` and the exact discrete form
used here, :func:`~ag_uav.analysis.allan.avar_gm`.  The random-walk term is tried too and kept
("auto") only when it halves the fit's sum of squares.

The product's generator (:mod:`ag_uav.vehicle.gps.noise`) has white and Gauss–Markov terms but
no random walk: a fitted random walk of step q is written as a Gauss–Markov term with
``T_rw`` = the log's length and ``σ = q √(T_rw / (2 τ0))``, whose Allan variance
``2σ²τ/(3T_rw) = q²τ/(3τ0)`` is the random walk's for τ ≪ T_rw; its expected scatter over the
log's length is 0.79 of the random walk's.  No correlation time is fitted beyond the log's
length either (the bound of T): a log cannot show a longer one, and a longer T would put into
the preset a stationary variance (a per-flight offset) the log never showed.

The preset block models the horizontal axes with one isotropic model fitted to the mean of the
east and north Allan variances (a flight's direction is arbitrary) and the vertical with its
own, in the format of :func:`~ag_uav.vehicle.gps.gps_preset`: one white component scaled per
axis, a horizontal Gauss–Markov (``axis_scale = [1, 1, 0]``) and a vertical one
(``[0, 0, 1]``), at the log's rate.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from ..vehicle.gps import GpsSensor
from .allan import (
    avar_gm,
    avar_rw,
    avar_white,
    octave_m,
    overlapping_avar,
    scatter_gm,
    scatter_rw,
    scatter_white,
)
from .gnss_log import GnssLog, GnssLogError, Selection

__all__ = ["AxisFit", "fit_axis", "fit_log", "LogFit", "preset_components", "preset_toml",
           "scatter_stats", "simulate_stats"]

#: the τ (s) at which a log and a simulation are compared besides the scatter
CHECK_TAU_S = 60.0
#: the terms :func:`fit_axis` can fit
MODELS = ("auto", "white+gm", "white+gm+rw")
#: weight of the scatter residual, per √(number of τ): large enough to act as a constraint
SCATTER_WEIGHT = 10.0
_RW_T_FACTOR = 1.0


@dataclass
class AxisFit:
    """One axis: measured Allan deviation at ``tau`` (s), the scatter about the mean, and the
    fitted model (``rw_q = 0`` without a random walk) with its Allan deviation at ``tau``."""

    axis: str
    tau: np.ndarray
    adev: np.ndarray
    scatter_std: float
    white: float
    gm_sigma: float
    gm_tau_s: float
    rw_q: float
    model_adev: np.ndarray
    rms_log_err: float

    def model_avar(self, m: np.ndarray, dt: float) -> np.ndarray:
        v = avar_white(self.white, m) + avar_gm(self.gm_sigma, self.gm_tau_s, m, dt)
        return v + avar_rw(self.rw_q, m) if self.rw_q > 0 else v


def _model(p: np.ndarray, m: np.ndarray, dt: float, n: int) -> tuple[np.ndarray, float]:
    sw, sg, tc = math.exp(p[0] / 2), math.exp(p[1] / 2), math.exp(p[2])
    av = avar_white(sw, m) + avar_gm(sg, tc, m, dt)
    sc = scatter_white(sw, n) + scatter_gm(sg, tc, n, dt)
    if p.size > 3:
        q = math.exp(p[3] / 2)
        av = av + avar_rw(q, m)
        sc += scatter_rw(q, n)
    return av, sc


def fit_axis(axis: str, avar: np.ndarray, m: np.ndarray, dt: float, n: int, scatter_var: float,
             model: str = "auto") -> AxisFit:
    """Least-squares fit of white + GM (``model`` "white+gm"), white + GM + random walk
    ("white+gm+rw") or the better of the two ("auto": the random walk only where it halves the
    sum of squares) to the Allan variance ``avar`` at cluster sizes ``m`` (sample interval
    ``dt``) and the variance ``scatter_var`` about the mean of ``n`` samples."""
    from scipy.optimize import least_squares

    if model not in MODELS:
        raise ValueError(f"model = {model!r} is invalid; allowed: {', '.join(MODELS)}")
    ok = np.isfinite(avar) & (avar > 0)
    if ok.sum() < 2:
        raise GnssLogError(f"axis {axis}: the position does not vary (Allan variance zero or "
                           "undefined at all but one tau); nothing to fit")
    mm, la = m[ok], np.log(avar[ok])
    ws = SCATTER_WEIGHT * math.sqrt(mm.size)
    ls = math.log(max(scatter_var, 1e-30))

    def res(p: np.ndarray) -> np.ndarray:
        av, sc = _model(p, mm, dt, n)
        return np.append(np.log(np.maximum(av, 1e-300)) - la, ws * (math.log(max(sc, 1e-300))
                                                                   - ls))

    t_hi = n * dt
    best: dict[int, Any] = {}
    for k in ((3,) if model == "white+gm" else (4,) if model == "white+gm+rw" else (3, 4)):
        lo = [math.log(1e-30), math.log(1e-30), math.log(dt)] + [math.log(1e-30)] * (k - 3)
        hi = [math.log(10 * avar[ok][0] + scatter_var) + 5, ls + 5, math.log(t_hi)] \
            + [la.max() + 5] * (k - 3)
        for t0 in np.unique(np.clip(np.concatenate((mm * dt, [n * dt])), dt * 1.01, t_hi * .99)):
            p0 = [math.log(avar[ok][0]), ls, math.log(t0)] + [math.log(avar[ok][0]) - 6] * (k - 3)
            p0 = np.clip(p0, np.array(lo) + 1e-9, np.array(hi) - 1e-9)
            r = least_squares(res, p0, bounds=(lo, hi), method="trf")
            if k not in best or r.cost < best[k].cost:
                best[k] = r
    k = 4 if 4 in best and (3 not in best or best[4].cost < 0.5 * best[3].cost) else 3
    p = best[k].x
    fm = AxisFit(axis, mm * dt, np.sqrt(avar[ok]), math.sqrt(scatter_var),
                 math.exp(p[0] / 2), math.exp(p[1] / 2), math.exp(p[2]),
                 math.exp(p[3] / 2) if k == 4 else 0.0, np.array([]), 0.0)
    fm.model_adev = np.sqrt(fm.model_avar(mm, dt))
    fm.rms_log_err = float(np.sqrt(np.mean(np.log(fm.model_adev / fm.adev) ** 2)))
    return fm


def scatter_stats(enu: np.ndarray, dt: float, segments: list[tuple[int, int]] | None = None
                  ) -> dict[str, float]:
    """Std about the mean per axis, horizontal RMS about the mean and the horizontal Allan
    deviation at :data:`CHECK_TAU_S` (RMS of east and north)."""
    e = enu - enu.mean(axis=0)
    m = np.array([max(1, round(CHECK_TAU_S / dt))])
    av = [overlapping_avar(e[:, i], m, segments)[0][0] for i in range(2)]
    return {"std_e": float(e[:, 0].std()), "std_n": float(e[:, 1].std()),
            "std_u": float(e[:, 2].std()),
            "h_rms": float(np.sqrt(np.mean(e[:, 0] ** 2 + e[:, 1] ** 2))),
            "adev60_h": float(np.sqrt(np.mean(av)))}


@dataclass
class LogFit:
    """The fit of a log: per-axis fits (E, N, U), the horizontal (H, for the preset), the
    scatter figures, the reported-accuracy ratios and the selection behind them."""

    path: str
    source: str
    selection: Selection
    n: int
    dt: float
    axes: dict[str, AxisFit]
    stats: dict[str, float]
    ratios: dict[str, float] = field(default_factory=dict)


def _ratios(log: GnssLog, mask: np.ndarray, enu: np.ndarray) -> dict[str, float]:
    """Actual scatter (RMS about the mean) over the RMS of the reported accuracy."""
    out = {}
    h = math.sqrt(float(np.mean(enu[:, 0] ** 2 + enu[:, 1] ** 2)))
    v = math.sqrt(float(np.mean(enu[:, 2] ** 2)))
    p3 = math.sqrt(float(np.mean(np.sum(enu**2, axis=1))))
    for key, act, acc in (("hAcc", h, log.h_acc), ("vAcc", v, log.v_acc),
                          ("pAcc", p3, log.p_acc)):
        a = acc[mask]
        a = a[np.isfinite(a)]
        if a.size:
            out[key] = act / math.sqrt(float(np.mean(a**2)))
            out[key + "_rms_m"] = math.sqrt(float(np.mean(a**2)))
    return out


def fit_log(log: GnssLog, sel: Selection, model: str = "auto") -> LogFit:
    """Fit every axis of the selected epochs (see module docstring)."""
    enu = log.enu(sel.mask)
    n = enu.shape[0]
    m = octave_m(n)
    av = {}
    var = {}
    for i, ax in enumerate("ENU"):
        av[ax] = overlapping_avar(enu[:, i], m, sel.segments)[0]
        var[ax] = float(enu[:, i].var())
    av["H"] = 0.5 * (av["E"] + av["N"])
    var["H"] = 0.5 * (var["E"] + var["N"])
    try:
        axes = {ax: fit_axis(ax, av[ax], m, sel.dt, n, var[ax], model) for ax in "ENUH"}
    except GnssLogError as e:
        raise GnssLogError(f"{log.path}: {e}") from None
    return LogFit(log.path, log.source, sel, n, sel.dt, axes,
                  scatter_stats(enu, sel.dt, sel.segments), _ratios(log, sel.mask, enu))


def _walk(f: AxisFit, n: int, dt: float) -> tuple[float, float]:
    """(σ, T) of the Gauss–Markov term standing for an axis's random walk (module docstring);
    σ = 0 without one."""
    t_rw = _RW_T_FACTOR * n * dt
    return f.rw_q * math.sqrt(t_rw / (2.0 * dt)), t_rw


def preset_components(fit: LogFit) -> dict[str, Any]:
    """The fitted model as a preset dict of :mod:`ag_uav.vehicle.gps.presets`."""
    h, u = fit.axes["H"], fit.axes["U"]
    r = lambda x: float(f"{x:.3g}")  # noqa: E731 - three significant figures
    wh, wu = h.white, u.white
    if max(wh, wu) < 1e-4 * min(h.scatter_std, u.scatter_std):  # no white term to speak of
        wh = wu = 0.0
    w = max(wh, wu)
    comps: list[dict[str, Any]] = [
        {"type": "gaussian", "name": "white", "sigma": r(w),
         "axis_scale": [r(wh / w), r(wh / w), r(wu / w)] if w > 0
         else [1.0, 1.0, 1.0]},
        {"type": "gauss-markov", "name": "gm", "sigma": r(h.gm_sigma), "tau_s": r(h.gm_tau_s),
         "axis_scale": [1.0, 1.0, 0.0]},
        {"type": "gauss-markov", "name": "gm-up", "sigma": r(u.gm_sigma),
         "tau_s": r(u.gm_tau_s), "axis_scale": [0.0, 0.0, 1.0]},
    ]
    for f, name, scale in ((h, "slow", [1.0, 1.0, 0.0]), (u, "slow-up", [0.0, 0.0, 1.0])):
        sig, t_rw = _walk(f, fit.n, fit.dt)
        if sig > 0:
            comps.append({"type": "gauss-markov", "name": name, "sigma": r(sig),
                          "tau_s": r(t_rw), "axis_scale": scale})
    return {"rate_hz": r(1.0 / fit.dt), "latency_s": 0.0, "axis_scale": [1.0, 1.0, 1.0],
            "components": comps, "outage": {}}


def _toml_value(v: Any) -> str:
    if isinstance(v, dict):
        return "{ " + ", ".join(f"{k} = {_toml_value(x)}" for k, x in v.items()) + " }"
    if isinstance(v, list):
        return "[" + ", ".join(_toml_value(x) for x in v) + "]"
    if isinstance(v, str):
        return f'"{v}"'
    return repr(float(v)) if isinstance(v, float) else str(v)


def preset_toml(fit: LogFit, name: str = "fitted") -> str:
    """A ``[gps]`` block to paste into a run config: the ``perfect`` preset (no error) with the
    fitted model as its overrides."""
    cfg = preset_components(fit)
    sel = fit.selection
    lines = [f"# {name}: fitted by `ag-uav gnss fit` on {fit.path}",
             f"# ({fit.n} epochs of fix type {'/'.join(sel.keep)} at {1 / fit.dt:g} Hz, "
             f"{fit.n * fit.dt:.0f} s)",
             "[gps]", 'preset = "perfect"', "", "[gps.overrides]"]
    for k in ("rate_hz", "latency_s", "axis_scale"):
        lines.append(f"{k} = {_toml_value(cfg[k])}")
    lines.append("components = [")
    lines += [f"  {_toml_value(c)}," for c in cfg["components"]]
    lines.append("]")
    return "\n".join(lines) + "\n"


def simulate_stats(cfg: dict[str, Any], n: int, dt: float, seeds: range
                   ) -> list[dict[str, float]]:
    """:func:`scatter_stats` of ``n`` fixes every ``dt`` drawn by the product's generator
    (:class:`~ag_uav.vehicle.gps.GpsSensor`) from preset dict ``cfg``, one per seed."""
    out = []
    for s in seeds:
        err = GpsSensor.from_config({**cfg, "rate_hz": 1.0 / dt}, s).generate_errors(n)
        out.append(scatter_stats(np.asarray(err), dt))
    return out
