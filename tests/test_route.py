"""Route-constrained KF (Zhou et al.), innovation gates, Singer model, PSO-tuned R."""

from __future__ import annotations

import math

import numpy as np
import pytest

from estimators.kf import KF
from estimators.models import motion_model
from estimators.pso_r import (
    innovation_nll,
    kf_fitness_batch,
    posterior_residual,
    r_from_params,
    tune_r,
)
from estimators.route import Route, RouteConstrainedKF, chi2_gate, paper_gate, singer_model


# ------------------------------------------------------------------------------------ Singer
def test_singer_closed_form_and_ca_limit():
    dt, lam, sa = 0.1, 0.7, 0.4
    F, Q = singer_model(dt, lam, sa, dim=2)
    a = lam * dt
    # closed form (Singer 1970): Φ[0, 2] = (a − 1 + e^{−a}) / λ², Φ[1, 2] = (1 − e^{−a}) / λ
    assert F[0, 2] == pytest.approx((a - 1 + math.exp(-a)) / lam**2, rel=1e-10)
    assert F[1, 2] == pytest.approx((1 - math.exp(-a)) / lam, rel=1e-10)
    assert F[2, 2] == pytest.approx(math.exp(-a), rel=1e-12)
    np.testing.assert_allclose(Q, Q.T, atol=0)
    assert np.all(np.linalg.eigvalsh(Q) > -1e-15)
    # Q[2,2] = σ_a² (1 − e^{−2a}): the stationary acceleration variance is σ_a²
    assert Q[2, 2] == pytest.approx(sa**2 * (1 - math.exp(-2 * a)), rel=1e-9)
    assert np.all(F[:3, 3:] == 0) and np.all(Q[:3, 3:] == 0)
    # λ → 0 with 2λσ_a² = q fixed: the white-jerk CA model
    q, lam0 = 0.3, 1e-6
    F0, Q0 = singer_model(dt, lam0, math.sqrt(q / (2 * lam0)), dim=1)
    ca = motion_model("ca", 1, dt, q=q)
    np.testing.assert_allclose(F0, ca.F, atol=1e-6)
    np.testing.assert_allclose(Q0, ca.Q, rtol=1e-4, atol=1e-12)


# ------------------------------------------------------------------------------------- route
def test_locate_along_track_handles_minus_x_and_y_legs():
    # leg 1 runs in −x, leg 2 along +y: the paper's x-range rule (x_a ≤ x ≤ x_b) fails on both
    rt = Route([[10.0, 0.0], [0.0, 0.0], [0.0, 10.0]])
    assert rt.locate([6.0, 0.1]) == 0
    assert rt.locate([0.1, 6.0]) == 1
    assert rt.locate([0.0, 0.0]) == 1  # at the corner: ties go to the later segment
    # monotone progress: passes the end of leg 0 → leg 1, never back
    assert rt.locate([-0.5, 0.2], hint=0) == 1
    assert rt.locate([5.0, 0.0], hint=1) == 1
    assert rt.along(0, [4.0, 3.0]) == pytest.approx(6.0)
    np.testing.assert_allclose(np.abs(rt.cross(0, [4.0, 3.0])), [3.0])
    np.testing.assert_allclose(rt.point_at(15.0), [0.0, 5.0])


def test_route_3d_normals_and_rotation():
    rt = Route([[0, 0, -10], [8, 8, -10], [16, 0, -10], [16, 0, -10]])  # duplicate dropped
    assert rt.n_segments == 2
    for i in range(2):
        N = rt.normals[i]
        np.testing.assert_allclose(N @ N.T, np.eye(2), atol=1e-12)
        np.testing.assert_allclose(N @ rt.dirs[i], 0.0, atol=1e-12)
        Rm = rt.turn_rotation(0)
    np.testing.assert_allclose(Rm @ rt.dirs[0], rt.dirs[1], atol=1e-12)
    np.testing.assert_allclose(Rm.T @ Rm, np.eye(3), atol=1e-12)
    assert np.linalg.det(Rm) == pytest.approx(1.0)
    with pytest.raises(ValueError):
        Route([[0, 0], [0, 0]])


def _cv2(dt=0.1, q=0.5, r=1.0):
    return motion_model("cv", 2, dt, q=q, r=r)  # state [px, vx, py, vy]


def test_virtual_measurement_pulls_estimate_onto_the_line():
    m = _cv2()
    rt = Route([[0.0, 0.0], [20.0, 0.0]])
    f = RouteConstrainedKF(m.F, m.H, m.Q, m.R, rt, [0, 2], [1, 3], r_virtual=1e-6,
                           x0=[5.0, 1.0, 2.0, 0.0], P0=np.eye(4))
    assert f.update(None) is False
    assert f.last == "virtual"
    assert abs(f.x[2]) < 1e-4  # cross-track removed
    assert f.x[0] == pytest.approx(5.0)  # along-track untouched (P isotropic, no correlation)
    assert f.P[2, 2] < 1e-5 and f.P[0, 0] == pytest.approx(1.0)
    # a real fix is fused as by the KF
    kf = KF(m.F, m.H, m.Q, m.R, x0=f.x, P0=f.P)
    f.predict()
    kf.predict()
    assert f.update([6.0, 0.3]) is True and f.last == "fix"
    kf.update([6.0, 0.3])
    np.testing.assert_allclose(f.x, kf.x, atol=1e-12)


def test_without_virtual_and_gate_it_is_the_kf():
    m = _cv2()
    rng = np.random.default_rng(3)
    x0, P0 = np.zeros(4), np.eye(4) * 4
    f = RouteConstrainedKF(m.F, m.H, m.Q, m.R, [[0, 0], [1, 1]], [0, 2], virtual="never",
                           x0=x0, P0=P0)
    kf = KF(m.F, m.H, m.Q, m.R, x0=x0, P0=P0)
    for k in range(60):
        z = None if k % 7 == 3 else rng.normal(size=2) * 3
        f.predict()
        kf.predict()
        assert f.update(z) == kf.update(z)
    np.testing.assert_allclose(f.x, kf.x, atol=1e-12)
    np.testing.assert_allclose(f.P, kf.P, atol=1e-12)


def test_chi2_and_paper_gates():
    S = 2.0 * np.eye(2)
    good, bad = np.array([1.0, -1.0]), np.array([6.0, 6.0])
    thr_p = 0.9999
    for nu in (good, bad):
        nis = float(nu @ np.linalg.solve(S, nu))
        from scipy.stats import chi2

        # with S = s·I and χ = 1/χ²_m(p) the two tests coincide
        assert chi2_gate(nis, 2, thr_p) == paper_gate(nu, S, 1.0 / chi2.ppf(thr_p, 2))
    assert chi2_gate(float(good @ np.linalg.solve(S, good)), 2, thr_p)
    assert not chi2_gate(float(bad @ np.linalg.solve(S, bad)), 2, thr_p)
    # anisotropic S: the paper's test only sees the largest variance and passes an innovation
    # that is 40 σ out in the well-determined direction
    S2 = np.diag([100.0, 0.01])
    nu = np.array([0.0, 4.0])
    chi = 1.0 / 18.4
    assert paper_gate(nu, S2, chi)
    assert not chi2_gate(float(nu @ np.linalg.solve(S2, nu)), 2, thr_p)


def test_gate_rejects_outliers_and_recovers_after_lockout():
    m = _cv2()
    f = RouteConstrainedKF(m.F, m.H, m.Q, m.R, [[0, 0], [100, 0]], [0, 2], gate="chi2",
                           recover_after=3, x0=np.zeros(4), P0=np.eye(4))
    x_before = f.x.copy()
    assert f.update([50.0, 50.0]) is False
    assert f.last == "fix-rejected"
    np.testing.assert_array_equal(f.x, x_before)
    assert f.update([0.5, -0.2]) is True
    for _ in range(3):
        assert f.update([50.0, 50.0]) is False
    assert f.update([50.0, 50.0]) is True  # forced through after 3 rejections
    assert f.rejected_fixes == 4
    pg = RouteConstrainedKF(m.F, m.H, m.Q, m.R, [[0, 0], [100, 0]], [0, 2], gate="paper",
                            x0=np.zeros(4), P0=np.eye(4))
    assert pg.update([50.0, 50.0]) is False and pg.update([0.5, -0.2]) is True


@pytest.mark.parametrize("turn", ["project", "rotate"])
def test_prediction_through_a_right_angle_turn(turn):
    dt = 0.05
    m = motion_model("cv", 2, dt, q=1e-4, r=1.0)
    rt = Route([[0.0, 0.0], [10.0, 0.0], [10.0, 10.0]])
    f = RouteConstrainedKF(m.F, m.H, m.Q, m.R, rt, [0, 2], [1, 3], turn=turn, r_virtual=1e-4,
                           x0=[8.0, 1.0, 0.0, 0.0], P0=np.diag([0.01, 0.001, 0.01, 0.001]))
    for _ in range(int(6.0 / dt)):  # 6 s at 1 m/s: 2 m to the corner, then 4 m up the leg
        f.predict()
        f.update(None)
    assert f.segment == 1
    assert abs(f.x[0] - 10.0) < 0.05  # on the second leg's line
    if turn == "rotate":
        assert f.x[2] == pytest.approx(4.0, abs=0.1)  # flew the turn at 1 m/s
        assert f.x[3] == pytest.approx(1.0, abs=0.02)
    else:  # velocity normal to the new leg is removed: v·cos 90° = 0, the estimate stalls
        assert abs(f.x[2]) < 0.5
        assert abs(f.x[1]) < 0.05


# ------------------------------------------------------------------------------------ PSO-R
def _cv_data(seed=0, T=300, r_true=0.25, q=0.2, dt=0.1):
    rng = np.random.default_rng(seed)
    m = motion_model("cv", 1, dt, q=q, r=r_true)
    x = np.array([0.0, 1.0])
    Lq = np.linalg.cholesky(m.Q)
    Z = np.empty((T, 1))
    for k in range(T):
        x = m.F @ x + Lq @ rng.standard_normal(2)
        Z[k] = x[0] + math.sqrt(r_true) * rng.standard_normal()
    return m, Z


def test_batched_fitness_matches_library_kf():
    m, Z = _cv_data(T=80)
    x0, P0 = np.array([0.0, 1.0]), np.eye(2)
    Rs = r_from_params(np.array([[-1.0], [0.3]]), [[0]], 1)
    out = kf_fitness_batch(m.F, m.H, m.Q, Rs, Z, x0, P0)
    for b in range(2):
        kf = KF(m.F, m.H, m.Q, Rs[b], x0=x0, P0=P0)
        assert out["nll"][b] == pytest.approx(innovation_nll(kf, Z), rel=1e-9, abs=1e-9)
        kf2 = KF(m.F, m.H, m.Q, Rs[b], x0=x0, P0=P0)
        assert out["paper"][b] == pytest.approx(posterior_residual(kf2, Z), rel=1e-9)
        np.testing.assert_allclose(out["x"][b], kf.x, atol=1e-9)


def test_pso_recovers_r_and_paper_fitness_collapses_to_lower_bound():
    m, Z = _cv_data(seed=1, T=400, r_true=0.25)
    x0, P0 = np.array([0.0, 1.0]), np.eye(2)
    res = tune_r(m.F, m.H, m.Q, Z, x0, P0, [[0]], -3.0, 2.0, pop=8, iters=10, rng=4)
    assert 10 ** res.theta[0] == pytest.approx(0.25, rel=0.35)
    assert not res.at_bound
    again = tune_r(m.F, m.H, m.Q, Z, x0, P0, [[0]], -3.0, 2.0, pop=8, iters=10, rng=4)
    np.testing.assert_array_equal(res.theta, again.theta)  # seeded: deterministic
    bad = tune_r(m.F, m.H, m.Q, Z, x0, P0, [[0]], -3.0, 2.0, fitness="paper", pop=8,
                 iters=10, rng=4)
    assert bad.at_bound and bad.theta[0] < -2.9
    with pytest.raises(ValueError):
        tune_r(m.F, m.H, m.Q, Z, x0, P0, [[0]], -3.0, 2.0, fitness="rmse")


# ------------------------------------------------------------------------------- experiment
def test_route_prediction_experiment_smoke(tmp_path):
    import argparse

    from ag_uav.jobs.experiments import route_prediction as rp

    p = argparse.ArgumentParser()
    rp.add_arguments(p)
    args = p.parse_args(["--runs", "1", "--pso-iters", "2", "--out", str(tmp_path)])
    assert rp.main(args) == 0
    for f in ("results.csv", "summary.csv", "errors.csv", "route_prediction.png"):
        assert (tmp_path / f).exists()
    rows = list(__import__("csv").DictReader((tmp_path / "summary.csv").open()))
    by = {r["filter"]: r for r in rows}
    # past the corner, the route + turn rotation beats the unconstrained KF by far
    assert float(by["PSO-CKF + turn"]["err_9s"]) < 0.3 * float(by["KF"]["err_9s"])
    assert float(by["KF"]["err_9s"]) > 5.0


def test_locate_advances_when_a_corner_is_cut():
    rt = Route([[0.0, 0.0], [10.0, 0.0], [10.0, 10.0]])
    # a filleted corner: never past x = 10 on leg 0, but already nearer leg 1
    assert rt.along(0, [9.5, 1.0]) < rt.lengths[0]
    assert rt.locate([9.5, 1.0], hint=0) == 1
    assert rt.locate([5.0, 0.5], hint=0) == 0


# ------------------------------------------------------------------------------ mission side
def test_route_feedback_bridges_an_outage_along_the_plan(tmp_path):
    from ag_uav.config import load_config
    from ag_uav.jobs.batch import write_rect_field
    from ag_uav.navigation.route import ROUTE_NAME, OutageGps, RouteConstrainedFeedback, plan_for

    fld = write_rect_field(tmp_path / "f.geojson", 60.0, 24.0)
    cfg = load_config(None, {"mission.field": str(fld), "gps.preset": "sbas",
                             "estimator.name": "true", "estimator.shadow": ["kf"]})
    plan = plan_for(cfg)
    fb = RouteConstrainedFeedback.for_config(cfg, plan=plan, outages=[(4.0, 9.0)])
    assert isinstance(fb.gps, OutageGps) and fb.gps.in_outage(5.0) and not fb.gps.in_outage(9.0)
    rt = Route(plan.path)
    dt, v, alt = 1.0 / cfg.sim.control_hz, 3.0, cfg.mission.altitude_m
    for k in range(int(12.0 / dt)):
        t = k * dt
        s = v * t
        p = rt.point_at(s)
        i = rt.locate(p)
        vel = v * rt.dirs[i]
        fb.update(t, (float(p[0]), float(p[1]), alt), (float(vel[0]), float(vel[1]), 0.0))
    assert fb.n_virtual > 400 and fb.n_virtual_rejected == 0  # ~4.5 s of 100 Hz constraints
    assert len(fb.est[ROUTE_NAME]) == len(fb.est["kf"])
    # on the plan the bridged estimate stays on the path and follows it
    e = np.asarray(fb.est[ROUTE_NAME][-1][:2]) - rt.point_at(v * (int(12.0 / dt) - 1) * dt)
    assert np.hypot(*e) < 3.0
    assert fb.summary()["route_virtual_updates"] == fb.n_virtual
