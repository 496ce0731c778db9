"""The multirotor cascade: position controller per axis → acceleration → thrust and attitude →
attitude loop → X mixer.

Any object with ``update(error, dt, ...) -> float`` can be the per-axis position controller
(``IT2FPID``, ``FPID`` or ``PID``).
Their output is a commanded acceleration (m/s²) in the world frame, to which the reference
acceleration is added as feed-forward. Plain Python floats throughout (hot path).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Any, Protocol

from .attitude import GeometricAttitudeController, Mat3, XMixer, thrust_attitude


class AxisController(Protocol):
    def update(self, error: float, dt: float, measurement: float | None = None,
               error_rate: float | None = None) -> float: ...

    def reset(self) -> None: ...


class PositionCascade:
    """Outer position loop on three axes with the inner attitude loop and mixer.

    Parameters
    ----------
    axes: controllers for world x, y and z (errors in metres, outputs in m/s²).
    mass, g: vehicle mass (kg) and gravity (m/s²) for the thrust vector ``f = m(a + g e3)``.
    attitude: the inner attitude controller; mixer: the rotor allocation.
    tilt_max: tilt limit of the thrust vector (rad).
    accel_feedforward: add the reference acceleration to the command.
    a_limit: bound on each axis' commanded acceleration from the outer loop (m/s²).

    The error rate fed to each axis controller is ``v_ref − v`` (the fed-back velocity), not a
    finite difference of the position error: an estimated position jumps at every GPS fix.
    """

    def __init__(self, axes: Sequence[AxisController], mass: float, g: float,
                 attitude: GeometricAttitudeController, mixer: XMixer,
                 tilt_max: float = math.radians(30.0), accel_feedforward: bool = True,
                 a_limit: float = 6.0) -> None:
        self.axes = list(axes)
        self.mass = mass
        self.g = g
        self.attitude = attitude
        self.mixer = mixer
        self.tilt_max = tilt_max
        self.ff = 1.0 if accel_feedforward else 0.0
        self.a_limit = a_limit
        self.a_cmd = (0.0, 0.0, 0.0)
        self.thrust = 0.0
        self.tilt = 0.0
        self.R_d: Mat3 = (1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0)
        self.torque = (0.0, 0.0, 0.0)
        self._internal_keys: list | None = None

    def reset(self) -> None:
        for a in self.axes:
            a.reset()

    def update(self, p: Sequence[float], v: Sequence[float], R: Mat3, omega: Sequence[float],
               p_ref: Sequence[float], v_ref: Sequence[float], a_ref: Sequence[float],
               yaw_ref: float, dt: float) -> list[float]:
        """Rotor thrusts (N) for the fed-back state and the reference at this tick.

        ``p``, ``v``: position and velocity used for feedback (true or estimated), world frame.
        ``R``: body → world rotation (row-major 9-tuple); ``omega``: body rates (rad/s).
        """
        lim = self.a_limit
        ff = self.ff
        acc = []
        for i in range(3):
            e = p_ref[i] - p[i]
            u = self.axes[i].update(e, dt, p[i], v_ref[i] - v[i])
            if u > lim:
                u = lim
            elif u < -lim:
                u = -lim
            acc.append(u + ff * a_ref[i])
        self.a_cmd = (acc[0], acc[1], acc[2])
        R_d, f_norm, tilt = thrust_attitude(acc[0], acc[1], acc[2], yaw_ref, self.mass, self.g,
                                            self.tilt_max)
        self.R_d = R_d
        self.tilt = tilt
        # collective thrust: the desired force projected on the current body z axis
        T = f_norm * (R_d[2] * R[2] + R_d[5] * R[5] + R_d[8] * R[8])
        if T < 0.0:
            T = 0.0
        self.thrust = T
        tx, ty, tz = self.attitude.update(R, omega, R_d)
        self.torque = (tx, ty, tz)
        return self.mixer.mix(T, tx, ty, tz)

    def internals(self) -> dict[str, Any]:
        """Per-tick values for logs: per-axis controller state, command, thrust, tilt."""
        keys = self._internal_keys
        if keys is None:
            keys = self._internal_keys = [
                (f"{name}.{attr}", a, attr) for name, a in zip("xyz", self.axes, strict=True)
                for attr in ("E", "dE", "U", "integral", "u") if hasattr(a, attr)]
        out: dict[str, Any] = {k: getattr(a, attr) for k, a, attr in keys}
        out["ax_cmd"], out["ay_cmd"], out["az_cmd"] = self.a_cmd
        out["thrust"] = self.thrust
        out["tilt_cmd"] = self.tilt
        out["mixer_saturated"] = float(self.mixer.saturated)
        return out
