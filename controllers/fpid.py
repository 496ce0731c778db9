"""Fuzzy PID controllers: interval type-2 (IT2-FPID) and type-1 (FPID).

Law (one controller per axis; the Kumbasar-group structure, Kumbasar & Hagras, Information
Sciences 282 (2014), used by Candan & Li's agricultural-UAV paper, Table I)::

    e_k  = error,   ed_k = (e_k - e_{k-1})/dt   or  -(y_k - y_{k-1})/dt (derivative="measurement")
    ed_k = 0 on the first call (no derivative kick); optional low-pass with time constant d_tau
    E    = clip(Ke e_k, -1, 1)
    dE   = clip(Kd ed_k, -1, 1)
    U    = Φ(E, dE)                      fuzzy PD core, |U| <= 1  (controllers.fuzzy)
    I_k  = I_{k-1} + dt U                clamped so that |K1 I_k| <= i_limit
    u_k  = K0 U + K1 I_k                 "PD part" + "PI part"; clamped to u_limit with
                                         conditional integration

Near the origin Φ ≈ G_E E + G_dE dE, which gives the equivalent linear PID (see
:func:`equivalent_pid`): Kp = K0 Ke G_E + K1 Kd G_dE, Ki = K1 Ke G_E, Kd = K0 Kd G_dE.
The controller is odd in (Ke, Kd, K0, K1) jointly; tune with positive bounds.
The law is computed by :func:`controllers.axis.axis_step` (one implementation shared with
:class:`controllers.pid.PID`, the cascade and the batch kernel).
"""

from __future__ import annotations

from typing import Any

from .axis import KIND_IT2, KIND_T1, A, ControllerBase, S, param, state
from .fuzzy import IT2FuzzyPD, T1FuzzyPD

__all__ = ["FPID", "IT2FPID", "PAPER_TABLE_I", "equivalent_pid"]

#: Candan & Li, Table I (indicative only: units and plant of the paper are unknown; the
#: paper does not say which type reducer it used — ``zeta`` suggests the "zeta" reducer).
PAPER_TABLE_I: dict[str, float] = {
    "Ke": 0.0034,
    "Kd": 0.003,
    "K0": 0.001,
    "K1": 65.0,
    "alpha": 0.25,
    "zeta": 0.5,
}


def equivalent_pid(
    Ke: float, Kd: float, K0: float, K1: float, G: float | tuple[float, float]
) -> tuple[float, float, float]:
    """Linear PID gains (Kp, Ki, Kd) of a fuzzy PID near the origin.

    ``G`` is the small-signal slope of the core (a float, or (G_E, G_dE) when the two inputs
    have different slopes)::

        Kp = K0 Ke G_E + K1 Kd G_dE,   Ki = K1 Ke G_E,   Kd = K0 Kd G_dE

    (substitute U ≈ G_E Ke e + G_dE Kd ė into u = K0 U + K1 ∫U).

    Caveat: the NT, BMM, zeta and type-1 cores are differentiable at the origin, so this is
    their first-order model for any small signal. The KM core is only piecewise linear there:
    the slopes hold along the axes and where E and dE have the same sign, but in the
    quadrants E·dE < 0 the first-order response differs (by ~17 % at Table I's heights).
    """
    if isinstance(G, tuple | list):
        g_e, g_de = float(G[0]), float(G[1])
    else:
        g_e = g_de = float(G)
    return (K0 * Ke * g_e + K1 * Kd * g_de, K1 * Ke * g_e, K0 * Kd * g_de)


class _FuzzyPID(ControllerBase):
    """Shared shell of the fuzzy PID law around a core ``Φ(E, dE)`` (the law itself is
    :func:`controllers.axis.axis_step`; the core's parameters are copied into the parameter
    block at construction).

    Attributes after :meth:`update` (for logging): ``e, de, E, dE, U, integral, u`` and the
    two parts ``u_pd = K0 U`` and ``u_pi = K1 I``.
    """

    core: IT2FuzzyPD | T1FuzzyPD
    Ke = param(A.G0, "Input scaling of the error.")
    Kd = param(A.G1, "Input scaling of the error's derivative.")
    K0 = param(A.G2, "Output gain of the PD part K0·U.")
    K1 = param(A.G3, "Output gain of the PI part K1·∫U.")
    E = state(S.E, "Last scaled, clipped error E.")
    dE = state(S.DE, "Last scaled, clipped derivative dE.")
    U = state(S.U, "Last core output U = Φ(E, dE).")

    def _init_gains(
        self,
        Ke: float,
        Kd: float,
        K0: float,
        K1: float,
        derivative: str,
        i_limit: float | None,
        u_limit: float | tuple[float, float] | None,
        d_tau: float,
    ) -> None:
        self._init_blocks()
        core = self.core
        self._p[A.CM] = core.cm
        if isinstance(core, IT2FuzzyPD):
            self._p[A.RED] = float(core.reducer_code)
            self._p[A.ZETA] = core.zeta
            self._p[A.HN1:A.HP2_END] = (*core.heights_e, *core.heights_de)
        self.Ke = Ke
        self.Kd = Kd
        self.K0 = K0
        self.K1 = K1
        self._init_common(derivative, i_limit, u_limit, d_tau)
        self.reset()

    @property
    def u_pd(self) -> float:
        """Last PD part K0·U."""
        return self.K0 * self.U

    @property
    def u_pi(self) -> float:
        """Last PI part K1·I."""
        return self.K1 * self.integral

    def small_signal_gains(self) -> tuple[float, float]:
        """(G_E, G_dE) of the core at the origin (closed form when available)."""
        core = self.core
        if isinstance(core, T1FuzzyPD):
            return core.cm, core.cm
        h_n, _, h_p = core.heights_e
        if core.heights_e == core.heights_de and h_n == h_p:
            g = core.small_signal_gain()
            return g, g
        return core.small_signal_gains()

    def equivalent_pid(self) -> tuple[float, float, float]:
        """(Kp, Ki, Kd) of the linearisation at the origin; see :func:`equivalent_pid`."""
        return equivalent_pid(self.Ke, self.Kd, self.K0, self.K1, self.small_signal_gains())


class IT2FPID(_FuzzyPID):
    """Interval type-2 fuzzy PID (one axis).

    Parameters
    ----------
    Ke, Kd : input scaling of the error and of its derivative.
    K0, K1 : output gains of the PD part (K0·U) and of the PI part (K1·∫U).
    **core : the IT2 core's alpha, cm, reducer, zeta, heights
        (:class:`controllers.fuzzy.IT2FuzzyPD`).
    derivative : "error" (d e/dt) or "measurement" (−d y/dt; pass ``measurement=y``).
    i_limit : anti-windup clamp, |K1·I| <= i_limit (None: no clamp).
    u_limit : output clamp, a symmetric bound or (lower, upper); conditional integration.
    d_tau : time constant of a first-order low-pass on the derivative (0: none).
    """

    _KIND = KIND_IT2

    def __init__(
        self,
        Ke: float,
        Kd: float,
        K0: float,
        K1: float,
        *,
        derivative: str = "error",
        i_limit: float | None = None,
        u_limit: float | tuple[float, float] | None = None,
        d_tau: float = 0.0,
        **core: Any,
    ) -> None:
        self.core = IT2FuzzyPD(**core)  # alpha, cm, reducer, zeta, heights (TypeError: others)
        self._init_gains(Ke, Kd, K0, K1, derivative, i_limit, u_limit, d_tau)

    def __repr__(self) -> str:
        return (
            f"IT2FPID(Ke={self.Ke}, Kd={self.Kd}, K0={self.K0}, K1={self.K1}, core={self.core!r})"
        )


class FPID(_FuzzyPID):
    """Type-1 fuzzy PID (one axis): same law as :class:`IT2FPID` with a type-1 core.

    Parameters as :class:`IT2FPID`; the core has only ``cm`` (small-signal slope c_m).
    """

    _KIND = KIND_T1

    def __init__(
        self,
        Ke: float,
        Kd: float,
        K0: float,
        K1: float,
        *,
        cm: float = 0.7,
        derivative: str = "error",
        i_limit: float | None = None,
        u_limit: float | tuple[float, float] | None = None,
        d_tau: float = 0.0,
    ) -> None:
        self.core = T1FuzzyPD(cm=cm)
        self._init_gains(Ke, Kd, K0, K1, derivative, i_limit, u_limit, d_tau)

    def __repr__(self) -> str:
        return f"FPID(Ke={self.Ke}, Kd={self.Kd}, K0={self.K0}, K1={self.K1}, cm={self.core.cm})"
