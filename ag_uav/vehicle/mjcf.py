"""The vehicle: its MJCF generated from the vehicle spec with MuJoCo's MjSpec, compiled.

``build_vehicle(cfg)`` returns the compiled ``MjModel`` plus the facts the controllers need
(mass, principal inertia, rotor layout, thrust limit) so that nothing downstream re-reads XML.

The scene (options, sky, ground, light, materials) is ``models/scene.xml``, shared by every
vehicle; :func:`add_vehicle` adds the airframe of a :class:`~ag_uav.vehicle.spec.VehicleSpec`:
a central box (body, batteries, avionics), an arm tube and a motor per rotor, visual propeller
discs, two landing skids (the only geoms meant to touch the ground), the spray tank box, a site
and a thrust actuator per rotor and the IMU. For the ``m350`` preset it is the M350 RTK-class
model, field for field (``tests/test_vehicles.py`` compares the compiled models):

- mass 6.47 kg with two TB65 batteries (DJI spec sheet), max take-off 9.2 kg;
- diagonal wheelbase 895 mm: arm 0.4475 m, X layout, rotors at ±0.3164 m;
- propellers 2110s (21 in, 0.533 m): discs of radius 0.267 m (visual only);
- inertia from a mass distribution MuJoCo integrates from the geoms: a 3.97 kg central box
  (0.40 × 0.30 × 0.14 m), four 0.05 kg arms and four 0.575 kg motor+prop+ESC cylinders at the
  rotors: Ixx ≈ 0.27, Iyy ≈ 0.28, Izz ≈ 0.53 kg m² (``ag-uav config --model-info``);
- thrust: the actuator's control is the rotor's thrust (N), ``ctrlrange`` ``[0, f_max]`` with
  ``f_max = thrust_to_weight · m g / Σ e_i``; motor lag: a first-order filter on the command
  (``dyntype="filter"``, ``vehicle.motor_tau_s``, 0.04 s for 21 in propellers: an estimate);
- yaw reaction torque ``k f`` (``vehicle.yaw_torque_coeff_m``, 0.016 m = C_Q D / (2π C_T) for
  C_Q/C_T ≈ 0.19: an estimate), signs alternating around the frame (:mod:`ag_uav.vehicle.spec`).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import mujoco
import numpy as np

from ..config import Config
from .spec import VehicleSpec, vehicle_spec

MODEL_DIR = Path(__file__).resolve().parents[2] / "models"
SCENE_XML = MODEL_DIR / "scene.xml"
G = 9.81
_GEOM = mujoco.mjtGeom


@dataclass
class Vehicle:
    model: mujoco.MjModel
    mass: float                      # total, with payload (kg)
    inertia: tuple[float, float, float]  # body-axis diagonal of the inertia tensor (kg m²)
    rotor_xy: list[tuple[float, float]]  # rotor positions about the centre of mass (m)
    spin: list[int]                  # +1: yaw reaction torque +k f (rotor spins clockwise)
    k_yaw: float
    f_max: float                     # per-rotor thrust limit (N)
    body_id: int
    ground_geom: int
    skid_geoms: tuple[int, ...]
    hover_z: float                   # z of the body frame resting on the skids (m)
    #: the flight controller's model of the vehicle: mass (kg), inertia (kg m²) and rotor arms
    #: about its centre of mass without the ``vehicle.unknown_payload_*`` (None: the above)
    ctrl_mass: float | None = None
    ctrl_inertia: tuple[float, float, float] | None = None
    ctrl_rotor_xy: list[tuple[float, float]] | None = None
    #: each rotor's thrust per unit command known to the controller (coaxial lower rotors)
    eff: list[float] = field(default_factory=lambda: [1.0] * 4)
    spec: VehicleSpec | None = None

    def __post_init__(self) -> None:
        if self.ctrl_mass is None:
            self.ctrl_mass = self.mass
        if self.ctrl_inertia is None:
            self.ctrl_inertia = self.inertia
        if self.ctrl_rotor_xy is None:
            self.ctrl_rotor_xy = list(self.rotor_xy)

    @property
    def n_rotors(self) -> int:
        return len(self.rotor_xy)

    def info(self) -> dict:
        out = {
            "mass_kg": round(self.mass, 4),
            "inertia_kgm2": [round(v, 4) for v in self.inertia],
            "rotor_xy_m": [[round(a, 4), round(b, 4)] for a, b in self.rotor_xy],
            "thrust_max_per_rotor_N": round(self.f_max, 3),
            "thrust_to_weight": round(sum(self.eff) * self.f_max / (self.mass * G), 3),
            "yaw_torque_coeff_m": self.k_yaw,
            "timestep_s": float(self.model.opt.timestep),
        }
        if self.spec is not None and self.spec.preset != "m350":
            out["vehicle"] = self.spec.info()
        return out


def _r4(v: float) -> float:
    return round(v, 4)


#: the arm tube starts at this share of the arm (the central box's edge)
ARM_ROOT = 0.316


def _add_rotors(body: mujoco.MjsBody, sp: VehicleSpec) -> None:
    """Arms, motors and propeller discs of ``sp`` (geom order: arms, motors, discs)."""
    s = sp.scale
    h = sp.rotors[0].z
    for (x, y), r in zip(sp.arms, sp.rotors, strict=False):
        body.add_geom(name=f"arm_{r.name.split('_')[0]}", type=_GEOM.mjGEOM_CAPSULE,
                      fromto=[_r4(x * ARM_ROOT), _r4(y * ARM_ROOT), _r4(h - 0.05 * s), x, y,
                              _r4(h - 0.05 * s)],
                      size=[_r4(0.02 * s), 0, 0], mass=sp.arm_mass_kg, material="arm")
    for r in sp.rotors:
        dz = 0.03 * s if r.z == h else -0.03 * s  # upper motors under, lower ones over, the arm
        body.add_geom(name=f"motor_{r.name}", type=_GEOM.mjGEOM_CYLINDER,
                      pos=[r.x, r.y, _r4(r.z - dz)], size=[_r4(0.045 * s), _r4(0.03 * s), 0],
                      mass=sp.rotor_mass_kg, material="frame")
    for r in sp.rotors:
        dz = 0.005 * s if r.z == h else -0.005 * s
        body.add_geom(name=f"prop_{r.name}", type=_GEOM.mjGEOM_CYLINDER,
                      pos=[r.x, r.y, _r4(r.z + dz)],
                      size=[round(sp.rotor_diameter_m / 2, 3), 0.003, 0], contype=0,
                      conaffinity=0, mass=0, material="prop_ccw" if r.spin < 0 else "prop_cw")


def add_vehicle(spec: mujoco.MjSpec, sp: VehicleSpec) -> mujoco.MjsBody:
    """The airframe of ``sp`` into the scene ``spec`` (module docstring); returns its body."""
    s = sp.scale
    c = max(1.0, s)  # the chase camera backs off for big vehicles
    body = spec.worldbody.add_body(name="drone", pos=[0, 0, _r4(0.33 * s)])
    body.add_freejoint(name="root")
    for name, mode, pos, fovy, axes in (
            ("chase", mujoco.mjtCamLight.mjCAMLIGHT_TRACKCOM, [-4 * c, -4 * c, 2.5 * c], 50,
             [0.707, -0.707, 0, 0.286, 0.286, 0.915]),  # follows the position, world-oriented
            ("down", mujoco.mjtCamLight.mjCAMLIGHT_FIXED, [0, 0, _r4(-0.215 * s)], 70,
             [0, -1, 0, 1, 0, 0])):  # nadir, under the body, image up = forward
        cam = body.add_camera(name=name, mode=mode, pos=pos, fovy=fovy)
        cam.alt.type = mujoco.mjtOrientation.mjORIENTATION_XYAXES
        cam.alt.xyaxes = axes
    body.add_geom(name="body", type=_GEOM.mjGEOM_BOX,
                  size=[_r4(0.20 * s), _r4(0.15 * s), _r4(0.07 * s)], mass=sp.body_mass_kg,
                  material="frame")
    _add_rotors(body, sp)
    for side, y in (("l", 1.0), ("r", -1.0)):  # landing gear: legs, then skids
        body.add_geom(name=f"leg_{side}", type=_GEOM.mjGEOM_CAPSULE,
                      fromto=[0, _r4(y * 0.15 * s), _r4(-0.07 * s), 0, _r4(y * 0.22 * s),
                              _r4(-0.30 * s)],
                      size=[_r4(0.012 * s), 0, 0], mass=0, contype=0, conaffinity=0,
                      material="arm")
    for side, y in (("l", 1.0), ("r", -1.0)):
        body.add_geom(name=f"skid_{side}", type=_GEOM.mjGEOM_CAPSULE,
                      fromto=[_r4(-0.25 * s), _r4(y * 0.22 * s), _r4(-0.31 * s),
                              _r4(0.25 * s), _r4(y * 0.22 * s), _r4(-0.31 * s)],
                      size=[_r4(0.015 * s), 0, 0], mass=0, material="arm")
    body.add_geom(name="tank", type=_GEOM.mjGEOM_BOX, pos=[0, 0, _r4(-0.14 * s)],
                  size=[_r4(0.10 * s), _r4(0.08 * s), _r4(0.06 * s)], mass=0.001,
                  contype=0, conaffinity=0, material="tank")
    for r in sp.rotors:
        body.add_site(name=f"rotor_{r.name}", pos=[r.x, r.y, r.z])
    body.add_site(name="imu", pos=[0, 0, 0])
    for r in sp.rotors:
        spec.add_actuator(name=f"thrust_{r.name}", target=f"rotor_{r.name}",
                          trntype=mujoco.mjtTrn.mjTRN_SITE,
                          gear=[0, 0, 1, 0, 0, r.spin * sp.k_yaw],
                          ctrlrange=[0, 31.73], dyntype=mujoco.mjtDyn.mjDYN_FILTER,
                          dynprm=[sp.motor_tau_s] + [0] * 9)
    spec.add_sensor(name="accel", type=mujoco.mjtSensor.mjSENS_ACCELEROMETER,
                    objtype=mujoco.mjtObj.mjOBJ_SITE, objname="imu")
    spec.add_sensor(name="gyro", type=mujoco.mjtSensor.mjSENS_GYRO,
                    objtype=mujoco.mjtObj.mjOBJ_SITE, objname="imu")
    return body


def vehicle_mjspec(sp: VehicleSpec) -> mujoco.MjSpec:
    """The scene with ``sp``'s airframe (before the config's run-time keys are applied)."""
    spec = mujoco.MjSpec.from_file(str(SCENE_XML))
    add_vehicle(spec, sp)
    return spec


def _compile(cfg: Config, f_max: float, sp: VehicleSpec) -> mujoco.MjModel:
    """The MJCF with the vehicle keys applied (masses, tank and unknown payload, the liquid's
    body, the actuators), compiled, with the cameras' clipping planes pinned in metres."""
    spec = vehicle_mjspec(sp)
    v = cfg.vehicle
    spec.option.timestep = cfg.sim.timestep_s
    # scale the dry mass of the airframe geoms so the total equals mass_kg, payload in the tank
    body = spec.body("drone")
    geoms = [g for g in body.geoms]
    dry = sum(g.mass for g in geoms if g.name != "tank")
    for g in geoms:
        if g.name == "tank":
            g.mass = max(v.payload_kg, 1e-3)
        else:
            g.mass = g.mass * v.mass_kg / dry
    tank = spec.geom("tank")
    tank_pos0 = list(tank.pos)
    if v.unknown_payload_kg > 0:  # lumped into the tank box at the mass-weighted position
        m_t, m_u = tank.mass, v.unknown_payload_kg
        tank.pos = [(m_t * a + m_u * b) / (m_t + m_u)
                    for a, b in zip(tank_pos0, v.unknown_payload_pos_m, strict=True)]
        tank.mass = m_t + m_u
    # the tank's liquid: its own body welded under the airframe at the tank (no joint), massless
    # here; ag_uav.engine.sprayer.Sprayer sets its mass and inertia at run time as the tank drains
    liq = body.add_body(name="liquid", pos=tank_pos0)
    liq.explicitinertial = True
    liq.mass = 1e-6
    liq.inertia = [1e-9, 1e-9, 1e-9]
    for a, r in zip(spec.actuators, sp.rotors, strict=True):
        a.ctrlrange = [0.0, f_max]
        a.dynprm[0] = v.motor_tau_s
        sign = 1.0 if a.gear[5] > 0 else -1.0
        eff = (1.0 - v.rotor_thrust_loss[sp.rotors.index(r)]) * r.eff
        a.gear[2] = eff
        a.gear[5] = sign * v.yaw_torque_coeff_m * eff
    if sp.inertia_kgm2 is not None:
        _given_inertia(spec, body, sp.inertia_kgm2)
    model = spec.compile()
    # MuJoCo's clipping planes are relative to the model extent: pin them in metres (5 cm near,
    # 800 m far) so the cameras neither clip the ground and the drone nor the field's far edge
    ext = float(model.stat.extent)
    model.vis.map.znear = 0.05 / ext
    model.vis.map.zfar = 800.0 / ext
    return model


def _given_inertia(spec: mujoco.MjSpec, body: mujoco.MjsBody,
                   inertia: tuple[float, float, float]) -> None:
    """``vehicle.inertia_kgm2``: the airframe body's inertia given (body axes about its centre
    of mass, which the geoms still place), its mass the geoms' (payload included)."""
    m = spec.compile()
    b = m.body("drone").id
    body.explicitinertial = True
    body.mass = float(m.body_mass[b])
    body.ipos = [float(x) for x in m.body_ipos[b]]
    body.iquat = [1.0, 0.0, 0.0, 0.0]
    body.inertia = list(inertia)


def build_vehicle(cfg: Config) -> Vehicle:
    """Compile the MJCF with the config applied.

    Model error the controller does not know: ``vehicle.unknown_payload_kg`` is added to the tank
    geom's mass and, at ``vehicle.unknown_payload_pos_m``, shifts the centre of mass (the tank
    box moves to the payload's mass-weighted position, so the composite centre of mass is where
    the known tank payload and the unknown mass put it); the ``ctrl_*`` facts of the returned
    vehicle are those of the same config without it (what :func:`ag_uav.vehicle.cascade.
    make_cascade` and the spray job's mass updates give the controller).
    ``vehicle.rotor_thrust_loss`` scales each rotor's actuator (thrust and yaw torque per unit of
    command) by ``1 − loss``: the command range, and so the controller's idea of the thrust
    limit, stays ``f_max``. A coaxial pair's lower rotor is scaled by its ``eff`` (the coaxial
    efficiency), which the controller knows (``Vehicle.eff``).

    The physics model depends on the vehicle and simulation keys only, never on the field: the
    field outline and other scenery are drawn into the cameras' scene by
    :class:`ag_uav.record.render.Renderer` (``scenery=``), so every vehicle of an engine batch,
    whatever field it flies, has a model of the same sizes (one ``MjData`` layout per batch).
    """
    v = cfg.vehicle
    sp = vehicle_spec(cfg)
    f_max = sp.f_max
    model = _compile(cfg, f_max, sp)
    body_id = model.body("drone").id
    # inertia tensor in body axes from the principal moments and their frame
    I_p = np.diag(model.body_inertia[body_id])
    Rq = np.zeros(9)
    mujoco.mju_quat2Mat(Rq, model.body_iquat[body_id])
    Rq = Rq.reshape(3, 3)
    I_body = Rq @ I_p @ Rq.T
    com = model.body_ipos[body_id]
    rotor_xy, spin = [], []
    for r in sp.rotors:
        s = model.site(f"rotor_{r.name}")
        rotor_xy.append((float(s.pos[0] - com[0]), float(s.pos[1] - com[1])))
        act = model.actuator(f"thrust_{r.name}")
        spin.append(1 if act.gear[5] > 0 else -1)
    skids = tuple(model.geom(n).id for n in ("skid_l", "skid_r"))
    skid_bottom = -(model.geom("skid_l").pos[2] - model.geom("skid_l").size[0])
    veh = Vehicle(
        model=model, mass=float(model.body_subtreemass[body_id]),
        inertia=(float(I_body[0, 0]), float(I_body[1, 1]), float(I_body[2, 2])),
        rotor_xy=rotor_xy, spin=spin, k_yaw=v.yaw_torque_coeff_m, f_max=f_max, body_id=body_id,
        ground_geom=model.geom("ground").id, skid_geoms=skids, hover_z=float(skid_bottom) + 0.002,
        eff=[r.eff for r in sp.rotors], spec=sp,
    )
    if v.unknown_payload_kg > 0:  # the controller's model: the same vehicle without it
        import copy

        known = copy.deepcopy(cfg)
        known.vehicle.unknown_payload_kg = 0.0
        known.vehicle.unknown_payload_pos_m = [0.0, 0.0, 0.0]
        nom = build_vehicle(known)
        veh.ctrl_mass, veh.ctrl_inertia, veh.ctrl_rotor_xy = nom.mass, nom.inertia, nom.rotor_xy
    return veh
