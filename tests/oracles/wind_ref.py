"""Reference wind: mean wind + Dryden turbulence (MIL-F-8785C, low altitude), in plain Python
from the formulas, independent of ``ag_uav.world.wind`` (which has the derivation).

* Parameters, h in feet: ``L_w = h``, ``L_u = L_v = h / (0.177 + 0.000823 h)^1.2``,
  ``σ_w = 0.1 W20``, ``σ_u = σ_v = σ_w / (0.177 + 0.000823 h)^0.4``; h clamped to [3 m, 1000 ft],
  V floored at 1 m/s.
* Longitudinal: ``z' = a z + sqrt(1 − a²) n``, ``a = e^{−θ}``, ``θ = V dt / L_u``; ``u = σ_u z``.
* Lateral / vertical: the normalised 2-state filter ``z' = Φ z + L n`` with
  ``Φ = e^{−θ} [[1 + θ, θ], [−θ, 1 − θ]]`` and ``L L^T = Q = I − Φ Φ^T``: ``Q11 = P(3, 2θ)``
  (regularised incomplete gamma, scipy), ``Q12 = 2 θ² e^{−2θ}``,
  ``Q22 = 1 − e^{−2θ}(1 − 2θ + 2θ²)``; output ``σ (z1/2 + √3/2 z2)``.
* The discretisation is recomputed when V or h moved by more than ``rel_tol`` (relative) from
  where it was last computed, or dt changed.
* Draws: 5 standard normals for the stationary start, then blocks of ``block`` normals, 5 per
  step (u, v, v, w, w), a new block when fewer than 5 are left.
* ENU: ``e_u = −(sin d, cos d, 0)`` (d: the direction the wind blows from, clockwise from
  north), ``e_v = e_w × e_u``, ``e_w = z``; wind = ``U e_u + u e_u + v e_v + w e_w``.
"""

from __future__ import annotations

import math

import numpy as np
from scipy.special import gammainc

FT = 0.3048


def milspec(w20: float, h_m: float) -> tuple[float, float, float, float]:
    """(σ_u, σ_w, L_u, L_w) in m/s and m at height ``h_m`` (clamped)."""
    h_ft = min(max(h_m, 3.0), 1000.0 * FT) / FT
    d = 0.177 + 0.000823 * h_ft
    return 0.1 * w20 / d**0.4, 0.1 * w20, h_ft / d**1.2 * FT, h_ft * FT


def second_order(theta: float) -> tuple[np.ndarray, np.ndarray]:
    """(Φ, L) of the normalised lateral/vertical filter for the step θ."""
    e = math.exp(-theta)
    phi = e * np.array([[1.0 + theta, theta], [-theta, 1.0 - theta]])
    e2 = e * e
    q11 = float(gammainc(3.0, 2.0 * theta))
    q12 = 2.0 * theta * theta * e2
    q22 = 1.0 - e2 * (1.0 - 2.0 * theta + 2.0 * theta * theta)
    l11 = math.sqrt(q11)
    l21 = q12 / l11
    return phi, np.array([[l11, 0.0], [l21, math.sqrt(max(q22 - l21 * l21, 0.0))]])


class WindRef:
    """One vehicle's wind (see the module docstring); ``w20 = 0``: the mean wind, no draws."""

    def __init__(self, mean_speed: float, direction_deg: float, w20: float,
                 rng: np.random.Generator | None, rel_tol: float = 0.01, block: int = 5120):
        d = math.radians(direction_deg)
        self.e_u = (-math.sin(d), -math.cos(d))
        self.mean = (mean_speed * self.e_u[0], mean_speed * self.e_u[1], 0.0)
        self.w20, self.rng, self.rel_tol = w20, rng, rel_tol
        self.block = max(5, block // 5 * 5)
        self.buf: list[float] = []
        self.at: tuple[float, float, float] | None = None   # (V, h, dt) of the discretisation
        if w20 > 0.0:
            z = rng.standard_normal(5)
            self.zu, self.zv, self.zw = z[0], np.array(z[1:3]), np.array(z[3:5])

    def _discretise(self, V: float, h: float, dt: float) -> None:
        self.su, self.sw, lu, lw = milspec(self.w20, h)
        self.a = math.exp(-V * dt / lu)
        self.b = math.sqrt(1.0 - self.a * self.a)
        self.phi_v, self.l_v = second_order(V * dt / lu)
        self.phi_w, self.l_w = second_order(V * dt / lw)
        self.at = (V, h, dt)

    def step(self, dt: float, altitude: float, airspeed: float) -> tuple[float, float, float]:
        if self.w20 == 0.0:
            return self.mean
        V = max(airspeed, 1.0)
        h = min(max(altitude, 3.0), 1000.0 * FT)
        at = self.at
        if (at is None or abs(V - at[0]) > self.rel_tol * at[0]
                or abs(h - at[1]) > self.rel_tol * at[1] or dt != at[2]):
            self._discretise(V, h, dt)
        if len(self.buf) < 5:
            self.buf = self.rng.standard_normal(self.block).tolist()
        n = self.buf[:5]
        del self.buf[:5]
        self.zu = self.a * self.zu + self.b * n[0]
        self.zv = self.phi_v @ self.zv + self.l_v @ np.array([n[1], n[2]])
        self.zw = self.phi_w @ self.zw + self.l_w @ np.array([n[3], n[4]])
        c = math.sqrt(3.0) / 2.0
        u = self.su * self.zu
        v = self.su * (0.5 * self.zv[0] + c * self.zv[1])
        w = self.sw * (0.5 * self.zw[0] + c * self.zw[1])
        ex, ey = self.e_u
        return self.mean[0] + u * ex - v * ey, self.mean[1] + u * ey + v * ex, w
