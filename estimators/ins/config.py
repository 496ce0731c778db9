"""The INS's configuration: :class:`INSConfig` and the names of its rules and kernels."""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np

from ..mckf import AP, FP, IP, MCKF_I
from . import layout
from .layout import MP

__all__ = ["DEG", "G_STD", "INS_RECOVERY", "KERNELS", "RULES", "RULE_CODE", "INSConfig"]

#: the GNSS position rules (a bank's rows), and their codes in the kernel
RULES = ("kf", "mckf", "pca-kf", "pca-mckf")
RULE_CODE = {r: i for i, r in enumerate(RULES)}
#: the MCKF kernels (``INSConfig.mckf_kernel``)
KERNELS = ("fixed", "adaptive", "multi")
#: the lock-out recovery rules and their codes in the kernel
INS_RECOVERY = {None: 0, "none": 0, "kf": 1, "inflate": 2}
G_STD = 9.81
DEG = math.pi / 180.0


# ------------------------------------------------------------------------ configuration
@dataclass
class INSConfig:
    """Parameters of the INS (defaults: the simulator's ICM-42688-P-class IMU at 100 Hz, an
    M350-RTK-class receiver, PX4's GNSS delay).

    IMU noise: ``accel_sigma`` / ``gyro_sigma`` per-sample white std (m/s², rad/s),
    ``accel_bias_rw`` ((m/s²)/√s), ``gyro_bias_rw`` ((rad/s)/√s); :meth:`from_imu` derives
    them from datasheet densities as ``ag_uav.vehicle.imu`` draws them.  Geometry (body axes,
    m): ``lever_arm`` IMU → GNSS antenna, ``heading_baseline`` the dual-antenna baseline
    direction, ``radar_offset`` IMU → radar; ``ground_z`` the flat ground height;
    ``radar_max_tilt_deg``, ``radar_max_range`` the radar's usable cone and range.  Fusion:
    ``delay_s`` (PX4 ``EKF2_GPS_DELAY`` default 110 ms), ``delayed`` (False: fuse at receipt),
    ``queue`` records per row.  GNSS position rule options: ``sigma`` the MCKF kernel
    bandwidth (scalar or 18 values, one per row of the whitened regression: 15 error states,
    then the 3 position channels; ``inf`` = KF), ``mckf_kernel`` (``"fixed"``: those widths;
    ``"adaptive"``: σ_k = σ max(1, √ŝ_k), ŝ the clipped exponentially weighted NIS/3 with
    factor ``adapt_lambda`` and clip ``adapt_clip``, the rule of :class:`estimators.MCKF`
    ``adaptive_sigma``; ``"multi"``: a scalar σ on the 3 position rows and ∞ on the 15 state
    rows, so only the fix is down-weighted, never the INS prior), ``max_iter``, ``eps``,
    ``recovery`` (``"kf"``, ``"inflate"`` or ``None``),
    ``lockout_n``, ``reject_weight``, ``inflate``; PCA block ``pca_window``, ``pca_mode``,
    ``pca_embed``, ``pca_components`` (as :class:`estimators.PCABlock`).  The innovation
    gate, common to the four rules and applied to the GNSS position, velocity and heading
    before any update (:func:`gate_ratio`): ``gate_sigma`` γ (PX4 ``EKF2_GPS_GATE``, default
    5; ``inf`` = no gate) and ``gate_reset_s``: a rejected position fix that comes that long
    after the last fused position and the last fused velocity, or twice that long after the
    last fused position, resets the position to the receiver (``inf`` = never);
    ``gate_latch_s``: the step latch's hold limit (s; 0 = no latch, ``inf`` = no limit; the
    module docstring of :mod:`estimators.ins`).  ``coning``: the IMU samples are the means of
    delta-angles and delta-velocities over Δt, and the prediction applies the previous-sample
    coning and sculling corrections (:func:`estimators.ins.model.increments`); False: rates
    held over the step.
    """

    dt: float = 0.01
    gravity: float = G_STD
    accel_sigma: float = 0.1004
    gyro_sigma: float = 3.46e-4
    accel_bias_rw: float = 3e-4
    gyro_bias_rw: float = 1e-3 * DEG
    lever_arm: Sequence[float] = (0.0, 0.0, 0.3)
    heading_baseline: Sequence[float] = (0.0, 1.0, 0.0)
    radar_offset: Sequence[float] = (0.0, 0.0, -0.1)
    ground_z: float = 0.0
    radar_max_tilt_deg: float = 30.0
    radar_max_range: float = 50.0
    delay_s: float = 0.11
    delayed: bool = True
    queue: int = 64
    sigma: float | Sequence[float] = 2.0
    mckf_kernel: str = "fixed"
    adapt_lambda: float = 0.98
    adapt_clip: float = 3.0
    max_iter: int = 10
    eps: float = 1e-6
    recovery: str | None = "kf"
    lockout_n: int = 10
    reject_weight: float = 0.05
    inflate: float = 4.0
    pca_window: int = 10
    pca_mode: str = "hankel"
    pca_embed: int | None = None
    pca_components: int | None = None
    gate_sigma: float = 5.0
    gate_reset_s: float = 5.0
    gate_latch_s: float = 60.0
    coning: bool = True
    extra: dict = field(default_factory=dict)

    @classmethod
    def from_imu(cls, rate_hz: float, accel_nd_ug: float = 70.0, gyro_nd_mdps: float = 2.8,
                 vibration: float = 0.1, accel_rw: float = 3e-4, gyro_rw_dps: float = 1e-3,
                 **kw) -> INSConfig:
        """σ per sample = density · √(f_s/2) (⊕ vibration for the accelerometer), as
        ``ag_uav.vehicle.imu.accel_sigma`` / ``gyro_sigma``; defaults ICM-42688-P (DS-000347
        Tables 1-2) and the simulator's ``[imu]`` defaults."""
        nyq = math.sqrt(rate_hz / 2.0)
        sa = math.hypot(accel_nd_ug * 1e-6 * G_STD * nyq, vibration)
        sg = gyro_nd_mdps * 1e-3 * DEG * nyq
        return cls(dt=1.0 / rate_hz, accel_sigma=sa, gyro_sigma=sg, accel_bias_rw=accel_rw,
                   gyro_bias_rw=gyro_rw_dps * DEG, **kw)

    def delay_ticks(self) -> int:
        return int(round(self.delay_s / self.dt)) if self.delayed else 0

    def prm(self) -> np.ndarray:
        p = np.zeros(layout.PRM.size)
        dt = self.dt
        p[layout.PR.DT], p[layout.PR.G] = dt, self.gravity
        p[layout.PR.QV] = (self.accel_sigma * dt) ** 2
        p[layout.PR.QT] = (self.gyro_sigma * dt) ** 2
        p[layout.PR.QBA] = self.accel_bias_rw**2 * dt
        p[layout.PR.QBG] = self.gyro_bias_rw**2 * dt
        p[layout.PRM.slice("r_ant")] = self.lever_arm
        b = np.asarray(self.heading_baseline, dtype=float)
        p[layout.PRM.slice("r_b")] = b / np.linalg.norm(b)
        p[layout.PRM.slice("r_rad")] = self.radar_offset
        p[layout.PR.Z_G] = self.ground_z
        p[layout.PR.COS_MAX] = math.cos(self.radar_max_tilt_deg * DEG)
        p[layout.PR.R_MAX] = self.radar_max_range
        D = self.delay_ticks()
        p[layout.PR.DELAY], p[layout.PR.DELAYED] = D, float(self.delayed)
        p[layout.PR.RING], p[layout.PR.QUEUE] = D + 2, self.queue
        if not (self.gate_sigma > 0 and self.gate_reset_s > 0):
            raise ValueError(f"gate_sigma and gate_reset_s must be > 0 (inf = off), got "
                             f"{self.gate_sigma!r}, {self.gate_reset_s!r}")
        p[layout.PR.GATE] = self.gate_sigma
        p[layout.PR.GATE_RESET] = self.gate_reset_s / dt
        if not self.gate_latch_s >= 0:
            raise ValueError(f"gate_latch_s must be >= 0 (0 = no latch, inf = no limit), got "
                             f"{self.gate_latch_s!r}")
        p[layout.PR.GATE_LATCH] = self.gate_latch_s / dt
        p[layout.PR.PCA_WINDOW] = self.pca_window
        p[layout.PR.CONING] = float(bool(self.coning))
        return p

    def kernel_widths(self) -> np.ndarray:
        """The 18 base kernel widths (15 state rows, 3 position rows) of ``sigma`` and
        ``mckf_kernel``; ValueError for a bad combination."""
        if self.mckf_kernel not in KERNELS:
            raise ValueError(f"mckf_kernel must be one of {', '.join(KERNELS)}, got "
                             f"{self.mckf_kernel!r}")
        s = np.atleast_1d(np.asarray(self.sigma, dtype=float))
        if self.mckf_kernel == "multi":
            if s.size != 1:
                raise ValueError("mckf_kernel = 'multi' takes a scalar sigma (the position "
                                 "rows'; the 15 state rows get inf)")
            s = np.concatenate([np.full(15, np.inf), np.full(3, s[0])])
        s = np.full(18, s[0]) if s.size == 1 else s
        if s.shape != (18,) or np.any(~(s > 0)):
            raise ValueError("sigma must be a positive scalar or 18 values (15 states + 3)")
        if self.mckf_kernel == "adaptive" and not (0.0 <= self.adapt_lambda < 1.0
                                                   and self.adapt_clip > 0.0):
            raise ValueError("mckf_kernel = 'adaptive' needs 0 <= adapt_lambda < 1 and "
                             "adapt_clip > 0")
        return s

    def mckf_params(self) -> tuple[np.ndarray, np.ndarray]:
        """(mpar = [kx(15), ky(3), fpar(5), apar(3) = (adaptive, λ, clip), σ(18)], ipar(4))
        as :class:`estimators.MCKF` sets them."""
        from scipy.special import gammaincinv

        s = self.kernel_widths()
        c = -1.0 / (2.0 * s * s)
        if self.recovery not in INS_RECOVERY:
            raise ValueError(f"recovery must be 'kf', 'inflate' or None, got {self.recovery!r}")
        gate = 2.0 * float(gammaincinv(1.5, 0.999))
        jmax = max(1, int(12.0 / math.log10(self.inflate))) if self.inflate > 1 else 1
        mpar = np.empty(layout.MPAR.size)
        ne = layout.ERR.size
        mpar[MP.KX:MP.KX_END], mpar[MP.KY:MP.KY_END] = c[:ne], 0.5 * c[ne:]  # −1/(2σ²), −1/(4σ²)
        f = mpar[MP.F:MP.F_END]
        f[FP.FLOOR], f[FP.EPS2], f[FP.REJECT] = 1e-12, self.eps**2, self.reject_weight
        f[FP.INFLATE], f[FP.GATE] = self.inflate, gate
        a = mpar[MP.A:MP.A_END]
        a[AP.ADAPTIVE], a[AP.LAM] = float(self.mckf_kernel == "adaptive"), self.adapt_lambda
        a[AP.CLIP] = self.adapt_clip
        mpar[MP.SIG:MP.SIG_END] = s
        ipar = np.empty(MCKF_I.size, dtype=np.int64)
        ipar[IP.MAX_ITER], ipar[IP.LOCKOUT] = self.max_iter, self.lockout_n
        ipar[IP.RECOVERY], ipar[IP.JMAX] = INS_RECOVERY[self.recovery], jmax
        return mpar, ipar

