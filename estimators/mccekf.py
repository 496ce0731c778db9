"""Maximum-correntropy-criterion extended Kalman filter (MCC-EKF) for nonlinear measurements
(Qin, Xu & Liu, "Path Planning for UAV Target Tracking with Non-Gaussian Noise", section III.A,
Table I; the fixed point is the MCKF of Chen, Liu, Zhao & Principe, Automatica 80, 2017).

Predict as the EKF: x̄ = f(x̂) + B u, P̄ = F P Fᵀ + Q with F = F_jac(x̂)  (the paper's eq 10 reads
"F P + Fᵀ Q", a typo for this).

Update: linearise at the prediction, H = H_jac(x̄) (the paper's eq 11 for bearings), and run the
MCKF fixed point (:class:`estimators.MCKF`, every option included) on the linearised regression
(the paper's eqs 12-15)::

    [x̄; z̃] = [I; H] x + α,    z̃ = H x̄ + ν,    ν = residual(z, h(x̄))

i.e. with the innovation z − h(x̄) (not z − H x̄), angle innovations wrapped to (−π, π] by the
``residual`` (:func:`estimators.bearing.angle_residual` for bearings). Whitened by
blkdiag(B_p, B_r)⁻¹ (Cholesky factors of P̄ and R), weighted per row by the Gaussian kernel
G_σ(e) = exp(−e²/(2σ²)), iterated from x̂⁽⁰⁾ = x̄ until the relative change is ≤ ``eps`` (at most
``max_iter`` iterations), gain K̃ = P̃Hᵀ(HP̃Hᵀ + R̃)⁻¹, x̂ = x̄ + K̃ν and the Joseph form with
the original P̄ and R (eqs 16-25).

With σ → ∞ every kernel weight is 1 and the filter is exactly the EKF (σ = 1e6 agrees to ~1e-11).
The robustness guards of :class:`estimators.MCKF` apply: the information-form gain (a channel
whose weight underflows drops out), floored state weights, the iteration cap and the lock-out
recovery rule (``recovery="kf"`` by default: after ``lockout_n`` consecutive rejected fixes one
plain EKF update is made).
"""

from __future__ import annotations

import numpy as np

from .ekf import NonlinearModelMixin, Residual
from .mckf import MCKF

__all__ = ["MCCEKF"]

_dot = np.dot


class MCCEKF(NonlinearModelMixin, MCKF):
    """MCC-EKF (see the module docstring).

    Parameters
    ----------
    f, F_jac, h, H_jac, Q, R, x0, P0 : as :class:`estimators.ekf.EKF`.
    **options : ``residual`` and ``B`` (keywords) as :class:`estimators.ekf.EKF`; then
        ``options`` (an :class:`estimators.mckf.MCKFOptions`) and any of its fields by name, as
        :class:`estimators.MCKF`: ``sigma`` the kernel bandwidth (dimensionless: the residuals
        are whitened; scalar or a vector of length n+m, one kernel per row), ``eps``,
        ``max_iter`` the fixed-point stop rule and iteration cap, ``kernel_floor``,
        ``adaptive_sigma``, ``recovery``, ``lockout_n``, ``reject_weight``, ...
    """

    def __init__(self, f, F_jac, h, H_jac, Q, R, x0=None, P0=None, **options) -> None:
        residual: Residual | None = options.pop("residual", None)
        B = options.pop("B", None)
        R = np.array(R, dtype=float, ndmin=2)
        Qa = np.array(Q, dtype=float, ndmin=2)
        n, m = Qa.shape[0], R.shape[0]
        F0 = self._set_models(f, F_jac, h, H_jac, residual, B, n)
        super().__init__(F0, np.zeros((m, n)), Qa, R, x0, P0, **options)

    def update(self, z) -> bool:
        """Fuse measurement ``z`` (m,); ``False`` (nothing changes) if there is none.

        Implemented as the MCKF update on the linearised pseudo-measurement z̃ = H x̄ + ν, so that
        the MCKF's innovation z̃ − H x̄ is the (wrapped) ν."""
        if z is None:
            return False
        z = np.asarray(z, dtype=float).reshape(-1)
        xb = self.x
        H = np.asarray(self._H_jac(xb), dtype=float)
        nu = np.asarray(self.residual(z, np.asarray(self._h(xb), dtype=float)), dtype=float)
        self.H = H  # refreshes the whitened H (B_r⁻¹ H) of the MCKF
        return super().update(_dot(H, xb) + nu)
