"""ag_uav.vehicle.sensors_batched: the batched wind/drag, IMU and attitude-error models equal the
per-vehicle objects bit for bit (values and Generator consumption: both run the same row
functions of ag_uav.world.wind and ag_uav.vehicle.imu) and a row does not depend on the batch.
The laws themselves are checked against the references in tests/oracles by test_wind.py and
test_imu.py."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

from ag_uav.config import ImuConfig
from ag_uav.vehicle.imu import AttitudeError, ImuSensor
from ag_uav.vehicle.sensors_batched import BatchAttitudeError, BatchImu, BatchWind, drag
from ag_uav.world.wind import Wind, drag_force

TICKS = 2600          # > 2 wind blocks (1024 ticks each)
DT = 0.01

# (mean speed, direction, turbulence, seed) -- different settings per vehicle
WIND_SPECS = [
    (3.0, 30.0, "mean", 1),
    (0.0, 0.0, "none", 2),
    (6.0, 250.0, "light", 3),
    (0.0, 90.0, "moderate", 4),
    (2.5, 120.0, 1.7, 5),
    (4.0, 300.0, "none", 6),
    (1.0, 10.0, "severe", 7),
]


def _winds(specs=WIND_SPECS) -> list[Wind]:
    return [Wind(s, d, t, rng=np.random.default_rng(seed)) for s, d, t, seed in specs]


def _profiles(n: int, ticks: int = TICKS, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """Altitude and airspeed per tick and vehicle: smooth drifts (the coefficient refresh fires
    every few ticks), jumps, values below the 3 m / 1 m/s clamps and above 1000 ft."""
    rng = np.random.default_rng(seed)
    t = np.arange(ticks)[:, None] * DT
    ph = rng.random(n) * 6.0
    alt = 15.0 + 14.0 * np.sin(0.3 * t + ph) + 0.05 * rng.standard_normal((ticks, n))
    spd = 6.0 + 6.5 * np.sin(0.2 * t + 2 * ph)
    alt[1000:1010] = 400.0            # above 1000 ft: clamped
    alt[1500:1600:7] = -2.0           # below ground
    return alt, spd


def _gen_state(rng: np.random.Generator | None):
    return None if rng is None else rng.bit_generator.state


def _assert_same_generators(a: list[Wind], b: list[Wind]) -> None:
    for wa, wb in zip(a, b, strict=True):
        ra = wa.turbulence.rng if wa.turbulence else None
        rb = wb.turbulence.rng if wb.turbulence else None
        assert _gen_state(ra) == _gen_state(rb)


# ------------------------------------------------------------------ wind


def test_wind_step_equals_scalar_winds_and_consumes_generators_alike():
    ref, winds = _winds(), _winds()
    bw = BatchWind.from_winds(winds)
    n = len(ref)
    np.testing.assert_array_equal(bw.mean, [w.mean for w in ref])
    alt, spd = _profiles(n)
    for k in range(TICKS):
        dt = DT if k < 2000 else 0.02     # a dt change refreshes the coefficients too
        exp = np.array([w.step(dt, alt[k, i], spd[k, i]) for i, w in enumerate(ref)])
        np.testing.assert_array_equal(bw.step(dt, alt[k], spd[k]), exp)
    _assert_same_generators(ref, winds)
    # the refresh fired: the batch's scale lengths follow the last altitude
    np.testing.assert_array_equal(bw.L_u, [w.turbulence.L_u if w.turbulence else 0.0
                                           for w in ref])
    assert np.all(bw.L_u[bw.turbulent] > 10.0)


def test_step_drag_equals_fly_reference_per_tick_formulas():
    ref, batch = _winds(), _winds()
    bw = BatchWind.from_winds(batch)
    n = len(ref)
    rng = np.random.default_rng(5)
    c_lin = 0.05 + 0.1 * rng.random((n, 3))
    c_quad = 0.01 + 0.05 * rng.random((n, 3))
    qpos = np.zeros((n, 7))
    qvel = np.zeros((n, 6))
    alt, _ = _profiles(n, ticks=1500)
    for k in range(1500):
        qpos[:, 2] = alt[k]
        qvel[:, :3] = 4.0 * np.sin(0.01 * k + np.arange(n))[:, None] * [1.0, -0.5, 0.2]
        # strided views, as the engine will pass them
        w, f = bw.step_drag(DT, qpos[:, 2], qvel[:, :3], c_lin, c_quad)
        for i, wind in enumerate(ref):
            vx, vy, vz = qvel[i, :3]
            pz = qpos[i, 2]
            wmx, wmy, _ = wind.mean
            ax_, ay_ = vx - wmx, vy - wmy
            wi = wind.step(DT, pz if pz > 0.0 else 0.0, math.sqrt(ax_ * ax_ + ay_ * ay_))
            fi = drag_force((vx, vy, vz), wi, tuple(c_lin[i]), tuple(c_quad[i]))
            np.testing.assert_array_equal(w[i], wi)
            np.testing.assert_array_equal(f[i], fi)
    _assert_same_generators(ref, batch)


def test_drag_matches_scalar_drag_force():
    rng = np.random.default_rng(1)
    v, w = rng.standard_normal((5, 3)) * 5, rng.standard_normal((5, 3)) * 3
    cl, cq = rng.random((5, 3)), rng.random((5, 3))
    out = np.empty((5, 3))
    assert drag(v, w, cl, cq, out) is out
    exp = [drag_force(v[i], w[i], tuple(cl[i]), tuple(cq[i])) for i in range(5)]
    np.testing.assert_array_equal(out, exp)
    # the law itself: F = -c_lin r - c_quad |r| r, r = v - w
    r = v - w
    np.testing.assert_allclose(out, -cl * r - cq * np.abs(r) * r, rtol=1e-15, atol=0)
    np.testing.assert_array_equal(drag(v, w, cl, cq), out)


def test_wind_row_is_bit_identical_alone_and_in_a_batch_of_7():
    alt, spd = _profiles(7)
    full = BatchWind.from_winds(_winds())
    rows = np.array([full.step(DT, alt[k], spd[k]).copy() for k in range(TICKS)])
    for i in (0, 3, 6):
        alone = BatchWind.from_winds(_winds([WIND_SPECS[i]]))
        mine = np.array([alone.step(DT, alt[k, i:i + 1], spd[k, i:i + 1])[0].copy()
                         for k in range(TICKS)])
        np.testing.assert_array_equal(mine, rows[:, i])


def test_wind_inactive_rows_are_frozen_and_draw_nothing():
    ref, winds = _winds(), _winds()
    bw = BatchWind.from_winds(winds)
    n = len(ref)
    alt, spd = _profiles(n, ticks=2200)
    rng = np.random.default_rng(3)
    for k in range(2200):
        act = rng.random(n) < 0.7
        before = bw.wind.copy()
        got = bw.step(DT, alt[k], spd[k], active=act)
        for i, w in enumerate(ref):
            if act[i]:
                np.testing.assert_array_equal(got[i], w.step(DT, alt[k, i], spd[k, i]))
            else:
                np.testing.assert_array_equal(got[i], before[i])
    _assert_same_generators(ref, winds)


def test_wind_takes_over_a_scalar_wind_mid_block():
    ref, winds = _winds(), _winds()
    n = len(ref)
    alt, spd = _profiles(n, ticks=1500)
    for k in range(700):          # both scalar sets advance; then one is handed to the batch
        for i in range(n):
            a = ref[i].step(DT, alt[k, i], spd[k, i])
            b = winds[i].step(DT, alt[k, i], spd[k, i])
            assert a == b
    bw = BatchWind.from_winds(winds)
    for k in range(700, 1500):
        exp = [w.step(DT, alt[k, i], spd[k, i]) for i, w in enumerate(ref)]
        np.testing.assert_array_equal(bw.step(DT, alt[k], spd[k]), exp)
    _assert_same_generators(ref, winds)


def test_batch_rejects_bad_input():
    with pytest.raises(ValueError, match="at least one"):
        BatchWind.from_winds([])
    bw = BatchWind.from_winds(_winds())
    with pytest.raises(ValueError, match="active"):
        bw.step(DT, np.ones(7), np.ones(7), active=np.ones(6, dtype=bool))


# ------------------------------------------------------------------ IMU and attitude

def _cfgs() -> list[ImuConfig]:
    base = ImuConfig()
    return [
        base,
        dataclasses.replace(base, accel_noise_density_ug=150.0, vibration_sigma_mps2=0.3,
                            accel_bias_rw=1e-2, gyro_bias_rw=5e-2),
        dataclasses.replace(base, accel_bias_mg=20.0, gyro_bias_dps=0.5, tilt_error_deg=1.0,
                            yaw_error_deg=3.0, attitude_error_tau_s=2.0),
        dataclasses.replace(base, gyro_noise_density_mdps=10.0, attitude_error_tau_s=300.0),
    ]


# small and odd blocks cross many refills within the test; 4096 is the default
BLOCKS = [4096, 256, 97, 1000]
IMU_TICKS = 4300


def _imus(cfgs=None, blocks=None, seeds=None) -> list[ImuSensor]:
    cfgs, blocks = cfgs or _cfgs(), blocks or BLOCKS
    seeds = seeds or [np.random.SeedSequence(10 + i) for i in range(len(cfgs))]
    return [ImuSensor(c, 100.0, s, block=b) for c, s, b in zip(cfgs, seeds, blocks, strict=True)]


def _errs(cfgs=None, blocks=None, seeds=None) -> list[AttitudeError]:
    cfgs, blocks = cfgs or _cfgs(), blocks or BLOCKS
    seeds = seeds or [np.random.SeedSequence(20 + i) for i in range(len(cfgs))]
    return [AttitudeError(c, 100.0, s, block=b)
            for c, s, b in zip(cfgs, seeds, blocks, strict=True)]


def _readings(n: int, ticks: int) -> tuple[np.ndarray, np.ndarray]:
    rng = np.random.default_rng(8)
    f = np.array([0.0, 0.0, 9.81]) + rng.standard_normal((ticks, n, 3))
    w = 0.3 * rng.standard_normal((ticks, n, 3))
    return f, w


def _rotations(n: int, ticks: int) -> np.ndarray:
    """Row-major rotations (ticks, n, 9): yaw, then tilt."""
    t = np.arange(ticks)[:, None] * 0.01 + np.arange(n)
    y, p = 0.7 * t, 0.3 * np.sin(t)
    cy, sy, cp, sp = np.cos(y), np.sin(y), np.cos(p), np.sin(p)
    z, o = np.zeros_like(y), np.ones_like(y)
    rz = np.stack([cy, -sy, z, sy, cy, z, z, z, o], axis=-1).reshape(ticks, n, 3, 3)
    ry = np.stack([cp, z, sp, z, o, z, -sp, z, cp], axis=-1).reshape(ticks, n, 3, 3)
    return (rz @ ry).reshape(ticks, n, 9)


def test_imu_measure_equals_scalar_sensors_including_refills():
    ref, imus = _imus(), _imus()
    bi = BatchImu.from_sensors(imus)
    np.testing.assert_array_equal(bi.bias0, [s.bias0 for s in ref])
    f, w = _readings(len(ref), IMU_TICKS)
    for k in range(IMU_TICKS):
        fm, wm = bi.measure(f[k], w[k])
        for i, s in enumerate(ref):
            ef, ew = s.measure(f[k, i].tolist(), w[k, i].tolist())
            assert fm[i].tolist() == ef and wm[i].tolist() == ew
    for a, b in zip(ref, imus, strict=True):
        assert a.rng.bit_generator.state == b.rng.bit_generator.state


def test_attitude_apply_equals_scalar_errors_including_refills():
    ref, errs = _errs(), _errs()
    ba = BatchAttitudeError.from_errors(errs)
    np.testing.assert_array_equal(ba.last, [e.last for e in ref])
    R = _rotations(len(ref), IMU_TICKS)
    for k in range(IMU_TICKS):
        got = ba.apply(R[k])
        for i, e in enumerate(ref):
            assert tuple(got[i].tolist()) == e.apply(R[k, i].tolist())
            np.testing.assert_array_equal(ba.last[i], e.last)
    for a, b in zip(ref, errs, strict=True):
        assert a.rng.bit_generator.state == b.rng.bit_generator.state


def test_imu_and_attitude_take_over_mid_block_and_respect_active():
    ref_i, imus = _imus(), _imus()
    ref_a, errs = _errs(), _errs()
    n, ticks = len(ref_i), 1500
    f, w = _readings(n, ticks)
    R = _rotations(n, ticks)
    for k in range(300):
        for i in range(n):
            assert ref_i[i].measure(f[k, i], w[k, i]) == imus[i].measure(f[k, i], w[k, i])
            assert ref_a[i].apply(R[k, i]) == errs[i].apply(R[k, i])
    bi, ba = BatchImu.from_sensors(imus), BatchAttitudeError.from_errors(errs)
    rng = np.random.default_rng(4)
    for k in range(300, ticks):
        act = rng.random(n) < 0.6
        f_before, r_before = bi.f_meas.copy(), ba.R_hat.copy()
        fm, _ = bi.measure(f[k], w[k], active=act)
        rh = ba.apply(R[k], active=act)
        for i in range(n):
            if act[i]:
                assert fm[i].tolist() == ref_i[i].measure(f[k, i], w[k, i])[0]
                assert tuple(rh[i].tolist()) == ref_a[i].apply(R[k, i])
            else:
                np.testing.assert_array_equal(fm[i], f_before[i])
                np.testing.assert_array_equal(rh[i], r_before[i])
    for a, b in zip(ref_i + ref_a, imus + errs, strict=True):
        assert a.rng.bit_generator.state == b.rng.bit_generator.state


def test_imu_and_attitude_rows_bit_identical_alone_and_in_a_batch_of_7():
    cfgs = (_cfgs() * 2)[:7]
    blocks = (BLOCKS * 2)[:7]
    seeds = list(range(100, 107))
    n, ticks = 7, 2500
    f, w = _readings(n, ticks)
    R = _rotations(n, ticks)
    bi = BatchImu.from_sensors(_imus(cfgs, blocks, seeds))
    ba = BatchAttitudeError.from_errors(_errs(cfgs, blocks, seeds))
    full_f, full_w, full_r, full_l = [], [], [], []
    for k in range(ticks):
        fm, wm = bi.measure(f[k], w[k])
        full_f.append(fm.copy())
        full_w.append(wm.copy())
        full_r.append(ba.apply(R[k]).copy())
        full_l.append(ba.last.copy())
    full_f, full_w, full_r, full_l = map(np.array, (full_f, full_w, full_r, full_l))
    for i in (1, 4, 6):
        s = slice(i, i + 1)
        bi1 = BatchImu.from_sensors(_imus(cfgs[s], blocks[s], seeds[s]))
        ba1 = BatchAttitudeError.from_errors(_errs(cfgs[s], blocks[s], seeds[s]))
        for k in range(ticks):
            fm, wm = bi1.measure(f[k, s], w[k, s])
            assert np.array_equal(fm[0], full_f[k, i]) and np.array_equal(wm[0], full_w[k, i])
            assert np.array_equal(ba1.apply(R[k, s])[0], full_r[k, i])
            assert np.array_equal(ba1.last[0], full_l[k, i])
