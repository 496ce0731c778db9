"""The MEMS IMU (MuJoCo accelerometer + gyro with errors), the attitude-error model and the
IMU-driven "cvb" motion model."""

from __future__ import annotations

import math

import mujoco
import numpy as np
import pytest
from oracles.imu_ref import AttitudeRef, ImuRef
from scipy.linalg import expm

import ag_uav
from ag_uav.config import ImuConfig
from ag_uav.vehicle.imu import DEG, AttitudeError, G, ImuSensor, accel_sigma, process_noise_psd
from ag_uav.vehicle.mjcf import build_vehicle
from estimators.models import motion_model


def _hover(seconds: float = 2.0):
    """The vehicle held in hover (thrust = weight) in still air: MuJoCo's sensor readings."""
    cfg = ag_uav.load_config(None, {"wind.speed_mps": 0.0, "wind.turbulence": "none"})
    veh = build_vehicle(cfg)
    m, d = veh.model, mujoco.MjData(veh.model)
    d.qpos[2] = 10.0
    d.ctrl[:] = d.act[:] = veh.mass * G / 4
    ia, ig = m.sensor("accel").adr[0], m.sensor("gyro").adr[0]
    n = int(seconds * 100)
    f, w = np.zeros((n, 3)), np.zeros((n, 3))
    for k in range(n):
        mujoco.mj_step(m, d, nstep=5)
        f[k], w[k] = d.sensordata[ia:ia + 3], d.sensordata[ig:ig + 3]
    return cfg, f, w


def test_hovering_accelerometer_reads_plus_g_along_body_z():
    cfg, f, w = _hover()
    # MuJoCo's exact specific force: +g up, nothing sideways, no rotation
    np.testing.assert_allclose(f[-1], [0.0, 0.0, G], atol=1e-6)
    np.testing.assert_allclose(w[-1], 0.0, atol=1e-9)
    # the MEMS reading: +g within its noise and turn-on bias
    imu = ImuSensor(cfg.imu, 100.0, np.random.SeedSequence(3))
    meas = np.array([imu.measure(fk, wk)[0] for fk, wk in zip(f, w, strict=True)])
    sig = accel_sigma(cfg.imu, 100.0)
    mean = meas.mean(axis=0)
    bias = imu.bias0[:3]
    # the mean is truth + bias to within 4 standard errors of the white noise
    np.testing.assert_allclose(mean - bias, [0.0, 0.0, G], atol=4 * sig / math.sqrt(len(meas)))
    # ... and the spread is the configured white noise (chi-square bounds for 200 samples)
    s = (meas - meas.mean(axis=0)).std(axis=0, ddof=1)
    assert np.all(s > 0.8 * sig) and np.all(s < 1.2 * sig)


def test_bias_statistics_match_the_configured_figures():
    c = ImuConfig(accel_bias_mg=10.0, gyro_bias_dps=0.2, accel_bias_rw=2e-3, gyro_bias_rw=0.01)
    b0 = np.array([ImuSensor(c, 100.0, np.random.SeedSequence(k)).bias0 for k in range(600)])
    # turn-on biases: zero mean, 1-sigma as configured (600 x 3 samples: ~±5 % on the std)
    std = b0.std(axis=0)
    np.testing.assert_allclose(std[:3], 10e-3 * G, rtol=0.12)
    np.testing.assert_allclose(std[3:], 0.2 * DEG, rtol=0.12)
    assert np.all(np.abs(b0.mean(axis=0)) < 4 * std / math.sqrt(len(b0)))
    # random walk: the bias increments over one sample have std sigma_rw sqrt(dt)
    imu = ImuSensor(c, 100.0, np.random.SeedSequence(1), block=20000)
    imu.measure((0, 0, 0), (0, 0, 0))
    bias = imu._last_bias_block
    inc = np.diff(bias, axis=0).std(axis=0)
    np.testing.assert_allclose(inc[:3], 2e-3 * 0.1, rtol=0.05)
    np.testing.assert_allclose(inc[3:], 0.01 * DEG * 0.1, rtol=0.05)
    # and the walk accumulates: var(b_T - b_0) = sigma_rw^2 T (T = 200 s)
    drift = bias[-1] - bias[0]
    assert np.all(np.abs(drift[:3]) < 5 * 2e-3 * math.sqrt(200.0))


def test_attitude_error_stays_within_its_stated_error_over_a_mission():
    cfg = ag_uav.load_config(None, {"log.enabled": False, "sim.max_time_s": 120.0})
    res = ag_uav.simulate(cfg)
    err = res.extra["imu"][:, 6:9] / DEG
    assert len(err) > 10000
    # the world-frame error (roll/pitch about x, y; yaw about z) has the configured 1-sigma ...
    rms = np.sqrt(np.mean(err**2, axis=0))
    c = cfg.imu
    # 120 s is 4 correlation times: a Gauss-Markov RMS is within ~[0.4, 1.7] sigma there
    assert 0.4 * c.tilt_error_deg < rms[0] < 1.7 * c.tilt_error_deg
    assert 0.4 * c.tilt_error_deg < rms[1] < 1.7 * c.tilt_error_deg
    assert 0.4 * c.yaw_error_deg < rms[2] < 1.7 * c.yaw_error_deg
    # ... never beyond 4.5 sigma
    assert np.all(np.abs(err[:, :2]) < 4.5 * c.tilt_error_deg)
    assert np.all(np.abs(err[:, 2]) < 4.5 * c.yaw_error_deg)
    # the estimate the drone flew on is a rotation off the truth by that error
    am = AttitudeError(c, 100.0, np.random.SeedSequence(0))
    R = np.eye(3).ravel()
    Rh = np.asarray(am.apply(R)).reshape(3, 3)
    np.testing.assert_allclose(Rh @ Rh.T, np.eye(3), atol=1e-12)
    ang = math.acos(max(-1.0, min(1.0, (np.trace(Rh) - 1) / 2)))
    assert ang == pytest.approx(np.linalg.norm(am.last), rel=1e-9)


def test_gauss_markov_attitude_error_has_its_variance_and_correlation():
    c = ImuConfig(tilt_error_deg=0.5, yaw_error_deg=2.0, attitude_error_tau_s=2.0)
    am = AttitudeError(c, 100.0, np.random.SeedSequence(5), block=200000)
    am.apply(np.eye(3).ravel())
    x = am._dth[0] / DEG
    np.testing.assert_allclose(x.std(axis=0), [0.5, 0.5, 2.0], rtol=0.1)
    lag = 200  # one correlation time: autocorrelation e^-1
    r = np.mean([np.corrcoef(x[:-lag, i], x[lag:, i])[0, 1] for i in range(3)])
    assert r == pytest.approx(math.exp(-1.0), abs=0.05)


# the default, a noisy/walking IMU, large biases and attitude errors, a long correlation time;
# small and odd blocks cross many refills
REF_CFGS = [ImuConfig(),
            ImuConfig(accel_noise_density_ug=150.0, vibration_sigma_mps2=0.3, accel_bias_rw=1e-2,
                      gyro_bias_rw=5e-2),
            ImuConfig(accel_bias_mg=20.0, gyro_bias_dps=0.5, tilt_error_deg=1.0,
                      yaw_error_deg=3.0, attitude_error_tau_s=2.0),
            ImuConfig(gyro_noise_density_mdps=10.0, attitude_error_tau_s=300.0)]


@pytest.mark.parametrize("case", range(4))
def test_imu_sensor_equals_the_reference_error_model(case):
    """ImuSensor.measure (the compiled imu_row on its block of imu_error_block) against
    tests/oracles/imu_ref.py: turn-on bias, random walk and white noise per axis; the same
    Generator use."""
    cfg, block = REF_CFGS[case], (4096, 97, 256, 1000)[case]
    imu = ImuSensor(cfg, 100.0, np.random.SeedSequence(30 + case), block=block)
    ref = ImuRef(cfg, 100.0, np.random.SeedSequence(30 + case), block=block)
    np.testing.assert_allclose(imu.bias0, ref.bias0, rtol=1e-15, atol=0)
    rng = np.random.default_rng(case)
    f = [0.0, 0.0, G] + rng.standard_normal((1500, 3))
    w = 0.3 * rng.standard_normal((1500, 3))
    for k in range(1500):
        got, exp = imu.measure(f[k], w[k]), ref.measure(f[k], w[k])
        np.testing.assert_allclose(got[0] + got[1], exp[0] + exp[1], rtol=0, atol=1e-13)
    np.testing.assert_allclose(imu.bias, ref.bias, rtol=0, atol=1e-15)
    assert np.abs(imu.bias - imu.bias0).max() > (1e-6 if cfg.accel_bias_rw < 1e-2 else 1e-3)
    assert imu.rng.bit_generator.state == ref.rng.bit_generator.state


@pytest.mark.parametrize("case", range(4))
def test_attitude_error_equals_the_reference_model(case):
    """AttitudeError.apply (the compiled attitude_row on gauss_markov_block's δθ) against
    tests/oracles/imu_ref.py (a Python Gauss-Markov recursion, scipy's rotation vector)."""
    cfg, block = REF_CFGS[case], (4096, 97, 256, 1000)[case]
    am = AttitudeError(cfg, 100.0, np.random.SeedSequence(40 + case), block=block)
    ref = AttitudeRef(cfg, 100.0, np.random.SeedSequence(40 + case), block=block)
    np.testing.assert_allclose(am.last, ref.last, rtol=1e-15, atol=0)
    t = np.arange(1500) * 0.01
    for k in range(1500):
        cy, sy = math.cos(0.7 * t[k]), math.sin(0.7 * t[k])
        R = [cy, -sy, 0.0, sy, cy, 0.0, 0.0, 0.0, 1.0]
        np.testing.assert_allclose(am.apply(R), ref.apply(R), rtol=0, atol=1e-14)
        np.testing.assert_allclose(am.last, ref.last, rtol=0, atol=1e-15)
    assert np.abs(am.last).max() > 1e-3
    assert am.rng.bit_generator.state == ref.rng.bit_generator.state


def test_cvb_model_is_the_exact_discretisation():
    dt, q, qb = 0.01, 0.3, 0.02
    mdl = motion_model("cvb", 1, dt, q=q, q_bias=qb)
    # continuous system: x = [p, v, b], p' = v, v' = -b + w_a, b' = w_b
    A = np.array([[0.0, 1.0, 0.0], [0.0, 0.0, -1.0], [0.0, 0.0, 0.0]])
    Qc = np.diag([0.0, q, qb])
    # Van Loan: exp([[-A, Qc], [0, A^T]] dt) gives F and Q
    M = np.block([[-A, Qc], [np.zeros((3, 3)), A.T]]) * dt
    E = expm(M)
    F = E[3:, 3:].T
    Q = F @ E[:3, 3:]
    np.testing.assert_allclose(mdl.F, F, atol=1e-14)
    np.testing.assert_allclose(mdl.Q, Q, rtol=1e-9, atol=1e-18)
    assert mdl.labels == ["px", "vx", "bx"]


def test_cvb_filter_estimates_a_constant_input_bias():
    """A KF on the cvb model, driven by a biased acceleration, learns the bias from positions."""
    import estimators

    dt, bias = 0.01, 0.2
    f = estimators.make("kf", model="cvb", dim=1, dt=dt, q=1e-4, q_bias=1e-4, r=1e-4)
    f.x = np.zeros(3)
    f.P = np.diag([1e-4, 1e-2, 0.1])
    rng = np.random.default_rng(0)
    p = v = 0.0
    for k in range(3000):
        a = math.sin(0.01 * k)            # true acceleration
        v += a * dt
        p += v * dt
        f.predict()
        f.x[0] += 0.5 * dt * dt * (a + bias)
        f.x[1] += dt * (a + bias)
        if k % 5 == 0:
            f.update(np.array([p + 0.01 * rng.standard_normal()]))
    assert f.x[2] == pytest.approx(bias, abs=0.02)
    assert abs(f.x[0] - p) < 0.03


def test_process_noise_follows_the_imu_figures():
    c = ImuConfig()
    q, qb, var0 = process_noise_psd(c, 100.0, bias_states=True)
    assert q == pytest.approx(accel_sigma(c, 100.0) ** 2 / 100.0)
    st = G * c.tilt_error_deg * DEG
    assert qb == pytest.approx(c.accel_bias_rw**2 + 2 * st * st / c.attitude_error_tau_s)
    assert var0 == pytest.approx((c.accel_bias_mg * 1e-3 * G) ** 2 + st * st)
    # a noisier IMU gets more process noise; folding the slow errors costs more than estimating
    q2, _, _ = process_noise_psd(ImuConfig(vibration_sigma_mps2=0.5), 100.0, bias_states=True)
    qf, _, _ = process_noise_psd(c, 100.0, bias_states=False)
    assert q2 > 20 * q and qf > 100 * q
