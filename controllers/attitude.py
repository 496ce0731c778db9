"""Inner loops of the multirotor cascade: thrust vectoring, attitude control and the X mixer.

Everything here runs once per control tick, so it is written with plain Python floats (numpy calls
on 3-vectors cost about 1 µs each; see ``../shared/specs/vehicle_and_speed.md``).

Frames: world ENU (x east, y north, z up), body FLU (x forward, y left, z up). A rotation matrix
``R`` maps body to world and is stored row-major as a 9-tuple ``(r00, r01, r02, r10, ...)``.

References
----------
T. Lee, M. Leok, N. H. McClamroch, "Geometric tracking control of a quadrotor UAV on SE(3)",
IEEE CDC 2010 (attitude error e_R = ½ vee(R_dᵀR − RᵀR_d), thrust f = (m a_d)·R e3).
"""

from __future__ import annotations

import math
from collections.abc import Sequence

Mat3 = tuple[float, float, float, float, float, float, float, float, float]
Vec3 = tuple[float, float, float]


def quat_to_rot(w: float, x: float, y: float, z: float) -> Mat3:
    """Rotation matrix (body → world, row-major) of a unit quaternion (w, x, y, z)."""
    xx, yy, zz = x * x, y * y, z * z
    xy, xz, yz = x * y, x * z, y * z
    wx, wy, wz = w * x, w * y, w * z
    return (
        1.0 - 2.0 * (yy + zz), 2.0 * (xy - wz), 2.0 * (xz + wy),
        2.0 * (xy + wz), 1.0 - 2.0 * (xx + zz), 2.0 * (yz - wx),
        2.0 * (xz - wy), 2.0 * (yz + wx), 1.0 - 2.0 * (xx + yy),
    )


def rot_to_euler(R: Mat3) -> tuple[float, float, float]:
    """ZYX Euler angles (roll, pitch, yaw) in radians of a row-major body → world matrix."""
    roll = math.atan2(R[7], R[8])
    pitch = -math.asin(max(-1.0, min(1.0, R[6])))
    yaw = math.atan2(R[3], R[0])
    return roll, pitch, yaw


def thrust_attitude(ax: float, ay: float, az: float, yaw: float, mass: float, g: float,
                    tilt_max: float) -> tuple[Mat3, float, float]:
    """Desired attitude and collective thrust for a desired acceleration (world frame).

    The desired force is ``f = m (a + g e3)``; its horizontal part is scaled down so that the tilt
    stays below ``tilt_max`` (rad) and its vertical part is kept ≥ 0.2 m g. The desired body z axis
    is ``f/|f|``; the body x axis is the heading ``yaw`` projected into the plane normal to it.

    Returns ``(R_d, |f|, tilt)`` with ``R_d`` row-major.
    """
    fx, fy, fz = mass * ax, mass * ay, mass * (az + g)
    fz_min = 0.2 * mass * g
    if fz < fz_min:
        fz = fz_min
    fh = math.hypot(fx, fy)
    fh_max = fz * math.tan(tilt_max)
    if fh > fh_max:
        s = fh_max / fh
        fx *= s
        fy *= s
        fh = fh_max
    fn = math.sqrt(fx * fx + fy * fy + fz * fz)
    b3x, b3y, b3z = fx / fn, fy / fn, fz / fn
    cx, cy = math.cos(yaw), math.sin(yaw)
    # b2 = b3 × c, c = (cx, cy, 0)
    b2x, b2y, b2z = -b3z * cy, b3z * cx, b3x * cy - b3y * cx
    n2 = math.sqrt(b2x * b2x + b2y * b2y + b2z * b2z)
    b2x, b2y, b2z = b2x / n2, b2y / n2, b2z / n2
    # b1 = b2 × b3
    b1x = b2y * b3z - b2z * b3y
    b1y = b2z * b3x - b2x * b3z
    b1z = b2x * b3y - b2y * b3x
    R_d = (b1x, b2x, b3x, b1y, b2y, b3y, b1z, b2z, b3z)
    return R_d, fn, math.atan2(fh, fz)


def geometric_torque(R: Mat3, omega: Sequence[float], R_d: Mat3, J: Sequence[float],
                     kR: Sequence[float], kw: Sequence[float]) -> tuple[Vec3, Vec3]:
    """The law of :class:`GeometricAttitudeController`: ``(τ, e_R)`` for attitude R, body rates
    omega, target R_d, inertia J and gains kR, kw (pure float code, also compiled for
    :mod:`controllers.batched`)."""
    r = R
    d = R_d
    # M = R_dᵀ R  (only the off-diagonal entries are needed for vee(M − Mᵀ))
    m01 = d[0] * r[1] + d[3] * r[4] + d[6] * r[7]
    m02 = d[0] * r[2] + d[3] * r[5] + d[6] * r[8]
    m10 = d[1] * r[0] + d[4] * r[3] + d[7] * r[6]
    m12 = d[1] * r[2] + d[4] * r[5] + d[7] * r[8]
    m20 = d[2] * r[0] + d[5] * r[3] + d[8] * r[6]
    m21 = d[2] * r[1] + d[5] * r[4] + d[8] * r[7]
    ex = 0.5 * (m21 - m12)
    ey = 0.5 * (m02 - m20)
    ez = 0.5 * (m10 - m01)
    wx, wy, wz = omega[0], omega[1], omega[2]
    Jx, Jy, Jz = J[0], J[1], J[2]
    # ω × Jω
    gx = wy * Jz * wz - wz * Jy * wy
    gy = wz * Jx * wx - wx * Jz * wz
    gz = wx * Jy * wy - wy * Jx * wx
    return (
        (-kR[0] * ex - kw[0] * wx + gx, -kR[1] * ey - kw[1] * wy + gy,
         -kR[2] * ez - kw[2] * wz + gz),
        (ex, ey, ez),
    )


class GeometricAttitudeController:
    """PD attitude control on SO(3) (Lee et al. 2010) with gyroscopic compensation.

    ``τ = J (−ω_n² e_R − 2ζω_n e_ω) + ω × Jω`` per body axis, with
    ``e_R = ½ vee(R_dᵀR − RᵀR_d)`` and ``e_ω = ω`` (the set point's angular rate is taken as zero,
    which is what a cascade with a slower outer loop needs).

    Parameters
    ----------
    inertia: principal moments (Jx, Jy, Jz) in kg m² (body axes).
    wn: natural frequencies (rad/s) for roll, pitch, yaw.
    zeta: damping ratios for roll, pitch, yaw.
    """

    def __init__(self, inertia: Sequence[float], wn: Sequence[float] = (9.0, 9.0, 3.0),
                 zeta: Sequence[float] = (0.9, 0.9, 0.9)) -> None:
        self.J = tuple(float(v) for v in inertia)
        self.kR = tuple(j * w * w for j, w in zip(self.J, wn, strict=True))
        self.kw = tuple(2.0 * j * z * w for j, z, w in zip(self.J, zeta, wn, strict=True))
        self.eR = (0.0, 0.0, 0.0)

    def update(self, R: Mat3, omega: Sequence[float], R_d: Mat3) -> tuple[float, float, float]:
        """Body torques (τx, τy, τz) in N m for attitude R, body rates omega, target R_d."""
        tau, self.eR = geometric_torque(R, omega, R_d, self.J, self.kR, self.kw)
        return tau


class XMixer:
    """Allocation of collective thrust and body torques to four rotors, with saturation.

    Rotor ``i`` sits at ``(x_i, y_i)`` in the body frame and pushes ``f_i`` along body z; its yaw
    reaction torque is ``s_i k f_i`` (``s_i = ±1``). Then
    ``[T, τx, τy, τz]ᵀ = A f``, rows ``1``, ``y_i``, ``−x_i``, ``s_i k``; ``A`` is inverted once.

    Saturation priority (as in PX4's and Betaflight's mixers): roll/pitch first, then collective
    thrust, then yaw. Yaw torque is scaled down until the rotors fit, then the collective is
    shifted, then the result is clipped to ``[0, f_max]``.
    """

    def __init__(self, positions: Sequence[Sequence[float]], spin: Sequence[int], k_yaw: float,
                 f_max: float) -> None:
        import numpy as np  # only at construction

        A = np.array([
            [1.0, 1.0, 1.0, 1.0],
            [p[1] for p in positions],
            [-p[0] for p in positions],
            [s * k_yaw for s in spin],
        ])
        self.A = A
        self.Ainv = tuple(tuple(float(v) for v in row) for row in np.linalg.inv(A))
        self.f_max = float(f_max)
        self.saturated = False

    def _alloc(self, T: float, tx: float, ty: float, tz: float) -> list[float]:
        return [r[0] * T + r[1] * tx + r[2] * ty + r[3] * tz for r in self.Ainv]

    def mix(self, T: float, tx: float, ty: float, tz: float) -> list[float]:
        """Rotor thrusts (N) for collective ``T`` (N) and body torques (N m)."""
        fmax = self.f_max
        f = self._alloc(T, tx, ty, tz)
        lo, hi = min(f), max(f)
        self.saturated = lo < 0.0 or hi > fmax
        if not self.saturated:
            return f
        # 1. drop yaw
        fy = self._alloc(T, tx, ty, 0.0)
        lo0, hi0 = min(fy), max(fy)
        if lo0 >= 0.0 and hi0 <= fmax:
            # largest yaw fraction that still fits (the allocation is linear in tz)
            s = 1.0
            for a, b in zip(fy, f, strict=True):
                d = b - a
                if d > 0.0 and b > fmax:
                    s = min(s, (fmax - a) / d)
                elif d < 0.0 and b < 0.0:
                    s = min(s, -a / d)
            return [a + s * (b - a) for a, b in zip(fy, f, strict=True)]
        # 2. shift the collective to keep roll/pitch
        if hi0 - lo0 <= fmax:
            shift = -lo0 if lo0 < 0.0 else fmax - hi0
            return [v + shift for v in fy]
        # 3. roll/pitch alone exceed the range: clip
        return [min(fmax, max(0.0, v)) for v in fy]
