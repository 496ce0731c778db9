"""The one implementation of the per-axis controller law (PID, type-1 FPID, IT2-FPID):
:func:`axis_step`, compiled with numba, on one controller's parameter block and state block.

The scalar classes (:class:`controllers.pid.PID`, :class:`controllers.fpid.FPID`,
:class:`controllers.fpid.IT2FPID`) are thin shells around their own blocks (a "batch of one",
:class:`ControllerBase`); the cascade row (:func:`controllers.cascade.vehicle_step`) and the
batch kernel (:mod:`controllers.batched`) call the same function on slices of a vehicle's row.

Law (one tick, sample time dt; Åström & Hägglund, *Advanced PID Control*, 2006, §3.5)::

    x_k  = e_k                       derivative="error"
         = -y_k                      derivative="measurement" (y = measurement)
    ed_k = error_rate                when the caller gives it (memory x still updated, no filter)
         = 0                         first call after construction/reset (no derivative kick)
         = (x_k - x_{k-1}) / dt      otherwise, then low-passed with time constant d_tau > 0:
                                     ed_k <- f_{k-1} + dt/(d_tau + dt) (ed_k - f_{k-1})
    PID   : u_rest = Kp e_k + Kd ed_k,     dI = dt e_k,  K = Ki
    fuzzy : E = clip(Ke e_k, ±1), dE = clip(Kd ed_k, ±1), U = Φ(E, dE) (t1_phi / it2_phi of
            :mod:`controllers.fuzzy`),     u_rest = K0 U, dI = dt U,  K = K1
    I_k  = I_{k-1} + dI              clamped so that |K I_k| <= i_limit
    u_k  = u_rest + K I_k            clamped to [u_min, u_max]; where it saturates and this tick's
                                     integration drives further out, I_k = I_{k-1}
                                     (conditional integration)

Parameter block (``AX_NP`` floats): type code (0 PID, 1 type-1 FPID, 2 IT2-FPID), reducer code
(0 km, 1 nt, 2 bmm, 3 zeta), gains ``G0..G3`` (PID: Kp, Kd, −, Ki; fuzzy: Ke, Kd, K0, K1), c_m,
ζ, lower-MF heights (h_N, h_Z, h_P) of E then of dE, derivative-on-measurement flag, i_limit
(``inf`` for none), u_limit lower and upper (``∓inf`` for none), d_tau.
State block (``AX_NS`` floats): E, dE, U, integral, u, derivative memory x, has-memory flag,
derivative-filter state, e, ed.
"""

from __future__ import annotations

import math

import numpy as np

from numkit import Layout

from ._jit import njit
from .fuzzy import it2_phi_jit as _it2_phi
from .fuzzy import t1_phi_jit as _t1_phi
from .rows import RowBlocks

__all__ = ["AXIS_PARAMS", "AXIS_STATE", "AX_NP", "AX_NS", "ControllerBase", "axis_step"]

KIND_PID, KIND_T1, KIND_IT2 = 0, 1, 2

#: parameter block: type code, reducer code, gains G0..G3, c_m, ζ, lower-MF heights (h_N, h_Z,
#: h_P) of E then of dE, derivative-on-measurement flag, i_limit, u_limit lower and upper, d_tau
AXIS_PARAMS = Layout("type red g0 g1 g2 g3 cm zeta hn1 hz1 hp1 hn2 hz2 hp2 onmeas ilim umin umax "
                     "dtau")
#: state block: E, dE, U, integral, u, derivative memory x, has-memory flag, derivative-filter
#: state, e, ed
AXIS_STATE = Layout("e de u i uout prev hasprev dfilt err rate")
A = AXIS_PARAMS.at
S = AXIS_STATE.at
AX_NP = AXIS_PARAMS.size
AX_NS = AXIS_STATE.size

_DERIVATIVE_MODES = ("error", "measurement")



@njit
def _integrate(prm: np.ndarray, st: np.ndarray, dI: float, K: float, u_rest: float) -> float:
    """Integral clamp, output clamp and conditional integration; stores I and u, returns u."""
    I_old = st[S.I]
    I = I_old + dI  # noqa: E741
    lim = prm[A.ILIM]
    if lim != math.inf and K != 0.0:
        imax = lim / abs(K)
        if I > imax:
            I = imax  # noqa: E741
        elif I < -imax:
            I = -imax  # noqa: E741
    u = u_rest + K * I
    umax = prm[A.UMAX]
    umin = prm[A.UMIN]
    # conditional integration: drop this tick's step where it drives further into saturation
    if (u > umax and K * (I - I_old) > 0.0) or (u < umin and K * (I - I_old) < 0.0):
        I = I_old  # noqa: E741
        u = u_rest + K * I
    if u > umax:
        u = umax
    elif u < umin:
        u = umin
    st[S.I] = I
    st[S.UOUT] = u
    return u


@njit
def axis_step(prm: np.ndarray, st: np.ndarray, error: float, meas: float, has_meas: bool,
              rate: float, has_rate: bool, dt: float) -> float:
    """One tick of the axis law (module docstring) on parameter block ``prm`` and state block
    ``st`` (advanced in place); returns the clamped output u.

    ``meas``/``has_meas``: the measurement y (read in derivative="measurement" mode);
    ``rate``/``has_rate``: the error rate used as the derivative. The caller checks dt > 0 and
    that a measurement-mode controller without a rate gets a measurement.
    """
    x = -meas if (prm[A.ONMEAS] != 0.0 and has_meas) else error
    if has_rate:
        de = rate
    elif st[S.HASPREV] == 0.0:
        de = 0.0
    else:
        de = (x - st[S.PREV]) / dt
        tau = prm[A.DTAU]
        if tau > 0.0:
            df = st[S.DFILT]
            de = df + dt / (tau + dt) * (de - df)
            st[S.DFILT] = de
    st[S.PREV] = x
    st[S.HASPREV] = 1.0
    st[S.ERR] = error
    st[S.RATE] = de
    kind = int(prm[A.TYPE])
    if kind == KIND_PID:
        p = prm[A.G0] * error
        d = prm[A.G1] * de
        return _integrate(prm, st, dt * error, prm[A.G3], p + d)
    E = prm[A.G0] * error
    if E > 1.0:
        E = 1.0
    elif E < -1.0:
        E = -1.0
    dE = prm[A.G1] * de
    if dE > 1.0:
        dE = 1.0
    elif dE < -1.0:
        dE = -1.0
    cm = prm[A.CM]
    y = (-1.0, -cm, 0.0, cm, 1.0)
    if kind == KIND_T1:
        U = _t1_phi(E, dE, y)
    else:
        U = _it2_phi(E, dE, y, (prm[A.HN1], prm[A.HZ1], prm[A.HP1]),
                     (prm[A.HN2], prm[A.HZ2], prm[A.HP2]), int(prm[A.RED]), prm[A.ZETA])
    st[S.E] = E
    st[S.DE] = dE
    st[S.U] = U
    return _integrate(prm, st, dt * U, prm[A.G3], prm[A.G2] * U)


# ================================================================================ Python shell
def _limits(u_limit: float | tuple[float, float] | None) -> tuple[float, float]:
    if u_limit is None:
        return -math.inf, math.inf
    if isinstance(u_limit, tuple | list):
        lo, hi = float(u_limit[0]), float(u_limit[1])
    else:
        hi = abs(float(u_limit))
        lo = -hi
    if not lo < hi:
        raise ValueError(f"u_limit needs lower < upper, got {u_limit!r}")
    return lo, hi


def param(col: int, doc: str) -> property:
    """A float attribute stored in the parameter block (read by the law every tick)."""

    def get(self: ControllerBase) -> float:
        return float(self._p[col])

    def set_(self: ControllerBase, value: float) -> None:
        self._p[col] = float(value)

    return property(get, set_, doc=doc)


def state(col: int, doc: str) -> property:
    """A float of the state block (last tick's value)."""

    def get(self: ControllerBase) -> float:
        return float(self._s[col])

    return property(get, doc=doc)


class ControllerBase(RowBlocks):
    """Python shell of one axis controller: its parameter block ``_p`` (AX_NP,) and state block
    ``_s`` (AX_NS,), the validation, :meth:`update` and :meth:`reset`; the law is
    :func:`axis_step`. A :class:`~controllers.cascade.PositionCascade` adopts the blocks (they
    become views of its row), so the object and the cascade always see the same state."""

    _KIND: int = KIND_PID

    e = state(S.ERR, "Last error e.")
    de = state(S.RATE, "Last derivative of the error used (rate, difference or filtered).")
    u = state(S.UOUT, "Last (clamped) output.")

    def _init_blocks(self) -> None:
        self._p = np.zeros(AX_NP)
        self._s = np.zeros(AX_NS)
        self._p[A.TYPE] = float(self._KIND)
        self._p[A.HN1:A.HP2_END] = 1.0
        self._p[A.CM] = 0.5

    def _init_common(self, derivative: str, i_limit: float | None,
                     u_limit: float | tuple[float, float] | None, d_tau: float) -> None:
        self.derivative = derivative
        self.i_limit = i_limit
        self.u_limit = u_limit
        self.d_tau = d_tau

    @property
    def derivative(self) -> str:
        """"error" (d e/dt) or "measurement" (−d y/dt)."""
        return _DERIVATIVE_MODES[int(self._p[A.ONMEAS] != 0.0)]

    @derivative.setter
    def derivative(self, mode: str) -> None:
        if mode not in _DERIVATIVE_MODES:
            raise ValueError(f"derivative must be one of {_DERIVATIVE_MODES}, got {mode!r}")
        self._p[A.ONMEAS] = 1.0 if mode == "measurement" else 0.0

    @property
    def i_limit(self) -> float | None:
        """Integral clamp |K·I| <= i_limit (None: none)."""
        lim = float(self._p[A.ILIM])
        return None if lim == math.inf else lim

    @i_limit.setter
    def i_limit(self, value: float | None) -> None:
        if value is not None and not value >= 0.0:
            raise ValueError(f"i_limit must be >= 0, got {value}")
        self._p[A.ILIM] = math.inf if value is None else float(value)

    @property
    def u_limit(self) -> float | tuple[float, float] | None:
        """Output clamp as given: a symmetric bound, (lower, upper) or None."""
        return self._u_limit

    @u_limit.setter
    def u_limit(self, value: float | tuple[float, float] | None) -> None:
        self._p[A.UMIN], self._p[A.UMAX] = _limits(value)
        self._u_limit = value

    @property
    def d_tau(self) -> float:
        """Time constant of the derivative low-pass (0: none)."""
        return float(self._p[A.DTAU])

    @d_tau.setter
    def d_tau(self, value: float) -> None:
        if not value >= 0.0:
            raise ValueError(f"d_tau must be >= 0, got {value}")
        self._p[A.DTAU] = float(value)

    @property
    def integral(self) -> float:
        """Integral state I."""
        return float(self._s[S.I])

    @integral.setter
    def integral(self, value: float) -> None:
        self._s[S.I] = float(value)

    def reset(self, integral: float = 0.0) -> None:
        """Clear derivative memory and the last tick's values; set the integral (default 0)."""
        self._s[:] = 0.0
        self._s[S.I] = float(integral)

    def update(self, error: float, dt: float, measurement: float | None = None,
               error_rate: float | None = None) -> float:
        """One control tick; returns the (clamped) output (:func:`axis_step`).

        ``error_rate``, when given, is the derivative directly (e.g. ``v_ref − v`` from a
        velocity estimate, smoother than differencing a position that jumps at every GPS fix).
        """
        if not dt > 0.0:
            raise ValueError(f"dt must be > 0, got {dt}")
        has_rate = error_rate is not None
        if measurement is None:
            if not has_rate and self._p[A.ONMEAS] != 0.0:
                raise ValueError('derivative="measurement" needs update(..., measurement=y)')
            return float(axis_step(self._p, self._s, error, 0.0, False,
                                   error_rate if has_rate else 0.0, has_rate, dt))
        return float(axis_step(self._p, self._s, error, measurement, True,
                               error_rate if has_rate else 0.0, has_rate, dt))
