"""Vehicles from one spec: the generated M350 equals the hand-written model it replaces, the
presets' models carry the spec's masses and inertias, and one allocation law serves every
frame."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import mujoco
import numpy as np
import pytest

from ag_uav.config import ConfigError, load_config
from ag_uav.config.vehicles import PRESETS
from ag_uav.vehicle.mjcf import MODEL_DIR, build_vehicle
from ag_uav.vehicle.spec import rotor_layout, vehicle_spec
from controllers.attitude import XMixer

FIXTURE = Path(__file__).parent / "data" / "quad_m350.xml"
FRAMES = ("quad-x", "hexa-x", "octo-x8")


def _hand_written_m350(cfg) -> mujoco.MjModel:
    """The hand-written M350 model with the config's run-time keys applied as the product
    applied them to it (dry mass scaled to mass_kg, tank payload, liquid body, actuators)."""
    spec = mujoco.MjSpec.from_string(
        FIXTURE.read_text(), assets={"crop_rows.png": (MODEL_DIR / "crop_rows.png").read_bytes()})
    v = cfg.vehicle
    body = spec.body("drone")
    geoms = list(body.geoms)
    dry = sum(g.mass for g in geoms if g.name != "tank")
    for g in geoms:
        g.mass = max(v.payload_kg, 1e-3) if g.name == "tank" else g.mass * v.mass_kg / dry
    liq = body.add_body(name="liquid", pos=list(spec.geom("tank").pos))
    liq.explicitinertial = True
    liq.mass = 1e-6
    liq.inertia = [1e-9, 1e-9, 1e-9]
    f_max = v.thrust_to_weight * v.mass_kg * 9.81 / 4.0
    for a in spec.actuators:
        a.ctrlrange = [0.0, f_max]
        a.dynprm[0] = v.motor_tau_s
    m = spec.compile()
    ext = float(m.stat.extent)
    m.vis.map.znear = 0.05 / ext
    m.vis.map.zfar = 800.0 / ext
    return m


def test_generated_m350_compiles_to_the_hand_written_model_field_for_field():
    cfg = load_config()
    new = build_vehicle(cfg).model
    old = _hand_written_m350(cfg)
    differ, n = [], 0
    for k in dir(old):
        a = getattr(old, k)
        if k.startswith("_") or k in ("paths", "npaths"):  # where the texture file was read
            continue
        if isinstance(a, np.ndarray):
            n += 1
            b = getattr(new, k)
            if a.shape != b.shape or not np.array_equal(a, b, equal_nan=True):
                differ.append(k)
        elif isinstance(a, int | float | bytes) and a != getattr(new, k):
            differ.append(k)
    assert n > 400 and not differ, differ
    for part in ("opt", "vis", "stat"):
        o, w = getattr(old, part), getattr(new, part)
        for k in dir(o):
            x = getattr(o, k)
            if not k.startswith("_") and isinstance(x, int | float | np.ndarray):
                assert np.array_equal(x, getattr(w, k)), f"{part}.{k}"


@pytest.mark.parametrize("preset", sorted(PRESETS))
def test_generated_model_mass_equals_the_spec(preset):
    cfg = load_config(overrides={"vehicle.preset": preset})
    veh = build_vehicle(cfg)
    sp = vehicle_spec(cfg)
    m = veh.model
    assert m.nu == sp.n_rotors == len(cfg.vehicle.rotor_thrust_loss)
    drone = m.body("drone").id
    # airframe + batteries, the empty tank's 1 g placeholder, the 1 mg liquid body
    assert m.body_subtreemass[drone] == pytest.approx(sp.mass_kg + 1e-3 + 1e-6, abs=1e-9)
    geoms = [m.geom(i) for i in range(m.ngeom) if m.geom_bodyid[i] == drone]
    rotors = [g for g in geoms if g.name.startswith("motor_")]
    assert len(rotors) == sp.n_rotors
    assert all(float(g.size[0]) > 0 for g in rotors)
    assert float(m.geom("body").size[0]) > 0
    # every rotor's actuator: f_max with the coaxial loss in its gear
    for r, a in zip(sp.rotors, range(m.nu), strict=True):
        assert m.actuator_gear[a, 2] == r.eff
        assert m.actuator_ctrlrange[a, 1] == pytest.approx(sp.f_max)
    assert sum(r.eff for r in sp.rotors) * sp.f_max == pytest.approx(
        cfg.vehicle.thrust_to_weight * sp.mass_kg * 9.81)


@pytest.mark.parametrize("preset", sorted(PRESETS))
def test_a_given_inertia_is_the_models(preset):
    inertia = [0.9, 1.3, 2.1] if preset == "m350" else [7.0, 9.0, 14.0]
    cfg = load_config(overrides={"vehicle.preset": preset, "vehicle.inertia_kgm2": inertia})
    veh = build_vehicle(cfg)
    b = veh.model.body("drone").id
    assert veh.model.body_inertia[b].tolist() == inertia
    assert veh.mass == pytest.approx(cfg.vehicle.mass_kg + 1e-3 + 1e-6, abs=1e-9)
    assert veh.inertia == pytest.approx(tuple(inertia), rel=1e-12)


def _mixer(frame: str, f_max: float = 60.0) -> tuple[XMixer, np.ndarray]:
    rotors, _ = rotor_layout(frame, 0.8, 0.1, 0.3, 0.8)
    pos = [(r.x, r.y) for r in rotors]
    mix = XMixer(pos, [r.spin for r in rotors], 0.03, f_max, [r.eff for r in rotors])
    return mix, mix.A


@pytest.mark.parametrize("frame", FRAMES)
def test_allocation_reproduces_the_commanded_wrench_when_unsaturated(frame):
    mix, B = _mixer(frame)
    rng = np.random.default_rng(3)
    n = B.shape[1]
    for _ in range(200):
        w = np.array([rng.uniform(0.3, 0.7) * 60.0 * n * 0.8, *rng.uniform(-3, 3, 2),
                      rng.uniform(-1, 1)])
        f = np.array(mix.mix(*w))
        assert not mix.saturated
        assert np.allclose(B @ f, w, atol=1e-9)
    # a pure yaw command rolls and pitches nothing
    f = np.array(mix.mix(0.5 * 60.0 * n * 0.8, 0.0, 0.0, 1.0))
    assert np.allclose((B @ f)[1:3], 0.0, atol=1e-12)


@pytest.mark.parametrize("frame", FRAMES)
def test_saturated_allocation_keeps_roll_and_pitch(frame):
    mix, B = _mixer(frame)
    n = B.shape[1]
    T = 0.9 * 60.0 * sum(B[0])
    for tx, ty, tz in ((12.0, 0.0, 8.0), (0.0, -10.0, -8.0), (7.0, 7.0, 10.0)):
        f = np.array(mix.mix(T, tx, ty, tz))
        assert mix.saturated
        assert np.all(f >= -1e-12) and np.all(f <= 60.0 + 1e-12)
        got = B @ f
        assert got[1:3] == pytest.approx([tx, ty], abs=1e-9)   # roll/pitch kept
        assert abs(got[3]) < abs(tz) + 1e-12                     # yaw gives way first
        assert len(f) == n


def test_the_quad_allocation_is_the_x_mixers_inverse():
    mix, B = _mixer("quad-x")
    assert np.array_equal(np.array(mix.Ainv), np.linalg.inv(B))


def test_a_preset_fills_what_the_config_leaves_unset():
    c = load_config(overrides={"vehicle.preset": "x8-40l", "spray.tank_l": 30.0})
    assert c.vehicle.frame == "octo-x8" and c.vehicle.mass_kg == 50.0
    assert c.spray.tank_l == 30.0                      # the config's own key wins
    assert c.battery.capacity_wh == 1566.0
    assert load_config().vehicle == load_config(overrides={"vehicle.preset": "m350"}).vehicle


@pytest.mark.parametrize("key,value,words", [
    ("vehicle.preset", "t99", "allowed: m350, quad-10l, x8-40l"),
    ("vehicle.frame", "tri", "allowed: quad-x, hexa-x, octo-x8"),
    ("vehicle.rotor_thrust_loss", [0.1, 0.0], "4 for vehicle.frame"),
    ("vehicle.inertia_kgm2", [1.0, 2.0], "expected [Ixx, Iyy, Izz]"),
    ("vehicle.rotor_mass_kg", 2.0, "must weigh less than vehicle.mass_kg"),
    ("vehicle.battery_mass_kg", 4.0, "must be less than vehicle.mass_kg = 6.47"),
    ("vehicle.coaxial_efficiency", 1.5, "must be <= 1.0"),
])
def test_bad_vehicle_values_are_named(key, value, words):
    with pytest.raises(ConfigError, match=None) as e:
        load_config(overrides={key: value})
    assert key in str(e.value) and words in str(e.value)


def test_bad_vehicle_value_on_the_command_line_is_one_line_and_exit_2():
    r = subprocess.run([sys.executable, "-m", "ag_uav.cli", "fly", "--no-log",
                        "--set", "vehicle.frame=tri"], capture_output=True, text=True)
    assert r.returncode == 2
    assert r.stderr.strip().count("\n") == 0 and "vehicle.frame" in r.stderr
