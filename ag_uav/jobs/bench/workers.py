"""Throughput of the local process pool: a batch of short missions flown with 1 and 2 workers
(``ag-uav bench``'s worker section)."""

from __future__ import annotations

import copy
import os
import time
from collections.abc import Sequence
from typing import Any

from ...config import Config, config_from_dict
from ..executor import LocalPoolExecutor

__all__ = ["bench_workers"]


def _bench_task(cfg_dict: dict[str, Any]) -> float:
    from ...engine.missions import simulate

    res = simulate(config_from_dict(cfg_dict))
    return float(res.summary["sim_time_s"])


def bench_workers(cfg: Config, repeats: int = 1, quick: bool = False, *,
                  n_runs: int | None = None, workers: Sequence[int] = (1, 2),
                  mission_s: float | None = None) -> dict[str, Any]:
    """Throughput of a batch of short missions on the local process pool with 1 and 2 workers
    (pools started and warmed up before timing; best of ``repeats``).

    Returns ``{"workers": {"runs": n, "mission_sim_s": ..., "runs_per_s_w1": ...,
    "runs_per_s_w2": ..., "speedup_w2": ...}}``. The missions are ``cfg`` with seeds 0..n-1,
    no log and ``sim.max_time_s`` capped at ``mission_s`` (default 30 s, 15 s with ``quick``).
    """
    c = copy.deepcopy(cfg)
    c.log.enabled = False
    cap = mission_s if mission_s is not None else (15.0 if quick else 30.0)
    c.sim.max_time_s = min(c.sim.max_time_s, cap)
    n = n_runs if n_runs is not None else (8 if quick else 16)
    items = []
    for s in range(n):
        d = c.to_dict()
        d["seed"] = s
        items.append(d)
    out: dict[str, Any] = {"runs": n, "mission_sim_s": cap, "cores": os.cpu_count()}
    rates: dict[int, float] = {}
    for w in workers:
        best = 0.0
        with LocalPoolExecutor(w) as ex:
            ex.warm_up()
            for _ in range(max(1, repeats)):
                t0 = time.perf_counter()
                sims = ex.map(_bench_task, items)
                dt = time.perf_counter() - t0
                best = max(best, n / dt)
        rates[w] = best
        out[f"runs_per_s_w{w}"] = round(best, 3)
        out[f"sim_s_per_wall_s_w{w}"] = round(best * (sum(sims) / n), 1)
    w0 = min(workers)
    for w in workers:
        if w != w0:
            out[f"speedup_w{w}"] = round(rates[w] / rates[w0], 3)
    return {"workers": out}
