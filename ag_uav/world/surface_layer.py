"""The atmospheric surface layer the escaped droplets settle through: Monin–Obukhov similarity
for the wind profile and the vertical eddy diffusivity, neutral, stable or unstable.

With the Obukhov length L (``1/L`` = ``inv_l``; 0: neutral, > 0: stable, < 0: unstable) and
ζ = z/L, the mean wind is u(z) = (u*/κ) [ln(z/z₀) − ψ_m(ζ) + ψ_m(z₀/L)] and the eddy
diffusivity of a scalar K = κ u* z / φ_h(ζ), with the Businger–Dyer forms (Dyer 1974,
Boundary-Layer Meteorol. 7:363; ψ_m of the unstable profile integrated by Paulson 1970,
J. Appl. Meteor. 9:857):

    stable:    φ_h = 1 + 5ζ,             ψ_m = −5ζ
    unstable:  φ_h = (1 − 16ζ)^(−1/2),   ψ_m = 2 ln((1+x)/2) + ln((1+x²)/2) − 2 atan x + π/2,
               x = (1 − 16ζ)^(1/4)

u* follows from the wind at the vehicle's height; the escaped part is advected by the mean of
u(z) over the layer below the nozzle (closed form when neutral or stable, 6-point Gauss-Legendre
when unstable) and diffuses with K taken at half the nozzle height, as in the neutral law the
deposition kernels used before (K = κ u* h / 2). The stability classes of the drift trial are
given by 1/L (:data:`STABILITY`).
"""

from __future__ import annotations

import math

from .._jit import njit

KAPPA = 0.41
#: 1/L (m⁻¹) of the drift trial's stability classes: about Pasquill's F and B over a 5-10 cm
#: roughness (Golder 1972, Boundary-Layer Meteorol. 3:47, nomogram; an assumption: one value
#: per class)
STABILITY = {"stable": 1.0 / 20.0, "neutral": 0.0, "unstable": -1.0 / 20.0}
#: Gauss-Legendre nodes and weights on [-1, 1], 6 points
GL6_X = (-0.9324695142031521, -0.6612093864662645, -0.2386191860831909,
         0.2386191860831909, 0.6612093864662645, 0.9324695142031521)
GL6_W = (0.1713244923791704, 0.3607615730481386, 0.4679139345726910,
         0.4679139345726910, 0.3607615730481386, 0.1713244923791704)


@njit(cache=True, inline="always")
def psi_m(zeta: float) -> float:
    """Businger–Dyer integrated stability function of momentum."""
    if zeta >= 0.0:
        return -5.0 * zeta
    x = (1.0 - 16.0 * zeta) ** 0.25
    return (2.0 * math.log(0.5 * (1.0 + x)) + math.log(0.5 * (1.0 + x * x))
            - 2.0 * math.atan(x) + 0.5 * math.pi)


@njit(cache=True, inline="always")
def phi_h(zeta: float) -> float:
    """Businger–Dyer dimensionless gradient of a scalar (the eddy diffusivity's divisor)."""
    if zeta >= 0.0:
        return 1.0 + 5.0 * zeta
    return (1.0 - 16.0 * zeta) ** -0.5


@njit(cache=True)
def layer_wind(w: float, pz: float, zn: float, z0: float, inv_l: float) -> tuple[float, float]:
    """(u*, f_u): the friction velocity from the wind ``w`` at height ``pz`` and the mean wind
    over [z₀, zn] as a share of ``w``; (0, 0) below the roughness. Neutral: exactly the log-law
    expressions (ln and its closed-form mean)."""
    if pz <= 1.01 * z0:
        return 0.0, 0.0
    p0 = psi_m(z0 * inv_l)
    lnv = math.log(pz / z0) if inv_l == 0.0 else math.log(pz / z0) - psi_m(pz * inv_l) + p0
    ust = KAPPA * w / lnv
    if zn <= z0:
        return ust, 0.0
    mean_ln = (zn * math.log(zn / z0) - zn + z0) / (zn - z0)
    if inv_l == 0.0:
        return ust, mean_ln / lnv
    if inv_l > 0.0:                                   # −ψ_m = 5ζ: its mean in closed form
        mean_psi = -2.5 * (zn + z0) * inv_l
    else:
        mean_psi = 0.0
        for i in range(6):
            z = z0 + 0.5 * (zn - z0) * (GL6_X[i] + 1.0)
            mean_psi += 0.5 * GL6_W[i] * psi_m(z * inv_l)
    return ust, (mean_ln - mean_psi + p0) / lnv


@njit(cache=True, inline="always")
def eddy_k(ust: float, h: float, inv_l: float) -> float:
    """K = κ u* (h/2) / φ_h((h/2)/L): the vertical eddy diffusivity at half the height ``h``."""
    if inv_l == 0.0:
        return KAPPA * ust * 0.5 * h
    return KAPPA * ust * 0.5 * h / phi_h(0.5 * h * inv_l)

