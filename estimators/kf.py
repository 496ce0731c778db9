"""Linear Kalman filter (Kalman 1960) with the Joseph-form covariance update.

Predict::

    x̄ = F x̂,            P̄ = F P Fᵀ + Q

Update with a fix y (position)::

    ν = y − H x̄,          S = H P̄ Hᵀ + R,     K = P̄ Hᵀ S⁻¹
    x̂ = x̄ + K ν,          P = (I − K H) P̄ (I − K H)ᵀ + K R Kᵀ      (Joseph form)
    NIS = νᵀ S⁻¹ ν

This is Algorithm 1 of Candan & Li with the Joseph form in place of the short form
``(I − K H) P`` (which loses symmetry and definiteness in floating point).

Where the law lives: the compiled row functions of this module, on one filter's arrays —
:func:`kf_predict_row` (F in sparse row form, so the zeros of F are skipped), :func:`kf_input_row`
(the IMU input ``x[pos] += dt²/2·u``, ``x[vel] += dt·u``), :func:`kf_innovation_row`,
:func:`kf_gain_row`, :func:`joseph_row` and :func:`kf_update_row` (the whole update).  The class
:class:`KF` calls them on its own arrays (a batch of one) and
:class:`estimators.batched.BatchKF` loops over its rows calling them, so a vehicle's results are
bit-identical in either.  The MCKF (:mod:`estimators.mckf`) reuses the innovation, gain and
Joseph steps.  Without numba the same functions run as Python (:mod:`estimators._jit`).

Interface shared by every filter of the bank: ``predict()``, ``update(z) -> bool``, attributes
``x`` (shape (n,)), ``P`` (n, n), and after an update ``y`` (innovation), ``S``, ``K``, ``nis``.
``update(None)`` or a fix with any NaN/inf component is "no fix": nothing changes and ``False``
is returned (detected on the scalar NIS, so a finite fix so large that νᵀS⁻¹ν overflows, e.g.
1e300 m, is also dropped).  ``F``, ``H``, ``Q``, ``R`` can be reassigned at any time
(``kf.R = ...``); ``predict`` and ``update`` store new ``x`` and ``P`` arrays (a reference kept
by the caller is not changed in place).
"""

from __future__ import annotations

import math
from collections import namedtuple

import numpy as np

from numkit import Layout

from ._jit import njit
from ._linalg import (
    add_into,
    copy_vec,
    inv_small_into,
    mat_mul,
    mat_mul_sparse,
    mat_vec,
    quad_form,
)

__all__ = ["AXIS_BLOCK", "KF", "KFWork", "KF_WORK_FIELDS", "inv_small", "as_fix", "as_matrix",
           "as_vector", "block3", "csr", "joseph",
           "joseph_row", "kf_gain_row",
           "kf_innovation_row", "kf_input_row", "kf_predict_row", "kf_update_row", "kf_work",
           "kf_work_in", "kf_work_layout", "kf_work_size", "kf_work_spec",
           "predict_b3_row", "predict_csr_row"]

_dot = np.dot

#: one axis's block of the per-axis motion models (:mod:`estimators.models`): position,
#: velocity, and the third state (acceleration, or the input's bias)
AXIS_BLOCK = Layout("p v d")
B = AXIS_BLOCK.at

#: the names of one KF update's work arrays, in their order in the buffer
KF_WORK_FIELDS = ("nu", "PHT", "S", "Si", "K", "xo", "A", "AP", "KR")


def inv_small(S: np.ndarray) -> np.ndarray:
    """Inverse of a small non-singular matrix: closed form (adjugate / determinant) for 1×1,
    2×2 and 3×3 (a numpy call on a tiny matrix costs more than the arithmetic), LAPACK above.
    (For the numpy filters of the package: EKF, UKF, coloured-noise KFs.)"""
    m = S.shape[0]
    if m == 2:
        (a, b), (c, d) = S.tolist()
        det = a * d - b * c
        return np.array([[d / det, -b / det], [-c / det, a / det]])
    if m == 3:
        return np.array(_inv3(S.tolist()))
    if m == 1:
        return 1.0 / S
    return np.linalg.inv(S)


def _inv3(M: list) -> list:
    """Adjugate / determinant of a 3×3 matrix given as nested lists (returns nested lists)."""
    (a, b, c), (d, e, f), (g, h, i) = M
    c00, c01, c02 = e * i - f * h, f * g - d * i, d * h - e * g
    det = a * c00 + b * c01 + c * c02
    return [
        [c00 / det, (c * h - b * i) / det, (b * f - c * e) / det],
        [c01 / det, (a * i - c * g) / det, (c * d - a * f) / det],
        [c02 / det, (b * g - a * h) / det, (a * e - b * d) / det],
    ]


def as_fix(z) -> np.ndarray | None:
    """Convert a fix to a float vector; ``None`` stays ``None`` (no fix)."""
    if z is None:
        return None
    return np.asarray(z, dtype=float).reshape(-1)


def csr(F: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """F in compressed sparse row form ``(ptr, idx, val)`` for :func:`kf_predict_row`."""
    ptr, idx, val = [0], [], []
    for row in np.asarray(F, dtype=float):
        nz = np.flatnonzero(row)
        idx.extend(nz.tolist())
        val.extend(row[nz].tolist())
        ptr.append(len(idx))
    return (np.array(ptr, dtype=np.int64), np.array(idx, dtype=np.int64),
            np.array(val, dtype=float))


# ------------------------------------------------------------------------------ the law, rows
def block3(F: np.ndarray) -> np.ndarray:
    """The 3×3 block Fb when F = blkdiag(Fb, …, Fb) (the per-axis models, e.g. "cvb"), else an
    empty (0, 0) array: the argument ``Fb`` of :func:`kf_predict_row`."""
    F = np.asarray(F, dtype=float)
    n = F.shape[0]
    Fb = np.ascontiguousarray(F[:B.SIZE, :B.SIZE])
    if n % 3 == 0 and np.array_equal(F, np.kron(np.eye(n // 3), Fb)):
        return Fb
    return np.zeros((0, 0))


@njit
def kf_predict_row(x, P, fptr, fidx, fval, Fb, Q, tx, FP):
    """x ← F x, P ← F P Fᵀ + Q in place.  F in CSR form (fptr, fidx, fval: its zeros are
    skipped); when F = blkdiag(Fb, …) with 3×3 blocks (Fb non-empty, :func:`block3`) the same
    sums run block by block on local floats (each 3×3 block P_ab ← Fb P_ab Fbᵀ + Q_ab; the
    zeros of Fb add exact zeros).  tx (n,), FP (n, n) are scratch."""
    if Fb.shape[0] == 3:
        predict_b3_row(x, P, Fb, Q)
    else:
        predict_csr_row(x, P, fptr, fidx, fval, Q, tx, FP)


@njit
def predict_csr_row(x, P, fptr, fidx, fval, Q, tx, FP):
    """:func:`kf_predict_row` for a general F in CSR form."""
    n = x.shape[0]
    for r in range(n):
        s = 0.0
        for k in range(fptr[r], fptr[r + 1]):
            s += fval[k] * x[fidx[k]]
        tx[r] = s
    for r in range(n):
        for c in range(n):
            s = 0.0
            for k in range(fptr[r], fptr[r + 1]):
                s += fval[k] * P[fidx[k], c]
            FP[r, c] = s
    for r in range(n):
        for c in range(n):
            s = 0.0
            for k in range(fptr[c], fptr[c + 1]):
                s += FP[r, fidx[k]] * fval[k]
            P[r, c] = s + Q[r, c]
    for r in range(n):
        x[r] = tx[r]


@njit(inline="always")
def predict_b3_row(x, P, Fb, Q):
    """:func:`kf_predict_row` for F = blkdiag(Fb, …, Fb), 3×3 blocks (one per axis, layout
    :data:`AXIS_BLOCK`), unrolled: x_a ← Fb x_a, P_ab ← Fb P_ab Fbᵀ + Q_ab."""
    na = x.shape[0] // B.SIZE
    f00, f01, f02 = Fb[B.P, B.P], Fb[B.P, B.V], Fb[B.P, B.D]
    f10, f11, f12 = Fb[B.V, B.P], Fb[B.V, B.V], Fb[B.V, B.D]
    f20, f21, f22 = Fb[B.D, B.P], Fb[B.D, B.V], Fb[B.D, B.D]
    for a in range(na):
        o = B.SIZE * a
        op, ov, od = o + B.P, o + B.V, o + B.D   # axis a's p, v, d rows
        x0, x1, x2 = x[op], x[ov], x[od]
        x[op] = f00 * x0 + f01 * x1 + f02 * x2
        x[ov] = f10 * x0 + f11 * x1 + f12 * x2
        x[od] = f20 * x0 + f21 * x1 + f22 * x2
        for bb in range(na):
            c = B.SIZE * bb
            cp, cv, cd = c + B.P, c + B.V, c + B.D
            p00, p01, p02 = P[op, cp], P[op, cv], P[op, cd]
            p10, p11, p12 = P[ov, cp], P[ov, cv], P[ov, cd]
            p20, p21, p22 = P[od, cp], P[od, cv], P[od, cd]
            g00 = f00 * p00 + f01 * p10 + f02 * p20  # G = Fb P_ab
            g01 = f00 * p01 + f01 * p11 + f02 * p21
            g02 = f00 * p02 + f01 * p12 + f02 * p22
            g10 = f10 * p00 + f11 * p10 + f12 * p20
            g11 = f10 * p01 + f11 * p11 + f12 * p21
            g12 = f10 * p02 + f11 * p12 + f12 * p22
            g20 = f20 * p00 + f21 * p10 + f22 * p20
            g21 = f20 * p01 + f21 * p11 + f22 * p21
            g22 = f20 * p02 + f21 * p12 + f22 * p22
            P[op, cp] = (g00 * f00 + g01 * f01 + g02 * f02) + Q[op, cp]  # G Fbᵀ + Q
            P[op, cv] = (g00 * f10 + g01 * f11 + g02 * f12) + Q[op, cv]
            P[op, cd] = (g00 * f20 + g01 * f21 + g02 * f22) + Q[op, cd]
            P[ov, cp] = (g10 * f00 + g11 * f01 + g12 * f02) + Q[ov, cp]
            P[ov, cv] = (g10 * f10 + g11 * f11 + g12 * f12) + Q[ov, cv]
            P[ov, cd] = (g10 * f20 + g11 * f21 + g12 * f22) + Q[ov, cd]
            P[od, cp] = (g20 * f00 + g21 * f01 + g22 * f02) + Q[od, cp]
            P[od, cv] = (g20 * f10 + g21 * f11 + g22 * f12) + Q[od, cv]
            P[od, cd] = (g20 * f20 + g21 * f21 + g22 * f22) + Q[od, cd]


@njit(inline="always")
def kf_input_row(x, u, pos, vel, hh, dt):
    """The IMU input of the prediction, after ``kf_predict_row``: per axis a
    x[pos_a] += dt²/2 · u_a (hh = dt²/2), x[vel_a] += dt · u_a."""
    for a in range(pos.shape[0]):
        x[pos[a]] += hh * u[a]
        x[vel[a]] += dt * u[a]


@njit
def kf_innovation_row(x, P, R, H, z, nu, PHT, S, Si):
    """ν = z − H x, P Hᵀ, S = H P Hᵀ + R, S⁻¹; returns NIS = νᵀ S⁻¹ ν (not finite: no fix)."""
    mat_vec(H, x, nu)
    for a in range(z.shape[0]):
        nu[a] = z[a] - nu[a]
    mat_mul_sparse(H, P.T, PHT.T)  # P Hᵀ, H's zeros skipped
    mat_mul_sparse(H, PHT, S)
    add_into(S, R)
    inv_small_into(S, Si)
    return quad_form(Si, nu)


@njit
def kf_gain_row(x, PHT, Si, nu, K, xo):
    """K = P Hᵀ S⁻¹, xo = x + K ν."""
    mat_mul(PHT, Si, K)
    mat_vec(K, nu, xo)
    for r in range(x.shape[0]):
        xo[r] = x[r] + xo[r]


@njit
def joseph_row(Pb, K, H, R, Pout, A, AP, KR):
    """Pout = (I − K H) Pb (I − K H)ᵀ + K R Kᵀ for a symmetric Pb (Pout may alias Pb); A (n, ≥ m),
    AP (≥ m, ≥ m), KR (n, m) scratch.  Joseph's form (Bucy & Joseph 1968; Simon 2006 eq 5.19),
    expanded on A = Pb Hᵀ and S = H A + R (:func:`joseph_from`); H's zero entries are skipped
    (a measurement touches few states: the sums are unchanged)."""
    m = H.shape[0]
    Am, S = A[:, :m], AP[:m, :m]
    mat_mul_sparse(H, Pb.T, Am.T)  # A = Pb Hᵀ
    mat_mul_sparse(H, Am, S)  # S = H A + R
    add_into(S, R)
    joseph_from(Pb, K, Am, S, Pout, KR)


@njit
def joseph_from(Pb, K, A, S, Pout, KR):
    """Joseph's form given A = Pb Hᵀ and S = H A + R (an update has both from its innovation):
    (I − K H) Pb (I − K H)ᵀ + K R Kᵀ = Pb − K Aᵀ − A Kᵀ + (K S) Kᵀ, exact for ANY gain K (so it
    keeps Joseph's first-order insensitivity to an error in K: the MCKF passes its own K̃).
    O(n² m) instead of two O(n³) products; the upper triangle is formed and mirrored (Pout
    exactly symmetric; Pout may alias Pb); KR (n, m) scratch."""
    n, m = Pb.shape[0], K.shape[1]
    mat_mul(K, S, KR)  # K S
    for r in range(n):  # Pout = Pb − K Aᵀ − A Kᵀ + (K S) Kᵀ, upper triangle, mirrored
        for c in range(r, n):
            s = Pb[r, c]
            for j in range(m):
                s += (KR[r, j] - A[r, j]) * K[c, j] - K[r, j] * A[c, j]
            Pout[r, c] = s
            Pout[c, r] = s


def joseph(P, K, H, R) -> np.ndarray:
    """(I − K H) P (I − K H)ᵀ + K R Kᵀ as a new array, by :func:`joseph_row`: the one Joseph
    update, for the filters that work on numpy arrays (EKF, information filter, route KF)."""
    P, K, H, R = (np.ascontiguousarray(a, dtype=float) for a in (P, K, H, R))
    n, m = P.shape[0], H.shape[0]
    out = np.empty((n, n))
    joseph_row(P, K, H, R, out, np.empty((n, n)), np.empty((n, n)), np.empty((n, m)))
    return out


@njit
def kf_work_size(n, m):
    """Length of a buffer holding :func:`kf_work_in`'s arrays."""
    return m + 3 * n * m + 2 * m * m + n + 2 * n * n


#: the work arrays of one KF update, by name (:func:`kf_work_in`; a plain tuple in this order)
KFWork = namedtuple("KFWork", KF_WORK_FIELDS)


def kf_work_spec(n: int, m: int) -> str:
    """The fields of :func:`kf_work_in`'s buffer for n states and m measurements (a
    :class:`numkit.Layout` text): ν (m), P Hᵀ (n, m), S (m, m), S⁻¹ (m, m), K (n, m), x̂ (n),
    and :func:`joseph_row`'s A, A P (n, n), K S (n, m)."""
    return (f"nu:{m} PHT:{n}x{m} S:{m}x{m} Si:{m}x{m} K:{n}x{m} xo:{n} A:{n}x{n} AP:{n}x{n} "
            f"KR:{n}x{m}")


def kf_work_layout(n: int, m: int) -> Layout:
    """The layout of :func:`kf_work_in`'s buffer (:func:`kf_work_spec`)."""
    return Layout(kf_work_spec(n, m))


@njit(inline="always")
def kf_work_in(buf, n, m):
    """The work arrays of one update (:class:`KFWork`: ν, P Hᵀ, S, S⁻¹, K, x̂, and
    :func:`joseph_row`'s A, AP, K S) as views of ``buf`` (≥ :func:`kf_work_size`), laid out
    as :func:`kf_work_layout`: a per-tick caller allocates nothing."""
    o1 = m
    o2 = o1 + n * m
    o3 = o2 + m * m
    o4 = o3 + m * m
    o5 = o4 + n * m
    o6 = o5 + n
    o7 = o6 + n * n
    o8 = o7 + n * n
    return KFWork(buf[0:o1], buf[o1:o2].reshape((n, m)), buf[o2:o3].reshape((m, m)),
                  buf[o3:o4].reshape((m, m)), buf[o4:o5].reshape((n, m)), buf[o5:o6],
                  buf[o6:o7].reshape((n, n)), buf[o7:o8].reshape((n, n)),
                  buf[o8:o8 + n * m].reshape((n, m)))


@njit
def kf_work(n, m):
    """Work arrays of one update (:func:`kf_work_in`)."""
    return kf_work_in(np.empty(kf_work_size(n, m)), n, m)


@njit(inline="always")
def kf_update_row(x, P, R, H, z, w):
    """The KF update of one filter in place (x, P); returns its NIS.  A non-finite NIS (NaN/inf
    in z, or an overflow) is "no fix": x and P are then untouched.  ``w``: the work arrays
    (:func:`kf_work`, or :func:`kf_work_in` on the caller's buffer); after a fix they hold ν
    (``w.nu``), S (``w.S``), K (``w.K``)."""
    nu, PHT, S, Si, K, xo, _, _, KR = w
    v = kf_innovation_row(x, P, R, H, z, nu, PHT, S, Si)
    if not math.isfinite(v):
        return v
    kf_gain_row(x, PHT, Si, nu, K, xo)
    copy_vec(xo, x)
    joseph_from(P, K, PHT, S, P, KR)  # A = P Hᵀ and S as the innovation formed them
    return v


# ------------------------------------------------------------------------------ classes
def as_matrix(a, name: str, shape: tuple[int, ...] | None = None) -> np.ndarray:
    """A fresh C-contiguous float64 copy of a matrix argument (at least 2-D); ValueError naming
    ``name`` when ``shape`` is given and differs."""
    arr = np.array(a, dtype=float, ndmin=2, order="C")
    if shape is not None and arr.shape != shape:
        raise ValueError(f"{name} must have shape {shape}, got {arr.shape}")
    return arr


def as_vector(a, n: int) -> np.ndarray:
    """A fresh C-contiguous float64 copy of a state vector (n,)."""
    return np.array(a, dtype=float, order="C").reshape(n)


class LinearGaussianBase:
    """Holds F, H, Q, R, x, P and the per-update diagnostics; caches transposes and F's CSR
    form; ``predict`` is :func:`kf_predict_row` on the filter's own arrays."""

    def __init__(self, F, H, Q, R, x0=None, P0=None) -> None:
        F = as_matrix(F, "F")
        n = F.shape[0]
        if F.shape != (n, n):
            raise ValueError(f"F must be square, got {F.shape}")
        H = as_matrix(H, "H")
        if H.shape[1] != n:
            raise ValueError(f"H must have {n} columns, got {H.shape}")
        self.n, self.m = n, H.shape[0]
        self.F = F
        self.H = H
        self.Q = Q
        self.R = R
        self.x = np.zeros(n) if x0 is None else np.array(x0, dtype=float).reshape(n)
        self.P = np.eye(n) if P0 is None else as_matrix(P0, "P0", (n, n)).copy()
        self.y = np.zeros(self.m)
        self.S = self.R.copy()
        self.K = np.zeros((n, self.m))
        self.nis = math.nan
        self._tx = np.empty(n)
        self._FP = np.empty((n, n))
        self._kfw = kf_work(n, self.m)

    # matrices with cached derived quantities -------------------------------------------------
    @property
    def F(self) -> np.ndarray:
        return self._F

    @F.setter
    def F(self, value) -> None:
        F = as_matrix(value, "F", (self.n, self.n))
        self._F, self._FT = F, F.T.copy()
        self._fcsr = csr(F)
        self._Fb = block3(F)

    @property
    def H(self) -> np.ndarray:
        return self._H

    @H.setter
    def H(self, value) -> None:
        H = as_matrix(value, "H", (self.m, self.n) if hasattr(self, "m") else None)
        self._H, self._HT = H, H.T.copy()
        self._on_model_change()

    @property
    def Q(self) -> np.ndarray:
        return self._Q

    @Q.setter
    def Q(self, value) -> None:
        self._Q = as_matrix(value, "Q", (self.n, self.n))

    @property
    def R(self) -> np.ndarray:
        return self._R

    @R.setter
    def R(self, value) -> None:
        self._R = as_matrix(value, "R", (self.m, self.m))
        self._on_model_change()

    def _on_model_change(self) -> None:
        """Hook for subclasses that check or cache factors of H or R."""

    # common steps ------------------------------------------------------------------------------
    def predict(self) -> None:
        """x̄ = F x̂, P̄ = F P Fᵀ + Q (:func:`kf_predict_row`)."""
        x = as_vector(self.x, self.n)
        P = as_matrix(self.P, "P", (self.n, self.n))
        ptr, idx, val = self._fcsr
        kf_predict_row(x, P, ptr, idx, val, self._Fb, self._Q, self._tx, self._FP)
        self.x, self.P = x, P

    def _joseph(self, P: np.ndarray, K: np.ndarray) -> np.ndarray:
        """(I − K H) P (I − K H)ᵀ + K R Kᵀ (:func:`joseph_row`)."""
        n = self.n
        return joseph(as_matrix(P, "P", (n, n)), as_matrix(K, "K", (n, self.m)), self._H, self._R)

    def _fix(self, z) -> np.ndarray | None:
        """``z`` as a C-contiguous float64 (m,) vector, or None (no fix)."""
        if z is None:
            return None
        zz = np.array(z, dtype=float, order="C").reshape(-1)
        if zz.shape != (self.m,):
            raise ValueError(f"z must have {self.m} elements, got {zz.size}")
        return zz


class KF(LinearGaussianBase):
    """Linear Kalman filter, Joseph-form update (see the module docstring).

    Parameters
    ----------
    F, H, Q, R : transition (n×n), measurement (m×n), process and measurement noise covariances.
    x0, P0 : initial state (n,) and covariance (n×n); default zeros and identity.
    """

    def update(self, z) -> bool:
        """Fuse fix ``z`` (shape (m,)); returns ``False`` (and changes nothing) if there is none
        (:func:`kf_update_row`)."""
        zz = self._fix(z)
        if zz is None:
            return False
        x = as_vector(self.x, self.n)
        P = as_matrix(self.P, "P", (self.n, self.n))
        w = self._kfw
        v = kf_update_row(x, P, self._R, self._H, zz, w)
        if not math.isfinite(v):
            return False
        self.x, self.P = x, P
        self.y, self.S, self.K, self.nis = w.nu.copy(), w.S.copy(), w.K.copy(), float(v)
        return True
