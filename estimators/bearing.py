"""Bearing (angle-of-arrival) measurement model, angle wrapping and the bearing-tracking setup of
Qin, Xu & Liu, "Path Planning for UAV Target Tracking with Non-Gaussian Noise" (MCEP).

Bearing from an observer u = (ξ_u, η_u) to a point b = (ξ_b, η_b) (the paper's eqs 1-3, a
four-quadrant arctangent)::

    θ = atan2(η_b − η_u, ξ_b − ξ_u),        d² = (ξ_b − ξ_u)² + (η_b − η_u)²

    ∂θ/∂ξ_u = (η_b − η_u)/d²,   ∂θ/∂η_u = (ξ_u − ξ_b)/d²        (the paper's eq 11)
    ∂θ/∂ξ_b = (η_u − η_b)/d²,   ∂θ/∂η_b = (ξ_b − ξ_u)/d²        (target in the state)

Angles are compared through :func:`wrap_angle` (to (−π, π]): a bearing innovation of 359° is −1°.

Noise (the paper's eq 4): a two-component Gaussian mixture per channel,
``v ~ (1 − ϑ) N(0, γ₁) + ϑ N(0, γ₂)`` with γ₁ = 0.01 rad², γ₂ = 0.1 rad², ϑ = 0.1 in section IV
(:func:`mixture_noise`).

Planning cost (the paper's Table II, eqs 30-32): the trace of the covariance after an update
with a candidate Jacobian H, for the optimal gain K = P̄Hᵀ S⁻¹ (then the Joseph form equals
P̄ − P̄HᵀS⁻¹HP̄), is the closed form ::

    tr P⁺ = tr P̄ − tr(S⁻¹ H P̄ P̄ Hᵀ),      S = H P̄ Hᵀ + R,

evaluated for a whole batch of candidate Jacobians at once (:func:`trace_after_update`).

Standalone (numpy only).
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence

import numpy as np

from numkit import X, Y

__all__ = [
    "BearingModel",
    "angle_residual",
    "bearing",
    "bearing_jacobian",
    "cv_transition",
    "cv_process_noise",
    "mixture_noise",
    "residual_with_angles",
    "trace_after_update",
    "trace_cost",
    "wrap_angle",
]

TWO_PI = 2.0 * math.pi

#: the observer's columns (its x, y) of a reduced Jacobian, before each target's two
OBS_COLS = 2


def wrap_angle(a):
    """Wrap angle(s) to (−π, π] (π stays π, −π becomes π)."""
    if isinstance(a, float | int):
        return math.pi - math.fmod(math.fmod(math.pi - a, TWO_PI) + TWO_PI, TWO_PI)
    return np.pi - np.mod(np.pi - np.asarray(a, dtype=float), TWO_PI)


def angle_residual(a, b):
    """``wrap_angle(a − b)`` (elementwise, broadcasting): the residual of angle measurements."""
    return np.pi - np.mod(np.pi - (np.asarray(a, dtype=float) - b), TWO_PI)


def residual_with_angles(angle_mask: Sequence[bool]) -> Callable[[np.ndarray, np.ndarray],
                                                                    np.ndarray]:
    """A residual ``r(a, b) = a − b`` that wraps the channels where ``angle_mask`` is true.

    Works on (m,) vectors and on (k, m) stacks (rows = sigma points)."""
    mask = np.asarray(angle_mask, dtype=bool)
    if mask.all():
        return angle_residual

    def residual(a, b):
        d = np.asarray(a, dtype=float) - b
        d[..., mask] = np.pi - np.mod(np.pi - d[..., mask], TWO_PI)
        return d

    return residual


def bearing(src, dst):
    """Bearing atan2(η_dst − η_src, ξ_dst − ξ_src) from ``src`` to ``dst`` (…, 2) arrays."""
    src = np.asarray(src, dtype=float)
    dst = np.asarray(dst, dtype=float)
    return np.arctan2(dst[..., 1] - src[..., 1], dst[..., 0] - src[..., 0])


def bearing_jacobian(src, dst) -> tuple[np.ndarray, np.ndarray]:
    """(∂θ/∂src, ∂θ/∂dst), each (…, 2), for θ = :func:`bearing` (src, dst)."""
    src = np.asarray(src, dtype=float)
    dst = np.asarray(dst, dtype=float)
    dx = dst[..., 0] - src[..., 0]
    dy = dst[..., 1] - src[..., 1]
    d2 = dx * dx + dy * dy
    g_src = np.stack([dy / d2, -dx / d2], axis=-1)
    return g_src, -g_src


def mixture_noise(rng: np.random.Generator, size, var1: float = 0.01, var2: float = 0.1,
                  weight: float = 0.1) -> np.ndarray:
    """Draws of ``(1 − weight) N(0, var1) + weight N(0, var2)`` (the paper's eq 4), i.i.d.

    Each sample picks its component with a Bernoulli(weight) draw, then a standard normal."""
    if not 0.0 <= weight < 1.0:
        raise ValueError("weight must be in [0, 1)")
    outlier = rng.random(size) < weight
    std = np.where(outlier, math.sqrt(var2), math.sqrt(var1))
    return std * rng.standard_normal(size)


def cv_transition(n_axes: int, dt: float) -> np.ndarray:
    """Block-diagonal constant-velocity F, one [[1, dt], [0, 1]] block per axis (eqs 7-8)."""
    return np.kron(np.eye(n_axes), np.array([[1.0, dt], [0.0, 1.0]]))


def cv_process_noise(q: Sequence[float], dt: float) -> np.ndarray:
    """Continuous white-acceleration Q, q_i [[dt³/3, dt²/2], [dt²/2, dt]] per axis."""
    blk = np.array([[dt**3 / 3, dt**2 / 2], [dt**2 / 2, dt]])
    return np.kron(np.diag(np.asarray(q, dtype=float)), blk)


def _trace_inv_prod(S: np.ndarray, M: np.ndarray) -> np.ndarray:
    """tr(S⁻¹ M) for stacks of symmetric matrices; closed form (adjugate) for m ≤ 3."""
    m = S.shape[-1]
    if m == 1:
        return M[..., 0, 0] / S[..., 0, 0]
    if m == 2:
        s00, s01, s11 = S[..., 0, 0], S[..., 0, 1], S[..., 1, 1]
        det = s00 * s11 - s01 * s01
        return (s11 * M[..., 0, 0] + s00 * M[..., 1, 1] - 2.0 * s01 * M[..., 0, 1]) / det
    if m == 3:
        # rows of (9, k) copies are contiguous: much faster than strided slices of (k, 3, 3)
        s00, s01, s02, _, s11, s12, _, _, s22 = np.ascontiguousarray(
            S.reshape(-1, 9).T)
        m00, m01, m02, _, m11, m12, _, _, m22 = np.ascontiguousarray(M.reshape(-1, 9).T)
        c00 = s11 * s22 - s12 * s12
        c11 = s00 * s22 - s02 * s02
        c22 = s00 * s11 - s01 * s01
        c01 = s02 * s12 - s01 * s22
        c02 = s01 * s12 - s02 * s11
        c12 = s01 * s02 - s00 * s12
        det = s00 * c00 + s01 * c01 + s02 * c02
        num = c00 * m00 + c11 * m11 + c22 * m22 + 2.0 * (c01 * m01 + c02 * m02 + c12 * m12)
        return (num / det).reshape(S.shape[:-2])
    return np.trace(np.linalg.solve(S, M), axis1=-2, axis2=-1)


def trace_after_update(P: np.ndarray, H: np.ndarray, R: np.ndarray,
                       cols: Sequence[int] | None = None) -> np.ndarray:
    """tr P⁺ for each candidate Jacobian of a batch (see the module docstring).

    ``P`` (n, n) prior, ``H`` (k, m, n) candidate Jacobians, ``R`` (m, m); returns (k,).
    Equals the trace of the Joseph form (I − KH) P (I − KH)ᵀ + K R Kᵀ with K = P Hᵀ S⁻¹.
    With ``cols`` the Jacobians are given on those state columns only, (k, m, len(cols)) (all
    other columns zero, e.g. :meth:`BearingModel.jacobian_reduced`); then only the c×c blocks
    P[cols, cols] and (P P)[cols, cols] are used. :func:`trace_cost` precomputes them once
    for many batches with the same P."""
    return trace_cost(P, R, cols)(H)


def trace_cost(P: np.ndarray, R: np.ndarray,
               cols: Sequence[int] | None = None) -> Callable[[np.ndarray], np.ndarray]:
    """``H ↦ tr P⁺`` (see :func:`trace_after_update`) with the P-dependent parts precomputed.

    ``P`` may be a batch (B, n, n); the returned function then takes H of shape (B, k, m, c)
    and returns (B, k): one closed-form evaluation for B priors × k candidates."""
    P = np.asarray(P, dtype=float)
    R = np.asarray(R, dtype=float)
    if cols is None:
        Pc, PPc = P, P @ P
    else:
        idx = np.asarray(cols)
        Pc = P[..., idx[:, None], idx[None, :]]
        PPc = P[..., idx, :] @ P[..., :, idx]
    c = Pc.shape[-1]
    both = np.concatenate([Pc, PPc], axis=-1)  # one matmul gives H P and H P P
    trP = np.trace(P, axis1=-2, axis2=-1)
    if P.ndim == 3:
        both = both[:, None]
        trP = trP[:, None]
    else:
        trP = float(trP)

    def cost(H: np.ndarray) -> np.ndarray:
        HT = np.swapaxes(H, -1, -2)
        HB = H @ both
        S = HB[..., :c] @ HT + R
        M = HB[..., c:] @ HT
        return trP - _trace_inv_prod(S, M)

    return cost


class BearingModel:
    """Bearings from one observer in the state to fixed landmarks and to points in the state.

    Parameters
    ----------
    n : state dimension.
    observer : state indices (ξ, η) of the observer (the UAV).
    landmarks : (L, 2) known positions (the paper's anchors b₁, b₂); may be empty.
    targets : state index pairs (ξ, η) of points in the state (the paper's target).

    Measurement order: landmarks first, then targets (the paper's Z = [θ_ub1, θ_ub2, θ_ut]).
    :meth:`h` and :meth:`jacobian` accept one state (n,) or a stack (k, n).
    """

    def __init__(self, n: int, observer: tuple[int, int] = (0, 2),
                 landmarks: Sequence[Sequence[float]] | np.ndarray = (),
                 targets: Sequence[tuple[int, int]] = ()) -> None:
        self.n = int(n)
        self.observer = (int(observer[0]), int(observer[1]))
        lm = np.asarray(landmarks, dtype=float).reshape(-1, 2)
        self.landmarks = lm
        self.targets = [(int(a), int(b)) for a, b in targets]
        self.m = lm.shape[0] + len(self.targets)
        if self.m == 0:
            raise ValueError("need at least one landmark or target")

    def _points(self, X: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Observer (k, 2) and the observed points (k, m, 2)."""
        ox, oy = self.observer
        obs = X[:, [ox, oy]]
        k = X.shape[0]
        pts = np.empty((k, self.m, 2))
        L = self.landmarks.shape[0]
        pts[:, :L, :] = self.landmarks
        for j, (tx, ty) in enumerate(self.targets):
            pts[:, L + j, 0] = X[:, tx]
            pts[:, L + j, 1] = X[:, ty]
        return obs, pts

    def _pts1(self, x: np.ndarray) -> tuple[float, float, list[tuple[float, float]]]:
        ox, oy = self.observer
        pts = [(float(a), float(b)) for a, b in self.landmarks]
        pts += [(float(x[tx]), float(x[ty])) for tx, ty in self.targets]
        return float(x[ox]), float(x[oy]), pts

    def h(self, x: np.ndarray) -> np.ndarray:
        """Bearings (m,) for a state (n,), or (k, m) for a stack of states (k, n)."""
        X = np.asarray(x, dtype=float)
        if X.ndim == 1:  # scalar fast path (a filter step)
            u, w, pts = self._pts1(X)
            return np.array([math.atan2(b - w, a - u) for a, b in pts])
        X = X.reshape(-1, self.n)
        obs, pts = self._points(X)
        return bearing(obs[:, None, :], pts)

    @property
    def columns(self) -> list[int]:
        """State columns the Jacobian can touch: observer, then each target (ξ, η)."""
        cols = list(self.observer)
        for t in self.targets:
            cols += list(t)
        return cols

    def jacobian_reduced(self, x: np.ndarray) -> np.ndarray:
        """∂h/∂x restricted to :attr:`columns`: (m, c) for a state, (k, m, c) for a stack."""
        X = np.asarray(x, dtype=float)
        single = X.ndim == 1
        X = X.reshape(-1, self.n)
        obs, pts = self._points(X)
        g_obs, g_pts = bearing_jacobian(obs[:, None, :], pts)
        k = X.shape[0]
        H = np.zeros((k, self.m, OBS_COLS + 2 * len(self.targets)))
        H[:, :, :OBS_COLS] = g_obs
        L = self.landmarks.shape[0]
        for j in range(len(self.targets)):
            H[:, L + j, OBS_COLS + 2 * j:OBS_COLS + 2 * (j + 1)] = g_pts[:, L + j, :]
        return H[0] if single else H

    def observer_jacobian(self, obs: np.ndarray, x: np.ndarray) -> tuple[np.ndarray,
                                                                         np.ndarray]:
        """Reduced Jacobians (…, k, m, c) at the state ``x`` (…, n) with the observer moved to
        each of the positions ``obs`` (…, k, 2), and the squared distances (…, k, m) to the
        observed points. Leading dimensions (…) broadcast: B states × k candidates at once.

        The fast path of path planning: only the observer changes between candidates."""
        obs = np.asarray(obs, dtype=float)
        x = np.asarray(x, dtype=float)
        L = self.landmarks.shape[0]
        pts = np.empty(x.shape[:-1] + (self.m, 2))
        pts[..., :L, :] = self.landmarks
        for j, (tx, ty) in enumerate(self.targets):
            pts[..., L + j, 0] = x[..., tx]
            pts[..., L + j, 1] = x[..., ty]
        pts = pts[..., None, :, :]  # (…, 1, m, 2)
        dx = pts[..., X] - obs[..., X:X + 1]
        dy = pts[..., Y] - obs[..., Y:Y + 1]
        d2 = dx * dx + dy * dy
        a = dy / d2
        b = -dx / d2
        H = np.zeros(d2.shape + (OBS_COLS + 2 * len(self.targets),))
        H[..., X] = a                        # ∂β/∂(observer x, y) = (Δy, −Δx) / d²
        H[..., Y] = b
        for j in range(len(self.targets)):
            c = OBS_COLS + 2 * j             # the target's (x, y) columns: the opposite sign
            H[..., L + j, c + X] = -a[..., L + j]
            H[..., L + j, c + Y] = -b[..., L + j]
        return H, d2

    def jacobian(self, x: np.ndarray) -> np.ndarray:
        """∂h/∂x, (m, n) for a state or (k, m, n) for a stack (the paper's eq 11)."""
        X = np.asarray(x, dtype=float)
        if X.ndim == 1:  # scalar fast path (a filter step)
            u, w, pts = self._pts1(X)
            H = np.zeros((self.m, self.n))
            ox, oy = self.observer
            L = self.landmarks.shape[0]
            for i, (a, b) in enumerate(pts):
                dx, dy = a - u, b - w
                d2 = dx * dx + dy * dy
                H[i, ox] = dy / d2
                H[i, oy] = -dx / d2
                if i >= L:
                    tx, ty = self.targets[i - L]
                    H[i, tx] -= dy / d2
                    H[i, ty] += dx / d2
            return H
        Hr = self.jacobian_reduced(X)
        H = np.zeros(Hr.shape[:-1] + (self.n,))
        for j, c in enumerate(self.columns):
            H[..., c] += Hr[..., j]
        return H

    def residual(self, a, b):
        """Wrapped bearing residual (every channel is an angle)."""
        return angle_residual(a, b)
