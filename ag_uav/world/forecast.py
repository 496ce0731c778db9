"""The wind a plan is made on, and the wind flown.

A spray plan is made before the flight, from a forecast or a hand-held anemometer; the flight
meets the wind of the day. The product keeps the two apart:

- **the planning wind** (:func:`plan_wind`, ``[forecast]``): the lanes of ``mission.swath_m =
  "auto"`` and the heading of ``mission.direction_deg = "crosswind"``
  (:mod:`ag_uav.world.pattern`) take it. A number in ``forecast.speed_mps`` /
  ``forecast.direction_deg`` is a forecast given by hand; ``"auto"`` (the default) is the flown
  mean wind plus an error drawn from the run's seed (the ``"forecast"`` stream of
  :func:`ag_uav.seeds.seed_sequences`, two standard normals z₁, z₂ drawn whether or not they
  are used):

      U_plan = max(0, U + σ_U z₁),   θ_plan = θ + σ_θ z₂   (mod 360°)

  σ_U = 1.5 m/s and σ_θ = 30° by default: the 10 m wind errors of short-range numerical weather
  forecasts verified at stations (speed RMSE 1.5–2.3 m/s, direction mean absolute error
  22–40° for the European and global models of a public 30-day verification,
  https://meteo.matrunich.com/benchmark/; a normal error's mean absolute value is 0.8 σ).
  ``speed_sigma_mps = 0`` and ``direction_sigma_deg = 0`` plan on the flown wind exactly.
- **the flown wind** (``[wind]``): its mean, the Dryden gusts and the meander of its
  direction (:func:`meander_angles`), stepped by :mod:`ag_uav.world.wind`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np

from ..seeds import seed_sequences

__all__ = ["PlanWind", "plan_wind", "forecast_errors", "meander_angles", "spread_winds",
           "SIGMA_POINTS", "MEANDER_STEP_S"]

#: the forecast errors (z₁, z₂) one standard deviation off in speed, then in direction: the
#: winds a plan made on the forecast must hold in (:func:`spread_winds`)
SIGMA_POINTS = ((1.0, 0.0), (-1.0, 0.0), (0.0, 1.0), (0.0, -1.0))

#: the meander's angle is updated every this many seconds of flight (held in between)
MEANDER_STEP_S = 1.0


@dataclass(frozen=True)
class PlanWind:
    """The planning wind: speed (m/s), the direction it blows FROM (deg, clockwise from north)
    and where it came from: ``"exact"`` (no error), ``"drawn"`` or ``"given"``."""

    speed_mps: float
    direction_deg: float
    source: str
    flown_speed_mps: float
    flown_direction_deg: float

    def text(self) -> str:
        """One line: the plan's wind beside the flown one."""
        if self.source == "exact":
            return (f"plan made on the flown wind ({self.speed_mps:.1f} m/s from "
                    f"{self.direction_deg:.0f}°)")
        err = (self.direction_deg - self.flown_direction_deg + 180.0) % 360.0 - 180.0
        du = self.speed_mps - self.flown_speed_mps
        return (f"plan made on a {self.source} forecast: {self.speed_mps:.1f} m/s from "
                f"{self.direction_deg:.0f}° (flown {self.flown_speed_mps:.1f} m/s from "
                f"{self.flown_direction_deg:.0f}°; error {du:+.1f} m/s, {err:+.0f}°)")

    def summary(self) -> dict[str, Any]:
        """The ``plan_wind`` table of a run's summary."""
        return {"speed_mps": self.speed_mps, "direction_deg": self.direction_deg,
                "source": self.source, "text": self.text()}


def forecast_errors(seed: int) -> tuple[float, float]:
    """The two standard normals (z₁, z₂) of run ``seed``'s forecast error."""
    z = np.random.default_rng(seed_sequences(seed)["forecast"]).standard_normal(2)
    return float(z[0]), float(z[1])


def plan_wind(cfg: Any) -> PlanWind:
    """The wind ``cfg``'s plan is made on (module docstring), rounded as a forecast is issued
    (0.1 m/s, 1°)."""
    f, w = cfg.forecast, cfg.wind
    z1, z2 = forecast_errors(cfg.seed)
    given = f.speed_mps != "auto" or f.direction_deg != "auto"
    if f.speed_mps == "auto":
        speed = max(0.0, w.speed_mps + f.speed_sigma_mps * z1)
    else:
        speed = float(f.speed_mps)
    if f.direction_deg == "auto":
        direction = w.direction_deg + f.direction_sigma_deg * z2
    else:
        direction = float(f.direction_deg)
    exact = (not given and f.speed_sigma_mps == 0 and f.direction_sigma_deg == 0)
    src = "exact" if exact else ("given" if given else "drawn")
    return PlanWind(round(speed, 1), round(direction % 360.0) % 360.0, src,
                    float(w.speed_mps), float(w.direction_deg) % 360.0)


def spread_winds(cross: float, along: float, z: Any, speed_sigma: float,
                 direction_sigma: float) -> list[tuple[float, float]]:
    """The winds (across, along the legs; m/s) a plan made on the forecast (``cross`` across,
    ``along`` along) meets for each forecast error (z₁, z₂) of ``z``: the forecast's vector
    turned by σ_θ z₂ and its length changed by σ_U z₁ (at least 0), the errors of
    :func:`plan_wind` (their sign is immaterial: a normal error is symmetric)."""
    speed, head = math.hypot(cross, along), math.atan2(along, cross)
    out = []
    for z1, z2 in z:
        u = max(0.0, speed + speed_sigma * z1)
        a = head + math.radians(direction_sigma) * z2
        out.append((u * math.cos(a), u * math.sin(a)))
    return out


def meander_angles(rng: np.random.Generator, sigma_deg: float, tau_s: float, duration_s: float,
                   step_s: float = MEANDER_STEP_S) -> np.ndarray:
    """The flown wind's direction offset (rad) every ``step_s`` over ``duration_s``: a
    stationary Gauss-Markov (Ornstein-Uhlenbeck) angle sampled exactly,

        φ₀ ~ N(0, σ²),   φ_{j+1} = a φ_j + σ √(1 − a²) n_j,   a = exp(−Δ/τ),

    so that E[φ²] = σ² and E[φ(t) φ(t+s)] = σ² exp(−|s|/τ) (Gardiner, *Stochastic Methods*,
    the Ornstein-Uhlenbeck process). Zeros when σ = 0 (no draws then)."""
    n = int(math.ceil(max(duration_s, 0.0) / step_s)) + 1
    if sigma_deg <= 0.0:
        return np.zeros(n)
    sig = math.radians(sigma_deg)
    a = math.exp(-step_s / tau_s)
    z = rng.standard_normal(n)
    out = np.empty(n)
    out[0] = sig * z[0]
    b = sig * math.sqrt(-math.expm1(-2.0 * step_s / tau_s))
    for j in range(1, n):
        out[j] = a * out[j - 1] + b * z[j]
    return out
