"""A synthetic run (tests, demos, benchmarks): a drone flying a lawnmower over a small field,
logged through :class:`~ag_uav.record.runlog.RunLog` as the simulation would log it."""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Any

import numpy as np

from numkit.axes import QX, QY
from numkit.geometry import quat_normalize, yaw_to_quat

from .log_ticks import Tick
from .runlog import RunLog


def lawnmower_plan(
    width: float = 60.0, height: float = 40.0, swath: float = 8.0, altitude: float = 3.0
) -> list[tuple[str, np.ndarray, bool]]:
    """Boustrophedon legs along x over ``[0, width] x [0, height]`` with transits between."""
    segs: list[tuple[str, np.ndarray, bool]] = []
    ys = np.arange(swath / 2, height, swath)
    prev = None
    for i, y in enumerate(ys):
        xa, xb = (2.0, width - 2.0) if i % 2 == 0 else (width - 2.0, 2.0)
        leg = np.array([[xa, y, altitude], [xb, y, altitude]])
        if prev is not None:
            segs.append(("transit", np.array([prev, leg[0]]), False))
        segs.append(("leg", leg, True))
        prev = leg[1]
    return segs


def synthetic_run(
    log: RunLog,
    duration: float = 30.0,
    *,
    dt: float = 0.01,
    gps_hz: float = 10.0,
    speed: float = 4.0,
    seed: int = 0,
    estimators: Sequence[str] = ("kf", "mckf"),
    on_tick: Any = None,
    origin: Sequence[float] | None = None,
) -> int:
    """Drive ``log`` like the simulation would: ticks at ``1/dt``, GPS fixes (RTK fixed, one
    in five RTK float), estimators.

    ``on_tick(t, p, q_wxyz)`` is called after each tick (e.g. to pose a body and render).
    ``origin`` (lat, lon, h): the geographic topics too (:meth:`RunLog.geo`).  Returns the tick
    count.  Deterministic for a given ``seed``.
    """
    rng = np.random.default_rng(seed)
    plan = lawnmower_plan()
    outer = np.array([[0, 0], [60, 0], [60, 40], [0, 40]], dtype=float)
    hole = np.array([[28, 18], [32, 18], [32, 22], [28, 22]], dtype=float)
    if origin is not None:
        log.geo(origin, dose_target_l_per_ha=1.0)
    log.scene(0.0, outer, [hole], plan, swath=8.0, altitude=3.0)
    pts = np.concatenate([s[1] for s in plan])
    seg_len = np.linalg.norm(np.diff(pts, axis=0), axis=1)
    s_cum = np.concatenate([[0.0], np.cumsum(seg_len)])
    n = int(round(duration / dt))
    gps_every = max(1, int(round(1.0 / (gps_hz * dt))))
    lag = np.zeros(3)
    est = {name: np.zeros(6) for name in estimators}
    wind = np.array([2.0, 0.5, 0.0])
    for k in range(n):
        t = k * dt
        s = min(speed * t, s_cum[-1] - 1e-6)
        i = int(np.searchsorted(s_cum, s, side="right") - 1)
        i = min(i, len(seg_len) - 1)
        u = (s - s_cum[i]) / max(seg_len[i], 1e-9)
        d = (pts[i + 1] - pts[i]) / max(seg_len[i], 1e-9)
        p_ref = pts[i] + u * (pts[i + 1] - pts[i])
        v_ref = speed * d
        yaw = math.atan2(d[1], d[0])
        lag = 0.97 * lag + 0.03 * rng.normal(0.0, 0.3, 3)
        p = p_ref + lag
        v = v_ref + rng.normal(0.0, 0.05, 3)
        q = np.empty(4)
        yaw_to_quat(yaw, q)
        q[QX], q[QY] = 0.02, -0.03   # a small steady tilt
        quat_normalize(q, q)
        q = tuple(q.tolist())
        e = p_ref - p
        ctrl = {}
        for ax, ev in zip(("x", "y", "z"), e, strict=True):
            ctrl[f"{ax}.E"] = float(np.clip(0.3 * ev, -1, 1))
            ctrl[f"{ax}.dE"] = float(np.clip(0.1 * ev, -1, 1))
            ctrl[f"{ax}.U"] = 0.5 * ctrl[f"{ax}.E"]
            ctrl[f"{ax}.I"] = 0.01 * t
            ctrl[f"{ax}.u"] = 2.0 * ev
        motors = [0.5 + 0.01 * math.sin(t + j) for j in range(4)]
        p_est = next(iter(est.values()))[:3] if est else None
        log.tick(t, Tick(p_true=p, q_true_wxyz=q, v_true=v, p_ref=p_ref, v_ref=v_ref,
                         yaw_ref=yaw, p_est=p_est, v_est=v, ctrl=ctrl, motors=motors, wind=wind,
                         spray=plan[min(i, len(plan) - 1)][2]))
        if k % gps_every == 0:
            fix = p + rng.normal(0.0, 0.8, 3) * np.array([1, 1, 0.5])
            float_ = k % (5 * gps_every) == 0
            log.gps(t, fix, (0.64, 0.64, 0.16) if float_ else (0.01, 0.01, 0.02),
                    "rtk-float" if float_ else "rtk-fixed")
            for j, (name, x) in enumerate(est.items()):
                a = 0.3 + 0.2 * j
                innov = fix - x[:3]
                x[:3] += a * innov
                x[3:] = v
                log.estimator(t, name, x, np.full(6, 0.5 / (1 + j)), innov,
                              {"nis": float(innov @ innov)}, pos=x[:3])
        if on_tick is not None:
            on_tick(t, p, q)
    return n
