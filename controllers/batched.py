"""N position cascades advanced in lockstep: :class:`BatchCascade` (one compiled kernel call per
control tick for the whole batch).

Where each law lives
--------------------
Nothing here computes a law: :func:`cascade_step` loops over the rows and calls, for each
active vehicle, :func:`controllers.cascade.vehicle_step` on that vehicle's parameter row and
state row — the very function :class:`~controllers.cascade.PositionCascade` calls on its own row
(a batch of one). The laws, each written once:

* axis law of every kind (PID, type-1 FPID, IT2-FPID with reducer km / nt / bmm / zeta; the
  derivative from the error rate, a difference or a filtered difference, derivative on
  measurement; ``i_limit``, ``u_limit``, conditional integration):
  :func:`controllers.axis.axis_step`, with the fuzzy cores :func:`controllers.fuzzy.t1_phi` and
  :func:`controllers.fuzzy.it2_phi`;
* acceleration clip, feed-forward, :func:`controllers.attitude.thrust_attitude` and the collective:
  :func:`controllers.cascade.command_step`;
* geometric attitude torques: :func:`controllers.attitude.attitude_step`
  (:func:`controllers.attitude.geometric_torque`);
* the allocation to the frame's rotors with its saturation priority:
  :func:`controllers.attitude.mix_step`.

So a row's results are the scalar classes' bit for bit, and a vehicle's row does not depend on
the other rows (identical bits whatever the batch size or the neighbours).

Why numba
---------
A numpy-vectorised cascade pays ~1 µs per array call, and one tick needs a few hundred of them
(fuzzy cores, the mixer's saturation branches). One ``@njit(cache=True)`` kernel (no fastmath)
costs the dispatch of one call plus well under a µs per vehicle, for any N (figures in the
README's benchmarks). Without numba (:mod:`controllers._jit`) the same functions run as Python
over the arrays: correct, slow.

Array layouts
-------------
``params``: (N, NP) float64 and ``state``: (N, NS) float64, one row per vehicle, each row laid
out as :mod:`controllers.cascade` describes (three axis blocks of :mod:`controllers.axis`, the
vehicle fields, the attitude and mixer blocks of :mod:`controllers.attitude`).

Inputs of :meth:`BatchCascade.update`: (N, 3) float64 arrays except ``R`` (N, 9) row-major
body → world and ``yaw_ref`` (N,). C-contiguous float64 arrays avoid extra compilations.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any, NamedTuple

import numpy as np

from ._jit import njit
from .attitude import GeometricAttitudeController, XMixer
from .axis import (
    AX_NP,
    AX_NS,
    KIND_PID,
    A,
    S,
)
from .cascade import (
    NP,
    NS,
    P_ALIM,
    P_FF,
    P_FMAX,
    P_G,
    P_J,
    P_J_END,
    P_MASS,
    P_NROT,
    P_TILT,
    ROW_AXES,
    S_ACMD,
    S_SAT,
    S_TAU,
    S_THRUST,
    S_TILT,
    PositionCascade,
    vehicle_step,
)
from .fpid import FPID, IT2FPID
from .pid import PID

__all__ = ["AX_NP", "AX_NS", "NP", "NS", "TYPE_CODES", "BatchCascade", "PoseRows", "RefRows",
           "cascade_step"]

#: Axis controller type codes.
TYPE_CODES: dict[type, int] = {PID: 0, FPID: 1, IT2FPID: 2}

_AXIS_ATTRS = ("E", "dE", "U", "integral", "u")
_STATE_COL = {"E": S.E, "dE": S.DE, "U": S.U, "integral": S.I, "u": S.UOUT}


class PoseRows(NamedTuple):
    """The measured state of N vehicles, declared once: ``p``, ``v``, ``omega`` (N, 3) and
    ``R`` (N, 9) row-major body → world, float64."""

    p: np.ndarray
    v: np.ndarray
    R: np.ndarray
    omega: np.ndarray


class RefRows(NamedTuple):
    """The reference of N vehicles, declared once: ``p_ref``, ``v_ref``, ``a_ref`` (N, 3) and
    ``yaw_ref`` (N,), float64."""

    p_ref: np.ndarray
    v_ref: np.ndarray
    a_ref: np.ndarray
    yaw_ref: np.ndarray


@njit
def cascade_step(P: np.ndarray, S: np.ndarray, pose: tuple, ref: tuple, dt: float,
                 active: np.ndarray, out: np.ndarray) -> None:
    """One control tick of every active row (the kernel behind :meth:`BatchCascade.update`):
    :func:`controllers.cascade.vehicle_step` per row.

    ``P`` (N, NP) parameters, ``S`` (N, NS) state (advanced in place for active rows),
    ``pose``: :class:`PoseRows`, ``ref``: :class:`RefRows` (plain tuples in field order),
    ``out`` (N, n) rotor thrusts (inactive rows set to 0; an active row's columns past its own
    rotor count are left as they are). See the module docstring.
    """
    po, rf = PoseRows(*pose), RefRows(*ref)
    p, v, R, omega = po.p, po.v, po.R, po.omega
    p_ref, v_ref, a_ref, yaw_ref = rf.p_ref, rf.v_ref, rf.a_ref, rf.yaw_ref
    n = P.shape[0]
    if not dt > 0.0:
        raise ValueError("dt must be > 0")
    if (S.shape[0] != n or p.shape[0] != n or v.shape[0] != n or R.shape[0] != n
            or omega.shape[0] != n or p_ref.shape[0] != n or v_ref.shape[0] != n
            or a_ref.shape[0] != n or yaw_ref.shape[0] != n or active.shape[0] != n
            or out.shape[0] != n):
        raise ValueError("every input needs the batch size N as its first dimension")
    if (p.shape[1] != 3 or v.shape[1] != 3 or omega.shape[1] != 3 or p_ref.shape[1] != 3
            or v_ref.shape[1] != 3 or a_ref.shape[1] != 3 or R.shape[1] != 9
            or out.shape[1] < 4 or P.shape[1] != NP or S.shape[1] != NS):
        raise ValueError("p, v, omega, p_ref, v_ref, a_ref need (N, 3), R (N, 9), out (N, n) "
                         "with n >= every row's rotor count")
    for i in range(n):
        if P[i, P_NROT] > out.shape[1]:
            raise ValueError("out has fewer columns than a row has rotors")
    for i in range(n):
        if active[i]:
            vehicle_step(P[i], S[i], (p[i], v[i], R[i], omega[i]),
                         (p_ref[i], v_ref[i], a_ref[i], yaw_ref[i]), dt, out[i])
        else:
            for j in range(out.shape[1]):
                out[i, j] = 0.0


# ======================================================================== Python side
def _column(col: int, doc: str) -> property:
    def get(self: BatchCascade) -> np.ndarray:
        return self.params[:, col]

    def set_(self: BatchCascade, value: Any) -> None:
        self.params[:, col] = value

    return property(get, set_, doc=f"{doc} (N,) view of ``params[:, {col}]``; writable.")


def _state_view(lo: int, hi: int, doc: str) -> property:
    def get(self: BatchCascade) -> np.ndarray:
        return self.state[:, lo] if hi == lo + 1 else self.state[:, lo:hi]

    return property(get, doc=f"{doc} View of ``state[:, {lo}:{hi}]`` (read it, do not write).")


class BatchCascade:
    """N :class:`~controllers.cascade.PositionCascade` in lockstep (row i = vehicle i).

    Build with :meth:`from_cascades`. ``params`` (N, NP) and ``state`` (N, NS) hold everything
    (layout: module docstring). Writable per-vehicle views (take effect at the next
    :meth:`update`): :attr:`mass` (e.g. a draining spray tank: ``bc.mass[i] = m``), :attr:`g`,
    :attr:`tilt_max`, :attr:`a_limit`, :attr:`accel_feedforward` (1.0 / 0.0) and :attr:`f_max`.
    Read-only views of the last tick: :attr:`a_cmd`, :attr:`thrust`, :attr:`tilt`,
    :attr:`saturated`, :attr:`torque`. Other ``params`` columns may be written too (gains,
    limits, inertia, ``Ainv``: the kernel reads them every tick); the type and reducer codes
    must stay valid codes (0–2, 0–3).
    """

    mass = _column(P_MASS, "Vehicle mass (kg).")
    g = _column(P_G, "Gravity (m/s²).")
    tilt_max = _column(P_TILT, "Tilt limit of the thrust vector (rad).")
    a_limit = _column(P_ALIM, "Bound on each axis' commanded acceleration (m/s²).")
    accel_feedforward = _column(P_FF, "Feed-forward factor on the reference acceleration (1/0).")
    f_max = _column(P_FMAX, "Rotor thrust limit (N).")
    a_cmd = _state_view(S_ACMD, S_ACMD + 3, "(N, 3) last commanded acceleration (m/s²).")
    thrust = _state_view(S_THRUST, S_THRUST + 1, "(N,) last collective thrust (N).")
    tilt = _state_view(S_TILT, S_TILT + 1, "(N,) last commanded tilt (rad).")
    saturated = _state_view(S_SAT, S_SAT + 1, "(N,) 1.0 where the mixer saturated last tick.")
    torque = _state_view(S_TAU, S_TAU + 3, "(N, 3) last body torques (N m).")

    def __init__(self, params: np.ndarray, state: np.ndarray | None = None) -> None:
        params = np.ascontiguousarray(params, dtype=np.float64)
        if params.ndim != 2 or params.shape[1] != NP or params.shape[0] < 1:
            raise ValueError(f"params must be (N >= 1, {NP}), got {params.shape}")
        n = params.shape[0]
        self.params = params.copy()
        if state is None:
            self.state = np.zeros((n, NS))
        else:
            state = np.asarray(state, dtype=np.float64)
            if state.shape != (n, NS):
                raise ValueError(f"state must be ({n}, {NS}), got {state.shape}")
            self.state = np.ascontiguousarray(state).copy()
        #: rotor thrusts (N, n): n the most rotors of any row
        self._out = np.zeros((n, int(params[:, P_NROT].max())))
        self._all = np.ones(n, dtype=np.bool_)
        self._keys: dict[tuple[int, int, int], list[tuple[str, int]]] = {}

    @classmethod
    def from_cascades(cls, cascades: Sequence[PositionCascade]) -> BatchCascade:
        """Copy every parameter and the current state of scalar cascades (row i = cascades[i]).

        Supported: :class:`PositionCascade` (exact class) with three axis controllers, each a
        :class:`PID`, :class:`FPID` or :class:`IT2FPID` (any reducer, heights, c_m, ζ,
        derivative mode, i_limit, u_limit, d_tau), a :class:`GeometricAttitudeController` and
        an :class:`XMixer`. Anything else (subclasses, other controller objects) raises
        ValueError. The scalar objects are not modified and not linked.
        """
        cascades = list(cascades)
        if not cascades:
            raise ValueError("from_cascades needs at least one cascade")
        P = np.zeros((len(cascades), NP))
        S = np.zeros((len(cascades), NS))
        for i, c in enumerate(cascades):
            if type(c) is not PositionCascade:
                raise ValueError(f"cascade {i}: expected PositionCascade, got {type(c).__name__}")
            for k, a in enumerate(c.axes):
                if type(a) not in ROW_AXES:
                    raise ValueError(
                        f"cascade {i} axis {'xyz'[k]}: BatchCascade supports exactly PID, FPID "
                        f"and IT2FPID axis controllers, got {type(a).__name__}")
            att, mix = c.attitude, c.mixer
            if type(att) is not GeometricAttitudeController:
                raise ValueError(f"cascade {i}: attitude must be GeometricAttitudeController, "
                                 f"got {type(att).__name__}")
            if type(mix) is not XMixer:
                raise ValueError(f"cascade {i}: mixer must be an XMixer, "
                                 f"got {type(mix).__name__}")
            P[i] = c.params
            S[i] = c.state
        return cls(P, S)

    @property
    def n(self) -> int:
        """Batch size N."""
        return self.params.shape[0]

    def update(self, pose: Sequence[np.ndarray], ref: Sequence[np.ndarray], dt: float,
               out: np.ndarray | None = None,
               active: np.ndarray | None = None) -> np.ndarray:
        """Rotor thrusts (N, n) in N for one control tick of every (active) vehicle.

        Inputs as :meth:`PositionCascade.update`, batched: ``pose`` (:class:`PoseRows`, or a
        plain tuple ``(p, v, R, omega)``) and ``ref`` (:class:`RefRows`, or ``(p_ref, v_ref,
        a_ref, yaw_ref)``): ``p, v, omega, p_ref, v_ref, a_ref`` (N, 3), ``R`` (N, 9) row-major
        body → world, ``yaw_ref`` (N,), float64.
        ``active`` (N,) bool: rows that are False keep their state and get zero thrusts.
        Without ``out`` the result is an internal buffer overwritten by the next call (copy
        it to keep it).
        """
        if out is None:
            out = self._out
        cascade_step(self.params, self.state, tuple(pose), tuple(ref), dt,
                     self._all if active is None else active, out)
        return out

    @property
    def J(self) -> np.ndarray:
        """(N, 3) principal inertia of each vehicle (kg m²), a writable view of ``params``: the
        gyroscopic term ``ω × Jω`` uses it (a draining tank changes it); the attitude gains
        ``kR``, ``kw`` stay as built, as in :class:`GeometricAttitudeController`."""
        return self.params[:, P_J:P_J_END]

    def reset_rows(self, rows: np.ndarray) -> None:
        """:meth:`reset` for the vehicles ``rows`` only (index array or bool mask)."""
        for k in range(3):
            self.state[rows, k * AX_NS:(k + 1) * AX_NS] = 0.0

    def reset(self) -> None:
        """Forget every axis controller's integral and derivative memory (as
        :meth:`PositionCascade.reset`: the last command, thrust and tilt are kept)."""
        for k in range(3):
            self.state[:, k * AX_NS:(k + 1) * AX_NS] = 0.0

    def internal_columns(self, i: int) -> list[tuple[str, int]]:
        """Vehicle ``i``'s log keys (those of :meth:`PositionCascade.internals`), each with
        the column of ``state[i]`` that holds its value."""
        P = self.params
        key = (int(P[i, A.TYPE]), int(P[i, AX_NP + A.TYPE]), int(P[i, 2 * AX_NP + A.TYPE]))
        keys = self._keys.get(key)
        if keys is None:
            keys = self._keys[key] = [
                (f"{name}.{attr}", k * AX_NS + _STATE_COL[attr])
                for k, (name, code) in enumerate(zip("xyz", key, strict=True))
                for attr in _AXIS_ATTRS if code != KIND_PID or attr in ("integral", "u")] + [
                ("ax_cmd", S_ACMD), ("ay_cmd", S_ACMD + 1), ("az_cmd", S_ACMD + 2),
                ("thrust", S_THRUST), ("tilt_cmd", S_TILT), ("mixer_saturated", S_SAT)]
        return keys

    def internals(self, i: int) -> dict[str, Any]:
        """Vehicle ``i``'s log values: the keys and values of :meth:`PositionCascade.internals`."""
        row = self.state[i].tolist()
        return {k: row[c] for k, c in self.internal_columns(i)}
