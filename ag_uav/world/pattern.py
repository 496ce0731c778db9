"""The spray pattern test of the deposition model, and the lane spacing it gives a mission.

**Pattern test** (ASABE S386-style; the effective swath for multirotors as in Martin, Woldt &
Latheef, *Drones* 3(4):83, 2019: the widest lane spacing with CV ≤ 25 %). A single pass is flown
across a line of collectors and the deposit profile across the flight line is read from the dose
map (mean over a 10 m stretch of track in the middle of a 60 m pass; collectors every 0.25 m,
out to 20 m on each side). The vehicle is kinematic (:func:`pass_states`): constant ground speed
along +x at y = 0, the tilt and thrust that balance its weight and the configured air drag at its
airspeed, no MuJoCo, so a case takes about a second. The crosswind blows along +y.

Overlaying the profile at lane spacing S (Σ_j p(y − jS); with symmetric nozzles in a pure
crosswind the back-and-forth and racetrack overlays coincide in the ground frame) gives the CV
against S (:func:`cv_vs_spacing`); the effective swath is the widest S (0.25 m steps up to 20 m)
with CV ≤ 25 % (:func:`effective_swath`).

**Lanes of a mission** (:func:`lane_choice`). With ``mission.swath_m = "auto"`` (the default) the
pattern test is run at the mission's height, ground speed, drag, nozzles, droplet spectrum, the
mean wind speed taken as a crosswind (the worst case over sweep directions: the lanes are chosen
before the plan's direction is) and two masses, with a full tank and an empty one, and the lane
spacing is the widest spacing whose overlaid CV is at most ``mission.swath_cv_max`` (0.25: the
effective swath) at both. The plan's legs are then at most that far apart (the planner splits the
interior into equal strips, :func:`ag_uav.world.plan.plan_coverage`), the nozzles meter the rate
over it, and the sortie planner and the exports use it. A number sets the spacing by hand. The
test is deterministic and cached per the inputs it depends on, so a batch and its runs flown
alone choose the same lanes.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass
from typing import Any

import numpy as np

from .deposition import DepositionBatch, DepositionConfig

__all__ = ["pass_states", "single_pass", "cv_vs_spacing", "effective_swath", "swath_pattern",
           "LaneChoice", "lane_choice", "mission_swath", "mission_headland", "CV_LIMIT",
           "SPACINGS"]

PASS_M = 60.0          # length of the sprayed pass
WINDOW_M = 10.0        # collectors: mean over this stretch of track in the middle
CV_LIMIT = 0.25        # the effective swath's CV (Martin et al. 2019)
COLLECTOR_M = 0.25     # collector spacing = the map's cell in this test
#: the lane spacings tried (m)
SPACINGS = np.arange(0.5, 20.01, 0.25)


def pass_states(speed: float, height: float, wind_y: float, mass_kg: float,
                drag_lin: float, drag_quad: float) -> tuple[np.ndarray, float]:
    """Body→world R (row-major, 9) and total thrust of a steady level pass along +x: thrust
    vector T = m g ẑ + (c₁ + c₂|v_a|) v_a balances weight and drag at airspeed v_a = v − W."""
    va = np.array([speed, -wind_y, 0.0])
    tv = np.array([0.0, 0.0, mass_kg * 9.81]) + (drag_lin + drag_quad * np.linalg.norm(va)) * va
    z = tv / np.linalg.norm(tv)
    x = np.array([1.0, 0.0, 0.0]) - z[0] * z
    x /= np.linalg.norm(x)
    y = np.cross(z, x)
    return np.column_stack([x, y, z]).ravel(), float(np.linalg.norm(tv))


def single_pass(cfg: DepositionConfig, speed: float, height: float, wind_y: float,
                mass_kg: float = 6.47, drag_lin: float = 0.25, drag_quad: float = 0.18,
                dt: float = 0.01, turb: float = 0.2) -> tuple[np.ndarray, np.ndarray, dict]:
    """One pass; returns (y of the collectors, deposit L/ha, bookkeeping dict). The steady pass
    has no gust samples, so ambient turbulence enters as σ_a = ``turb`` × wind (0.2: the Dryden
    "mean" preset's σ_u at 3 m, :mod:`ag_uav.world.wind`) unless the config sets its own."""
    R, thrust = pass_states(speed, height, wind_y, mass_kg, drag_lin, drag_quad)
    sig = cfg.ambient_sigma_mps or turb * abs(wind_y)
    cfg = dataclasses.replace(cfg, cell_m=COLLECTOR_M, buffer_m=max(cfg.buffer_m, 20.0),
                              ambient_sigma_mps=sig)
    dep = DepositionBatch(cfg, None, 1, bounds=(-PASS_M / 2, -1.0, PASS_M / 2, 1.0))
    x = -PASS_M / 2 - 2.0 * speed
    n = int(round((PASS_M + 4.0 * speed) / (speed * dt)))
    inp = np.zeros((1, 20))
    inp[0, 6:15] = R
    inp[0, 15] = thrust
    inp[0, 17] = wind_y
    inp[0, 3] = speed
    inp[0, 2] = height
    for _ in range(n):
        x += speed * dt
        inp[0, 0] = x
        inp[0, 19] = 1.0 if -PASS_M / 2 <= x <= PASS_M / 2 else 0.0
        dep.step_packed(dt, inp)
    dm = dep.dose_map(0)
    xc, yc = dm.centres()
    cols = np.abs(xc) <= WINDOW_M / 2
    prof = dm.l_per_ha[:, cols].mean(axis=1)
    info = {"sprayed_l": dm.sprayed_l, "drift_l": dm.drift_l,
            "outside_l": dm.outside_grid_l, "grid_l": float(dm.litres.sum())}
    return yc, prof, info


def cv_vs_spacing(y: np.ndarray, prof: np.ndarray, spacings: np.ndarray) -> np.ndarray:
    """CV of the overlaid deposit Σ_j p(y − jS) over one period, for each spacing S."""
    dy = y[1] - y[0]
    out = np.empty(len(spacings))
    for i, s in enumerate(spacings):
        k = max(1, int(round(s / dy)))
        per = np.zeros(k)
        for j in range(len(prof)):
            per[j % k] += prof[j]
        out[i] = per.std() / per.mean() if per.mean() > 0 else math.inf
    return out


def effective_swath(spacings: np.ndarray, cv: np.ndarray, limit: float = CV_LIMIT) -> float:
    """The widest spacing with CV ≤ ``limit`` (0 if none)."""
    ok = np.nonzero(cv <= limit)[0]
    return float(spacings[ok[-1]]) if len(ok) else 0.0


def swath_pattern(cfg: DepositionConfig, heights, speeds, winds, mass_kg: float = 6.47,
                  drag_lin: float = 0.25, drag_quad: float = 0.18,
                  spacings: np.ndarray | None = None, turb: float = 0.2
                  ) -> tuple[list[dict], dict]:
    """Every (height, speed, wind) case: a row of pattern figures and its profile."""
    sp = SPACINGS if spacings is None else spacings
    rows, profiles = [], {}
    for h in heights:
        for v in speeds:
            for w in winds:
                y, p, info = single_pass(cfg, v, h, w, mass_kg, drag_lin, drag_quad, turb=turb)
                cv = cv_vs_spacing(y, p, sp)
                tot = p.sum()
                cen = float((y * p).sum() / tot) if tot > 0 else math.nan
                i_cfg = int(np.argmin(np.abs(sp - cfg.swath_m)))
                rows.append({"height_m": h, "speed_mps": v, "wind_mps": w,
                             "effective_swath_m": effective_swath(sp, cv),
                             "cv_at_swath": float(cv[i_cfg]), "peak_l_per_ha": float(p.max()),
                             "centroid_m": cen,
                             "beyond_5m_fraction": float(p[y > 5.0].sum() / tot) if tot else 0.0,
                             "drift_fraction": info["drift_l"] / info["sprayed_l"]})
                profiles[(h, v, w)] = (y, p)
    return rows, profiles


# ------------------------------------------------------------------------------ a mission's lanes
@dataclass(frozen=True)
class PatternCase:
    """What a mission's pattern test depends on (the cache key)."""

    dep: DepositionConfig
    speed_mps: float
    height_m: float
    wind_mps: float
    masses_kg: tuple[float, ...]     # a full tank, an empty one
    drag_linear: float
    drag_quadratic: float


@dataclass(frozen=True)
class LaneChoice:
    """The lane spacing of a mission and where it came from. ``source``: ``"auto"`` (the pattern
    test) or ``"config"`` (a number in ``mission.swath_m``). With ``"auto"``, ``cv`` is the
    overlaid CV at ``swath_m`` (the worse of the masses tested) and ``y``/``profiles`` the
    single-pass deposits (per unit flow), one per mass of :attr:`PatternCase.masses_kg`."""

    swath_m: float
    source: str
    cv_max: float = CV_LIMIT
    cv: float | None = None
    case: PatternCase | None = None
    y: np.ndarray | None = dataclasses.field(default=None, repr=False, compare=False)
    profiles: tuple = dataclasses.field(default=(), repr=False, compare=False)

    def cv_at(self, spacing: float) -> float | None:
        """The pattern test's overlaid CV at ``spacing``, the worse of the masses tested (None
        without a test)."""
        if not self.profiles or self.y is None:
            return None
        return max(float(cv_vs_spacing(self.y, p, np.array([spacing]))[0])
                   for p in self.profiles)

    def text(self) -> str:
        """One line: the spacing and where it came from."""
        if self.case is None:
            return f"lanes {self.swath_m:g} m: mission.swath_m (set by hand)"
        c = self.case
        wind = "calm" if c.wind_mps == 0 else f"{c.wind_mps:g} m/s crosswind"
        if len(c.masses_kg) > 1:
            wind += ", full and empty tank"
        rule = ("effective swath" if self.cv_max == CV_LIMIT
                else f"widest spacing with CV <= {100 * self.cv_max:g} %")
        if self.swath_m <= 0:
            return (f"lanes: no spacing of the pattern test at {c.height_m:g} m, "
                    f"{c.speed_mps:g} m/s, {wind} has CV <= {100 * self.cv_max:g} %")
        return (f"lanes {self.swath_m:g} m: {rule} of the pattern test at {c.height_m:g} m, "
                f"{c.speed_mps:g} m/s, {wind} (CV {100 * (self.cv or 0.0):.0f} %)")

    def summary(self, leg_spacing: float | None = None) -> dict[str, Any]:
        """The ``lanes`` table of a run's summary."""
        out: dict[str, Any] = {"swath_m": self.swath_m, "source": self.source,
                               "text": self.text()}
        if self.case is not None:
            c = self.case
            out.update({"cv": self.cv, "cv_max": self.cv_max, "height_m": c.height_m,
                        "speed_mps": c.speed_mps, "crosswind_mps": c.wind_mps,
                        "masses_kg": list(c.masses_kg)})
        if leg_spacing is not None:
            out["leg_spacing_m"] = leg_spacing
            cv = self.cv_at(leg_spacing)
            if cv is not None:
                out["cv_at_leg_spacing"] = cv
        return out


_CACHE: dict[str, LaneChoice] = {}


def pattern_case(cfg: Any) -> PatternCase:
    """The pattern test of ``cfg``'s mission: height, ground speed, the masses it sprays at (dry
    + payload + unknown payload, with a full tank and with an empty one when the sprayer is
    modelled: the rotor wake, hence the pattern, follows the thrust), drag along the body x
    axis, the deposition config (nozzles, spectrum, rotors, air) and the mean wind as a
    crosswind."""
    v, sp = cfg.vehicle, cfg.spray
    dry = v.mass_kg + v.payload_kg + v.unknown_payload_kg
    masses = (dry + sp.tank_l * sp.density_kg_per_l, dry) if sp.enabled else (dry,)
    dep = DepositionConfig.from_config(cfg, swath_m=1.0)  # the profile is per unit swath flow
    return PatternCase(dep, float(cfg.mission.speed_mps), float(cfg.mission.altitude_m),
                       float(cfg.wind.speed_mps), masses, float(v.drag_linear[0]),
                       float(v.drag_quadratic[0]))


def run_pattern(case: PatternCase, cv_max: float = CV_LIMIT) -> LaneChoice:
    """The pattern test of ``case`` at each of its masses and the widest spacing whose CV is ≤
    ``cv_max`` at all of them (the lanes must hold from a full tank to an empty one)."""
    profiles, cvs = [], []
    for m in case.masses_kg:
        y, p, _ = single_pass(case.dep, case.speed_mps, case.height_m, case.wind_mps, m,
                              case.drag_linear, case.drag_quadratic)
        profiles.append(p)
        cvs.append(cv_vs_spacing(y, p, SPACINGS))
    cv = np.max(cvs, axis=0)
    s = effective_swath(SPACINGS, cv, cv_max)
    cv_s = float(cv[int(np.argmin(np.abs(SPACINGS - s)))]) if s > 0 else None
    return LaneChoice(s, "auto", cv_max, cv_s, case, y, tuple(profiles))


def lane_choice(cfg: Any) -> LaneChoice:
    """The lane spacing of ``cfg``'s mission: ``mission.swath_m`` when it is a number, else the
    pattern test's (cached per :class:`PatternCase` and ``mission.swath_cv_max``)."""
    m = cfg.mission
    if not isinstance(m.swath_m, str):
        return LaneChoice(float(m.swath_m), "config")
    case = pattern_case(cfg)
    key = repr((case, m.swath_cv_max))
    hit = _CACHE.get(key)
    if hit is None:
        if len(_CACHE) > 64:
            _CACHE.clear()
        hit = _CACHE[key] = run_pattern(case, m.swath_cv_max)
    return hit


def mission_swath(cfg: Any) -> float:
    """The lane spacing (m) of ``cfg``'s mission (:func:`lane_choice`)."""
    return lane_choice(cfg).swath_m


def mission_headland(cfg: Any) -> float:
    """The headland margin (m): ``mission.headland_m``, or one lap of the lanes for ``"auto"``."""
    h = cfg.mission.headland_m
    return mission_swath(cfg) if isinstance(h, str) else float(h)
