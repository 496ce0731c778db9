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
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np

from ...world.deposition import DepositionConfig
from ...world.surface_layer import STABILITY

#: the bounds' inputs: (ε₀ factor, stability class, σθ in degrees)
BOUNDS = {"low": (0.5, "unstable", 20.0), "high": (2.0, "stable", 0.0)}


def meander(x: np.ndarray, dep: np.ndarray, sigma_deg: float) -> np.ndarray:
    """The deposit ``dep`` at the distances ``x`` from a strip's edge averaged over wind
    directions θ ~ N(0, σθ) off the edge's normal: E[dep(x / cos θ) / cos θ]."""
    if sigma_deg <= 0.0:
        return dep.copy()
    z, w = np.polynomial.hermite_e.hermegauss(9)
    w = w / w.sum()
    out = np.zeros_like(dep)
    for zi, wi in zip(z, w, strict=True):
        th = min(abs(zi * math.radians(sigma_deg)), math.radians(80.0))
        c = math.cos(th)
        out += wi * np.interp(x / c, x, dep, left=dep[0], right=0.0) / c
    return out


def bound_config(base: DepositionConfig, which: str) -> tuple[DepositionConfig, float]:
    """The deposition config and σθ (degrees) of the ``"low"`` or ``"high"`` bound."""
    f, stab, sig = BOUNDS[which]
    return (dataclasses.replace(base, wake_escape=min(1.0, base.wake_escape * f),
                                obukhov_inv_m=STABILITY[stab]), sig)

