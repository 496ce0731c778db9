"""Reference MEMS IMU and attitude-error models in plain Python, from the formulas, independent of
``ag_uav.vehicle.imu`` (which has the sources of the figures).

IMU, per axis and sample k (rate f_s, dt = 1/f_s), accelerometer then gyro:

    f̃_k = f_k + b_k + n_k,   b_0 ~ N(0, σ_b²),   b_k+1 = b_k + σ_rw √dt ξ_k,   n_k ~ N(0, σ_n²)
    σ_n (accel) = √((ND µg g)² f_s/2 + σ_vib²),   σ_n (gyro) = ND mdps · √(f_s/2)

Draws from the sensor's Generator: the six turn-on biases, then per block of ``block`` samples
the ``block × 6`` walk steps ξ, then the ``block × 6`` white numbers.

Attitude error: ``R̂ = Exp(δθ) R`` (δθ about the world axes), ``δθ`` a first-order
Gauss–Markov process per axis, ``δθ_k+1 = φ δθ_k + σ √(1 − φ²) ξ_k``, ``φ = exp(−dt / τ)``, σ the
tilt error for x, y and the yaw error for z, a stationary start ``δθ_0 ~ N(0, σ²)``; draws: the
three start values, then ``block × 3`` per block. ``Exp`` is scipy's rotation from a rotation
vector.
"""

from __future__ import annotations

import math

import numpy as np
from scipy.spatial.transform import Rotation

G = 9.81
DEG = math.pi / 180.0


class ImuRef:
    """``measure(f, w)`` -> (f̃, w̃) as lists; ``bias0``: the six turn-on biases; ``bias``: the
    bias b_k of the last sample returned."""

    def __init__(self, cfg, rate_hz: float, seed, block: int = 4096):
        self.rng = np.random.default_rng(seed)
        self.block = block
        dt = 1.0 / rate_hz
        nd_a = cfg.accel_noise_density_ug * 1e-6 * G
        s_a = math.sqrt(nd_a * nd_a * rate_hz / 2.0 + cfg.vibration_sigma_mps2 ** 2)
        s_g = cfg.gyro_noise_density_mdps * 1e-3 * DEG * math.sqrt(rate_hz / 2.0)
        self.s_white = [s_a] * 3 + [s_g] * 3
        self.s_rw = ([cfg.accel_bias_rw * math.sqrt(dt)] * 3
                     + [cfg.gyro_bias_rw * DEG * math.sqrt(dt)] * 3)
        s_b = [cfg.accel_bias_mg * 1e-3 * G] * 3 + [cfg.gyro_bias_dps * DEG] * 3
        z = self.rng.standard_normal(6)
        self.bias0 = [float(z[j]) * s_b[j] for j in range(6)]
        self.b = list(self.bias0)
        self.bias = list(self.bias0)
        self.errors: list[tuple[list[float], list[float]]] = []

    def measure(self, f, w) -> tuple[list[float], list[float]]:
        if not self.errors:
            xi = self.rng.standard_normal((self.block, 6))
            white = self.rng.standard_normal((self.block, 6))
            for k in range(self.block):
                self.errors.append(([self.b[j] + self.s_white[j] * white[k, j]
                                     for j in range(6)], self.b))
                self.b = [self.b[j] + self.s_rw[j] * xi[k, j] for j in range(6)]
            self.errors.reverse()
        e, self.bias = self.errors.pop()
        return [f[j] + e[j] for j in range(3)], [w[j] + e[3 + j] for j in range(3)]


class AttitudeRef:
    """``apply(R)`` -> R̂ (row-major 9-list); ``last``: the δθ of the last call (rad)."""

    def __init__(self, cfg, rate_hz: float, seed, block: int = 4096):
        self.rng = np.random.default_rng(seed)
        self.block = block
        self.sigma = [cfg.tilt_error_deg * DEG, cfg.tilt_error_deg * DEG, cfg.yaw_error_deg * DEG]
        self.phi = math.exp(-1.0 / (rate_hz * cfg.attitude_error_tau_s))
        z = self.rng.standard_normal(3)
        self.x = [float(z[j]) * self.sigma[j] for j in range(3)]
        self.last = list(self.x)
        self.queue: list[list[float]] = []

    def apply(self, R) -> list[float]:
        if not self.queue:
            xi = self.rng.standard_normal((self.block, 3))
            c = math.sqrt(1.0 - self.phi * self.phi)
            for k in range(self.block):
                self.x = [self.phi * self.x[j] + self.sigma[j] * c * xi[k, j] for j in range(3)]
                self.queue.append(self.x)
            self.queue.reverse()
        self.last = self.queue.pop()
        E = Rotation.from_rotvec(self.last).as_matrix()
        return (E @ np.asarray(R, dtype=float).reshape(3, 3)).ravel().tolist()
