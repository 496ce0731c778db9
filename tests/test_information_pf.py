"""Information-form KF, state-dependent-noise KF (kfuea eq 25), bootstrap particle filter."""

from __future__ import annotations

import math

import numpy as np
import pytest

from estimators.information import InformationKF, StateDependentNoiseKF, rls_solution
from estimators.kf import KF
from estimators.models import motion_model
from estimators.particle import ParticleFilter, effective_sample_size, systematic_resample


# ------------------------------------------------------------------------ information form
def test_information_kf_equals_kf():
    m = motion_model("ca", 2, 0.1, q=0.3, r=[2.0, 5.0])
    rng = np.random.default_rng(0)
    x0, P0 = rng.normal(size=6), np.diag(rng.uniform(0.5, 3.0, 6))
    a = InformationKF(m.F, m.H, m.Q, m.R, x0=x0, P0=P0)
    b = KF(m.F, m.H, m.Q, m.R, x0=x0, P0=P0)
    for k in range(200):
        z = None if k % 13 == 5 else rng.normal(size=2) * 4 + k * 0.1
        a.predict()
        b.predict()
        assert a.update(z) == b.update(z)
        np.testing.assert_allclose(a.x, b.x, rtol=0, atol=1e-9)
        np.testing.assert_allclose(a.P, b.P, rtol=0, atol=1e-9)
    np.testing.assert_allclose(a.K, b.K, atol=1e-9)
    assert a.nis == pytest.approx(b.nis, rel=1e-9)
    np.testing.assert_allclose(a.info_matrix @ a.P, np.eye(6), atol=1e-8)
    np.testing.assert_allclose(a.info_vector, np.linalg.solve(a.P, a.x), atol=1e-8)
    assert a.update([np.nan, 1.0]) is False


def test_rls_solution_is_the_kalman_correction():
    rng = np.random.default_rng(1)
    A = rng.normal(size=(4, 4))
    P = A @ A.T + np.eye(4)
    H = rng.normal(size=(2, 4))
    R = np.diag([0.5, 2.0])
    e = rng.normal(size=2)
    w = rls_solution(np.linalg.inv(P), H, np.linalg.inv(R), e)
    K = P @ H.T @ np.linalg.inv(H @ P @ H.T + R)
    np.testing.assert_allclose(w, K @ e, atol=1e-12)


# --------------------------------------------------------------------- state-dependent noise
def test_sdn_kf_without_state_term_is_kf_with_added_noise():
    m = motion_model("cv", 1, 0.1, q=0.2, r=1.0)
    D = np.array([[0.1], [0.3]])
    E = np.array([[0.7]])
    f = StateDependentNoiseKF(m.F, m.H, m.Q, m.R, D=D, E=E, x0=[1.0, 0.0])
    kf = KF(m.F, m.H, m.Q + D @ D.T, m.R + E @ E.T, x0=[1.0, 0.0])
    rng = np.random.default_rng(2)
    for _ in range(50):
        z = rng.normal(size=1)
        f.predict()
        kf.predict()
        f.update(z)
        kf.update(z)
    np.testing.assert_allclose(f.x, kf.x, atol=1e-12)
    np.testing.assert_allclose(f.P, kf.P, atol=1e-12)


def test_sdn_process_noise_is_eq_25():
    F = np.eye(2)
    Db = np.array([[0.2, 0.0], [0.1, 0.3]])
    Dx = np.array([[0.5], [0.0]])
    f = StateDependentNoiseKF(F, np.eye(2), 0.1 * np.eye(2), np.eye(2), D=Dx, Dbar=Db)
    x, P = np.array([2.0, -1.0]), np.array([[1.0, 0.2], [0.2, 0.5]])
    expect = 0.1 * np.eye(2) + Dx @ Dx.T + Db @ (P + np.outer(x, x)) @ Db.T
    np.testing.assert_allclose(f.process_noise(x, P), expect, atol=1e-15)
    f.x, f.P = x, P
    f.predict()
    np.testing.assert_allclose(f.P, P + expect, atol=1e-15)


def test_sdn_kf_is_consistent_where_the_plain_kf_is_overconfident():
    # x' = 0.95 x + w + 0.3 x b, y = x + v: multiplicative noise dominates for |x| ≫ 1
    rng = np.random.default_rng(5)
    a, c, q, r = 0.95, 0.3, 1.0, 4.0
    sdn = StateDependentNoiseKF([[a]], [[1.0]], [[q]], [[r]], Dbar=[[c]], x0=[0.0],
                                P0=[[100.0]])
    kf = KF([[a]], [[1.0]], [[q]], [[r]], x0=[0.0], P0=[[100.0]])
    x = 0.0
    nees_sdn, nees_kf, se_sdn, se_kf = [], [], [], []
    for k in range(3000):
        x = a * x + math.sqrt(q) * rng.standard_normal() + c * x * rng.standard_normal()
        z = [x + math.sqrt(r) * rng.standard_normal()]
        for f, nees, se in ((sdn, nees_sdn, se_sdn), (kf, nees_kf, se_kf)):
            f.predict()
            f.update(z)
            if k > 50:
                e = x - f.x[0]
                nees.append(e * e / f.P[0, 0])
                se.append(e * e)
    assert 0.7 < np.mean(nees_sdn) < 1.4
    assert np.mean(nees_kf) > 1.4  # measured 1.65 (1.9-3.7 for other seeds)
    assert np.mean(se_sdn) < np.mean(se_kf)


# ----------------------------------------------------------------------------- particle filter
def test_systematic_resample_counts():
    rng = np.random.default_rng(0)
    w = rng.dirichlet(np.ones(50))
    idx = systematic_resample(w, rng)
    counts = np.bincount(idx, minlength=50)
    assert counts.sum() == 50
    assert np.all(counts >= np.floor(50 * w) - 1e-9) and np.all(counts <= np.ceil(50 * w))
    assert effective_sample_size(np.full(10, 0.1)) == pytest.approx(10.0)


def test_pf_tracks_the_kf_on_a_linear_gaussian_model_and_is_seeded():
    m = motion_model("cv", 1, 0.1, q=0.5, r=0.5)
    x0, P0 = np.array([0.0, 1.0]), np.eye(2)
    rng = np.random.default_rng(7)
    Z = [np.array([0.1 * k + rng.normal() * 0.7]) for k in range(40)]

    def run(seed):
        pf = ParticleFilter.linear_gaussian(m.F, m.H, m.Q, m.R, x0, P0, n_particles=4000,
                                            rng=seed)
        for z in Z:
            pf.predict()
            pf.update(z)
        return pf

    kf = KF(m.F, m.H, m.Q, m.R, x0=x0, P0=P0)
    for z in Z:
        kf.predict()
        kf.update(z)
    pf = run(3)
    sd = np.sqrt(np.diag(kf.P))
    assert np.all(np.abs(pf.x - kf.x) < 0.15 * sd)
    np.testing.assert_allclose(np.sqrt(np.diag(pf.P)), sd, rtol=0.15)
    assert pf.n_resamples > 0
    np.testing.assert_array_equal(run(3).particles, pf.particles)
    assert not np.array_equal(run(4).particles, pf.particles)


def test_pf_resamples_only_below_ess_threshold_and_handles_bad_likelihoods():
    X = np.linspace(-1, 1, 100)[:, None]
    pf = ParticleFilter(lambda P, g: P, lambda z, P: -0.5 * ((z[0] - P[:, 0]) / 10.0) ** 2,
                        particles=X, rng=0)
    assert pf.update([0.0]) is True and not pf.resampled  # flat likelihood: ESS ≈ N
    pf.log_likelihood = lambda z, P: -0.5 * ((z[0] - P[:, 0]) / 0.05) ** 2
    assert pf.update([0.3]) is True and pf.resampled and pf.ess < 50
    assert abs(pf.x[0] - 0.3) < 0.05
    w0 = pf.logw.copy()
    pf.log_likelihood = lambda z, P: np.full(len(P), -np.inf)
    assert pf.update([0.0]) is False
    np.testing.assert_array_equal(pf.logw, w0)
    assert pf.update(None) is False


# --------------------------------------------------------------------------- Langevin experiment
def test_langevin_jacobians_and_short_run():
    from ag_uav.jobs.experiments import langevin as lg

    th = np.array([1.3, 5.2])
    eps = 1e-6
    num = np.column_stack([(lg.h(th + eps * e) - lg.h(th - eps * e)) / (2 * eps)
                           for e in np.eye(2)])
    np.testing.assert_allclose(lg.jac_h(th), num, atol=1e-7)
    num_f = np.column_stack([(lg.step_mean(th + eps * e, 0.01) - lg.step_mean(th - eps * e, 0.01))
                             / (2 * eps) for e in np.eye(2)])
    np.testing.assert_allclose(lg.jac_step(th, 0.01), num_f, atol=1e-7)
    s = lg.Setup(steps=300, particles=200)
    res = lg.one_run(s, 1.0, 0)
    assert res["if_diff"] < 1e-9
    for name in ("EKF", "SDN-EKF", "PF"):
        assert np.all(res["nrmse"][name] < 0.8 * res["nrmse"]["Meas"])
    assert lg.one_run(s, 1.0, 0)["nrmse"]["PF"] == pytest.approx(res["nrmse"]["PF"])
