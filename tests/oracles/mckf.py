"""Reference MCKF (Chen, Liu, Zhao, Principe 2017) in vectorised numpy, independent of the
product's row functions; the same options (σ scalar or per row, ε, cap, floor, recovery
None/"kf"/"inflate", adaptive σ).  See ``estimators.mckf`` for the formulas."""

from __future__ import annotations

import math

import numpy as np
from scipy.special import gammaincinv

REL_PIVOT = 1e-8  # the documented pivot rule: d ≤ 1e-8 · P̄_jj goes to the jittered factor


def safe_cholesky(P: np.ndarray) -> np.ndarray:
    """LAPACK Cholesky; if it fails, symmetrise + jitter 1e-12·max|diag| growing ×10, then an
    eigenvalue floor."""
    try:
        return np.linalg.cholesky(P)
    except np.linalg.LinAlgError:
        Ps = 0.5 * (P + P.T)
        scale = max(float(np.max(np.abs(np.diag(Ps)))), 1e-300)
        jitter = 1e-12 * scale
        for _ in range(20):
            try:
                return np.linalg.cholesky(Ps + jitter * np.eye(P.shape[0]))
            except np.linalg.LinAlgError:
                jitter *= 10.0
        w, V = np.linalg.eigh(Ps)
        return np.linalg.cholesky((V * np.maximum(w, 1e-12 * scale)) @ V.T)


def prior_factor(P: np.ndarray) -> np.ndarray:
    """B_p: plain Cholesky when every pivot passes d > REL_PIVOT · P_jj, else safe_cholesky."""
    try:
        L = np.linalg.cholesky(P)
    except np.linalg.LinAlgError:
        return safe_cholesky(P)
    if np.all(np.diag(L) ** 2 > REL_PIVOT * np.diag(P)):
        return L
    return safe_cholesky(P)


class OracleMCKF:
    """predict() / update(z) like ``estimators.MCKF``; attributes x, P, y, S, K, nis, n_iter,
    weights, weights_x, rejected, n_rejected, recovered, sigma_k; R settable."""

    def __init__(self, F, H, Q, R, x0, P0, sigma=2.0, eps=1e-6, max_iter=10,
                 kernel_floor=1e-12, adaptive_sigma=False, adapt_lambda=0.98, adapt_clip=3.0,
                 recovery="kf", lockout_n=10, reject_weight=0.05, inflate=4.0):
        self.F, self.H, self.Q = (np.array(a, dtype=float) for a in (F, H, Q))
        self.R = np.array(R, dtype=float)
        self.n, self.m = self.H.shape[1], self.H.shape[0]
        self.x, self.P = np.array(x0, dtype=float), np.array(P0, dtype=float)
        s = np.atleast_1d(np.asarray(sigma, dtype=float))
        self.sigma = np.full(self.n + self.m, s[0]) if s.size == 1 else s
        self.sigma_k = self.sigma.copy()
        self.eps, self.max_iter, self.floor = eps, max_iter, kernel_floor
        self.adaptive, self.lam, self.clip = adaptive_sigma, adapt_lambda, adapt_clip
        self.recovery, self.lockout_n, self.reject_weight = recovery, lockout_n, reject_weight
        self.inflate = inflate
        self.jmax = max(1, int(12.0 / math.log10(inflate))) if inflate > 1.0 else 1
        self.gate = 2.0 * float(gammaincinv(0.5 * self.m, 0.999))
        self.scale2 = 1.0
        self.n_rejected, self.n_iter, self.rejected, self.recovered = 0, 0, False, False
        self.weights, self.weights_x = np.ones(self.m), np.ones(self.n)
        self.nis = math.nan

    def predict(self) -> None:
        self.x = self.F @ self.x
        self.P = self.F @ self.P @ self.F.T + self.Q

    def update(self, z) -> bool:
        if z is None:
            return False
        z = np.asarray(z, dtype=float)
        xb, Pb, H, R = self.x, self.P, self.H, self.R
        nu = z - H @ xb
        PHT = Pb @ H.T
        S = H @ PHT + R
        Si = np.linalg.inv(S)
        nis = float(nu @ Si @ nu)
        if not math.isfinite(nis):
            return False
        sig = self.sigma
        if self.adaptive:
            lim = self.clip**2 * max(self.scale2, 1.0)
            self.scale2 = self.lam * self.scale2 + (1 - self.lam) * min(nis / self.m, lim)
            sig = self.sigma * max(1.0, math.sqrt(self.scale2))
            self.sigma_k = sig
        x_new, K, Cy = self._fixed_point(xb, Pb, nu, sig)
        rejected = float(np.min(Cy)) < self.reject_weight
        self.recovered = False
        if rejected:
            self.n_rejected += 1
            if self.n_rejected >= self.lockout_n:
                if self.recovery == "kf":
                    K = PHT @ Si
                    x_new = xb + K @ nu
                    self.n_rejected, self.recovered = 0, True
                elif self.recovery == "inflate":
                    j = min(self.n_rejected - self.lockout_n + 1, self.jmax)
                    alpha = self.inflate**j
                    Sai = np.linalg.inv(H @ (alpha * PHT) + R)
                    if float(nu @ Sai @ nu) <= self.gate:
                        Pb = alpha * Pb
                        K = alpha * PHT @ Sai
                        x_new = xb + K @ nu
                        self.n_rejected, self.recovered = 0, True
        else:
            self.n_rejected = 0
        self.rejected = rejected
        IKH = np.eye(self.n) - K @ H
        self.x, self.P = x_new, IKH @ Pb @ IKH.T + K @ R @ K.T
        self.y, self.S, self.K, self.nis = nu, S, K, nis
        return True

    def _fixed_point(self, xb, Pb, nu, sig):
        """Step 4 in whitened coordinates (matrix-inversion-lemma gain, see estimators.mckf)."""
        n = self.n
        c = -1.0 / (2.0 * sig * sig)
        kx, ky = c[:n], 0.5 * c[n:]
        Bp = prior_factor(Pb)
        Brinv = np.linalg.inv(np.linalg.cholesky(self.R))
        nu_w = Brinv @ nu
        A = Brinv @ self.H @ Bp
        Im = np.eye(self.m)
        inv_cx = np.ones(n)
        s = np.exp(nu_w * nu_w * ky)
        x_prev, it = xb, 0
        while True:
            it += 1
            As = A * s[:, None]
            G = As * inv_cx
            Mi = np.linalg.inv(G @ As.T + Im)
            u = ((Mi @ (s * nu_w)) * s) @ A * inv_cx
            x_new = xb + Bp @ u
            if it >= self.max_iter:
                break
            dx = x_new - x_prev
            nrm2 = float(x_prev @ x_prev)
            if float(dx @ dx) <= self.eps**2 * max(nrm2, 1.0):
                break
            x_prev = x_new
            ey = nu_w - A @ u
            inv_cx = 1.0 / np.maximum(np.exp(u * u * kx), self.floor)
            s = np.exp(ey * ey * ky)
        K = Bp @ (G.T @ (Mi * s)) @ Brinv
        self.n_iter = it
        self.weights = s * s
        self.weights_x = 1.0 / inv_cx
        return x_new, K, self.weights
