"""PCA block (both readings) and the PCA-KF / PCA-MCKF compositions."""

from __future__ import annotations

import numpy as np
import pytest

from estimators import KF, MCKF, PCAKF, PCAMCKF, PCABlock, motion_model
from estimators.pca import DEFAULT_MODE, lawnmower_truth


def _channels_reference(W, m):
    """Paper eqs 3-7 on a c×N window, returning the last reconstructed column."""
    mean = W.mean(axis=1, keepdims=True)
    Wc = W - mean
    cov = Wc @ Wc.T / (W.shape[1] - 1)
    lam, V = np.linalg.eig(cov)
    Pm = V[:, np.argsort(lam)[::-1][:m]].real
    Y_tilde = Pm @ (Pm.T @ Wc) + mean
    return Y_tilde[:, -1]


def _ssa_reference(w, L, r):
    """Textbook SSA of one channel: centre, embed, truncated SVD, diagonal averaging."""
    mu = w.mean()
    x = w - mu
    N = len(x)
    K = N - L + 1
    X = np.array([x[i : i + K] for i in range(L)])
    U, s, Vt = np.linalg.svd(X, full_matrices=False)
    Xr = (U[:, :r] * s[:r]) @ Vt[:r]
    rec = np.zeros(N)
    cnt = np.zeros(N)
    for i in range(L):
        for j in range(K):
            rec[i + j] += Xr[i, j]
            cnt[i + j] += 1
    return mu + rec[-1] / cnt[-1]


def test_passthrough_and_invalid_fixes():
    blk = PCABlock(2, window=5, mode="channels")
    rng = np.random.default_rng(0)
    for k in range(4):
        z = rng.normal(size=2)
        np.testing.assert_array_equal(blk(z), z)
        assert blk.count == k + 1
    assert blk(None) is None
    out = blk([np.nan, 1.0])
    assert np.isnan(out[0]) and blk.count == 4  # not pushed
    z = rng.normal(size=2)
    assert not np.array_equal(blk(z), z)  # the 5th valid sample is filtered
    assert blk.ready


@pytest.mark.parametrize("c,m", [(2, 1), (3, 1), (3, 2)])
def test_channels_mode_is_eqs_3_to_7(c, m):
    rng = np.random.default_rng(c + m)
    N = 15
    blk = PCABlock(c, window=N, n_components=m, mode="channels")
    data = np.cumsum(rng.normal(size=(60, c)), axis=0) * [3.0, 1.0, 0.5][:c]
    for k, z in enumerate(data):
        out = blk(z)
        if k >= N - 1:
            np.testing.assert_allclose(
                out, _channels_reference(data[k - N + 1 : k + 1].T, m), atol=1e-9
            )
            np.testing.assert_allclose(blk.window_data, data[k - N + 1 : k + 1].T)


def test_channels_mode_projects_onto_the_leg():
    rng = np.random.default_rng(3)
    N = 30
    blk = PCABlock(2, window=N, mode="channels")
    d = np.array([np.cos(0.3), np.sin(0.3)])
    s = np.arange(200) * 0.25
    Z = 100.0 + s[:, None] * d + 0.2 * rng.standard_normal((200, 2))
    outs = np.array([blk(z) for z in Z])[N:]
    cross = lambda p: (p - 100.0) @ np.array([-d[1], d[0]])  # noqa: E731
    assert np.std(cross(outs)) < 0.5 * np.std(cross(Z[N:]))  # ~0.3 expected


def test_full_rank_channels_is_identity():
    blk = PCABlock(2, window=6, n_components=2, mode="channels")
    rng = np.random.default_rng(1)
    for z in rng.normal(size=(20, 2)):
        np.testing.assert_allclose(blk(z), z, atol=1e-9)


@pytest.mark.parametrize("N,L,r", [(20, 10, 2), (16, 5, 3), (12, 6, 1)])
def test_hankel_mode_is_ssa(N, L, r):
    rng = np.random.default_rng(N)
    blk = PCABlock(2, window=N, n_components=r, mode="hankel", embed=L)
    data = np.cumsum(rng.normal(size=(50, 2)), axis=0)
    for k, z in enumerate(data):
        out = blk(z)
        if k >= N - 1:
            win = data[k - N + 1 : k + 1]
            ref = [_ssa_reference(win[:, i], L, r) for i in range(2)]
            np.testing.assert_allclose(out, ref, atol=1e-8)


def test_hankel_rank2_is_exact_on_constant_velocity():
    blk = PCABlock(2, window=20, n_components=2, mode="hankel")
    t = np.arange(40) * 0.05
    Z = np.stack([1000.0 + 5.0 * t, -300.0 + 2.0 * t], axis=1)
    for z in Z:
        out = blk(z)
    np.testing.assert_allclose(out, Z[-1], atol=1e-8)


def test_bad_parameters():
    with pytest.raises(ValueError):
        PCABlock(2, mode="svd")
    with pytest.raises(ValueError):
        PCABlock(2, window=10, mode="hankel", embed=10)
    with pytest.raises(ValueError):
        PCABlock(2, window=10, n_components=3, mode="channels")


@pytest.mark.parametrize("mode", ["channels", "hankel"])
@pytest.mark.parametrize("base,comp", [(KF, PCAKF), (MCKF, PCAMCKF)])
def test_compositions_are_pca_then_filter(mode, base, comp):
    mdl = motion_model("cv", 2, 0.05, q=1.0, r=4.0)
    truth = lawnmower_truth(n_legs=2, leg=20.0)
    rng = np.random.default_rng(5)
    Z = truth + 2.0 * rng.standard_normal(truth.shape)
    Z[17] = np.nan
    x0 = mdl.state(truth[0], [5.0, 0.0])
    f = comp(mdl.F, mdl.H, mdl.Q, mdl.R, x0, np.eye(4), window=12, mode=mode)
    g = base(mdl.F, mdl.H, mdl.Q, mdl.R, x0, np.eye(4))
    blk = PCABlock(2, window=12, mode=mode)
    for k, z in enumerate(Z):
        f.predict()
        g.predict()
        assert f.update(z) == g.update(blk(z))
        if k < 11:  # pass-through: the 12th valid sample is the first one filtered
            np.testing.assert_array_equal(f.z_filtered, Z[k])
        np.testing.assert_allclose(f.x, g.x, atol=1e-12)
        np.testing.assert_allclose(f.P, g.P, atol=1e-12)
    assert not f.update(None)


def test_default_mode_is_documented():
    assert DEFAULT_MODE in ("channels", "hankel")
    assert PCABlock(2).mode == DEFAULT_MODE
