"""The position filters of the ideal-attitude chain: their process noise, their construction,
and the coloured-noise filters' model of the receiver (``kf-bias``, ``kf-diff``: the receiver's
Gauss–Markov component, read from its noise components)."""

from __future__ import annotations

from typing import Any

import numpy as np

import estimators
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


R_FLOOR = 1e-4


def process_noise(cfg: Config, model: str | None = None) -> tuple[float, float, float]:
    """``(q, q_bias, bias_var0)`` of the bank's motion model: ``estimator.q`` (and ``q_bias``),
    or with ``"auto"`` what the IMU's figures imply (:func:`ag_uav.vehicle.imu.process_noise_psd`);
    without IMU aiding, ``q`` = 2 m²/s³ (the motion model alone must then carry the manoeuvres).
    ``bias_var0`` is the initial variance of the ``"cvb"`` model's bias states. ``model``:
    the motion model it is for (default ``estimator.model``)."""
    from ..vehicle.imu import process_noise_psd

    e = cfg.estimator
    q, q_bias, var0 = process_noise_psd(cfg.imu, cfg.sim.control_hz,
                                        bias_states=(model or e.model) == "cvb")
    if not e.imu and isinstance(e.q, str):
        q = 2.0
    if not isinstance(e.q, str):
        q = float(e.q)
    if not isinstance(e.q_bias, str):
        q_bias = float(e.q_bias)
    return q, q_bias, var0


def make_filter(name: str, cfg: Config, r_diag: np.ndarray, components: tuple = ()) -> Any:
    """One position filter of the ideal-attitude chain; ``components``: the receiver's base
    noise components (the coloured-noise filters model its Gauss–Markov part)."""
    e = cfg.estimator
    dt = 1.0 / cfg.sim.control_hz
    q, q_bias, _ = process_noise(cfg)
    params: dict[str, Any] = {"model": e.model, "dim": 3, "dt": dt, "q": q, "r": list(r_diag)}
    if e.model == "cvb":
        params["q_bias"] = q_bias
    if "mckf" in name:
        if e.mckf_kernel != "fixed":
            raise ConfigError(f'estimator.mckf_kernel = "{e.mckf_kernel}": only with '
                              'estimator.nav = "ins" (the ideal-attitude bank\'s batched MCKF '
                              'has a fixed kernel)')
        params.update(sigma=e.sigma, max_iter=e.max_iter,
                      recovery=None if e.mckf_recovery == "none" else e.mckf_recovery)
    if name.startswith("pca"):
        params.update(window=e.window, mode=e.pca_mode)
    if name in ("kf-bias", "kf-diff"):
        params.update(coloured_noise(name, cfg, r_diag, components, R_FLOOR))
    return estimators.make(name, **params)
