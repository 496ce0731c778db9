"""The multirotor cascade: position controller per axis → acceleration → thrust and attitude →
attitude loop → mixer (n rotors); :func:`vehicle_step` is its one implementation, on one vehicle's
parameter row and state row.

Per tick (:func:`vehicle_step`):

* per world axis ``k``: ``e = p_ref − p``, error rate ``v_ref − v`` (used as the derivative:
  an estimated position jumps at every GPS fix), the axis law
  :func:`controllers.axis.axis_step` (PID, type-1 FPID or IT2-FPID);
* :func:`command_step`: clip each axis output to ``±a_limit``, add ``ff·a_ref``;
  :func:`controllers.attitude.thrust_attitude` (tilt limit, ``f_z ≥ 0.2 m g``); collective
  ``T = |f| (R_d e3)·(R e3)`` floored at 0;
* :func:`controllers.attitude.attitude_step` (geometric attitude torques);
* :func:`controllers.attitude.mix_step` (the allocation to the frame's rotors with its
  saturation priority).

:class:`PositionCascade` is the scalar shell (a batch of one): it owns one row and adopts its
axis controllers', attitude controller's and mixer's blocks (:class:`controllers.rows.RowBlocks`:
they become views of the row), so
one compiled call advances the whole cascade. Axis controllers of other classes (any object
with ``update(error, dt, measurement, error_rate) -> float``), or an attitude controller / mixer
of a subclass, are called through their own ``update`` / ``mix`` and the rest of the row runs
compiled. :class:`controllers.batched.BatchCascade` stacks the rows of N cascades.

Row layouts
-----------
``params`` (NP,): the three axis parameter blocks (``AX_NP`` each, :mod:`controllers.axis`), then
mass, g, tilt_max, feed-forward factor (1/0), a_limit, the attitude block (J, kR, kw) and the
mixer block (Ainv row-major, f_max, number of rotors) (:mod:`controllers.attitude`).
``state`` (NS,): the three axis state blocks (``AX_NS`` each), then the commanded acceleration
(3), collective thrust, tilt, R_d (9, row-major), the attitude block (τ, e_R) and the mixer block
(saturated flag).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Any, Protocol

import numpy as np

from ._jit import njit
from .attitude import (
    ATT_ER,
    ATT_J,
    ATT_KR,
    ATT_KW,
    ATT_NP,
    ATT_NS,
    ATT_TAU,
    MIX_AINV,
    MIX_FMAX,
    MIX_N,
    MIX_NMAX,
    MIX_NP,
    MIX_NS,
    MIX_SAT,
    GeometricAttitudeController,
    Mat3,
    XMixer,
    attitude_step,
    mix_step,
    thrust_attitude,
)
from .axis import AX_NP, AX_NS, ControllerBase, axis_step
from .fpid import FPID, IT2FPID
from .pid import PID

__all__ = ["MIX_NMAX", "NP", "NS", "PositionCascade", "command_step", "vehicle_step"]

#: Axis controller classes the compiled row runs itself (exact classes).
ROW_AXES: tuple[type, ...] = (PID, FPID, IT2FPID)

# --- params row ---------------------------------------------------------------------------------
P_MASS = 3 * AX_NP
P_G = P_MASS + 1
P_TILT = P_MASS + 2
P_FF = P_MASS + 3
P_ALIM = P_MASS + 4
P_ATT = P_MASS + 5  # attitude block
P_J = P_ATT + ATT_J  # 3
P_KR = P_ATT + ATT_KR  # 3
P_KW = P_ATT + ATT_KW  # 3
P_MIX = P_ATT + ATT_NP  # mixer block
P_AINV = P_MIX + MIX_AINV  # 4 MIX_NMAX, row-major (rotor rows)
P_FMAX = P_MIX + MIX_FMAX
P_NROT = P_MIX + MIX_N  # number of rotors
NP = P_MIX + MIX_NP
# --- state row ----------------------------------------------------------------------------------
S_ACMD = 3 * AX_NS  # 3
S_THRUST = S_ACMD + 3
S_TILT = S_ACMD + 4
S_RD = S_ACMD + 5  # 9
S_ATT = S_RD + 9  # attitude block
S_TAU = S_ATT + ATT_TAU  # 3
S_ER = S_ATT + ATT_ER  # 3
S_MIX = S_ATT + ATT_NS  # mixer block
S_SAT = S_MIX + MIX_SAT
NS = S_MIX + MIX_NS
# --- packed inputs of the scalar shell ----------------------------------------------------------
X_P, X_V, X_R, X_W, X_PR, X_VR, X_AR, X_YAW, NX = 0, 3, 6, 15, 18, 21, 24, 27, 28


class AxisController(Protocol):
    def update(self, error: float, dt: float, measurement: float | None = None,
               error_rate: float | None = None) -> float: ...

    def reset(self) -> None: ...


@njit
def _clip(u: float, lim: float) -> float:
    """``u`` clipped to ``[−lim, lim]``."""
    if u > lim:
        u = lim
    elif u < -lim:
        u = -lim
    return u


@njit
def command_step(prm: np.ndarray, st: np.ndarray, ux: float, uy: float, uz: float,
                 R: np.ndarray, a_ref: np.ndarray, yaw: float) -> tuple[float, Any]:
    """Axis outputs → acceleration command → (collective T, R_d); stores the command, tilt,
    R_d and T in the state row."""
    lim = prm[P_ALIM]
    ff = prm[P_FF]
    ax = _clip(ux, lim) + ff * a_ref[0]
    ay = _clip(uy, lim) + ff * a_ref[1]
    az = _clip(uz, lim) + ff * a_ref[2]
    st[S_ACMD] = ax
    st[S_ACMD + 1] = ay
    st[S_ACMD + 2] = az
    R_d, fn, tilt = thrust_attitude(ax, ay, az, yaw, prm[P_MASS], prm[P_G], prm[P_TILT])
    st[S_TILT] = tilt
    for j in range(9):
        st[S_RD + j] = R_d[j]
    # collective thrust: the desired force projected on the current body z axis
    T = fn * (R_d[2] * R[2] + R_d[5] * R[5] + R_d[8] * R[8])
    if T < 0.0:
        T = 0.0
    st[S_THRUST] = T
    return T, R_d


@njit
def vehicle_step(prm: np.ndarray, st: np.ndarray, fb: tuple, ref: tuple, dt: float,
                 out: np.ndarray) -> None:
    """One control tick of one vehicle's row (module docstring); rotor thrusts to ``out`` (n,).

    ``prm`` (NP,), ``st`` (NS,) advanced in place; ``fb`` = (p, v, R, omega) the fed-back
    state, ``ref`` = (p_ref, v_ref, a_ref, yaw) the reference: ``p, v, omega, p_ref, v_ref,
    a_ref`` (3,), ``R`` (9,) row-major body → world. The caller checks dt > 0.
    """
    p, v, R, omega = fb
    p_ref, v_ref, a_ref, yaw = ref
    u0 = axis_step(prm[0:AX_NP], st[0:AX_NS], p_ref[0] - p[0], p[0], True, v_ref[0] - v[0],
                   True, dt)
    u1 = axis_step(prm[AX_NP:2 * AX_NP], st[AX_NS:2 * AX_NS], p_ref[1] - p[1], p[1], True,
                   v_ref[1] - v[1], True, dt)
    u2 = axis_step(prm[2 * AX_NP:3 * AX_NP], st[2 * AX_NS:3 * AX_NS], p_ref[2] - p[2], p[2],
                   True, v_ref[2] - v[2], True, dt)
    T, R_d = command_step(prm, st, u0, u1, u2, R, a_ref, yaw)
    tx, ty, tz = attitude_step(prm[P_ATT:P_ATT + ATT_NP], st[S_ATT:S_ATT + ATT_NS], R, omega, R_d)
    mix_step(prm[P_MIX:P_MIX + MIX_NP], st[S_MIX:S_MIX + MIX_NS], T, tx, ty, tz, out)


@njit
def _vehicle_call(prm: np.ndarray, st: np.ndarray, x: np.ndarray, dt: float,
                  out: np.ndarray) -> None:
    """:func:`vehicle_step` with the inputs packed in ``x`` (the scalar shell's call)."""
    vehicle_step(prm, st, (x[X_P:X_P + 3], x[X_V:X_V + 3], x[X_R:X_R + 9], x[X_W:X_W + 3]),
                 (x[X_PR:X_PR + 3], x[X_VR:X_VR + 3], x[X_AR:X_AR + 3], x[X_YAW]), dt, out)


@njit
def _command_call(prm: np.ndarray, st: np.ndarray, x: np.ndarray, ux: float, uy: float,
                  uz: float) -> float:
    """:func:`command_step` with the inputs packed in ``x``; returns T."""
    T, _ = command_step(prm, st, ux, uy, uz, x[X_R:X_R + 9], x[X_AR:X_AR + 3], x[X_YAW])
    return T


def _field(col: int, doc: str) -> property:
    def get(self: PositionCascade) -> float:
        return float(self._P[col])

    def set_(self: PositionCascade, value: float) -> None:
        self._P[col] = float(value)

    return property(get, set_, doc=doc)


def _last(lo: int, n: int, doc: str) -> property:
    def get(self: PositionCascade) -> Any:
        s = self._S
        return float(s[lo]) if n == 1 else tuple(s[lo:lo + n].tolist())

    return property(get, doc=doc)


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

    The cascade owns one parameter row and one state row (module docstring; ``_P``, ``_S``) and
    adopts the blocks of its axis controllers, attitude controller and mixer: they become views
    of the row (an object adopted by a second cascade follows the second one). Writable:
    ``mass``, ``g``, ``tilt_max``, ``ff``, ``a_limit`` and the sub-objects' attributes (e.g.
    ``attitude.J``). Last tick: ``a_cmd``, ``thrust``, ``tilt``, ``R_d``, ``torque``.
    """

    mass = _field(P_MASS, "Vehicle mass (kg).")
    g = _field(P_G, "Gravity (m/s²).")
    tilt_max = _field(P_TILT, "Tilt limit of the thrust vector (rad).")
    ff = _field(P_FF, "Feed-forward factor on the reference acceleration (1/0).")
    a_limit = _field(P_ALIM, "Bound on each axis' commanded acceleration (m/s²).")
    a_cmd = _last(S_ACMD, 3, "Last commanded acceleration (m/s²).")
    thrust = _last(S_THRUST, 1, "Last collective thrust (N).")
    tilt = _last(S_TILT, 1, "Last commanded tilt (rad).")
    R_d = _last(S_RD, 9, "Last desired attitude (row-major).")
    torque = _last(S_TAU, 3, "Last body torques (N m).")

    def __init__(self, axes: Sequence[AxisController], mass: float, g: float,
                 attitude: GeometricAttitudeController, mixer: XMixer,
                 tilt_max: float = math.radians(30.0), accel_feedforward: bool = True,
                 a_limit: float = 6.0) -> None:
        self.axes = list(axes)
        if len(self.axes) != 3:
            raise ValueError(f"expected 3 axis controllers, got {len(self.axes)}")
        self.attitude = attitude
        self.mixer = mixer
        self._P = np.zeros(NP)
        self._S = np.zeros(NS)
        self._S[S_RD:S_RD + 9] = (1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0)
        self._x = np.zeros(NX)
        self._out = np.zeros(getattr(mixer, "n", 4))
        self.mass = mass
        self.g = g
        self.tilt_max = tilt_max
        self.ff = 1.0 if accel_feedforward else 0.0
        self.a_limit = a_limit
        self._adopt(copy=True)
        self._internal_keys: list | None = None

    @property
    def params(self) -> np.ndarray:
        """The parameter row (NP,) (module docstring); a view: writes reach the law."""
        return self._P

    @property
    def state(self) -> np.ndarray:
        """The state row (NS,) (module docstring); a view (read it, do not write)."""
        return self._S

    def _blocks(self) -> list[tuple[Any, type, slice, slice]]:
        return [(a, ControllerBase, slice(k * AX_NP, (k + 1) * AX_NP),
                 slice(k * AX_NS, (k + 1) * AX_NS)) for k, a in enumerate(self.axes)] + [
            (self.attitude, GeometricAttitudeController, slice(P_ATT, P_ATT + ATT_NP),
             slice(S_ATT, S_ATT + ATT_NS)),
            (self.mixer, XMixer, slice(P_MIX, P_MIX + MIX_NP), slice(S_MIX, S_MIX + MIX_NS))]

    def _adopt(self, copy: bool) -> None:
        """Make the sub-objects' blocks views of this row (copying their values in first)."""
        for obj, cls, ps, ss in self._blocks():
            if isinstance(obj, cls):
                obj.adopt_blocks(self._P[ps], self._S[ss], copy)
        self._compiled = (all(type(a) in ROW_AXES for a in self.axes)
                          and type(self.attitude) is GeometricAttitudeController
                          and type(self.mixer) is XMixer)

    def __setstate__(self, state: dict[str, Any]) -> None:
        """Unpickled / deep-copied: adopt the (copied) sub-objects again."""
        self.__dict__.update(state)
        self._adopt(copy=False)

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
        if not dt > 0.0:
            raise ValueError(f"dt must be > 0, got {dt}")
        x = self._x
        x[X_P:X_P + 3] = p
        x[X_V:X_V + 3] = v
        x[X_R:X_R + 9] = R
        x[X_W:X_W + 3] = omega
        x[X_PR:X_PR + 3] = p_ref
        x[X_VR:X_VR + 3] = v_ref
        x[X_AR:X_AR + 3] = a_ref
        x[X_YAW] = yaw_ref
        if self._compiled:
            _vehicle_call(self._P, self._S, x, dt, self._out)
            return self._out.tolist()
        return self._update_objects(x, R, omega, dt)

    def _update_objects(self, x: np.ndarray, R: Mat3, omega: Sequence[float],
                        dt: float) -> list[float]:
        """The same tick through the sub-objects' own ``update`` / ``mix`` (other classes)."""
        xs = x.tolist()
        u = [a.update(xs[X_PR + k] - xs[X_P + k], dt, xs[X_P + k],
                      xs[X_VR + k] - xs[X_V + k]) for k, a in enumerate(self.axes)]
        T = _command_call(self._P, self._S, x, u[0], u[1], u[2])
        tau = self.attitude.update(R, omega, self.R_d)
        self._S[S_TAU:S_TAU + 3] = tau
        return self.mixer.mix(T, tau[0], tau[1], tau[2])

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
