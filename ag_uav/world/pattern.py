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
pattern test is run at the mission's height, ground speed, drag, nozzles, droplet spectrum and
two masses, a full tank and an empty one, with the mean wind split across and along the legs the
planner will fly (the planning wind of :func:`ag_uav.world.forecast.plan_wind`, a forecast, not
the wind flown; :func:`mission_direction`: by default ``"crosswind"``, legs across the mean
wind, so that the passes out and back meet the same airspeed), a pass out and a pass back
overlaid alternately; the lane spacing is the widest spacing whose overlaid CV is at most
``mission.swath_cv_max`` at both masses (default 0.15, the spacing at which a normally spread
dose leaves about 10 % of the field below 80 % of its mean; 0.25 is the effective swath proper).
The plan's legs are then at most that far apart (the planner splits the interior into equal
strips, :func:`ag_uav.world.plan.plan_coverage`), the nozzles meter the rate over it, and the
sortie planner and the exports use it. A number sets the spacing by hand. The test is
deterministic and cached per the inputs it depends on, so a batch and its runs flown alone
choose the same lanes.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass
from typing import Any

import numpy as np

from numkit import X, Y, Z

from .deposition import DepositionBatch, DepositionConfig
from .deposition_layout import INPUT
from .forecast import SIGMA_POINTS, plan_wind, spread_winds

__all__ = ["pass_states", "single_pass", "cv_vs_spacing", "effective_swath", "swath_pattern",
           "LaneChoice", "lane_choice", "mission_swath", "mission_headland", "mission_direction",
           "crosswind_heading", "pattern_shift", "mission_offset", "CV_LIMIT", "SPACINGS"]

PASS_M = 60.0          # length of the sprayed pass
WINDOW_M = 10.0        # collectors: mean over this stretch of track in the middle
CV_LIMIT = 0.25        # the effective swath's CV (Martin et al. 2019)
COLLECTOR_M = 0.25     # collector spacing = the map's cell in this test
#: the lane spacings tried (m)
SPACINGS = np.arange(0.5, 20.01, 0.25)


def pass_states(speed: float, height: float, wind_y: float, mass_kg: float,
                drag_lin: float, drag_quad: float, wind_x: float = 0.0
                ) -> tuple[np.ndarray, float]:
    """Body→world R (row-major, 9) and total thrust of a steady level pass along +x: thrust
    vector T = m g ẑ + (c₁ + c₂|v_a|) v_a balances weight and drag at airspeed v_a = v − W."""
    va = np.array([speed - wind_x, -wind_y, 0.0])
    tv = np.array([0.0, 0.0, mass_kg * 9.81]) + (drag_lin + drag_quad * np.linalg.norm(va)) * va
    z = tv / np.linalg.norm(tv)
    x = np.array([1.0, 0.0, 0.0]) - z[0] * z
    x /= np.linalg.norm(x)
    y = np.cross(z, x)
    return np.column_stack([x, y, z]).ravel(), float(np.linalg.norm(tv))


def single_pass(cfg: DepositionConfig, speed: float, height: float, wind_y: float,
                mass_kg: float = 6.47, drag_lin: float = 0.25, drag_quad: float = 0.18,
                dt: float = 0.01, turb: float = 0.2, wind_x: float = 0.0
                ) -> tuple[np.ndarray, np.ndarray, dict]:
    """One pass along +x; returns (y of the collectors, deposit L/ha, bookkeeping dict). The
    wind has ``wind_y`` across the track (towards +y, the left of the pass) and ``wind_x`` along
    it. The steady pass has no gust samples, so ambient turbulence enters as σ_a = ``turb`` ×
    wind speed (0.2: the Dryden "mean" preset's σ_u at 3 m, :mod:`ag_uav.world.wind`) unless the
    config sets its own."""
    R, thrust = pass_states(speed, height, wind_y, mass_kg, drag_lin, drag_quad, wind_x)
    sig = cfg.ambient_sigma_mps or turb * math.hypot(wind_x, wind_y)
    cfg = dataclasses.replace(cfg, cell_m=COLLECTOR_M, buffer_m=max(cfg.buffer_m, 20.0),
                              ambient_sigma_mps=sig)
    dep = DepositionBatch(cfg, None, 1, bounds=(-PASS_M / 2, -1.0, PASS_M / 2, 1.0))
    x = -PASS_M / 2 - 2.0 * speed
    n = int(round((PASS_M + 4.0 * speed) / (speed * dt)))
    inp = np.zeros((1, INPUT.size))
    I = INPUT.at
    inp[0, I.R:I.R_END] = R
    inp[0, I.THRUST] = thrust
    inp[0, I.WIND + X] = wind_x
    inp[0, I.WIND + Y] = wind_y
    inp[0, I.VEL + X] = speed
    inp[0, I.POS + Z] = height
    for _ in range(n):
        x += speed * dt
        inp[0, I.POS + X] = x
        inp[0, I.CMD] = 1.0 if -PASS_M / 2 <= x <= PASS_M / 2 else 0.0
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


def cv_back_and_forth(y: np.ndarray, fwd: np.ndarray, back: np.ndarray,
                      spacings: np.ndarray) -> np.ndarray:
    """CV of a back-and-forth overlay, for each spacing S: passes out (profile ``fwd``) at
    y = 2jS and back (``back``, in the same y) at (2j + 1)S, over one period 2S. With a wind along
    the track the two directions fly at different airspeeds and lay different profiles."""
    dy = y[1] - y[0]
    out = np.empty(len(spacings))
    for i, s in enumerate(spacings):
        k = max(1, int(round(s / dy)))
        pair = fwd.astype(float).copy()
        if k < len(back):
            pair[k:] += back[:len(back) - k]
        per = np.bincount(np.arange(len(pair)) % (2 * k), weights=pair, minlength=2 * k)
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
    """What a mission's pattern test depends on (the cache key): the wind in the frame of the
    legs flown out (``wind_cross_mps`` to their left, ``wind_along_mps`` along them) and the legs'
    heading ``legs_deg`` (degrees counter-clockwise from east)."""

    dep: DepositionConfig
    speed_mps: float
    height_m: float
    wind_cross_mps: float
    wind_along_mps: float
    legs_deg: float | None
    masses_kg: tuple[float, ...]     # a full tank, an empty one
    drag_linear: float
    drag_quadratic: float
    #: the winds (across, along) of the forecast's spread the lanes must also hold in
    spread: tuple[tuple[float, float], ...] = ()


@dataclass(frozen=True)
class LaneChoice:
    """The lane spacing of a mission and where it came from. ``source``: ``"auto"`` (the pattern
    test) or ``"config"`` (a number in ``mission.swath_m``). With ``"auto"``, ``cv`` is the
    back-and-forth overlay's CV at ``swath_m`` (the worse of the masses tested) and ``y`` /
    ``profiles`` the single-pass deposits (per unit flow): (out, back) per mass of
    :attr:`PatternCase.masses_kg`, the back pass in the frame of the pass out."""

    swath_m: float
    source: str
    cv_max: float = CV_LIMIT
    cv: float | None = None
    case: PatternCase | None = None
    y: np.ndarray | None = dataclasses.field(default=None, repr=False, compare=False)
    profiles: tuple = dataclasses.field(default=(), repr=False, compare=False)
    #: the mean CV over the forecast's spread at ``swath_m`` (:attr:`PatternCase.spread`)
    cv_spread: float | None = None

    def cv_at(self, spacing: float) -> float | None:
        """The pattern test's overlaid CV at ``spacing``, the worse of the masses tested (None
        without a test)."""
        if not self.profiles or self.y is None:
            return None
        return max(float(cv_back_and_forth(self.y, f, b, np.array([spacing]))[0])
                   for f, b in self.profiles)

    def _wind(self) -> str:
        c = self.case
        assert c is not None
        if c.wind_cross_mps == 0 and c.wind_along_mps == 0:
            return "calm"
        legs = "" if c.legs_deg is None else f" ({c.legs_deg:.1f}°)"
        return (f"wind {abs(c.wind_cross_mps):.1f} m/s across and {abs(c.wind_along_mps):.1f} "
                f"m/s along the legs{legs}")

    def text(self) -> str:
        """One line: the spacing and where it came from."""
        if self.case is None:
            return f"lanes {self.swath_m:g} m: mission.swath_m (set by hand)"
        c = self.case
        rule = ("effective swath" if self.cv_max == CV_LIMIT
                else f"widest spacing with CV <= {100 * self.cv_max:g} %")
        tank = ", full and empty tank" if len(c.masses_kg) > 1 else ""
        where = f"{c.height_m:g} m, {c.speed_mps:g} m/s, {self._wind()}{tank}"
        if self.swath_m <= 0:
            return (f"lanes: no spacing of the back-and-forth pattern test at {where} has CV <= "
                    f"{100 * self.cv_max:g} %")
        spread = ("" if self.cv_spread is None else
                  f"; {100 * self.cv_spread:.0f} % on average one sigma off the forecast")
        return (f"lanes {self.swath_m:g} m: {rule} of the back-and-forth pattern test at "
                f"{where} (CV {100 * (self.cv or 0.0):.0f} %{spread})")

    def summary(self, leg_spacing: float | None = None) -> dict[str, Any]:
        """The ``lanes`` table of a run's summary."""
        out: dict[str, Any] = {"swath_m": self.swath_m, "source": self.source,
                               "text": self.text()}
        if self.case is not None:
            c = self.case
            out.update({"cv": self.cv, "cv_max": self.cv_max, "height_m": c.height_m,
                        "speed_mps": c.speed_mps, "wind_cross_mps": c.wind_cross_mps,
                        "wind_along_mps": c.wind_along_mps, "legs_deg": c.legs_deg,
                        "masses_kg": list(c.masses_kg), "cv_spread": self.cv_spread})
        if leg_spacing is not None:
            out["leg_spacing_m"] = leg_spacing
            cv = self.cv_at(leg_spacing)
            if cv is not None:
                out["cv_at_leg_spacing"] = cv
        return out


_CACHE: dict[str, Any] = {}


def _cached(key: str, make: Any) -> Any:
    hit = _CACHE.get(key)
    if hit is None:
        if len(_CACHE) > 64:
            _CACHE.clear()
        hit = _CACHE[key] = make()
    return hit


def crosswind_heading(wind_from_deg: float) -> float:
    """The heading (deg from east, counter-clockwise, in [0, 180)) of legs across a wind that
    blows from compass bearing ``wind_from_deg``: the wind blows towards
    atan2(−cos d, −sin d) in ENU; the legs run 90° to that."""
    d = math.radians(wind_from_deg)
    towards = math.degrees(math.atan2(-math.cos(d), -math.sin(d)))
    return round((towards + 90.0) % 180.0, 9)


def mission_direction(cfg: Any) -> float | None:
    """The legs' heading given to the planner: ``mission.direction_deg`` when a number; for
    ``"crosswind"`` the heading across the planning wind (:func:`~ag_uav.world.forecast.
    plan_wind`; :func:`crosswind_heading`), or None in calm
    air; for ``"auto"`` None (the planner's fewest turns)."""
    d = cfg.mission.direction_deg
    if d == "crosswind":
        w = plan_wind(cfg)
        return crosswind_heading(w.direction_deg) if w.speed_mps > 0 else None
    return None if d == "auto" else float(d)


def _legs_heading(cfg: Any, base: PatternCase) -> float | None:
    """The heading (deg) of the legs the planner flies: :func:`mission_direction`, or where the
    planner picks it (``"auto"``, or ``"crosswind"`` in calm air) the direction of a plan whose
    lanes are the pure-crosswind effective swath at the full tank (the direction with the fewest
    legs hardly moves with the lanes). None where that plan fails (the lanes then take the
    whole wind as a crosswind)."""
    m = cfg.mission
    given = mission_direction(cfg)
    if given is not None:
        return given % 180.0
    from .field import load_field
    from .plan import plan_coverage

    w = math.hypot(base.wind_cross_mps, base.wind_along_mps)
    y, p, _ = single_pass(base.dep, base.speed_mps, base.height_m, w, base.masses_kg[0],
                          base.drag_linear, base.drag_quadratic)
    s0 = effective_swath(SPACINGS, cv_vs_spacing(y, p, SPACINGS), m.swath_cv_max) or 4.0
    try:
        fld = load_field(m.field)
        head = s0 if isinstance(m.headland_m, str) else float(m.headland_m)
        return plan_coverage(fld, swath=s0, headland=head).direction_deg
    except ValueError:
        return None


def pattern_case(cfg: Any) -> PatternCase:
    """The pattern test of ``cfg``'s mission: height, ground speed, the masses it sprays at (dry
    + payload + unknown payload, with a full tank and with an empty one when the sprayer is
    modelled: the rotor wake, hence the pattern, follows the thrust), drag along the body x
    axis, the deposition config (nozzles, spectrum, rotors, air) and the planning wind
    (:func:`~ag_uav.world.forecast.plan_wind`) split across
    and along the legs (:func:`_legs_heading`)."""
    v, sp, m, wd = cfg.vehicle, cfg.spray, cfg.mission, plan_wind(cfg)
    dry = v.mass_kg + v.payload_kg + v.unknown_payload_kg
    masses = (dry + sp.tank_l * sp.density_kg_per_l, dry) if sp.enabled else (dry,)
    dep = DepositionConfig.from_config(cfg, swath_m=1.0)  # the profile is per unit swath flow
    base = PatternCase(dep, float(m.speed_mps), float(m.altitude_m), float(wd.speed_mps), 0.0,
                       None, masses, float(v.drag_linear[0]), float(v.drag_quadratic[0]))
    if wd.speed_mps == 0:
        return base
    key = repr(("legs", base, m.field, mission_direction(cfg), m.headland_m, m.swath_cv_max))
    legs = _cached(key, lambda: _legs_heading(cfg, base))
    if legs is None:
        return base
    d = math.radians(wd.direction_deg)
    wx, wy = -wd.speed_mps * math.sin(d), -wd.speed_mps * math.cos(d)   # ENU, blowing to
    t = math.radians(legs)
    along = wx * math.cos(t) + wy * math.sin(t)
    cross = -wx * math.sin(t) + wy * math.cos(t)
    fc = cfg.forecast
    spread = (tuple((round(c, 9), round(a, 9)) for c, a in spread_winds(
        cross, along, SIGMA_POINTS, fc.speed_sigma_mps, fc.direction_sigma_deg))
        if m.swath_spread and (fc.speed_sigma_mps > 0 or fc.direction_sigma_deg > 0) else ())
    return dataclasses.replace(base, wind_cross_mps=round(cross, 9),
                               wind_along_mps=round(along, 9), legs_deg=legs, spread=spread)


def _overlay(case: PatternCase, cross: float, along: float
             ) -> tuple[np.ndarray, list[tuple[np.ndarray, np.ndarray]], np.ndarray]:
    """The passes out and back of ``case`` in the wind (``cross``, ``along``) at each of its
    masses: (y, [(out, back) per mass], the worse mass's back-and-forth CV at every spacing)."""
    profiles, cvs = [], []
    args = (case.speed_mps, case.height_m)
    drag = (case.drag_linear, case.drag_quadratic)
    for mass in case.masses_kg:
        y, fwd, _ = single_pass(case.dep, *args, cross, mass, *drag, wind_x=along)
        yb, back, _ = single_pass(case.dep, *args, -cross, mass, *drag, wind_x=-along)
        assert np.allclose(yb[::-1], -y)   # the collectors are symmetric about the track
        profiles.append((fwd, back[::-1].copy()))
        cvs.append(cv_back_and_forth(y, fwd, back[::-1], SPACINGS))
    return y, profiles, np.max(cvs, axis=0)


def run_pattern(case: PatternCase, cv_max: float = CV_LIMIT) -> LaneChoice:
    """The back-and-forth pattern test of ``case`` at each of its masses: a pass out along the
    legs and one back (the same pass with the wind reversed, mirrored across the track), and
    the widest spacing whose overlay CV is ≤ ``cv_max`` at every mass (the lanes must hold from
    a full tank to an empty one). With a :attr:`PatternCase.spread` the spacing's CV averaged
    over those winds must be ≤ ``cv_max`` too (the lanes hold, on average, when the forecast is
    one σ off)."""
    y, profiles, cv = _overlay(case, case.wind_cross_mps, case.wind_along_mps)
    need = cv
    if case.spread:
        cv_sp = np.mean([cv_w for _, _, cv_w in (_overlay(case, c, a) for c, a in case.spread)],
                        axis=0)
        need = np.maximum(cv, cv_sp)
    s = effective_swath(SPACINGS, need, cv_max)
    i = int(np.argmin(np.abs(SPACINGS - s)))
    cv_s = float(cv[i]) if s > 0 else None
    cv_spread = float(cv_sp[i]) if case.spread and s > 0 else None
    return LaneChoice(s, "auto", cv_max, cv_s, case, y, tuple(profiles), cv_spread)


def lane_choice(cfg: Any) -> LaneChoice:
    """The lane spacing of ``cfg``'s mission: ``mission.swath_m`` when it is a number, else the
    pattern test's (cached per :class:`PatternCase` and ``mission.swath_cv_max``)."""
    m = cfg.mission
    if not isinstance(m.swath_m, str):
        return LaneChoice(float(m.swath_m), "config")
    case = pattern_case(cfg)
    return _cached(repr(("lanes", case, m.swath_cv_max)),
                   lambda: run_pattern(case, m.swath_cv_max))


def mission_swath(cfg: Any) -> float:
    """The lane spacing (m) of ``cfg``'s mission (:func:`lane_choice`)."""
    return lane_choice(cfg).swath_m


def pattern_shift(y: np.ndarray, profiles: tuple) -> float:
    """Where the pattern's deposit lies across the flight line (m, in the pattern test's y: +y
    the way the crosswind blows when ``wind_cross_mps`` > 0): the centre of its width at half
    its peak (the two outermost collectors at ≥ half the peak, as a pattern test's trace is
    read for its swath: ASABE S386), of the mean of the passes out and back, averaged over the
    masses tested. A crosswind carries the deposit downwind of the track; a spray operator
    offsets the flight lines upwind by that much so that the pattern, not the track, covers the
    field (the swath displacement of aerial application's pattern testing)."""
    out = []
    for fwd, back in profiles:
        p = 0.5 * (fwd + back)
        k = np.nonzero(p >= 0.5 * p.max())[0] if p.max() > 0 else np.array([], int)
        if len(k):
            out.append(0.5 * (y[k[0]] + y[k[-1]]))
    return float(np.mean(out)) if out else 0.0


def mission_offset(cfg: Any) -> tuple[float, float]:
    """The translation (east, north; m) of ``cfg``'s whole plan: ``mission.upwind_offset_m``
    upwind across the legs, or for ``"auto"`` minus the :func:`pattern_shift` of the back-and-
    forth pattern test in the planning wind, across the legs, at most half the lanes (zero in
    calm air or where the legs' heading is not known before the plan). The lanes and the
    headland are unchanged: the boundary laps move with the legs, the upwind one towards the
    edge (at most onto it: the flight stays over the field), the downwind one inside it, as the
    deposit moves the other way."""
    given = cfg.mission.upwind_offset_m
    if given != "auto" and float(given) == 0.0:
        return 0.0, 0.0
    case = pattern_case(cfg)
    if case.legs_deg is None or case.wind_cross_mps == 0.0:
        return 0.0, 0.0
    if given == "auto":
        lc = _cached(repr(("lanes", case, cfg.mission.swath_cv_max)),
                     lambda: run_pattern(case, cfg.mission.swath_cv_max))
        lanes = mission_swath(cfg)
        c = float(np.clip(pattern_shift(lc.y, lc.profiles), -0.5 * lanes, 0.5 * lanes))
    else:
        c = math.copysign(float(given), case.wind_cross_mps)
    t = math.radians(case.legs_deg)
    return round(c * math.sin(t), 9), round(-c * math.cos(t), 9)   # −c along (−sin t, cos t)


def mission_headland(cfg: Any) -> float:
    """The headland margin (m): ``mission.headland_m``, or one lap of the lanes for ``"auto"``."""
    h = cfg.mission.headland_m
    return mission_swath(cfg) if isinstance(h, str) else float(h)
