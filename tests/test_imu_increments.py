"""The IMU as real ones report it: delta-angle / delta-velocity samples integrated from the
physics' sub-steps (``ag_uav.vehicle.imu.imu_integrate_row``) and the INS's coning and sculling
corrections (``estimators.ins.model.increments``), against closed forms.

* Coning: a body coning at half-angle β and frequency Ω, q(t) = (cos β/2, sin β/2 cos Ωt,
  sin β/2 sin Ωt, 0), has the body rate ω = (−Ω sin β sin Ωt, Ω sin β cos Ωt, −2Ω sin² β/2)
  and the exact delta-angles Δθ = (sin β [cos Ωt]ₜ₀ᵗ¹, sin β [sin Ωt]ₜ₀ᵗ¹, −2Ω sin² β/2 Δt);
  the attitude integrated from them with the coning correction matches q(T) far better than
  without (without, the attitude drifts about the cone's axis).
* Sculling: a rotation θ(t) = θ₀ sin Ωt about body x with the specific force A sin Ωt along body
  y gives, over whole periods, the world z velocity A J₁(θ₀) T (sin(x sin φ) =
  2 Σ J₂ₖ₊₁(x) sin((2k+1)φ)); with the sculling correction the integrated increments match it.
* The physics: the samples the IMU integrates are exactly the rates and specific forces MuJoCo's
  semi-implicit Euler step applies, so their sums are the physics' velocity and rotation change.
"""

from __future__ import annotations

import math

import mujoco
import numpy as np
from scipy.special import j1

import ag_uav
from ag_uav.vehicle.imu import filter_alpha, imu_integrate_row
from ag_uav.vehicle.mjcf import build_vehicle
from estimators.ins import INSConfig, nominal_step, quat_log_err, quat_mul
from estimators.ins.layout import STEP


def _fly(u: np.ndarray, x0: np.ndarray, coning: bool, gravity: float = 0.0) -> np.ndarray:
    """Nominal states after each sample of ``u`` (K+1, 6; row 0 the sample before the start),
    biases zero."""
    prm = INSConfig(dt=DT, gravity=gravity, coning=coning).prm()
    x = x0.copy()
    S3, w = np.zeros((1, 3, 3)), np.zeros(STEP.size)
    out = [x.copy()]
    for k in range(1, len(u)):
        nominal_step(x, u[k], u[k - 1], prm, S3, w)
        out.append(x.copy())
    return np.array(out)


DT = 0.01


def _cone_q(t: float, beta: float, om: float) -> np.ndarray:
    c, s = math.cos(beta / 2), math.sin(beta / 2)
    return np.array([c, s * math.cos(om * t), s * math.sin(om * t), 0.0])


def _cone_err(beta: float, om: float, T: float, coning: bool) -> float:
    K = int(round(T / DT))
    t = np.arange(-1, K + 1) * DT
    sb, s2 = math.sin(beta), math.sin(beta / 2) ** 2
    u = np.zeros((K + 1, 6))
    for k in range(K + 1):       # u[k]: the interval t[k] .. t[k+1] (u[0]: before the start)
        t0, t1 = t[k], t[k + 1]
        u[k, 3:] = (sb * (math.cos(om * t1) - math.cos(om * t0)),
                    sb * (math.sin(om * t1) - math.sin(om * t0)), -2 * om * s2 * DT)
        u[k, 3:] /= DT
    # an exact check of the closed form: ω = 2 vec(q* ⊗ q̇) at one instant
    q, dq = _cone_q(0.3, beta, om), (_cone_q(0.3 + 1e-6, beta, om) - _cone_q(0.3 - 1e-6, beta, om))
    qc = q * np.array([1, -1, -1, -1])
    wq = np.zeros(4)
    quat_mul(qc, dq / 2e-6, wq)
    w_cf = (-om * sb * math.sin(om * 0.3), om * sb * math.cos(om * 0.3), -2 * om * s2)
    np.testing.assert_allclose(2 * wq[1:], w_cf, atol=1e-6)
    x0 = np.zeros(16)
    x0[6:10] = _cone_q(0.0, beta, om)
    xs = _fly(u, x0, coning)
    e = np.zeros(3)
    quat_log_err(xs[-1, 6:10], _cone_q(K * DT, beta, om), e)
    return float(np.linalg.norm(e))


def test_coning_correction_matches_the_closed_form_coning_motion():
    """β = 2°, Ω = 2π · 5 Hz, 20 s at 100 Hz: the uncorrected attitude drifts about the cone
    axis (6.3 mrad at the end); the corrected one ends 50× closer (0.12 mrad)."""
    beta, om = 2.0 * math.pi / 180, 2 * math.pi * 5.0
    off = _cone_err(beta, om, 20.0, coning=False)
    on = _cone_err(beta, om, 20.0, coning=True)
    assert off > 1e-3                 # ~0.1°: the drift the correction exists for
    assert on < off / 20.0
    # the two-sample algorithm's residual is of the next order in (Ω Δt)
    assert on < 2e-4


def test_sculling_correction_matches_the_closed_form_sculling_motion():
    th0, om, A = 0.05, 2 * math.pi * 5.0, 2.0
    n_per = 20                                     # samples per period (Ω Δt = 2π/20)
    periods = 50
    K = n_per * periods
    t = np.arange(-1, K + 1) * DT
    u = np.zeros((K + 1, 6))
    for k in range(K + 1):
        t0, t1 = t[k], t[k + 1]
        u[k, 1] = A * (math.cos(om * t0) - math.cos(om * t1)) / om / DT
        u[k, 3] = th0 * (math.sin(om * t1) - math.sin(om * t0)) / DT
    x0 = np.zeros(16)
    x0[6] = 1.0
    T = K * DT
    exact = A * j1(th0) * T
    on = _fly(u, x0, True)[-1, 3:6]
    off = _fly(u, x0, False)[-1, 3:6]
    # held rates miss the rectified velocity by 1.6 %, the corrected increments by 0.03 %
    assert abs(off[2] - exact) > 0.01 * exact
    assert abs(on[2] - exact) < abs(off[2] - exact) / 20.0
    assert abs(on[1]) < 1e-9


def _physics(ticks: int = 150, nsub: int = 5):
    """A vehicle in still air under uneven rotor commands (it rolls, pitches and yaws while it
    accelerates): per tick the state and each sub-step's sensor readings."""
    cfg = ag_uav.load_config(None, {"wind.speed_mps": 0.0, "wind.turbulence": "none"})
    veh = build_vehicle(cfg)
    m, d = veh.model, mujoco.MjData(veh.model)
    d.qpos[2] = 20.0
    hover = veh.mass * 9.81 / 4
    d.ctrl[:] = d.act[:] = hover
    mujoco.mj_forward(m, d)
    qs, vs, ws, subs = [d.qpos[3:7].copy()], [d.qvel[0:3].copy()], [d.qvel[3:6].copy()], []
    Rj = []
    for k in range(ticks):
        d.ctrl[:] = hover * (1 + 0.2 * np.array([math.sin(0.3 * k), math.cos(0.2 * k),
                                                 -math.sin(0.25 * k), 0.1]))
        sub, rot = np.zeros((nsub, m.nsensordata)), np.zeros((nsub, 3, 3))
        for j in range(nsub):
            rot[j] = _rot(d.qpos[3:7])
            mujoco.mj_step(m, d)
            sub[j] = d.sensordata
        subs.append(sub)
        Rj.append(rot)
        qs.append(d.qpos[3:7].copy())
        vs.append(d.qvel[0:3].copy())
        ws.append(d.qvel[3:6].copy())
    ia, ig = int(m.sensor("accel").adr[0]), int(m.sensor("gyro").adr[0])
    return (np.array(qs), np.array(vs), np.array(ws), np.array(subs), np.array(Rj), ia, ig,
            m.opt.timestep)


def _rot(q) -> np.ndarray:
    R = np.zeros(9)
    mujoco.mju_quat2Mat(R, np.asarray(q, dtype=float))
    return R.reshape(3, 3)


def _qexp(phi) -> np.ndarray:
    th = np.linalg.norm(phi)
    if th < 1e-15:
        return np.array([1.0, *(0.5 * np.asarray(phi))])
    return np.array([math.cos(th / 2), *(math.sin(th / 2) * np.asarray(phi) / th)])


def test_imu_samples_sum_to_the_physics_velocity_and_rotation_change():
    qs, vs, ws, subs, Rj, ia, ig, h = _physics()
    nsub = subs.shape[1]
    g = np.array([0.0, 0.0, -9.81])
    lp = np.full((1, 6), np.nan)
    fo, wo = np.zeros((1, 3)), np.zeros((1, 3))
    turned = 0.0
    for k in range(len(subs)):
        sub = subs[k]
        # the accelerometer at each sub-step's start, rotated to the world, is what Euler adds
        dv = sum(h * (Rj[k, j] @ sub[j, ia:ia + 3] + g) for j in range(nsub))
        np.testing.assert_allclose(dv, vs[k + 1] - vs[k], atol=1e-9)
        # the gyro after each sub-step's velocity update composes to the physics' rotation
        rates = [sub[j + 1, ig:ig + 3] for j in range(nsub - 1)] + [ws[k + 1]]
        q = qs[k].copy()
        for w in rates:
            qn = np.zeros(4)
            mujoco.mju_mulQuat(qn, q, _qexp(h * np.asarray(w)))
            q = qn / np.linalg.norm(qn)
        assert min(np.abs(q - qs[k + 1]).max(), np.abs(q + qs[k + 1]).max()) < 1e-9
        # the row function without its filter: the means of exactly those samples
        imu_integrate_row(sub[None], ia, ig, ws[k + 1][None], 0, 1.0, lp, fo, wo)
        np.testing.assert_allclose(fo[0], np.mean(sub[:, ia:ia + 3], axis=0), atol=1e-12)
        np.testing.assert_allclose(wo[0], np.mean(rates, axis=0), atol=1e-12)
        # Δθ = mean rate × Δt is the rotation vector of the tick to second order (coning)
        e = np.zeros(3)
        quat_log_err(qs[k], qs[k + 1], e)
        np.testing.assert_allclose(wo[0] * nsub * h, e, atol=1e-6)
        turned += float(np.linalg.norm(e))
    assert turned > 0.05           # the vehicle did rotate (rad, summed over the ticks)


def test_anti_alias_filter_passes_a_constant_and_attenuates_at_its_bandwidth():
    h, fc = 0.002, 116.0
    a = filter_alpha(fc, h)
    assert filter_alpha(0.0, h) == 1.0
    lp = np.full((1, 6), np.nan)
    fo, wo = np.zeros((1, 3)), np.zeros((1, 3))
    sub = np.zeros((1, 5, 6))
    sub[0, :, 0:3] = 1.5
    sub[0, :, 3:6] = -0.5
    for _ in range(20):
        imu_integrate_row(sub, 0, 3, np.full((1, 3), -0.5), 0, a, lp, fo, wo)
    np.testing.assert_allclose(fo[0], 1.5, atol=1e-12)
    np.testing.assert_allclose(wo[0], -0.5, atol=1e-12)
    # the discrete pole's gain |H| = α / |1 − (1−α) e^{−iωh}|: 1/√2 at f_c for f_c h ≪ 1;
    # at f_c = 116 Hz on the 500 Hz physics 0.77, and one tenth of it passes
    def gain(f):
        return abs(a / (1 - (1 - a) * np.exp(-2j * math.pi * f * h)))
    assert 0.7 < gain(fc) < 0.8
    assert gain(fc / 10) > 0.99


def test_single_sensor_and_batch_integrate_alike():
    """ImuSensor.integrate and BatchImu.integrate run the one row function: the same samples
    from the same sub-steps, bit for bit, and the filter's state carries over ticks."""
    from ag_uav.config import ImuConfig
    from ag_uav.vehicle.imu import ImuSensor
    from ag_uav.vehicle.sensors_batched import BatchImu

    rng = np.random.default_rng(4)
    cfg = ImuConfig()
    single = ImuSensor(cfg, 100.0, 1)
    batch = BatchImu.from_sensors([ImuSensor(cfg, 100.0, 2), ImuSensor(cfg, 100.0, 3)])
    for _ in range(5):
        sub = rng.normal(size=(2, 5, 6))
        w_end = rng.normal(size=(2, 3))
        fb, wb = batch.integrate(sub, 0, 3, w_end)
        fs, ws = single.integrate(sub[1], 0, 3, w_end[1])
        assert np.array_equal(fb[1], fs) and np.array_equal(wb[1], ws)
