"""The bank's update laws as compiled row functions, for :mod:`estimators.ins`.

The INS fuses a GNSS fix through the same KF (Joseph), MCKF (Chen et al. 2017 fixed point with
the lock-out recovery) and PCA-block laws as the position filters of the bank; it must not
write them a second time.  Those laws are being moved to public row functions
(``estimators.kf.kf_update_row``, ``estimators.mckf.mckf_update_row``,
``estimators.pca.pca_row``); until that lands, the same arithmetic lives in the private batch
kernels of :mod:`estimators.batched`.  This shim binds whichever exists to three signatures:

``kf_fuse(dx, P, R, H, nu) -> NIS``
    The KF update of the error state ``dx`` (zero on entry) with the innovation ``nu`` as its
    "measurement" (ν − H·0 = ν): ``dx = K ν``, ``P = (I − K H) P (I − K H)ᵀ + K R Kᵀ``.
``mckf_fuse(dx, P, R, H, nu, kx, ky, fpar, ipar, ist, wy) -> NIS``
    The MCKF update (whitened fixed point from x̂⁽⁰⁾ = 0, recovery rule, Joseph with the original
    P̄ and R); parameters as :class:`estimators.batched.BatchMCKF` rows: ``kx``/``ky`` the
    kernel coefficients −1/(2σ²) / −1/(4σ²), ``fpar`` = (kernel_floor, ε², reject_weight,
    inflate, inflate_gate), ``ipar`` = (max_iter, lockout_n, recovery, inflate_jmax), ``ist`` =
    (n_rejected, n_iter, rejected, recovered) updated, ``wy`` ← diag C_y.
``pca_row(buf, pcs, z, Nw, L, r, mode, zf)``
    The PCA block (Candan & Li §III.C) on one window.

A non-finite NIS means "not fused" (``dx``, ``P`` untouched).
"""

from __future__ import annotations

import numpy as np

from ._jit import njit

__all__ = ["kf_fuse", "mckf_fuse", "pca_row", "SOURCE"]

try:  # the restructured bank: one public row function per law
    from .kf import kf_update_row as _kf_row
    from .kf import kf_work as _kf_work
    from .mckf import mckf_update_row as _mckf_row
    from .mckf import mckf_work as _mckf_work
    from .pca import pca_row

    SOURCE = "row functions of estimators.kf / mckf / pca"

    @njit
    def kf_fuse(dx, P, R, H, nu):
        n, m = dx.shape[0], nu.shape[0]
        a0, a1, a2, a3, a4, a5, a6, a7, a8 = _kf_work(n, m)
        return _kf_row(dx, P, R, H, nu, a0, a1, a2, a3, a4, a5, a6, a7, a8)

    @njit
    def mckf_fuse(dx, P, R, H, nu, kx, ky, fpar, ipar, ist, wy):
        w = _mckf_work(dx.shape[0], nu.shape[0])
        return _mckf_row(dx, P, R, H, nu, kx, ky, fpar, ipar, ist, wy, w)

except ImportError:  # the bank before the restructure: its batch kernels, one row at a time
    from .batched import _gain_update, _innovation, _joseph, _kf_work, _mckf_update_batch
    from .batched import _pca_row as pca_row
    from .mckf_kernel import REL_PIVOT

    SOURCE = "batch kernels of estimators.batched"

    @njit
    def kf_fuse(dx, P, R, H, nu):
        n, m = dx.shape[0], nu.shape[0]
        a0, a1, a2, a3, a4, a5, a6, a7, a8 = _kf_work(n, m)
        v = _innovation(dx, P, R, H, nu, a0, a1, a2, a3)
        if not np.isfinite(v):
            return v
        _gain_update(dx, a1, a3, a0, a4, a5)
        for k in range(n):
            dx[k] = a5[k]
        _joseph(P, a4, H, R, P, a6, a7, a8)
        return v

    @njit
    def mckf_fuse(dx, P, R, H, nu, kx, ky, fpar, ipar, ist, wy):
        n, m = dx.shape[0], nu.shape[0]
        x2 = dx.copy().reshape((1, n))
        P3 = P.copy().reshape((1, n, n))
        R3 = R.copy().reshape((1, m, m))
        z2 = nu.copy().reshape((1, m))
        nis = np.empty(1)
        y = np.empty((1, m))
        mask = np.ones(1, dtype=np.bool_)
        ok = np.zeros(1, dtype=np.bool_)
        ist2 = ist.copy().reshape((1, 4))
        wy2 = np.empty((1, m))
        _mckf_update_batch(x2, P3, R3, nis, y, H, z2, mask, ok, kx.copy().reshape((1, n)),
                           ky.copy().reshape((1, m)), fpar.copy().reshape((1, 5)),
                           ipar.copy().reshape((1, 4)), ist2, wy2, REL_PIVOT)
        if not ok[0]:
            return np.inf
        for k in range(n):
            dx[k] = x2[0, k]
            for c in range(n):
                P[k, c] = P3[0, k, c]
        for k in range(4):
            ist[k] = ist2[0, k]
        for a in range(m):
            wy[a] = wy2[0, a]
        return nis[0]
