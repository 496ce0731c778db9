"""GPS presets (illustrative engineering values, and the sourced ``rtk-m350``) and merging
a preset with a config's overrides."""

from __future__ import annotations

import copy
import math
from collections.abc import Mapping
from typing import Any

from .checks import bad
from .episodes import FIXQ_KEYS

_PAPER_SCALE = [math.sqrt(10.0), 10.0, math.sqrt(10.0)]

# Reasoning behind the numbers (illustrative, not datasheet figures):
# * rtk: cm-level; a small slowly wandering residual plus white noise, ~1 cm horizontal std,
#   vertical 2x (vertical dilution of precision), 20 Hz (RTK receivers output up to 20 Hz).
# * sbas: ~0.6 m horizontal std dominated by a 2-minute Gauss-Markov bias, 0.2 m white, z 1.7x.
# * standalone: ~1.4 m horizontal std, slow bias (tau = 120 s, within "30 s to minutes") plus
#   0.35 m white, z 1.7x, 10 Hz (typical consumer receiver rate).
# * paper-numerical: Candan & Li eqs 8-11: Ts = 0.05 s, R = diag(10, 100) m^2, white Gaussian.
#   The paper's experiment is 2-D; z is given the x variance.
# * distribution presets share paper-numerical's covariance (unit-variance components times
#   axis_scale) so that only the noise SHAPE differs; alpha-stable has no variance, its scale
#   1/sqrt(2) would give unit variance at alpha = 2.  Shape parameters: Student-t nu = 3; Weibull
#   k = 0.8 (heavier than Laplace); mixture eps = 0.1 with a 10x variance ratio as in Qin et al.
#   (0.9 N(0, 0.01) + 0.1 N(0, 0.1)), normalised to unit variance; alpha = 1.5; coloured:
#   Gaussian AR(1) with tau = 1 s (rho = 0.951 at 20 Hz); coloured-impulsive: AR(1) (variance
#   0.36) followed by 4 % spikes of amplitude 4 (variance 0.64), total unit variance.
_MIX_S1 = math.sqrt(1.0 / 1.9)
_PRESETS: dict[str, dict[str, Any]] = {
    "perfect": {
        "rate_hz": 20.0, "latency_s": 0.0, "axis_scale": [1.0, 1.0, 1.0],
        "components": [], "outage": {},
    },
    "rtk": {
        "rate_hz": 20.0, "latency_s": 0.0, "axis_scale": [1.0, 1.0, 2.0],
        "components": [
            {"type": "gauss-markov", "name": "bias", "sigma": 0.006, "tau_s": 30.0},
            {"type": "gaussian", "name": "white", "sigma": 0.008},
        ],
        "outage": {},
    },
    "sbas": {
        "rate_hz": 10.0, "latency_s": 0.0, "axis_scale": [1.0, 1.0, 1.7],
        "components": [
            {"type": "gauss-markov", "name": "bias", "sigma": 0.6, "tau_s": 120.0},
            {"type": "gaussian", "name": "white", "sigma": 0.2},
        ],
        "outage": {},
    },
    "standalone": {
        "rate_hz": 10.0, "latency_s": 0.0, "axis_scale": [1.0, 1.0, 1.7],
        "components": [
            {"type": "gauss-markov", "name": "bias", "sigma": 1.4, "tau_s": 120.0},
            {"type": "gaussian", "name": "white", "sigma": 0.35},
        ],
        "outage": {},
    },
    "paper-numerical": {
        "rate_hz": 20.0, "latency_s": 0.0, "axis_scale": list(_PAPER_SCALE),
        "components": [{"type": "gaussian", "name": "white", "sigma": 1.0}],
        "outage": {},
    },
    "student-t": {
        "rate_hz": 20.0, "latency_s": 0.0, "axis_scale": list(_PAPER_SCALE),
        "components": [{"type": "student-t", "name": "white", "sigma": 1.0, "nu": 3.0}],
        "outage": {},
    },
    "laplace": {
        "rate_hz": 20.0, "latency_s": 0.0, "axis_scale": list(_PAPER_SCALE),
        "components": [{"type": "laplace", "name": "white", "sigma": 1.0}],
        "outage": {},
    },
    "weibull": {
        "rate_hz": 20.0, "latency_s": 0.0, "axis_scale": list(_PAPER_SCALE),
        "components": [{"type": "weibull", "name": "white", "sigma": 1.0, "k": 0.8}],
        "outage": {},
    },
    "mixture": {
        "rate_hz": 20.0, "latency_s": 0.0, "axis_scale": list(_PAPER_SCALE),
        "components": [{"type": "mixture", "name": "white", "eps": 0.1,
                        "sigma1": _MIX_S1, "sigma2": math.sqrt(10.0) * _MIX_S1}],
        "outage": {},
    },
    "alpha-stable": {
        "rate_hz": 20.0, "latency_s": 0.0, "axis_scale": list(_PAPER_SCALE),
        "components": [{"type": "alpha-stable", "name": "white", "alpha": 1.5,
                        "scale": 1.0 / math.sqrt(2.0), "beta": 0.0}],
        "outage": {},
    },
    "coloured": {
        "rate_hz": 20.0, "latency_s": 0.0, "axis_scale": list(_PAPER_SCALE),
        "components": [{"type": "ar1", "name": "coloured", "tau_s": 1.0,
                        "driver": {"type": "gaussian", "sigma": 1.0}}],
        "outage": {},
    },
    "coloured-impulsive": {
        "rate_hz": 20.0, "latency_s": 0.0, "axis_scale": list(_PAPER_SCALE),
        "components": [
            {"type": "ar1", "name": "coloured", "tau_s": 1.0,
             "driver": {"type": "gaussian", "sigma": 0.6}},
            {"type": "spikes", "name": "spikes", "prob": 0.04, "amplitude": 4.0},
        ],
        "outage": {},
    },
}

# --- rtk-m350: a DJI Matrice 350 RTK-class receiver with fix-quality episodes -----------------
# Figures and where they come from ("judgement" marks an engineering judgement, not a datasheet):
# [DJI-M350]  DJI Matrice 350 RTK specifications (dji.com/matrice-350-rtk/specs), GNSS section:
#             "RTK positioning accuracy (RTK FIX): 1 cm + 1 ppm (horizontal), 1.5 cm + 1 ppm
#             (vertical)".  The same horizontal figure is in the D-RTK 2 High Precision GNSS
#             Mobile Station datasheet [D-RTK2], which lists "positioning update rate: 1, 2, 5,
#             10, 20 Hz" and single-point accuracy 1.5 m H / 3.0 m V (RMS).
# [F9P]       u-blox ZED-F9P data sheet (UBX-17051259) and integration manual (UBX-18010802): RTK
#             navigation update rate up to 20 Hz (lower with all four constellations),
#             "convergence time RTK < 10 s", horizontal accuracy "SBAS 1.0 m CEP", "RTK 0.01 m +
#             1 ppm CEP"; carrier solution states none / float / fixed (NMEA GGA quality 2 =
#             DGPS, 5 = RTK float, 4 = RTK fixed).
# [FLOAT]     RTK float: "typically 10 cm to 50 cm horizontally" (diginto.tech, "Float vs Fixed
#             RTK: Understanding Ambiguity Resolution"); "decimetre to sub-metre" (Point One
#             Navigation, "Float RTK"); Takasu & Yasuda 2009 (ION GNSS, RTKLIB) show float
#             errors of decimetres before the fix.
# [GK88]      Georgiadou & Kleusberg 1988, "On carrier signal multipath effects in relative GPS
#             positioning", manuscripta geodaetica 13: carrier-phase multipath is a slowly varying
#             (periods of minutes for a static antenna), centimetre-level error.
#
# * rate 10 Hz: within the 1-20 Hz of [D-RTK2]; 20 Hz is the [F9P] ceiling with few
#   constellations, a multi-constellation RTK engine sustains ~10 Hz (judgement; set rate_hz=20 to
#   test the ceiling).
# * base level (always on) = RTK fixed: horizontal RMS 1 cm + 1 ppm x baseline [DJI-M350], baseline
#   1 km (D-RTK 2 at the field edge; judgement) -> 1.1 cm H RMS -> per axis 1.1/sqrt(2) = 0.78 cm;
#   vertical 1.5 cm + 1 ppm = 1.6 cm (z axis_scale = 1.6 / 0.78 = 2.06).  Split 60 % of the
#   variance coloured (Gauss-Markov, tau = 30 s: carrier multipath is minutes-slow for a static
#   antenna [GK88], faster on a moving one; judgement) and 40 % white Student-t (nu = 4: heavier
#   tails than Gaussian, finite kurtosis only for nu > 4 so outliers are real; judgement).
# * rtk-fixed mode extra: rare glitches (cycle slips, partial re-fixes): spikes with probability
#   0.001 per fix (one per ~100 s at 10 Hz), 5-20 cm (judgement).
# * rtk-float: H RMS 0.3 m (middle of the 0.1-0.5 m of [FLOAT]) -> per axis 0.21 m; 80 % coloured
#   (GM tau = 20 s: float ambiguities drift slowly as they converge; judgement) + 20 % Student-t
#   (nu = 4); code-multipath spikes 1 % of fixes, 0.3-1.0 m (judgement); vertical x 2 (VDOP/HDOP
#   ~ 1.5-2 in open sky; judgement).
# * dgps (DGPS / SBAS): 1.0 m CEP [F9P] -> per axis sigma = CEP / 1.1774 = 0.85 m; 85 % coloured
#   (GM tau = 60 s: residual ionosphere/orbit errors vary over minutes; judgement) + 15 %
#   Student-t (nu = 4); spikes 1 % of fixes, 1-3 m (code multipath; judgement); vertical x 2.83
#   (= the 3.0 m V / (1.5 m H / sqrt(2)) ratio of [D-RTK2]'s single-point figures).
# * episode chain (all judgement, tuned to "degrades for tens of seconds, then recovers"):
#   mean dwell RTK fixed 300 s (an open field with the base <= 1 km: fix is lost to tree lines,
#   masking in banked turns and radio-link drop-outs, a few times an hour), RTK float 20 s
#   (twice the [F9P] open-sky convergence time < 10 s, since the conditions that broke the fix
#   persist a while), DGPS/SBAS 30 s (a correction-link drop-out of tens of seconds).  On leaving
#   fixed: 85 % to float, 15 % straight to DGPS (link loss); float: 80 % re-fixes, 20 % falls to
#   DGPS; DGPS always returns through float (an RTK engine re-converges before it fixes).
#   Occupancy pi_i ~ nu_i T_i with nu ~ (0.8, 1, 0.32): fixed 240/269.6 = 89.0 %, float
#   20/269.6 = 7.4 %, DGPS 9.6/269.6 = 3.6 %.
# * transitions: fixed -> degraded modes ramp with the degraded mode's ramp_s (float 2 s, DGPS
#   3 s: the receiver's navigation filter carries the last solution and drifts off it over a few
#   seconds; judgement); any -> fixed snaps in one epoch (ramp_s = 0): resolving the integers
#   corrects the position at once, a step of the float error (decimetres), as real receivers do.
_M350_BASELINE_M = 1000.0
_M350_FIX_H_RMS = 0.010 + 1e-6 * _M350_BASELINE_M  # [DJI-M350] 1 cm + 1 ppm, horizontal RMS
_M350_FIX_V_RMS = 0.015 + 1e-6 * _M350_BASELINE_M  # [DJI-M350] 1.5 cm + 1 ppm, vertical
_M350_FIX_SIG = _M350_FIX_H_RMS / math.sqrt(2.0)   # per horizontal axis
_M350_FLOAT_SIG = 0.30 / math.sqrt(2.0)            # [FLOAT] 0.3 m H RMS, per axis
_M350_DGPS_SIG = 1.0 / 1.1774                      # [F9P] SBAS 1.0 m CEP, per axis (CEP = 1.1774 s)


def _split(sigma: float, coloured: float, tau_s: float, nu: float = 4.0) -> list[dict[str, Any]]:
    """A Gauss-Markov part with ``coloured`` of the variance ``sigma**2`` plus a Student-t
    white part with the rest (total variance ``sigma**2``)."""
    return [
        {"type": "gauss-markov", "name": "coloured", "sigma": sigma * math.sqrt(coloured),
         "tau_s": tau_s},
        {"type": "student-t", "name": "white", "sigma": sigma * math.sqrt(1.0 - coloured),
         "nu": nu},
    ]


_RTK_M350: dict[str, Any] = {
    "rate_hz": 10.0, "latency_s": 0.0, "axis_scale": [1.0, 1.0, 1.0],
    "components": [{**c, "axis_scale": [1.0, 1.0, _M350_FIX_V_RMS / _M350_FIX_SIG]}
                   for c in _split(_M350_FIX_SIG, 0.6, 30.0)],
    "outage": {},
    "fix_quality": {
        "start": "rtk-fixed",
        "modes": {
            "rtk-fixed": {
                "mean_dwell_s": 300.0, "ramp_s": 0.0,
                "next": {"rtk-float": 0.85, "dgps": 0.15},
                "components": [{"type": "spikes", "name": "glitch", "prob": 0.001,
                                "amplitude": 0.05, "amplitude_max": 0.20}],
            },
            "rtk-float": {
                "mean_dwell_s": 20.0, "ramp_s": 2.0,
                "next": {"rtk-fixed": 0.8, "dgps": 0.2},
                "components": [
                    *({**c, "axis_scale": [1.0, 1.0, 2.0]}
                      for c in _split(_M350_FLOAT_SIG, 0.8, 20.0)),
                    {"type": "spikes", "name": "multipath", "prob": 0.01, "amplitude": 0.3,
                     "amplitude_max": 1.0, "axis_scale": [1.0, 1.0, 2.0]},
                ],
            },
            "dgps": {
                "mean_dwell_s": 30.0, "ramp_s": 3.0,
                "next": {"rtk-float": 1.0},
                "components": [
                    *({**c, "axis_scale": [1.0, 1.0, 2.83]}
                      for c in _split(_M350_DGPS_SIG, 0.85, 60.0)),
                    {"type": "spikes", "name": "multipath", "prob": 0.01, "amplitude": 1.0,
                     "amplitude_max": 3.0, "axis_scale": [1.0, 1.0, 2.83]},
                ],
            },
        },
    },
}

_PRESETS["rtk-m350"] = _RTK_M350

# --- m8p-rtk-static, m8p-standalone: fitted on real u-blox M8P logs ---------------------------
# Source: jdesbonnet/GNSS_RTK_data (github.com/jdesbonnet/GNSS_RTK_data; J. Desbonnet, NUI
# Galway, October 2018), u-blox NEO-M8P receivers standing still, 1 Hz:
# * m8p-rtk-static: rover-20181004-1237.ubx.gz (static rover in RTK beside its base), the 1121
#   epochs the receiver reported RTK fixed (NMEA GGA quality 4) of 1205 (UBX NAV-SOL ECEF).
# * m8p-standalone: base-20181015-1654.ubx.gz (a receiver without corrections, limited sky
#   view), its 2555 3-D fixes (NAV-SOL gpsFix 3) of 3687 (the rest time-only, after survey-in).
# Numbers as fitted by `ag-uav gnss fit LOG` (white + Gauss-Markov [+ random walk] to the
# overlapping Allan variance per axis and the scatter about the mean; horizontal = east and
# north together; a random walk is written as a Gauss-Markov term with tau = the log's length;
# no correlation time exceeds the log's length).  Figures and the check against the logs:
# docs/gnss.md.  Rate: the logs are 1 Hz, the presets fix at 5 Hz because the INS crashes at
# take-off on 1 Hz fixes with any preset (measured: `ag-uav fly --set gps.preset=rtk
# --set gps.rate_hz=1`, tilt > 80 deg at 2.06 s; 2 and 5 Hz fly); the Gauss-Markov terms are
# continuous-time (the same at any rate), the white term stays per fix as fitted at 1 Hz.
_PRESETS["m8p-rtk-static"] = {
    "rate_hz": 5.0, "latency_s": 0.0, "axis_scale": [1.0, 1.0, 1.0],
    "components": [
        {"type": "gaussian", "name": "white", "sigma": 0.00297, "axis_scale": [0.644, 0.644, 1.0]},
        {"type": "gauss-markov", "name": "gm", "sigma": 0.00542, "tau_s": 3.65,
         "axis_scale": [1.0, 1.0, 0.0]},
        {"type": "gauss-markov", "name": "gm-up", "sigma": 0.00993, "tau_s": 5.42,
         "axis_scale": [0.0, 0.0, 1.0]},
        {"type": "gauss-markov", "name": "slow", "sigma": 0.00711, "tau_s": 1120.0,
         "axis_scale": [1.0, 1.0, 0.0]},
        {"type": "gauss-markov", "name": "slow-up", "sigma": 0.0131, "tau_s": 1120.0,
         "axis_scale": [0.0, 0.0, 1.0]},
    ],
    "outage": {},
}
_PRESETS["m8p-standalone"] = {
    "rate_hz": 5.0, "latency_s": 0.0, "axis_scale": [1.0, 1.0, 1.0],
    "components": [
        {"type": "gauss-markov", "name": "gm", "sigma": 3.36, "tau_s": 2550.0,
         "axis_scale": [1.0, 1.0, 0.0]},
        {"type": "gauss-markov", "name": "gm-up", "sigma": 6.12, "tau_s": 2550.0,
         "axis_scale": [0.0, 0.0, 1.0]},
    ],
    "outage": {},
}

SENSOR_KEYS = {"rate_hz", "latency_s", "axis_scale", "components", "outage", "fix_quality"}




def available_presets() -> list[str]:
    """Names accepted by :func:`gps_preset` / :meth:`GpsSensor.from_preset`."""
    return list(_PRESETS)


def gps_preset(name: str) -> dict[str, Any]:
    """A deep copy of the named preset's config dict (safe to modify)."""
    if not isinstance(name, str) or name not in _PRESETS:
        raise bad("gps_preset", "name", name, f"allowed: {', '.join(_PRESETS)}")
    return copy.deepcopy(_PRESETS[name])


def _table(who: str, key: str, value: Any, allowed: str) -> dict[str, Any]:
    """``value`` as a dict with string keys, or a ValueError naming ``key``."""
    if not isinstance(value, Mapping):
        raise bad(who, key, value, allowed)
    for k in value:
        if not isinstance(k, str) or not k:
            raise bad(who, f"{key} key", k, "table keys must be non-empty strings")
    return dict(value)


def _merge_components(
    base: list[dict[str, Any]], override: Any, who: str = "gps config", key: str = "components"
) -> list[dict[str, Any]]:
    """Override ``base`` component tables: a list replaces them all; a table keyed by component
    name merges keys into that component (an empty table removes it; a new name adds one)."""
    allowed = "must be a list of component tables or a table of them keyed by name"
    if isinstance(override, Mapping):
        out = [copy.deepcopy(c) for c in base]
        names = [c.get("name", c.get("type")) for c in out]
        for name, upd in _table(who, key, override, allowed).items():
            if not isinstance(upd, Mapping):
                raise bad(who, f"{key}.{name}", upd, "must be a table of component keys "
                           "(an empty table removes the component)")
            if name in names:
                i = names.index(name)
                if len(upd) == 0:
                    out.pop(i)
                    names.pop(i)
                else:
                    out[i].update(copy.deepcopy(dict(upd)))
            elif len(upd):
                new = copy.deepcopy(dict(upd))
                new.setdefault("name", name)
                out.append(new)
                names.append(name)
        return out
    if isinstance(override, (list, tuple)):
        out = []
        for i, c in enumerate(override):
            if not isinstance(c, Mapping):
                raise bad(who, f"{key}[{i}]", c, "must be a component table with a 'type' key")
            out.append(copy.deepcopy(dict(c)))
        return out
    raise bad(who, key, override, allowed)


def _merge_fix_quality(base: Mapping[str, Any], override: Any) -> dict[str, Any]:
    """Override a ``fix_quality`` table: an empty table disables the episodes; otherwise
    ``start`` is replaced and ``modes`` merge by name (a mode's keys are replaced except
    ``components``, which merge as at sensor level; an empty mode table removes the mode)."""
    who = "gps fix_quality"
    ov = _table("gps config", "fix_quality", override,
                "must be a table with keys start, modes (an empty table disables episodes)")
    if not ov:
        return {}
    for k in ov:
        if k not in FIXQ_KEYS:
            raise bad(who, k, ov[k], f"unknown key; allowed: {', '.join(sorted(FIXQ_KEYS))}")
    out = copy.deepcopy(dict(base)) if base else {}
    if "start" in ov:
        out["start"] = ov["start"]
    if "modes" in ov:
        modes = dict(out.get("modes", {}))
        for nm, upd in _table(who, "modes", ov["modes"], "must be a table of mode tables "
                              "keyed by mode name").items():
            if not isinstance(upd, Mapping):
                raise bad(who, f"modes.{nm}", upd, "must be a table with mean_dwell_s, next, "
                           "ramp_s, components (an empty table removes the mode)")
            if nm in modes and not upd:
                del modes[nm]
                continue
            cur = copy.deepcopy(dict(modes.get(nm, {})))
            for k, v in upd.items():
                if k == "components":
                    cur[k] = _merge_components(cur.get(k, []), v, who, f"modes.{nm}.components")
                else:
                    cur[k] = copy.deepcopy(v)
            modes[nm] = cur
        out["modes"] = modes
    return out


def apply_overrides(preset: str, overrides: Any) -> dict[str, Any]:
    """The preset's config dict with ``overrides`` applied (structure checked, values not)."""
    cfg = gps_preset(preset)
    ov = _table(f"gps preset {preset!r}", "overrides", overrides,
                f"must be a table with keys among {', '.join(sorted(SENSOR_KEYS))}")
    for k, v in ov.items():
        if k not in SENSOR_KEYS:
            raise bad(f"gps preset {preset!r}", k, v,
                       f"unknown key; allowed: {', '.join(sorted(SENSOR_KEYS))}")
        if k == "components":
            cfg[k] = _merge_components(cfg.get(k, []), v)
        elif k == "fix_quality":
            cfg[k] = _merge_fix_quality(cfg.get(k, {}), v)
        elif k == "outage":
            cfg[k] = _table("gps config", "outage", v,
                            "must be a table with mean_up_s, mean_down_s[, start_in_outage] "
                            "(an empty table means no outages)")
        else:
            cfg[k] = v
    return cfg
