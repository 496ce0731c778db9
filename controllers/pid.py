"""Discrete PID controller with the same interface as the fuzzy PIDs in :mod:`controllers.fpid`.

Common interface of every controller in this package::

    c = PID(Kp, Ki, Kd, derivative="error", i_limit=None, u_limit=None, d_tau=0.0)
    u = c.update(error, dt, measurement=None)   # one control tick, returns a float
    c.reset()                                    # forget integral and derivative memory

Discrete law (backward Euler, sample time dt)::

    e_k  = error
    ed_k = (e_k - e_{k-1}) / dt          derivative="error" (default)
         = -(y_k - y_{k-1}) / dt         derivative="measurement" (y = measurement)
    ed_k = 0 on the first call after construction/reset (no derivative kick)
    ed_k <- first-order low-pass with time constant d_tau (if d_tau > 0)
    I_k  = I_{k-1} + dt * e_k            clamped so that |Ki * I_k| <= i_limit
    u_k  = Kp e_k + Ki I_k + Kd ed_k     clamped to u_limit with conditional integration

Conditional integration (anti-windup, Åström & Hägglund, *Advanced PID Control*, 2006,
§3.5): when the unclamped output exceeds a limit and this tick's integration pushes it
further out, the integral keeps its previous value.
"""

from __future__ import annotations

import math

__all__ = ["PID", "ControllerBase"]

_DERIVATIVE_MODES = ("error", "measurement")


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


class ControllerBase:
    """Derivative memory, derivative filter and limits shared by PID and fuzzy PIDs."""

    derivative: str
    i_limit: float | None
    u_limit: float | tuple[float, float] | None
    d_tau: float

    def _init_common(
        self,
        derivative: str,
        i_limit: float | None,
        u_limit: float | tuple[float, float] | None,
        d_tau: float,
    ) -> None:
        if derivative not in _DERIVATIVE_MODES:
            raise ValueError(f"derivative must be one of {_DERIVATIVE_MODES}, got {derivative!r}")
        if i_limit is not None and not i_limit >= 0.0:
            raise ValueError(f"i_limit must be >= 0, got {i_limit}")
        if not d_tau >= 0.0:
            raise ValueError(f"d_tau must be >= 0, got {d_tau}")
        self.derivative = derivative
        self._on_meas = derivative == "measurement"
        self.i_limit = None if i_limit is None else float(i_limit)
        self.u_limit = u_limit
        self._umin, self._umax = _limits(u_limit)
        self.d_tau = float(d_tau)

    def _reset_derivative(self) -> None:
        self._prev: float | None = None
        self._dfilt = 0.0

    def _derivative(self, error: float, dt: float, measurement: float | None,
                    error_rate: float | None = None) -> float:
        """Raw (optionally low-passed) derivative of the error; 0 on the first call.

        ``error_rate``, when given, is used as the derivative directly (e.g. ``v_ref − v`` from a
        velocity estimate, which is smoother than differencing a position that jumps at every
        GPS fix); the finite-difference memory is still updated.
        """
        if not dt > 0.0:
            raise ValueError(f"dt must be > 0, got {dt}")
        if error_rate is not None:
            self._prev = -measurement if (self._on_meas and measurement is not None) else error
            return error_rate
        if self._on_meas:
            if measurement is None:
                raise ValueError('derivative="measurement" needs update(..., measurement=y)')
            x = -measurement
        else:
            x = error
        prev = self._prev
        self._prev = x
        if prev is None:
            return 0.0
        d = (x - prev) / dt
        tau = self.d_tau
        if tau > 0.0:
            d = self._dfilt + dt / (tau + dt) * (d - self._dfilt)
            self._dfilt = d
        return d


    def _integrate(self, dI: float, K: float, u_rest: float) -> tuple[float, float]:
        """Advance the integral by ``dI`` with anti-windup; returns (integral, output).

        The output is ``u_rest + K·I``. The integral is clamped so that |K·I| ≤ ``i_limit``;
        where the output saturates, the step is dropped if it drives further into the limit
        (conditional integration), and the output is clamped to ``u_limit``.
        """
        I_old = self.integral
        I = I_old + dI
        lim = self.i_limit
        if lim is not None and K != 0.0:
            imax = lim / abs(K)
            if I > imax:
                I = imax
            elif I < -imax:
                I = -imax
        u = u_rest + K * I
        if u > self._umax:
            if K * (I - I_old) > 0.0:  # integration drives further into saturation
                I = I_old
                u = u_rest + K * I
            if u > self._umax:
                u = self._umax
        elif u < self._umin:
            if K * (I - I_old) < 0.0:
                I = I_old
                u = u_rest + K * I
            if u < self._umin:
                u = self._umin
        return I, u


class PID(ControllerBase):
    """Parallel-form discrete PID: u = Kp·e + Ki·∫e + Kd·ė (see module docstring).

    After each :meth:`update` the terms are available for logging as attributes
    ``e, de, p, i, d, u, integral``.
    """

    def __init__(
        self,
        Kp: float,
        Ki: float = 0.0,
        Kd: float = 0.0,
        *,
        derivative: str = "error",
        i_limit: float | None = None,
        u_limit: float | tuple[float, float] | None = None,
        d_tau: float = 0.0,
    ) -> None:
        self.Kp = float(Kp)
        self.Ki = float(Ki)
        self.Kd = float(Kd)
        self._init_common(derivative, i_limit, u_limit, d_tau)
        self.reset()

    def __repr__(self) -> str:
        return f"PID(Kp={self.Kp}, Ki={self.Ki}, Kd={self.Kd}, derivative={self.derivative!r})"

    def reset(self, integral: float = 0.0) -> None:
        """Clear derivative memory; set the integral state (default 0)."""
        self._reset_derivative()
        self.integral = float(integral)
        self.e = self.de = self.p = self.i = self.d = self.u = 0.0

    def update(self, error: float, dt: float, measurement: float | None = None,
               error_rate: float | None = None) -> float:
        """One control tick; returns the (clamped) control output."""
        de = self._derivative(error, dt, measurement, error_rate)
        Ki = self.Ki
        p = self.Kp * error
        d = self.Kd * de
        I, u = self._integrate(dt * error, Ki, p + d)
        self.integral = I
        self.e = error
        self.de = de
        self.p = p
        self.i = Ki * I
        self.d = d
        self.u = u
        return u
