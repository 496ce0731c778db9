"""N position cascades advanced in lockstep: :class:`BatchCascade` (one compiled kernel call per
control tick for the whole batch).

Equations
---------
Per vehicle and per tick, exactly :meth:`controllers.cascade.PositionCascade.update`:

* per world axis ``k``: ``e = p_ref − p``, error rate ``v_ref − v`` (used as the derivative,
  see :meth:`controllers.pid.ControllerBase._derivative`), the axis law of
  :class:`controllers.pid.PID`, :class:`controllers.fpid.FPID` (type-1 core
  :class:`controllers.fuzzy.T1FuzzyPD`) or :class:`controllers.fpid.IT2FPID` (IT2 core
  :class:`controllers.fuzzy.IT2FuzzyPD`, reducer km / nt / bmm / zeta) with the integral clamp
  ``i_limit``, the output clamp ``u_limit`` and conditional integration
  (:meth:`controllers.pid.ControllerBase._integrate`);
* clip to ``±a_limit``, add ``ff·a_ref``;
* :func:`controllers.attitude.thrust_attitude` (tilt limit, ``f_z ≥ 0.2 m g``), collective
  ``T = |f| (R_d e3)·(R e3)`` floored at 0;
* :class:`controllers.attitude.GeometricAttitudeController` torques;
* :class:`controllers.attitude.XMixer` allocation with its saturation priority (yaw scaled
  down, then the collective shifted, then clipping).

The fuzzy cores (:func:`controllers.fuzzy.t1_phi`, :func:`~controllers.fuzzy.it2_phi`),
:func:`~controllers.attitude.thrust_attitude` and :func:`~controllers.attitude.geometric_torque`
are the scalar classes' own pure float functions, compiled here with numba; the axis law and the
mixer repeat the scalar code's floating-point operations in the same order. So the kernel's
results equal the scalar classes' to rounding (tests: 1e-12), and a vehicle's row does not depend
on the other rows (identical bits whatever the batch size or the neighbours).

Why numba
---------
A numpy-vectorised cascade pays ~1 µs per array call, and one tick needs a few hundred of them
(fuzzy cores, the mixer's saturation branches): fine at N = 256, far slower than the scalar
Python cascade (~15–20 µs) at N = 1. One ``@njit(cache=True)`` kernel (no fastmath) costs the
dispatch of one call plus well under a µs per vehicle, for any N. Measured (2-core dev machine,
IT2 KM axes): numba 1.6 µs/tick at N = 1, 21 µs at N = 64, 79 µs at N = 256 (0.31 µs per
vehicle); a numpy-vectorised cascade 183–290 µs at N = 1 and 365–680 µs at N = 256; the scalar
cascade 15 µs. First compile ~2–3 s, loading the cached kernel ~0.3 s (plus ~0.2–0.4 s to
import numba). Without numba (:mod:`controllers._jit`) the same kernel runs as Python over the
arrays: correct, slow.

Array layouts
-------------
``params``: (N, NP) float64, one row per vehicle. Per axis ``k`` (x, y, z) a block of ``AX_NP``
columns at ``k·AX_NP``: type code (0 PID, 1 type-1 FPID, 2 IT2-FPID), reducer code (0 km, 1 nt,
2 bmm, 3 zeta), gains ``G0..G3`` (PID: Kp, Kd, −, Ki; fuzzy: Ke, Kd, K0, K1), c_m, ζ, lower-MF
heights (h_N, h_Z, h_P) for E then dE, derivative-on-measurement flag, i_limit (``inf`` for
None), u_limit lower/upper (``∓inf`` for None), d_tau. Then the vehicle block (``P_MASS`` …):
mass, g, tilt_max, feed-forward factor (1/0), a_limit, inertia J (3), attitude gains kR (3) and
kw (3), the mixer's inverse allocation ``Ainv`` (16, row-major) and f_max.

``state``: (N, NS) float64. Per axis a block of ``AX_NS`` columns: E, dE, U, integral, u,
finite-difference memory, has-memory flag, derivative filter state. Then the vehicle block:
commanded acceleration (3), collective thrust, tilt, mixer-saturated flag (1/0), torques (3).

Inputs of :meth:`BatchCascade.update`: (N, 3) float64 arrays except ``R`` (N, 9) row-major
body → world and ``yaw_ref`` (N,). C-contiguous float64 arrays avoid extra compilations.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Any

import numpy as np

from ._jit import njit
from .attitude import GeometricAttitudeController, XMixer, geometric_torque, thrust_attitude
from .cascade import PositionCascade
from .fpid import FPID, IT2FPID
from .fuzzy import IT2FuzzyPD, T1FuzzyPD, it2_phi, t1_phi
from .pid import PID

__all__ = ["AX_NP", "AX_NS", "NP", "NS", "TYPE_CODES", "BatchCascade", "cascade_step"]

#: Axis controller type codes.
TYPE_CODES: dict[type, int] = {PID: 0, FPID: 1, IT2FPID: 2}
_PID, _T1, _IT2 = 0, 1, 2

# --- params: per-axis block ------------------------------------------------------------
A_TYPE, A_RED, A_G0, A_G1, A_G2, A_G3, A_CM, A_ZETA = 0, 1, 2, 3, 4, 5, 6, 7
A_HN1, A_HZ1, A_HP1, A_HN2, A_HZ2, A_HP2 = 8, 9, 10, 11, 12, 13
A_ONMEAS, A_ILIM, A_UMIN, A_UMAX, A_DTAU = 14, 15, 16, 17, 18
AX_NP = 19
# --- params: vehicle block -------------------------------------------------------------
P_MASS = 3 * AX_NP
P_G = P_MASS + 1
P_TILT = P_MASS + 2
P_FF = P_MASS + 3
P_ALIM = P_MASS + 4
P_J = P_MASS + 5  # 3
P_KR = P_MASS + 8  # 3
P_KW = P_MASS + 11  # 3
P_AINV = P_MASS + 14  # 16, row-major
P_FMAX = P_MASS + 30
NP = P_FMAX + 1

# --- state: per-axis block -------------------------------------------------------------
S_E, S_DE, S_U, S_I, S_UOUT, S_PREV, S_HASPREV, S_DFILT = 0, 1, 2, 3, 4, 5, 6, 7
AX_NS = 8
# --- state: vehicle block --------------------------------------------------------------
S_ACMD = 3 * AX_NS  # 3
S_THRUST = S_ACMD + 3
S_TILT = S_ACMD + 4
S_SAT = S_ACMD + 5
S_TAU = S_ACMD + 6  # 3
NS = S_TAU + 3

_AXIS_ATTRS = ("E", "dE", "U", "integral", "u")
_STATE_COL = {"E": S_E, "dE": S_DE, "U": S_U, "integral": S_I, "u": S_UOUT}


# ======================================================================== compiled kernel
# The scalar classes' pure float functions, compiled for the kernel (the classes keep calling the
# Python originals): one implementation of the fuzzy cores, the thrust vectoring and the attitude
# law.
_t1_phi = njit(t1_phi)
_it2_phi = njit(it2_phi)
_thrust_attitude = njit(thrust_attitude)
_geometric_torque = njit(geometric_torque)


@njit
def _axis(P: np.ndarray, S: np.ndarray, i: int, k: int, error: float, meas: float,
          rate: float, dt: float) -> float:
    """One tick of axis ``k``'s controller of vehicle ``i`` (PID / FPID / IT2FPID ``update``)."""
    b = k * AX_NP
    s = k * AX_NS
    kind = int(P[i, b + A_TYPE])
    # ControllerBase._derivative with error_rate given: memory updated, rate returned
    S[i, s + S_PREV] = -meas if P[i, b + A_ONMEAS] != 0.0 else error
    S[i, s + S_HASPREV] = 1.0
    de = rate
    if kind == _PID:
        p = P[i, b + A_G0] * error
        d = P[i, b + A_G1] * de
        dI = dt * error
        u_rest = p + d
    else:
        E = P[i, b + A_G0] * error
        if E > 1.0:
            E = 1.0
        elif E < -1.0:
            E = -1.0
        dE = P[i, b + A_G1] * de
        if dE > 1.0:
            dE = 1.0
        elif dE < -1.0:
            dE = -1.0
        cm = P[i, b + A_CM]
        y = (-1.0, -cm, 0.0, cm, 1.0)
        if kind == _T1:
            U = _t1_phi(E, dE, y)
        else:
            U = _it2_phi(E, dE, y, P[i, b + A_HN1], P[i, b + A_HZ1], P[i, b + A_HP1],
                         P[i, b + A_HN2], P[i, b + A_HZ2], P[i, b + A_HP2],
                         int(P[i, b + A_RED]), P[i, b + A_ZETA])
        S[i, s + S_E] = E
        S[i, s + S_DE] = dE
        S[i, s + S_U] = U
        dI = dt * U
        u_rest = P[i, b + A_G2] * U
    # ControllerBase._integrate
    K = P[i, b + A_G3]
    I_old = S[i, s + S_I]
    I = I_old + dI  # noqa: E741
    lim = P[i, b + A_ILIM]
    if lim != math.inf and K != 0.0:
        imax = lim / abs(K)
        if I > imax:
            I = imax  # noqa: E741
        elif I < -imax:
            I = -imax  # noqa: E741
    u = u_rest + K * I
    umax = P[i, b + A_UMAX]
    umin = P[i, b + A_UMIN]
    if u > umax:
        if K * (I - I_old) > 0.0:
            I = I_old  # noqa: E741
            u = u_rest + K * I
        if u > umax:
            u = umax
    elif u < umin:
        if K * (I - I_old) < 0.0:
            I = I_old  # noqa: E741
            u = u_rest + K * I
        if u < umin:
            u = umin
    S[i, s + S_I] = I
    S[i, s + S_UOUT] = u
    return u


@njit
def _yaw_frac(s: float, a: float, b: float, fmax: float) -> float:
    """One rotor's bound on the kept yaw fraction (XMixer.mix step 1)."""
    d = b - a
    if d > 0.0 and b > fmax:
        x = (fmax - a) / d
        if x < s:
            s = x
    elif d < 0.0 and b < 0.0:
        x = -a / d
        if x < s:
            s = x
    return s


@njit
def _clip0(v: float, fmax: float) -> float:
    """``min(fmax, max(0.0, v))`` with Python's min/max tie rules."""
    x = v if v > 0.0 else 0.0
    return x if x < fmax else fmax


@njit
def _vehicle(P: np.ndarray, S: np.ndarray, i: int, p: np.ndarray, v: np.ndarray, R: np.ndarray,
             omega: np.ndarray, p_ref: np.ndarray, v_ref: np.ndarray, a_ref: np.ndarray,
             yaw: float, dt: float, out: np.ndarray) -> None:
    """PositionCascade.update for row ``i``; writes ``out[i, :4]`` and the state row."""
    lim = P[i, P_ALIM]
    ff = P[i, P_FF]
    ax = 0.0
    ay = 0.0
    az = 0.0
    for k in range(3):
        e = p_ref[i, k] - p[i, k]
        u = _axis(P, S, i, k, e, p[i, k], v_ref[i, k] - v[i, k], dt)
        if u > lim:
            u = lim
        elif u < -lim:
            u = -lim
        acc = u + ff * a_ref[i, k]
        if k == 0:
            ax = acc
        elif k == 1:
            ay = acc
        else:
            az = acc
    S[i, S_ACMD] = ax
    S[i, S_ACMD + 1] = ay
    S[i, S_ACMD + 2] = az
    R_d, fn, tilt = _thrust_attitude(ax, ay, az, yaw, P[i, P_MASS], P[i, P_G], P[i, P_TILT])
    S[i, S_TILT] = tilt
    r = R[i]
    T = fn * (R_d[2] * r[2] + R_d[5] * r[5] + R_d[8] * r[8])
    if T < 0.0:
        T = 0.0
    S[i, S_THRUST] = T
    tau, _ = _geometric_torque(r, omega[i], R_d, (P[i, P_J], P[i, P_J + 1], P[i, P_J + 2]),
                               (P[i, P_KR], P[i, P_KR + 1], P[i, P_KR + 2]),
                               (P[i, P_KW], P[i, P_KW + 1], P[i, P_KW + 2]))
    tx, ty, tz = tau
    S[i, S_TAU] = tx
    S[i, S_TAU + 1] = ty
    S[i, S_TAU + 2] = tz
    # XMixer.mix
    a = P_AINV
    fmax = P[i, P_FMAX]
    f0 = P[i, a] * T + P[i, a + 1] * tx + P[i, a + 2] * ty + P[i, a + 3] * tz
    f1 = P[i, a + 4] * T + P[i, a + 5] * tx + P[i, a + 6] * ty + P[i, a + 7] * tz
    f2 = P[i, a + 8] * T + P[i, a + 9] * tx + P[i, a + 10] * ty + P[i, a + 11] * tz
    f3 = P[i, a + 12] * T + P[i, a + 13] * tx + P[i, a + 14] * ty + P[i, a + 15] * tz
    lo = min(min(f0, f1), min(f2, f3))
    hi = max(max(f0, f1), max(f2, f3))
    sat = lo < 0.0 or hi > fmax
    S[i, S_SAT] = 1.0 if sat else 0.0
    if sat:
        # 1. drop yaw
        g0 = P[i, a] * T + P[i, a + 1] * tx + P[i, a + 2] * ty + P[i, a + 3] * 0.0
        g1 = P[i, a + 4] * T + P[i, a + 5] * tx + P[i, a + 6] * ty + P[i, a + 7] * 0.0
        g2 = P[i, a + 8] * T + P[i, a + 9] * tx + P[i, a + 10] * ty + P[i, a + 11] * 0.0
        g3 = P[i, a + 12] * T + P[i, a + 13] * tx + P[i, a + 14] * ty + P[i, a + 15] * 0.0
        lo0 = min(min(g0, g1), min(g2, g3))
        hi0 = max(max(g0, g1), max(g2, g3))
        if lo0 >= 0.0 and hi0 <= fmax:
            s = 1.0
            s = _yaw_frac(s, g0, f0, fmax)
            s = _yaw_frac(s, g1, f1, fmax)
            s = _yaw_frac(s, g2, f2, fmax)
            s = _yaw_frac(s, g3, f3, fmax)
            f0 = g0 + s * (f0 - g0)
            f1 = g1 + s * (f1 - g1)
            f2 = g2 + s * (f2 - g2)
            f3 = g3 + s * (f3 - g3)
        elif hi0 - lo0 <= fmax:
            # 2. shift the collective
            shift = -lo0 if lo0 < 0.0 else fmax - hi0
            f0 = g0 + shift
            f1 = g1 + shift
            f2 = g2 + shift
            f3 = g3 + shift
        else:
            # 3. clip
            f0 = _clip0(g0, fmax)
            f1 = _clip0(g1, fmax)
            f2 = _clip0(g2, fmax)
            f3 = _clip0(g3, fmax)
    out[i, 0] = f0
    out[i, 1] = f1
    out[i, 2] = f2
    out[i, 3] = f3


@njit
def cascade_step(P: np.ndarray, S: np.ndarray, p: np.ndarray, v: np.ndarray, R: np.ndarray,
                 omega: np.ndarray, p_ref: np.ndarray, v_ref: np.ndarray, a_ref: np.ndarray,
                 yaw_ref: np.ndarray, dt: float, active: np.ndarray, out: np.ndarray) -> None:
    """One control tick of every active row (the kernel behind :meth:`BatchCascade.update`).

    ``P`` (N, NP) parameters, ``S`` (N, NS) state (advanced in place for active rows),
    ``out`` (N, 4) rotor thrusts (inactive rows set to 0). See the module docstring.
    """
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
            or out.shape[1] != 4 or P.shape[1] != NP or S.shape[1] != NS):
        raise ValueError("p, v, omega, p_ref, v_ref, a_ref need (N, 3), R (N, 9), out (N, 4)")
    for i in range(n):
        if active[i]:
            _vehicle(P, S, i, p, v, R, omega, p_ref, v_ref, a_ref, yaw_ref[i], dt, out)
        else:
            out[i, 0] = 0.0
            out[i, 1] = 0.0
            out[i, 2] = 0.0
            out[i, 3] = 0.0


# ======================================================================== Python side
def _axis_row(a: Any, where: str) -> tuple[list[float], list[float]]:
    """(params block, state block) of one scalar axis controller; ValueError if unsupported."""
    kind = type(a)
    if kind not in TYPE_CODES:
        raise ValueError(
            f"{where}: BatchCascade supports exactly PID, FPID and IT2FPID axis controllers, "
            f"got {kind.__name__}")
    pr = [0.0] * AX_NP
    st = [0.0] * AX_NS
    code = TYPE_CODES[kind]
    pr[A_TYPE] = float(code)
    if code == _PID:
        pr[A_G0], pr[A_G1], pr[A_G3] = a.Kp, a.Kd, a.Ki
        pr[A_HN1:A_HP2 + 1] = [1.0] * 6
        pr[A_CM] = 0.5
    else:
        core = a.core
        want = T1FuzzyPD if code == _T1 else IT2FuzzyPD
        if type(core) is not want:
            raise ValueError(f"{where}: {kind.__name__} core must be {want.__name__}, "
                             f"got {type(core).__name__}")
        cm = float(core._y[3])
        if tuple(core._y) != (-1.0, -cm, 0.0, cm, 1.0):
            raise ValueError(f"{where}: unexpected consequents {core._y!r}")
        pr[A_G0], pr[A_G1], pr[A_G2], pr[A_G3] = a.Ke, a.Kd, a.K0, a.K1
        pr[A_CM] = cm
        if code == _IT2:
            pr[A_RED] = float(core._code)
            pr[A_ZETA] = core.zeta
            pr[A_HN1:A_HP2 + 1] = [core._hn1, core._hz1, core._hp1,
                                   core._hn2, core._hz2, core._hp2]
        else:
            pr[A_HN1:A_HP2 + 1] = [1.0] * 6
        st[S_E], st[S_DE], st[S_U] = a.E, a.dE, a.U
    pr[A_ONMEAS] = 1.0 if a._on_meas else 0.0
    pr[A_ILIM] = math.inf if a.i_limit is None else a.i_limit
    pr[A_UMIN], pr[A_UMAX] = a._umin, a._umax
    pr[A_DTAU] = a.d_tau
    st[S_I] = a.integral
    st[S_UOUT] = a.u
    st[S_PREV] = 0.0 if a._prev is None else a._prev
    st[S_HASPREV] = 0.0 if a._prev is None else 1.0
    st[S_DFILT] = a._dfilt
    return [float(x) for x in pr], [float(x) for x in st]


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
        self._out = np.zeros((n, 4))
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
            if len(c.axes) != 3:
                raise ValueError(f"cascade {i}: expected 3 axis controllers, got {len(c.axes)}")
            for k, a in enumerate(c.axes):
                pr, st = _axis_row(a, f"cascade {i} axis {'xyz'[k]}")
                P[i, k * AX_NP:(k + 1) * AX_NP] = pr
                S[i, k * AX_NS:(k + 1) * AX_NS] = st
            att, mix = c.attitude, c.mixer
            if type(att) is not GeometricAttitudeController:
                raise ValueError(f"cascade {i}: attitude must be GeometricAttitudeController, "
                                 f"got {type(att).__name__}")
            if type(mix) is not XMixer or len(mix.Ainv) != 4:
                raise ValueError(f"cascade {i}: mixer must be a four-rotor XMixer, "
                                 f"got {type(mix).__name__}")
            P[i, P_MASS] = c.mass
            P[i, P_G] = c.g
            P[i, P_TILT] = c.tilt_max
            P[i, P_FF] = c.ff
            P[i, P_ALIM] = c.a_limit
            P[i, P_J:P_J + 3] = att.J
            P[i, P_KR:P_KR + 3] = att.kR
            P[i, P_KW:P_KW + 3] = att.kw
            P[i, P_AINV:P_AINV + 16] = [x for row in mix.Ainv for x in row]
            P[i, P_FMAX] = mix.f_max
            S[i, S_ACMD:S_ACMD + 3] = c.a_cmd
            S[i, S_THRUST] = c.thrust
            S[i, S_TILT] = c.tilt
            S[i, S_SAT] = float(mix.saturated)
            S[i, S_TAU:S_TAU + 3] = c.torque
        return cls(P, S)

    @property
    def n(self) -> int:
        """Batch size N."""
        return self.params.shape[0]

    def update(self, p: np.ndarray, v: np.ndarray, R: np.ndarray, omega: np.ndarray,
               p_ref: np.ndarray, v_ref: np.ndarray, a_ref: np.ndarray, yaw_ref: np.ndarray,
               dt: float, out: np.ndarray | None = None,
               active: np.ndarray | None = None) -> np.ndarray:
        """Rotor thrusts (N, 4) in N for one control tick of every (active) vehicle.

        Inputs as :meth:`PositionCascade.update`, batched: ``p, v, omega, p_ref, v_ref, a_ref``
        (N, 3), ``R`` (N, 9) row-major body → world, ``yaw_ref`` (N,), float64.
        ``active`` (N,) bool: rows that are False keep their state and get zero thrusts.
        Without ``out`` the result is an internal buffer overwritten by the next call (copy
        it to keep it).
        """
        if out is None:
            out = self._out
        cascade_step(self.params, self.state, p, v, R, omega, p_ref, v_ref, a_ref, yaw_ref, dt,
                     self._all if active is None else active, out)
        return out

    @property
    def J(self) -> np.ndarray:
        """(N, 3) principal inertia of each vehicle (kg m²), a writable view of ``params``: the
        gyroscopic term ``ω × Jω`` uses it (a draining tank changes it); the attitude gains
        ``kR``, ``kw`` stay as built, as in :class:`GeometricAttitudeController`."""
        return self.params[:, P_J:P_J + 3]

    def reset_rows(self, rows: np.ndarray) -> None:
        """:meth:`reset` for the vehicles ``rows`` only (index array or bool mask)."""
        for k in range(3):
            self.state[rows, k * AX_NS:(k + 1) * AX_NS] = 0.0

    def reset(self) -> None:
        """Forget every axis controller's integral and derivative memory (as
        :meth:`PositionCascade.reset`: the last command, thrust and tilt are kept)."""
        for k in range(3):
            self.state[:, k * AX_NS:(k + 1) * AX_NS] = 0.0

    def internals(self, i: int) -> dict[str, Any]:
        """Vehicle ``i``'s log values: the keys and values of :meth:`PositionCascade.internals`."""
        P = self.params
        key = (int(P[i, A_TYPE]), int(P[i, AX_NP + A_TYPE]), int(P[i, 2 * AX_NP + A_TYPE]))
        keys = self._keys.get(key)
        if keys is None:
            keys = self._keys[key] = [
                (f"{name}.{attr}", k * AX_NS + _STATE_COL[attr])
                for k, (name, code) in enumerate(zip("xyz", key, strict=True))
                for attr in _AXIS_ATTRS if code != _PID or attr in ("integral", "u")]
        row = self.state[i].tolist()
        out: dict[str, Any] = {k: row[c] for k, c in keys}
        out["ax_cmd"] = row[S_ACMD]
        out["ay_cmd"] = row[S_ACMD + 1]
        out["az_cmd"] = row[S_ACMD + 2]
        out["thrust"] = row[S_THRUST]
        out["tilt_cmd"] = row[S_TILT]
        out["mixer_saturated"] = row[S_SAT]
        return out
