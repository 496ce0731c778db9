"""The bank's update laws as compiled row functions, for :mod:`estimators.ins`.

The INS fuses a GNSS fix through the same KF (Joseph), MCKF (Chen et al. 2017 fixed point with
the lock-out recovery) and PCA-block laws as the position filters of the bank; it must not
write them a second time.  It binds the bank's row functions (``estimators.kf.kf_update_row``,
``estimators.mckf.mckf_update_row``, ``estimators.pca.pca_row``) to these signatures:

``kf_fuse_b(dx, P, R, H, nu, buf) -> NIS``
    The KF update of the error state ``dx`` (zero on entry) with the innovation ``nu`` as its
    "measurement" (ν − H·0 = ν): ``dx = K ν``, ``P = (I − K H) P (I − K H)ᵀ + K R Kᵀ``, on the
    caller's work: ``buf`` ≥ ``kf_work_size(n, m)`` floats, whose views are the work arrays
    (``estimators.kf.kf_work_in``).
``mckf_fuse_b(dx, P, R, H, nu, mp, st, ad, buf) -> NIS``
    The MCKF update (whitened fixed point from x̂⁽⁰⁾ = 0, recovery rule, Joseph with the original
    P̄ and R); ``mp`` = (kx, ky, fpar, ipar) and ``st`` = (ist, wy) as
    ``estimators.mckf.mckf_update_row`` (the rows of :class:`estimators.batched.BatchMCKF`):
    ``kx``/``ky`` the kernel coefficients −1/(2σ²) / −1/(4σ²), ``fpar`` = (kernel_floor, ε²,
    reject_weight, inflate, inflate_gate), ``ipar`` = (max_iter, lockout_n, recovery,
    inflate_jmax), ``ist`` = (n_rejected, n_iter, rejected, recovered) updated, ``wy`` ← diag
    C_y.  ``ad`` = (apar, sig, ast, kxa, kya): with ``apar`` = (adaptive 0/1, λ, clip)
    (``estimators.mckf.MCKF_A``) and
    adaptive = 1 the kernels come from the adaptive bandwidth rule instead
    (``estimators.mckf.mckf_adaptive_update_row``: base widths ``sig``, n + m values, state ŝ
    in ``ast[0]``, the kernels written to ``kxa`` (n), ``kya`` (m)), as :class:`estimators.MCKF`
    with ``adaptive_sigma=True``.  ``buf`` ≥ ``mckf_work_size(n, m)`` floats
    (``estimators.mckf.mckf_work_in``).
``pca_row(buf, pcs, z, Nw, L, r, mode, zf)``
    The PCA block (Candan & Li §III.C) on one window.

A non-finite NIS means "not fused" (``dx``, ``P`` untouched).
"""

from __future__ import annotations

import math

from ._jit import njit
from .kf import kf_update_row as _kf_row
from .kf import kf_work_in, kf_work_size
from .mckf import AP, adapt_kernels_row, mckf_work_in, mckf_work_size
from .mckf import mckf_update_row as _mckf_row
from .pca import pca_row

__all__ = ["kf_fuse_b", "kf_work_size", "mckf_fuse_b", "mckf_work_size", "pca_row"]


@njit(inline="always")
def kf_fuse_b(dx, P, R, H, nu, buf):
    return _kf_row(dx, P, R, H, nu, kf_work_in(buf, dx.shape[0], nu.shape[0]))


@njit(inline="always")
def mckf_fuse_b(dx, P, R, H, nu, mp, st, ad, buf):
    w = mckf_work_in(buf, dx.shape[0], nu.shape[0])
    apar, sig, ast, kxa, kya = ad
    if apar[AP.ADAPTIVE] > 0.0:  # mckf_adaptive_update_row's law, one call of the MCKF row
        v = adapt_kernels_row(dx, P, R, H, nu, w,
                              (sig, apar[AP.LAM], apar[AP.CLIP], ast, kxa, kya))
        if not math.isfinite(v):
            return v
        _, _, fpar, ipar = mp
        mp = (kxa, kya, fpar, ipar)
    return _mckf_row(dx, P, R, H, nu, mp, st, w)
