"""The receiver as the navigation sees it: the GNSS sensor a run's config builds, the
pre-flight check an autopilot makes with it, its latency, and the variance of its fixes as the
INS fuses them (white and Gauss–Markov parts, the colour of the latter over the filter's
window)."""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from numkit import X, Y, Z

from ..config import Config, ConfigError
from ..vehicle.gps import GpsSensor


def preflight_gnss(cfg: Config) -> str | None:
    """The pre-flight check an autopilot makes before it arms: no take-off without a GNSS fix
    (PX4's ``COM_ARM_WO_GPS`` default, ArduPilot's GPS arming check).  A run that flies on an
    estimate (``estimator.name`` other than ``"true"``, or bearings) whose receiver starts in
    an outage (``gps.overrides.outage.start_in_outage``) has no fix at take-off: the reason,
    in one line (None when the check passes)."""
    e = cfg.estimator
    if e.source == "gps" and e.name == "true":
        return None
    out = cfg.gps.overrides.get("outage") or {}
    if isinstance(out, dict) and out.get("start_in_outage") is True:
        return ("pre-flight check: no GNSS fix at take-off (gps.overrides.outage."
                "start_in_outage = true): not armed, the vehicle stays on the ground")
    return None


def gnss_latency_s(cfg: Config) -> float:
    """The receiver latency the INS chain applies (s): ``gps.overrides.latency_s`` where it is
    given (the sensor's own key, which the ideal-attitude chain's sensor reads), else
    ``gps.latency_s``."""
    v = cfg.gps.overrides.get("latency_s", cfg.gps.latency_s)
    if isinstance(v, bool) or not isinstance(v, int | float) or not 0.0 <= v <= 1.0:
        raise ConfigError(f"gps.overrides.latency_s = {v!r}: must be a number in [0, 1] s")
    return float(v)


def make_gps(cfg: Config, seed: np.random.SeedSequence) -> GpsSensor:
    g = cfg.gps
    ov: dict[str, Any] = dict(g.overrides)
    if g.rate_hz > 0:
        ov["rate_hz"] = g.rate_hz
    if g.multipath_prob > 0:
        comps = dict(ov.get("components", {})) if isinstance(ov.get("components"), dict) else {}
        comps["multipath_extra"] = {"type": "spikes", "prob": g.multipath_prob,
                                    "amplitude": g.multipath_amplitude_m}
        if isinstance(ov.get("components"), list):
            raise ConfigError("gps.multipath_prob: cannot be combined with a components list in "
                              "gps.overrides; add the spikes to that list")
        ov["components"] = comps
    try:
        return GpsSensor.from_preset(g.preset, seed, **ov)
    except ValueError as e:
        raise ConfigError(f"gps.overrides = {ov!r}: {e}") from None


def colour_factor(rho: float, n: int) -> float:
    """``n f(n, ρ) = 1 + 2 Σ_{j=1}^{n−1} (1 − j/n) ρ^j``: the variance of the mean of ``n``
    successive samples of a Gauss–Markov sequence with correlation ``ρ`` per sample, over the
    σ²/n the same samples would have if white. A filter that averages about ``n`` fixes sees
    the coloured part of the fix error ``n f`` times larger than white fusion assumes (→
    (1+ρ)/(1−ρ) for n → ∞; 1 for n = 1). Inflating that part of R by it keeps the averaged
    position's variance honest (Bar-Shalom, Li & Kirubarajan 2001, *Estimation with
    Applications to Tracking and Navigation*, §8.1: coloured measurement noise)."""
    if n <= 1 or rho <= 0.0:
        return 1.0
    j = np.arange(1, n)
    return float(1.0 + 2.0 * np.sum((1.0 - j / n) * rho**j))


def fix_variance(gps: Any, mode: str | None, n: int) -> tuple[np.ndarray, np.ndarray]:
    """Per-axis variance of a fix of the receiver's error chain (the base components, plus
    fix type ``mode``'s own) as (its white part, its Gauss–Markov / AR(1) part times
    :func:`colour_factor` at the fix interval and the filter's window of ``n`` fixes); NaN
    (no variance) reads 1 m²."""
    dt = 1.0 / gps.rate_hz
    comps = list(gps.components)
    if mode is not None:
        comps += list(gps.mode_components[gps.fix_types.index(mode)])
    v = np.zeros((2, 3))
    for _name, procs, scale in comps:
        for ax in range(3):
            if not scale[ax]:
                continue
            p = procs[ax]
            var = float(p.variance)
            if not math.isfinite(var):
                var = 1.0
            if hasattr(p, "rho_at"):
                rho = p.rho_at(dt)
            elif getattr(p, "tau_s", None):
                rho = math.exp(-dt / p.tau_s)
            else:
                v[0, ax] += scale[ax] ** 2 * var
                continue
            v[1, ax] += scale[ax] ** 2 * var * colour_factor(rho, n)
    v *= np.asarray(gps.axis_scale, dtype=float) ** 2
    return v[0], v[1]


#: the least variance (m², (1 cm)²) of a fix's whole reported variance (as EKF2 floors hAcc)
R_FLOOR = 1e-4
#: the least variance (m², (5 mm)²) a "consider" fix is fused with: a receiver whose error is
#: all Gauss–Markov leaves no white part, and R = 0 would make the position block singular
R_WHITE_FLOOR = 2.5e-5


def reported_acc(var: tuple[float, float, float] | list[float], s2: float) -> list[float]:
    """The per-axis variance (east, north, up; m²) of a receiver's report ``(hAcc, vAcc)``:
    hAcc² = s² (σ_x² + σ_y²)/2 on both horizontal axes and vAcc² = s² σ_z², ``var`` the fix
    type's per-axis variance and ``s`` the receiver's calibration error
    (:class:`~ag_uav.vehicle.gps.ReceiverReport`): one horizontal and one vertical figure, as
    u-blox UBX-NAV-PVT ``hAcc``/``vAcc`` and NMEA GST give, and as PX4's EKF2 uses ``eph``
    for both horizontal axes."""
    h = 0.5 * (var[X] + var[Y]) * s2
    return [h, h, var[Z] * s2]


def reported_r(acc: list[float], colour: str, share: float, inflate: float,
               r_scale: float) -> tuple[list[float], list[float]]:
    """(R, considered variance) per axis from the receiver's reported variance ``acc``
    (:func:`reported_acc`), not from the error generator's components:
    ``V = max(r_scale · acc, R_FLOOR)``; the share ``g`` of ``V`` the configured model takes
    as Gauss–Markov (``estimator.ins_gnss_gm_share``): "white" R = V; "inflate"
    R = (1 − g) V + g V · ``inflate`` (:func:`colour_factor` at the model's τ over the
    filter's window); "consider" R = max(V − g V, R_WHITE_FLOOR), g V considered
    (Schmidt's consider covariance without its cross terms; Bar-Shalom, Li & Kirubarajan
    2001, §8.1 for the coloured part)."""
    v = [max(r_scale * a, R_FLOOR) for a in acc]
    if colour == "white":
        return v, [0.0, 0.0, 0.0]
    if colour == "inflate":
        return [x * (1.0 - share) + x * share * inflate for x in v], [0.0, 0.0, 0.0]
    cv = [share * x for x in v]
    return [max(x - c, R_WHITE_FLOOR) for x, c in zip(v, cv, strict=True)], cv


def truth_r(gps: Any, mode: str | None, colour: str, n_window: int,
            r_scale: float) -> tuple[np.ndarray, np.ndarray]:
    """(R, considered variance) per axis of a fix of type ``mode`` (None: the preset's
    nominal) read from the error generator's own components (``estimator.ins_r_source =
    "truth"``: a filter that knows the noise): "white" R = the whole variance; "inflate" its
    Gauss–Markov part times :func:`colour_factor` over the window of ``n_window`` fixes;
    "consider" R = the floored whole less the Gauss–Markov part, which is considered."""
    white, gm = fix_variance(gps, mode, 1)
    if colour == "white":
        return np.maximum(r_scale * (white + gm), R_FLOOR), np.zeros(3)
    if colour == "inflate":
        wi, gi = fix_variance(gps, mode, n_window)
        return np.maximum(r_scale * (wi + gi), R_FLOOR), np.zeros(3)
    # the floor applies to the whole variance (as EKF2's to hAcc); the considered part comes
    # off after it, and what is fused keeps R_WHITE_FLOOR
    tot = np.maximum(r_scale * (white + gm), R_FLOOR)
    return np.maximum(tot - r_scale * gm, R_WHITE_FLOOR), r_scale * gm
