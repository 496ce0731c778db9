"""Batches equal solo runs, over any mix: every vehicle steps on data made for its
own model, and a run's whole mission depends on its config and seed only."""

from __future__ import annotations

import mujoco
import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

import ag_uav
from ag_uav.engine import loop
from ag_uav.engine.loop import Flight, fly
from ag_uav.engine.missions import batch_key, mission_setup, simulate, simulate_many
from ag_uav.engine.physics import RolloutStepper, check_data, model_signature
from ag_uav.jobs.batch import write_rect_field
from ag_uav.vehicle.mjcf import build_vehicle

FIELDS = ("default", "hole", "l-shape", "two-part")


def _cfg(seed: int = 0, **over) -> ag_uav.Config:
    c = ag_uav.load_config(None, {"log.render": False, "sim.max_time_s": 10.0, **over})
    c.log.enabled = False
    c.seed = seed
    return c


def _same_mission(a, b) -> None:
    """Two results of the same config and seed: bit for bit."""
    assert a.p_true.shape == b.p_true.shape
    assert np.array_equal(a.p_true, b.p_true)
    assert np.array_equal(a.p_fb, b.p_fb)
    assert np.array_equal(a.motors, b.motors)
    skip = {"wall_time_s", "loop_wall_time_s", "loop_cpu_time_s", "real_time_factor",
            "batch_size", "notes"}
    sa = {k: v for k, v in a.summary.items() if k not in skip and "update_us" not in k}
    sb = {k: v for k, v in b.summary.items() if k not in skip and "update_us" not in k}
    sa.pop("estimators", None), sb.pop("estimators", None)
    assert sa == sb
    for name, e in a.summary.get("estimators", {}).items():
        o = b.summary["estimators"][name]
        for k in ("estimate_rmse_m", "nees15_mean", "nis_mean"):
            assert o.get(k) == e.get(k)


@pytest.mark.parametrize("spray", [True, False])
def test_a_batch_over_fields_flies_every_vehicle_as_alone(spray):
    """The regression: the field outline was compiled into each physics model, and the rollout
    stepped every model with data made for vehicle 0's (hole rows crashed at t = 0.07 s, or
    were "ok" with a 27 m tracking error). Now the field is scenery and every row equals its
    solo run, in either order of the fields."""
    over = {"estimator.name": "true", "estimator.shadow": [], "spray.enabled": spray}
    cfgs = [_cfg(s, **{"mission.field": f, **over}) for f in FIELDS for s in (0, 1)]
    assert len({batch_key(c) for c in cfgs}) == 1
    many = simulate_many(cfgs)
    back = simulate_many(cfgs[::-1])[::-1]
    for c, r, r2 in zip(cfgs, many, back, strict=True):
        solo = simulate(c)
        assert not r.summary["crashed"], r.summary.get("crash_reason")
        _same_mission(solo, r)
        _same_mission(solo, r2)
        assert r.summary["tracking_rmse_m"] < 0.2


def test_the_physics_model_does_not_depend_on_the_field():
    sigs = set()
    for f in FIELDS:
        c = _cfg(**{"mission.field": f})
        sigs.add(model_signature(build_vehicle(c).model))
    assert len(sigs) == 1


def _model_with_extra_geom() -> mujoco.MjModel:
    from ag_uav.vehicle.mjcf import vehicle_mjspec
    from ag_uav.vehicle.spec import vehicle_spec

    spec = vehicle_mjspec(vehicle_spec(_cfg()))
    spec.worldbody.add_geom(type=mujoco.mjtGeom.mjGEOM_SPHERE, size=[0.1, 0, 0],
                            pos=[5, 5, 0.1], contype=0, conaffinity=0)
    return spec.compile()


def test_data_of_another_model_is_refused():
    m = build_vehicle(_cfg()).model
    other = _model_with_extra_geom()
    assert model_signature(m) != model_signature(other)
    with pytest.raises(ValueError, match="other sizes"):
        check_data(m, mujoco.MjData(other))
    check_data(m, mujoco.MjData(build_vehicle(_cfg()).model))  # same sizes: fine


def test_a_rollout_over_models_of_two_sizes_is_refused():
    veh = build_vehicle(_cfg())
    with pytest.raises(ValueError, match="other sizes"):
        RolloutStepper([veh.model, _model_with_extra_geom()], veh.body_id, 5, nthread=2)


def test_observers_see_the_same_data_alone_and_in_a_batch():
    """A tick hook gets the vehicle's up-to-date data (positions, sensors after mj_forward)
    whether it flies alone (direct stepper) or in a batch (rollout)."""
    def recorder(store):
        def hook(t, data):
            if int(round(t * 100)) % 50 == 0:
                store.append((t, data.time, data.qpos.copy(), data.xpos[1].copy(),
                              data.sensordata.copy(), data.ctrl.copy()))
        return hook

    c = _cfg(2, **{"sim.max_time_s": 3.0})
    ref = mission_setup(c)[2]
    alone: list = []
    fly([Flight(c, ref, 3.0, tick_hook=recorder(alone))])
    batch: list = []
    fly([Flight(_cfg(5), ref, 3.0), Flight(c, ref, 3.0, tick_hook=recorder(batch)),
         Flight(_cfg(7), ref, 3.0)])
    assert len(alone) == len(batch) >= 5
    for a, b in zip(alone, batch, strict=True):
        assert a[0] == b[0] and a[1] == pytest.approx(a[0] + 0.01)
        for x, y in zip(a[2:], b[2:], strict=True):
            assert np.array_equal(x, y)
        assert np.array_equal(a[3], a[2][:3])  # xpos is current: mj_forward ran


# ------------------------------------------------------------------------- property-based
_CONTROLLERS = ("it2-fpid", "t1-fpid", "pid")
_FILTER_SETS = (("true", []), ("pca-mckf", ["kf", "mckf", "pca-kf"]), ("kf", []),
                ("mckf", ["kf"]))
_GPS = ("rtk-m350", "rtk", "coloured-impulsive", "sbas")
_PRESETS = ("m350", "quad-10l", "x8-40l")


@st.composite
def _run(draw, rect: str):
    field = draw(st.sampled_from(FIELDS + (rect,)))
    name, shadow = draw(st.sampled_from(_FILTER_SETS))
    over = {
        "mission.field": field,
        "vehicle.preset": draw(st.sampled_from(_PRESETS)),
        "vehicle.payload_kg": draw(st.sampled_from([0.0, 1.2, 2.7])),
        "vehicle.motor_tau_s": draw(st.sampled_from([0.02, 0.04, 0.08])),
        "wind.speed_mps": draw(st.sampled_from([0.0, 3.0, 7.0])),
        "wind.turbulence": draw(st.sampled_from(["none", "light", "moderate"])),
        "gps.preset": draw(st.sampled_from(_GPS)),
        "controller.type": draw(st.sampled_from(_CONTROLLERS)),
        "estimator.name": name, "estimator.shadow": shadow,
        "spray.tank_l": draw(st.sampled_from([2.7, 0.02])),
        "spray.service_s": 0.0,
    }
    return _cfg(draw(st.integers(0, 2 ** 16)), **over)


@pytest.fixture(scope="module")
def rect_field(tmp_path_factory):
    return str(write_rect_field(tmp_path_factory.mktemp("f") / "rect.geojson", 40.0, 24.0))


@settings(max_examples=6, deadline=None, derandomize=True,
          suppress_health_check=[HealthCheck.function_scoped_fixture, HealthCheck.too_slow])
@given(data=st.data())
def test_any_mix_flies_every_vehicle_as_alone(rect_field, data):
    """Batches drawn over vehicle presets (quad, coaxial octo), fields (built-in and a file),
    payloads, motor lags, winds, GPS presets, filter sets and controllers, grouped by batch
    key as the batch runner does (a frame's model layout is part of it), one
    engine or split into lanes (each in a thread of its own): each vehicle's whole mission
    (sorties included) equals the same config flown alone."""
    cfgs = data.draw(st.lists(_run(rect_field), min_size=2, max_size=5))
    lane_min = data.draw(st.sampled_from([1, loop.LANE_MIN]), label="LANE_MIN")
    groups: dict[tuple, list[int]] = {}
    for i, c in enumerate(cfgs):
        groups.setdefault(batch_key(c), []).append(i)
    results: dict[int, object] = {}
    with pytest.MonkeyPatch.context() as mp:
        mp.setattr(loop, "LANE_MIN", lane_min)
        mp.setenv("AG_UAV_ENGINE_THREADS", "2")
        for idx in groups.values():
            for i, r in zip(idx, simulate_many([cfgs[i] for i in idx]), strict=True):
                results[i] = r
    for i, c in enumerate(cfgs):
        _same_mission(simulate(c), results[i])


def test_a_mixed_batch_with_sorties_equals_solo(rect_field):
    """Payloads, fields and tank sizes mixed in one engine batch, with refill sorties flown."""
    over = {"spray.tank_l": 0.02, "spray.service_s": 0.0, "sim.max_time_s": 45.0}
    cfgs = [_cfg(1, **{**over, "mission.field": rect_field}),
            _cfg(2, **{**over, "mission.field": "hole", "vehicle.payload_kg": 1.5}),
            _cfg(3, **{**over, "spray.tank_l": 2.7})]
    many = simulate_many(cfgs)
    assert max(r.summary["sorties"] for r in many) >= 2
    for c, r in zip(cfgs, many, strict=True):
        _same_mission(simulate(c), r)


def test_a_batch_of_octocopters_equals_solo(rect_field):
    """Eight-rotor vehicles (coaxial X8) in one engine batch, with a refill sortie: every rotor's
    command, state and summary equal the same config flown alone; the presets are grouped
    by their model layouts."""
    over = {"vehicle.preset": "x8-40l", "spray.tank_l": 0.01, "spray.service_s": 0.0,
            "sim.max_time_s": 45.0}
    cfgs = [_cfg(1, **{**over, "mission.field": rect_field}),
            _cfg(2, **{**over, "vehicle.payload_kg": 10.0}),
            _cfg(3, **{**over, "wind.speed_mps": 5.0})]
    assert len({batch_key(c) for c in cfgs}) == 1
    assert batch_key(_cfg(1)) != batch_key(cfgs[0])
    many = simulate_many(cfgs)
    assert max(r.summary["sorties"] for r in many) >= 2
    for c, r in zip(cfgs, many, strict=True):
        assert r.motors.shape[1] == 8 and not r.summary["crashed"]
        _same_mission(simulate(c), r)


def test_the_physics_replay_reproduces_the_flights_bit_for_bit():
    """``ag-uav bench`` measures the engine against MuJoCo alone replaying the very same flights
    (initial states, the controls handed to the physics each tick and the spray job's mass
    changes captured from the engine): the replay lands on the engine's states exactly, pool or
    lanes, so the reference really is the engine's own physics."""
    from ag_uav.engine.missions import fly_many
    from ag_uav.jobs.bench.physics import replay_physics

    over = {"spray.tank_l": 0.02, "spray.service_s": 0.0, "sim.max_time_s": 30.0}
    cfgs = [_cfg(s, **over) for s in (1, 2, 3)]
    outs = fly_many(cfgs, capture=True)
    assert any(o.sprayer.mass_events for o in outs)
    models = [o.vehicle.model for o in outs]
    body = outs[0].vehicle.body_id
    for way in (None, "lanes", "threads"):
        _, S = replay_physics(models, body, 5, [o.s0 for o in outs],
                              [o.controls[:-1] for o in outs], 2, way,
                              [o.sprayer for o in outs])
        for i, o in enumerate(outs):
            # the state after tick n-2's physics is the state tick n-1 recorded
            assert np.array_equal(S[i, 1:4], o.rec[-1, :3])


@pytest.mark.parametrize("lanes", [2, 3])
def test_lanes_change_nothing(lanes):
    """A batch split into lanes (engines over disjoint parts, each flying in a thread of its
    own) flies every vehicle as one engine does, on the truth and on the INS bank."""
    for name in ("true", "pca-mckf"):
        cfgs = [_cfg(s, **{"sim.max_time_s": 4.0, "estimator.name": name}) for s in range(5)]
        ref = mission_setup(cfgs[0])[2]
        one = fly([Flight(c, ref, 4.0) for c in cfgs], lanes=1)
        many = fly([Flight(c, ref, 4.0) for c in cfgs], lanes=lanes)
        for a, b in zip(one, many, strict=True):
            assert np.array_equal(a.rec, b.rec)
            assert (a.imu is None) == (b.imu is None)
            if a.imu is not None:
                assert np.array_equal(a.imu, b.imu)


def test_big_batches_fly_in_lanes_unless_watched(monkeypatch):
    """One lane per thread for batches of at least LANE_MIN vehicles per thread; a batch with
    an observer (a log, frames or a tick hook) stays one engine, served from this thread."""
    monkeypatch.setattr(loop, "LANE_MIN", 2)
    cfgs = [_cfg(s) for s in range(4)]
    ref = mission_setup(cfgs[0])[2]
    assert len(loop._lanes([Flight(c, ref, 1.0) for c in cfgs], 2, None)) == 2
    hooked = [Flight(c, ref, 1.0, tick_hook=(lambda t, d: None) if i == 0 else None)
              for i, c in enumerate(cfgs)]
    assert len(loop._lanes(hooked, 2, None)) == 1
    assert len(loop._lanes([Flight(c, ref, 1.0) for c in cfgs], 1, None)) == 1


def test_ins_scores_alone_and_beside_a_slower_receiver():
    """An INS batch mixing receivers of different fix rates (rtk-m350 and rtk): every vehicle's
    NEES and NIS records hold all its fixes, so its scores equal its solo run's (the records
    were once sized by the first vehicle's rate, and the faster receiver lost its later fixes;
    found by the property test above)."""
    base = {"estimator.name": "pca-mckf", "estimator.shadow": ["kf"], "sim.max_time_s": 8.0}
    cfgs = [_cfg(0, **base, **{"gps.preset": p}) for p in ("rtk-m350", "rtk")]
    for c, r in zip(cfgs, simulate_many(cfgs), strict=True):
        _same_mission(simulate(c), r)


def test_ins_runs_with_other_filter_settings_do_not_share_a_bank():
    """What an INS bank takes from its first vehicle (the filter settings, the radar) is in
    batch_key, and the bank refuses vehicles that differ in it."""
    from ag_uav.navigation.ins_feedback import InsFeedback
    from ag_uav.seeds import seed_sequences

    a = _cfg(0, **{"estimator.name": "pca-mckf"})
    b = _cfg(1, **{"estimator.name": "pca-mckf", "estimator.sigma": a.estimator.sigma * 2})
    assert batch_key(a) != batch_key(b)
    fbs = [InsFeedback(c, seed_sequences(c.seed)) for c in (a, b)]
    with pytest.raises(ValueError, match="INS banks differ"):
        InsFeedback.batch(fbs, 10)


def test_a_lane_that_fails_halts_the_others_and_its_error_reaches_the_caller():
    cfgs = [_cfg(s, **{"sim.max_time_s": 10.0}) for s in range(4)]
    ref = mission_setup(cfgs[0])[2]
    lanes = loop._lanes([Flight(c, ref, 10.0) for c in cfgs], 2, 2)
    tick = lanes[0].tick

    def broken(k):
        if k == 50:
            raise RuntimeError("lane 0 broke")
        return tick(k)

    lanes[0].tick = broken
    try:
        with pytest.raises(RuntimeError, match="lane 0 broke"):
            loop._run(lanes, None)
        assert lanes[1].halt and lanes[1].k < lanes[1].b.n_max - 1
    finally:
        for e in lanes:
            e.close()


def test_a_lane_left_alone_takes_up_the_idle_cores_and_flies_the_same():
    """Vehicle i flies in lane i mod L; when a lane's vehicles are all done, the lanes still
    flying are offered its core and their rollouts widen, with the same results."""
    cfgs = [_cfg(s, **{"sim.max_time_s": 10.0}) for s in range(4)]
    ref = mission_setup(cfgs[0])[2]
    durations = (1.0, 5.0, 1.0, 5.0)   # lane 0: vehicles 0 and 2 (short); lane 1: 1 and 3
    flights = [Flight(c, ref, d) for c, d in zip(cfgs, durations, strict=True)]
    lanes = loop._lanes(flights, 2, 2)
    assert [e.rows for e in lanes] == [[0, 2], [1, 3]]
    try:
        loop._run(lanes, None)
        assert lanes[1].stepper.nthread == 2 and lanes[0].stepper.nthread == 0
    finally:
        for e in lanes:
            e.close()
    one = fly([Flight(c, ref, d) for c, d in zip(cfgs, durations, strict=True)], lanes=1)
    two = fly([Flight(c, ref, d) for c, d in zip(cfgs, durations, strict=True)], lanes=2)
    for a, b in zip(one, two, strict=True):
        assert np.array_equal(a.rec, b.rec) and b.lanes == 2
