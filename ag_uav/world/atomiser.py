"""The rotary atomiser: the droplet size its disc speed sets, and how far it throws a droplet.

**Droplet size.** A spinning disc (or cage) fed at low flow sheds drops directly from its rim;
their diameter follows the balance of centrifugal force and surface tension (Walton & Prewett
1949, "The production of sprays and mists of uniform drop size by means of spinning disc type
sprayers", Proc. Phys. Soc. B 62:341):

    d = K / ω · sqrt(σ / (ρ_l D)),  K = 3.8, D = 2R the disc diameter

(ω in rad/s; equivalently K / √2 ≈ 2.69 with the radius R). The spectrum's volume median
diameter (VMD, Dv50) is taken as this d; Dv10 and Dv90 scale with it, so the configured
spectrum's relative span (Dv90 − Dv10) / Dv50 is kept (:func:`rotary_spectrum`): the
size follows 1/ω.

**The throw.** A droplet leaves the rim radially at about the tip speed v₀ = ωR and is slowed by
drag while the rotor downwash (vertical air speed w_a) carries it down. With the droplet's
horizontal and vertical (down) speeds u, w and the air's (0, w_a), the relative velocity
u_r = (u, w − w_a) gives

    du/dt = −k u,  dw/dt = g − k (w − w_a),  k = 3 ρ_a C_D |u_r| / (4 ρ_l d),

C_D the Schiller–Naumann sphere drag 24/Re (1 + 0.15 Re^0.687) (0.44 above Re = 1000; Schiller &
Naumann 1933; Clift, Grace & Weber 1978, *Bubbles, Drops and Particles*, table 5.2). Integrated
(RK4, steps of 2 % of the current relaxation time 1/k) until u falls to 10⁻⁴ v₀, the Stokes tail
u τ_p (τ_p = ρ_l d² / 18 μ) added, the horizontal distance is the throw radius r_t(d) (the
air has no horizontal speed relative to the vehicle there). In the Stokes limit (Re ≪ 1)
r_t = v₀ τ_p. The release of a class is then a ring of radius r_t around the atomiser: on each
horizontal axis its variance r_t² / 2 adds to the class's release variance (hydraulic nozzles:
no throw). The integration runs once per class when the parameters are packed, not per tick;
the ground is not in it (the depth a droplet has fallen when its throw ends is returned, to
check against the spray height)."""

from __future__ import annotations

import math

import numpy as np

from .._jit import njit

#: Walton & Prewett's constant for the disc diameter D: d ω sqrt(ρ_l D / σ) = 3.8
WALTON_PREWETT_K = 3.8
#: gravity (m/s²)
G = 9.81
#: the throw ends when the horizontal speed falls to this share of the tip speed
STOP_SHARE = 1e-4
#: RK4 step as a share of the current relaxation time
STEP_SHARE = 0.02


def disc_vmd_m(rpm: float, radius_m: float, surface_tension_n_m: float = 0.072,
               liquid_density: float = 1000.0) -> float:
    """The direct-droplet diameter (m) of a disc of radius ``radius_m`` spinning at ``rpm``:
    d = K / ω · sqrt(σ / (ρ_l · 2R)), K = 3.8 (Walton & Prewett 1949)."""
    if rpm <= 0.0 or radius_m <= 0.0:
        raise ValueError(f"atomiser: rpm = {rpm:g} and radius = {radius_m:g} m must be > 0")
    omega = rpm * 2.0 * math.pi / 60.0
    return WALTON_PREWETT_K / omega * math.sqrt(surface_tension_n_m
                                                / (liquid_density * 2.0 * radius_m))


def rotary_spectrum(dv10_um: float, dv50_um: float, dv90_um: float, vmd_um: float
                    ) -> tuple[float, float, float]:
    """(Dv10, Dv50, Dv90) in µm with Dv50 = ``vmd_um`` and Dv10, Dv90 scaled by the same factor
    vmd / Dv50 (the relative span (Dv90 − Dv10) / Dv50 of the given spectrum kept)."""
    s = vmd_um / dv50_um
    return dv10_um * s, vmd_um, dv90_um * s


def tip_speed_mps(rpm: float, radius_m: float) -> float:
    """The disc's rim speed ω R (m/s)."""
    return rpm * 2.0 * math.pi / 60.0 * radius_m


@njit(cache=True, inline="always")
def _drag_k(d: float, ur: float, wr: float, rho_l: float, rho_a: float, mu: float) -> float:
    """k = 3 ρ_a C_D |u_r| / (4 ρ_l d) (1/s) with the Schiller–Naumann C_D (Stokes at Re → 0:
    18 μ / (ρ_l d²))."""
    sp = math.sqrt(ur * ur + wr * wr)
    re = rho_a * sp * d / mu
    corr = 1.0 + 0.15 * re ** 0.687 if re <= 1000.0 else 0.44 * re / 24.0
    return 18.0 * mu / (rho_l * d * d) * corr


@njit(cache=True)
def throw_radius(d: float, v0: float, w_air: float, rho_l: float, rho_a: float,
                 mu: float) -> tuple[float, float, float]:
    """(throw radius r_t m, time s, depth fallen m) of a droplet of diameter ``d`` leaving at
    ``v0`` horizontally (vertical speed 0) into air moving down at ``w_air`` (module docstring)."""
    if v0 <= 0.0:
        return 0.0, 0.0, 0.0
    x = z = t = 0.0
    u, w = v0, 0.0
    tau_s = rho_l * d * d / (18.0 * mu)
    for _ in range(200000):
        if u <= STOP_SHARE * v0:
            break
        h = STEP_SHARE / _drag_k(d, u, w - w_air, rho_l, rho_a, mu)
        k1 = _drag_k(d, u, w - w_air, rho_l, rho_a, mu)
        a1u, a1w = -k1 * u, G - k1 * (w - w_air)
        u2, w2 = u + 0.5 * h * a1u, w + 0.5 * h * a1w
        k2 = _drag_k(d, u2, w2 - w_air, rho_l, rho_a, mu)
        a2u, a2w = -k2 * u2, G - k2 * (w2 - w_air)
        u3, w3 = u + 0.5 * h * a2u, w + 0.5 * h * a2w
        k3 = _drag_k(d, u3, w3 - w_air, rho_l, rho_a, mu)
        a3u, a3w = -k3 * u3, G - k3 * (w3 - w_air)
        u4, w4 = u + h * a3u, w + h * a3w
        k4 = _drag_k(d, u4, w4 - w_air, rho_l, rho_a, mu)
        a4u, a4w = -k4 * u4, G - k4 * (w4 - w_air)
        x += h / 6.0 * (u + 2.0 * u2 + 2.0 * u3 + u4)
        z += h / 6.0 * (w + 2.0 * w2 + 2.0 * w3 + w4)
        u += h / 6.0 * (a1u + 2.0 * a2u + 2.0 * a3u + a4u)
        w += h / 6.0 * (a1w + 2.0 * a2w + 2.0 * a3w + a4w)
        t += h
    return x + u * tau_s, t, z


def throw_variances(d_m: np.ndarray, v0: float, w_air: float, rho_l: float = 1000.0,
                    rho_a: float = 1.225, mu: float = 1.81e-5) -> np.ndarray:
    """Per class of diameters ``d_m``: the ring's variance on each horizontal axis, r_t² / 2
    (zeros when ``v0`` = 0: no throw)."""
    out = np.zeros(len(d_m))
    if v0 <= 0.0:
        return out
    for i, d in enumerate(np.asarray(d_m, float)):
        r = throw_radius(float(d), float(v0), float(w_air), rho_l, rho_a, mu)[0]
        out[i] = 0.5 * r * r
    return out
