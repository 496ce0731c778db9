"""GPS-denied flight: localisation from bearings to known field landmarks (no GPS at all).

:class:`BearingFeedback` plugs into the feedback seam of :mod:`ag_uav.engine.missions` like
:class:`~ag_uav.navigation.estimation.EstimatorFeedback`, with the GPS replaced by an
angle-of-arrival sensor (a camera or a radio direction finder) that measures, every ``1/rate_hz`` s,
the azimuth from the drone to each of N known landmarks (beacons), as in Qin, Xu & Liu, "Path
Planning for UAV Target Tracking with Non-Gaussian Noise" (section II, eqs 1-4: bearings to known
anchors, Gaussian-mixture noise)::

    θ_i = atan2(η_i − y, ξ_i − x) + v_i,      wrapped to (−π, π]

in the world (ENU) frame: the sensor's body-frame bearing is assumed rotated by a perfect yaw
(an AHRS yaw error would be a common bias on every bearing; not modelled). Every landmark is
always visible (no occlusion, no field-of-view limit, no data association: each bearing comes
labelled with its beacon). Default landmarks: 4 beacons at the corners of the field's bounding
box pushed out by 10 m per axis (:func:`default_landmarks`).

Noise (``noise="mixture"``, the paper's eq 4 with ϑ = 0.1)::

    v ~ (1 − ϑ) N(0, s² γ₁) + ϑ N(0, s² γ₂),     γ₁ = 0.01 rad², γ₂ = 0.1 rad²

``s = noise_scale`` scales both standard deviations. ``s = 1`` is the paper's noise: 0.1 rad
(5.7°) nominal with 10 % outliers of 0.32 rad (18°); at 100 m range one such bearing is 10 m of
cross-range error. The default ``s = 0.1`` (nominal 0.57°, outliers 1.8°, RMS 0.79°) is what a
calibrated camera or radio angle-of-arrival sensor achieves, with the same outlier shape.
``noise="gaussian"`` draws N(0, s² γ₁) only.

The height comes from the radar altimeter (``gps.radar_sigma_m``, white, height above the flat
ground), fused with the bearings as one more channel of the same measurement vector
``z = [θ_1 … θ_N, h]``.

Filter (``filter``): ``"mcc-ekf"`` (:class:`estimators.mccekf.MCCEKF`, kernel σ =
``estimator.sigma``), ``"ekf"`` (:class:`estimators.ekf.EKF`) or ``"ukf"``
(:class:`estimators.ukf.UKF`), all with the bearing Jacobian of eq 11
(:class:`estimators.bearing.BearingModel`) and the angle channels' residuals wrapped to
(−π, π] (:func:`estimators.bearing.residual_with_angles`). ``R = diag(r_var, …, r_var,
radar σ²)`` with ``r_var`` by default the noise's total variance (mixture: s²((1 − ϑ)γ₁ + ϑγ₂),
the consistent Gaussian approximation; gaussian: s²γ₁); the same R for every filter.

Prediction exactly as :class:`~ag_uav.navigation.estimation.EstimatorFeedback`: the
``estimator.model`` motion model (``"cvb"``: constant velocity + IMU input-bias states, or ``"cv"``)
at the control rate, process noise from the IMU's figures (``estimator.q``), and with
``estimator.imu`` the IMU's world-frame acceleration as a known input ``B a``
(:mod:`ag_uav.vehicle.imu`). Initialisation at the first tick: the true position (plus
``init_offset_m``, default 0: a GPS-denied drone knows its take-off spot) with position variance
``init_sigma_m²`` (3 m by default), velocity variance 0.25 and, for cvb, the bias states at the
IMU's turn-on figures.

Shadows (``shadow``) are further filters fed the very same bearings and scored only (common
random numbers), as in :class:`~ag_uav.navigation.estimation.EstimatorFeedback`; ``scores()`` and
``summary()`` have the same shape, so ``simulate`` puts them in ``summary["estimators"]``.

Usage (``estimator.source = "bearings"`` in the config builds it; or pass it as the feedback)::

    fb = BearingFeedback.for_config(cfg, filter="mcc-ekf", noise_scale=1.0)
    res = simulate(cfg, feedback=fb)
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, replace
from typing import Any

import numpy as np

from estimators.bearing import BearingModel, residual_with_angles, wrap_angle
from estimators.ekf import EKF
from estimators.mccekf import MCCEKF
from estimators.models import motion_model
from estimators.ukf import UKF
from numkit import Z

from ..config import Config
from ..seeds import seed_sequences
from ..world.mission import build_field
from .estimation import EstimatorFeedback, FilterBank, process_noise
from .feedback import Feedback

__all__ = ["FILTERS", "BearingFeedback", "BearingOptions", "default_landmarks"]

#: filters the bearing feedback can run
FILTERS = ("mcc-ekf", "ekf", "ukf")
#: the paper's mixture (eq 4): nominal and outlier variances (rad²) and the outlier weight
GAMMA1, GAMMA2, THETA = 0.01, 0.1, 0.1
R_FLOOR = 1e-4


def default_landmarks(cfg: Config, margin_m: float = 10.0) -> np.ndarray:
    """(4, 2) beacons at the corners of the field's bounding box pushed out by ``margin_m``."""
    x0, y0, x1, y1 = build_field(cfg).bounds
    m = float(margin_m)
    return np.array([[x0 - m, y0 - m], [x1 + m, y0 - m], [x1 + m, y1 + m], [x0 - m, y1 + m]])


@dataclass(frozen=True)
class BearingOptions:
    """The options of :class:`BearingFeedback`, declared once.

    landmarks : (N, 2) beacon positions (m, ENU); default :func:`default_landmarks`.
    rate_hz : bearing (and altimeter) rate.
    filter : the filter the controller flies on, one of :data:`FILTERS`.
    noise : ``"mixture"`` (the paper's eq 4) or ``"gaussian"`` (its nominal component only).
    noise_scale : s, multiplies both noise standard deviations (1 = the paper's noise).
    r_var : bearing variance in the filters' R (rad²); default the noise's total variance.
    shadow : more filters fed the same measurements, scored only.
    sigma : MCC-EKF kernel bandwidth (default ``estimator.sigma``).
    init_sigma_m : initial position standard deviation (m) in P0.
    init_offset_m : (dx, dy, dz) added to the true start position for the initial estimate.
    """

    landmarks: Sequence[Sequence[float]] | np.ndarray | None = None
    rate_hz: float = 10.0
    filter: str = "mcc-ekf"
    noise: str = "mixture"
    noise_scale: float = 0.1
    r_var: float | None = None
    shadow: Sequence[str] = ()
    sigma: float | None = None
    init_sigma_m: float = 3.0
    init_offset_m: Sequence[float] = (0.0, 0.0, 0.0)


class BearingFeedback(FilterBank, Feedback):
    """Bearings to known landmarks + radar altimeter + IMU-aided prediction, no GPS.

    Parameters
    ----------
    cfg : run config (``estimator.q``, ``model``, ``imu``, ``[imu]``, ``sigma``, ``max_iter``;
        ``gps.radar_sigma_m``; ``sim.control_hz``; the field for the default landmarks).
    seed : bearing-noise stream (``for_config`` passes the run's ``"gps"`` stream: the bearing
        sensor replaces the GPS).
    alt_seed, imu_seed : radar-altimeter and accelerometer noise streams.
    options : the options (:class:`BearingOptions`; its defaults when omitted).
    **changes : any :class:`BearingOptions` field by name, over ``options``.
    """

    def __init__(self, cfg: Config, seed: np.random.SeedSequence | None,
                 alt_seed: np.random.SeedSequence | None = None,
                 imu_seed: np.random.SeedSequence | None = None,
                 options: BearingOptions | None = None, **changes: Any) -> None:
        o = replace(options or BearingOptions(), **changes)  # TypeError names a bad keyword
        filter, shadow, noise, rate_hz = o.filter, o.shadow, o.noise, o.rate_hz
        if filter not in FILTERS:
            raise ValueError(f"filter {filter!r}: not one of {FILTERS}")
        for s in shadow:
            if s not in FILTERS:
                raise ValueError(f"shadow {s!r}: not one of {FILTERS}")
        if noise not in ("mixture", "gaussian"):
            raise ValueError(f"noise {noise!r}: 'mixture' or 'gaussian'")
        if not rate_hz > 0 or not o.noise_scale > 0 or not o.init_sigma_m > 0:
            raise ValueError("rate_hz, noise_scale and init_sigma_m must be > 0")
        self.cfg = cfg
        lm = default_landmarks(cfg) if o.landmarks is None else o.landmarks
        self.landmarks = np.asarray(lm, dtype=float).reshape(-1, 2)
        self.L = self.landmarks.shape[0]
        if self.L < 2:
            raise ValueError("need at least 2 landmarks to fix a horizontal position")
        self.rate_hz = float(rate_hz)
        self.noise = noise
        self.noise_scale = float(o.noise_scale)
        s2 = self.noise_scale**2
        self.var1, self.var2 = s2 * GAMMA1, s2 * GAMMA2
        total = (1 - THETA) * self.var1 + THETA * self.var2 if noise == "mixture" else self.var1
        self.r_var = float(total if o.r_var is None else o.r_var)
        self.rng = np.random.default_rng(seed)
        self.radar_sigma = float(cfg.gps.radar_sigma_m)
        self.radar_rng = np.random.default_rng(alt_seed)
        e = cfg.estimator
        self.sigma = float(e.sigma if o.sigma is None else o.sigma)
        self.init_sigma_m = float(o.init_sigma_m)
        self.init_offset = np.asarray(o.init_offset_m, dtype=float).reshape(3)

        self.dt = 1.0 / cfg.sim.control_hz
        # CV, or CV + the IMU input-bias states ("cvb", the default) as the GPS bank
        kind = "cvb" if e.model == "cvb" else "cv"
        q, q_bias, self._bias_var0 = process_noise(cfg, kind)
        mdl = motion_model(kind, 3, self.dt, q=q, q_bias=q_bias)
        self.F, self.Q = mdl.F, mdl.Q
        self.pos_idx, self.vel_idx = [int(i) for i in mdl.pos_idx], [int(i) for i in mdl.vel_idx]
        self.n = mdl.n
        self._kind = kind
        self.bm = BearingModel(self.n, observer=(self.pos_idx[0], self.pos_idx[1]),
                               landmarks=self.landmarks)
        self.R = np.diag([self.r_var] * self.L + [max(self.radar_sigma**2, R_FLOOR)])
        self.residual = residual_with_angles([True] * self.L + [False])

        self.primary = self.name = filter
        self.names = [filter] + [s for s in dict.fromkeys(shadow) if s != filter]
        self.filters = {n: self._make(n) for n in self.names}
        self.initialised = False
        self._setup_imu(cfg, imu_seed)
        self._k_next = 0  # index of the next measurement epoch (t = k / rate_hz)
        self.n_meas = 0
        self.n_outliers = 0
        self._setup_records()
        self.log = None

    @classmethod
    def for_config(cls, cfg: Config, **kw) -> BearingFeedback:
        """Build with the same seed streams ``simulate(cfg)`` gives the GPS feedback: the
        ``"gps"`` stream drives the bearing noise, ``"altimeter"`` and ``"imu"`` as usual."""
        ss = seed_sequences(cfg.seed)
        return cls(cfg, ss["gps"], ss["altimeter"], ss["imu"], **kw)

    # ------------------------------------------------------------------ measurement model
    def h(self, x: np.ndarray) -> np.ndarray:
        """[θ_1 … θ_N, z] for a state (n,) or a stack (k, n)."""
        x = np.asarray(x, dtype=float)
        iz = self.pos_idx[Z]
        if x.ndim == 1:
            return np.append(self.bm.h(x), x[iz])
        return np.column_stack([self.bm.h(x), x[:, iz]])

    def H_jac(self, x: np.ndarray) -> np.ndarray:
        H = np.zeros((self.L + 1, self.n))
        H[: self.L] = self.bm.jacobian(x)
        H[self.L, self.pos_idx[Z]] = 1.0
        return H

    def _make(self, name: str) -> Any:
        x0, P0 = np.zeros(self.n), np.eye(self.n)
        if name == "ekf":
            return EKF(self.F, None, self.h, self.H_jac, self.Q, self.R, x0, P0,
                       residual=self.residual)
        if name == "ukf":
            return UKF(self.F, self.h, self.Q, self.R, x0, P0, residual=self.residual,
                       vectorized=True)
        return MCCEKF(self.F, None, self.h, self.H_jac, self.Q, self.R, x0, P0,
                      residual=self.residual, sigma=self.sigma,
                      max_iter=self.cfg.estimator.max_iter)

    def measure(self, p_true: Sequence[float]) -> np.ndarray:
        """One noisy measurement [θ_1 … θ_N, h] at the true position (advances the streams)."""
        p = np.asarray(p_true, dtype=float)
        xs = np.zeros(self.n)
        xs[self.pos_idx] = p
        theta = self.bm.h(xs)
        if self.noise == "mixture":
            # same draws as estimators.bearing.mixture_noise (component choice, then normal)
            u = self.rng.random(self.L)
            out = u < THETA
            std = np.where(out, math.sqrt(self.var2), math.sqrt(self.var1))
            v = std * self.rng.standard_normal(self.L)
            self.n_outliers += int(out.sum())
        else:
            v = math.sqrt(self.var1) * self.rng.standard_normal(self.L)
        hz = float(p[Z]) + self.radar_sigma * float(self.radar_rng.standard_normal())
        return np.append(wrap_angle(theta + v), hz)

    # --------------------------------------------------------------------------- the seam
    def _init(self, p_true: Sequence[float]) -> None:
        x0 = np.zeros(self.n)
        x0[self.pos_idx] = np.asarray(p_true, dtype=float) + self.init_offset
        P0 = np.diag([self.init_sigma_m**2, 0.25, self._bias_var0][: self.F.shape[0] // 3] * 3)
        for f in self.filters.values():
            f.x = x0.copy()
            f.P = P0.copy()
        self.initialised = True

    def update(self, t, p_true, v_true, imu=None):
        z = None
        if t + 1e-9 >= self._k_next / self.rate_hz:
            self._k_next += 1
            z = self.measure(p_true)
            self.n_meas += 1
            if self.log is not None:
                self.log.set_truth(p_true)
        if not self.initialised:
            self._init(p_true)
            z = None  # the first epoch's measurement is spent on nothing: we start at home
        return self._step_bank(t, z, v_true, imu)

    #: per-estimator scores over the mission ticks, exactly as the GPS feedback scores them
    scores = EstimatorFeedback.scores

    def summary(self) -> dict[str, Any]:
        return {"gps_preset": None, "gps_fixes": 0, "gps_denied": True,
                "bearing_landmarks": [[round(float(a), 3), round(float(b), 3)]
                                      for a, b in self.landmarks],
                "bearing_rate_hz": self.rate_hz, "bearing_noise": self.noise,
                "bearing_noise_scale": self.noise_scale,
                "bearing_measurements": self.n_meas, "bearing_outliers": self.n_outliers,
                "bearing_r_var_rad2": self.r_var,
                "estimator_r_diag": [round(float(v), 6) for v in np.diag(self.R)]}
