"""Tests for ag_uav.world.reference: smoothness, bounds, spray flags, cross-track."""

import math

import numpy as np
import pytest

from ag_uav.world.field import Field, load_field
from ag_uav.world.plan import plan_coverage
from ag_uav.world.reference import Reference


@pytest.fixture(scope="module")
def ref():
    return Reference(plan_coverage(load_field("default")), speed=5.0, altitude=3.0, a_max=1.5)


@pytest.fixture(scope="module")
def dense(ref):
    t = np.arange(0.0, ref.duration, 0.0037)
    return t, ref.sample_all(t)


def test_bounded_acceleration_and_speed(ref, dense):
    _, s = dense
    assert np.max(np.linalg.norm(s["acc"], axis=1)) <= ref.a_max * (1 + 1e-3)
    assert np.max(np.linalg.norm(s["vel"], axis=1)) <= ref.speed * (1 + 1e-6)
    assert np.max(np.linalg.norm(s["vel"], axis=1)) > 0.99 * ref.speed
    jerk = np.diff(ref.accelerations, axis=0) / ref.dt
    assert np.max(np.linalg.norm(jerk, axis=1)) <= 2 * ref.a_max / ref.window * 1.05


def test_continuous_and_consistent(ref, dense):
    t, s = dense
    dt = np.diff(t)[:, None]
    dv = np.linalg.norm(np.diff(s["vel"], axis=0), axis=1)
    assert np.max(dv) <= ref.a_max * dt[0, 0] * 1.01  # no velocity jumps anywhere
    # velocity is the derivative of position (central differences)
    v_fd = np.diff(s["pos"], axis=0) / dt
    v_mid = 0.5 * (s["vel"][1:] + s["vel"][:-1])
    assert np.max(np.abs(v_fd - v_mid)) < 0.02
    a_fd = np.diff(s["vel"], axis=0) / dt
    a_mid = 0.5 * (s["acc"][1:] + s["acc"][:-1])
    assert np.max(np.abs(a_fd - a_mid)) < 0.1
    yaw_steps = np.abs((np.diff(s["yaw"]) + math.pi) % (2 * math.pi) - math.pi)
    assert np.max(yaw_steps) < ref.yaw_rate_max * dt[0, 0] * 1.2


def test_takeoff_reaches_end_and_hovers(ref):
    plan = ref.plan
    s0 = ref.sample(0.0)
    assert np.allclose(s0.pos, [*plan.start, 0.0]) and np.allclose(s0.vel, 0)
    end = ref.sample(ref.duration)
    assert np.allclose(end.pos, [*plan.end, ref.altitude], atol=1e-6)
    assert np.allclose(end.vel, 0, atol=1e-9) and not end.spray and end.seg == -1
    hover = ref.sample(ref.duration - 0.5 * ref.hover_time)
    assert np.allclose(hover.pos, end.pos, atol=1e-6)
    assert ref.duration > plan.length / ref.speed
    assert ref.sample(ref.duration + 10.0).pos == pytest.approx(end.pos)


def test_spray_flags_follow_segments(ref, dense):
    _, s = dense
    kinds = np.array([seg.kind for seg in ref.plan.segments] + ["none"])
    k = kinds[s["seg"]]
    assert not np.any(s["spray"][np.isin(k, ["turn", "transit", "none"])])
    assert np.all(s["spray"][np.isin(k, ["leg", "headland"])])
    assert np.any(s["spray"]) and (k == "turn").any()
    # on a leg, away from its ends, yaw is the leg heading
    j = next(i for i, g in enumerate(ref.plan.segments) if g.kind == "leg")
    leg = ref.plan.segments[j].points
    mid = 0.5 * (leg[0] + leg[-1])
    i = np.argmin(np.linalg.norm(ref.positions[:, :2] - mid, axis=1))
    heading = math.atan2(*(leg[-1] - leg[0])[::-1])
    assert abs((ref.yaws[i] - heading + math.pi) % (2 * math.pi) - math.pi) < 1e-3


def test_sample_matches_sample_all(ref):
    rng = np.random.default_rng(1)
    ts = rng.uniform(0, ref.duration, 200)
    allv = ref.sample_all(ts)
    for n, t in enumerate(ts):
        s = ref.sample(float(t))
        assert np.allclose(s.pos, allv["pos"][n]) and np.allclose(s.acc, allv["acc"][n])
        assert abs((s.yaw - allv["yaw"][n] + math.pi) % (2 * math.pi) - math.pi) < 1e-9


def test_cross_track_sign_and_reference_deviation(ref):
    j = next(i for i, g in enumerate(ref.plan.segments) if g.kind == "leg")
    a, b = ref.plan.segments[j].points[[0, -1]]
    u = (b - a) / np.linalg.norm(b - a)
    left = np.array([-u[1], u[0]])
    mid = 0.5 * (a + b)
    pts = np.array([mid + 0.7 * left, mid - 1.3 * left, mid])
    assert ref.cross_track(pts, j) == pytest.approx([0.7, -1.3, 0.0], abs=1e-9)
    ct = ref.cross_track(ref.positions[:, :2], ref.seg_indices)
    assert np.all(np.isnan(ct[ref.seg_indices < 0]))
    assert np.nanmax(np.abs(ct)) < 0.3  # fillets cut corners by ≤ max_deviation


def test_other_limits_and_stop_turns():
    f = Field.from_coords([(0, 0), (60, 0), (60, 40), (0, 40)])
    r = Reference(plan_coverage(f, turn="stop"), speed=3.0, a_max=0.8, altitude=2.0,
                  takeoff=False, hover_time=1.0)
    t = np.arange(0, r.duration, 0.005)
    s = r.sample_all(t)
    assert np.max(np.linalg.norm(s["acc"], axis=1)) <= 0.8 * (1 + 1e-3)
    assert np.max(np.linalg.norm(s["vel"], axis=1)) <= 3.0 * (1 + 1e-6)
    assert np.allclose(s["pos"][:, 2], 2.0)
    assert r.n_stops >= 4
