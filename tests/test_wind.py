"""Tests for ag_uav.world.wind: Dryden turbulence (MIL-F-8785C), mean wind, drag."""

from __future__ import annotations

import math

import numpy as np
import pytest
from oracles.wind_ref import WindRef, milspec
from scipy.linalg import expm

from ag_uav.world.wind import (
    KNOT,
    DrydenTurbulence,
    Wind,
    _second_order_coeffs,
    drag_force,
    dryden_parameters,
)


def _run(turb: DrydenTurbulence, n: int, dt: float, h: float, v: float) -> np.ndarray:
    return np.array([turb.step(dt, h, v) for _ in range(n)])


def _acf(x: np.ndarray, lag: int) -> float:
    x = x - x.mean()
    return float(np.dot(x[:-lag], x[lag:]) / np.dot(x, x))


# ------------------------------------------------------------------ MIL-F-8785C parameters


def test_dryden_parameters_follow_milspec_in_feet():
    w20 = 10.0
    for h_m in (3.0, 10.0, 50.0, 200.0):
        h_ft = h_m / 0.3048
        base = 0.177 + 0.000823 * h_ft
        su, sw, lu, lw, h_used = dryden_parameters(w20, h_m)
        assert h_used == pytest.approx(h_m)
        assert sw == pytest.approx(1.0)  # 0.1 * W20
        assert su == pytest.approx(1.0 / base**0.4)
        assert lw == pytest.approx(h_m)  # L_w = h
        assert lu == pytest.approx(h_ft / base**1.2 * 0.3048)
    # at 1000 ft the denominators are 1: L_u = L_w = h, sigma_u = sigma_w
    su, sw, lu, lw, _ = dryden_parameters(w20, 304.8)
    assert su == pytest.approx(sw, rel=1e-3) and lu == pytest.approx(lw, rel=1e-3)


def test_altitude_clamped_to_3m_and_1000ft():
    assert dryden_parameters(5.0, 0.0) == dryden_parameters(5.0, 3.0)
    assert dryden_parameters(5.0, 5000.0) == dryden_parameters(5.0, 304.8)


# ------------------------------------------------------------------ exact discretisation


@pytest.mark.parametrize("theta", [1e-6, 1e-3, 0.05, 0.7, 3.0])
def test_second_order_discretisation_matches_van_loan(theta):
    f11, f12, f21, f22, l11, l21, l22 = _second_order_coeffs(theta)
    F = np.array([[f11, f12], [f21, f22]])
    L = np.array([[l11, 0.0], [l21, l22]])
    # stationary covariance of the normalised state is I
    np.testing.assert_allclose(F @ F.T + L @ L.T, np.eye(2), atol=1e-14)
    # compare with Van Loan's method on the forming filter (1 + sqrt3 s)/(1+s)^2 (time unit L/V)
    A = np.array([[0.0, 1.0], [-1.0, -2.0]])
    B = np.array([[0.0], [1.0]])
    M = np.block([[-A, B @ B.T], [np.zeros((2, 2)), A.T]]) * theta
    E = expm(M)
    phi = E[2:, 2:].T
    qd = phi @ E[:2, 2:]
    S = np.diag([2.0, 2.0])  # scaling to unit stationary variance (P_inf = I/4 for p = 1)
    np.testing.assert_allclose(S @ phi @ np.linalg.inv(S), F, atol=1e-12)
    np.testing.assert_allclose(S @ qd @ S.T, L @ L.T, rtol=1e-8, atol=1e-300)


def test_tiny_step_noise_is_accurate():
    theta = 1e-7
    *_, l11, l21, l22 = _second_order_coeffs(theta)
    assert l11**2 == pytest.approx(4.0 / 3.0 * theta**3, rel=1e-5)
    assert l22**2 == pytest.approx(theta, rel=1e-5)


# ------------------------------------------------------------------ statistics


@pytest.mark.parametrize(
    "h, v, dt",
    [(3.0, 10.0, 0.1), (3.0, 0.0, 1.0), (30.0, 8.0, 0.5)],
)
def test_dryden_stationary_std(h, v, dt):
    turb = DrydenTurbulence(8.0, np.random.default_rng(11))
    x = _run(turb, 150_000, dt, h, v)
    su, sv, sw = turb.sigmas(h)
    std = x.std(axis=0)
    assert std[0] == pytest.approx(su, rel=0.10)
    assert std[1] == pytest.approx(sv, rel=0.10)
    assert std[2] == pytest.approx(sw, rel=0.10)
    assert abs(x.mean(axis=0)).max() < 0.1 * su


def test_dryden_autocorrelation_at_scale_length():
    h, v, lag = 3.0, 10.0, 10
    _, _, l_u, l_w, _ = dryden_parameters(1.0, h)
    # dt chosen so that `lag` steps = L_u / V
    x = _run(DrydenTurbulence(8.0, np.random.default_rng(5)), 150_000, l_u / v / lag, h, v)
    # longitudinal: exp(-tau V / L) = e^-1; lateral (L_v = L_u): exp(-s)(1 - s/2) at s = 1
    assert _acf(x[:, 0], lag) == pytest.approx(math.exp(-1.0), abs=0.04)
    assert _acf(x[:, 1], lag) == pytest.approx(0.5 * math.exp(-1.0), abs=0.04)
    # lateral correlation crosses zero at s = 2
    assert abs(_acf(x[:, 1], 2 * lag)) < 0.04
    # vertical, its own scale length L_w = h
    x = _run(DrydenTurbulence(8.0, np.random.default_rng(6)), 100_000, l_w / v / lag, h, v)
    assert _acf(x[:, 2], lag) == pytest.approx(0.5 * math.exp(-1.0), abs=0.04)


def test_hover_uses_1mps_floor():
    a = DrydenTurbulence(5.0, np.random.default_rng(3))
    b = DrydenTurbulence(5.0, np.random.default_rng(3))
    xa = _run(a, 50, 0.01, 3.0, 0.0)
    xb = _run(b, 50, 0.01, 3.0, 1.0)
    np.testing.assert_array_equal(xa, xb)


def test_determinism_and_block_size_invariance():
    x1 = _run(DrydenTurbulence(5.0, np.random.default_rng(7)), 3000, 0.01, 5.0, 3.0)
    x2 = _run(DrydenTurbulence(5.0, np.random.default_rng(7)), 3000, 0.01, 5.0, 3.0)
    x3 = _run(DrydenTurbulence(5.0, np.random.default_rng(7), block=5), 3000, 0.01, 5.0, 3.0)
    x4 = _run(DrydenTurbulence(5.0, np.random.default_rng(8)), 3000, 0.01, 5.0, 3.0)
    np.testing.assert_array_equal(x1, x2)
    np.testing.assert_array_equal(x1, x3)
    assert not np.allclose(x1, x4)


def test_altitude_change_rescales_immediately():
    turb = DrydenTurbulence(5.0, np.random.default_rng(1))
    x = _run(turb, 40_000, 0.2, 100.0, 5.0)
    su100, _, sw100 = turb.sigmas(100.0)
    assert x[:, 2].std() == pytest.approx(sw100, rel=0.1)
    assert turb.sigmas(3.0)[0] > su100  # sigma_u grows toward the ground


# ------------------------------------------------------------------ Wind


def test_direction_convention_meteorological_from():
    s = 5.0
    cases = {0.0: (0.0, -s), 90.0: (-s, 0.0), 180.0: (0.0, s), 270.0: (s, 0.0)}
    for d, (ex, ey) in cases.items():
        w = Wind(s, d)
        wx, wy, wz = w.step(0.01, 3.0, 0.0)
        assert (wx, wy, wz) == pytest.approx((ex, ey, 0.0), abs=1e-12)
    wx, wy, _ = Wind(s, 45.0).step(0.01, 3.0, 0.0)  # from north-east: blows to south-west
    assert wx == pytest.approx(-s / math.sqrt(2)) and wy == pytest.approx(-s / math.sqrt(2))


def test_gust_frame_u_downwind_v_left_w_up():
    """Wind - mean = u e_u + v e_v + w e_w with the gusts of a DrydenTurbulence on the same seed:
    e_u downwind, e_v 90 deg left of it, e_w up."""
    w = Wind(4.0, 90.0, "mean", np.random.default_rng(0))  # air moves west (-x)
    t = DrydenTurbulence(4.0, np.random.default_rng(0))
    gusts = []
    for k in range(300):
        h, v = 3.0 + 0.05 * k, 2.0 + 0.01 * k
        wx, wy, wz = w.step(0.01, h, v)
        u, gv, gw = t.step(0.01, h, v)
        # e_u = (-1, 0, 0); left of west-going air is south: e_v = (0, -1, 0) (cos 90 deg ~ 6e-17)
        assert (wx, wy, wz) == pytest.approx((-4.0 - u, -gv, gw), rel=0, abs=1e-14)
        gusts.append((u, gv, gw))
    assert np.all(np.abs(gusts).max(axis=0) > 0.05)  # every component was exercised


# (mean speed, direction, turbulence, seed): the default, aircraft presets, an explicit W20, calm
REF_SPECS = [(3.0, 240.0, "light", 1), (3.0, 30.0, "mean", 2), (6.0, 250.0, "moderate", 3),
             (1.0, 10.0, "severe", 4), (0.0, 90.0, 1.7, 5), (2.0, 0.0, "none", 6)]


@pytest.mark.parametrize("spec", REF_SPECS)
def test_wind_equals_the_reference_from_the_formulas(spec):
    """Wind.step (the compiled wind_row) against tests/oracles/wind_ref.py (plain Python from the
    MIL-F-8785C formulas, Q from scipy's incomplete gamma): clamps below 3 m, above 1000 ft and
    under 1 m/s, refreshes on drift and on a dt change, block refills; the same Generator use."""
    speed, direction, turb, seed = spec
    w = Wind(speed, direction, turb, np.random.default_rng(seed))
    ref = WindRef(speed, direction, w.w20, np.random.default_rng(seed))
    rng = np.random.default_rng(100 + seed)
    n = 3000  # > 2 blocks of 1024 steps
    alt = 15.0 + 14.0 * np.sin(0.003 * np.arange(n)) + 0.05 * rng.standard_normal(n)
    alt[1000:1010] = 400.0
    alt[1500:1600:7] = -2.0
    spd = 6.0 + 6.5 * np.sin(0.002 * np.arange(n))
    got = np.array([w.step(0.01 if k < 2000 else 0.02, alt[k], spd[k]) for k in range(n)])
    exp = np.array([ref.step(0.01 if k < 2000 else 0.02, alt[k], spd[k]) for k in range(n)])
    np.testing.assert_allclose(got, exp, rtol=0, atol=1e-11)
    if w.turbulence is not None:
        assert np.abs(got[:, 2]).max() > 0.1
        assert w.turbulence.rng.bit_generator.state == ref.rng.bit_generator.state
        _, _, lu, lw = milspec(w.w20, ref.at[1])  # at the height of the last refresh
        assert (w.turbulence.L_u, w.turbulence.L_w) == pytest.approx((lu, lw), rel=1e-14)
    else:
        np.testing.assert_array_equal(got, np.tile(w.mean, (n, 1)))


def test_wind_mean_equals_mean_wind_and_gust_std():
    w = Wind(6.0, 30.0, "mean", np.random.default_rng(21))
    x = np.array([w.step(0.1, 3.0, 10.0) for _ in range(150_000)])
    np.testing.assert_allclose(x.mean(axis=0), w.mean, atol=0.1)
    su, _, sw = w.sigmas(3.0)
    assert w.w20 == 6.0 and sw == pytest.approx(0.6)
    horiz = x[:, :2] - np.array(w.mean[:2])
    assert np.sqrt((horiz**2).sum(axis=1).mean()) == pytest.approx(math.sqrt(2) * su, rel=0.1)


def test_turbulence_presets_and_errors():
    assert Wind(3.0, 0.0, "light", np.random.default_rng(0)).w20 == pytest.approx(15 * KNOT)
    assert Wind(3.0, 0.0, "moderate", np.random.default_rng(0)).w20 == pytest.approx(30 * KNOT)
    assert Wind(3.0, 0.0, "severe", np.random.default_rng(0)).w20 == pytest.approx(45 * KNOT)
    assert Wind(3.0, 0.0, "mean", np.random.default_rng(0)).w20 == 3.0
    assert Wind(3.0, 0.0, 2.5, np.random.default_rng(0)).w20 == 2.5
    assert Wind(3.0, 0.0, "none").turbulence is None
    with pytest.raises(ValueError, match="turbulence = 'gale'"):
        Wind(3.0, 0.0, "gale", np.random.default_rng(0))
    with pytest.raises(ValueError, match="mean_speed"):
        Wind(-1.0, 0.0)
    with pytest.raises(ValueError, match="rng"):
        Wind(3.0, 0.0, "light")


def test_drag_force_steady_wind():
    wind = (3.0, -2.0, 0.5)
    f = drag_force((0.0, 0.0, 0.0), wind, 0.4, 0.1)
    expect = [0.4 * c + 0.1 * abs(c) * c for c in wind]
    assert f == pytest.approx(expect)
    # moving with the air: no drag; per-axis coefficients
    assert drag_force(wind, wind, 0.4, 0.1) == pytest.approx((0.0, 0.0, 0.0))
    f = drag_force((1.0, 1.0, 1.0), (0.0, 0.0, 0.0), (1.0, 2.0, 3.0), (0.0, 0.0, 1.0))
    assert f == pytest.approx((-1.0, -2.0, -4.0))
