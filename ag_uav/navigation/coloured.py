"""The coloured-noise position filters' model of the receiver (``kf-bias``, ``kf-diff`` on the
ideal-attitude chain): the receiver's Gauss–Markov component, read from its noise components."""

from __future__ import annotations

from typing import Any

import numpy as np

from numkit import Z

from ..config import Config, ConfigError


def coloured_noise(name: str, cfg: Config, r_diag: np.ndarray, components: tuple,
                   r_floor: float) -> dict[str, Any]:
    """The coloured-noise filters' model of the receiver: its Gauss–Markov component's
    correlation time τ and per-axis σ (σ · axis_scale).  "kf-bias" takes σ as its bias states'
    σ_b and the rest of the variance as its white R; "kf-diff" takes τ (its R is the whole
    stationary variance).  A preset without a Gauss–Markov part is refused."""
    gm = [c for c in components
          if str(c.get("type", "")).lower().replace("_", "-") in ("gauss-markov", "gm")]
    if not gm:
        raise ConfigError(f'estimator.name = "{name}": the GPS preset "{cfg.gps.preset}" has no '
                          'gauss-markov component to model (use a preset with one, e.g. '
                          '"rtk-m350", or estimator.name = "kf")')
    if name == "kf-diff" and cfg.estimator.imu:
        raise ConfigError('estimator.name = "kf-diff": the differencing filter has no control '
                          'input, and in the loop the IMU drives the filters (estimator.imu = '
                          'true); use it with estimator.imu = false, or kf-bias')
    c = gm[0]
    sigma = float(c["sigma"]) * np.asarray(c.get("axis_scale", (1.0, 1.0, 1.0)), dtype=float)
    tau = np.full(3, float(c["tau_s"]))
    if cfg.gps.altitude_source == "radar":   # the height channel is the radar's: white noise
        sigma[Z], tau[Z] = 0.0, 1e-9           # (σ_b = 0; Γ = e^(−Δt/τ) = 0: a plain update)
    if name == "kf-diff":
        return {"tau": tau, "r": list(r_diag)}
    white = np.maximum(np.asarray(r_diag, dtype=float) - sigma**2, r_floor)
    return {"tau": tau, "sigma_b": np.maximum(sigma, 1e-9), "r": list(white)}
