"""Each law of the bank (KF, MCKF, PCA block, PCA-KF, PCA-MCKF), written once as the row
functions of ``estimators``, against an independent oracle: filterpy for the KF, the numpy
references of ``tests/oracles`` for the MCKF and the PCA block.  Hundreds of ticks with
outliers, a sustained step (lock-out and recovery), outages (None and NaN fixes) and R switches;
rel + abs 1e-9."""

from __future__ import annotations

import numpy as np
import pytest

from estimators import KF, MCKF, PCAKF, PCAMCKF, PCABlock, motion_model
from tests.oracles.mckf import OracleMCKF
from tests.oracles.pca import OraclePCABlock

T = 400


def _close(a, b, scale=1.0):
    np.testing.assert_allclose(a, b, rtol=1e-9, atol=1e-9 * scale)


def _fixes(m: int, seed: int, R: np.ndarray):
    """Fixes along a random-acceleration track: white noise from R, 5 % spikes of 25σ, a 40 m
    step on channel 0 for 60 ticks, None and NaN outages; and the tick → R-scale schedule."""
    rng = np.random.default_rng(seed)
    vel = np.cumsum(0.2 * rng.standard_normal((T, m)), axis=0)
    pos = np.cumsum(0.05 * vel, axis=0) + 20.0 * rng.standard_normal(m)
    std = np.sqrt(np.diag(R))
    Z = pos + std * rng.standard_normal((T, m))
    Z += (rng.random((T, m)) < 0.05) * 25.0 * std * rng.choice([-1.0, 1.0], (T, m))
    Z[150:210, 0] += 40.0
    fixes: list = list(Z)
    for k in rng.choice(T, 30, replace=False):
        fixes[k] = None if k % 2 else np.where(np.arange(m) == k % m, np.nan, Z[k])
    rscale = np.where((np.arange(T) // 90) % 2 == 1, 4.0, 1.0)
    return fixes, rscale


def _model(kind: str, dim):
    return motion_model(kind, dim, 0.05, q=0.5, r=[1.0, 2.0, 0.25] if dim == 3 else 2.0)


def _filterpy_kf(mdl, x0, P0):
    filterpy = pytest.importorskip("filterpy.kalman")  # the oracle (a dev extra)
    f = filterpy.KalmanFilter(mdl.n, mdl.m)
    f.F, f.H, f.Q, f.R = mdl.F.copy(), mdl.H.copy(), mdl.Q.copy(), mdl.R.copy()
    f.x, f.P = x0.reshape(-1, 1).copy(), P0.copy()
    return f


def _run(ours, ref, fixes, rscale, R0, fuse_ref, state_ref, extra=None):
    """Predict + update both on every tick (R switched on both), comparing after each."""
    for k, z in enumerate(fixes):
        ours.predict()
        ref.predict()
        if k and rscale[k] != rscale[k - 1]:
            ours.R = rscale[k] * R0
            ref.R = rscale[k] * R0
        ok = ours.update(z)
        assert ok == fuse_ref(ref, z)
        x, P = state_ref(ref)
        sc = max(1.0, float(np.max(np.abs(x))))
        _close(ours.x, x, sc)
        _close(ours.P, P, float(np.max(np.abs(P))))
        if extra is not None and ok:
            extra(ours, ref)


def _kf_fuse(ref, z):
    if z is None or not np.all(np.isfinite(z)):
        return False
    ref.update(np.asarray(z, dtype=float).reshape(-1, 1))
    return True


def _kf_state(ref):
    return ref.x.ravel(), ref.P


@pytest.mark.parametrize("kind,dim", [("cv", 2), ("cvb", 3), ("ca", 3), ("cv", 1)])
def test_kf_matches_filterpy(kind, dim):
    mdl = _model(kind, dim)
    fixes, rscale = _fixes(mdl.m, 1, mdl.R)
    x0, P0 = np.zeros(mdl.n), 10.0 * np.eye(mdl.n)
    ours, ref = KF(mdl.F, mdl.H, mdl.Q, mdl.R, x0, P0), _filterpy_kf(mdl, x0, P0)

    def extra(o, r):
        _close(o.y, r.y.ravel(), 10.0)
        _close(o.K, r.K)
        assert o.nis == pytest.approx(r.mahalanobis**2, rel=1e-9)

    _run(ours, ref, fixes, rscale, mdl.R, _kf_fuse, _kf_state, extra)


def test_kf_general_m_matches_filterpy():
    """m = 4 measurements: the row's LAPACK inverse instead of the closed forms."""
    rng = np.random.default_rng(4)
    F, H = np.eye(4) + 0.05 * np.eye(4, k=1), np.eye(4)
    Q, R = 0.01 * np.eye(4), np.diag([1.0, 2.0, 3.0, 4.0])

    class M:
        n = m = 4

    M.F, M.H, M.Q, M.R = F, H, Q, R
    ours, ref = KF(F, H, Q, R, np.zeros(4), np.eye(4)), _filterpy_kf(M, np.zeros(4), np.eye(4))
    fixes = list(rng.normal(size=(200, 4)) * 3.0)
    _run(ours, ref, fixes, np.ones(200), R, _kf_fuse, _kf_state)


MCKF_CASES = [
    ("cvb", 3, {"recovery": "kf"}),
    ("cvb", 3, {"recovery": "inflate", "sigma": 2.5}),
    ("cv", 2, {"recovery": None, "max_iter": 3}),
    ("cv", 2, {"adaptive_sigma": True}),
    ("cv", 2, {"sigma": [5, 5, 5, 5, 1.5, np.inf], "eps": 1e-9, "max_iter": 20}),
    ("ca", 3, {"recovery": "inflate", "lockout_n": 4}),
]


def _mckf_fuse(ref, z):
    if z is None:
        return False
    return ref.update(z)


def _mckf_state(ref):
    return ref.x, ref.P


def _mckf_extra(o, r):
    assert (o.n_iter, o.rejected, o.recovered, o.n_rejected) == (
        r.n_iter, r.rejected, r.recovered, r.n_rejected)
    _close(o.weights, r.weights)
    _close(o.weights_x, r.weights_x)
    _close(o.K, r.K)
    assert o.nis == pytest.approx(r.nis, rel=1e-9)


@pytest.mark.parametrize("kind,dim,kw", MCKF_CASES, ids=[str(c) for c in MCKF_CASES])
def test_mckf_matches_oracle(kind, dim, kw):
    mdl = _model(kind, dim)
    fixes, rscale = _fixes(mdl.m, 2, mdl.R)
    x0, P0 = np.zeros(mdl.n), 10.0 * np.eye(mdl.n)
    ours = MCKF(mdl.F, mdl.H, mdl.Q, mdl.R, x0, P0, **kw)
    ref = OracleMCKF(mdl.F, mdl.H, mdl.Q, mdl.R, x0, P0, **kw)
    seen = {"rec": 0, "rej": 0}

    def extra(o, r):
        _mckf_extra(o, r)
        seen["rec"] += o.recovered
        seen["rej"] += o.rejected

    _run(ours, ref, fixes, rscale, mdl.R, _mckf_fuse, _mckf_state, extra)
    assert seen["rej"] > 10
    if kw.get("recovery", "kf") is not None and not kw.get("adaptive_sigma"):
        assert seen["rec"] > 0


def test_mckf_singular_prior_uses_the_jittered_factor():
    """A prior that fails the relative pivot test (zero velocity variance, Q = 0)."""
    mdl = _model("cv", 2)
    P0 = np.diag([1.0, 0.0, 1.0, 0.0])
    ours = MCKF(mdl.F, mdl.H, 0 * mdl.Q, mdl.R, np.zeros(4), P0)
    ref = OracleMCKF(mdl.F, mdl.H, 0 * mdl.Q, mdl.R, np.zeros(4), P0)
    for z in ([3.0, 40.0], [2.0, -1.0], [0.5, 0.5]):
        ours.update(z)
        ref.update(z)
        _close(ours.x, ref.x, 10.0)
        _close(ours.P, ref.P)
    assert np.all(np.isfinite(ours.P))


PCA_CASES = [(2, "hankel", 20, None, None), (3, "hankel", 16, 3, 5), (2, "channels", 12, 1, None),
             (3, "channels", 10, 2, None), (2, "hankel", 30, 4, 15)]


@pytest.mark.parametrize("c,mode,N,r,L", PCA_CASES, ids=[str(c) for c in PCA_CASES])
def test_pca_block_matches_oracle(c, mode, N, r, L):
    R = np.eye(c)
    fixes, _ = _fixes(c, 3, R)
    blk = PCABlock(c, N, r, mode, L)
    ref = OraclePCABlock(c, N, r, mode, L)
    full = OraclePCABlock(c, N, r, mode, L, full_eigh=True)
    for z in fixes:
        a, b, e = blk(z), ref(z), full(z)
        if z is None:
            assert a is None and b is None
            continue
        sc = max(1.0, float(np.max(np.abs(b[np.isfinite(b)]))) if np.isfinite(b).any() else 1.0)
        np.testing.assert_allclose(a, b, rtol=1e-9, atol=1e-9 * sc)
        np.testing.assert_allclose(a, e, rtol=1e-9, atol=1e-9 * sc)
        assert blk.ready == ref.ready


@pytest.mark.parametrize("mode", ["hankel", "channels"])
@pytest.mark.parametrize("comp", ["pca-kf", "pca-mckf"])
def test_pca_filters_match_oracle(mode, comp):
    mdl = _model("cvb", 3) if mode == "hankel" else _model("cv", 2)
    fixes, rscale = _fixes(mdl.m, 5, mdl.R)
    x0, P0 = np.zeros(mdl.n), 10.0 * np.eye(mdl.n)
    kw = {"window": 12, "mode": mode}
    blk = OraclePCABlock(mdl.m, 12, None, mode)
    if comp == "pca-kf":
        ours = PCAKF(mdl.F, mdl.H, mdl.Q, mdl.R, x0, P0, **kw)
        ref = _filterpy_kf(mdl, x0, P0)

        def fuse(r, z):
            return _kf_fuse(r, blk(z))

        state = _kf_state
    else:
        ours = PCAMCKF(mdl.F, mdl.H, mdl.Q, mdl.R, x0, P0, recovery="inflate", **kw)
        ref = OracleMCKF(mdl.F, mdl.H, mdl.Q, mdl.R, x0, P0, recovery="inflate")

        def fuse(r, z):
            return _mckf_fuse(r, blk(z))

        state = _mckf_state
    _run(ours, ref, fixes, rscale, mdl.R, fuse, state)
