"""The vehicle: MJCF quadrotor compiled from ``models/quad.xml`` with the config applied (MjSpec).

``build_vehicle(cfg)`` returns the compiled ``MjModel`` plus the facts the controllers need
(mass, principal inertia, rotor layout, thrust limit) so that nothing downstream re-reads XML.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import mujoco
import numpy as np

from ..config import Config

MODEL_DIR = Path(__file__).resolve().parents[2] / "models"
MODEL_XML = MODEL_DIR / "quad.xml"
ROTORS = ("fr", "fl", "rl", "rr")
G = 9.81


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

    def __post_init__(self) -> None:
        if self.ctrl_mass is None:
            self.ctrl_mass = self.mass
        if self.ctrl_inertia is None:
            self.ctrl_inertia = self.inertia
        if self.ctrl_rotor_xy is None:
            self.ctrl_rotor_xy = list(self.rotor_xy)

    def info(self) -> dict:
        return {
            "mass_kg": round(self.mass, 4),
            "inertia_kgm2": [round(v, 4) for v in self.inertia],
            "rotor_xy_m": [[round(a, 4), round(b, 4)] for a, b in self.rotor_xy],
            "thrust_max_per_rotor_N": round(self.f_max, 3),
            "thrust_to_weight": round(4 * self.f_max / (self.mass * G), 3),
            "yaw_torque_coeff_m": self.k_yaw,
            "timestep_s": float(self.model.opt.timestep),
        }


def _compile(cfg: Config, f_max: float) -> mujoco.MjModel:
    """The MJCF with the vehicle keys applied (masses, tank and unknown payload, the liquid's
    body, the actuators), compiled, with the cameras' clipping planes pinned in metres."""
    spec = mujoco.MjSpec.from_file(str(MODEL_XML))
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
    for a in spec.actuators:
        a.ctrlrange = [0.0, f_max]
        a.dynprm[0] = v.motor_tau_s
        sign = 1.0 if a.gear[5] > 0 else -1.0
        eff = 1.0 - v.rotor_thrust_loss[ROTORS.index(a.name.removeprefix("thrust_"))]
        a.gear[2] = eff
        a.gear[5] = sign * v.yaw_torque_coeff_m * eff
    model = spec.compile()
    # MuJoCo's clipping planes are relative to the model extent: pin them in metres (5 cm near,
    # 800 m far) so the cameras neither clip the ground and the drone nor the field's far edge
    ext = float(model.stat.extent)
    model.vis.map.znear = 0.05 / ext
    model.vis.map.zfar = 800.0 / ext
    return model


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
    limit, stays ``f_max``.

    The physics model depends on the vehicle and simulation keys only, never on the field: the
    field outline and other scenery are drawn into the cameras' scene by
    :class:`ag_uav.record.render.Renderer` (``scenery=``), so every vehicle of an engine batch,
    whatever field it flies, has a model of the same sizes (one ``MjData`` layout per batch).
    """
    v = cfg.vehicle
    f_max = v.thrust_to_weight * v.mass_kg * G / 4.0
    model = _compile(cfg, f_max)
    body_id = model.body("drone").id
    # inertia tensor in body axes from the principal moments and their frame
    I_p = np.diag(model.body_inertia[body_id])
    Rq = np.zeros(9)
    mujoco.mju_quat2Mat(Rq, model.body_iquat[body_id])
    Rq = Rq.reshape(3, 3)
    I_body = Rq @ I_p @ Rq.T
    com = model.body_ipos[body_id]
    rotor_xy, spin = [], []
    for r in ROTORS:
        s = model.site(f"rotor_{r}")
        rotor_xy.append((float(s.pos[0] - com[0]), float(s.pos[1] - com[1])))
        act = model.actuator(f"thrust_{r}")
        spin.append(1 if act.gear[5] > 0 else -1)
    skids = tuple(model.geom(n).id for n in ("skid_l", "skid_r"))
    skid_bottom = -(model.geom("skid_l").pos[2] - model.geom("skid_l").size[0])
    veh = Vehicle(
        model=model, mass=float(model.body_subtreemass[body_id]),
        inertia=(float(I_body[0, 0]), float(I_body[1, 1]), float(I_body[2, 2])),
        rotor_xy=rotor_xy, spin=spin, k_yaw=v.yaw_torque_coeff_m, f_max=f_max, body_id=body_id,
        ground_geom=model.geom("ground").id, skid_geoms=skids, hover_z=float(skid_bottom) + 0.002,
    )
    if v.unknown_payload_kg > 0:  # the controller's model: the same vehicle without it
        import copy

        known = copy.deepcopy(cfg)
        known.vehicle.unknown_payload_kg = 0.0
        known.vehicle.unknown_payload_pos_m = [0.0, 0.0, 0.0]
        nom = build_vehicle(known)
        veh.ctrl_mass, veh.ctrl_inertia, veh.ctrl_rotor_xy = nom.mass, nom.inertia, nom.rotor_xy
    return veh
