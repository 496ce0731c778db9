"""Reference sliding-window PCA block (Candan & Li §III.C) in numpy/LAPACK, independent of the
product's :func:`estimators.pca.pca_row`; both readings ("channels": eigenvectors of the c×c
window covariance; "hankel": SSA per channel, only the r leading eigenvectors by LAPACK
``dsyevr``, or the full ``eigh`` with ``full_eigh=True``)."""

from __future__ import annotations

import math

import numpy as np
from scipy.linalg.lapack import dsyevr


class OraclePCABlock:
    def __init__(self, c: int, window: int = 20, n_components: int | None = None,
                 mode: str = "hankel", embed: int | None = None, full_eigh: bool = False):
        self.c, self.N, self.mode, self.full_eigh = c, window, mode, full_eigh
        if mode == "hankel":
            self.L = window // 2 if embed is None else embed
            self.r = 2 if n_components is None else n_components
        else:
            self.L, self.r = 0, 1 if n_components is None else n_components
        self.window: list[np.ndarray] = []

    @property
    def ready(self) -> bool:
        return len(self.window) >= self.N

    def __call__(self, z):
        if z is None:
            return None
        z = np.asarray(z, dtype=float)
        if not np.all(np.isfinite(z)):
            return z.copy()
        self.window = (self.window + [z.copy()])[-self.N:]
        if not self.ready:
            return z.copy()
        W = np.array(self.window).T  # c × N, oldest first
        mean = W.mean(axis=1)
        Wc = W - mean[:, None]
        if self.mode == "channels":
            return self._channels(Wc, mean, z)
        return self._hankel(Wc, mean)

    def _channels(self, Wc, mean, z):
        if self.c == 2 and self.r == 1:
            (a, b), (_, e) = Wc @ Wc.T
            th = 0.5 * math.atan2(2.0 * b, a - e)
            v = np.array([math.cos(th), math.sin(th)])
            return mean + v * (v @ (z - mean))
        _, V = np.linalg.eigh(Wc @ Wc.T)
        Pm = V[:, -self.r:]
        return mean + Pm @ (Pm.T @ (z - mean))

    def _hankel(self, Wc, mean):
        L, r = self.L, self.r
        K = self.N - L + 1
        out = mean.copy()
        for ch in range(self.c):
            X = np.array([Wc[ch, i:i + K] for i in range(L)])  # L × K, X[i, j] = w[i + j]
            C = X @ X.T
            if self.full_eigh:
                Ur = np.linalg.eigh(C)[1][:, L - r:]
            else:
                Ur, info = dsyevr(C, compute_v=1, range="I", il=L - r + 1, iu=L)[1::3]
                assert info == 0
            out[ch] += Ur[L - 1] @ (Ur.T @ X[:, K - 1])
        return out
