"""Inertial sensing: the MEMS IMU at the vehicle's ``imu`` site and the attitude estimate.

The vehicle model carries MuJoCo ``accelerometer`` and ``gyro`` sensors at the ``imu`` site
(``models/quad.xml``). MuJoCo computes them exactly: the **specific force** ``f = Rᵀ (a − g)``
(body frame; a vehicle at rest reads ``+9.81`` along body z) and the body angular rate ``ω``.
:class:`ImuSensor` turns those into what a MEMS IMU reports, per axis and sample ``k``::

    f̃_k = f_k + b_a,k + n_a,k         ω̃_k = ω_k + b_g,k + n_g,k
    b_k+1 = b_k + σ_rw √dt ξ_k,  b_0 ~ N(0, σ_b²)          (turn-on bias + random walk)
    n_k ~ N(0, σ_n²),  σ_n = ND · √(f_s / 2)               (white, noise density ND over the
                                                            Nyquist band of the sample rate f_s)

plus, for the accelerometer, white airframe vibration ``σ_vib`` (the dominant term on a real
multirotor; MuJoCo has no rotor vibration). The default figures are a TDK InvenSense ICM-42688-P,
a common flight-controller IMU (datasheet DS-000347 rev 1.8, Tables 1–2: accelerometer noise
density 70 µg/√Hz, board-level zero-g offset ±20 mg; gyro noise density 2.8 mdps/√Hz,
zero-rate offset ±0.5 dps). The turn-on biases default to what is left after the flight
controller's calibrations (5 mg, 0.05 dps, 1σ); the bias random walks and the vibration level are
engineering judgement (no datasheet gives them); all are ``[imu]`` config keys.

**Attitude estimate.** The navigation filters need the attitude to rotate ``f̃`` into the world
frame. ag-uav does not run an AHRS: on a multirotor the accelerometer mostly measures the thrust
direction, not gravity, so a gyro + accelerometer complementary filter has a tilt error that
grows with the manoeuvre, and real autopilots get their tilt from the GNSS-aided EKF instead. We
stand that estimator in with its *error*: ``R̂ = Exp(δθ) · R`` where ``δθ`` (world frame, the
"psi-angle" error of a navigation-frame attitude estimate, Groves 2013 §5.6) is a
first-order Gauss–Markov process per axis, σ ``imu.tilt_error_deg`` for roll/pitch and
``imu.yaw_error_deg`` for yaw, correlation time ``imu.attitude_error_tau_s``. This is a stated
idealisation: the error level does not depend on the manoeuvre or on the GNSS quality.

The controller flies on ``R̂`` and the gyro's ``ω̃`` whenever an estimator is in the loop (as
an autopilot does); with true-state feedback it gets the truth.

The navigation filters predict with the world-frame acceleration ``â = R̂ f̃ + g`` as a known
input (loose GNSS/INS coupling). With the default ``estimator.model = "cvb"`` they estimate the
input's slow error (accelerometer bias plus projected attitude error, world frame) as three bias
states; :func:`process_noise_psd` derives their noise from the ``[imu]`` figures.

``imu.model = "ideal"`` keeps the earlier idealisation for comparison: the mean acceleration over
the control period (finite difference of the true world-frame velocity) plus white noise
``σ_vib``, the true attitude and no gyro errors.
"""

from __future__ import annotations

import math

import numpy as np

from ..config import ImuConfig

G = 9.81
UG = 1e-6 * G                # one micro-g in m/s²
DEG = math.pi / 180.0

__all__ = ["AttitudeError", "ImuSensor", "accel_sigma", "gyro_sigma", "process_noise_psd"]


def accel_sigma(cfg: ImuConfig, rate_hz: float) -> float:
    """White accelerometer noise per sample (m/s²): datasheet density over the Nyquist band,
    plus the vibration term."""
    nd = cfg.accel_noise_density_ug * UG * math.sqrt(rate_hz / 2.0)
    return math.hypot(nd, cfg.vibration_sigma_mps2)


def gyro_sigma(cfg: ImuConfig, rate_hz: float) -> float:
    """White gyro noise per sample (rad/s)."""
    return cfg.gyro_noise_density_mdps * 1e-3 * DEG * math.sqrt(rate_hz / 2.0)


def process_noise_psd(cfg: ImuConfig, rate_hz: float, bias_states: bool = False,
                      duration_s: float = 600.0) -> tuple[float, float, float]:
    """``(q, q_bias, bias_var0)`` for an IMU-driven motion model from the ``[imu]`` figures.

    The input error of ``â = R̂ f̃ + g`` per sample has a white part ``σ_a`` (density over the
    Nyquist band, plus vibration) and slow parts: the accelerometer bias (turn-on ``σ_b``, random
    walk ``σ_rw``) and the gravity the attitude error projects, ``g σ_tilt`` (Gauss–Markov with
    correlation time ``τ``). Sampled at ``f_s`` and held over ``dt = 1/f_s``, a white sequence of
    variance ``σ²`` has the PSD ``σ² dt``.

    With ``bias_states`` (the ``"cvb"`` model estimates the slow part): ``q = σ_a² dt``; the
    bias wanders with ``q_bias = σ_rw² + 2 (g σ_tilt)² / τ`` (the PSD of a Gauss–Markov
    process's driving noise, ``2σ²/τ``) and starts with ``bias_var0 = σ_b² + (g σ_tilt)²``.
    Without bias states the slow part is folded into the white one at its low-frequency PSD
    (a Gauss–Markov process of variance σ² and correlation time τ has the PSD 2σ²τ below
    1/τ; the bias is given the attitude error's τ), which is what a position filter sees of it
    (measured in the README to be the worse choice)::

        q = σ_a² dt + 2 τ (σ_b² + σ_rw² T + (g σ_tilt)²)        (T = ``duration_s``)
    """
    dt = 1.0 / rate_hz
    if cfg.model == "ideal":
        return max(cfg.vibration_sigma_mps2**2 * dt, 1e-8), 1e-8, 1e-4
    sa = accel_sigma(cfg, rate_hz)
    sb = cfg.accel_bias_mg * 1e-3 * G
    st = G * cfg.tilt_error_deg * DEG
    bias_var0 = max(sb * sb + st * st, 1e-8)
    if bias_states:
        q_bias = cfg.accel_bias_rw**2 + 2.0 * st * st / cfg.attitude_error_tau_s
        return max(sa * sa * dt, 1e-8), max(q_bias, 1e-10), bias_var0
    srw2 = cfg.accel_bias_rw**2 * duration_s
    tau = cfg.attitude_error_tau_s
    return max(sa * sa * dt + 2.0 * tau * (sb * sb + srw2 + st * st), 1e-8), 0.0, bias_var0


def _gauss_markov_block(rng: np.random.Generator, x0: np.ndarray, n: int, phi: float,
                        sigma: np.ndarray) -> np.ndarray:
    """``n`` steps of ``x_k+1 = φ x_k + σ √(1−φ²) ξ`` (exact discretisation), rows k = 1..n."""
    from scipy.signal import lfilter

    drive = rng.standard_normal((n, len(x0))) * (sigma * math.sqrt(max(1.0 - phi * phi, 0.0)))
    out, _ = lfilter([1.0], [1.0, -phi], drive, axis=0, zi=(phi * x0)[None, :])
    return out


class ImuSensor:
    """MEMS accelerometer + gyro errors on MuJoCo's exact readings (module docstring).

    ``measure(f, w)`` takes the noiseless specific force and body rate (3-sequences) and returns
    the measured ones as lists. Errors are drawn in blocks of ``block`` samples from one
    Generator (``seed``), so a run's IMU depends only on its seed.
    """

    def __init__(self, cfg: ImuConfig, rate_hz: float, seed: np.random.SeedSequence | int,
                 block: int = 4096) -> None:
        self.cfg = cfg
        self.dt = 1.0 / rate_hz
        self.rng = np.random.default_rng(seed)
        self.block = block
        sa, sg = accel_sigma(cfg, rate_hz), gyro_sigma(cfg, rate_hz)
        self.sigma_white = np.array([sa] * 3 + [sg] * 3)
        rw = np.array([cfg.accel_bias_rw] * 3 + [cfg.gyro_bias_rw * DEG] * 3)
        self.sigma_rw = rw * math.sqrt(self.dt)
        self.bias0 = self.rng.standard_normal(6) * np.array(
            [cfg.accel_bias_mg * 1e-3 * G] * 3 + [cfg.gyro_bias_dps * DEG] * 3)
        self._bias = self.bias0.copy()
        self._err: list[list[float]] = []
        self._i = 0
        self.bias_log: list[np.ndarray] = []   # the bias at the start of every block

    def _refill(self) -> None:
        n = self.block
        steps = self.rng.standard_normal((n, 6)) * self.sigma_rw
        bias = self._bias + np.cumsum(steps, axis=0) - steps   # bias in force at sample k
        self._bias = bias[-1] + steps[-1]
        self.bias_log.append(bias[0].copy())
        white = self.rng.standard_normal((n, 6)) * self.sigma_white
        self._last_bias_block = bias
        self._err = (bias + white).tolist()
        self._i = 0

    def measure(self, f, w) -> tuple[list[float], list[float]]:
        if self._i >= len(self._err):
            self._refill()
        e = self._err[self._i]
        self._i += 1
        return ([f[0] + e[0], f[1] + e[1], f[2] + e[2]],
                [w[0] + e[3], w[1] + e[4], w[2] + e[5]])

    @property
    def bias(self) -> np.ndarray:
        """The bias (accel m/s², gyro rad/s) of the last sample returned."""
        if not self._err:
            return self.bias0.copy()
        return self._last_bias_block[max(self._i - 1, 0)].copy()


class AttitudeError:
    """The attitude estimate ``R̂ = Exp(δθ) · R`` with a Gauss–Markov ``δθ`` (module docstring).

    ``apply(R)`` takes a row-major 3×3 rotation as a 9-sequence and returns ``R̂`` the same way;
    ``last`` is the last ``δθ`` (rad, about the world x, y (tilt) and z (yaw) axes).
    """

    def __init__(self, cfg: ImuConfig, rate_hz: float, seed: np.random.SeedSequence | int,
                 block: int = 4096) -> None:
        self.rng = np.random.default_rng(seed)
        self.sigma = np.array([cfg.tilt_error_deg, cfg.tilt_error_deg, cfg.yaw_error_deg]) * DEG
        self.phi = math.exp(-1.0 / (rate_hz * cfg.attitude_error_tau_s))
        self.block = block
        self._x = self.rng.standard_normal(3) * self.sigma     # stationary start
        self._rot: list[list[float]] = []
        self._dth: np.ndarray | None = None
        self._i = 0
        self.last = self._x.copy()

    def _refill(self) -> None:
        x = _gauss_markov_block(self.rng, self._x, self.block, self.phi, self.sigma)
        self._x = x[-1].copy()
        self._dth = x
        # Exp(δθ) by Rodrigues, row-major, for the whole block
        th = np.linalg.norm(x, axis=1)
        th_s = np.where(th > 1e-12, th, 1.0)
        k = x / th_s[:, None]
        s, c = np.sin(th), np.cos(th)
        kx, ky, kz = k[:, 0], k[:, 1], k[:, 2]
        v = 1.0 - c
        E = np.stack([c + kx * kx * v, kx * ky * v - kz * s, kx * kz * v + ky * s,
                      ky * kx * v + kz * s, c + ky * ky * v, ky * kz * v - kx * s,
                      kz * kx * v - ky * s, kz * ky * v + kx * s, c + kz * kz * v], axis=1)
        self._rot = E.tolist()
        self._i = 0

    def apply(self, R) -> tuple[float, ...]:
        if self._i >= len(self._rot):
            self._refill()
        E = self._rot[self._i]
        self.last = self._dth[self._i]
        self._i += 1
        r0, r1, r2, r3, r4, r5, r6, r7, r8 = E
        e0, e1, e2, e3, e4, e5, e6, e7, e8 = R
        return (r0 * e0 + r1 * e3 + r2 * e6, r0 * e1 + r1 * e4 + r2 * e7,
                r0 * e2 + r1 * e5 + r2 * e8,
                r3 * e0 + r4 * e3 + r5 * e6, r3 * e1 + r4 * e4 + r5 * e7,
                r3 * e2 + r4 * e5 + r5 * e8,
                r6 * e0 + r7 * e3 + r8 * e6, r6 * e1 + r7 * e4 + r8 * e7,
                r6 * e2 + r7 * e5 + r8 * e8)
