"""Spray jobs: tank and application, battery energy, and sorties (return to base, refill, resume).

**Application.** The nozzles deliver the application rate R (L/ha) over the swath w (m) at the
ground speed v (m/s): flow q = R · w · v / 10⁴ (L/s), i.e. R·w/10⁴ litres per metre of sprayed
track, whatever the speed (constant-rate control, as spray drones do with a flow meter). They
are on only while the plan sprays, the tank is not empty and the height above ground is within
[``spray.min_height_m``, ``spray.max_height_m``] (off on the ground and above the maximum).

**Mass.** The liquid is its own MuJoCo body (``liquid``, welded under the airframe at the tank,
built in :mod:`ag_uav.vehicle.mjcf`); each change of ≥ 1 g sets ``model.body_mass``,
``model.body_inertia`` (a box of liquid of the tank's footprint) and ``model.body_subtreemass``
(used by ``mj_comPos`` for the subtree centre of mass; ``mj_setConst`` is not needed and would
overwrite ``data`` with ``qpos0``). The autopilot knows its payload (spray drones weigh the tank or
count the flow): the position cascade's mass and the attitude loop's inertia follow the tank.

**Energy.** Momentum theory (Leishman, *Principles of Helicopter Aerodynamics*, 2nd ed., §2.3
and §2.6): the ideal induced power of a rotor of disc area A in air of density ρ giving thrust T
is T^{3/2}/sqrt(2ρA); with a figure of merit FM (here: rotor FM × motor/ESC efficiency, electrical
to induced power) the electrical power is

    P_i = T_i^{3/2} / (FM · sqrt(2 ρ A)),     P = Σ_i P_i + P_avionics,

integrated every control tick over the four *actual* rotor thrusts (the actuator states after the
motor lag). Forward flight at 5–8 m/s is treated like hover (translational lift lowers the
induced power, parasite drag raises it; neither is modelled), so the figures are hover-class.

Calibration (DJI M350 RTK: 6.47 kg with two TB65 batteries, 2 × 263 Wh = 526 Wh, max flight
time 55 min without payload, DJI spec sheet; 2110s propellers, D = 0.533 m, A = πD²/4 =
0.2231 m²; ρ = 1.225 kg/m³): per rotor T = 6.47·9.81/4 = 15.87 N, ideal P = 85.5 W, 342 W for
four. 526 Wh over 55 min is 574 W; with 25 W of avionics (an estimate) the rotors take 549 W,
so FM = 342/549 = 0.623 (:func:`implied_figure_of_merit`; a plausible product of a rotor FM of
~0.75 and a motor/ESC efficiency of ~0.83). At the 9.2 kg maximum take-off mass the same model
gives 33 min (P ∝ m^{3/2}). I recall DJI quoting ~31 min at full payload for the M300 RTK (the
M350's predecessor, same TB60-class energy) but could not confirm it here: treat the loaded figure
as unverified. The m^{3/2} scaling itself checks against a published pair: DJI's AGRAS T40 spec
page (dji.com/support/product/t40) gives 18 min hover at 50 kg and 7 min at 90 kg on the same
30,000 mAh battery; 18·(50/90)^{3/2} = 7.45 min, 6 % above the published 7 min.

**Sorties** (:func:`plan_job`; transits go around holes, :func:`transit_path`). The planner walks
the single-sortie reference (the coverage plan flown as today) on its control grid with the
predicted tank use (R·w/10⁴ per metre sprayed) and the predicted energy (hover power of the current
mass × (1 + ``battery.plan_margin``) × time, plus the way home: the distance to the base at
``spray.transit_speed_mps`` plus acceleration and the descent; the margin covers what manoeuvres
cost above hover, +2–3 % measured). The sortie ends at the last tick where (a) the tank still holds
``spray.plan_margin`` of its volume and (b) the energy used plus the way home leaves
``battery.reserve_frac`` of the capacity. There the drone stops, flies to the base, lands (a
deliberate phase: the last 1.5 m at 0.3 m/s, the skids touch at ~0.3 m/s, within the crash
detector's 1 m/s for the skids; then motors off), is refilled and gets a fresh battery
(``spray.service_s``), takes off, flies back to the cut point and resumes. A job that fits one
battery and one tank is flown exactly as the plain mission (no base visit). The loop then
integrates the actual flow, mass and energy (:class:`ag_uav.engine.sprayer.Sprayer`); the summary
compares actual with planned and flags a battery below the reserve or a tank that ran dry before the
planned return.
"""

from __future__ import annotations

import dataclasses
import math
import os
from dataclasses import dataclass
from typing import Any

import numpy as np

from numkit.axes import XY

from ..config import Config, ConfigError
from .pattern import mission_swath
from .reference import Reference, RefSample

G = 9.81
#: seg index of the inserted transits to and from the base, and of the time on the ground there
SEG_TRANSIT = -2
SEG_GROUND = -3
#: a sortie's set point stays on the ground this long after the landing before the motors stop
#: (a heavy, slow-motored vehicle lags its descent by centimetres: cut at once, it drops)
LAND_SETTLE_S = 1.5
#: a sortie's landing descends at the climb speed to this height above the ground, then at the
#: landing speed (0.3 m/s): the heavy octocopter, braking from 1.5 m/s at 0.6 m, touched down at
#: about 1 m/s (PX4 likewise slows its landing descent below MPC_LAND_ALT2)
LAND_FLARE_M = 1.5
#: control ticks per piece when the planner walks the single-sortie reference
_WALK_CHUNK = 1 << 16


# ------------------------------------------------------------------------------ energy model
def rotor_power_coeff(figure_of_merit: float, rotor_diameter_m: float,
                      air_density: float) -> float:
    """k in P = k · T^{3/2} (W per N^{3/2}): k = 1 / (FM · sqrt(2 ρ A)), A = π D²/4."""
    area = math.pi * rotor_diameter_m ** 2 / 4.0
    return 1.0 / (figure_of_merit * math.sqrt(2.0 * air_density * area))


def hover_power(mass_kg: float, k: float, avionics_w: float, n_rotors: int = 4) -> float:
    """Electrical hover power (W) of ``n_rotors`` sharing the weight: n·k·(m g/n)^{3/2} + P_av."""
    t = mass_kg * G / n_rotors
    return n_rotors * k * t ** 1.5 + avionics_w


def implied_figure_of_merit(capacity_wh: float = 526.0, hover_min: float = 55.0,
                            mass_kg: float = 6.47, rotor_diameter_m: float = 0.533,
                            air_density: float = 1.225, avionics_w: float = 25.0) -> float:
    """The FM for which ``capacity_wh`` hovers ``mass_kg`` for ``hover_min`` minutes."""
    p_total = capacity_wh / (hover_min / 60.0)
    area = math.pi * rotor_diameter_m ** 2 / 4.0
    ideal = 4.0 * (mass_kg * G / 4.0) ** 1.5 / math.sqrt(2.0 * air_density * area)
    return ideal / (p_total - avionics_w)


def rotor_counts(cfg: Config) -> tuple[float, float]:
    """``(n, Σe)``: the frame's rotors and their total thrust per unit of a common command (a
    coaxial pair's lower rotor counts its efficiency): in hover each rotor's command is
    ``m g / Σe`` and the rotors draw ``n k (m g / Σe)^{3/2}``."""
    from ..config.vehicles import FRAME_ROTORS, rotor_thrust_sum

    v = cfg.vehicle
    return float(FRAME_ROTORS[v.frame]), rotor_thrust_sum(v.frame, v.coaxial_efficiency)


def hover_endurance_min(cfg: Config, mass_kg: float) -> float:
    """Minutes the full battery hovers ``mass_kg`` (no reserve) on ``cfg``'s frame."""
    b = cfg.battery
    k = rotor_power_coeff(b.figure_of_merit, b.rotor_diameter_m, b.air_density_kgm3)
    n, se = rotor_counts(cfg)
    return 60.0 * b.capacity_wh / (n * k * (mass_kg * G / se) ** 1.5 + b.avionics_w)


def base_point(cfg: Config, field, takeoff_xy) -> np.ndarray:
    """``spray.base``, or the field corner (exterior vertex) nearest the take-off point."""
    if not isinstance(cfg.spray.base, str):
        return np.asarray(cfg.spray.base, float)
    ext = np.asarray(field.exterior, float)[:, XY]
    d = np.hypot(*(ext - np.asarray(takeoff_xy, float)[XY]).T)
    return ext[int(np.argmin(d))].copy()


def liquid_l_per_m(cfg: Config) -> float:
    """Litres per metre of sprayed track: R · w / 10⁴ (w: the mission's lane spacing,
    :func:`ag_uav.world.pattern.mission_swath`)."""
    return cfg.spray.rate_l_per_ha * mission_swath(cfg) / 1e4


# ------------------------------------------------------------------------------ the job
@dataclass
class Sortie:
    """One planned sortie: its time span in the job reference and the predicted use."""

    index: int
    t_start: float               # take-off (s, job time)
    t_end: float                 # landing at the base, or the end of the job
    cut_xy: list[float] | None   # where it stopped spraying to go home (None: the job's end)
    litres: float                # predicted litres sprayed
    energy_wh: float             # predicted battery energy used
    returns: bool                # lands at the base at the end


@dataclass
class SprayJob:
    """The sortie plan of a spray job (what :class:`ChainedReference` flies)."""

    base_xy: np.ndarray
    sorties: list[Sortie]
    fill_l: float                # litres each sortie takes off with (:func:`sortie_fill`)
    dry_mass_kg: float
    service_s: float
    tank_l: float | None = None  # the tank's volume (None: ``fill_l``)

    def summary(self) -> dict[str, Any]:
        out = {
            "base_xy": [round(float(v), 3) for v in self.base_xy],
            "sorties_planned": len(self.sorties),
            "litres_planned": round(sum(s.litres for s in self.sorties), 4),
            "energy_planned_wh": round(sum(s.energy_wh for s in self.sorties), 2),
        }
        if self.tank_l is not None and self.fill_l < self.tank_l:
            out["fill_l"] = round(self.fill_l, 3)  # a part-filled tank: the battery binds
        return out


class ChainedReference:
    """Sorties flown one after another, with ``service_s`` on the ground between them.

    Same interface as :class:`~ag_uav.world.reference.Reference` for the loop (``sample``,
    ``sample_all``, ``duration``); ``sample_all`` adds ``sortie`` (int) and ``ground`` (bool:
    landed at the base, motors off). Plan-segment indices are mapped back to the original plan's,
    so a leg split between two sorties keeps its index; inserted transits have seg
    :data:`SEG_TRANSIT`, the time on the ground :data:`SEG_GROUND`, climbs and descents −1.
    """

    def __init__(self, pieces: list[tuple[Reference, np.ndarray]], service_s: float,
                 job: SprayJob):
        self.pieces = pieces
        self.service_s = float(service_s)
        self.job = job
        self.spray_job = job
        t0 = []
        t = 0.0
        for i, (ref, _m) in enumerate(pieces):
            t0.append(t)
            t += ref.duration + (self.service_s if i < len(pieces) - 1 else 0.0)
        self.t0 = np.array(t0)
        self.duration = float(t)
        self.rate = pieces[0][0].rate

    def _map(self, seg: np.ndarray, m: np.ndarray) -> np.ndarray:
        out = np.where(seg >= 0, m[np.clip(seg, 0, len(m) - 1)], seg)
        return out.astype(int)

    def sortie_ground(self, times) -> tuple[np.ndarray, np.ndarray]:
        """The sortie (int) flown at each of ``times`` and whether the vehicle is then on the
        ground at the base (bool: after its sortie's reference ends, before the next starts)."""
        t = np.asarray(times, float)
        piece = np.clip(np.searchsorted(self.t0, t, side="right") - 1, 0, len(self.pieces) - 1)
        ends = np.array([ref.duration for ref, _m in self.pieces])
        ground = (t - self.t0[piece] > ends[piece]) & (piece < len(self.pieces) - 1)
        return piece, ground

    def sample_all(self, times) -> dict[str, np.ndarray]:
        t = np.asarray(times, float)
        n = len(t)
        out = {"pos": np.zeros((n, 3)), "vel": np.zeros((n, 3)), "acc": np.zeros((n, 3)),
               "yaw": np.zeros(n), "yaw_rate": np.zeros(n), "spray": np.zeros(n, bool),
               "seg": np.zeros(n, int)}
        piece, ground = self.sortie_ground(t)
        out["sortie"], out["ground"] = piece.astype(int), ground
        for i, (ref, m) in enumerate(self.pieces):
            sel = np.flatnonzero(piece == i)
            if not sel.size:
                continue
            tl = t[sel] - self.t0[i]
            tab = ref.sample_all(np.minimum(tl, ref.duration))
            for key in ("pos", "vel", "acc", "yaw", "yaw_rate", "spray"):
                out[key][sel] = tab[key]
            seg = self._map(tab["seg"], m)
            seg[ground[sel]] = SEG_GROUND
            out["seg"][sel] = seg
        # the ground hold: at rest where the sortie landed
        g = out["ground"]
        out["vel"][g] = 0.0
        out["acc"][g] = 0.0
        out["yaw_rate"][g] = 0.0
        out["spray"][g] = False
        return out

    def sample(self, t: float) -> RefSample:
        tab = self.sample_all(np.array([t]))
        return RefSample(tab["pos"][0], tab["vel"][0], tab["acc"][0], float(tab["yaw"][0]),
                         float(tab["yaw_rate"][0]), bool(tab["spray"][0]), int(tab["seg"][0]))


def _split_at(points: np.ndarray, q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Split polyline ``points`` at its point nearest to ``q``: (head to it, tail from it)."""
    a, b = points[:-1], points[1:]
    ab = b - a
    l2 = np.maximum(np.einsum("ij,ij->i", ab, ab), 1e-18)
    tp = np.clip(np.einsum("ij,ij->i", q[None, XY] - a, ab) / l2, 0.0, 1.0)
    proj = a + tp[:, None] * ab
    j = int(np.argmin(np.hypot(*(proj - q[None, XY]).T)))
    p = proj[j]
    head = np.vstack([points[:j + 1], p[None]])
    tail = np.vstack([p[None], points[j + 1:]])
    return head, tail


def transit_path(a, b, field, clearance: float) -> np.ndarray:
    """Shortest polyline from ``a`` to ``b`` around the field's holes (obstacles), through their
    corners grown by ``clearance`` and never closer than ``clearance``/2 to a hole: a visibility
    graph (Lozano-Pérez & Wesley 1979) searched with Dijkstra. A straight line when nothing is
    in the way."""
    import heapq

    import shapely

    a = np.asarray(a, float)[XY]
    b = np.asarray(b, float)[XY]
    holes = [shapely.Polygon(h) for h in getattr(field, "holes", [])]
    if not holes:
        return np.array([a, b])
    grown = [h.buffer(clearance, join_style="mitre") for h in holes]
    # the no-fly test uses half the clearance, so that end points on a leg that passes a hole at
    # half a swath still see the corners (which are at the full clearance)
    solid = shapely.union_all([h.buffer(0.5 * clearance, join_style="mitre") for h in holes])

    def visible(p, q) -> bool:
        return not shapely.LineString([p, q]).intersects(solid)

    if visible(a, b):
        return np.array([a, b])
    nodes = [a, b]
    for g in grown:
        for poly in getattr(g, "geoms", [g]):
            nodes += [np.asarray(c) for c in list(poly.exterior.coords)[:-1]]
    n = len(nodes)
    dist = [math.inf] * n
    prev = [-1] * n
    dist[0] = 0.0
    heap = [(0.0, 0)]
    while heap:
        d, i = heapq.heappop(heap)
        if d > dist[i]:
            continue
        if i == 1:
            break
        for j in range(n):
            if j == i:
                continue
            w = float(np.hypot(*(nodes[j] - nodes[i])))
            if d + w < dist[j] and visible(nodes[i], nodes[j]):
                dist[j] = d + w
                prev[j] = i
                heapq.heappush(heap, (d + w, j))
    if prev[1] < 0:  # boxed in: fly straight
        return np.array([a, b])
    path = [1]
    while path[-1] != 0:
        path.append(prev[path[-1]])
    return np.array([nodes[i] for i in reversed(path)])


def _seg(kind: str, pts, spray: bool):
    from .plan import Segment

    return Segment(kind, np.asarray(pts, float), spray)


def _walk(ref: Reference, base: np.ndarray, lpm: float, dt: float
          ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(segment, litres sprayed before the tick, distance to the base) on the control grid of
    ``ref``, sampled in pieces so that only these three columns are held."""
    n = int(math.floor(ref.duration / dt)) + 1
    seg = np.empty(n, dtype=np.int64)
    flow = np.empty(n)
    d_home = np.empty(n)
    for a in range(0, n, _WALK_CHUNK):
        b = min(n, a + _WALK_CHUNK)
        tab = ref.sample_all(np.arange(a, b) * dt)
        seg[a:b] = tab["seg"]
        speed = np.hypot(tab["vel"][:, 0], tab["vel"][:, 1])
        flow[a:b] = np.where(tab["spray"], speed, 0.0) * dt * lpm
        d_home[a:b] = np.hypot(*(tab["pos"][:, XY] - base[None]).T)
    litres_cum = np.concatenate([[0.0], np.cumsum(flow)])[:-1]
    return seg, litres_cum, d_home


def plan_job(cfg: Config, plan, ref: Reference, field, *, dry_mass_kg: float,
             z_land: float, truncated: bool = False,
             plan_s: float | None = None) -> tuple[Any, SprayJob]:
    """Split the mission into sorties (see the module docstring).

    Returns ``(reference, job)``: ``ref`` itself (with ``spray_job`` set) when one sortie does
    the job, else a :class:`ChainedReference`. Raises :class:`ConfigError` when the tank or the
    battery cannot make any progress from the base.

    ``truncated``: ``plan`` is the head of a longer plan (:meth:`CoveragePlan.head`, a mission
    cut by ``sim.max_time_s``), so its end is not the job's end: a sortie reaching it must still
    keep its way home at every tick, or it is cut as anywhere else; ``plan_s``: the whole
    plan's length over the mission speed (what :func:`sortie_fill` weighs a head against).
    """
    base = base_point(cfg, field, plan.start)
    dt = 1.0 / cfg.sim.control_hz
    walk = _walk(ref, base, liquid_l_per_m(cfg), dt)
    energy = _energy_model(cfg, dry_mass_kg, z_land)
    fill = sortie_fill(cfg, energy, walk, dt, truncated, plan_s)
    cuts = _cuts(cfg, energy, walk, dt, truncated, fill)
    sp = cfg.spray
    job = SprayJob(base_xy=base, sorties=[], fill_l=fill, dry_mass_kg=dry_mass_kg,
                   service_s=sp.service_s, tank_l=sp.tank_l)
    if len(cuts) == 1:
        _, litres, e_j = cuts[0]
        job.sorties.append(Sortie(0, 0.0, ref.duration, None, litres, e_j / 3600.0, False))
        ref.spray_job = job
        return ref, job
    pieces = _sortie_references(cfg, plan, ref, field, walk[0], cuts, job, z_land)
    return ChainedReference(pieces, sp.service_s, job), job


def _energy_model(cfg: Config, dry_mass_kg: float, z_land: float) -> tuple[Any, Any]:
    """``(t_way, power)``: the predicted time (s) of a way between the base and a point d metres
    away (transit plus a descent or climb and dwells), and the electrical power (W, planning
    margin included) with ``litres_left`` in the tank."""
    sp, b, m = cfg.spray, cfg.battery, cfg.mission
    k_p = rotor_power_coeff(b.figure_of_merit, b.rotor_diameter_m, b.air_density_kgm3)
    rho = sp.density_kg_per_l
    v_tr = sp.transit_speed_mps
    a_max = m.accel_max_mps2
    climb = 1.5  # Reference's default climb speed (m/s)

    drop = m.altitude_m - z_land

    def t_way(d: np.ndarray | float) -> np.ndarray | float:
        """Predicted time (s) of a transit of d metres plus a descent or climb and dwells."""
        return (np.asarray(d) / v_tr + v_tr / a_max
                + max(drop - LAND_FLARE_M, 0.0) / climb + min(drop, LAND_FLARE_M) / 0.3
                + climb / a_max + 3.0 + LAND_SETTLE_S)  # the last metres at 0.3 m/s

    n, se = rotor_counts(cfg)

    def power(litres_left: np.ndarray | float) -> np.ndarray | float:
        mass = dry_mass_kg + np.asarray(litres_left) * rho
        return (n * k_p * (mass * G / se) ** 1.5 + b.avionics_w) * (1.0 + b.plan_margin)

    return t_way, power


def _sortie_run(cfg: Config, energy: tuple[Any, Any],
                walk: tuple[np.ndarray, np.ndarray, np.ndarray], dt: float, i0: int,
                fill: float, e_pre: float, truncated: bool) -> tuple[str, int, Any]:
    """One sortie from tick ``i0`` with ``fill`` litres and ``e_pre`` joules already spent:
    ``("end" | "tank" | "battery", first failing tick (local), (left, e_run, e_home))``.
    Only the ticks one battery can fly are walked (past them the energy test fails anyway:
    every tick costs at least the empty-tank power), so a sortie costs its own length."""
    sp, b = cfg.spray, cfg.battery
    t_way, power = energy
    seg, litres_cum, d_home = walk
    e_use = b.capacity_wh * 3600.0 * (1.0 - b.reserve_frac)  # J
    n = len(seg)
    span = int(math.ceil(e_use / (float(power(0.0)) * dt))) + 2
    hi = n if i0 + span >= n else i0 + span
    left = fill - (litres_cum[i0:hi] - litres_cum[i0])
    p = power(np.maximum(left, 0.0))
    e_run = e_pre + np.concatenate([[0.0], np.cumsum(p[:-1] * dt)])
    e_home = power(np.maximum(left, 0.0)) * t_way(d_home[i0:hi])
    ok = (left >= fill * sp.plan_margin) & (e_run + e_home <= e_use)
    arrays = (left, e_run, e_home)
    # the job's end: no way home needed (the pilot collects the drone where it hovers)
    if hi == n and (ok.all() if truncated else left[-1] >= 0.0 and e_run[-1] <= e_use):
        return "end", hi - i0 - 1, arrays
    if ok.all():  # not reached: the walked ticks cost more than the battery holds
        raise ConfigError(f"battery.capacity_wh = {b.capacity_wh}: the sortie planner's window "
                          "ended before the battery")
    bad = int(np.argmin(ok))  # first tick that fails
    return ("tank" if left[bad] < fill * sp.plan_margin else "battery"), bad, arrays


def sortie_fill(cfg: Config, energy: tuple[Any, Any],
                walk: tuple[np.ndarray, np.ndarray, np.ndarray], dt: float,
                truncated: bool = False, plan_s: float | None = None) -> float:
    """The litres each sortie takes off with: the full tank, unless a sortie with the full
    tank is cut by the battery (the liquid would be ballast); then the least fill with which
    the first sortie is not cut by the tank (the battery's reserve or the job's end comes
    first), rounded up to 0.1 L: the liquid the battery can carry and spray in one sortie, as
    operators fill a drone that cannot fly a full tank empty. Bisection on the fill: the tank
    cut comes later and the battery cut earlier as the fill grows. The head of a longer plan
    (``truncated``) that ends before either cut: the full tank when the whole plan
    (``plan_s`` seconds at the mission speed) is shorter than a full-tank battery, else
    :func:`_fill_by_rate`."""
    full = cfg.spray.tank_l
    kind = _sortie_run(cfg, energy, walk, dt, 0, full, 0.0, truncated)[0]
    if kind == "end" and truncated:
        e_use = cfg.battery.capacity_wh * 3600.0 * (1.0 - cfg.battery.reserve_frac)
        if plan_s is not None and plan_s <= e_use / float(energy[1](full)):
            return full  # the whole job is shorter than a full-tank battery
        return _fill_by_rate(cfg, energy, walk, dt)
    if kind != "battery":
        return full
    lo, hi = 0.0, full
    for _ in range(24):
        mid = 0.5 * (lo + hi)
        if _sortie_run(cfg, energy, walk, dt, 0, mid, 0.0, truncated)[0] == "tank":
            lo = mid
        else:
            hi = mid
    return min(full, math.ceil(hi * 10.0 - 1e-9) / 10.0)


def _fill_by_rate(cfg: Config, energy: tuple[Any, Any],
                  walk: tuple[np.ndarray, np.ndarray, np.ndarray], dt: float) -> float:
    """:func:`sortie_fill` for the head of a longer plan too short to show a full sortie (a
    mission cut by ``sim.max_time_s``): the least fill ``F`` whose tank time at the head's mean
    flow ``q``, ``F (1 − margin) / q``, is no shorter than the battery's time at the power of
    half that fill, ``E_use / P(F/2)`` (the battery binds); the full tank when even it empties
    first."""
    sp, b = cfg.spray, cfg.battery
    power = energy[1]
    litres_cum = walk[1]
    q = float(litres_cum[-1]) / max(len(litres_cum) * dt, dt)
    full = sp.tank_l
    if q <= 0.0:
        return full
    e_use = b.capacity_wh * 3600.0 * (1.0 - b.reserve_frac)

    def tank_first(f: float) -> bool:
        return f * (1.0 - sp.plan_margin) / q < e_use / float(power(0.5 * f))

    if tank_first(full):
        return full
    lo, hi = 0.0, full
    for _ in range(24):
        mid = 0.5 * (lo + hi)
        lo, hi = (mid, hi) if tank_first(mid) else (lo, mid)
    return min(full, math.ceil(hi * 10.0 - 1e-9) / 10.0)


def _cuts(cfg: Config, energy: tuple[Any, Any], walk: tuple[np.ndarray, np.ndarray, np.ndarray],
          dt: float, truncated: bool, fill: float) -> list[tuple[int, float, float]]:
    """Where the sorties end: (tick of the cut, litres, energy J) each, the last at the end of
    the job; ``walk`` from :func:`_walk`, ``energy`` from :func:`_energy_model`, ``fill`` the
    litres each sortie takes off with (:func:`sortie_fill`)."""
    sp, b = cfg.spray, cfg.battery
    t_way, power = energy
    seg, _, d_home = walk  # per tick: plan segment, litres sprayed before, distance to base
    i0 = 0
    cuts: list[tuple[int, float, float]] = []  # (tick of the cut, litres, energy J)
    e_pre = 0.0
    while True:
        if len(cuts) >= sp.max_sorties:
            raise ConfigError(f"spray.max_sorties = {sp.max_sorties}: the job needs more sorties "
                              f"(one {fill:g} L fill sprays {fill / liquid_l_per_m(cfg):.0f} m "
                              "of track)")
        kind, bad, (left, e_run, e_home) = _sortie_run(cfg, energy, walk, dt, i0, fill, e_pre,
                                                       truncated)
        if kind == "end":
            cuts.append((i0 + bad, float(left[0] - left[-1]), float(e_run[-1])))
            return cuts
        k = i0 + bad - 1
        while k > i0 and seg[k] < 0:
            k -= 1
        if k <= i0 + 1:
            what = "spray.tank_l" if kind == "tank" else "battery.capacity_wh"
            val = sp.tank_l if what == "spray.tank_l" else b.capacity_wh
            raise ConfigError(f"{what} = {val}: too small to spray from the base and come back "
                              f"(sortie {len(cuts) + 1})")
        kk = k - i0
        cuts.append((k, float(left[0] - left[kk]), float(e_run[kk] + e_home[kk])))
        i0 = k
        # next sortie: climb at the base and transit out to the cut point, with the fill
        e_pre = float(power(fill) * t_way(d_home[k]))


def _sortie_references(cfg: Config, plan, ref: Reference, field, seg: np.ndarray,
                       cuts: list[tuple[int, float, float]], job: SprayJob,
                       z_land: float) -> list[tuple[Reference, np.ndarray]]:
    """One Reference per sortie on a sub-plan (transit in, the plan from the resume point to
    the cut point, transit out, a short nudge that turns it towards the next resume point), and
    each sub-plan segment's segment of ``plan``; appends the sorties to ``job``."""
    sp, m = cfg.spray, cfg.mission
    dt = 1.0 / cfg.sim.control_hz
    base = job.base_xy
    segs = plan.segments
    made: list[tuple[Any, dict[str, Any], list[int], Any, float, float, bool]] = []
    resume: tuple[int, np.ndarray] | None = None  # (segment, point)
    land_xy = base
    clear = 0.5 * plan.swath  # transits keep half a swath from the holes (obstacles)
    for si, (k, litres, e_j) in enumerate(cuts):
        last = si == len(cuts) - 1
        sub: list = []
        gmap: list[int] = []
        speeds: list[float | None] = []
        if resume is None:
            j_from = 0
            first_pts = None
        else:
            j_from, q = resume
            sub.append(_seg("transit", transit_path(land_xy, q[XY], field, clear), False))
            gmap.append(SEG_TRANSIT)
            speeds.append(sp.transit_speed_mps)
            _, first_pts = _split_at(segs[j_from].points, q)
        j_to = len(segs) - 1 if last else int(seg[k])
        cut_q = None if last else ref.sample_all(np.array([k * dt]))["pos"][0, XY].copy()
        last_pts = _plan_part(segs, j_from, j_to, first_pts, cut_q, sub, gmap, speeds)
        if not last:
            end_xy = np.asarray(last_pts[-1], float)
            land_xy = _home_legs(end_xy, base, field, clear, sp.transit_speed_mps, sub, gmap,
                                 speeds)
            resume = (j_to, end_xy)
        opts = dict(speed=m.speed_mps, altitude=m.altitude_m, a_max=m.accel_max_mps2,
                    takeoff=cfg.sim.takeoff or si > 0,
                    # a take-off from the base starts where the landing left the set point (the
                    # vehicle's resting height, not 0: a tall vehicle would be pushed down)
                    **({"z0": z_land} if si > 0 else {}),
                    hover_time=cfg.sim.hover_after_s if last else LAND_SETTLE_S,
                    rate=cfg.sim.control_hz, landing=not last, z_land=z_land, seg_speeds=speeds,
                    flare_height=LAND_FLARE_M)
        made.append((dataclasses.replace(plan, segments=sub), opts, gmap, cut_q, litres, e_j,
                     last))
    refs = _references([(a[0], a[1]) for a in made])
    pieces: list[tuple[Reference, np.ndarray]] = []
    t_acc = 0.0
    for si, (r, (_, _, gmap, cut_q, litres, e_j, last)) in enumerate(zip(refs, made,
                                                                          strict=True)):
        pieces.append((r, np.asarray(gmap, int)))
        job.sorties.append(Sortie(si, t_acc, t_acc + r.duration,
                                  None if last else [float(v) for v in cut_q], litres,
                                  e_j / 3600.0, not last))
        t_acc += r.duration + sp.service_s
    return pieces


def _references(specs: list[tuple[Any, dict[str, Any]]]) -> list[Reference]:
    """The sorties' references, ``Reference(subplan, **options)`` each, built two at a time in
    threads (numpy's array work runs outside the GIL; each reference is its own object, so the
    results are those of a serial build)."""
    if len(specs) < 2 or (os.cpu_count() or 1) < 2:
        return [Reference(p, **o) for p, o in specs]
    from concurrent.futures import ThreadPoolExecutor

    with ThreadPoolExecutor(max_workers=2) as ex:
        return list(ex.map(lambda spec: Reference(spec[0], **spec[1]), specs))


def _plan_part(segs: list, j_from: int, j_to: int, first_pts: Any, cut_q: Any, sub: list,
               gmap: list[int], speeds: list[float | None]) -> Any:
    """Append the plan's segments ``j_from``..``j_to`` to a sortie's sub-plan, the first from
    ``first_pts`` (the resume point on), the last up to ``cut_q`` (None: whole); the points of
    the cut segment (None when not cut)."""
    last_pts = None
    for j in range(j_from, j_to + 1):
        pts = segs[j].points
        if j == j_from and first_pts is not None:
            pts = first_pts
        if j == j_to and cut_q is not None:
            if j == j_from and first_pts is not None:
                pts, _ = _split_at(first_pts, cut_q)
            else:
                pts, _ = _split_at(pts, cut_q)
            last_pts = pts
        if len(pts) >= 2 and float(np.sum(np.hypot(*np.diff(pts, axis=0).T))) > 1e-6:
            sub.append(dataclasses.replace(segs[j], points=np.asarray(pts, float)))
            gmap.append(j)
            speeds.append(None)
    return last_pts


def _home_legs(end_xy: np.ndarray, base: np.ndarray, field, clear: float, v_tr: float,
               sub: list, gmap: list[int], speeds: list[float | None]) -> np.ndarray:
    """Append the transit home and a 0.5 m nudge towards the next resume point (so that the
    drone lands, and takes off again, facing the way it will fly); the landing point."""
    u = end_xy - base
    nu = float(np.hypot(*u))
    u = u / nu if nu > 1e-9 else np.array([1.0, 0.0])
    land_xy = base + 0.5 * u
    sub.append(_seg("transit", transit_path(end_xy, base, field, clear), False))
    sub.append(_seg("transit", [base, land_xy], False))
    gmap += [SEG_TRANSIT, SEG_TRANSIT]
    speeds += [v_tr, 0.5]
    return land_xy
