"""Bearing model, Gaussian-mixture noise, the planning cost, the PSO planner and the
bearing-tracking experiment end to end."""

from __future__ import annotations

import argparse
import csv
import math
from dataclasses import replace

import numpy as np
import pytest

from ag_uav.jobs.experiments import bearing_tracking as bt
from estimators.bearing import (
    BearingModel,
    angle_residual,
    bearing,
    mixture_noise,
    residual_with_angles,
    trace_after_update,
    trace_cost,
    wrap_angle,
)

MODEL = BearingModel(8, (0, 2), [(0.0, 925.0), (200.0, 1050.0)], [(4, 6)])


def test_wrap_angle():
    assert wrap_angle(math.pi) == pytest.approx(math.pi)
    assert wrap_angle(-math.pi) == pytest.approx(math.pi)
    assert wrap_angle(3 * math.pi) == pytest.approx(math.pi)
    assert wrap_angle(2 * math.pi + 0.1) == pytest.approx(0.1)
    a = np.array([-7.0, -math.pi, -3.0, 0.0, 3.0, math.pi, 7.0])
    w = wrap_angle(a)
    assert np.all(w > -math.pi) and np.all(w <= math.pi)
    np.testing.assert_allclose(np.cos(w), np.cos(a), atol=1e-12)
    np.testing.assert_allclose(np.sin(w), np.sin(a), atol=1e-12)
    # residuals across the cut are small
    assert angle_residual(-math.pi + 0.01, math.pi - 0.01) == pytest.approx(0.02)
    r = residual_with_angles([True, False])(np.array([3.1, 10.0]), np.array([-3.1, 2.0]))
    np.testing.assert_allclose(r, [6.2 - 2 * math.pi, 8.0])


def test_bearing_is_four_quadrant():
    src = np.zeros(2)
    for ang in (0.3, 2.0, -2.5, -0.4):
        assert bearing(src, [math.cos(ang), math.sin(ang)]) == pytest.approx(ang)


def test_jacobian_matches_finite_differences_and_eq_11():
    rng = np.random.default_rng(0)
    for _ in range(5):
        x = rng.normal(0.0, 500.0, 8)
        H = MODEL.jacobian(x)
        num = np.zeros_like(H)
        for j in range(8):
            e = np.zeros(8)
            e[j] = 1e-4
            num[:, j] = angle_residual(MODEL.h(x + e), MODEL.h(x - e)) / 2e-4
        np.testing.assert_allclose(H, num, rtol=1e-6, atol=1e-10)
        # eq 11, anchor row: (η_b − η_u)/d², (ξ_u − ξ_b)/d² on the UAV position
        b = np.array([0.0, 925.0])
        d2 = (x[0] - b[0]) ** 2 + (x[2] - b[1]) ** 2
        assert H[0, 0] == pytest.approx((b[1] - x[2]) / d2)
        assert H[0, 2] == pytest.approx((x[0] - b[0]) / d2)
        assert np.all(H[:, [1, 3, 5, 7]] == 0.0)
    X = rng.normal(0.0, 500.0, (6, 8))
    np.testing.assert_allclose(MODEL.h(X), np.array([MODEL.h(x) for x in X]), atol=1e-15)
    np.testing.assert_allclose(MODEL.jacobian(X), np.array([MODEL.jacobian(x) for x in X]),
                               atol=1e-15)


def test_trace_after_update_is_the_joseph_trace():
    rng = np.random.default_rng(1)
    for m in (1, 2, 3, 4):
        A = rng.normal(size=(6, 6))
        P = A @ A.T + np.eye(6)
        H = rng.normal(size=(5, m, 6))
        Rm = np.diag(rng.uniform(0.1, 1.0, m))
        got = trace_after_update(P, H, Rm)
        for k in range(5):
            S = H[k] @ P @ H[k].T + Rm
            K = P @ H[k].T @ np.linalg.inv(S)
            IKH = np.eye(6) - K @ H[k]
            assert got[k] == pytest.approx(np.trace(IKH @ P @ IKH.T + K @ Rm @ K.T), rel=1e-10)
    # reduced columns and batches of priors agree with the full form
    x = rng.normal(0.0, 400.0, (3, 8))
    A = rng.normal(size=(3, 8, 8))
    P = A @ A.transpose(0, 2, 1) + np.eye(8)
    lam = rng.uniform(-20, 20, (3, 7, 2))
    Hr, _ = MODEL.observer_jacobian(x[:, None, [0, 2]] + lam, x)
    got = trace_cost(P, 0.1 * np.eye(3), MODEL.columns)(Hr)
    for b in range(3):
        X = np.repeat(x[b][None], 7, 0)
        X[:, [0, 2]] += lam[b]
        ref = trace_after_update(P[b], MODEL.jacobian(X), 0.1 * np.eye(3))
        np.testing.assert_allclose(got[b], ref, rtol=1e-10)


def test_mixture_noise_statistics_and_determinism():
    v = mixture_noise(np.random.default_rng(3), 400_000)
    # variance of (1 − ϑ) N(0, 0.01) + ϑ N(0, 0.1): 0.9·0.01 + 0.1·0.1 = 0.019
    assert v.var() == pytest.approx(0.019, rel=0.02)
    # heavy tail: P(|v| > 0.5) = 0.9·2Φ(−5) + 0.1·2Φ(−0.5/√0.1) ≈ 0.01139
    p = 0.9 * math.erfc(5 / math.sqrt(2)) + 0.1 * math.erfc(0.5 / math.sqrt(0.2))
    assert np.mean(np.abs(v) > 0.5) == pytest.approx(p, rel=0.06)
    kurt = np.mean(v**4) / v.var() ** 2
    assert kurt > 5.0  # a Gaussian has 3
    a = mixture_noise(np.random.default_rng(9), (5, 3))
    np.testing.assert_array_equal(a, mixture_noise(np.random.default_rng(9), (5, 3)))


# ---------------------------------------------------------------------------- PSO planning
def test_pso_plan_is_deterministic_and_beats_standing_still():
    s = bt.Setup()
    F, Q = s.F(), s.Q()
    xb = F @ np.array(s.x0_hat)
    Pb = F @ np.diag(s.p0_diag) @ F.T + Q
    Rp = s.plan_r * np.eye(3)
    lam1, c1 = bt.plan_waypoint(MODEL, xb, Pb, Rp, s, np.random.default_rng(5))
    lam2, c2 = bt.plan_waypoint(MODEL, xb, Pb, Rp, s, np.random.default_rng(5))
    np.testing.assert_array_equal(lam1, lam2)
    assert np.all(np.abs(lam1) <= s.step_max)
    cost = bt.plan_cost(MODEL, xb, Pb, Rp)
    assert c1 == pytest.approx(float(cost(lam1[None])[0]))
    assert c1 < float(cost(np.zeros((1, 2)))[0])
    # a brute-force grid over the box finds nothing clearly better
    g = np.linspace(-s.step_max, s.step_max, 41)
    grid = np.stack(np.meshgrid(g, g), -1).reshape(-1, 2)
    assert c1 <= cost(grid).min() + 1e-3 * (np.trace(Pb) - cost(grid).min())


def test_standoff_keeps_the_uav_away_from_an_anchor():
    s = replace(bt.Setup(), standoff=50.0)
    F, Q = s.F(), s.Q()
    x = np.array([30.0, 0.0, 925.0 + 25.0, 0.0, 300.0, 0.3, 700.0, 0.3])  # 39 m from b₁
    xb = F @ x
    Pb = F @ np.diag(s.p0_diag) @ F.T + Q
    lam, _ = bt.plan_waypoint(MODEL, xb, Pb, s.plan_r * np.eye(3), s,
                              np.random.default_rng(0))
    new = xb[[0, 2]] + lam
    assert np.hypot(new[0] - 0.0, new[1] - 925.0) >= 50.0
    # without the standoff the same plan goes closer (the trace rewards proximity)
    lam0, _ = bt.plan_waypoint(MODEL, xb, Pb, s.plan_r * np.eye(3), replace(s, standoff=0.0),
                               np.random.default_rng(0))
    new0 = xb[[0, 2]] + lam0
    assert np.hypot(new0[0], new0[1] - 925.0) < 50.0


def test_planned_path_reduces_the_covariance_trace_vs_the_fixed_path():
    s = replace(bt.Setup(), steps=40, methods=("EKF", "EKF-PSO"), pso_iters=3)
    out = bt.run_one((s, 0, True))["methods"]
    fixed, planned = out["EKF"], out["EKF-PSO"]
    assert planned["trace"][-1] < 0.5 * fixed["trace"][-1]
    assert planned["trace"].mean() < fixed["trace"].mean()
    # the planned UAV really moved differently; the target path is shared
    assert not np.allclose(planned["truth"][:, 0], fixed["truth"][:, 0])
    np.testing.assert_array_equal(planned["truth"][:, 4:], fixed["truth"][:, 4:])


def test_runs_are_seeded_and_common_random_numbers():
    s = replace(bt.Setup(), steps=12, pso_iters=2)
    a = bt.run_one((s, 3, False))
    b = bt.run_one((s, 3, False))
    c = bt.run_one((s, 4, False))
    for m in s.methods:
        np.testing.assert_array_equal(a["methods"][m]["rmse"], b["methods"][m]["rmse"])
        assert not np.array_equal(a["methods"][m]["rmse"], c["methods"][m]["rmse"])


def test_experiment_end_to_end_writes_outputs(tmp_path, capsys):
    p = argparse.ArgumentParser()
    bt.add_arguments(p)
    args = p.parse_args(["--runs", "2", "--steps", "15", "--pso-iters", "2", "--workers", "1",
                         "--quiet", "--out", str(tmp_path)])
    assert bt.main(args) == 0
    for name in ("results.csv", "table.csv", "table.md", "bearing_tracking.png"):
        assert (tmp_path / name).stat().st_size > 0
    rows = list(csv.DictReader(open(tmp_path / "table.csv")))
    assert [r["method"] for r in rows] == list(bt.METHODS)
    assert all(float(r["target_xi"]) > 0 for r in rows)
    assert float(rows[0]["target_xi_paper"]) == pytest.approx(44.26)
    assert len(list(csv.DictReader(open(tmp_path / "results.csv")))) == 2 * len(bt.METHODS)
    out = capsys.readouterr().out
    assert "Table IV" in out and "MCEP" in out


def test_experiment_is_registered_with_the_cli():
    from ag_uav.cli import build_parser

    args = build_parser().parse_args(["experiment", "bearing-tracking", "--runs", "3"])
    assert args.runs == 3 and args.func is bt.main
