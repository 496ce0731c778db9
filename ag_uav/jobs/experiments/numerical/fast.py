"""The fast engine of the numerical experiment: the library's laws batched over runs (recorded
gains for the linear filters, the batched PCA block and MCKF rows)."""

from __future__ import annotations

from typing import Any

import numpy as np

from .setup import (
    NOREC,
    Setup,
    filter_params,
    fixes,
    initial,
    library_states,
    make_filter,
    model,
    parse_estimator,
    truth,
)


# --------------------------------------------------------------------------- fast: linear KFs
def gain_sequence(name: str, setup: Setup, T: int, x0: np.ndarray, P0: np.ndarray
                  ) -> np.ndarray:
    """Gains K_k (T, n, m) of a fixed-gain filter, recorded from the library filter run on
    dummy (zero) fixes; with fixed F, H, Q, R and no missing fix they do not depend on data."""
    f = make_filter(name, setup, x0, P0)
    z = np.zeros(2)
    Ks = []
    for k in range(T):
        if k:
            f.predict()
        f.update(z)
        Ks.append(np.array(f.K))
    return np.array(Ks)


def kf_fixed_gain(F: np.ndarray, H: np.ndarray, Ks: np.ndarray, x0: np.ndarray,
                  Z: np.ndarray) -> np.ndarray:
    """KF state recursion with precomputed gains for a batch of runs: Z (B, T, m) → x̂ (B, T, n).
    x̄ = F x̂, x̂ = x̄ + K_k (z_k − H x̄) (no predict at k = 0)."""
    B, T, _ = Z.shape
    FT, HT = F.T, H.T
    x = np.broadcast_to(x0, (B, x0.size)).copy()
    out = np.empty((B, T, x0.size))
    for k in range(T):
        if k:
            x = x @ FT
        x = x + (Z[:, k] - x @ HT) @ Ks[k].T
        out[:, k] = x
    return out


def kf_diff_fixed_gain(F: np.ndarray, H: np.ndarray, gamma: np.ndarray, Ks: np.ndarray,
                       x0: np.ndarray, Z: np.ndarray) -> np.ndarray:
    """Bryson-Henrikson recursion of :class:`estimators.DifferencingKF` (one predict per fix)
    with precomputed gains: k = 0 plain KF update; then with H̄ = H F − Γ H,
    x̂_k = F x̂_{k−1} + K_k (z_k − Γ z_{k−1} − H̄ x̂_{k−1})."""
    B, T, _ = Z.shape
    Hb = np.dot(H, F) - np.dot(gamma, H)
    x = np.broadcast_to(x0, (B, x0.size)).copy()
    out = np.empty((B, T, x0.size))
    x = x + (Z[:, 0] - x @ H.T) @ Ks[0].T
    out[:, 0] = x
    for k in range(1, T):
        y = Z[:, k] - Z[:, k - 1] @ gamma.T - x @ Hb.T
        x = x @ F.T + y @ Ks[k].T
        out[:, k] = x
    return out


# ------------------------------------------------------------------------------ fast: PCA
def pca_batch(Z: np.ndarray, setup: Setup) -> np.ndarray:
    """Output of :class:`estimators.PCABlock` (2 channels, the filters' window/mode defaults)
    for every fix of every run: Z (B, T, 2) → (B, T, 2), the runs as the rows of the batched
    block (:func:`estimators.batched.pca_batch`, the library's ``pca_row``).  The first N − 1
    fixes pass through unchanged."""
    from estimators import PCABlock
    from estimators.batched import pca_batch as run_rows
    from estimators.pca import PCA_MODE

    blk = PCABlock(2, setup.window, None, setup.pca_mode)
    B, T, c = Z.shape
    Zt = np.ascontiguousarray(np.asarray(Z, dtype=float).transpose(1, 0, 2))  # T × B × c
    buf = np.zeros((B, c, 2 * blk.N))
    pcs = np.zeros((B, 2), dtype=np.int64)
    zf = np.empty((B, c))
    rows = np.ones(B, dtype=bool)
    out = np.empty((B, T, c))
    for k in range(T):
        run_rows(buf, pcs, zf, Zt[k], rows, blk.N, blk.L, blk.n_components,
                 PCA_MODE[blk.mode])
        out[:, k] = zf
    return out


# ------------------------------------------------------------------------------ fast: MCKF
def mckf_batch(m: Any, x0: np.ndarray, P0: np.ndarray, Z: np.ndarray,
               **options: Any) -> np.ndarray:
    """:class:`estimators.MCKF` on a batch of runs: Z (B, T, m) → x̂ (B, T, n), the runs as the
    rows of :class:`estimators.batched.BatchMCKF` (the library's ``mckf_update_row``; no
    predict at k = 0).  ``m``: the model (its F, H, Q, R); ``options``: keyword arguments of
    :class:`estimators.MCKF` (``sigma``, ``recovery``, ...; the library's defaults
    otherwise)."""
    from estimators import MCKF
    from estimators.batched import BatchMCKF

    F, H, Q, R = m.F, m.H, m.Q, m.R
    B, T, nz = Z.shape
    n = F.shape[0]
    f = MCKF(F, H, Q, R, x0, P0, **options)
    bf = BatchMCKF(F, H, Q, np.broadcast_to(f.R, (B, nz, nz)), np.broadcast_to(f.x, (B, n)),
                   np.broadcast_to(f.P, (B, n, n)), [], [], 1.0)
    bf.adopt([f] * B)
    Zt = np.ascontiguousarray(np.asarray(Z, dtype=float).transpose(1, 0, 2))  # T × B × m
    out = np.empty((B, T, n))
    for k in range(T):
        if k:
            bf.predict()
        bf.update(Zt[k])
        out[:, k] = bf.x
    return out



def fast_tracks(setup: Setup, case: str, runs: list[int], ests: list[str],
                gains: dict[str, np.ndarray]) -> tuple[np.ndarray, dict[str, np.ndarray]]:
    """Fixes (B, T, 2) and every estimator's position track (B, T, 2) for ``runs``, fast path."""
    pos, vel = truth(setup)
    x0, P0 = initial(setup, pos, vel)
    m = model()
    Z = np.stack([fixes(case, r, pos, setup.dt) for r in runs])
    Zp = pca_batch(Z, setup) if any(e.startswith("pca-") for e in ests) else None
    tracks: dict[str, np.ndarray] = {}
    for e in ests:
        data = Zp if e.startswith("pca-") else Z
        base, kernel, _ = parse_estimator(e)
        if e in ("kf", "pca-kf"):
            xs = kf_fixed_gain(m.F, m.H, gains["kf"], x0, data)
        elif kernel == "adaptive":  # BatchMCKF has no adaptive rows: the library, run by run
            xs = np.stack([library_states(e, setup, Z[i], x0, P0) for i in range(len(Z))])
        elif "mckf" in base:
            xs = mckf_batch(m, x0, P0, data,
                            sigma=filter_params(e, setup)["sigma"],
                            recovery=None if base.endswith(NOREC) else "kf")
        elif e == "kf-bias":
            f = make_filter(e, setup, x0, P0)
            xs = kf_fixed_gain(f.kf.F, f.kf.H, gains[e], f.x_aug, data)
        elif e == "kf-diff":
            # Γ over one predict, as DifferencingKF computes it: exp(−n_pred·dt/τ), n_pred = 1
            gamma = np.diag(np.exp(-1 * setup.dt / np.full(2, setup.tau_s)))
            xs = kf_diff_fixed_gain(m.F, m.H, gamma, gains[e], x0, data)
        else:
            raise ValueError(f"unknown estimator {e!r}")
        tracks[e] = xs[:, :, [0, 2]]
    return Z, tracks
