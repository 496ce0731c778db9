"""What the autopilot reads off a navigation filter besides its estimate, and the one aid it
fuses without a GNSS fix.

:func:`horizontal_sigma` is the horizontal position 1σ of each vehicle's flown filter (the
position failsafe's test, :class:`ag_uav.engine.stages.Failsafe`); :func:`fuse_height` is the
radar altimeter's height as a scalar Kalman update, which the ideal-attitude chain makes when
a fix is due and none comes, so its height does not stop with the fix.
"""

from __future__ import annotations

from collections.abc import Iterable
from typing import Any

import numpy as np


def horizontal_sigma(P: np.ndarray | None, ix: int, iy: int, init: np.ndarray,
                     out: np.ndarray) -> None:
    """``out[i] = sqrt(P_i[ix, ix] + P_i[iy, iy])`` of each vehicle's covariance ``P`` (N, n, n);
    NaN for a vehicle not yet initialised, and for all when ``P`` is None (no flown filter)."""
    if P is None:
        out[:] = np.nan
        return
    out[:] = np.sqrt(P[:, ix, ix] + P[:, iy, iy])
    out[~init] = np.nan


def fuse_height(filters: Iterable[Any], i: int, h: float, r: float, iz: int) -> None:
    """Row ``i`` of every batched filter (``x`` (N, n), ``P`` (N, n, n)) updated with the height
    ``h`` of variance ``r`` measured on state ``iz``: K = P eᵢ / (P_zz + r), x += K (h − x_z),
    P −= K (eᵢᵀ P) (the scalar Kalman update; the radar's noise is white, so every rule takes
    it as the KF does)."""
    for bf in filters:
        x, P = bf.x[i], bf.P[i]
        k = P[:, iz] / (P[iz, iz] + r)
        x += k * (h - x[iz])
        P -= np.outer(k, P[iz, :])
