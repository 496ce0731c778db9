"""Quaternions, rotation matrices and Euler angles: every conversion of the three packages,
written once.

Conventions (the same everywhere, and MuJoCo's):

- a quaternion is a unit Hamilton quaternion stored scalar-first ``q = (w, x, y, z)``
  (components ``q[QW]``, ``q[QX]``, ``q[QY]``, ``q[QZ]``, :mod:`numkit.axes`); the product is
  Hamilton's, ``(a ⊗ b)_w = a_w b_w − a_v · b_v``, ``(a ⊗ b)_v = a_w b_v + b_w a_v + a_v × b_v``
  (MuJoCo's ``mju_mulQuat``);
- ``R(q)`` maps body to world, ``v_world = R(q) v_body = q ⊗ (0, v_body) ⊗ q*`` (MuJoCo's
  ``mju_quat2Mat`` and ``mju_rotVecQuat``; Solà, "Quaternion kinematics for the error-state
  Kalman filter", arXiv:1711.02508, eq 115);
- a rotation matrix is either a (3, 3) array ``R[i, j]`` or a flat row-major 9-vector
  ``R[3 i + j]`` (MuJoCo's ``xmat``; the named positions :data:`RXX` … :data:`RZZ`);
- Euler angles are roll φ, pitch θ, yaw ψ in radians, ZYX intrinsic (yaw about z, then pitch
  about the new y, then roll about the new x): ``R = Rz(ψ) Ry(θ) Rx(φ)`` (scipy's
  ``Rotation.from_euler("ZYX", [ψ, θ, φ])``); back from a matrix
  ``φ = atan2(R₂₁, R₂₂)``, ``θ = −asin(R₂₀)``, ``ψ = atan2(R₁₀, R₀₀)``, with θ ∈ [−π/2, π/2]
  (at θ = ±π/2, gimbal lock, only ψ ∓ φ is defined: φ and ψ come out of round-off there);
- the exponential map ``Exp(φ) = (cos(θ/2), sin(θ/2) φ/θ)``, θ = ‖φ‖, turns a rotation vector
  into a quaternion (Solà eq 101) and ``Log`` is its inverse.

The kernels are compiled (numba, :mod:`numkit._jit`) so the packages' compiled kernels call
them, and plain Python calls them too; they write into an ``out`` argument or return a tuple
(a kernel's tick allocates nothing).  The ``*s_*`` functions at the end work on arrays of
``n`` rotations for the offline tools (log replay, encoding).  Each formula keeps the order of
operations its callers had, so their results are unchanged bit for bit.
"""

from __future__ import annotations

import math

import numpy as np

from ._jit import njit
from .axes import QW, QX, QY, QZ, X, Y, Z

__all__ = ["RXX", "RXY", "RXZ", "RYX", "RYY", "RYZ", "RZX", "RZY", "RZZ", "euler_to_quat",
           "euler_to_rots", "quat_conj", "quat_exp", "quat_log_err", "quat_mul", "quat_normalize",
           "quat_rotate", "quat_to_euler", "quat_to_rot", "quat_to_rot9", "quat_to_rot_flat",
           "quats_to_rots", "rot_to_euler", "rot_to_quat", "rot_to_yaw", "rots_to_euler",
           "rots_to_quats", "yaw_to_quat"]

#: positions of R[i, j] in a flat row-major rotation matrix
RXX, RXY, RXZ = 3 * X + X, 3 * X + Y, 3 * X + Z
RYX, RYY, RYZ = 3 * Y + X, 3 * Y + Y, 3 * Y + Z
RZX, RZY, RZZ = 3 * Z + X, 3 * Z + Y, 3 * Z + Z


# --------------------------------------------------------------------- quaternion → rotation
@njit
def quat_to_rot9(w: float, x: float, y: float, z: float) -> tuple[float, ...]:
    """R(q) of a unit quaternion (w, x, y, z), body → world, as a row-major 9-tuple::

        R = [[1 − 2(y² + z²), 2(xy − wz),     2(xz + wy)    ],
             [2(xy + wz),     1 − 2(x² + z²), 2(yz − wx)    ],
             [2(xz − wy),     2(yz + wx),     1 − 2(x² + y²)]]      (Solà eq 115)
    """
    xx, yy, zz = x * x, y * y, z * z
    xy, xz, yz = x * y, x * z, y * z
    wx, wy, wz = w * x, w * y, w * z
    return (
        1.0 - 2.0 * (yy + zz), 2.0 * (xy - wz), 2.0 * (xz + wy),
        2.0 * (xy + wz), 1.0 - 2.0 * (xx + zz), 2.0 * (yz - wx),
        2.0 * (xz - wy), 2.0 * (yz + wx), 1.0 - 2.0 * (xx + yy),
    )


@njit
def quat_to_rot(q, R) -> None:
    """R (3, 3) ← R(q) (:func:`quat_to_rot9`)."""
    m = quat_to_rot9(q[QW], q[QX], q[QY], q[QZ])
    for i in range(3):
        for j in range(3):
            R[i, j] = m[3 * i + j]


@njit
def quat_to_rot_flat(q, R) -> None:
    """R (9,), row-major, ← R(q) (:func:`quat_to_rot9`)."""
    m = quat_to_rot9(q[QW], q[QX], q[QY], q[QZ])
    for k in range(9):
        R[k] = m[k]


@njit
def rot_to_quat(R, q) -> None:
    """q ← the quaternion of a flat row-major rotation R (Shepperd's method: the largest of
    4w², 4x², 4y², 4z² found from the trace and the diagonal, the others from the off-diagonal
    sums and differences).  Not normalised; its sign is the branch's (w ≥ 0 when the trace is
    positive)."""
    tr = R[RXX] + R[RYY] + R[RZZ]
    if tr > 0.0:
        s = math.sqrt(tr + 1.0) * 2.0
        q[QW], q[QX] = 0.25 * s, (R[RZY] - R[RYZ]) / s
        q[QY], q[QZ] = (R[RXZ] - R[RZX]) / s, (R[RYX] - R[RXY]) / s
    elif R[RXX] > R[RYY] and R[RXX] > R[RZZ]:
        s = math.sqrt(1.0 + R[RXX] - R[RYY] - R[RZZ]) * 2.0
        q[QW], q[QX] = (R[RZY] - R[RYZ]) / s, 0.25 * s
        q[QY], q[QZ] = (R[RXY] + R[RYX]) / s, (R[RXZ] + R[RZX]) / s
    elif R[RYY] > R[RZZ]:
        s = math.sqrt(1.0 + R[RYY] - R[RXX] - R[RZZ]) * 2.0
        q[QW], q[QX] = (R[RXZ] - R[RZX]) / s, (R[RXY] + R[RYX]) / s
        q[QY], q[QZ] = 0.25 * s, (R[RYZ] + R[RZY]) / s
    else:
        s = math.sqrt(1.0 + R[RZZ] - R[RXX] - R[RYY]) * 2.0
        q[QW], q[QX] = (R[RYX] - R[RXY]) / s, (R[RXZ] + R[RZX]) / s
        q[QY], q[QZ] = (R[RYZ] + R[RZY]) / s, 0.25 * s


# ------------------------------------------------------------------------ quaternion algebra
@njit
def quat_mul(a, b, out) -> None:
    """out = a ⊗ b (Hamilton); ``out`` may not alias ``a`` or ``b``."""
    out[QW] = a[QW] * b[QW] - a[QX] * b[QX] - a[QY] * b[QY] - a[QZ] * b[QZ]
    out[QX] = a[QW] * b[QX] + a[QX] * b[QW] + a[QY] * b[QZ] - a[QZ] * b[QY]
    out[QY] = a[QW] * b[QY] - a[QX] * b[QZ] + a[QY] * b[QW] + a[QZ] * b[QX]
    out[QZ] = a[QW] * b[QZ] + a[QX] * b[QY] - a[QY] * b[QX] + a[QZ] * b[QW]


@njit
def quat_conj(q, out) -> None:
    """out = q* = (w, −x, −y, −z), the inverse of a unit quaternion."""
    out[QW] = q[QW]
    out[QX], out[QY], out[QZ] = -q[QX], -q[QY], -q[QZ]


@njit
def quat_normalize(q, out) -> None:
    """out = q / ‖q‖ (``out`` may be ``q``)."""
    nrm = math.sqrt(q[QW] * q[QW] + q[QX] * q[QX] + q[QY] * q[QY] + q[QZ] * q[QZ])
    for k in range(4):
        out[k] = q[k] / nrm


@njit
def quat_rotate(q, v, out) -> None:
    """out = R(q) v (= q ⊗ (0, v) ⊗ q*): a body vector in the world frame."""
    m = quat_to_rot9(q[QW], q[QX], q[QY], q[QZ])
    for i in range(3):
        out[i] = m[3 * i + X] * v[X] + m[3 * i + Y] * v[Y] + m[3 * i + Z] * v[Z]


@njit
def quat_exp(phi, out) -> None:
    """out = Exp(φ) = (cos(θ/2), sin(θ/2) φ/θ), θ = ‖φ‖ (Solà eq 101); (1, φ/2) below
    θ = 1e-12."""
    th = math.sqrt(phi[X] * phi[X] + phi[Y] * phi[Y] + phi[Z] * phi[Z])
    if th < 1e-12:
        out[QW] = 1.0
        for k in range(3):
            out[QX + k] = 0.5 * phi[k]
        return
    s = math.sin(0.5 * th) / th
    out[QW] = math.cos(0.5 * th)
    for k in range(3):
        out[QX + k] = s * phi[k]


@njit
def quat_log_err(q_est, q_true, out) -> None:
    """out = Log(q_est* ⊗ q_true): the local attitude error δθ with q_true = q_est ⊗ Exp(δθ)
    (the shorter way round: d and −d are the same rotation)."""
    c = np.empty(4)
    quat_conj(q_est, c)
    d = np.empty(4)
    quat_mul(c, q_true, d)
    if d[QW] < 0.0:
        for k in range(4):
            d[k] = -d[k]
    n = math.sqrt(d[QX] * d[QX] + d[QY] * d[QY] + d[QZ] * d[QZ])
    th = 2.0 * math.atan2(n, d[QW])
    s = th / n if n > 1e-15 else 2.0
    for k in range(3):
        out[k] = s * d[QX + k]


# ---------------------------------------------------------------------------- Euler angles
@njit
def euler_to_quat(roll: float, pitch: float, yaw: float, q) -> None:
    """q ← the quaternion of ZYX Euler angles, q = q_z(ψ) ⊗ q_y(θ) ⊗ q_x(φ)::

        w = cφ cθ cψ + sφ sθ sψ,   x = sφ cθ cψ − cφ sθ sψ,
        y = cφ sθ cψ + sφ cθ sψ,   z = cφ cθ sψ − sφ sθ cψ      (c·, s· of half angles)
    """
    cr, sr = math.cos(roll / 2), math.sin(roll / 2)
    cp, sp = math.cos(pitch / 2), math.sin(pitch / 2)
    cy, sy = math.cos(yaw / 2), math.sin(yaw / 2)
    q[QW] = cr * cp * cy + sr * sp * sy
    q[QX] = sr * cp * cy - cr * sp * sy
    q[QY] = cr * sp * cy + sr * cp * sy
    q[QZ] = cr * cp * sy - sr * sp * cy


@njit
def yaw_to_quat(yaw: float, q) -> None:
    """q ← (cos(ψ/2), 0, 0, sin(ψ/2)): a turn by ψ about z (:func:`euler_to_quat` at φ = θ = 0,
    its zeros exact)."""
    q[QW], q[QX], q[QY], q[QZ] = math.cos(yaw / 2), 0.0, 0.0, math.sin(yaw / 2)


@njit
def quat_to_euler(w: float, x: float, y: float, z: float) -> tuple[float, float, float]:
    """(roll, pitch, yaw) of a unit quaternion (w, x, y, z)::

        φ = atan2(2(wx + yz), 1 − 2(x² + y²)),  θ = asin(2(wy − zx)),
        ψ = atan2(2(wz + xy), 1 − 2(y² + z²))

    (the asin's argument clipped to [−1, 1] against rounding)."""
    sr = 2.0 * (w * x + y * z)
    cr = 1.0 - 2.0 * (x * x + y * y)
    sp = 2.0 * (w * y - z * x)
    sp = 1.0 if sp > 1.0 else (-1.0 if sp < -1.0 else sp)
    sy = 2.0 * (w * z + x * y)
    cy = 1.0 - 2.0 * (y * y + z * z)
    return math.atan2(sr, cr), math.asin(sp), math.atan2(sy, cy)


@njit
def rot_to_euler(R) -> tuple[float, float, float]:
    """(roll, pitch, yaw) of a flat row-major rotation (or a 9-tuple):
    φ = atan2(R₂₁, R₂₂), θ = −asin(R₂₀), ψ = atan2(R₁₀, R₀₀)."""
    roll = math.atan2(R[RZY], R[RZZ])
    pitch = -math.asin(max(-1.0, min(1.0, R[RZX])))
    return roll, pitch, rot_to_yaw(R)


@njit
def rot_to_yaw(R) -> float:
    """The yaw ψ = atan2(R₁₀, R₀₀) of a flat row-major rotation (or a 9-tuple)."""
    return math.atan2(R[RYX], R[RXX])


# --------------------------------------------------------------- arrays of n rotations
@njit
def _quats_to_rots_into(q, R) -> None:
    for i in range(q.shape[0]):
        quat_to_rot(q[i], R[i])


def quats_to_rots(q: np.ndarray) -> np.ndarray:
    """Quaternions (n, 4), normalised here → rotation matrices (n, 3, 3) (:func:`quat_to_rot`)."""
    q = np.asarray(q, dtype=float)
    q = q / np.linalg.norm(q, axis=1, keepdims=True)
    R = np.empty((q.shape[0], 3, 3))
    _quats_to_rots_into(q, R)
    return R


def rots_to_quats(R: np.ndarray) -> np.ndarray:
    """Rotation matrices (n, 3, 3) → unit quaternions (n, 4) with w ≥ 0 (:func:`rot_to_quat`)."""
    R = np.ascontiguousarray(R, dtype=float).reshape(-1, 9)
    q = np.empty((R.shape[0], 4))
    for i in range(R.shape[0]):
        rot_to_quat(R[i], q[i])
    q /= np.linalg.norm(q, axis=1, keepdims=True)
    q[q[:, QW] < 0.0] *= -1.0
    return q


def euler_to_rots(roll: np.ndarray, pitch: np.ndarray, yaw: np.ndarray) -> np.ndarray:
    """ZYX Euler angles (n,) each → rotation matrices (n, 3, 3), R = Rz(ψ) Ry(θ) Rx(φ)::

        R = [[cψ cθ, cψ sθ sφ − sψ cφ, cψ sθ cφ + sψ sφ],
             [sψ cθ, sψ sθ sφ + cψ cφ, sψ sθ cφ − cψ sφ],
             [−sθ,   cθ sφ,            cθ cφ           ]]
    """
    cr, sr = np.cos(roll), np.sin(roll)
    cp, sp = np.cos(pitch), np.sin(pitch)
    cy, sy = np.cos(yaw), np.sin(yaw)
    R = np.empty((np.size(roll), 3, 3))
    R[:, X, X], R[:, X, Y], R[:, X, Z] = cy * cp, cy * sp * sr - sy * cr, cy * sp * cr + sy * sr
    R[:, Y, X], R[:, Y, Y], R[:, Y, Z] = sy * cp, sy * sp * sr + cy * cr, sy * sp * cr - cy * sr
    R[:, Z, X], R[:, Z, Y], R[:, Z, Z] = -sp, cp * sr, cp * cr
    return R


def rots_to_euler(R: np.ndarray) -> np.ndarray:
    """Rotation matrices (n, 3, 3) → (n, 3) roll, pitch, yaw (:func:`rot_to_euler`'s law)."""
    roll = np.arctan2(R[:, Z, Y], R[:, Z, Z])
    pitch = np.arcsin(np.clip(-R[:, Z, X], -1.0, 1.0))
    yaw = np.arctan2(R[:, Y, X], R[:, X, X])
    return np.stack([roll, pitch, yaw], axis=1)
