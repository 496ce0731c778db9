"""Estimator section of ``ag-uav bench``: per-update cost of the filter bank (and filterpy's KF).

Everything is measured in one process, in one run, on identical data, so the figures can be
compared with each other (not with figures from another machine or another run):

- **paper model** (Candan & Li eqs 8-11: 2-D CV, 4 states, 2 measurements, ``Ts = 0.05 s``,
  ``R = diag(10, 100) m²``): a track simulated from the model, fixes ``H x + v`` with white
  ``v ~ N(0, R)`` plus 5 % outliers (``20 · √R_ii · N(0, 1)`` on a channel with probability
  0.05).  Figure: µs per ``predict() + update(z)`` pair, for our KF, filterpy's
  ``KalmanFilter`` (fed column vectors, its native layout), MCKF, PCA-KF and PCA-MCKF in both
  PCA readings (hankel, channels), all with their default options (σ = 2, ``max_iter`` = 10,
  window 20).
- **in-loop model** (what :mod:`ag_uav.navigation.estimation` runs: 3-D CVB, 9 states, 3
measurements,
  predicted at 100 Hz, a fix every 10th tick): µs per ``predict()`` and per ``update(z)``
  separately (update = time of the predict+update loop − time of the predict-only loop), and
  µs of filter work per second of flight.

Timing: each filter runs ``n`` steps per repeat on a fresh instance; the repeats are
interleaved across filters (so load spikes on a shared machine hit them alike) and the figure is
the best of ``repeats`` (timeit's convention: the minimum is the run least disturbed by other
processes); the median is given as well.  ``ratio_to_filterpy`` = ours / filterpy's (< 1: ours
is faster).
"""

from __future__ import annotations

import gc
import math
import statistics
import time
from collections.abc import Callable
from typing import Any

import numpy as np

import estimators
from estimators.models import motion_model, paper_numerical_model

OUTLIER_PROB = 0.05
OUTLIER_SCALE = 20.0
LOOP_PREDICT_HZ = 100.0
LOOP_FIX_EVERY = 10  # 10 Hz fixes


def _simulate(F, Q, H, R, n: int, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """Truth from the model (process noise Q) and fixes with white noise + 5 % outliers."""
    nx, m = F.shape[0], H.shape[0]
    Lq = np.linalg.cholesky(Q + 1e-15 * np.eye(nx))
    x = np.zeros(nx)
    X = np.empty((n, nx))
    for k in range(n):
        x = F @ x + Lq @ rng.standard_normal(nx)
        X[k] = x
    std = np.sqrt(np.diag(R))
    Z = X @ H.T + std * rng.standard_normal((n, m))
    hit = rng.random((n, m)) < OUTLIER_PROB
    Z += hit * OUTLIER_SCALE * std * rng.standard_normal((n, m))
    return X, Z


def _paper_filters(mdl, x0, P0) -> dict[str, Callable[[], Any]]:
    F, H, Q, R = mdl.F, mdl.H, mdl.Q, mdl.R
    return {
        "kf": lambda: estimators.KF(F, H, Q, R, x0, P0),
        "mckf": lambda: estimators.MCKF(F, H, Q, R, x0, P0),
        "pca_kf_hankel": lambda: estimators.PCAKF(F, H, Q, R, x0, P0, mode="hankel"),
        "pca_kf_channels": lambda: estimators.PCAKF(F, H, Q, R, x0, P0, mode="channels"),
        "pca_mckf_hankel": lambda: estimators.PCAMCKF(F, H, Q, R, x0, P0, mode="hankel"),
        "pca_mckf_channels": lambda: estimators.PCAMCKF(F, H, Q, R, x0, P0, mode="channels"),
    }


def _filterpy_factory(F, H, Q, R, x0, P0) -> Callable[[], Any] | None:
    try:
        from filterpy.kalman import KalmanFilter
    except ImportError:
        return None

    def make():
        f = KalmanFilter(F.shape[0], H.shape[0])
        f.F, f.H, f.Q, f.R = F.copy(), H.copy(), Q.copy(), R.copy()
        f.x, f.P = x0.reshape(-1, 1).copy(), P0.copy()
        return f

    return make


def _time_pu(make: Callable[[], Any], Z: list) -> float:
    """Seconds for len(Z) predict+update pairs on a fresh filter."""
    f = make()
    predict, update = f.predict, f.update
    t0 = time.perf_counter()
    for z in Z:
        predict()
        update(z)
    return time.perf_counter() - t0


def _time_loop(make: Callable[[], Any], Z: list, every: int, with_update: bool) -> float:
    """Seconds for len(Z) ticks of the in-loop schedule: predict each tick, a fix every
    ``every`` ticks (skipped when ``with_update`` is False)."""
    f = make()
    predict, update = f.predict, f.update
    t0 = time.perf_counter()
    for k, z in enumerate(Z):
        predict()
        if with_update and k % every == 0:
            update(z)
    return time.perf_counter() - t0


def _summary(samples: list[float], per: int) -> dict[str, float]:
    us = [1e6 * s / per for s in samples]
    return {"us": round(min(us), 2), "median_us": round(statistics.median(us), 2)}


def bench_estimators(repeats: int = 5, n: int = 2000, seed: int = 0) -> dict[str, Any]:
    """µs per predict+update of the estimator bank (see the module docstring).

    Returns ``{"paper_model": {...}, "in_loop_model": {...}, "filterpy": version or note}``;
    each filter's entry holds ``us`` (best of ``repeats``) and ``median_us``; the paper-model KF
    entry also ``ratio_to_filterpy``.
    """
    repeats, n = max(1, int(repeats)), max(50, int(n))
    rng = np.random.default_rng(seed)
    out: dict[str, Any] = {}
    gc_was = gc.isenabled()
    gc.disable()
    try:
        paper, out["filterpy"] = _paper_model(rng, n, repeats)
        out["paper_model"] = paper
        out["in_loop_model"] = _in_loop_model(rng, n, repeats)
        out["n"], out["repeats"] = n, repeats
    finally:
        if gc_was:
            gc.enable()
    return out


def _paper_model(rng: np.random.Generator, n: int, repeats: int) -> tuple[dict[str, Any], str]:
    """The paper model's filters (and filterpy's KF, if installed): their figures and what
    filterpy was."""
    mdl = paper_numerical_model()
    _, Z = _simulate(mdl.F, mdl.Q, mdl.H, mdl.R, n, rng)
    x0, P0 = np.zeros(mdl.n), 100.0 * np.eye(mdl.n)
    makers = _paper_filters(mdl, x0, P0)
    fp = _filterpy_factory(mdl.F, mdl.H, mdl.Q, mdl.R, x0, P0)
    if fp is not None:
        makers["filterpy_kf"] = fp
    Zlist = [z.copy() for z in Z]
    Zcol = [z.reshape(-1, 1).copy() for z in Z]
    samples: dict[str, list[float]] = {k: [] for k in makers}
    for name, make in makers.items():  # warm-up (imports, caches)
        _time_pu(make, (Zcol if name == "filterpy_kf" else Zlist)[:50])
    for _ in range(repeats):
        for name, make in makers.items():
            samples[name].append(_time_pu(make, Zcol if name == "filterpy_kf" else Zlist))
    paper = {name: _summary(s, n) for name, s in samples.items()}
    if fp is not None:
        ref = paper["filterpy_kf"]
        for name, d in paper.items():
            if name != "filterpy_kf":
                d["ratio_to_filterpy"] = round(d["us"] / ref["us"], 3)
        import filterpy

        note = f"filterpy {filterpy.__version__}"
    else:
        note = "filterpy not installed"
    paper["model"] = "paper eqs 8-11: 4 states, 2 measurements; white + 5% outliers"
    return paper, note


def _in_loop_model(rng: np.random.Generator, n: int, repeats: int) -> dict[str, Any]:
    """The in-loop model's four filters (and filterpy's KF): predict and update µs, µs per
    flight second."""
    dt = 1.0 / LOOP_PREDICT_HZ
    # the bank's model: CV + IMU input-bias states (cvb), RTK-class R, radar height
    lm = motion_model("cvb", 3, dt, q=1e-4, q_bias=2e-4, r=[1e-4, 1e-4, 0.0025])
    _, Zl = _simulate(lm.F, lm.Q, lm.H, lm.R, n, rng)
    Zl_list = [z.copy() for z in Zl]
    x0l, P0l = np.zeros(lm.n), np.diag([1e-4, 4.0, 0.005] * 2 + [0.0025, 4.0, 0.005])
    loop_makers = {
        name: (lambda name=name: estimators.make(
            name, F=lm.F, H=lm.H, Q=lm.Q, R=lm.R, x0=x0l, P0=P0l))
        for name in ("kf", "mckf", "pca-kf", "pca-mckf")
    }
    lfp = _filterpy_factory(lm.F, lm.H, lm.Q, lm.R, x0l, P0l)
    Zl_col = [z.reshape(-1, 1).copy() for z in Zl]
    if lfp is not None:
        loop_makers["filterpy_kf"] = lfp
    n_upd = math.ceil(n / LOOP_FIX_EVERY)
    ls: dict[str, dict[str, list[float]]] = {k: {"p": [], "pu": []} for k in loop_makers}
    for _ in range(repeats):
        for name, make in loop_makers.items():
            data = Zl_col if name == "filterpy_kf" else Zl_list
            ls[name]["p"].append(_time_loop(make, data, LOOP_FIX_EVERY, False))
            ls[name]["pu"].append(_time_loop(make, data, LOOP_FIX_EVERY, True))
    loop: dict[str, Any] = {}
    for name, d in ls.items():
        p_us = min(d["p"]) * 1e6 / n
        u_us = max(min(d["pu"]) - min(d["p"]), 0.0) * 1e6 / n_upd
        per_s = (min(d["pu"]) * 1e6 / n) * LOOP_PREDICT_HZ
        loop[name.replace("-", "_")] = {
            "predict_us": round(p_us, 2),
            "update_us": round(u_us, 2),
            "us_per_flight_s": round(per_s, 1),
        }
    if lfp is not None:
        for name, d in loop.items():
            if name != "filterpy_kf":
                ref = loop["filterpy_kf"]
                d["ratio_to_filterpy"] = round(d["us_per_flight_s"] / ref["us_per_flight_s"], 3)
    loop["model"] = (f"3-D CVB (CV + input bias), 9 states, 3 measurements; predict "
                     f"{LOOP_PREDICT_HZ:g} Hz, "
                     f"fix every {LOOP_FIX_EVERY} ticks")
    return loop


if __name__ == "__main__":  # pragma: no cover
    import json

    print(json.dumps(bench_estimators(), indent=1))
