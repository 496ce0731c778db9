"""Drift past a buffer with an error bar: one pass's deposit profile across the wind, evaluated
analytically (no grid), and the low and high bounds from the inputs a real application does not
know.

**The profile** (:func:`pass_profile`): the vehicle flies a steady level pass
(:func:`ag_uav.world.pattern.pass_states`), every droplet class's landing law is the loop's
(:func:`ag_uav.world.deposition.footprints`, the same compiled function); per class the part
the wake carries down lands as a Gaussian, the part that escapes at the wake's edge as the
inverse-Gaussian first passage of a settling droplet through the turbulent surface layer
(``scipy.stats.invgauss``) blurred by the edge ring, so the tail runs on to any distance.
:func:`strip_tail` is the share of a strip of passes that lands (or stays aloft) beyond a
distance past its downwind edge.

**The bounds.** Three inputs are not known for a real application:

- the share of the sheet at the wake's edge, ε₀ (``wake_escape``, assumed 0.3): halved and
  doubled (the range the docs show the far field to scale with; on the wind-tunnel trial's 2 L
  rows 0.3-0.6 fit alike);
- the surface layer's stability (Monin–Obukhov, :mod:`ag_uav.world.surface_layer`): stable
  (1/L = +1/20 m⁻¹), neutral, unstable (−1/20 m⁻¹); a stable layer diffuses the escaped fines
  less (K / φ_h), so fewer land early and more far out;
- the meander of the wind's direction over the application, σθ: with the wind at θ off the
  normal to the strip's edge, the deposit at a distance d from the edge is the profile at
  d / cos θ divided by cos θ (the same line source seen obliquely), averaged over θ ~ N(0, σθ)
  (9-point Gauss-Hermite, |θ| < 80°); it lowers the deposit at a fixed distance.

The central case is ε₀ = 0.3, neutral, a steady direction across the strip. The bounds take
each input at the end that lowers / raises the far deposit: **low** = ε₀/2, unstable,
σθ = 20°; **high** = 2ε₀, stable, a steady direction. They are corners of the inputs' ranges,
not a statistical interval. A flight's summary scales its own drift past the buffer by the
strip's low / central and high / central ratios (:func:`drift_ratios`).
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np

from .deposition import DepositionConfig, footprints, pack_input
from .pattern import pass_states
from .surface_layer import STABILITY

__all__ = ["BOUNDS", "DY", "FAR", "bound_config", "drift_ratios", "meander", "pass_profile",
           "strip_tail"]

DY = 0.02              # m, the grid the single-pass profile is evaluated on
FAR = 400.0            # m, the furthest distance the profile (and the buffers) are evaluated to


def _ig_pdf(t: np.ndarray, mu: float, lam: float) -> np.ndarray:
    """Inverse-Gaussian density IG(μ, λ): f(t) = √(λ / (2π t³)) exp(−λ (t − μ)² / (2 μ² t)),
    t > 0 (Chhikara & Folks 1989; scipy.stats.invgauss with shape μ/λ and scale λ, written out
    so that a flight's summary does not import scipy.stats)."""
    out = np.zeros_like(t)
    pos = t > 0
    tp = t[pos]
    out[pos] = np.sqrt(lam / (2.0 * math.pi * tp ** 3)) * np.exp(
        -lam * (tp - mu) ** 2 / (2.0 * mu * mu * tp))
    return out


def pass_profile(cfg: DepositionConfig, wind: float, height: float, speed: float,
                 mass_kg: float = 6.47, drag_lin: float = 0.25, drag_quad: float = 0.18
                 ) -> tuple[np.ndarray, np.ndarray, dict]:
    """Tracer deposit density across one pass in a crosswind ``wind`` (1/m; integrates to the
    landed share): y grid, density, and the volume book of the pass (shares of the sprayed
    volume)."""
    R, thrust = pass_states(speed, height, wind, mass_kg, drag_lin, drag_quad)
    inp = pack_input([0.0, 0.0, height], [speed, 0.0, 0.0], R, thrust, [0.0, wind, 0.0], 1)
    fp = footprints(cfg, inp)
    noz = np.asarray(cfg.nozzle_xyz_m, float).reshape(-1, 3)
    ym = noz @ R.reshape(3, 3)[1]                    # nozzle y in the world frame
    share = np.asarray(cfg.nozzle_share, float)
    y = np.arange(-30.0, FAR + 30.0, DY)
    dens = np.zeros_like(y)
    edge2 = np.max(np.hypot(noz[:, 0], noz[:, 1])) + 0.5 * cfg.rotor_diameter_m
    for k in range(len(fp["frac"])):
        f = fp["frac"][k]
        # the escaped part's release spread: the sheet, a rotary atomiser's throw, the edge ring
        s_e = math.sqrt(cfg.release_sigma_m ** 2 + fp["throw"][k] + 0.5 * edge2 ** 2)
        kern_y = np.arange(-5 * s_e, 5 * s_e + DY, DY)
        kern = np.exp(-0.5 * (kern_y / s_e) ** 2)
        kern /= kern.sum()
        sw = math.sqrt(fp["wvar"][k])
        esc = np.zeros_like(y)
        uy = fp["uy"][k]
        if fp["esc"][k] > 0 and uy > 1e-9:
            y0 = fp["ey"][k] - uy * fp["mut"][k]     # where the escaped part starts to settle
            esc = _ig_pdf((y - y0) / uy, fp["mut"][k], fp["lamt"][k]) / uy
            esc = np.convolve(esc, kern, mode="same")
        elif fp["esc"][k] > 0:
            esc = np.exp(-0.5 * ((y - fp["ey"][k]) / s_e) ** 2) / (s_e * math.sqrt(2 * math.pi))
        for m in range(len(ym)):
            g = np.exp(-0.5 * ((y - ym[m] - fp["wy"][k]) / sw) ** 2) / (sw * math.sqrt(2 * math.pi))
            e = np.interp(y - ym[m], y, esc, left=0.0, right=0.0)
            dens += share[m] * f * (fp["wake"][k] * g + fp["esc"][k] * e)
            if fp["vort"][k] > 0.0:                  # the trailing vortex pair's part
                sv = math.sqrt(fp["vvy"][k])
                dens += (share[m] * f * fp["vort"][k] / (sv * math.sqrt(2 * math.pi))
                         * np.exp(-0.5 * ((y - ym[m] - fp["vy"][k]) / sv) ** 2))
    book = {"evaporated": float(np.sum(fp["frac"] * (
        fp["wake"] * (1 - fp["wland"]) + fp["vort"] * (1 - fp["vland"])
        + fp["esc"] * ((1 - fp["pair"]) * (1 - fp["rland"]) + fp["pair"] * (1 - fp["rair"]))))),
            "airborne": float(np.sum(fp["frac"] * fp["esc"] * fp["pair"] * fp["rair"])),
            "escaped": float(np.sum(fp["frac"] * fp["esc"]))}
    return y, dens, book


#: the bounds' inputs: (ε₀ factor, stability class, σθ in degrees)
BOUNDS = {"low": (0.5, "unstable", 20.0), "high": (2.0, "stable", 0.0)}


def meander(x: np.ndarray, dep: np.ndarray, sigma_deg: float) -> np.ndarray:
    """The deposit ``dep`` at the distances ``x`` from a strip's edge averaged over wind
    directions θ ~ N(0, σθ) off the edge's normal: E[dep(x / cos θ) / cos θ]."""
    if sigma_deg <= 0.0:
        return dep.copy()
    z, w = np.polynomial.hermite_e.hermegauss(9)
    w = w / w.sum()
    out = np.zeros_like(dep)
    for zi, wi in zip(z, w, strict=True):
        th = min(abs(zi * math.radians(sigma_deg)), math.radians(80.0))
        c = math.cos(th)
        out += wi * np.interp(x / c, x, dep, left=dep[0], right=0.0) / c
    return out


def bound_config(base: DepositionConfig, which: str) -> tuple[DepositionConfig, float]:
    """The deposition config and σθ (degrees) of the ``"low"`` or ``"high"`` bound."""
    f, stab, sig = BOUNDS[which]
    return (dataclasses.replace(base, wake_escape=min(1.0, base.wake_escape * f),
                                obukhov_inv_m=STABILITY[stab]), sig)



def strip_tail(y: np.ndarray, dens: np.ndarray, airborne: float, lane: float, passes: int,
               beyond_m: float, sigma_deg: float = 0.0) -> float:
    """The share of what a strip of ``passes`` passes at −(j + ½)·``lane`` sprays that lands
    beyond ``beyond_m`` past its downwind edge, plus what stays aloft (``airborne``), with the
    wind's direction meandering σθ = ``sigma_deg`` (:func:`meander`)."""
    x = np.arange(0.0, FAR + 1e-9, 0.5)
    dep = np.zeros_like(x)
    for j in range(passes):
        dep += np.interp(x + (j + 0.5) * lane, y, dens, left=0.0, right=0.0)
    dep = meander(x, dep, sigma_deg) / passes
    far = x >= beyond_m
    return float(np.trapezoid(dep[far], x[far])) + airborne


def drift_ratios(cfg: DepositionConfig, wind: float, height: float, speed: float, lane: float,
                 mass_kg: float, buffer_m: float, passes: int = 10) -> dict[str, float]:
    """The low / central and high / central ratios of a strip's drift past ``buffer_m``
    (:func:`strip_tail` of :func:`pass_profile` at the central case and at each bound)."""
    out = {}
    for which, (c, sig) in {"central": (cfg, 0.0), **{k: bound_config(cfg, k)
                                                        for k in BOUNDS}}.items():
        y, dens, book = pass_profile(c, wind, height, speed, mass_kg)
        out[which] = strip_tail(y, dens, book["airborne"], lane, passes, buffer_m, sig)
    ref = out["central"]
    return {k: (out[k] / ref if ref > 0 else 1.0) for k in BOUNDS}
