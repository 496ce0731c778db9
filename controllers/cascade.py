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

from numkit import Layout, X, Y, Z
from numkit.geometry import RXZ, RYZ, RZZ

from ._jit import njit
from .attitude import (
    ATT_PARAMS,
    ATT_STATE,
    MIX_NMAX,
    MIX_PARAMS,
    MIX_STATE,
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

#: the parameter row: the axis parameter blocks of x, y, z, then mass, g, tilt_max,
#: feed-forward factor, a_limit, the attitude block and the mixer block
ROW_PARAMS = Layout(f"axes:3x{AX_NP} mass g tilt ff alim att:{ATT_PARAMS.size} "
                    f"mix:{MIX_PARAMS.size}")
#: the state row: the axis state blocks of x, y, z, then the commanded acceleration, collective
#: thrust, tilt, R_d (row-major), the attitude block and the mixer block
ROW_STATE = Layout(f"axes:3x{AX_NS} acmd:3 thrust tilt rd:9 att:{ATT_STATE.size} "
                   f"mix:{MIX_STATE.size}")
#: the scalar shell's packed inputs
_IN = Layout("p:3 v:3 r:9 omega:3 p_ref:3 v_ref:3 a_ref:3 yaw").at
_RP, _RS = ROW_PARAMS.at, ROW_STATE.at
# --- params row, by name (the attitude and mixer blocks' fields offset by their block) ----------
P_MASS, P_G, P_TILT, P_FF, P_ALIM = _RP.MASS, _RP.G, _RP.TILT, _RP.FF, _RP.ALIM
P_ATT, P_MIX = _RP.ATT, _RP.MIX
P_J, P_J_END = P_ATT + ATT_PARAMS.at.J, P_ATT + ATT_PARAMS.at.J_END
P_KR, P_KW = P_ATT + ATT_PARAMS.at.KR, P_ATT + ATT_PARAMS.at.KW
P_AINV = P_MIX + MIX_PARAMS.at.AINV  # MIX_NMAX rotor rows of the wrench [T, τx, τy, τz]
P_FMAX = P_MIX + MIX_PARAMS.at.FMAX
P_NROT = P_MIX + MIX_PARAMS.at.N  # number of rotors
NP = ROW_PARAMS.size
# --- state row, by name -------------------------------------------------------------------------
S_ACMD, S_THRUST, S_TILT, S_RD = _RS.ACMD, _RS.THRUST, _RS.TILT, _RS.RD
S_ATT, S_MIX = _RS.ATT, _RS.MIX
S_TAU, S_ER = S_ATT + ATT_STATE.at.TAU, S_ATT + ATT_STATE.at.ER
S_SAT = S_MIX + MIX_STATE.at.SAT
NS = ROW_STATE.size


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
    # a = clip(u, ±a_limit) + ff a_ref per axis
    ax = _clip(ux, lim) + ff * a_ref[X]
    ay = _clip(uy, lim) + ff * a_ref[Y]
    az = _clip(uz, lim) + ff * a_ref[Z]
    st[S_ACMD + X] = ax
    st[S_ACMD + Y] = ay
    st[S_ACMD + Z] = az
    R_d, fn, tilt = thrust_attitude(ax, ay, az, yaw, prm[P_MASS], prm[P_G], prm[P_TILT])
    st[S_TILT] = tilt
    for j in range(9):
        st[S_RD + j] = R_d[j]
    # collective thrust: the desired force projected on the current body z axis,
    # T = |f| (R_d e3)·(R e3)
    T = fn * (R_d[RXZ] * R[RXZ] + R_d[RYZ] * R[RYZ] + R_d[RZZ] * R[RZZ])
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
    # per axis k: e = p_ref − p, error rate v_ref − v, on the k-th axis blocks of the rows
    u0 = axis_step(prm[_RP.AXES + X * AX_NP:_RP.AXES + (X + 1) * AX_NP],
                   st[_RS.AXES + X * AX_NS:_RS.AXES + (X + 1) * AX_NS], p_ref[X] - p[X], p[X],
                   True, v_ref[X] - v[X], True, dt)
    u1 = axis_step(prm[_RP.AXES + Y * AX_NP:_RP.AXES + (Y + 1) * AX_NP],
                   st[_RS.AXES + Y * AX_NS:_RS.AXES + (Y + 1) * AX_NS], p_ref[Y] - p[Y], p[Y],
                   True, v_ref[Y] - v[Y], True, dt)
    u2 = axis_step(prm[_RP.AXES + Z * AX_NP:_RP.AXES + (Z + 1) * AX_NP],
                   st[_RS.AXES + Z * AX_NS:_RS.AXES + (Z + 1) * AX_NS], p_ref[Z] - p[Z], p[Z],
                   True, v_ref[Z] - v[Z], True, dt)
    T, R_d = command_step(prm, st, u0, u1, u2, R, a_ref, yaw)
    tx, ty, tz = attitude_step(prm[_RP.ATT:_RP.ATT_END], st[_RS.ATT:_RS.ATT_END], R, omega, R_d)
    mix_step(prm[_RP.MIX:_RP.MIX_END], st[_RS.MIX:_RS.MIX_END], T, tx, ty, tz, out)


@njit
def _vehicle_call(prm: np.ndarray, st: np.ndarray, x: np.ndarray, dt: float,
                  out: np.ndarray) -> None:
    """:func:`vehicle_step` with the inputs packed in ``x`` (the scalar shell's call)."""
    vehicle_step(prm, st, (x[_IN.P:_IN.P_END], x[_IN.V:_IN.V_END], x[_IN.R:_IN.R_END],
                           x[_IN.OMEGA:_IN.OMEGA_END]),
                 (x[_IN.P_REF:_IN.P_REF_END], x[_IN.V_REF:_IN.V_REF_END],
                  x[_IN.A_REF:_IN.A_REF_END], x[_IN.YAW]), dt, out)


@njit
def _command_call(prm: np.ndarray, st: np.ndarray, x: np.ndarray, ux: float, uy: float,
                  uz: float) -> float:
    """:func:`command_step` with the inputs packed in ``x``; returns T."""
    T, _ = command_step(prm, st, ux, uy, uz, x[_IN.R:_IN.R_END], x[_IN.A_REF:_IN.A_REF_END],
                        x[_IN.YAW])
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
        self._S[_RS.RD:_RS.RD_END] = np.eye(3).ravel()  # R_d = I
        self._x = np.zeros(_IN.SIZE)
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
        return [(a, ControllerBase, slice(_RP.AXES + k * AX_NP, _RP.AXES + (k + 1) * AX_NP),
                 slice(_RS.AXES + k * AX_NS, _RS.AXES + (k + 1) * AX_NS))
                for k, a in enumerate(self.axes)] + [
            (self.attitude, GeometricAttitudeController, ROW_PARAMS.slice("att"),
             ROW_STATE.slice("att")),
            (self.mixer, XMixer, ROW_PARAMS.slice("mix"), ROW_STATE.slice("mix"))]

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
        x[_IN.P:_IN.P_END] = p
        x[_IN.V:_IN.V_END] = v
        x[_IN.R:_IN.R_END] = R
        x[_IN.OMEGA:_IN.OMEGA_END] = omega
        x[_IN.P_REF:_IN.P_REF_END] = p_ref
        x[_IN.V_REF:_IN.V_REF_END] = v_ref
        x[_IN.A_REF:_IN.A_REF_END] = a_ref
        x[_IN.YAW] = yaw_ref
        if self._compiled:
            _vehicle_call(self._P, self._S, x, dt, self._out)
            return self._out.tolist()
        return self._update_objects(x, R, omega, dt)

    def _update_objects(self, x: np.ndarray, R: Mat3, omega: Sequence[float],
                        dt: float) -> list[float]:
        """The same tick through the sub-objects' own ``update`` / ``mix`` (other classes)."""
        xs = x.tolist()
        u = [a.update(xs[_IN.P_REF + k] - xs[_IN.P + k], dt, xs[_IN.P + k],
                      xs[_IN.V_REF + k] - xs[_IN.V + k]) for k, a in enumerate(self.axes)]
        T = _command_call(self._P, self._S, x, u[X], u[Y], u[Z])
        tau = self.attitude.update(R, omega, self.R_d)
        self._S[S_TAU + X:S_TAU + Z + 1] = tau
        return self.mixer.mix(T, tau[X], tau[Y], tau[Z])

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
