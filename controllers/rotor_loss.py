"""A quadrotor flying on three rotors: the relaxed hover and its reduced-attitude control.

Source: M. W. Mueller and R. D'Andrea, "Stability and control of a quadrocopter despite the
complete loss of one, two, or three propellers", IEEE ICRA 2014, pp. 45-52 (§III the relaxed
hover solutions, §IV the linearised reduced-attitude dynamics and their LQR); the same
construction in M. W. Mueller and R. D'Andrea, "Relaxed hover solutions for multicopters:
application to algorithmic redundancy and novel vehicles", IJRR 35(8), 2016.

Body frame x forward, y left, z up; ``ω = (p, q, r)`` the body rates, ``J = diag(Ix, Iy, Iz)``.
With one rotor stopped the vehicle gives up yaw and spins about a **primary axis** ``n`` fixed
in the body, the thrust's direction in the world held along the commanded one. Euler's
equation with the rotors' torque ``τ`` and the rotors' yaw damping ``γ r`` (in the plant, not
used here)::

    J ω̇ = τ − ω × J ω,     ω × J ω = ((Iz − Iy) q r, (Ix − Iz) p r, (Iy − Ix) p q)
    ṅ_B = −ω × n_B          (n_B: the commanded thrust direction seen in the body)

**The relaxed hover** (the ICRA paper's eq. 11-14 with one propeller lost): the two rotors next
to the stopped one (the diagonal pair) each give ``f``, the opposite one ``ρ f``; the pair's
torques cancel and the opposite rotor's ``τ̄ = ρ f (y_o, −x_o)`` is balanced by the spin's
gyroscopic torque, which fixes ``n̄ ∥ ω̄``::

    p̄ = −τ̄_y / ((Iz − Ix) r),   q̄ = τ̄_x / ((Iz − Iy) r),   n̄ = (p̄, q̄, r) / |(p̄, q̄, r)|

``ρ`` is the smallest that keeps the pair within ``F_SHARE`` of its limit for the commanded
collective (``ρ ≥ f_Σ / (F_SHARE f_max) − 2``), at least ``RHO_MIN`` (two-sided authority on
the opposite rotor), and at most what the spin can balance with ``n̄`` tilted ``TILT_N_MAX`` off
body z: ``ρ ≤ (Iz − I_xy) r² tan(TILT_N_MAX) / (|xy_o| f)``. While the vehicle spins up that
bound is the binding one and the collective falls short of the command (the descent then runs
faster than asked: the physics of three rotors, not a choice of the law).

**Spinning up** (``spun`` false: the spin cannot yet balance ``RHO_MIN`` of the pair's thrust).
Nothing but the stopped and the opposite rotor acts about the pair's diagonal, and the opposite
pushes one way only: the momentum it gives about that diagonal stays until the body has yawed
about a quarter turn (the pair's differential then has a component along it). So while spinning
up the opposite rotor pushes only to brake a body rate against its push, by no more than that
rate's momentum over its lag (:meth:`RelaxedHover.opposite_cap`), and the pair flies at
``F_SHARE`` of its limit whatever the translation asks: the yaw torque ``k Σ f`` that spins the
vehicle up is the pair's thrust, and so is nearly all its lift.

**Reduced attitude** (the paper's §IV): the state ``s = (δp, δq, δn_x, δn_y, δτ_x, δτ_y)``
about the relaxed hover at the measured ``r`` (``n_B`` against ``n̄``; ``δτ`` the motors' lag,
first order with ``τ_m``, tracked by the law's own model of it), linear time-invariant in the
body frame::

    δṗ = ((Iy − Iz) r δq + δτ_x) / Ix       δṅ_x = r δn_y − n̄_z δq
    δq̇ = ((Iz − Ix) r δp + δτ_y) / Iy       δṅ_y = n̄_z δp − r δn_x
    δτ̇ = (δu − δτ) / τ_m

discretised with the control period (zero-order hold, the matrix exponential) and closed with
the discrete LQR gain ``K`` (Riccati iteration), recomputed when ``r`` has moved by more than
``R_RESCHEDULE`` of itself: ``τ_cmd = τ̄ − K s``. The rotors get the torque first
(:meth:`RelaxedHover.allocate`): the opposite rotor alone pushes along ``u_o = (y_o, −x_o)/|xy_o|``
and only one way (``f_o = max(τ·u_o, 0)/|xy_o|``; the stopped rotor gave the other), the pair's
difference along ``u_p`` both ways; what the limits leave goes to the collective. Yaw is what
is left (``k Σ s_i f_i``), which spins the vehicle up.

**Translation** (the paper's §V): a PD on the position and velocity errors gives the commanded
acceleration ``a`` (horizontal part limited to ``tan(TILT_MAX)`` g), ``n_W = (a + g e_z) /
|a + g e_z|`` and ``f_Σ = m |a + g e_z| / n̄_z``.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np

from numkit.axes import X, Y, Z

__all__ = ["RelaxedHover", "expm", "dlqr"]


def expm(A: np.ndarray) -> np.ndarray:
    """Matrix exponential: scaling and squaring of a 16-term Taylor series (``‖A/2^s‖ ≤ 0.5``)."""
    nrm = float(np.abs(A).sum(axis=1).max())
    s = max(0, math.ceil(math.log2(nrm / 0.5))) if nrm > 0.5 else 0
    X = A / (2.0 ** s)
    E = np.eye(len(A))
    term = np.eye(len(A))
    for k in range(1, 17):
        term = term @ X / k
        E = E + term
    for _ in range(s):
        E = E @ E
    return E


def dlqr(Ad: np.ndarray, Bd: np.ndarray, Q: np.ndarray, R: np.ndarray,
         iters: int = 2000, tol: float = 1e-9) -> np.ndarray:
    """The discrete LQR gain ``K`` (``u = −K x``) by iterating the Riccati difference equation
    ``P ← Q + AᵀPA − AᵀPB (R + BᵀPB)⁻¹ BᵀPA`` to its fixed point."""
    P = Q.copy()
    for _ in range(iters):
        BtP = Bd.T @ P
        K = np.linalg.solve(R + BtP @ Bd, BtP @ Ad)
        Pn = Q + Ad.T @ P @ (Ad - Bd @ K)
        if float(np.abs(Pn - P).max()) <= tol * max(1.0, float(np.abs(Pn).max())):
            P = Pn
            break
        P = Pn
    BtP = Bd.T @ P
    return np.linalg.solve(R + BtP @ Bd, BtP @ Ad)


#: the reduced-attitude state (δp, δq, δn_x, δn_y, δτ_x, δτ_y) and the torque input (u_x, u_y)
SP, SQ, SNX, SNY, STX, STY = range(6)
NS, NU = 6, 2
UX, UY = 0, 1
#: the (position error, velocity error) halves of ``update``'s ``error``
EP, EV = slice(0, 3), slice(3, 6)
HORIZ = slice(X, Z)


class RelaxedHover:
    """Three rotors of a quad-X holding the thrust direction while the vehicle spins (module
    docstring). ``update(error, dt, R, omega)`` returns every rotor's thrust (N), the stopped
    one 0; ``mass`` may change between calls (a tank)."""

    F_SHARE = 0.92        # the pair's collective share of f_max (the rest: control)
    RHO_MIN = 0.1         # the opposite rotor's least share of the pair's thrust
    TILT_N_MAX = math.radians(20.0)   # n̄ off body z at most
    TILT_MAX = math.radians(20.0)     # the commanded thrust direction off vertical at most
    R_RESCHEDULE = 0.05   # recompute K when r moved this share (or 0.5 rad/s)
    KP_XY, KD_XY, KP_Z, KD_Z = 0.8, 1.6, 1.5, 2.5
    Q_DIAG = (0.02, 0.02, 40.0, 40.0, 0.0, 0.0)
    R_TORQUE_NM = 4.0     # the torque the LQR weighs as one unit of cost

    def __init__(self, rotor_xy: Sequence[Sequence[float]], failed: int, f_max: float,
                 inertia: Sequence[float], motor_tau_s: float, mass: float,
                 g: float = 9.81) -> None:
        xy = np.asarray(rotor_xy, float)
        if xy.shape != (4, 2):
            raise ValueError(f"rotor_xy: {xy.shape} rotors: a quad-X has 4")
        self.failed, self.f_max, self.mass, self.g = int(failed), float(f_max), mass, g
        self.J = np.asarray(inertia, float)
        self.tau_m = float(motor_tau_s)
        self.opp = int(np.argmin(np.linalg.norm(xy + xy[self.failed], axis=1)))
        self.pair = [i for i in range(4) if i not in (self.failed, self.opp)]
        self.live = [self.pair[0], self.opp, self.pair[1]]
        self.xy = xy
        self.arm_o = float(np.hypot(*xy[self.opp]))
        self.u_o = np.array([xy[self.opp, 1], -xy[self.opp, 0]]) / self.arm_o
        p0 = xy[self.pair[0]]
        self.arm_p = float(np.hypot(*p0))
        self.u_p = np.array([p0[1], -p0[0]]) / self.arm_p
        self.tau_est = np.zeros(2)    # the motors' torque, the law's first-order model of it
        self.K = np.zeros((2, 6))
        self.r_K = math.nan
        self.n_bar = np.array([0.0, 0.0, 1.0])
        self.rho = self.RHO_MIN
        self.spun = False             # the spin balances the opposite rotor's least share
        self.shortfall = 0.0          # the collective asked but not given (N)

    # ------------------------------------------------------------------------ relaxed hover
    def hover(self, f_sum: float, r: float) -> tuple[np.ndarray, np.ndarray, np.ndarray, float]:
        """The relaxed hover at collective ``f_sum`` and spin ``r``: (τ̄_xy, ω̄_xy, n̄, f_Σ
        given)."""
        Ix, Iy, Iz = self.J
        cap = self.F_SHARE * self.f_max
        rho = max(self.RHO_MIN, f_sum / cap - 2.0)
        f = f_sum / (2.0 + rho)
        dI = min(Iz - Ix, Iz - Iy)
        rho_spin = dI * r * r * math.tan(self.TILT_N_MAX) / (self.arm_o * max(f, 1e-6))
        self.spun = rho_spin >= self.RHO_MIN
        rho = min(rho, rho_spin, 1.0)
        f = min(f_sum / (2.0 + rho), cap)
        self.rho = rho
        xo, yo = self.xy[self.opp]
        tau = rho * f * np.array([yo, -xo])
        if abs(r) > 1e-3:
            w = np.array([-tau[1] / ((Iz - Ix) * r), tau[0] / ((Iz - Iy) * r)])
        else:
            w = np.zeros(2)
        n = np.array([w[0], w[1], r if abs(r) > 1e-3 else 1.0])
        n = n / np.linalg.norm(n) * (1.0 if abs(r) <= 1e-3 else math.copysign(1.0, r))
        return tau, w, n, f * (2.0 + rho)

    # ------------------------------------------------------------------------ the LQR gain
    def gain(self, r: float, nz: float, dt: float) -> np.ndarray:
        """The discrete LQR gain of the reduced-attitude dynamics at spin ``r``."""
        Ix, Iy, Iz = self.J
        A = np.zeros((NS, NS))
        A[SP, SQ], A[SP, STX] = (Iy - Iz) * r / Ix, 1.0 / Ix
        A[SQ, SP], A[SQ, STY] = (Iz - Ix) * r / Iy, 1.0 / Iy
        A[SNX, SNY], A[SNX, SQ] = r, -nz
        A[SNY, SP], A[SNY, SNX] = nz, -r
        A[STX, STX] = A[STY, STY] = -1.0 / self.tau_m
        B = np.zeros((NS, NU))
        B[STX, UX] = B[STY, UY] = 1.0 / self.tau_m
        M = np.zeros((NS + NU, NS + NU))   # zero-order hold: expm([[A, B], [0, 0]] dt)
        M[:NS, :NS], M[:NS, NS:] = A * dt, B * dt
        E = expm(M)
        Q = np.diag(self.Q_DIAG) + 1e-6 * np.eye(NS)
        R = np.eye(NU) / self.R_TORQUE_NM ** 2
        return dlqr(E[:NS, :NS], E[:NS, NS:], Q, R)

    def opposite_cap(self, omega_xy: np.ndarray, dt: float) -> float:
        """The most the opposite rotor may push (N). Spun up, its limit. While spinning up
        (``ρ`` bounded below ``RHO_MIN`` by the spin) its push only adds momentum about the pair's
        diagonal that nothing can take out before the body has yawed a quarter turn (the pair's
        thrust acts about the other axis), so it pushes only to brake a body rate against it
        (``ω·u_o < 0``), and no more than that rate's momentum over its lag:
        ``f_o ≤ I_u |ω·u_o| / (|xy_o| (τ_m + dt))``, ``I_u = u_oᵀ diag(Ix, Iy) u_o``."""
        if self.spun:
            return self.f_max
        w = float(omega_xy @ self.u_o)
        if w >= 0.0:
            return 0.0
        i_u = float(self.J[X] * self.u_o[0] ** 2 + self.J[Y] * self.u_o[1] ** 2)
        return min(self.f_max, i_u * -w / (self.arm_o * (self.tau_m + dt)))

    def allocate(self, f_sum: float, tau: np.ndarray, o_max: float | None = None
                 ) -> np.ndarray:
        """The three rotors' thrusts (pair[0], opposite, pair[1]) for the collective ``f_sum``
        and the torque ``tau``, torque first: the opposite rotor alone pushes along
        ``u_o = (y_o, −x_o)/|xy_o|`` (one sign only: the stopped rotor gave the other), the
        pair's difference along ``u_p`` (both signs); what the limits leave goes to the
        collective."""
        fm = self.f_max
        f_o = min(max(float(tau @ self.u_o), 0.0) / self.arm_o, fm if o_max is None else o_max)
        diff = float(np.clip(float(tau @ self.u_p) / self.arm_p, -fm, fm))
        pair = min(max(f_sum - f_o, abs(diff)), 2.0 * fm - abs(diff))
        return np.array([0.5 * (pair + diff), f_o, 0.5 * (pair - diff)])

    # ------------------------------------------------------------------------ one tick
    def update(self, error: Sequence[float], dt: float, R: Sequence[float],
               omega: Sequence[float], a_ff: Sequence[float] = (0.0, 0.0, 0.0)) -> np.ndarray:
        """One tick: ``error`` = (position error, velocity error) in the world (reference −
        vehicle, 6 values), ``R`` the body-to-world rotation (9, row-major), ``omega`` the
        body rates; returns the four rotors' thrusts (N)."""
        e = np.asarray(error, float)
        Rm = np.asarray(R, float).reshape(3, 3)
        w = np.asarray(omega, float)
        kp = np.array([self.KP_XY, self.KP_XY, self.KP_Z])
        kd = np.array([self.KD_XY, self.KD_XY, self.KD_Z])
        a = np.asarray(a_ff, float) + kp * e[EP] + kd * e[EV]
        h = math.hypot(a[X], a[Y])
        lim = math.tan(self.TILT_MAX) * self.g
        if h > lim:
            a[HORIZ] *= lim / h
        a[Z] = max(a[Z] + self.g, 0.2 * self.g)
        n_w = a / np.linalg.norm(a)
        r = float(w[Z])
        f_sum = self.mass * float(np.linalg.norm(a)) / max(self.n_bar[Z], 0.5)
        tau_bar, w_bar, n_bar, f_given = self.hover(f_sum, r)
        self.n_bar = n_bar
        self.shortfall = f_sum - f_given
        if not self.spun:  # spinning up: the pair at its share of the limit (its yaw torque)
            f_given = 2.0 * self.F_SHARE * self.f_max
        if not (abs(r - self.r_K) <= self.R_RESCHEDULE * abs(self.r_K) + 0.5):
            self.K = self.gain(r, float(n_bar[Z]), dt)
            self.r_K = r
        n_b = Rm.T @ n_w
        s = np.array([w[0] - w_bar[0], w[1] - w_bar[1], n_b[0] - n_bar[0], n_b[1] - n_bar[1],
                      self.tau_est[0] - tau_bar[0], self.tau_est[1] - tau_bar[1]])
        tau = tau_bar - self.K @ s
        f3 = self.allocate(f_given, tau, self.opposite_cap(w[HORIZ], dt))
        out = np.zeros(4)
        out[self.live] = f3
        tau_real = np.array([self.xy[self.live, 1] @ f3, -(self.xy[self.live, 0] @ f3)])
        self.tau_est += (tau_real - self.tau_est) * (1.0 - math.exp(-dt / self.tau_m))
        return out
