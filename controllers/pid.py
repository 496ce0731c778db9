"""Discrete PID controller with the same interface as the fuzzy PIDs in :mod:`controllers.fpid`.

Common interface of every controller in this package::

    c = PID(Kp, Ki, Kd, derivative="error", i_limit=None, u_limit=None, d_tau=0.0)
    u = c.update(error, dt, measurement=None)   # one control tick, returns a float
    c.reset()                                    # forget integral and derivative memory

Discrete law (backward Euler, sample time dt; computed by :func:`controllers.axis.axis_step`,
the one implementation shared with the fuzzy PIDs, the cascade and the batch kernel)::

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

from .axis import KIND_PID, A, ControllerBase, param

__all__ = ["PID", "ControllerBase"]


class PID(ControllerBase):
    """Parallel-form discrete PID: u = Kp·e + Ki·∫e + Kd·ė (see module docstring).

    After each :meth:`update` the terms are available for logging as attributes
    ``e, de, p, i, d, u, integral``.
    """

    _KIND = KIND_PID
    Kp = param(A.G0, "Proportional gain.")
    Kd = param(A.G1, "Derivative gain.")
    Ki = param(A.G3, "Integral gain.")

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
        self._init_blocks()
        self.Kp = Kp
        self.Ki = Ki
        self.Kd = Kd
        self._init_common(derivative, i_limit, u_limit, d_tau)
        self.reset()

    def __repr__(self) -> str:
        return f"PID(Kp={self.Kp}, Ki={self.Ki}, Kd={self.Kd}, derivative={self.derivative!r})"

    @property
    def p(self) -> float:
        """Last proportional term Kp·e."""
        return self.Kp * self.e

    @property
    def i(self) -> float:
        """Last integral term Ki·I."""
        return self.Ki * self.integral

    @property
    def d(self) -> float:
        """Last derivative term Kd·ė."""
        return self.Kd * self.de
