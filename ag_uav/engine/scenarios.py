"""Short deterministic flight scenarios (step responses, hover in steady wind) on the same loop
as the missions. Used by tests, by ``ag-uav tune`` costs and by the README's step figures."""

from __future__ import annotations

import copy
from dataclasses import dataclass

import numpy as np

from ..config import Config
from .loop import LoopOutput


@dataclass(frozen=True)
class RefSample:
    """Same fields as :class:`ag_uav.world.reference.RefSample`."""

    pos: np.ndarray
    vel: np.ndarray
    acc: np.ndarray
    yaw: float
    yaw_rate: float = 0.0
    spray: bool = False
    seg: int = -1


class StepReference:
    """Hover at ``p0`` and jump by ``step`` (m, world frame) at ``t_step`` (no feed-forward)."""

    def __init__(self, p0=(0.0, 0.0, 3.0), step=(1.0, 0.0, 0.0), t_step: float = 1.0,
                 yaw: float = 0.0) -> None:
        self.p0 = tuple(float(v) for v in p0)
        self.p1 = tuple(a + b for a, b in zip(self.p0, step, strict=True))
        self.t_step = t_step
        z = np.zeros(3)
        self._before = RefSample(np.array(self.p0), z, z, yaw)
        self._after = RefSample(np.array(self.p1), z, z, yaw)

    def sample(self, t: float) -> RefSample:
        return self._before if t < self.t_step else self._after

    def sample_all(self, times) -> dict[str, np.ndarray]:
        times = np.asarray(times, float)
        after = (times >= self.t_step)[:, None]
        n = len(times)
        return {"pos": np.where(after, self._after.pos, self._before.pos),
                "vel": np.zeros((n, 3)), "acc": np.zeros((n, 3)),
                "yaw": np.full(n, self._before.yaw), "yaw_rate": np.zeros(n),
                "spray": np.zeros(n, bool), "seg": np.full(n, -1)}


def hover_config(cfg: Config, wind_speed: float | None = None, turbulence: str = "none") -> Config:
    c = copy.deepcopy(cfg)
    c.sim.takeoff = False
    if wind_speed is not None:
        c.wind.speed_mps = wind_speed
    c.wind.turbulence = turbulence
    return c


def step_response(cfg: Config, axis: int = 0, size: float = 1.0, duration: float = 8.0,
                  t_step: float = 1.0, wind_speed: float = 0.0) -> tuple[np.ndarray, np.ndarray,
                                                                          LoopOutput]:
    """Step of ``size`` m on ``axis`` from hover at 3 m. Returns (t − t_step, response, output);
    the response is the axis position minus its start, for t ≥ t_step."""
    return step_responses([cfg], axis, size, duration, t_step, wind_speed)[0]


def step_responses(cfgs: list[Config], axis: int = 0, size: float = 1.0, duration: float = 8.0,
                   t_step: float = 1.0, wind_speed: float = 0.0,
                   ) -> list[tuple[np.ndarray, np.ndarray, LoopOutput]]:
    """:func:`step_response` of every config, flown as one engine batch (same results)."""
    from .loop import Flight, fly

    step = [0.0, 0.0, 0.0]
    step[axis] = size
    flights, refs = [], []
    for cfg in cfgs:
        c = hover_config(cfg, wind_speed)
        ref = StepReference(step=step, t_step=t_step)
        refs.append(ref)
        flights.append(Flight(c, ref, duration + t_step))
    res = []
    for ref, out in zip(refs, fly(flights), strict=True):
        sel = out.t >= t_step
        res.append((out.t[sel] - t_step, out.rec[sel, axis] - ref.p0[axis], out))
    return res


def step_metrics(t: np.ndarray, y: np.ndarray, size: float, band: float = 0.05) -> dict:
    """Overshoot (fraction of the step), settling time into ±band (m) and rise time 10–90 %."""
    err = np.abs(y - size)
    outside = np.flatnonzero(err > band)
    settle = float(t[outside[-1] + 1]) if outside.size and outside[-1] + 1 < len(t) else (
        0.0 if not outside.size else float("inf"))
    over = float(max(0.0, (np.max(y) - size) / size)) if size > 0 else float(
        max(0.0, (size - np.min(y)) / -size))
    i10 = np.flatnonzero(y >= 0.1 * size)
    i90 = np.flatnonzero(y >= 0.9 * size)
    rise = float(t[i90[0]] - t[i10[0]]) if i10.size and i90.size else float("inf")
    return {"overshoot": over, "settling_time_s": settle, "rise_time_s": rise,
            "final_error_m": float(err[-1])}
