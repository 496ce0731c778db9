"""Extended Kalman filter with the Joseph-form update and a custom innovation residual.

Predict (linearised at the prior estimate x̂)::

    F = F_jac(x̂),      x̄ = f(x̂) + B u,      P̄ = F P Fᵀ + Q

(The paper of Qin, Xu & Liu prints eq 10 as "F P + Fᵀ Q": a typo for F P Fᵀ + Q, which its own
Table I uses.)

Update with a measurement z (linearised at the prediction x̄)::

    H = H_jac(x̄),      ν = residual(z, h(x̄)),     S = H P̄ Hᵀ + R,     K = P̄ Hᵀ S⁻¹
    x̂ = x̄ + K ν,       P = (I − K H) P̄ (I − K H)ᵀ + K R Kᵀ,            NIS = νᵀ S⁻¹ ν

``residual`` defaults to plain subtraction; for bearings pass
:func:`estimators.bearing.angle_residual` so that ν is wrapped to (−π, π].

Same interface as the linear bank (:mod:`estimators.kf`): ``predict()``, ``update(z) -> bool``
(``None`` or a fix with NaN/inf is "no fix": nothing changes, ``False``), attributes ``x``, ``P``
and after an update ``y`` (= ν), ``S``, ``K``, ``nis``, ``H``.  filterpy's
``ExtendedKalmanFilter`` (Joseph form, ``residual`` argument) is the test oracle.
"""

from __future__ import annotations

import math
from collections.abc import Callable

import numpy as np

from .kf import LinearGaussianBase, inv_small, joseph

__all__ = ["EKF", "NonlinearModelMixin"]

_dot = np.dot
Residual = Callable[[np.ndarray, np.ndarray], np.ndarray]


def _subtract(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    return a - b


class NonlinearModelMixin:
    """Holds f, F_jac, h, H_jac, B and the residual for EKF-type filters."""

    def _set_models(self, f, F_jac, h, H_jac, residual, B, n: int) -> np.ndarray:
        """Store the model functions; returns the F to start from (for the base class)."""
        if callable(f):
            if F_jac is None:
                raise ValueError("a callable f needs F_jac")
            self._f, self._F_jac = f, F_jac
            F0 = np.eye(n)
        else:
            F0 = np.array(f, dtype=float, ndmin=2)
            self._f, self._F_jac = None, None
        if not callable(h) or not callable(H_jac):
            raise ValueError("h and H_jac must be callables")
        self._h, self._H_jac = h, H_jac
        self.residual: Residual = _subtract if residual is None else residual
        self.B = None if B is None else np.array(B, dtype=float, ndmin=2)
        return F0

    def predict(self, u=None) -> None:
        """x̄ = f(x̂) + B u, P̄ = F P Fᵀ + Q with F = F_jac(x̂) (or the constant F)."""
        x = self.x
        if self._f is None:
            F, FT = self._F, self._FT
            xb = _dot(F, x)
        else:
            F = np.asarray(self._F_jac(x), dtype=float)
            FT = F.T
            self._F, self._FT = F, FT
            xb = np.asarray(self._f(x), dtype=float).reshape(-1)
        if u is not None:
            if self.B is None:
                raise ValueError("predict(u) needs B")
            xb = xb + _dot(self.B, np.asarray(u, dtype=float).reshape(-1))
        self.x = xb
        self.P = _dot(_dot(F, self.P), FT) + self.Q  # the base filter's Q (a property)


class EKF(NonlinearModelMixin, LinearGaussianBase):
    """Extended Kalman filter (see the module docstring).

    Parameters
    ----------
    f : transition function ``f(x) -> x`` or a constant (n×n) matrix (linear dynamics).
    F_jac : ``F_jac(x) -> (n×n)`` (ignored when ``f`` is a matrix; may be ``None`` then).
    h, H_jac : measurement function ``h(x) -> (m,)`` and its Jacobian ``H_jac(x) -> (m×n)``.
    Q, R : process (n×n) and measurement (m×m) noise covariances.
    x0, P0 : initial state and covariance (default zeros and identity).
    residual : ``residual(z, h(x̄))``; default ``z − h(x̄)``.
    B : control matrix for ``predict(u)`` (n×p); optional.
    """

    def __init__(self, f, F_jac, h, H_jac, Q, R, x0=None, P0=None,
                 residual: Residual | None = None, B=None) -> None:
        R = np.array(R, dtype=float, ndmin=2)
        Qa = np.array(Q, dtype=float, ndmin=2)
        n, m = Qa.shape[0], R.shape[0]
        F0 = self._set_models(f, F_jac, h, H_jac, residual, B, n)
        super().__init__(F0, np.zeros((m, n)), Qa, R, x0, P0)

    def update(self, z) -> bool:
        """Fuse measurement ``z`` (m,); ``False`` (nothing changes) if there is none."""
        if z is None:
            return False
        z = np.asarray(z, dtype=float).reshape(-1)
        x, P = self.x, self.P
        H = np.asarray(self._H_jac(x), dtype=float)
        HT = H.T
        PHT = _dot(P, HT)
        S = _dot(H, PHT) + self._R
        Si = inv_small(S)
        y = np.asarray(self.residual(z, np.asarray(self._h(x), dtype=float)), dtype=float)
        nis = float(_dot(y, _dot(Si, y)))
        if not math.isfinite(nis):
            return False
        K = _dot(PHT, Si)
        self.x = x + _dot(K, y)
        self.P = joseph(P, K, H, self._R)
        self._H, self._HT = H, HT
        self.y, self.S, self.K, self.nis = y, S, K, nis
        return True
