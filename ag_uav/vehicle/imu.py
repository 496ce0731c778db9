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

**Where the law lives** (each law written once). The error sequences are drawn in
blocks from the vehicle's own Generator: :func:`imu_error_block` (bias walk + white noise, six
axes) and :func:`gauss_markov_block` (``δθ``). The per-tick law is a compiled row function,
:func:`imu_row` (``f̃ = f + e_k``) and :func:`attitude_row` (``R̂ = Exp(δθ_k) R``, Rodrigues),
which :class:`ImuSensor` / :class:`AttitudeError` call on their own one-row arrays (a batch of
one) and the loops over rows :func:`imu_rows` / :func:`attitude_rows` (run by
:mod:`ag_uav.vehicle.sensors_batched`) call row by row. The independent reference is
``tests/oracles/imu_ref.py``.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np

from .._jit import njit, register_jitable
from ..config import ImuConfig
from .ar1 import ar1_filter

G = 9.81
UG = 1e-6 * G                # one micro-g in m/s²
DEG = math.pi / 180.0

__all__ = ["AttitudeError", "AttitudeRow", "ImuRow", "ImuSensor", "accel_sigma", "attitude_row",
           "attitude_rows", "block_used_up",
           "gauss_markov_block", "gyro_sigma", "imu_error_block", "imu_row", "imu_rows",
           "process_noise_psd", "rows_need"]


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


def imu_error_block(rng: np.random.Generator, bias: np.ndarray, n: int, sigma_rw: np.ndarray,
                    sigma_white: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The next ``n`` samples of the six IMU errors (accel m/s², gyro rad/s), from ``rng``.

    ``e_k = b_k + σ_white ξ'_k`` with the bias walk ``b_k+1 = b_k + σ_rw ξ_k`` started at
    ``bias`` (``σ_rw`` already holds the √dt). Draws ``n × 6`` steps, then ``n × 6`` white
    numbers. Returns ``(e (n, 6), the bias after the block, b_k (n, 6))``.
    """
    steps = rng.standard_normal((n, 6)) * sigma_rw
    b = bias + np.cumsum(steps, axis=0) - steps   # the bias in force at sample k
    white = rng.standard_normal((n, 6)) * sigma_white
    return b + white, b[-1] + steps[-1], b


def gauss_markov_block(rng: np.random.Generator, x0: np.ndarray, n: int, phi: float,
                       sigma: np.ndarray) -> np.ndarray:
    """``n`` steps of ``x_k+1 = φ x_k + σ √(1−φ²) ξ`` (exact discretisation), rows k = 1..n."""
    drive = rng.standard_normal((n, len(x0))) * (sigma * math.sqrt(max(1.0 - phi * phi, 0.0)))
    return ar1_filter(drive, 1.0, phi, phi * np.asarray(x0, dtype=float))


@register_jitable
def block_used_up(ist: np.ndarray, i: int) -> bool:
    """Row ``i`` has no unread sample left (``ist[i] = (next sample, samples buffered)``)."""
    return ist[i, 0] >= ist[i, 1]


@njit(cache=True)
def imu_row(f: np.ndarray, w: np.ndarray, err: np.ndarray, ist: np.ndarray, i: int,
            f_out: np.ndarray, w_out: np.ndarray) -> None:
    """One IMU sample of row ``i``: ``f_out[i] = f[i] + e_k[:3]``, ``w_out[i] = w[i] + e_k[3:]``
    with ``k = ist[i, 0]``, the next unread error of ``err[i]`` (the caller refills first when
    :func:`block_used_up`)."""
    k = ist[i, 0]
    ist[i, 0] = k + 1
    for j in range(3):
        f_out[i, j] = f[i, j] + err[i, k, j]
        w_out[i, j] = w[i, j] + err[i, k, 3 + j]


@njit(cache=True)
def attitude_row(R: np.ndarray, dth: np.ndarray, ist: np.ndarray, i: int, out: np.ndarray,
                 last: np.ndarray) -> None:
    """One attitude estimate of row ``i``: ``out[i] = Exp(δθ_k) R[i]`` (row-major 3×3, ``Exp`` by
    Rodrigues about the world axes), ``last[i] = δθ_k``, ``k = ist[i, 0]`` the next unread
    sample of ``dth[i]`` (the caller refills first when :func:`block_used_up`)."""
    k = ist[i, 0]
    ist[i, 0] = k + 1
    x0 = dth[i, k, 0]
    x1 = dth[i, k, 1]
    x2 = dth[i, k, 2]
    last[i, 0] = x0
    last[i, 1] = x1
    last[i, 2] = x2
    th = math.sqrt(x0 * x0 + x1 * x1 + x2 * x2)
    ths = th if th > 1e-12 else 1.0
    kx = x0 / ths
    ky = x1 / ths
    kz = x2 / ths
    s = math.sin(th)
    c = math.cos(th)
    v = 1.0 - c
    E = ((c + kx * kx * v, kx * ky * v - kz * s, kx * kz * v + ky * s),
         (ky * kx * v + kz * s, c + ky * ky * v, ky * kz * v - kx * s),
         (kz * kx * v - ky * s, kz * ky * v + kx * s, c + kz * kz * v))
    for r in range(3):
        er = E[r]
        for col in range(3):
            out[i, 3 * r + col] = (er[0] * R[i, col] + er[1] * R[i, 3 + col]
                                   + er[2] * R[i, 6 + col])


# ---- the loops of ag_uav.vehicle.sensors_batched over rows live here, beside the row law:
# numba's cache of a function is renewed only when its own file changes.


@njit(cache=True)
def rows_need(active: np.ndarray, ist: np.ndarray) -> int:
    """Number of active rows whose sample buffer is used up (ist[:, 0] = next, [:, 1] = len)."""
    need = 0
    for i in range(ist.shape[0]):
        if active[i] and block_used_up(ist, i):
            need += 1
    return need


@njit(cache=True)
def imu_rows(f: np.ndarray, w: np.ndarray, active: np.ndarray, err: np.ndarray,
             ist: np.ndarray, f_out: np.ndarray, w_out: np.ndarray) -> int:
    """:func:`imu_row` of every active row; returns 0, or (nothing done) the number of active
    rows whose block is used up."""
    need = rows_need(active, ist)
    if need:
        return need
    for i in range(f.shape[0]):
        if active[i]:
            imu_row(f, w, err, ist, i, f_out, w_out)
    return 0


@njit(cache=True)
def attitude_rows(R: np.ndarray, active: np.ndarray, dth: np.ndarray, ist: np.ndarray,
                  out: np.ndarray, last: np.ndarray) -> int:
    """:func:`attitude_row` of every active row; returns 0, or (nothing done) the number of
    active rows whose block is used up."""
    need = rows_need(active, ist)
    if need:
        return need
    for i in range(R.shape[0]):
        if active[i]:
            attitude_row(R, dth, ist, i, out, last)
    return 0


class ImuRow(NamedTuple):
    """An :class:`ImuSensor`'s row state, one row each: the bias after the buffered block
    ``bias`` (6,), the buffered errors ``err`` (1, block, 6) and ``ist`` (1, 2: the next sample,
    the samples buffered). :class:`~ag_uav.vehicle.sensors_batched.BatchImu` stacks them."""

    bias: np.ndarray
    err: np.ndarray
    ist: np.ndarray


class AttitudeRow(NamedTuple):
    """An :class:`AttitudeError`'s row state: the Gauss–Markov state after the buffered block
    ``x`` (3,), the buffered ``δθ`` ``dth`` (1, block, 3), ``ist`` (1, 2) and the last ``δθ``
    ``last`` (1, 3). :class:`~ag_uav.vehicle.sensors_batched.BatchAttitudeError` stacks them."""

    x: np.ndarray
    dth: np.ndarray
    ist: np.ndarray
    last: np.ndarray


class ImuSensor:
    """MEMS accelerometer + gyro errors on MuJoCo's exact readings (module docstring).

    ``measure(f, w)`` takes the noiseless specific force and body rate (3-sequences) and returns
    the measured ones as lists (:func:`imu_row` on this sensor's one-row arrays). Errors are
    drawn in blocks of ``block`` samples (:func:`imu_error_block`) from one Generator
    (``seed``), so a run's IMU depends only on its seed.
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
        self._bias = self.bias0.copy()                  # the bias after the buffered block
        self._err = np.zeros((1, block, 6))             # the buffered errors e_k
        self._ist = np.zeros((1, 2), dtype=np.int64)    # next sample, samples buffered
        self._io = np.zeros((4, 1, 3))                  # f, w in; f, w out
        self._last_bias_block = np.zeros((0, 6))
        self.bias_log: list[np.ndarray] = []   # the bias at the start of every block

    def _refill(self) -> None:
        n = self.block
        err, self._bias, bias = imu_error_block(self.rng, self._bias, n, self.sigma_rw,
                                                self.sigma_white)
        self.bias_log.append(bias[0].copy())
        self._last_bias_block = bias
        self._err[0, :n] = err
        self._ist[0] = 0, n

    @property
    def row_state(self) -> ImuRow:
        """This sensor's row state (the arrays themselves: a batch taking it over copies them)."""
        return ImuRow(self._bias, self._err, self._ist)

    def walk_block(self) -> np.ndarray:
        """Draw this sensor's next block and return its walked bias ``b_k`` (block, 6): the
        bias in force at each sample (accel m/s², gyro rad/s), drawn exactly as
        :meth:`measure` draws it. A second sensor built from the same seed and block, called
        block after block, therefore gives the engine's IMU's bias truth sample by sample (the
        INS scores its bias states against it: ``ag_uav.navigation.ins_feedback``); the
        returned array is overwritten by the next call."""
        self._refill()
        return self._last_bias_block

    def measure(self, f, w) -> tuple[list[float], list[float]]:
        if block_used_up(self._ist, 0):
            self._refill()
        io = self._io
        io[0, 0] = f
        io[1, 0] = w
        imu_row(io[0], io[1], self._err, self._ist, 0, io[2], io[3])
        return io[2, 0].tolist(), io[3, 0].tolist()

    @property
    def bias(self) -> np.ndarray:
        """The bias (accel m/s², gyro rad/s) of the last sample returned."""
        if self._ist[0, 1] == 0:
            return self.bias0.copy()
        return self._last_bias_block[max(int(self._ist[0, 0]) - 1, 0)].copy()


class AttitudeError:
    """The attitude estimate ``R̂ = Exp(δθ) · R`` with a Gauss–Markov ``δθ`` (module docstring).

    ``apply(R)`` takes a row-major 3×3 rotation as a 9-sequence and returns ``R̂`` the same way
    (:func:`attitude_row` on this object's one-row arrays); ``last`` is the last ``δθ`` (rad,
    about the world x, y (tilt) and z (yaw) axes). ``δθ`` is drawn in blocks of ``block``
    samples (:func:`gauss_markov_block`).
    """

    def __init__(self, cfg: ImuConfig, rate_hz: float, seed: np.random.SeedSequence | int,
                 block: int = 4096) -> None:
        self.rng = np.random.default_rng(seed)
        self.sigma = np.array([cfg.tilt_error_deg, cfg.tilt_error_deg, cfg.yaw_error_deg]) * DEG
        self.phi = math.exp(-1.0 / (rate_hz * cfg.attitude_error_tau_s))
        self.block = block
        self._x = self.rng.standard_normal(3) * self.sigma     # stationary start
        self._dth = np.zeros((1, block, 3))                    # the buffered δθ_k
        self._ist = np.zeros((1, 2), dtype=np.int64)           # next sample, samples buffered
        self._last = self._x.copy()[None, :]
        self._io = np.zeros((2, 1, 9))                         # R in, R̂ out

    @property
    def last(self) -> np.ndarray:
        """The last ``δθ`` (rad, world x, y, z; the stationary start before the first apply)."""
        return self._last[0].copy()

    @property
    def row_state(self) -> AttitudeRow:
        """This error's row state (the arrays themselves: a batch taking it over copies them)."""
        return AttitudeRow(self._x, self._dth, self._ist, self._last)

    def _refill(self) -> None:
        x = gauss_markov_block(self.rng, self._x, self.block, self.phi, self.sigma)
        self._x = x[-1].copy()
        self._dth[0, :self.block] = x
        self._ist[0] = 0, self.block

    def apply(self, R) -> tuple[float, ...]:
        if block_used_up(self._ist, 0):
            self._refill()
        io = self._io
        io[0, 0] = R
        attitude_row(io[0], self._dth, self._ist, 0, io[1], self._last)
        return tuple(io[1, 0].tolist())
