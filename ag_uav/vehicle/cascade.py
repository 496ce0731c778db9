"""The flight controller of a vehicle: the per-axis position controllers named by
``controller.type`` (PID, type-1 or interval type-2 fuzzy PID, from :mod:`controllers`) in the
position → attitude → mixer cascade (the mixer allocates to the frame's rotors).

The gains are the configured ones, slowed as a whole for a vehicle whose motor lag would leave
the attitude loop under-damped (:func:`controllers.attitude.lag_time_scale`, :func:`time_scaled`;
the default M350's 0.04 s motors leave them as configured)."""

from __future__ import annotations

import dataclasses
import math
from typing import Any

from controllers.attitude import GeometricAttitudeController, XMixer, lag_time_scale
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


def time_scaled(g: AxisGains, s: float) -> AxisGains:
    """``g`` for the same loop run ``1/s`` times slower: the closed loop's response to an error
    ``e(t)`` becomes ``e(s t)`` (accelerations ``s²`` as large). The fuzzy inputs
    ``E = Ke e``, ``dE = Kd ė`` keep their values with ``Kd/s``; the output ``K0 U + K1 ∫U dt``
    (m/s²) takes ``K0 s²``, ``K1 s³``; a PID ``Kp s²``, ``Kd s``, ``Ki s³``. The integral's bound
    ``i_limit`` is kept: it is the acceleration the integral may spend against a steady force
    (the wind's drag), which does not shrink with the loop's speed (scaled by ``s²`` too, the
    octocopter's tracking RMSE on 150 s of the default mission read 0.26 m against 0.23 m)."""
    return dataclasses.replace(g, kd=g.kd / s, k0=g.k0 * s * s, k1=g.k1 * s ** 3,
                               kp=g.kp * s * s, kdd=g.kdd * s, ki=g.ki * s ** 3)


def cascade_time_scale(cfg: Config) -> float:
    """The time scale of ``cfg``'s cascade for its motor lag
    (:func:`controllers.attitude.lag_time_scale` on the roll and pitch attitude loops): 1 for
    the default M350, about 0.86 for the 10 L quad (0.08 s), 0.57 for the octocopter (0.12 s)."""
    a = cfg.controller.attitude
    return lag_time_scale(cfg.vehicle.motor_tau_s, a.wn[:2], a.zeta[:2])


def make_cascade(cfg: Config, veh: Vehicle) -> PositionCascade:
    c = cfg.controller
    xy, z, wn = c.xy, c.z, list(c.attitude.wn)
    s = cascade_time_scale(cfg)
    if s < 1.0:  # the motor lag: every loop slowed by s (1: the configured gains, untouched)
        xy, z, wn = time_scaled(xy, s), time_scaled(z, s), [w * s for w in wn]
    axes = [make_axis_controller(c.type, xy), make_axis_controller(c.type, xy),
            make_axis_controller(c.type, z)]
    # the controller's model of the vehicle (without vehicle.unknown_payload_*: model error)
    att = GeometricAttitudeController(veh.ctrl_inertia, wn=wn, zeta=c.attitude.zeta)
    mixer = XMixer(veh.ctrl_rotor_xy, veh.spin, veh.k_yaw, veh.f_max, veh.eff)
    return PositionCascade(axes, veh.ctrl_mass, G, att, mixer,
                           tilt_max=math.radians(c.tilt_max_deg),
                           accel_feedforward=c.accel_feedforward)
