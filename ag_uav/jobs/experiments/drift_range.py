"""The drift trial's buffers with an error bar: low and high bounds from the uncertain inputs.

Three inputs of the drift trial (:mod:`.drift`) are not known for a real application:

- the share of the sheet at the wake's edge, ε₀ (``wake_escape``, assumed 0.3): halved and
  doubled (the range the docs show the far field to scale with; on the wind-tunnel trial's 2 L
  rows 0.3-0.6 fit alike);
- the surface layer's stability (Monin–Obukhov, :mod:`ag_uav.world.surface_layer`): stable
  (1/L = +1/20 m⁻¹), neutral, unstable (−1/20 m⁻¹); a stable layer diffuses the escaped fines
  less (K / φ_h), so fewer land early and more far out;
- the meander of the wind's direction over the application, σθ: with the wind at θ off the
  normal to the strip's edge, the deposit at a distance d from the edge is the profile at
  d / cos θ divided by cos θ (the same line source seen obliquely), averaged over θ ~ N(0, σθ)
  (9-point Gauss-Hermite, |θ| < 80°); it lowers the deposit at a fixed distance.

The central trial is the one the docs tabulate (ε₀ = 0.3, neutral, a steady direction across the
strip). The bounds take each input at the end that lowers / raises the far deposit: **low** =
ε₀/2, unstable, σθ = 20°; **high** = 2ε₀, stable, a steady direction. They are corners of the
inputs' ranges, not a statistical interval.

The law is :mod:`ag_uav.world.drift_bounds` (the flight's summary uses it too).
"""

from __future__ import annotations

from ...world.drift_bounds import BOUNDS, bound_config, meander  # noqa: F401

__all__ = ["BOUNDS", "bound_config", "meander"]
