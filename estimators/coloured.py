"""Baselines for coloured (time-correlated) GPS noise, the paper's eq 2: v_k = Γ v_{k−1} + ξ.

Both classes have the KF interface (``predict()``, ``update(z) -> bool``, ``x``, ``P``, ``y``,
``S``, ``K``, ``nis``); ``None`` or non-finite fixes are "no fix".

:class:`BiasAugmentedKF` — state augmentation (Gelb 1974, §4.5)
    The GPS error is white noise (covariance ``R``) plus a first-order Gauss–Markov bias b per
    measured channel, appended to the state::

        x_a = [x; b],   F_a = blkdiag(F, Φ_b),   Q_a = blkdiag(Q, Q_b),   H_a = [H  I],
        Φ_b = diag(e^{−dt/τ}),   Q_b = diag(σ_b² (1 − e^{−2dt/τ}))   (exact discretisation)

    ``dt`` is the ``predict()`` period.  ``x``/``P`` are the base state and its block (so the
    filter is a drop-in replacement); ``x_aug``, ``P_aug`` and ``bias`` expose the rest.
    The bias and the position are separated only through their different dynamics and the
    prior σ_b, as with any GPS-only augmentation.

:class:`DifferencingKF` — measurement differencing (Bryson & Henrikson 1968)
    With z_k = y_k − Γ y_{k−1} = H̄ x_{k−1} + H w + ξ, H̄ = H F − Γ H, the filtered estimate at
    the new fix is (the spec's formulas)::

        K  = (F P H̄ᵀ + Q Hᵀ)(H̄ P H̄ᵀ + H Q Hᵀ + R_ξ)⁻¹
        x⁺ = F x + K (z − H̄ x),     P⁺ = F P Fᵀ + Q − K (H̄ P Fᵀ + H Q)

    where x, P are the estimate at the previous fix.  Because the simulator predicts at 100 Hz
    and fixes arrive at 20 Hz (or not at all during outages), F and Q above are the transition
    Φ and accumulated noise Q_acc since the previous fix (Φ ← F Φ, Q_acc ← F Q_acc Fᵀ + Q at
    every ``predict()``), and Γ is the correlation over that interval: ``gamma**g`` with g the
    number of ``update()`` calls since the last fix (``update(None)`` counts as a missed fix),
    or, if ``tau`` and ``dt`` are given, ``exp(−(#predicts)·dt/τ)``.  ``R`` is the stationary
    covariance of v (as for every other filter) and R_ξ = R − Γ R Γᵀ, unless ``R_xi`` is given
    (then used as is for a one-interval gap).  The first fix (and the first after ``reset_diff``)
    is fused by a plain KF update with R.  With Γ = 0 the filter is exactly the KF.
    ``P⁺`` is computed as ``P̄ − K S Kᵀ`` (equal to the formula above, symmetric by construction).
"""

from __future__ import annotations

import math

import numpy as np

from .kf import KF, LinearGaussianBase, as_matrix, inv_small

__all__ = ["BiasAugmentedKF", "DifferencingKF"]

_dot = np.dot


def _per_channel(value, m: int, name: str) -> np.ndarray:
    arr = np.atleast_1d(np.asarray(value, dtype=float))
    if arr.size == 1:
        arr = np.full(m, float(arr[0]))
    if arr.shape != (m,):
        raise ValueError(f"{name} needs 1 or {m} values")
    return arr


class BiasAugmentedKF:
    """KF with a Gauss–Markov GPS bias per channel as augmented states (module docstring).

    Parameters
    ----------
    F, H, Q, R : base model; R is the covariance of the WHITE part of the GPS error.
    x0, P0 : base initial state and covariance.
    tau : bias correlation time [s] (scalar or per channel); ``np.inf`` = random constant.
    sigma_b : stationary bias std [m] (scalar or per channel).
    dt : ``predict()`` period [s].
    """

    def __init__(
        self,
        F,
        H,
        Q,
        R,
        x0=None,
        P0=None,
        tau: float | np.ndarray = 60.0,
        sigma_b: float | np.ndarray = 1.0,
        dt: float = 0.01,
    ) -> None:
        F, H, Q = as_matrix(F, "F"), as_matrix(H, "H"), as_matrix(Q, "Q")
        n, m = F.shape[0], H.shape[0]
        self.n, self.m, self.dt = n, m, float(dt)
        self.tau = _per_channel(tau, m, "tau")
        self.sigma_b = _per_channel(sigma_b, m, "sigma_b")
        phi = np.exp(-self.dt / self.tau)
        self._phi = phi
        Fa = np.zeros((n + m, n + m))
        Fa[:n, :n] = F
        Fa[n:, n:] = np.diag(phi)
        Qa = np.zeros((n + m, n + m))
        Qa[:n, :n] = Q
        Qa[n:, n:] = np.diag(self.sigma_b**2 * (1.0 - phi**2))
        Ha = np.hstack([H, np.eye(m)])
        xa = np.zeros(n + m)
        if x0 is not None:
            xa[:n] = np.asarray(x0, dtype=float).reshape(n)
        Pa = np.zeros((n + m, n + m))
        Pa[:n, :n] = np.eye(n) if P0 is None else as_matrix(P0, "P0", (n, n))
        Pa[n:, n:] = np.diag(self.sigma_b**2)
        self.kf = KF(Fa, Ha, Qa, R, xa, Pa)

    def predict(self) -> None:
        self.kf.predict()

    def update(self, z) -> bool:
        return self.kf.update(z)

    # interface ---------------------------------------------------------------------------------
    @property
    def x(self) -> np.ndarray:
        return self.kf.x[: self.n]

    @x.setter
    def x(self, value) -> None:
        """(Re)start the base state at ``value``; the bias estimate returns to its prior mean 0."""
        xa = np.zeros(self.n + self.m)
        xa[: self.n] = np.asarray(value, dtype=float).reshape(self.n)
        self.kf.x = xa

    @property
    def P(self) -> np.ndarray:
        return self.kf.P[: self.n, : self.n]

    @P.setter
    def P(self, value) -> None:
        """(Re)start the base covariance at ``value``: no cross-covariance with the bias, whose
        covariance returns to its stationary prior diag(σ_b²)."""
        Pa = np.zeros((self.n + self.m, self.n + self.m))
        Pa[: self.n, : self.n] = as_matrix(value, "P", (self.n, self.n))
        Pa[self.n :, self.n :] = np.diag(self.sigma_b**2)
        self.kf.P = Pa

    @property
    def x_aug(self) -> np.ndarray:
        return self.kf.x

    @property
    def P_aug(self) -> np.ndarray:
        return self.kf.P

    @property
    def bias(self) -> np.ndarray:
        return self.kf.x[self.n :]

    @property
    def y(self) -> np.ndarray:
        return self.kf.y

    @property
    def S(self) -> np.ndarray:
        return self.kf.S

    @property
    def K(self) -> np.ndarray:
        return self.kf.K

    @property
    def nis(self) -> float:
        return self.kf.nis

    @property
    def F(self) -> np.ndarray:
        return self.kf.F[: self.n, : self.n]

    @F.setter
    def F(self, value) -> None:
        Fa = self.kf.F.copy()
        Fa[: self.n, : self.n] = value
        self.kf.F = Fa

    @property
    def Q(self) -> np.ndarray:
        return self.kf.Q[: self.n, : self.n]

    @Q.setter
    def Q(self, value) -> None:
        Qa = self.kf.Q.copy()
        Qa[: self.n, : self.n] = value
        self.kf.Q = Qa

    @property
    def H(self) -> np.ndarray:
        return self.kf.H[:, : self.n]

    @property
    def R(self) -> np.ndarray:
        return self.kf.R

    @R.setter
    def R(self, value) -> None:
        self.kf.R = value


class DifferencingKF(LinearGaussianBase):
    """Bryson–Henrikson measurement-differencing KF for AR(1) GPS noise (module docstring).

    Parameters
    ----------
    F, H, Q, R, x0, P0 : as :class:`~estimators.KF`; R is the stationary covariance of v.
    gamma : Γ per fix interval (scalar, per-channel vector or m×m matrix), or
    tau, dt : correlation time [s] and ``predict()`` period [s] (Γ = exp(−elapsed/τ)).
    R_xi : optional covariance of ξ for a one-interval gap (default R − Γ R Γᵀ).
    """

    def __init__(
        self,
        F,
        H,
        Q,
        R,
        x0=None,
        P0=None,
        gamma: float | np.ndarray | None = None,
        tau: float | np.ndarray | None = None,
        dt: float | None = None,
        R_xi=None,
    ) -> None:
        super().__init__(F, H, Q, R, x0, P0)
        if (gamma is None) == (tau is None):
            raise ValueError("give exactly one of gamma or (tau, dt)")
        if tau is not None:
            if dt is None:
                raise ValueError("tau needs dt (the predict() period)")
            self._tau = _per_channel(tau, self.m, "tau")
            self._gamma = None
        else:
            g = np.asarray(gamma, dtype=float)
            self._gamma = (
                np.diag(_per_channel(g, self.m, "gamma"))
                if g.ndim < 2
                else as_matrix(g, "gamma", (self.m, self.m))
            )
            self._tau = None
        self.dt = None if dt is None else float(dt)
        self._R_xi = None if R_xi is None else as_matrix(R_xi, "R_xi", (self.m, self.m))
        self.reset_diff()

    def reset_diff(self) -> None:
        """Forget the previous fix: the next fix is fused by a plain KF update."""
        self._y_prev: np.ndarray | None = None
        self._xa, self._Pa = self.x.copy(), self.P.copy()
        self._Phi = np.eye(self.n)
        self._Qacc = np.zeros((self.n, self.n))
        self._n_pred = 0
        self._n_upd = 0

    def predict(self) -> None:
        F, FT = self._F, self._FT
        self.x = _dot(F, self.x)
        self.P = _dot(_dot(F, self.P), FT) + self._Q
        self._Phi = _dot(F, self._Phi)
        self._Qacc = _dot(_dot(F, self._Qacc), FT) + self._Q
        self._n_pred += 1

    def _gamma_now(self) -> np.ndarray:
        if self._tau is not None:
            return np.diag(np.exp(-self._n_pred * self.dt / self._tau))
        return np.linalg.matrix_power(self._gamma, max(self._n_upd, 1))

    def update(self, z) -> bool:
        """Fuse fix ``z``; ``None``/non-finite ``z`` is a missed fix (returns ``False``)."""
        self._n_upd += 1
        if z is None:
            return False
        z = np.asarray(z, dtype=float).reshape(-1)
        if not math.isfinite(float(z.sum())):
            return False
        H, R = self._H, self._R
        if self._y_prev is None:  # first fix: plain KF update
            PHT = _dot(self.P, self._HT)
            S = _dot(H, PHT) + R
            Si = inv_small(S)
            K = _dot(PHT, Si)
            y = z - _dot(H, self.x)
            self.x = self.x + _dot(K, y)
            self.P = self._joseph(self.P, K)
        else:
            G = self._gamma_now()
            Phi, Qacc, xa, Pa = self._Phi, self._Qacc, self._xa, self._Pa
            Hb = _dot(H, Phi) - _dot(G, H)
            if self._R_xi is not None and self._n_upd == 1 and self._tau is None:
                Rxi = self._R_xi
            else:
                Rxi = R - _dot(_dot(G, R), G.T)
            PaHbT = _dot(Pa, Hb.T)
            QHT = _dot(Qacc, self._HT)
            Cxz = _dot(Phi, PaHbT) + QHT
            S = _dot(Hb, PaHbT) + _dot(H, QHT) + Rxi
            Si = inv_small(S)
            y = z - _dot(G, self._y_prev) - _dot(Hb, xa)
            K = _dot(Cxz, Si)
            Pbar = _dot(_dot(Phi, Pa), Phi.T) + Qacc
            self.x = _dot(Phi, xa) + _dot(K, y)
            self.P = Pbar - _dot(_dot(K, S), K.T)
        self.y, self.S, self.K = y, S, K
        self.nis = float(_dot(y, _dot(Si, y)))
        self._y_prev = z
        self._xa, self._Pa = self.x.copy(), self.P.copy()
        self._Phi = np.eye(self.n)
        self._Qacc = np.zeros((self.n, self.n))
        self._n_pred = 0
        self._n_upd = 0
        return True
