"""The downwash of a multirotor from its geometry: each rotor's own jet near the vehicle, one
merged round jet of the whole vehicle below it.

**Near the vehicle** each rotor's far wake (momentum theory: 2 v_i over the contracted area
A_r/2, diameter D/√2; Leishman, *Principles of Helicopter Aerodynamics* §2.3) keeps its speed
over a core of length s_r = B D/√2 and then decays as a round jet, u = 2 v_i s_r / s.

**Below the vehicle** the rotors' jets merge into one turbulent round jet: Bauersfeld, Muller,
Ziegler, Coletti & Scaramuzza (2024, "Robotics meets Fluid Dynamics: A Characterization of the
Induced Airflow below a Quadrotor as a Turbulent Jet", arXiv 2403.13321; 16 h of flights of six
quadrotors) find the combined flow a turbulent jet beyond about 2.5 vehicle length scales l (the
motor-to-motor distance; here l = 2 × the arm, the wheelbase), scaled by the hover induced
velocity, the rotor size and the vehicle size. A round jet's centreline decays as

    u_c(s) = B u_0 D_0 / (s − s_v)        (Pope 2000, *Turbulent Flows* §5.1; B ≈ 5.8-6.1)

with u_0 D_0 the exit velocity × diameter of a jet with the same momentum flux. The merged jet
carries the whole thrust T = ρ u_0² π D_0²/4 (its momentum flux), so with u_0 = 2 v_i and
D_0 = D_eq/√2, D_eq = √n D (n rotors of diameter D: the total disc area), B u_0 D_0 = √n × a
single rotor's. Its virtual origin s_v makes the velocity continuous at the merge depth
s_m = 2.5 l: s_v = s_m − B u_0 D_0 / u_near(s_m). The speed never exceeds u_0.

In forward flight or wind the wake skews back by χ (tan χ = V_a / v_i, Glauert); every length
is along the skewed axis, so at depth z the axial distance is z / cos χ (the lengths in depth
are the axial lengths × cos χ).

**In forward flight** the wake also rolls up as a lifting wing's into a trailing vortex pair
(:func:`vortex_pair`, :func:`vortex_landing`), which takes the share :func:`wing_share` of the
wake, a smooth blend by V_a / (2 v_h): the hover jet at V_a = 0, all of it from V_a = 2 v_h on
(where ground effect is negligible, Leishman §5).

The compiled :func:`centreline_speed` and :func:`fall_time` are the laws the deposition kernels
use (:mod:`ag_uav.world.deposition_kernels`); :class:`MultirotorWake` is the same law from a
vehicle's mass and geometry (mass, rotor count, rotor diameter, arm), for tests and reports.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from .._jit import njit

#: the round jet's centreline decay constant (Pope 2000, table 5.1: 5.8-6.1 over the cited
#: experiments; 6.11 at Re 19,400, Abdel-Rahman et al. 1996, Mech. Res. Commun. 23(3):313)
JET_B = 6.0
#: merged jet beyond this many vehicle length scales (Bauersfeld et al. 2024)
MERGE_LENGTHS = 2.5


@njit(cache=True, inline="always")
def centreline_speed(a: float, s_r: float, s_m: float, bd0: float, s: float) -> float:
    """Wake speed at axial distance ``s`` below the rotors: ``a`` (= 2 v_i) in the rotors'
    cores (s < s_r), a s_r / s in their own decay (s_r ≤ s < s_m), the merged jet
    a·bd0 / (s − s_v) beyond s_m (bd0 = B D_0 of the merged jet, s_v from continuity); never
    above ``a``."""
    if s < s_m:
        return a if s < s_r else a * s_r / s
    un = a if s_m <= s_r else a * s_r / s_m  # s_m = s_r = 0: no wake (motors off)
    sv = s_m - a * bd0 / max(un, 1e-12)
    return min(a, a * bd0 / max(s - sv, 1e-12))


@njit(cache=True, inline="always")
def _decay_time(vt: float, c: float, s1: float, s2: float) -> float:
    """Time to fall from s1 to s2 (> s1 > 0) at ds/dt = vt + c / s, in closed form (c = 0,
    no wake: (s2 - s1) / vt)."""
    if c <= 0.0:
        return (s2 - s1) / vt
    return ((s2 - s1) - c / vt * math.log1p(vt * (s2 - s1) / (vt * s1 + c))) / vt


@njit(cache=True, inline="always")
def fall_time(vt: float, a: float, s_r: float, s_m: float, bd0: float, s1: float,
              s2: float) -> float:
    """Time for a droplet of terminal velocity ``vt`` to fall from depth s1 to s2 through the
    wake of :func:`centreline_speed` (ds/dt = vt + u(s)), segment by segment in closed form."""
    t = 0.0
    core = min(s_r, s_m)
    if s1 < core:                                   # the cores: u = a
        e = min(s2, core)
        t += (e - s1) / (vt + a)
        s1 = e
    if s1 < s_m and s2 > s1:                        # the rotors' own decay: u = a s_r / s
        e = min(s2, s_m)
        t += _decay_time(vt, a * s_r, s1, e)
        s1 = e
    if s2 > s1:                                     # the merged jet: u = a bd0 / (s − s_v)
        un = a if s_m <= s_r else a * s_r / s_m  # s_m = s_r = 0: no wake (motors off)
        sv = s_m - a * bd0 / max(un, 1e-12)
        # below s_m the speed is a bd0/(s − s_v) ≤ a, exactly (continuity at s_m)
        t += _decay_time(vt, a * bd0, s1 - sv, s2 - sv)
    return t


@dataclass(frozen=True)
class MultirotorWake:
    """A vehicle's downwash from its mass and geometry (laws in the module docstring)."""

    mass_kg: float
    n_rotors: int = 4
    rotor_d_m: float = 0.533
    arm_m: float = 0.4475               # rotor hub from the centre (M350 class: 895 mm wheelbase)
    rho: float = 1.225
    b: float = JET_B
    merge_lengths: float = MERGE_LENGTHS

    @property
    def disc_area(self) -> float:
        return self.n_rotors * math.pi * self.rotor_d_m ** 2 / 4.0

    @property
    def d_eq(self) -> float:
        """The diameter of one disc of the total disc area: √n D."""
        return math.sqrt(self.n_rotors) * self.rotor_d_m

    def v_induced(self, thrust: float | None = None, airspeed: float = 0.0) -> float:
        """Induced velocity v_i: v_h = sqrt(T/(2ρA)), and in edgewise flow (Glauert)
        v_i⁴ + V_a² v_i² = v_h⁴."""
        t = self.mass_kg * 9.81 if thrust is None else thrust
        vh2 = t / (2.0 * self.rho * self.disc_area)
        va2 = airspeed * airspeed
        return math.sqrt(0.5 * (-va2 + math.sqrt(va2 * va2 + 4.0 * vh2 * vh2)))

    def lengths(self) -> tuple[float, float, float]:
        """Axial lengths (s_r, s_m, B D_0): a rotor jet's core, the merge depth 2.5 l, and
        the merged jet's B D_0 = B √n D / √2."""
        s_r = self.b * self.rotor_d_m / math.sqrt(2.0)
        s_m = self.merge_lengths * 2.0 * self.arm_m
        return s_r, s_m, self.b * self.d_eq / math.sqrt(2.0)

    def centreline(self, depth: float, airspeed: float = 0.0) -> float:
        """The wake's speed along its axis at ``depth`` below the rotors (m/s), skewed by the
        airspeed (lengths × cos χ, tan χ = V_a / v_i)."""
        vi = self.v_induced(None, airspeed)
        c = vi / math.hypot(vi, airspeed)
        s_r, s_m, bd0 = self.lengths()
        return centreline_speed(2.0 * vi, s_r * c, s_m * c, bd0 * c, depth)


# ------------------------------------------------------------------ the wake in forward flight
#: the wake is wing-like (swept clear of the ground) from V_a = this × v_h on: "ground effect is
#: usually considered negligible for V > 2 v_h" (Leishman, *Principles of Helicopter
#: Aerodynamics* §5, after Curtiss et al. 1984)
WING_SPEED_VH = 2.0


@njit(cache=True, inline="always")
def wing_share(va: float, vh: float, end: float = WING_SPEED_VH) -> float:
    """Share of the wake in the wing-like regime, a smooth blend of the advance ratio
    normalised by the hover induced velocity: x = V_a / (``end`` v_h) clipped to [0, 1],
    f = 3x² − 2x³ (0 in hover, where the merged jet impinges; 1 from V_a = 2 v_h on, where the
    wake is swept clear of the ground and rolls up as a wing's)."""
    if vh <= 0.0:
        return 1.0 if va > 0.0 else 0.0
    x = min(va / (end * vh), 1.0)
    return x * x * (3.0 - 2.0 * x)


@njit(cache=True, inline="always")
def vortex_pair(thrust: float, rho: float, va: float, b0: float, z_r: float
                ) -> tuple[float, float, float, float, float]:
    """The trailing vortex pair of a lifting system of weight ``thrust`` at airspeed ``va``
    (Prandtl's lifting line; the rotor in forward flight as a wing: Leishman §2.14, §10):
    separation b₀ = (π/4) b (elliptic loading; ``b0`` is passed in), circulation
    Γ = T / (ρ V_a b₀), the pair's descent w₀ = Γ / (2π b₀), its time scale t* = b₀ / w₀.
    Near the ground the image vortices turn the descent outward: with the pair's half
    separation y and height z, 1/y² + 1/z² = 1/c² (Lamb 1932, *Hydrodynamics* §155, the pair
    and its images; inviscid), c = (4/b₀² + 1/z_r²)^(−1/2) from the start (b₀/2, z_r); the
    vortices end at height c running apart at U = Γ / (4π c). Returns (Γ, w₀, c, U, t*);
    zeros where there is no airspeed or lift."""
    if va <= 1e-6 or thrust <= 0.0 or b0 <= 0.0 or z_r <= 0.0:
        return 0.0, 0.0, 0.0, 0.0, 0.0
    gam = thrust / (rho * va * b0)
    w0 = gam / (2.0 * math.pi * b0)
    c = 1.0 / math.sqrt(4.0 / (b0 * b0) + 1.0 / (z_r * z_r))
    return gam, w0, c, gam / (4.0 * math.pi * c), b0 / w0


@njit(cache=True, inline="always")
def vortex_landing(vt: float, b0: float, z_n: float, w0: float, c: float, u: float,
                   t_life: float) -> tuple[float, float]:
    """A droplet of terminal velocity ``vt`` released at height ``z_n`` into the pair of
    :func:`vortex_pair`: it descends with the pair to its ground-effect height c in
    t_d = (z_n − c) / (w₀ + v_t), then rides a vortex outward at U while it settles out of the
    pair's layer (height h = min(z_n, c), the droplets even in height) at v_t, so it lands
    after s ~ U[0, h / v_t], having run U min(s, t_l), t_l = t_life − t_d the pair's time left.
    Each side it lands on [b₀/2, b₀/2 + U t_l] (a share p = v_t t_l / h, evenly) or at its end
    (the rest). Returns (mean landing time t_d + h / (2 v_t), lateral variance
    p (a² + a L + L²/3) + (1 − p)(a + L)², a = b₀/2, L = U min(t_l, h / v_t))."""
    a = 0.5 * b0
    t_d = max(z_n - c, 0.0) / (w0 + vt)
    h = min(z_n, c)
    s_max = h / vt
    t_l = max(min(s_max, t_life - t_d), 0.0)
    run = u * t_l
    p = t_l / s_max if s_max > 0.0 else 1.0
    var = p * (a * a + a * run + run * run / 3.0) + (1.0 - p) * (a + run) ** 2
    return t_d + 0.5 * s_max, var

