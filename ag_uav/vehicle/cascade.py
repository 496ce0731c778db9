"""The flight controller of a vehicle: the per-axis position controllers named by
``controller.type`` (PID, type-1 or interval type-2 fuzzy PID, from :mod:`controllers`) in the
position → attitude → mixer cascade (the mixer allocates to the frame's rotors)."""

from __future__ import annotations

import math
from typing import Any

from controllers.attitude import GeometricAttitudeController, XMixer
from controllers.cascade import PositionCascade
from controllers.factory import make_controller

from ..config import AxisGains, Config
from .mjcf import G, Vehicle


def make_axis_controller(kind: str, g: AxisGains) -> Any:
    """The per-axis position controller named by ``controller.type`` with its gains."""
    if kind == "pid":
        return make_controller("pid", Kp=g.kp, Ki=g.ki, Kd=g.kdd, i_limit=g.i_limit)
    if kind == "t1-fpid":
        return make_controller("t1-fpid", Ke=g.ke, Kd=g.kd, K0=g.k0, K1=g.k1, cm=g.cm,
                               i_limit=g.i_limit)
    return make_controller("it2-fpid", Ke=g.ke, Kd=g.kd, K0=g.k0, K1=g.k1, alpha=g.alpha,
                           zeta=g.zeta, cm=g.cm, reducer=g.reducer, i_limit=g.i_limit)


def make_cascade(cfg: Config, veh: Vehicle) -> PositionCascade:
    c = cfg.controller
    axes = [make_axis_controller(c.type, c.xy), make_axis_controller(c.type, c.xy),
            make_axis_controller(c.type, c.z)]
    # the controller's model of the vehicle (without vehicle.unknown_payload_*: model error)
    att = GeometricAttitudeController(veh.ctrl_inertia, wn=c.attitude.wn, zeta=c.attitude.zeta)
    mixer = XMixer(veh.ctrl_rotor_xy, veh.spin, veh.k_yaw, veh.f_max, veh.eff)
    return PositionCascade(axes, veh.ctrl_mass, G, att, mixer,
                           tilt_max=math.radians(c.tilt_max_deg),
                           accel_feedforward=c.accel_feedforward)
