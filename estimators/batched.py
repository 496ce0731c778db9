"""Batched KF / MCKF / PCA-KF / PCA-MCKF: N independent filters advanced in one call.

Used by a lockstep engine that flies N missions at once: every control tick it predicts every
vehicle's filters with its IMU acceleration, and on a GNSS fix (some vehicles only: outages)
updates them.  Each law lives once, as a compiled row function on one filter's arrays; the
kernels here only loop over the rows calling them, and the scalar classes call the same
functions on their own arrays, so row i equals the scalar filter bit for bit:

* predict (all classes): :func:`estimators.kf.kf_predict_row` (x̄ = F x̂, P̄ = F P Fᵀ + Q) and
  the IMU input :func:`estimators.kf.kf_input_row` (x[pos_a] += dt²/2·u_a, x[vel_a] += dt·u_a,
  as ``ag_uav.navigation.estimation.FilterBank._step_bank`` adds it to a scalar filter);
* :class:`BatchKF` ↔ :class:`estimators.KF`: :func:`estimators.kf.kf_update_row` (Kalman
  1960, Joseph form; Candan & Li Alg. 1);
* :class:`BatchMCKF` ↔ :class:`estimators.MCKF`: :func:`estimators.mckf.mckf_update_row`
  (Chen, Liu, Zhao, Principe 2017: the whitened fixed point
  :func:`~estimators.mckf.mckf_fixed_point_row`, the Cholesky pivot test and jittered factor,
  the lock-out recovery rules ``"kf"`` / ``"inflate"`` / ``None``, the Joseph update with the
  original P̄ or α P̄ after an inflation reset);
* :class:`BatchPCAKF`, :class:`BatchPCAMCKF` ↔ :class:`estimators.PCAKF` / ``PCAMCKF``:
  :func:`estimators.pca.pca_row` (Candan & Li §III.C, "hankel" = SSA per channel or
  "channels") in front of the KF / MCKF update row.

Array layout (C-contiguous float64, leading batch axis N): ``x`` (N, n), ``P`` (N, n, n),
``R`` (N, m, m), ``nis`` (N,), ``y`` (N, m) (last innovation), MCKF ``n_rejected`` etc. (N,),
PCA window ring buffers (N, m, 2·window).  F, H, Q are shared by the batch (same model, dt,
q).  R is per vehicle and may be written at any time (``bf.R[i] = R_i`` or
:meth:`BatchFilter.set_R`): every quantity derived from R (B_r⁻¹ of the MCKF) is recomputed at
each update, as in the scalar filters.

Why numba: at the sizes of the bank (n = 9, m = 3) a numpy call costs about a microsecond
whatever the size, and a vectorised batched update needs dozens of calls (more for the MCKF's
per-row fixed point with its data-dependent iteration count, the PCA eigenproblems and the
recovery branches); the compiled kernels loop over the rows with straight float arithmetic.
No row touches another and there is no cross-row BLAS call, so vehicle i's results are
bit-identical whatever N and whatever the other rows hold (determinism of the lockstep
engine).  Without numba the same functions run as (slow) Python (:mod:`estimators._jit`).
The first use compiles the kernels (cached by numba in ``__pycache__``); :func:`warm_up` does
it before anything is timed.  Speed against a numpy-vectorised KF:
``python tests/oracles/batched_numpy.py``.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np

from ._jit import njit
from ._linalg import copy_vec
from .kf import (
    KF,
    block3,
    csr,
    kf_input_row,
    kf_update_row,
    kf_work,
    predict_b3_row,
    predict_csr_row,
)
from .mckf import MCKF, MCKF_F, MCKF_I, MCKF_ST, RECOVERY, ST, mckf_update_row, mckf_work
from .pca import PCA_MODE, PCAKF, PCAMCKF, pca_row

__all__ = [
    "BatchBank",
    "BatchFilter",
    "BatchKF",
    "BatchMCKF",
    "BatchPCAKF",
    "BatchPCAMCKF",
    "batch_class",
    "pca_batch",
    "warm_up",
]

_MODELS = ("cv", "cvb")

# ----------------------------------------------------------------------------------------------
# batch kernels: loops over the rows calling the row functions where each law lives
# ----------------------------------------------------------------------------------------------


@njit
def _predict_batch_b3(x, P, Fb, Q, u, pos, vel, dt, active, use_u):
    """:func:`estimators.kf.kf_predict_row` on the active rows for F = blkdiag(Fb, …) (its
    3×3-block form :func:`~estimators.kf.predict_b3_row`), then with ``use_u`` the IMU input
    :func:`~estimators.kf.kf_input_row` (x[pos] += dt²/2·u, x[vel] += dt·u)."""
    hh = 0.5 * dt * dt
    for i in range(x.shape[0]):
        if active[i]:
            predict_b3_row(x[i], P[i], Fb, Q)
            if use_u:
                kf_input_row(x[i], u[i], pos, vel, hh, dt)


@njit
def _predict_batch(x, P, fcsr, Q, u, axes, dt, active, use_u, scratch):
    """As :func:`_predict_batch_b3` for a general F in CSR form ``fcsr`` = (ptr, idx, val)
    (:func:`~estimators.kf.predict_csr_row`); ``axes`` = (pos, vel) the input's indices,
    ``scratch`` = (tx (n,), FP (n, n))."""
    fptr, fidx, fval = fcsr
    pos, vel = axes
    tx, FP = scratch
    hh = 0.5 * dt * dt
    for i in range(x.shape[0]):
        if active[i]:
            predict_csr_row(x[i], P[i], fptr, fidx, fval, Q, tx, FP)
            if use_u:
                kf_input_row(x[i], u[i], pos, vel, hh, dt)


@njit
def pca_batch(buf, pcs, zf, z, mask, Nw, L, r, mode):
    """The PCA block of the masked rows: :func:`estimators.pca.pca_row` on each."""
    for i in range(z.shape[0]):
        if mask[i]:
            pca_row(buf[i], pcs[i], z[i], Nw, L, r, mode, zf[i])


@njit
def _pca_batch2(one, two, z, mask, Nw, L, r, mode):
    """:func:`pca_batch` for two filters with the same PCA options (PCA-KF and PCA-MCKF of
    one bank), ``one`` and ``two`` each (ring buffers, ring states, outputs): where a row's two
    windows are equal (they see the same fixes) the block runs once and its result (window,
    output) is copied; otherwise each runs on its own window.  The same deterministic function
    of the same inputs: bit-identical to running both."""
    buf, pcs, zf = one
    buf2, pcs2, zf2 = two
    c = z.shape[1]
    W = buf.shape[2]
    for i in range(z.shape[0]):
        if not mask[i]:
            continue
        same = pcs[i, 0] == pcs2[i, 0] and pcs[i, 1] == pcs2[i, 1]
        if same:
            for a in range(c):
                for j in range(W):
                    if buf[i, a, j] != buf2[i, a, j]:
                        same = False
                        break
                if not same:
                    break
        pca_row(buf[i], pcs[i], z[i], Nw, L, r, mode, zf[i])
        if same:
            for a in range(c):
                for j in range(W):
                    buf2[i, a, j] = buf[i, a, j]
                zf2[i, a] = zf[i, a]
            pcs2[i, 0] = pcs[i, 0]
            pcs2[i, 1] = pcs[i, 1]
        else:
            pca_row(buf2[i], pcs2[i], z[i], Nw, L, r, mode, zf2[i])


@njit
def _kf_update_batch(x, P, R, nis, y, H, z, mask, ok):
    """:func:`estimators.kf.kf_update_row` on the masked rows; ok[i] = a fix was fused."""
    N, n = x.shape
    w = kf_work(n, H.shape[0])
    for i in range(N):
        ok[i] = False
        if not mask[i]:
            continue
        v = kf_update_row(x[i], P[i], R[i], H, z[i], w)
        if not math.isfinite(v):
            continue
        copy_vec(w.nu, y[i])
        nis[i] = v
        ok[i] = True


@njit
def _mckf_update_batch(x, P, R, H, z, mask, mp, st, res):
    """:func:`estimators.mckf.mckf_update_row` on the masked rows: per-row parameters ``mp`` =
    (kx, ky, fpar, ipar) and state ``st`` = (ist, wy), results ``res`` = (nis, y, ok): ok[i] =
    a fix was fused."""
    kx, ky, fpar, ipar = mp
    ist, wy = st
    nis, y, ok = res
    N, n = x.shape
    w = mckf_work(n, H.shape[0])
    for i in range(N):
        ok[i] = False
        if not mask[i]:
            continue
        v = mckf_update_row(x[i], P[i], R[i], H, z[i], (kx[i], ky[i], fpar[i], ipar[i]),
                            (ist[i], wy[i]), w)
        if not math.isfinite(v):
            continue
        copy_vec(w.nu, y[i])
        nis[i] = v
        ok[i] = True


# ----------------------------------------------------------------------------------------------
# classes
# ----------------------------------------------------------------------------------------------


def _rows(mask, N: int) -> np.ndarray:
    if mask is None:
        return np.ones(N, dtype=bool)
    a = np.asarray(mask)
    if a.dtype == bool:
        if a.shape != (N,):
            raise ValueError(f"mask must have shape ({N},), got {a.shape}")
        return np.ascontiguousarray(a)
    out = np.zeros(N, dtype=bool)
    out[a.astype(np.int64)] = True
    return out


class BatchFilter:
    """N filters of one class on one shared model (F, H, Q, dt); see the module docstring.

    Build with :meth:`from_filters` from scalar filters (``ag_uav.estimation.make_filter``).
    Attributes: ``x`` (N, n), ``P`` (N, n, n), ``R`` (N, m, m, writable per vehicle), ``nis``
    (N,) (NaN until the first update), ``y`` (N, m), ``n``, ``m``, ``N``, ``pos_idx``,
    ``vel_idx``, ``dt``, ``F``, ``H``, ``Q``.
    """

    scalar_class: type = KF
    name = "kf"

    def __init__(self, F: np.ndarray, H: np.ndarray, Q: np.ndarray, R: np.ndarray,
                 x: np.ndarray, P: np.ndarray, pos_idx: Sequence[int], vel_idx: Sequence[int],
                 dt: float) -> None:
        self.F = np.array(F, dtype=float)
        self.H = np.ascontiguousarray(H, dtype=float)
        self.Q = np.ascontiguousarray(Q, dtype=float)
        self.n, self.m = self.F.shape[0], self.H.shape[0]
        if not 1 <= self.m <= 3:
            raise ValueError(f"batched filters need 1 <= m <= 3 measurements, got {self.m}")
        self.x = np.array(x, dtype=float)
        self.N = self.x.shape[0]
        if self.x.shape != (self.N, self.n):
            raise ValueError(f"x must have shape (N, {self.n}), got {self.x.shape}")
        self.P = np.array(P, dtype=float).reshape(self.N, self.n, self.n)
        self.R = np.array(R, dtype=float).reshape(self.N, self.m, self.m)
        self.pos_idx = np.asarray(pos_idx, dtype=np.int64)
        self.vel_idx = np.asarray(vel_idx, dtype=np.int64)
        self.dt = float(dt)
        self._fcsr = csr(self.F)
        self._Fb = block3(self.F)
        self.nis = np.full(self.N, np.nan)
        self.y = np.zeros((self.N, self.m))
        self._ok = np.zeros(self.N, dtype=bool)
        self._all = np.ones(self.N, dtype=bool)
        self._u0 = np.zeros((self.N, len(self.pos_idx)))
        self._scratch = (np.empty(self.n), np.empty((self.n, self.n)))  # predict_csr_row's

    # construction ------------------------------------------------------------------------------
    @classmethod
    def _check(cls, filters: Sequence[Any]) -> None:
        if len(filters) == 0:
            raise ValueError("from_filters needs at least one filter")
        for f in filters:
            if type(f) is not cls.scalar_class:
                raise ValueError(f"{cls.__name__}.from_filters needs {cls.scalar_class.__name__}"
                                 f" instances, got {type(f).__name__}")
            mdl = getattr(f, "model", None)
            if mdl is None or mdl.kind not in _MODELS:
                raise ValueError(f"{cls.__name__}: filters must be built from a motion model "
                                 f"{_MODELS} (estimators.make(..., model=...)), got "
                                 f"{getattr(mdl, 'kind', None)!r}")
        f0 = filters[0]
        for f in filters[1:]:
            for name in ("F", "H", "Q"):
                if not np.array_equal(getattr(f, name), getattr(f0, name)):
                    raise ValueError(f"{cls.__name__}: {name} differs between the filters (the "
                                     "batch shares F, H, Q: same model, dt and q)")
            if f.model.dt != f0.model.dt or f.model.kind != f0.model.kind:
                raise ValueError(f"{cls.__name__}: model kind/dt differ between the filters")

    @classmethod
    def from_filters(cls, filters: Sequence[Any]) -> BatchFilter:
        """Batch of N scalar filters of :attr:`scalar_class`: copies F, H, Q (shared, checked
        equal), R, x, P, nis, y and the class's parameters and state (MCKF counters, PCA
        window).  Raises ValueError for unsupported classes or options."""
        cls._check(filters)
        f0 = filters[0]
        mdl = f0.model
        out = cls(f0.F, f0.H, f0.Q, np.stack([f.R for f in filters]),
                  np.stack([f.x for f in filters]), np.stack([f.P for f in filters]),
                  mdl.pos_idx, mdl.vel_idx, mdl.dt)
        out.nis[:] = [f.nis for f in filters]
        out.y[:] = np.stack([f.y for f in filters])
        out.adopt(filters)
        return out

    def adopt(self, filters: Sequence[Any]) -> None:
        """Take the class-specific parameters and state of ``filters`` (one per row; each mixin
        extends it via super()): :meth:`from_filters` calls it, and a caller that builds the
        batch itself (without a motion model) calls it to copy the filters' options in."""

    # verbs -------------------------------------------------------------------------------------
    def predict(self, u: np.ndarray | None = None, active: np.ndarray | None = None) -> None:
        """x = F x, P = F P Fᵀ + Q on the active rows (default all; bool (N,) or indices),
        then with ``u`` (N, axes) ``x[pos] += dt²/2·u``, ``x[vel] += dt·u``."""
        act = self._all if active is None else _rows(active, self.N)
        if u is None:
            uu, use_u = self._u0, False
        else:
            uu = np.ascontiguousarray(u, dtype=float)
            if uu.shape != self._u0.shape:
                raise ValueError(f"u must have shape {self._u0.shape}, got {uu.shape}")
            use_u = True
        if self._Fb.shape[0] == 3:  # the two forms of kf_predict_row, chosen once per batch
            _predict_batch_b3(self.x, self.P, self._Fb, self.Q, uu, self.pos_idx, self.vel_idx,
                              self.dt, act, use_u)
            return
        _predict_batch(self.x, self.P, self._fcsr, self.Q, uu, (self.pos_idx, self.vel_idx),
                       self.dt, act, use_u, self._scratch)

    def update(self, z: np.ndarray, mask: np.ndarray | None = None) -> np.ndarray:
        """Fuse fix z[i] into the rows with mask[i] (default all), each exactly as the scalar
        ``update(z[i])``; other rows are untouched.  Returns ok (N,) bool: a fix was fused
        (False for masked-out rows and for non-finite fixes).  The array is reused."""
        zz = np.ascontiguousarray(z, dtype=float)
        if zz.shape != (self.N, self.m):
            raise ValueError(f"z must have shape ({self.N}, {self.m}), got {zz.shape}")
        self._update(zz, self._all if mask is None else _rows(mask, self.N))
        return self._ok

    def _update(self, z: np.ndarray, mask: np.ndarray) -> None:
        self._fuse(z, mask)

    def _fuse(self, z: np.ndarray, mask: np.ndarray) -> None:
        """The filter's update proper (after the PCA block of the PCA classes)."""
        _kf_update_batch(self.x, self.P, self.R, self.nis, self.y, self.H, z, mask, self._ok)

    def initialise(self, mask, x0: np.ndarray, P0: np.ndarray, reset_window: bool = False) -> None:
        """Set x, P of the masked rows (bool (N,) or indices) to x0 ((n,) or (N, n)) and P0
        ((n, n) or (N, n, n)), as ``f.x = x0; f.P = P0`` (what EstimatorFeedback._init does:
        the PCA windows and MCKF counters are NOT reset; ``reset_window=True`` empties the PCA
        windows as ``PCABlock.reset()``)."""
        rows = _rows(mask, self.N)
        x0 = np.asarray(x0, dtype=float)
        P0 = np.asarray(P0, dtype=float)
        self.x[rows] = x0 if x0.ndim == 1 else x0[rows]
        self.P[rows] = P0 if P0.ndim == 2 else P0[rows]
        if reset_window:
            self._reset_window(rows)

    def _reset_window(self, rows: np.ndarray) -> None:
        """Hook of the PCA classes."""

    def set_R(self, R: np.ndarray, rows=None) -> None:
        """R of the given rows (default all): (m, m) or (len(rows), m, m); checked SPD as the
        scalar ``f.R = R`` (whose MCKF Cholesky raises otherwise)."""
        sel = _rows(rows, self.N)
        Ra = np.asarray(R, dtype=float)
        np.linalg.cholesky(Ra)
        self.R[sel] = Ra

    def positions(self) -> np.ndarray:
        """(N, axes) copy of the position estimates."""
        return self.x[:, self.pos_idx]

    def velocities(self) -> np.ndarray:
        """(N, axes) copy of the velocity estimates."""
        return self.x[:, self.vel_idx]

    def to_filter(self, i: int, f: Any) -> Any:
        """Write vehicle i's state (x, P, R, nis, y and the class's state) into scalar ``f``."""
        f.x = self.x[i].copy()
        f.P = self.P[i].copy()
        f.R = self.R[i].copy()
        f.nis = float(self.nis[i])
        f.y = self.y[i].copy()
        self._to(i, f)
        return f

    def _to(self, i: int, f: Any) -> None:
        """Class-specific state (hook; each mixin extends it via super())."""


class BatchKF(BatchFilter):
    """Batched :class:`estimators.KF`."""

    scalar_class = KF
    name = "kf"


class _MCKFMixin:
    """MCKF parameters (per row) and state: ``n_rejected``, ``n_iter``, ``rejected``,
    ``recovered`` (N,) int views, ``weights`` (N, m) = diag C_y of the last update."""

    N: int
    n: int
    m: int

    def adopt(self, filters: Sequence[Any]) -> None:
        super().adopt(filters)  # type: ignore[misc]
        N, n = self.N, self.n
        self._kx = np.empty((N, n))
        self._ky = np.empty((N, self.m))
        self._fpar = np.empty((N, MCKF_F.size))
        self._ipar = np.empty((N, MCKF_I.size), dtype=np.int64)
        self._ist = np.zeros((N, MCKF_ST.size), dtype=np.int64)
        self.weights = np.ones((N, self.m))
        for i, f in enumerate(filters):
            if f.adaptive_sigma:
                raise ValueError("batched MCKF: adaptive_sigma is not supported")
            if not f.kernel_floor > 0.0:
                raise ValueError("batched MCKF: kernel_floor must be > 0")
            if f.recovery not in RECOVERY:
                raise ValueError(f"batched MCKF: unknown recovery {f.recovery!r}")
            self._kx[i], self._ky[i] = f.kernels
            self._fpar[i], self._ipar[i] = f.params()
            self._ist[i, ST.N_REJECTED], self._ist[i, ST.N_ITER] = f.n_rejected, f.n_iter
            self._ist[i, ST.REJECTED], self._ist[i, ST.RECOVERED] = f.rejected, f.recovered
            self.weights[i] = f.weights

    @property
    def n_rejected(self) -> np.ndarray:
        return self._ist[:, ST.N_REJECTED]

    @property
    def n_iter(self) -> np.ndarray:
        return self._ist[:, ST.N_ITER]

    @property
    def rejected(self) -> np.ndarray:
        return self._ist[:, ST.REJECTED].astype(bool)

    @property
    def recovered(self) -> np.ndarray:
        return self._ist[:, ST.RECOVERED].astype(bool)

    def _fuse(self, z: np.ndarray, mask: np.ndarray) -> None:
        _mckf_update_batch(self.x, self.P, self.R, self.H, z, mask,
                           (self._kx, self._ky, self._fpar, self._ipar), (self._ist, self.weights),
                           (self.nis, self.y, self._ok))

    def _to(self, i: int, f: Any) -> None:
        super()._to(i, f)  # type: ignore[misc]
        f.n_rejected = int(self._ist[i, ST.N_REJECTED])
        f.n_iter = int(self._ist[i, ST.N_ITER])
        f.rejected = bool(self._ist[i, ST.REJECTED])
        f.recovered = bool(self._ist[i, ST.RECOVERED])
        f.weights = self.weights[i].copy()


class _PCAMixin:
    """PCA window state: ``ring`` (N, m, 2·window) the ring buffers, ``ring_state`` (N, 2) their
    positions and counts (each row :class:`estimators.PCABlock`'s), ``z_filtered`` (N, m) = the
    last fix after the PCA block."""

    N: int
    m: int

    def adopt(self, filters: Sequence[Any]) -> None:
        super().adopt(filters)  # type: ignore[misc]
        b0 = filters[0].pca
        for f in filters:
            b = f.pca
            if (b.N, b.mode, b.L, b.n_components, b.c) != (b0.N, b0.mode, b0.L,
                                                          b0.n_components, b0.c):
                raise ValueError("batched PCA filters: window, mode, embed and n_components "
                                 "must be the same for every filter")
        if b0.mode not in PCA_MODE:
            raise ValueError(f"batched PCA filters: unknown mode {b0.mode!r}")
        self.window, self.pca_mode = b0.N, b0.mode
        self._L, self._r = b0.L, b0.n_components
        self.ring = np.ascontiguousarray(np.stack([f.pca.ring for f in filters]))
        self.ring_state = np.array([f.pca.ring_state for f in filters], dtype=np.int64)
        self.z_filtered = np.zeros((self.N, self.m))
        for i, f in enumerate(filters):
            if f.z_filtered is not None:
                self.z_filtered[i] = f.z_filtered

    def _update(self, z: np.ndarray, mask: np.ndarray) -> None:
        self._pca(z, mask)
        self._fuse(self.z_filtered, mask)  # type: ignore[attr-defined]

    def _pca_key(self) -> tuple:
        return (self.window, self._L, self._r, self.pca_mode, self.m)

    def _pca(self, z: np.ndarray, mask: np.ndarray) -> None:
        pca_batch(self.ring, self.ring_state, self.z_filtered, z, mask, self.window, self._L,
                   self._r, PCA_MODE[self.pca_mode])

    def _pca2(self, other: _PCAMixin, z: np.ndarray, mask: np.ndarray) -> None:
        """Run the PCA block of self and ``other`` (same options), once per row where their
        windows are equal."""
        _pca_batch2((self.ring, self.ring_state, self.z_filtered),
                    (other.ring, other.ring_state, other.z_filtered), z, mask, self.window,
                    self._L, self._r, PCA_MODE[self.pca_mode])

    def _reset_window(self, rows: np.ndarray) -> None:
        self.ring_state[rows] = 0

    def _to(self, i: int, f: Any) -> None:
        super()._to(i, f)  # type: ignore[misc]
        f.pca.ring[:] = self.ring[i]
        f.pca.ring_state[:] = self.ring_state[i]
        f.z_filtered = self.z_filtered[i].copy()


class BatchMCKF(_MCKFMixin, BatchFilter):
    """Batched :class:`estimators.MCKF` (options: sigma scalar or per row n+m, eps, max_iter,
    kernel_floor > 0, recovery None/"kf"/"inflate" with lockout_n, reject_weight, inflate;
    adaptive_sigma is refused)."""

    scalar_class = MCKF
    name = "mckf"


class BatchPCAKF(_PCAMixin, BatchFilter):
    """Batched :class:`estimators.PCAKF` (modes "hankel" and "channels")."""

    scalar_class = PCAKF
    name = "pca-kf"


class BatchPCAMCKF(_PCAMixin, _MCKFMixin, BatchFilter):
    """Batched :class:`estimators.PCAMCKF`: the PCA block of :class:`BatchPCAKF` in front of
    the :class:`BatchMCKF` update."""

    scalar_class = PCAMCKF
    name = "pca-mckf"


_BY_SCALAR: dict[type, type[BatchFilter]] = {
    KF: BatchKF, MCKF: BatchMCKF, PCAKF: BatchPCAKF, PCAMCKF: BatchPCAMCKF,
}


def batch_class(f: Any) -> type[BatchFilter]:
    """The batched class for scalar filter ``f`` (ValueError for unsupported classes)."""
    try:
        return _BY_SCALAR[type(f)]
    except KeyError:
        raise ValueError(f"no batched version of {type(f).__name__}; supported: "
                         f"{', '.join(c.__name__ for c in _BY_SCALAR)}") from None


class BatchBank:
    """name → batched filter, advanced together (the lockstep counterpart of
    ``ag_uav.estimation.FilterBank._step_bank``: predict + IMU input, then update).

    PCA filters with the same PCA options (PCA-KF and PCA-MCKF of the bank) are paired: their
    blocks see the same fixes, so :meth:`update` runs the block once per row where the two
    windows are equal (checked per row and update; results bit-identical to running both)."""

    def __init__(self, filters: Mapping[str, BatchFilter]) -> None:
        self.filters = dict(filters)
        pca = [f for f in self.filters.values() if isinstance(f, _PCAMixin)]
        self._pairs: list[tuple[Any, Any]] = []
        used: set[int] = set()
        for a, fa in enumerate(pca):
            for b in range(a + 1, len(pca)):
                fb = pca[b]
                if a in used or b in used or fa.N != fb.N or fa._pca_key() != fb._pca_key():
                    continue
                self._pairs.append((fa, fb))
                used.update((a, b))
        self._paired = {id(f) for pair in self._pairs for f in pair}

    @classmethod
    def from_filters(cls, banks: Sequence[Mapping[str, Any]]) -> BatchBank:
        """From one {name: scalar filter} dict per vehicle (same names in each)."""
        names = list(banks[0])
        if any(list(b) != names for b in banks):
            raise ValueError("every vehicle's bank must hold the same filter names")
        return cls({k: batch_class(banks[0][k]).from_filters([b[k] for b in banks])
                    for k in names})

    def __getitem__(self, name: str) -> BatchFilter:
        return self.filters[name]

    def predict(self, u: np.ndarray | None = None, active: np.ndarray | None = None) -> None:
        for f in self.filters.values():
            f.predict(u, active)

    def update(self, z: np.ndarray, mask: np.ndarray | None = None) -> dict[str, np.ndarray]:
        """Update every filter with the same fixes z (N, m) on the rows of mask (default all),
        as each filter's :meth:`BatchFilter.update`; returns {name: ok (N,) bool copy}."""
        f0 = next(iter(self.filters.values()))
        zz = np.ascontiguousarray(z, dtype=float)
        if zz.shape != (f0.N, f0.m):
            raise ValueError(f"z must have shape ({f0.N}, {f0.m}), got {zz.shape}")
        mk = f0._all if mask is None else _rows(mask, f0.N)
        for fa, fb in self._pairs:
            fa._pca2(fb, zz, mk)
            fa._fuse(fa.z_filtered, mk)
            fb._fuse(fb.z_filtered, mk)
        for f in self.filters.values():
            if id(f) not in self._paired:
                f._update(zz, mk)
        return {k: f._ok.copy() for k, f in self.filters.items()}

    def initialise(self, mask, x0: np.ndarray, P0: np.ndarray) -> None:
        for f in self.filters.values():
            f.initialise(mask, x0, P0)

    def set_R(self, R: np.ndarray, rows=None) -> None:
        for f in self.filters.values():
            f.set_R(R, rows)

    def positions(self, name: str) -> np.ndarray:
        return self.filters[name].positions()

    def velocities(self, name: str) -> np.ndarray:
        return self.filters[name].velocities()


def warm_up(bank: BatchBank) -> None:
    """Compile (first use) or load from numba's cache every kernel ``bank`` will run — predict
    with and without input, each filter's update and the bank's paired update — on a copy, so
    that no timed update pays for it (``update_us`` of the run's scores)."""
    import copy

    b = copy.deepcopy(bank)
    f0 = next(iter(b.filters.values()))
    u = np.zeros((f0.N, len(f0.pos_idx)))
    z = np.ascontiguousarray(np.einsum("ij,nj->ni", f0.H, f0.x))
    b.predict()
    b.predict(u)
    for f in b.filters.values():
        f.update(z)
    b.update(z)
