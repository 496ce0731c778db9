"""EKF, UKF and MCC-EKF: filterpy equivalence, σ → ∞ limit, wrapped bearing innovations."""

from __future__ import annotations

import math

import numpy as np
import pytest

from estimators.bearing import (
    BearingModel,
    angle_residual,
    cv_process_noise,
    cv_transition,
    mixture_noise,
    wrap_angle,
)
from estimators.ekf import EKF
from estimators.mccekf import MCCEKF
from estimators.ukf import UKF


def _fpk():
    """filterpy.kalman, the oracle (a dev extra): only its comparisons skip without it."""
    return pytest.importorskip("filterpy.kalman")


ANCHORS = [(0.0, 925.0), (200.0, 1050.0)]
F = cv_transition(4, 1.0)
Q = cv_process_noise([1e-2, 1e-2, 1e-4, 1e-4], 1.0)
R = 0.01 * np.eye(3)
X0 = np.array([-1000.0, 10.0, 1200.0, 5.0, 200.0, 0.3, 800.0, 0.3])
P0 = np.diag([1e3, 10.0, 1e3, 10.0, 1e3, 10.0, 1e3, 10.0])
B = np.zeros((8, 2))
B[0, 0] = B[2, 1] = 1.0
MODEL = BearingModel(8, (0, 2), ANCHORS, [(4, 6)])


def _scenario(seed: int, steps: int, model: BearingModel = MODEL, x_true0=None):
    """Truth (CV + process noise), UAV controls and mixture-noise bearings."""
    rng = np.random.default_rng(seed)
    x = np.array([-980.0, 9.0, 1230.0, 4.0, 0.0, 0.3, 600.0, 0.3]) if x_true0 is None \
        else np.array(x_true0, dtype=float)
    L = np.linalg.cholesky(Q)
    us, zs = [], []
    for _ in range(steps):
        u = rng.uniform(-15.0, 15.0, 2)
        x = F @ x + B @ u + L @ rng.standard_normal(8)
        z = wrap_angle(model.h(x) + mixture_noise(rng, 3))
        us.append(u)
        zs.append(z)
    return us, zs


def test_ekf_matches_filterpy():
    us, zs = _scenario(1, 60)
    ekf = EKF(F, None, MODEL.h, MODEL.jacobian, Q, R, X0, P0, residual=angle_residual, B=B)
    ref = _fpk().ExtendedKalmanFilter(dim_x=8, dim_z=3, dim_u=2)
    ref.x, ref.P, ref.F, ref.Q, ref.R, ref.B = X0.copy(), P0.copy(), F, Q, R, B
    for u, z in zip(us, zs, strict=True):
        ekf.predict(u=u)
        ref.predict(u=u)
        assert ekf.update(z)
        ref.update(z, MODEL.jacobian, MODEL.h, residual=angle_residual)
        np.testing.assert_allclose(ekf.x, ref.x, rtol=1e-8, atol=1e-8)
        np.testing.assert_allclose(ekf.P, ref.P, rtol=1e-8, atol=1e-8)
        np.testing.assert_allclose(ekf.y, ref.y, rtol=1e-8, atol=1e-10)


def test_ekf_callable_model_equals_matrix_model_and_predict_is_fpft_plus_q():
    us, zs = _scenario(2, 20)
    a = EKF(F, None, MODEL.h, MODEL.jacobian, Q, R, X0, P0, residual=angle_residual, B=B)
    b = EKF(lambda x: F @ x, lambda x: F, MODEL.h, MODEL.jacobian, Q, R, X0, P0,
            residual=angle_residual, B=B)
    for u, z in zip(us, zs, strict=True):
        P_prev = a.P.copy()
        a.predict(u=u)
        # the paper's eq 10 typo ("F P + Fᵀ Q") is F P Fᵀ + Q
        np.testing.assert_allclose(a.P, F @ P_prev @ F.T + Q, rtol=1e-13)
        b.predict(u=u)
        a.update(z)
        b.update(z)
    np.testing.assert_allclose(a.x, b.x, rtol=1e-12)
    np.testing.assert_allclose(a.P, b.P, rtol=1e-12)


def _fp_ukf(alpha=1.0, beta=2.0, kappa=0.0):
    pts = _fpk().MerweScaledSigmaPoints(8, alpha=alpha, beta=beta, kappa=kappa)
    ukf = _fpk().UnscentedKalmanFilter(
        dim_x=8, dim_z=3, dt=1.0, hx=MODEL.h, fx=lambda x, dt, u: F @ x + B @ u, points=pts,
        residual_z=angle_residual,
        z_mean_fn=lambda sig, Wm: sig[0] + Wm @ angle_residual(sig, sig[0]))
    ukf.x, ukf.P, ukf.Q, ukf.R = X0.copy(), P0.copy(), Q, R
    return ukf


@pytest.mark.parametrize("params", [(1.0, 2.0, 0.0), (0.5, 2.0, 1.0)])
@pytest.mark.parametrize("vectorized", [False, True])
def test_ukf_matches_filterpy(params, vectorized):
    us, zs = _scenario(3, 40)
    a, b, k = params
    ukf = UKF(F, MODEL.h, Q, R, X0, P0, residual=angle_residual, alpha=a, beta=b, kappa=k,
              B=B, vectorized=vectorized)
    ref = _fp_ukf(a, b, k)
    for u, z in zip(us, zs, strict=True):
        ukf.predict(u=u)
        ref.predict(u=u)
        np.testing.assert_allclose(ukf.x, ref.x, rtol=1e-8, atol=1e-8)
        np.testing.assert_allclose(ukf.P, ref.P, rtol=1e-8, atol=1e-8)
        assert ukf.update(z)
        ref.update(z)
        np.testing.assert_allclose(ukf.x, ref.x, rtol=1e-8, atol=1e-8)
        np.testing.assert_allclose(ukf.P, ref.P, rtol=1e-8, atol=1e-8)


def test_ukf_callable_nonlinear_f_matches_filterpy():
    """A nonlinear transition (a slow coordinated turn of the target) through both UKFs."""
    w = 0.01

    def fx(x):
        y = F @ x
        c, s = math.cos(w), math.sin(w)
        y[5], y[7] = c * x[5] - s * x[7], s * x[5] + c * x[7]
        return y

    us, zs = _scenario(4, 30)
    ukf = UKF(fx, MODEL.h, Q, R, X0, P0, residual=angle_residual)
    pts = _fpk().MerweScaledSigmaPoints(8, alpha=1.0, beta=2.0, kappa=0.0)
    ref = _fpk().UnscentedKalmanFilter(
        dim_x=8, dim_z=3, dt=1.0, hx=MODEL.h, fx=lambda x, dt: fx(x), points=pts,
        residual_z=angle_residual,
        z_mean_fn=lambda sig, Wm: sig[0] + Wm @ angle_residual(sig, sig[0]))
    ref.x, ref.P, ref.Q, ref.R = X0.copy(), P0.copy(), Q, R
    for z in zs:
        ukf.predict()
        ref.predict()
        ukf.update(z)
        ref.update(z)
    np.testing.assert_allclose(ukf.x, ref.x, rtol=1e-8, atol=1e-8)
    np.testing.assert_allclose(ukf.P, ref.P, rtol=1e-8, atol=1e-8)


def test_mccekf_with_huge_sigma_is_the_ekf():
    us, zs = _scenario(5, 80)
    ekf = EKF(F, None, MODEL.h, MODEL.jacobian, Q, R, X0, P0, residual=angle_residual, B=B)
    mcc = MCCEKF(F, None, MODEL.h, MODEL.jacobian, Q, R, X0, P0, residual=angle_residual, B=B,
                 sigma=1e6)
    for u, z in zip(us, zs, strict=True):
        ekf.predict(u=u)
        mcc.predict(u=u)
        ekf.update(z)
        mcc.update(z)
        np.testing.assert_allclose(mcc.x, ekf.x, rtol=1e-8, atol=1e-8)
        np.testing.assert_allclose(mcc.P, ekf.P, rtol=1e-8, atol=1e-8)


def test_mccekf_rejects_a_bearing_outlier():
    """One target bearing 1 rad off: the EKF jumps, the MCC-EKF barely moves."""
    x_true = np.array([-1000.0, 10.0, 1200.0, 5.0, 0.0, 0.3, 600.0, 0.3])
    P = np.diag([100.0, 1.0, 100.0, 1.0, 100.0, 1.0, 100.0, 1.0])
    z = MODEL.h(x_true)
    z[2] += 1.0
    ekf = EKF(F, None, MODEL.h, MODEL.jacobian, Q, R, x_true, P, residual=angle_residual)
    mcc = MCCEKF(F, None, MODEL.h, MODEL.jacobian, Q, R, x_true, P, residual=angle_residual,
                 sigma=2.0)
    for f in (ekf, mcc):
        f.update(z)
    d_ekf = np.linalg.norm(ekf.x - x_true)
    d_mcc = np.linalg.norm(mcc.x - x_true)
    assert d_ekf > 5.0
    assert d_mcc < 0.05 * d_ekf
    assert mcc.weights[2] < 0.01 < mcc.weights[0]


# ------------------------------------------------------------------------- angle wrapping
def _rot_state(phi: float) -> np.ndarray:
    """Rotation of every (ξ, η) pair of the state [ξu, ξ̇u, ηu, η̇u, ξt, ξ̇t, ηt, η̇t]."""
    c, s = math.cos(phi), math.sin(phi)
    T = np.eye(8)
    for i, j in ((0, 2), (1, 3), (4, 6), (5, 7)):
        T[np.ix_([i, j], [i, j])] = [[c, -s], [s, c]]
    return T


def test_ekf_is_rotation_equivariant_across_the_bearing_cut():
    """The same scenario in two frames, one where the target bearing sits on ±π (its
    measurements wrap every few steps) and one rotated by 90° (no wrap): identical estimates.
    Without wrapped innovations the first frame jumps by 2π-sized innovations."""
    # UAV east of the target: bearing UAV -> target ≈ π
    x_true0 = [500.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0]
    anchors = [(0.0, 400.0), (300.0, -300.0)]
    mA = BearingModel(8, (0, 2), anchors, [(4, 6)])
    phi = math.pi / 2
    T = _rot_state(phi)
    Rm = T[np.ix_([0, 2], [0, 2])]
    mB = BearingModel(8, (0, 2), [tuple(Rm @ np.array(a)) for a in anchors], [(4, 6)])
    rng = np.random.default_rng(7)
    x = np.array(x_true0)
    xhat0 = x + np.array([20.0, 0.5, -15.0, 0.2, -10.0, 0.1, 25.0, -0.1])
    P = np.diag([400.0, 1.0, 400.0, 1.0, 400.0, 1.0, 400.0, 1.0])
    fa = EKF(F, None, mA.h, mA.jacobian, Q, R, xhat0, P, residual=angle_residual)
    fb = EKF(F, None, mB.h, mB.jacobian, Q, R, T @ xhat0, T @ P @ T.T, residual=angle_residual)
    naive = EKF(F, None, mA.h, mA.jacobian, Q, R, xhat0, P)  # plain subtraction
    wrapped = 0
    for _ in range(40):
        x = F @ x
        v = 0.01 * rng.standard_normal(3)
        za = wrap_angle(mA.h(x) + v)
        zb = wrap_angle(za + phi)
        for f in (fa, fb, naive):
            f.predict()
        fa.update(za)
        fb.update(zb)
        naive.update(za)
        wrapped += abs(za[2] - mA.h(fa.x)[2]) > math.pi
        np.testing.assert_allclose(T @ fa.x, fb.x, rtol=1e-9, atol=1e-7)
    assert wrapped > 0  # the cut was really crossed
    assert np.linalg.norm(fa.x[[4, 6]] - x[[4, 6]]) < 30.0
    assert np.linalg.norm(naive.x[[4, 6]] - x[[4, 6]]) > 100.0


def _cut_case():
    """A prior whose target bearing is π − 0.01 with the sigma points straddling ±π."""
    x = np.array([500.0, 0.0, 0.0, 0.0, 0.0, 0.0, 5.0, 0.0])
    P = np.diag([25.0, 1.0, 25.0, 1.0, 25.0, 1.0, 400.0, 1.0])
    z = MODEL.h(x)
    z[2] = wrap_angle(math.pi + 0.008)  # just across the cut: -π + 0.008
    return x, P, z


@pytest.mark.parametrize("kind", ["ekf", "ukf", "mcc"])
def test_innovation_across_pi_is_wrapped(kind):
    x, P, z = _cut_case()

    def make():
        if kind == "ekf":
            return EKF(F, None, MODEL.h, MODEL.jacobian, Q, R, x, P, residual=angle_residual)
        if kind == "ukf":
            return UKF(F, MODEL.h, Q, R, x, P, residual=angle_residual)
        return MCCEKF(F, None, MODEL.h, MODEL.jacobian, Q, R, x, P, residual=angle_residual)

    outs = []
    for shift in (0.0, 2 * math.pi, -2 * math.pi):
        f = make()
        f.predict()
        assert f.update(z + np.array([0.0, 0.0, shift]))
        assert abs(f.y[2]) < 0.1  # ≈ 0.018, not ≈ 2π
        outs.append(f.x.copy())
    np.testing.assert_allclose(outs[1], outs[0], atol=1e-9)
    np.testing.assert_allclose(outs[2], outs[0], atol=1e-9)
    assert np.linalg.norm(outs[0] - F @ x) < 10.0


def test_ukf_predicted_bearing_mean_near_the_cut():
    """Sigma points on both sides of ±π: the predicted bearing is near π, not near 0."""
    x, P, z = _cut_case()
    ukf = UKF(F, MODEL.h, Q, R, x, P, residual=angle_residual)
    ukf.predict()
    Z = MODEL.h(ukf.sigma_points(ukf.x, ukf.P))
    assert Z[:, 2].max() > 3.0 and Z[:, 2].min() < -3.0  # straddles the cut
    ukf.update(z)
    zp = wrap_angle(z[2] - ukf.y[2])
    assert abs(abs(zp) - math.pi) < 0.05


@pytest.mark.parametrize("kind", ["ekf", "ukf", "mcc"])
def test_no_fix_changes_nothing(kind):
    if kind == "ekf":
        f = EKF(F, None, MODEL.h, MODEL.jacobian, Q, R, X0, P0, residual=angle_residual)
    elif kind == "ukf":
        f = UKF(F, MODEL.h, Q, R, X0, P0, residual=angle_residual)
    else:
        f = MCCEKF(F, None, MODEL.h, MODEL.jacobian, Q, R, X0, P0, residual=angle_residual)
    f.predict()
    x, P = f.x.copy(), f.P.copy()
    assert f.update(None) is False
    assert f.update([0.1, np.nan, 0.2]) is False
    np.testing.assert_array_equal(f.x, x)
    np.testing.assert_array_equal(f.P, P)
