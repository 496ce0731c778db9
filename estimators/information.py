"""The well-defined parts of "KFUEA" (Kalman filter with uncertainty and error awareness).

Paper: "Tracking of UAVs using a Kalman filter with error and uncertainty awareness" (the
kfuea paper in ``shared/papers``).  Its operators (V(·), I(·), ∧, Δ, S(·) in eqs 17-41) and the
parameters δ_w, δ̄_w, J are never defined, and eqs 32-41 cannot be evaluated as printed, so a
faithful implementation of KFUEA is not possible.  Two parts are well defined and implemented
here under honest names:

:class:`InformationKF` — eqs 3-14.  The update is the regularised-least-squares (RLS) solution
(eqs 10-11) w* = (K + Tᵀ M T)⁻¹ Tᵀ M e with K = P̄⁻¹ (prior information), T = H, M = R⁻¹ and
e = y − H x̄, i.e. the information form of the KF update::

    P = (P̄⁻¹ + Hᵀ R⁻¹ H)⁻¹          (eq 14)
    K = P Hᵀ R⁻¹                     (eq 13)
    x̂ = x̄ + K (y − H x̄)            (eq 12)

with the usual prediction x̄ = F x̂, P̄ = F P Fᵀ + Q (eqs 8-9).  It equals the covariance-form
KF exactly in exact arithmetic (tested to 1e-9); the information matrix Y = P⁻¹ and vector
ŷ = P⁻¹ x̂ are available as properties.  Inverses are Cholesky-based and the result is
symmetrised.

:class:`StateDependentNoiseKF` — eq 25 (and eq 38 for the measurement).  The model (eqs 20-21)
with the noise terms read as independent zero-mean white sequences::

    x_{k+1} = F x_k + δ w_k + δ_x a_k + Σ_j δ̄_x^(j) x_k b_k^(j)
    y_k     = H x_k + v_k   + δ_z c_k + Σ_j δ̄_z^(j) x_k d_k^(j)

(w, a, c vectors, b^(j), d^(j) scalars, all unit variance, mutually independent) is a linear
system with *multiplicative* (state-dependent) noise.  Conditioned on x ~ N(x̂, P) the process
noise has covariance E[(δ̄ x b)(δ̄ x b)ᵀ] = δ̄ (P + x̂ x̂ᵀ) δ̄ᵀ, hence eq 25::

    Q_eff = δ δᵀ + δ_x δ_xᵀ + Σ_j δ̄_x^(j) (P + x̂ x̂ᵀ) δ̄_x^(j)ᵀ     (with P, x̂ the posterior)
    R_eff = R + δ_z δ_zᵀ + Σ_j δ̄_z^(j) (P̄ + x̄ x̄ᵀ) δ̄_z^(j)ᵀ      (with P̄, x̄ the prior)

and the filter is a KF with these covariances.  Eq 38 evaluates R_eff at the *posterior*, which
is circular; the prior is used here.  This is the linear-MMSE filter for multiplicative noise
when the conditional second moment is used (cf. De Koning 1984, "Optimal estimation of linear
discrete-time systems with stochastic parameters", Automatica 20, which uses the unconditional
one).  The state-dependent term inflates the noise where |x| is large, so the filter trusts its
model less there.  With all δ̄ = 0 it is the KF with Q + δδᵀ + δ_xδ_xᵀ and R + δ_zδ_zᵀ.

What could not be reproduced: KFUEA's "improved update" (eqs 31-36), its covariance constraint
(eqs 37-41) and the role of J; see ``docs/langevin.md``.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np
from scipy import linalg

from .kf import KF, LinearGaussianBase, joseph

__all__ = ["InformationKF", "StateDependentNoiseKF", "rls_solution"]


def _spd_inv(A: np.ndarray) -> np.ndarray:
    """Inverse of a symmetric positive-definite matrix via Cholesky (symmetrised)."""
    c = linalg.cho_factor(A, lower=True, check_finite=False)
    Ai = linalg.cho_solve(c, np.eye(A.shape[0]), check_finite=False)
    return 0.5 * (Ai + Ai.T)


def rls_solution(K: np.ndarray, T: np.ndarray, M: np.ndarray, e: np.ndarray) -> np.ndarray:
    """Eq 11: argmin_w wᵀKw + (Tw − e)ᵀM(Tw − e) = (K + TᵀMT)⁻¹ TᵀM e (K, M SPD)."""
    A = K + T.T @ M @ T
    return linalg.cho_solve(linalg.cho_factor(A, lower=True), T.T @ M @ e)


class InformationKF(LinearGaussianBase):
    """KF whose update is the information (RLS) form of eqs 10-14 (see the module docstring).

    Same interface as :class:`estimators.kf.KF`: ``predict()``, ``update(z) -> bool``, ``x``,
    ``P``, ``y``, ``S``, ``K``, ``nis``; ``update(None)`` or a non-finite fix changes nothing.
    """

    def _on_model_change(self) -> None:
        if hasattr(self, "_R") and hasattr(self, "_H"):
            self._Ri = _spd_inv(self._R)
            self._HtRi = self._HT @ self._Ri
            self._info_gain = self._HtRi @ self._H

    @property
    def info_matrix(self) -> np.ndarray:
        """Y = P⁻¹."""
        return _spd_inv(self.P)

    @property
    def info_vector(self) -> np.ndarray:
        """ŷ = P⁻¹ x̂."""
        return self.info_matrix @ self.x

    def update(self, z) -> bool:
        """Information-form update with fix ``z``; ``False`` (no change) if there is none."""
        if z is None:
            return False
        z = np.asarray(z, dtype=float).reshape(-1)
        if not np.all(np.isfinite(z)):
            return False
        Pbar, xbar = self.P, self.x
        Ybar = _spd_inv(Pbar)
        P = _spd_inv(Ybar + self._info_gain)  # eq 14
        K = P @ self._HtRi  # eq 13
        y = z - self._H @ xbar
        S = self._H @ Pbar @ self._HT + self._R
        nis = float(y @ np.linalg.solve(S, y))
        if not math.isfinite(nis):
            return False
        self.x = xbar + K @ y  # eq 12
        self.P = P
        self.y, self.S, self.K, self.nis = y, S, K, nis
        return True


def _as_list(mats, n_cols: int, name: str) -> list[np.ndarray]:
    if mats is None:
        return []
    try:
        arr = np.asarray(mats, dtype=float)
    except ValueError:  # ragged: a sequence of differently shaped matrices
        arr = None
    if arr is not None and arr.ndim == 2:
        mats = [arr]  # one matrix (also a nested list such as [[c]])
    out = []
    for M in mats:
        M = np.asarray(M, dtype=float)
        if M.ndim != 2 or M.shape[1] != n_cols:
            raise ValueError(f"{name}: each matrix must have {n_cols} columns, got {M.shape}")
        out.append(M)
    return out


class StateDependentNoiseKF(KF):
    """KF for linear systems with additive + state-dependent (multiplicative) noise, eq 25.

    Parameters
    ----------
    F, H, x0, P0 : as :class:`estimators.kf.KF`.
    Q, R : the additive covariances (δ δᵀ and w wᵀ of the paper).
    D, E : extra additive noise gains δ_x (n×p) and δ_z (m×q) (optional; covariance DDᵀ, EEᵀ).
    Dbar : one n×n matrix or a sequence of them (δ̄_x^(j)); Ebar : m×n matrices (δ̄_z^(j)).
        A 2-D array-like is one matrix, a 3-D one a stack.

    ``Q_eff`` and ``R_eff`` (attributes) are the covariances used by the last predict / update.
    """

    def __init__(self, F, H, Q, R, *, D=None, E=None, Dbar: Sequence | np.ndarray | None = None,
                 Ebar: Sequence | np.ndarray | None = None, x0=None, P0=None) -> None:
        super().__init__(F, H, Q, R, x0=x0, P0=P0)
        self.D = None if D is None else np.asarray(D, dtype=float).reshape(self.n, -1)
        self.E = None if E is None else np.asarray(E, dtype=float).reshape(self.m, -1)
        self.Dbar = _as_list(Dbar, self.n, "Dbar")
        self.Ebar = _as_list(Ebar, self.n, "Ebar")
        for M in self.Dbar:
            if M.shape[0] != self.n:
                raise ValueError(f"Dbar matrices must be {self.n}×{self.n}")
        for M in self.Ebar:
            if M.shape[0] != self.m:
                raise ValueError(f"Ebar matrices must be {self.m}×{self.n}")
        self.Q_eff = self.Q.copy()
        self.R_eff = self.R.copy()

    def process_noise(self, x: np.ndarray, P: np.ndarray) -> np.ndarray:
        """Eq 25: Q + δ_xδ_xᵀ + Σ δ̄ (P + x xᵀ) δ̄ᵀ at the given moments."""
        Qe = self.Q.copy()
        if self.D is not None:
            Qe += self.D @ self.D.T
        if self.Dbar:
            M2 = P + np.outer(x, x)
            for Db in self.Dbar:
                Qe += Db @ M2 @ Db.T
        return Qe

    def measurement_noise(self, x: np.ndarray, P: np.ndarray) -> np.ndarray:
        """R + δ_zδ_zᵀ + Σ δ̄_z (P + x xᵀ) δ̄_zᵀ at the given (prior) moments."""
        Re = self.R.copy()
        if self.E is not None:
            Re += self.E @ self.E.T
        if self.Ebar:
            M2 = P + np.outer(x, x)
            for Eb in self.Ebar:
                Re += Eb @ M2 @ Eb.T
        return Re

    def predict(self) -> None:
        """x̄ = F x̂, P̄ = F P Fᵀ + Q_eff(x̂, P)."""
        self.Q_eff = self.process_noise(self.x, self.P)
        F = self.F
        self.x = F @ self.x
        self.P = F @ self.P @ F.T + self.Q_eff

    def update(self, z) -> bool:
        """KF update with R_eff(x̄, P̄) (Joseph form)."""
        if z is None:
            return False
        zf = np.asarray(z, dtype=float).reshape(-1)
        if not np.all(np.isfinite(zf)):
            return False
        Re = self.measurement_noise(self.x, self.P)
        self.R_eff = Re
        H, P, x = self.H, self.P, self.x
        S = H @ P @ H.T + Re
        Si = np.linalg.inv(S)
        y = zf - H @ x
        nis = float(y @ Si @ y)
        if not math.isfinite(nis):
            return False
        K = P @ H.T @ Si
        self.x = x + K @ y
        self.P = joseph(P, K, H, Re)
        self.y, self.S, self.K, self.nis = y, S, K, nis
        return True
