"""KF, motion models, coloured-noise baselines and the registry."""

from __future__ import annotations

import math

import numpy as np
import pytest

import estimators
from estimators import KF, BiasAugmentedKF, DifferencingKF, make, motion_model
from estimators.models import (
    measurement_matrix,
    paper_numerical_model,
    process_noise,
    state_labels,
    transition,
)


# ---------------------------------------------------------------------------------- models
def test_paper_model_is_eq_8_to_11():
    mdl = paper_numerical_model()
    F = np.array([[1, 0.05, 0, 0], [0, 1, 0, 0], [0, 0, 1, 0.05], [0, 0, 0, 1.0]])
    np.testing.assert_array_equal(mdl.F, F)
    np.testing.assert_array_equal(mdl.H, [[1, 0, 0, 0], [0, 0, 1, 0]])
    np.testing.assert_array_equal(mdl.R, np.diag([10.0, 100.0]))
    np.testing.assert_allclose(np.diag(mdl.Q), [1.562e-5, 0.025, 1.562e-5, 0.025])
    # the 'paper' Q form is diag(q dt²/4, q): eq 9 up to its printed rounding
    Qp = process_noise("cv", 2, 0.05, 0.025, "paper")
    np.testing.assert_allclose(Qp, mdl.Q, rtol=1e-3)


def test_cv_ca_blocks_and_ordering():
    dt = 0.1
    F = transition("ca", 3, dt)
    assert F.shape == (9, 9)
    np.testing.assert_allclose(F[3:6, 3:6], [[1, dt, dt * dt / 2], [0, 1, dt], [0, 0, 1]])
    assert state_labels("cv", 3) == ["px", "vx", "py", "vy", "pz", "vz"]
    H = measurement_matrix("ca", 2)
    np.testing.assert_array_equal(np.nonzero(H)[1], [0, 3])
    # continuous white-acceleration Q: q [[dt³/3, dt²/2], [dt²/2, dt]]
    Q = process_noise("cv", 1, dt, 2.0)
    np.testing.assert_allclose(Q, 2.0 * np.array([[dt**3 / 3, dt**2 / 2], [dt**2 / 2, dt]]))
    # discrete white acceleration: q Γ Γᵀ with Γ = [dt²/2, dt]
    Qd = process_noise("cv", 1, dt, 2.0, "discrete")
    np.testing.assert_allclose(Qd, 2.0 * np.outer([dt**2 / 2, dt], [dt**2 / 2, dt]))
    # continuous Q is the integral of e^{Fs} G q Gᵀ e^{Fᵀs}: check by quadrature (CA)
    Qc = process_noise("ca", 1, dt, 3.0)
    s = np.linspace(0, dt, 2001)
    g = np.stack([s**2 / 2, s, np.ones_like(s)])
    integrand = 3.0 * g[:, None, :] * g[None, :, :]
    np.testing.assert_allclose(Qc, np.trapezoid(integrand, s, axis=2), rtol=1e-5, atol=1e-14)


def test_2d_alt_and_model_helpers():
    mdl = motion_model("cv", "2d+alt", 0.01, q=1.0, r=[2.0, 2.0, 5.0], q_alt=0.1)
    assert mdl.n == 6 and mdl.m == 3
    np.testing.assert_array_equal(np.diag(mdl.R), [2.0, 2.0, 5.0])
    assert mdl.Q[5, 5] == pytest.approx(0.1 * 0.01)
    assert mdl.Q[1, 1] == pytest.approx(1.0 * 0.01)
    x = mdl.state([1, 2, 3], [4, 5, 6])
    np.testing.assert_array_equal(x, [1, 4, 2, 5, 3, 6])
    np.testing.assert_array_equal(mdl.H @ x, [1, 2, 3])
    with pytest.raises(ValueError):
        motion_model("singer")
    with pytest.raises(ValueError):
        motion_model("cv", 4)


# ------------------------------------------------------------------------------------- KF
def _filterpy_kf(F, H, Q, R, x0, P0):
    filterpy = pytest.importorskip("filterpy.kalman")  # the oracle (a dev extra)
    f = filterpy.KalmanFilter(F.shape[0], H.shape[0])
    f.F, f.H, f.Q, f.R = F.copy(), H.copy(), Q.copy(), R.copy()
    f.x, f.P = x0.reshape(-1, 1).copy(), P0.copy()
    return f


@pytest.mark.parametrize("kind,dim", [("cv", 2), ("cv", 1), ("ca", 3), ("cv", "2d+alt")])
def test_kf_matches_filterpy(kind, dim):
    rng = np.random.default_rng(1)
    mdl = motion_model(
        kind,
        dim,
        0.05,
        q=0.5,
        r=rng.uniform(1, 10, size=3)[: 3 if dim != 1 else 1] if dim in (3, "2d+alt") else 4.0,
    )
    n, m = mdl.n, mdl.m
    x0 = rng.normal(size=n)
    A = rng.normal(size=(n, n))
    P0 = A @ A.T + np.eye(n)
    ours = KF(mdl.F, mdl.H, mdl.Q, mdl.R, x0, P0)
    ref = _filterpy_kf(mdl.F, mdl.H, mdl.Q, mdl.R, x0, P0)
    for k in range(300):
        ours.predict()
        ref.predict()
        if k % 7 == 3:
            continue  # no fix
        z = rng.normal(scale=5.0, size=m)
        assert ours.update(z)
        ref.update(z.reshape(-1, 1))
        np.testing.assert_allclose(ours.x, ref.x.ravel(), rtol=0, atol=1e-9)
        np.testing.assert_allclose(ours.P, ref.P, rtol=0, atol=1e-9)
        np.testing.assert_allclose(ours.K, ref.K, rtol=0, atol=1e-9)
        np.testing.assert_allclose(ours.y, ref.y.ravel(), rtol=0, atol=1e-9)
        np.testing.assert_allclose(ours.S, ref.S, rtol=0, atol=1e-9)
        assert ours.nis == pytest.approx(ref.mahalanobis**2, rel=1e-9)
    np.testing.assert_allclose(ours.P, ours.P.T, atol=1e-12)


def test_kf_settable_matrices_and_no_fix():
    mdl = paper_numerical_model()
    x0, P0 = np.array([1.0, 0.5, -2.0, 0.1]), 10 * np.eye(4)
    ours = KF(mdl.F, mdl.H, mdl.Q, mdl.R, x0, P0)
    ref = _filterpy_kf(mdl.F, mdl.H, mdl.Q, mdl.R, x0, P0)
    ours.R = np.diag([1.0, 2.0])
    ref.R = np.diag([1.0, 2.0])
    ours.Q = 2 * mdl.Q
    ref.Q = 2 * mdl.Q
    F2 = mdl.F.copy()
    F2[0, 1] = F2[2, 3] = 0.1
    ours.F = F2
    ref.F = F2
    for z in ([1.0, 2.0], [3.0, -1.0]):
        ours.predict()
        ref.predict()
        ours.update(z)
        ref.update(np.array(z).reshape(-1, 1))
    np.testing.assert_allclose(ours.x, ref.x.ravel(), atol=1e-12)
    np.testing.assert_allclose(ours.P, ref.P, atol=1e-12)
    x, P = ours.x.copy(), ours.P.copy()
    for bad in (None, [np.nan, 1.0], [1.0, np.inf], np.array([np.nan, np.nan])):
        assert ours.update(bad) is False
        np.testing.assert_array_equal(ours.x, x)
        np.testing.assert_array_equal(ours.P, P)
    with pytest.raises(ValueError):
        ours.R = np.eye(3)


# ---------------------------------------------------------------------- coloured baselines
def _cv_truth(T, dt, rng):
    """A smoothly manoeuvring 2-D track (positions and velocities)."""
    t = np.arange(T) * dt
    pos = np.stack([5 * t + 20 * np.sin(0.05 * t), 30 * np.cos(0.04 * t)], axis=1)
    return pos


def _ar1(T, m, rho, std, rng):
    v = np.empty((T, m))
    v[0] = std * rng.standard_normal(m)
    xi = std * math.sqrt(1 - rho * rho) * rng.standard_normal((T, m))
    for k in range(1, T):
        v[k] = rho * v[k - 1] + xi[k]
    return v


def test_bias_kf_reduces_to_kf_without_bias():
    mdl = motion_model("cv", 2, 0.05, q=1.0, r=2.0)
    x0 = np.array([0.0, 1.0, 0.0, -1.0])
    a = BiasAugmentedKF(mdl.F, mdl.H, mdl.Q, mdl.R, x0, np.eye(4), tau=10.0, sigma_b=1e-9, dt=0.05)
    b = KF(mdl.F, mdl.H, mdl.Q, mdl.R, x0, np.eye(4))
    rng = np.random.default_rng(3)
    for _ in range(200):
        a.predict()
        b.predict()
        z = rng.normal(size=2)
        a.update(z)
        b.update(z)
    np.testing.assert_allclose(a.x, b.x, atol=1e-7)
    np.testing.assert_allclose(a.P, b.P, atol=1e-7)
    assert a.x_aug.shape == (6,) and a.P_aug.shape == (6, 6)


def test_bias_states_reach_stationary_variance():
    mdl = motion_model("cv", 1, 0.01, q=1.0, r=1.0)
    f = BiasAugmentedKF(mdl.F, mdl.H, mdl.Q, mdl.R, tau=2.0, sigma_b=3.0, dt=0.01)
    f.kf.P[2, 2] = 0.0  # start certain; exact discretisation must bring it to σ_b² = 9
    for _ in range(5000):  # 50 s = 25 τ
        f.predict()
    assert f.P_aug[2, 2] == pytest.approx(9.0, rel=1e-6)


def _run(filt, Z, predicts_per_fix, truth):
    err = []
    nis = []
    for k in range(len(Z)):
        for _ in range(predicts_per_fix):
            filt.predict()
        if filt.update(Z[k]):
            nis.append(filt.nis)
        err.append(filt.x[[0, 2]] - truth[k])
    err = np.array(err[len(Z) // 5 :])
    return math.sqrt(np.mean(np.sum(err**2, axis=1))), float(np.mean(nis[len(nis) // 5 :]))


@pytest.mark.parametrize("std_w", [0.0, 0.3])
def test_coloured_filters_beat_white_kf_on_ar1_noise(std_w):
    dt_pred, ppf = 0.01, 5  # 100 Hz predict, 20 Hz fixes
    dt_fix = dt_pred * ppf
    T = 3000
    rng = np.random.default_rng(11)
    truth = _cv_truth(T, dt_fix, rng)
    tau, std_ar = 2.0, 2.0
    rho = math.exp(-dt_fix / tau)
    Z = truth + _ar1(T, 2, rho, std_ar, rng) + std_w * rng.standard_normal((T, 2))
    mdl = motion_model("cv", 2, dt_pred, q=2.0, r=std_ar**2 + std_w**2)
    x0 = mdl.state(truth[0], [5.0, 0.0])
    kf = KF(mdl.F, mdl.H, mdl.Q, mdl.R, x0, np.eye(4))
    rmse_kf, nis_kf = _run(kf, Z, ppf, truth)
    # a white-noise KF explains the slow error as motion: innovations far below their S
    assert nis_kf < 1.0
    bias = BiasAugmentedKF(
        mdl.F,
        mdl.H,
        mdl.Q,
        max(std_w, 1e-3) ** 2 * np.eye(2),
        x0,
        np.eye(4),
        tau=tau,
        sigma_b=std_ar,
        dt=dt_pred,
    )
    rmse_b, nis_b = _run(bias, Z, ppf, truth)
    assert 1.5 < nis_b < 2.5  # E[NIS] = m = 2 for a consistent filter
    assert rmse_b < rmse_kf
    if std_w == 0.0:  # differencing assumes purely AR(1) error
        diff = DifferencingKF(mdl.F, mdl.H, mdl.Q, mdl.R, x0, np.eye(4), tau=tau, dt=dt_pred)
        rmse_d, nis_d = _run(diff, Z, ppf, truth)
        assert 1.5 < nis_d < 2.5
        assert rmse_d < rmse_kf
        # Γ per fix interval gives the same filter as τ with regular fixes
        diffg = DifferencingKF(mdl.F, mdl.H, mdl.Q, mdl.R, x0, np.eye(4), gamma=rho)
        assert _run(diffg, Z, ppf, truth)[0] == pytest.approx(rmse_d, rel=1e-9)


def test_differencing_with_zero_gamma_is_the_kf():
    mdl = motion_model("cv", 2, 0.01, q=1.0, r=[2.0, 3.0])
    x0 = np.array([1.0, 2.0, 3.0, -1.0])
    d = DifferencingKF(mdl.F, mdl.H, mdl.Q, mdl.R, x0, 5 * np.eye(4), gamma=0.0)
    k = KF(mdl.F, mdl.H, mdl.Q, mdl.R, x0, 5 * np.eye(4))
    rng = np.random.default_rng(5)
    for i in range(400):
        d.predict()
        k.predict()
        if i % 5 == 0:
            z = None if i % 35 == 0 else rng.normal(size=2)
            d.update(z)
            k.update(z)
            np.testing.assert_allclose(d.x, k.x, atol=1e-9)
            np.testing.assert_allclose(d.P, k.P, atol=1e-9)


def test_differencing_matches_augmented_kf_for_pure_ar1():
    """Pure AR(1) GPS error: differencing is exact, so it must agree with the augmented KF
    whose white part is negligible (an independent route to the same posterior)."""
    dt_pred, ppf, tau = 0.01, 5, 1.5
    mdl = motion_model("cv", 2, dt_pred, q=1.0, r=4.0)
    rng = np.random.default_rng(2)
    T = 300
    truth = _cv_truth(T, dt_pred * ppf, rng)
    Z = truth + _ar1(T, 2, math.exp(-dt_pred * ppf / tau), 2.0, rng)
    x0 = mdl.state(truth[0], [5, 0])
    diff = DifferencingKF(mdl.F, mdl.H, mdl.Q, mdl.R, x0, np.eye(4), tau=tau, dt=dt_pred)
    aug = BiasAugmentedKF(
        mdl.F, mdl.H, mdl.Q, 1e-10 * np.eye(2), x0, np.eye(4), tau=tau, sigma_b=2.0, dt=dt_pred
    )
    for k in range(T):
        for _ in range(ppf):
            diff.predict()
            aug.predict()
        diff.update(Z[k])
        aug.update(Z[k])
    np.testing.assert_allclose(diff.x, aug.x, atol=1e-3)
    np.testing.assert_allclose(diff.P, aug.P, atol=1e-3, rtol=1e-3)


# ------------------------------------------------------------------------------- registry
def test_registry_builds_everything():
    assert set(estimators.available()) == {"kf", "mckf", "pca-kf", "pca-mckf", "kf-bias", "kf-diff"}
    extra = {"kf-bias": dict(tau=30.0, sigma_b=1.0), "kf-diff": dict(tau=30.0)}
    for name in estimators.available():
        f = make(name, model="cv", dim=2, dt=0.05, q=1.0, r=4.0, **extra.get(name, {}))
        assert f.x.shape == (4,) and f.P.shape == (4, 4)
        assert f.model is not None and list(f.model.pos_idx) == [0, 2]
        f.predict()
        assert f.update([1.0, 2.0])
        assert not f.update(None)
        assert np.all(np.isfinite(f.x))
    mdl = paper_numerical_model()
    f = make("mckf", F=mdl.F, H=mdl.H, Q=mdl.Q, R=mdl.R, sigma=3.0)
    np.testing.assert_array_equal(f.sigma, np.full(6, 3.0))
    assert f.model is None


def test_registry_errors():
    with pytest.raises(ValueError, match="kf, mckf, pca-kf"):
        make("ukf", model="cv")
    with pytest.raises(ValueError):
        make("kf")  # no model
    with pytest.raises(TypeError):
        make("kf", model="cv", sigma=2.0)  # not a KF parameter


@pytest.mark.parametrize("m", [1, 2, 3, 4])
def test_inv_small_closed_forms(m):
    from estimators.kf import inv_small

    rng = np.random.default_rng(m)
    for _ in range(20):
        A = rng.normal(size=(m, m))
        S = A @ A.T + 0.1 * np.eye(m)
        np.testing.assert_allclose(inv_small(S), np.linalg.inv(S), rtol=1e-10, atol=1e-12)
        B = rng.normal(size=(m, m)) + 3 * np.eye(m)  # not symmetric: general formula
        np.testing.assert_allclose(inv_small(B), np.linalg.inv(B), rtol=1e-10, atol=1e-12)


@pytest.mark.parametrize("m, cols", [(1, [2, 6, 7, 8]), (3, [0, 1, 2, 6, 7, 8]), (2, range(15))])
def test_joseph_is_the_product_form_for_any_gain_and_exactly_symmetric(m, cols) -> None:
    """joseph_row's expansion Pb − K Aᵀ − A Kᵀ + (K S) Kᵀ against the textbook product
    (I − K H) P (I − K H)ᵀ + K R Kᵀ, for the optimal gain and for another one (the MCKF's K̃),
    with a sparse H (its zeros skipped) and a dense one."""
    from estimators.kf import joseph

    rng = np.random.default_rng(m)
    A = rng.standard_normal((15, 15))
    P = A @ A.T / 15 + np.eye(15)
    P = 0.5 * (P + P.T)
    H = np.zeros((m, 15))
    H[:, list(cols)] = rng.standard_normal((m, len(list(cols))))
    B = rng.standard_normal((m, m))
    R = B @ B.T + 0.1 * np.eye(m)
    K_opt = P @ H.T @ np.linalg.inv(H @ P @ H.T + R)
    for K in (K_opt, K_opt * 0.7 + 0.01 * rng.standard_normal(K_opt.shape)):
        I_KH = np.eye(15) - K @ H
        want = I_KH @ P @ I_KH.T + K @ R @ K.T
        got = joseph(P, K, H, R)
        np.testing.assert_allclose(got, want, rtol=1e-12, atol=1e-12)
        assert np.array_equal(got, got.T)
