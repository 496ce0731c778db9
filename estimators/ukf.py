"""Unscented Kalman filter (Julier & Uhlmann 1997; scaled sigma points of Van der Merwe 2004).

Sigma points (2n + 1) for a mean x and covariance P::

    λ = α²(n + κ) − n,        L Lᵀ = (n + λ) P          (lower Cholesky factor)
    χ₀ = x,   χᵢ = x + Lᵢ,   χₙ₊ᵢ = x − Lᵢ           (Lᵢ the i-th column of L)
    W₀ᵐ = λ/(n + λ),   W₀ᶜ = W₀ᵐ + 1 − α² + β,   Wᵢᵐ = Wᵢᶜ = 1/(2(n + λ))

Defaults α = 1, β = 2, κ = 0 (so λ = 0, W₀ᵐ = 0, W₀ᶜ = 2 and every weight is ≥ 0: the
covariance estimates stay positive semi-definite, the points lie at ±√n standard deviations).
The popular α = 1e-3 makes W₀ hugely negative for n = 8, which is fragile with bearings.

Predict::

    χ = sigma(x̂, P),    𝒳ᵢ = f(χᵢ) + B u,    x̄ = Σ Wᵢᵐ 𝒳ᵢ,    P̄ = Σ Wᵢᶜ (𝒳ᵢ − x̄)(𝒳ᵢ − x̄)ᵀ + Q

Update (sigma points redrawn from the prior, 𝒳 = sigma(x̄, P̄), so that they carry Q — the
additive-noise UKF, as filterpy does)::

    𝒵ᵢ = h(𝒳ᵢ),   ẑ = 𝒵₀ + Σ Wᵢᵐ r(𝒵ᵢ, 𝒵₀)            (mean of residuals: correct for angles)
    S = Σ Wᵢᶜ r(𝒵ᵢ, ẑ) r(𝒵ᵢ, ẑ)ᵀ + R,   C = Σ Wᵢᶜ (𝒳ᵢ − x̄) r(𝒵ᵢ, ẑ)ᵀ,   K = C S⁻¹
    x̂ = x̄ + K r(z, ẑ),   P = P̄ − K S Kᵀ  (symmetrised)

``r`` is the ``residual`` (default subtraction; :func:`estimators.bearing.angle_residual` wraps
bearings). With plain subtraction ẑ is the usual weighted mean Σ Wᵢᵐ 𝒵ᵢ.

Interface as the rest of the bank: ``predict(u=None)``, ``update(z) -> bool`` (``None`` / NaN
is "no fix"), attributes ``x``, ``P``, ``y``, ``S``, ``K``, ``nis``. filterpy's
``UnscentedKalmanFilter`` with ``MerweScaledSigmaPoints(n, α, β, κ)`` is the test oracle.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, replace

import numpy as np

from .kf import inv_small
from .mckf import safe_cholesky

__all__ = ["UKF", "UKFOptions", "merwe_weights"]

_dot = np.dot
Residual = Callable[[np.ndarray, np.ndarray], np.ndarray]


def merwe_weights(n: int, alpha: float, beta: float, kappa: float):
    """(λ, Wᵐ, Wᶜ) of the scaled sigma points."""
    lam = alpha * alpha * (n + kappa) - n
    c = n + lam
    if c <= 0:
        raise ValueError(f"n + λ = {c} must be > 0 (choose α, κ accordingly)")
    Wm = np.full(2 * n + 1, 0.5 / c)
    Wc = Wm.copy()
    Wm[0] = lam / c
    Wc[0] = lam / c + 1.0 - alpha * alpha + beta
    return lam, Wm, Wc


@dataclass(frozen=True)
class UKFOptions:
    """The sigma-point options of :class:`UKF`.

    alpha, beta, kappa : sigma-point scaling (defaults 1, 2, 0; :func:`merwe_weights`).
    vectorized : ``f`` and ``h`` accept a (k, n) stack of states and return (k, ·) — one call
        per step instead of 2n + 1.
    """

    alpha: float = 1.0
    beta: float = 2.0
    kappa: float = 0.0
    vectorized: bool = False


class UKF:
    """Unscented Kalman filter (see the module docstring).

    Parameters
    ----------
    f : transition ``f(x) -> x`` or a constant (n×n) matrix.
    h : measurement function ``h(x) -> (m,)``.
    Q, R : process and measurement noise covariances.
    x0, P0 : initial state and covariance (default zeros and identity).
    residual : measurement residual ``r(a, b)`` (must broadcast over a (k, m) stack).
    B : control matrix for ``predict(u)``.
    options : :class:`UKFOptions` (its defaults when omitted); ``alpha``, ``beta``, ``kappa``,
        ``vectorized`` may be given by name instead (keywords over ``options``).
    """

    def __init__(self, f, h, Q, R, x0=None, P0=None, residual: Residual | None = None, B=None,
                 options: UKFOptions | None = None, **changes) -> None:
        o = replace(options or UKFOptions(), **changes)  # TypeError names a bad keyword
        alpha, beta, kappa, vectorized = o.alpha, o.beta, o.kappa, o.vectorized
        self.Q = np.array(Q, dtype=float, ndmin=2)
        self.R = np.array(R, dtype=float, ndmin=2)
        n, m = self.Q.shape[0], self.R.shape[0]
        self.n, self.m = n, m
        if callable(f):
            self._f, self._F = f, None
        else:
            self._F = np.array(f, dtype=float, ndmin=2)
            self._f = None
        self._h = h
        self.residual: Residual = (lambda a, b: a - b) if residual is None else residual
        self.B = None if B is None else np.array(B, dtype=float, ndmin=2)
        self.vectorized = bool(vectorized)
        self.alpha, self.beta, self.kappa = float(alpha), float(beta), float(kappa)
        self.lam, self.Wm, self.Wc = merwe_weights(n, self.alpha, self.beta, self.kappa)
        self.x = np.zeros(n) if x0 is None else np.array(x0, dtype=float).reshape(n)
        self.P = np.eye(n) if P0 is None else np.array(P0, dtype=float).reshape(n, n).copy()
        self.y = np.zeros(m)
        self.S = self.R.copy()
        self.K = np.zeros((n, m))
        self.nis = math.nan

    def sigma_points(self, x: np.ndarray, P: np.ndarray) -> np.ndarray:
        """The 2n + 1 scaled sigma points as rows, (2n + 1, n)."""
        L = safe_cholesky((self.n + self.lam) * P)
        LT = L.T
        return np.concatenate([x[None, :], x + LT, x - LT])

    def _fx(self, X: np.ndarray) -> np.ndarray:
        if self._f is None:
            return _dot(X, self._F.T)
        if self.vectorized:
            return np.asarray(self._f(X), dtype=float)
        return np.array([self._f(xi) for xi in X], dtype=float)

    def _hx(self, X: np.ndarray) -> np.ndarray:
        if self.vectorized:
            return np.asarray(self._h(X), dtype=float).reshape(X.shape[0], self.m)
        return np.array([self._h(xi) for xi in X], dtype=float).reshape(X.shape[0], self.m)

    def predict(self, u=None) -> None:
        """Unscented prediction (see the module docstring)."""
        Xf = self._fx(self.sigma_points(self.x, self.P))
        if u is not None:
            if self.B is None:
                raise ValueError("predict(u) needs B")
            Xf = Xf + _dot(self.B, np.asarray(u, dtype=float).reshape(-1))
        x = _dot(self.Wm, Xf)
        d = Xf - x
        self.x = x
        self.P = _dot(d.T * self.Wc, d) + self.Q

    def update(self, z) -> bool:
        """Unscented update with measurement ``z``; ``False`` (nothing changes) if none."""
        if z is None:
            return False
        z = np.asarray(z, dtype=float).reshape(-1)
        x, P = self.x, self.P
        Xf = self.sigma_points(x, P)
        Z = self._hx(Xf)
        r = self.residual
        zp = Z[0] + _dot(self.Wm, r(Z, Z[0]))
        dz = r(Z, zp)
        Wc = self.Wc
        S = _dot(dz.T * Wc, dz) + self.R
        C = _dot((Xf - x).T * Wc, dz)
        Si = inv_small(S)
        y = np.asarray(r(z, zp), dtype=float)
        nis = float(_dot(y, _dot(Si, y)))
        if not math.isfinite(nis):
            return False
        K = _dot(C, Si)
        self.x = x + _dot(K, y)
        Pn = P - _dot(_dot(K, S), K.T)
        self.P = 0.5 * (Pn + Pn.T)
        self.y, self.S, self.K, self.nis = y, S, K, nis
        return True
