"""Maximum correntropy Kalman filter (Chen, Liu, Zhao, Principe, Automatica 80, 2017).

Algorithm 2 of Candan & Li is garbled; this is the original MCKF.

1. Predict as the KF: x̄ = F x̂, P̄ = F P Fᵀ + Q.
2. Lower Cholesky factors P̄ = B_p B_pᵀ, R = B_r B_rᵀ, B = blkdiag(B_p, B_r).
3. Whitened regression D = W x + e with D = B⁻¹[x̄; y], W = B⁻¹[I; H].
4. Fixed point from x̂⁽⁰⁾ = x̄: e = D − W x̂⁽ᵗ⁻¹⁾, G(e) = exp(−e²/(2σ²)) per element,
   C_x = diag(G(e_1..e_n)), C_y = diag(G(e_n+1..e_n+m)), P̃ = B_p C_x⁻¹ B_pᵀ, R̃ = B_r C_y⁻¹ B_rᵀ,
   K̃ = P̃ Hᵀ (H P̃ Hᵀ + R̃)⁻¹, x̂⁽ᵗ⁾ = x̄ + K̃ (y − H x̄)   (innovation against the prior).
   Stop when ‖x̂⁽ᵗ⁾ − x̂⁽ᵗ⁻¹⁾‖ / max(‖x̂⁽ᵗ⁻¹⁾‖, 1) ≤ ε or after ``max_iter`` iterations.
5. P = (I − K̃ H) P̄ (I − K̃ H)ᵀ + K̃ R K̃ᵀ with the ORIGINAL P̄ and R.

Implementation (algebraically identical, numerically guarded)
-------------------------------------------------------------
With u = B_p⁻¹(x̂ − x̄) (whitened correction), ν = y − H x̄, ν_w = B_r⁻¹ ν, A = B_r⁻¹ H B_p the
residuals are e_x = −u and e_y = ν_w − A u.  Writing s = √diag(C_y) and c = diag(C_x), the
gain of step 4 is, by the matrix-inversion lemma,

    K̃ = B_p C_x⁻¹ Aᵀ S_y (I + S_y A C_x⁻¹ Aᵀ S_y)⁻¹ S_y B_r⁻¹,     S_y = diag(s),

which never forms C_y⁻¹: a measurement channel whose kernel underflows to 0 (|e| ≳ 38.6 σ)
simply drops out (K̃ column 0) instead of producing inf/NaN.  The state weights are floored at
``kernel_floor`` (default 1e-12) so C_x⁻¹ stays finite.  The m×m matrix inverted is I + PSD.

Speed: for m ≤ 3 and n ≤ 12 the whole of step 2-4 (Cholesky of P̄, whitening, fixed point and
K̃) runs in an unrolled, generated straight-line kernel on Python floats
(:mod:`estimators.mckf_kernel`): numpy's ~0.5 µs per call dominated the tiny matrices (~25
calls per iteration).  Same arithmetic, results equal to the vectorised path to ~1e-12 and the
same iteration counts (tests); the vectorised path (``impl = "numpy"``) runs for larger sizes,
for ``kernel_floor = 0`` and whenever the kernel's Cholesky pivot test fails (P̄
ill-conditioned: LAPACK and :func:`safe_cholesky` decide).  Measured by
``ag_uav.bench_estimators`` (one run each on a loaded 2-core machine): paper model 97 → 29 µs
per predict+update (filterpy's KF: 28-29); 6-state in-loop model 191 → 54 µs per update.

Options
-------
- ``sigma``: scalar, or a vector of length n+m (one kernel per row of the whitened regression:
  the multi-kernel MCKF of Li, Shi, Zou, Shi 2021).  σ is dimensionless (residuals are
  whitened); ``np.inf`` entries give weight 1 (plain least squares on that row).
- ``adaptive_sigma``: σ_k = σ · max(1, √ŝ_k), where ŝ_k is an exponentially weighted mean
  (factor ``adapt_lambda``) of the per-channel normalised innovation power NIS_k/m, each sample
  clipped at ``adapt_clip²·max(ŝ_{k−1}, 1)`` so that isolated outliers cannot widen the kernel.
  When the innovations are persistently larger than the model says (coloured noise,
  manoeuvres, mis-set R) the kernel widens instead of rejecting good fixes; with a consistent
  model ŝ ≈ 1 and σ stays at its nominal value.
- Lock-out recovery (``recovery``): a fix counts as *rejected* when any channel's weight C_y
  is below ``reject_weight`` (default 0.05, i.e. |e| > 4.9 σ).  After ``lockout_n``
  consecutive rejections (default 10, 0.5 s at 20 Hz) the filter assumes that it, not the
  sensor, is wrong (outage, sharp turn):
  ``"kf"`` (default) fuses that fix with a plain KF update (a reset towards GPS, as navigation
  filters do after persistent innovation-gate failures) and restarts the count;
  ``"inflate"`` tries, on the j-th rejected fix from the ``lockout_n``-th on, the inflated prior
  α P̄ with α = ``inflate``^j (capped at ~1e12): if the fix is consistent with it (KF NIS
  νᵀ(H α P̄ Hᵀ + R)⁻¹ν ≤ ``inflate_gate``, the χ²_m 99.9 % quantile) it is fused by a KF update
  on α P̄, which is also the prior of the Joseph update (a covariance reset), and the count
  restarts; otherwise the MCKF result stands.  (The first version multiplied P̄ itself by
  ``inflate``^j before the fixed point: the inflation compounded through P to ~1e190 — the
  fixed point started at x̄ cannot accept a far fix whatever P̄, as its first weight
  exp(−ν_w²/(4σ²)) does not depend on P̄ — and the result then hung on rounding.)
  ``None`` disables recovery.
- ``eps``, ``max_iter``: stop rule and iteration cap (the relative rule misbehaves near the
  origin and in large coordinates, so the cap always applies).

Diagnostics after an update: ``n_iter`` (fixed-point iterations), ``weights`` (diag C_y),
``weights_x`` (diag C_x), ``sigma_k`` (kernel widths used), ``rejected`` (bool),
``n_rejected`` (consecutive rejections), ``recovered`` (recovery used on this fix), and
``y``, ``S`` (= H P̄ Hᵀ + R), ``K`` (= K̃), ``nis`` (KF NIS of the innovation).
"""

from __future__ import annotations

import math

import numpy as np

from .kf import LinearGaussianBase, inv_small
from .mckf_kernel import REL_PIVOT, kernel

__all__ = ["MCKF", "safe_cholesky"]

_dot = np.dot
_exp = np.exp

#: largest n (state size) run by the unrolled kernel of :mod:`estimators.mckf_kernel` (m ≤ 3)
KERNEL_MAX_N = 12


def safe_cholesky(P: np.ndarray) -> np.ndarray:
    """Lower Cholesky factor; symmetrises and adds growing jitter if P is not numerically PD."""
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


class MCKF(LinearGaussianBase):
    """Maximum correntropy Kalman filter; see the module docstring for every option.

    Parameters
    ----------
    F, H, Q, R, x0, P0 : as :class:`estimators.KF`.
    sigma : kernel bandwidth, scalar or vector of length n+m (multi-kernel).
    eps, max_iter : fixed-point stop rule and cap.
    kernel_floor : lower bound of the state weights C_x.
    adaptive_sigma, adapt_lambda, adapt_clip : adaptive bandwidth rule.
    recovery, lockout_n, reject_weight, inflate : lock-out recovery rule.
    """

    def __init__(
        self,
        F,
        H,
        Q,
        R,
        x0=None,
        P0=None,
        sigma: float | np.ndarray = 2.0,
        eps: float = 1e-6,
        max_iter: int = 10,
        kernel_floor: float = 1e-12,
        adaptive_sigma: bool = False,
        adapt_lambda: float = 0.98,
        adapt_clip: float = 3.0,
        recovery: str | None = "kf",
        lockout_n: int = 10,
        reject_weight: float = 0.05,
        inflate: float = 4.0,
    ) -> None:
        super().__init__(F, H, Q, R, x0, P0)
        if recovery not in (None, "kf", "inflate"):
            raise ValueError(f"recovery must be None, 'kf' or 'inflate', got {recovery!r}")
        if max_iter < 1:
            raise ValueError("max_iter must be >= 1")
        self.sigma = sigma
        self.eps = float(eps)
        self.max_iter = int(max_iter)
        self.kernel_floor = float(kernel_floor)
        self.adaptive_sigma = bool(adaptive_sigma)
        self.adapt_lambda = float(adapt_lambda)
        self.adapt_clip = float(adapt_clip)
        self.recovery = recovery
        self.lockout_n = int(lockout_n)
        self.reject_weight = float(reject_weight)
        self.inflate = float(inflate)
        if recovery == "inflate" and not self.inflate > 1.0:
            raise ValueError("inflate must be > 1")
        # α = inflate^j is capped at ~1e12; gate = χ²_m 99.9 % quantile
        self._inflate_jmax = max(1, int(12.0 / math.log10(self.inflate))) if recovery else 1
        from scipy.special import gammaincinv

        self.inflate_gate = 2.0 * float(gammaincinv(0.5 * self.m, 0.999))
        self.scale2 = 1.0  # ŝ_k of the adaptive rule
        self.n_iter = 0
        self.weights = np.ones(self.m)
        self.weights_x = np.ones(self.n)
        self.sigma_k = self._sigma.copy()
        self.rejected = False
        self.n_rejected = 0
        self.recovered = False
        self._Im = np.eye(self.m)
        self._ones_n = np.ones(self.n)
        small = self.m <= 3 and self.n <= KERNEL_MAX_N
        self._kernel = kernel(self.n, self.m) if small else None
        self.impl = "auto"  # "numpy": always the vectorised fixed point (tests, comparisons)

    @property
    def sigma(self) -> np.ndarray:
        return self._sigma

    @sigma.setter
    def sigma(self, value) -> None:
        s = np.atleast_1d(np.asarray(value, dtype=float))
        if s.size == 1:
            s = np.full(self.n + self.m, float(s[0]))
        if s.shape != (self.n + self.m,) or np.any(s <= 0):
            n_m = self.n + self.m
            raise ValueError(f"sigma must be a positive scalar or have length n+m={n_m}")
        self._sigma = s
        self._set_kernel(s)

    def _set_kernel(self, s: np.ndarray) -> None:
        c = -1.0 / (2.0 * s * s)  # inf sigma -> 0 -> weight exactly 1
        self._ncx, self._ncy_half = c[: self.n].copy(), 0.5 * c[self.n :]
        self._ncx_l, self._ncyh_l = self._ncx.tolist(), self._ncy_half.tolist()

    def _on_model_change(self) -> None:
        if hasattr(self, "_R") and hasattr(self, "_H"):
            Br = np.linalg.cholesky(self._R)
            self._Brinv = np.linalg.inv(Br)
            self._BrinvH = _dot(self._Brinv, self._H)
            self._Gf = self._BrinvH.ravel().tolist()
            self._Rf = self._Brinv.ravel().tolist()

    def update(self, z) -> bool:
        """Fuse fix ``z``; returns ``False`` (nothing changes) for "no fix": ``None``, NaN/inf in
        ``z``, or a fix so large that its NIS overflows."""
        if z is None:
            return False
        z = np.asarray(z, dtype=float).reshape(-1)
        xb, Pb, H = self.x, self.P, self._H
        nu = z - H.dot(xb)
        PHT = Pb.dot(self._HT)
        S = H.dot(PHT) + self._R
        Si = inv_small(S)
        nis = float(nu.dot(Si.dot(nu)))
        if not math.isfinite(nis):
            return False

        if self.adaptive_sigma:
            lim = self.adapt_clip**2 * max(self.scale2, 1.0)
            lam = self.adapt_lambda
            self.scale2 = lam * self.scale2 + (1.0 - lam) * min(nis / self.m, lim)
            self.sigma_k = self._sigma * max(1.0, math.sqrt(self.scale2))
            self._set_kernel(self.sigma_k)

        x_new, K, Cy = self._fixed_point(xb, Pb, nu)
        rejected = min(Cy.tolist()) < self.reject_weight
        self.recovered = False
        if rejected:
            self.n_rejected += 1
            if self.n_rejected >= self.lockout_n:
                if self.recovery == "kf":
                    K = PHT.dot(Si)
                    x_new = xb + K.dot(nu)
                    self.n_rejected = 0
                    self.recovered = True
                elif self.recovery == "inflate":
                    j = min(self.n_rejected - self.lockout_n + 1, self._inflate_jmax)
                    alpha = self.inflate**j
                    PaHT = alpha * PHT
                    Sai = inv_small(H.dot(PaHT) + self._R)
                    if float(nu.dot(Sai.dot(nu))) <= self.inflate_gate:
                        Pb = alpha * Pb  # covariance reset: the inflated prior is kept
                        K = PaHT.dot(Sai)
                        x_new = xb + K.dot(nu)
                        self.n_rejected = 0
                        self.recovered = True
        else:
            self.n_rejected = 0
        self.rejected = rejected
        self.x = x_new
        self.P = self._joseph(Pb, K)  # original P̄ (inflated only by recovery) and R
        self.y, self.S, self.K, self.nis = nu, S, K, nis
        if self.adaptive_sigma:
            self._set_kernel(self._sigma)
        return True

    def _fixed_point(self, xb: np.ndarray, Pb: np.ndarray, nu: np.ndarray):
        """Run step 4 in whitened coordinates; returns (x̂, K̃, diag C_y).

        For m ≤ 3 and n ≤ ``KERNEL_MAX_N`` (and ``impl != "numpy"``) the unrolled kernel of
        :mod:`estimators.mckf_kernel` runs the same arithmetic on Python floats; if its
        Cholesky pivot test fails (P̄ ill-conditioned or not PD), or otherwise, the vectorised
        :meth:`_fixed_point_numpy` does (with :func:`safe_cholesky`)."""
        kern = self._kernel
        if kern is not None and self.impl != "numpy" and self.kernel_floor > 0.0:
            r = kern(Pb.ravel().tolist(), xb.tolist(), nu.tolist(), self._Gf, self._Rf,
                     self._ncx_l, self._ncyh_l, self.kernel_floor, self.eps * self.eps,
                     self.max_iter, REL_PIVOT)
            if r is not None:
                x, K, w, cx, self.n_iter = r
                self.weights = np.array(w)
                self.weights_x = self._ones_n if cx is None else np.array(cx)
                return np.array(x), np.array(K).reshape(self.n, self.m), self.weights
        return self._fixed_point_numpy(xb, Pb, nu)

    def _fixed_point_numpy(self, xb: np.ndarray, Pb: np.ndarray, nu: np.ndarray):
        """Step 4 vectorised (any m, n)."""
        Bp = safe_cholesky(Pb)
        Brinv = self._Brinv
        nu_w = _dot(Brinv, nu)
        A = _dot(self._BrinvH, Bp)
        ncx, ncy_half, floor = self._ncx, self._ncy_half, self.kernel_floor
        Im, eps2, max_iter = self._Im, self.eps * self.eps, self.max_iter
        # iteration 1: x̂⁽⁰⁾ = x̄ so e_x = 0, C_x = I exactly and e_y = ν_w
        s = _exp(nu_w * nu_w * ncy_half)  # √C_y
        G = As = A * s[:, None]  # S_y A C_x⁻¹ with C_x = I
        Mi = inv_small(_dot(As, As.T) + Im)
        sb = _dot(Mi, s * nu_w) * s
        u = _dot(sb, A)
        inv_cx = None
        x_prev = xb
        x_new = xb + _dot(Bp, u)
        it = 1
        while it < max_iter:
            dx = x_new - x_prev
            nrm2 = float(_dot(x_prev, x_prev))
            if float(_dot(dx, dx)) <= eps2 * (nrm2 if nrm2 > 1.0 else 1.0):
                break
            it += 1
            x_prev = x_new
            ey = nu_w - _dot(A, u)
            inv_cx = 1.0 / np.maximum(_exp(u * u * ncx), floor)
            s = _exp(ey * ey * ncy_half)
            As = A * s[:, None]
            G = As * inv_cx
            Mi = inv_small(_dot(G, As.T) + Im)
            sb = _dot(Mi, s * nu_w) * s
            u = _dot(sb, A) * inv_cx
            x_new = xb + _dot(Bp, u)
        # K̃ = B_p C_x⁻¹ Aᵀ S_y M⁻¹ S_y B_r⁻¹ = B_p Gᵀ M⁻¹ S_y B_r⁻¹
        K = _dot(_dot(Bp, _dot(G.T, Mi * s)), Brinv)
        self.n_iter = it
        self.weights = s * s
        self.weights_x = self._ones_n if inv_cx is None else 1.0 / inv_cx
        return x_new, K, self.weights
