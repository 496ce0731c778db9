"""MCKF: limits, the spec's hand case, a literal reference implementation, guards, recovery."""

from __future__ import annotations

import math

import numpy as np
import pytest

from estimators import KF, MCKF, motion_model, paper_numerical_model


def _mckf_reference(x_prior, P_prior, H, R, y, sigma, eps, max_iter):
    """Spec step 2-5 written literally (covariance form, explicit inverses)."""
    n = len(x_prior)
    Bp, Br = np.linalg.cholesky(P_prior), np.linalg.cholesky(R)
    B = np.block([[Bp, np.zeros((n, len(y)))], [np.zeros((len(y), n)), Br]])
    Binv = np.linalg.inv(B)
    D = Binv @ np.concatenate([x_prior, y])
    W = Binv @ np.vstack([np.eye(n), H])
    sig = np.broadcast_to(np.asarray(sigma, dtype=float), (n + len(y),))
    x = x_prior.copy()
    it = 0
    while it < max_iter:
        it += 1
        e = D - W @ x
        G = np.exp(-(e**2) / (2 * sig**2))
        Pt = Bp @ np.diag(1 / G[:n]) @ Bp.T
        Rt = Br @ np.diag(1 / G[n:]) @ Br.T
        K = Pt @ H.T @ np.linalg.inv(H @ Pt @ H.T + Rt)
        x_new = x_prior + K @ (y - H @ x_prior)
        done = np.linalg.norm(x_new - x) / max(np.linalg.norm(x), 1.0) <= eps
        x = x_new
        if done:
            break
    IKH = np.eye(n) - K @ H
    P = IKH @ P_prior @ IKH.T + K @ R @ K.T
    return x, P, it, G[n:]


def test_hand_case_of_the_spec():
    f = MCKF(1, 1, 0, 1, [0.0], [[1.0]], sigma=2.0)
    f.predict()
    assert f.update([10.0])
    assert f.x[0] == pytest.approx(3.7e-5, rel=0.02)
    assert f.P[0, 0] == pytest.approx(0.99999, abs=1e-5)
    assert f.n_iter <= 3
    k = KF(1, 1, 0, 1, [0.0], [[1.0]])
    k.predict()
    k.update([10.0])
    assert k.x[0] == pytest.approx(5.0) and k.P[0, 0] == pytest.approx(0.5)


@pytest.mark.parametrize("kind,dim", [("cv", 2), ("ca", 3), ("cv", 1)])
def test_huge_sigma_is_the_kf(kind, dim):
    mdl = motion_model(kind, dim, 0.05, q=0.5, r=3.0)
    rng = np.random.default_rng(4)
    x0 = rng.normal(size=mdl.n)
    a = MCKF(mdl.F, mdl.H, mdl.Q, mdl.R, x0, 5 * np.eye(mdl.n), sigma=1e6)
    b = KF(mdl.F, mdl.H, mdl.Q, mdl.R, x0, 5 * np.eye(mdl.n))
    for _ in range(300):
        a.predict()
        b.predict()
        z = rng.normal(scale=3.0, size=mdl.m)
        a.update(z)
        b.update(z)
        np.testing.assert_allclose(a.x, b.x, rtol=0, atol=1e-8)
        np.testing.assert_allclose(a.P, b.P, rtol=0, atol=1e-8)


@pytest.mark.parametrize("sigma", [2.0, 1.0, [5, 5, 5, 5, 1.5, 3.0]])
def test_matches_literal_reference(sigma):
    mdl = paper_numerical_model()
    rng = np.random.default_rng(7)
    f = MCKF(
        mdl.F,
        mdl.H,
        mdl.Q,
        mdl.R,
        np.zeros(4),
        20 * np.eye(4),
        sigma=sigma,
        eps=1e-9,
        max_iter=30,
        recovery=None,
    )
    for k in range(150):
        f.predict()
        xp, Pp = f.x.copy(), f.P.copy()
        z = rng.normal(size=2) * np.sqrt([10.0, 100.0])
        if k % 10 == 0:
            z[k % 20 // 10] += 40.0  # moderate outliers: weights small but not underflowing
        f.update(z)
        x_ref, P_ref, it_ref, w_ref = _mckf_reference(xp, Pp, mdl.H, mdl.R, z, sigma, 1e-9, 30)
        np.testing.assert_allclose(f.x, x_ref, rtol=1e-7, atol=1e-8)
        np.testing.assert_allclose(f.P, P_ref, rtol=1e-7, atol=1e-8)
        np.testing.assert_allclose(f.weights, w_ref, rtol=1e-6, atol=1e-12)
        assert f.n_iter == it_ref


def test_first_iteration_has_unit_state_weights():
    mdl = paper_numerical_model()
    f = MCKF(mdl.F, mdl.H, mdl.Q, mdl.R, np.zeros(4), np.eye(4), max_iter=1)
    f.predict()
    f.update([30.0, -5.0])
    assert f.n_iter == 1
    np.testing.assert_array_equal(f.weights_x, np.ones(4))


def test_kernel_underflow_is_guarded():
    mdl = paper_numerical_model()
    f = MCKF(mdl.F, mdl.H, mdl.Q, mdl.R, np.zeros(4), np.eye(4), recovery=None)
    f.predict()
    x_prior = f.x.copy()
    x0, P0 = f.x.copy(), f.P.copy()
    with np.errstate(over="ignore", invalid="ignore"):
        assert not f.update([1e300, -1e300])  # NIS overflows: treated as no fix
    np.testing.assert_array_equal(f.x, x0)
    np.testing.assert_array_equal(f.P, P0)
    for z in ([1e6, 1e6], [-1e12, 1e9], [1e6, 0.0]):
        assert f.update(z)
        assert np.all(np.isfinite(f.x)) and np.all(np.isfinite(f.P))
    # the first two fixes are fully rejected; the third one keeps the sane channel
    assert abs(f.x[0] - x_prior[0]) < 1e-6
    assert f.weights[0] == 0.0 and f.weights[1] > 0.5
    np.testing.assert_allclose(f.P, f.P.T, atol=1e-12)
    assert np.all(np.linalg.eigvalsh(f.P) > 0)


def test_sigma_validation_and_multikernel_inf_rows():
    mdl = paper_numerical_model()
    with pytest.raises(ValueError):
        MCKF(mdl.F, mdl.H, mdl.Q, mdl.R, sigma=[1.0, 2.0])
    with pytest.raises(ValueError):
        MCKF(mdl.F, mdl.H, mdl.Q, mdl.R, sigma=-1.0)
    # inf kernel on every row = least squares = the KF, exactly in one iteration pair
    a = MCKF(mdl.F, mdl.H, mdl.Q, mdl.R, sigma=np.inf)
    b = KF(mdl.F, mdl.H, mdl.Q, mdl.R)
    for z in ([3.0, 4.0], [100.0, -50.0]):
        a.predict()
        b.predict()
        a.update(z)
        b.update(z)
    np.testing.assert_allclose(a.x, b.x, atol=1e-12)
    np.testing.assert_allclose(a.P, b.P, atol=1e-12)


def _track(T, dt, jump_at=None, jump=0.0):
    t = np.arange(T) * dt
    pos = np.stack([3.0 * t, 1.0 * t], axis=1)
    if jump_at is not None:
        pos[jump_at:, 1] += jump  # a sudden displacement the model cannot predict
    return pos


@pytest.mark.parametrize("recovery", ["kf", "inflate"])
def test_lockout_recovery(recovery):
    dt, T = 0.05, 400
    mdl = motion_model("cv", 2, dt, q=0.01, r=0.25)
    truth = _track(T, dt, jump_at=100, jump=30.0)
    rng = np.random.default_rng(1)
    Z = truth + 0.5 * rng.standard_normal((T, 2))
    x0 = mdl.state(truth[0], [3.0, 1.0])
    stuck = MCKF(mdl.F, mdl.H, mdl.Q, mdl.R, x0, np.eye(4), recovery=None)
    rec = MCKF(mdl.F, mdl.H, mdl.Q, mdl.R, x0, np.eye(4), recovery=recovery, lockout_n=10)
    used = 0
    for k in range(T):
        for f in (stuck, rec):
            if k:
                f.predict()
            f.update(Z[k])
        used += rec.recovered
    assert used >= 1
    err_stuck = abs(stuck.x[2] - truth[-1, 1])
    err_rec = abs(rec.x[2] - truth[-1, 1])
    assert err_stuck > 10.0  # without recovery the filter coasts, rejecting every fix
    assert err_rec < 1.0


def test_adaptive_sigma_widens_only_under_persistent_mismatch():
    dt, T = 0.05, 600
    rng = np.random.default_rng(2)
    truth = _track(T, dt)
    mdl = motion_model("cv", 2, dt, q=0.1, r=1.0)
    x0 = mdl.state(truth[0], [3.0, 1.0])
    for true_std, expect_wide in ((1.0, False), (4.0, True)):
        Z = truth + true_std * rng.standard_normal((T, 2))
        Z[::50] += 500.0  # isolated outliers must not widen the kernel
        f = MCKF(mdl.F, mdl.H, mdl.Q, mdl.R, x0, np.eye(4), sigma=2.0, adaptive_sigma=True)
        for k in range(T):
            f.predict()
            f.update(Z[k])
        widened = f.sigma_k[-1] / 2.0
        assert (widened > 2.0) == expect_wide
        if not expect_wide:
            assert widened < 1.5
        np.testing.assert_array_equal(f.sigma, np.full(6, 2.0))  # nominal σ untouched


def test_mckf_beats_kf_on_impulsive_noise_and_costs_little_on_gaussian():
    mdl = paper_numerical_model()
    dt, T = 0.05, 2000
    t = np.arange(T) * dt
    truth = np.stack([2 * t, 10 * np.sin(0.1 * t)], axis=1)
    rng = np.random.default_rng(9)
    std = np.sqrt([10.0, 100.0])
    rmse = {}
    for case in ("gauss", "impulsive"):
        Z = truth + std * rng.standard_normal((T, 2))
        if case == "impulsive":
            hit = rng.random((T, 2)) < 0.1
            Z += hit * 20 * std * rng.standard_normal((T, 2))
        for name, f in (
            ("kf", KF(mdl.F, mdl.H, mdl.Q, mdl.R, np.zeros(4), 100 * np.eye(4))),
            ("mckf", MCKF(mdl.F, mdl.H, mdl.Q, mdl.R, np.zeros(4), 100 * np.eye(4))),
        ):
            se = 0.0
            for k in range(T):
                f.predict()
                f.update(Z[k])
                if k >= 200:
                    se += float(np.sum((f.x[[0, 2]] - truth[k]) ** 2))
                assert f.n_iter <= 10 if name == "mckf" else True
            rmse[case, name] = math.sqrt(se / (T - 200))
    assert rmse["impulsive", "mckf"] < 0.5 * rmse["impulsive", "kf"]
    assert rmse["gauss", "mckf"] < 1.2 * rmse["gauss", "kf"]


# ------------------------------------------------------------- the row functions, 3-D
def test_matches_literal_reference_3d():
    mdl = motion_model("cv", 3, 0.01, q=0.05, r=[1.0, 1.0, 0.04])
    rng = np.random.default_rng(3)
    f = MCKF(mdl.F, mdl.H, mdl.Q, mdl.R, np.zeros(6), 4 * np.eye(6), eps=1e-9, max_iter=30,
             recovery=None)
    for k in range(100):
        f.predict()
        xp, Pp = f.x.copy(), f.P.copy()
        z = rng.normal(size=3) * np.sqrt([1.0, 1.0, 0.04])
        if k % 7 == 0:
            z[k % 3] += 6.0
        f.update(z)
        x_ref, P_ref, it_ref, w_ref = _mckf_reference(xp, Pp, mdl.H, mdl.R, z, 2.0, 1e-9, 30)
        np.testing.assert_allclose(f.x, x_ref, rtol=1e-9, atol=1e-10)
        np.testing.assert_allclose(f.P, P_ref, rtol=1e-9, atol=1e-12)
        np.testing.assert_allclose(f.weights, w_ref, rtol=1e-9, atol=1e-14)
        assert f.n_iter == it_ref


def test_general_m_and_refused_floor():
    # m = 4: the rows' LAPACK inverse in place of the closed forms, still the spec's MCKF
    H = np.eye(4)
    R = np.diag([1.0, 2.0, 3.0, 4.0])
    f = MCKF(np.eye(4), H, 0.01 * np.eye(4), R, np.zeros(4), np.eye(4), eps=1e-9, max_iter=30)
    z = np.array([1.0, -2.0, 9.0, 0.5])
    f.update(z)
    x_ref, P_ref, it_ref, _ = _mckf_reference(np.zeros(4), np.eye(4), H, R, z, 2.0, 1e-9, 30)
    np.testing.assert_allclose(f.x, x_ref, atol=1e-10)
    assert f.n_iter == it_ref
    with pytest.raises(ValueError, match="kernel_floor"):
        MCKF(np.eye(4), H, 0.01 * np.eye(4), R, kernel_floor=0.0)


def test_inflate_recovery_keeps_the_covariance_bounded():
    dt, T = 0.05, 300
    mdl = motion_model("cv", 2, dt, q=0.01, r=0.25)
    truth = _track(T, dt, jump_at=100, jump=30.0)
    rng = np.random.default_rng(1)
    Z = truth + 0.5 * rng.standard_normal((T, 2))
    f = MCKF(mdl.F, mdl.H, mdl.Q, mdl.R, mdl.state(truth[0], [3.0, 1.0]), np.eye(4),
             recovery="inflate", lockout_n=10)
    rec, pmax = [], 0.0
    for k in range(T):
        if k:
            f.predict()
        f.update(Z[k])
        pmax = max(pmax, float(np.max(np.abs(f.P))))
        if f.recovered:
            rec.append(k)
    assert len(rec) == 1 and 109 <= rec[0] <= 125  # a few inflation steps after the lock-out
    assert pmax < 1e6  # α ≤ 1e12 and no compounding through P
    assert abs(f.x[2] - truth[-1, 1]) < 1.0
