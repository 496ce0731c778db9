"""Coverage path planning: headland laps plus boustrophedon sweeps over a :class:`Field`.

Scheme (see Choset, "Coverage path planning: the boustrophedon cellular decomposition", 2000,
and the agricultural headland/track practice in Oksanen & Visala, J. Field Robotics 2009):

1. **Headland.** ``n_headland`` laps run along the inside of the boundary (and around every hole)
   at offsets ``swath/2, 3·swath/2, …`` (mitred offsets, so corners stay square and the laps'
   footprints tile the margin). Default margin = one swath, i.e. one lap.
2. **Interior.** The field shrunk by the headland margin (holes grown by it) is cut into strips of
   equal width ``spacing = W / ceil(W / swath) ≤ swath`` across the sweep direction (``W`` = the
   interior's extent across it). Each strip ∩ interior is split into connected pieces; each piece
   gets one leg on the strip's centre line spanning the piece's whole along-track extent (so
   slanted ends leave no wedge gaps), clipped to the region where the sprayer centre keeps
   ``swath/2`` clear of the boundary and of the obstacles. Legs never cross an obstacle.
3. **Cells.** Legs of adjacent strips whose along-track intervals overlap are linked; a chain of
   one-to-one links is a boustrophedon cell (a split or merge, e.g. at a hole or an L's reflex
   corner, closes cells and opens new ones). Each cell is flown back and forth with U-turns.
4. **Order.** Outer headland laps first, starting at the corner nearest the first sweep leg; then
   hole laps and cells in greedy nearest-entry order (each cell may be entered at any of its four
   corners). Transits between pieces follow the shortest path (visibility graph) inside the
   region that keeps ``swath/2`` clear of boundary and holes, so they never cross a hole.
5. **Turns.** ``turn="arc"``: straight run-out to the farther leg end, then a semicircle of radius
   ``spacing/2`` (falls back to a straight hop when the arc would leave the field, inset by
   ``swath/4``); ``turn="stop"``: straight hop (the vehicle stops at both corners).

6. **Parts.** A multi-part field (:attr:`Field.parts`, e.g. a GeoJSON MultiPolygon) is planned
   part by part (each with its own default direction), the first part first, then greedily the
   part whose plan starts or ends nearest to the current position (a part may be flown in
   reverse). Parts are joined by ``transit`` segments with the sprayer off, along the shortest
   path inside the parts' convex hull grown by one swath that keeps ``swath/2`` clear of every
   hole.

Sweep direction default: the angle that minimises the number of legs (= turns + 1) over candidate
angles: the minimum rotated rectangle's edges, every boundary/hole edge and a 5° sweep; ties go to
fewer cells, then to rectangle/edge-aligned angles. Angles are of the leg heading, degrees
counter-clockwise from east, in [0, 180).
"""

from __future__ import annotations

import dataclasses
import heapq
import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import shapely
from shapely import affinity
from shapely.geometry import LineString, MultiPolygon, Polygon, box
from shapely.ops import polylabel

from .field import Field

__all__ = ["CoveragePlan", "Segment", "plan_coverage"]

KINDS = ("leg", "headland", "turn", "transit")


@dataclass
class Segment:
    """One piece of the plan: ``kind`` in {"leg", "headland", "turn", "transit"}, an (N, 2)
    polyline in local metres (N ≥ 2) and whether the sprayer is on."""

    kind: str
    points: np.ndarray
    spray: bool

    @property
    def length(self) -> float:
        return float(np.sum(np.hypot(*np.diff(self.points, axis=0).T)))


@dataclass
class CoveragePlan:
    """Ordered coverage path. ``segments`` join end to start; ``path`` concatenates them.

    For a multi-part field, ``direction_deg`` is the first part's; ``spacing`` the largest of the
    parts'; ``meta["parts"]`` has each part's direction, legs, cells, spacing and area, and
    ``meta["part_order"]`` the order flown (1-based)."""

    field: Field
    segments: list[Segment]
    swath: float
    spacing: float
    headland: float
    n_headland: int
    direction_deg: float
    legs: int
    cells: int
    interior: Polygon | MultiPolygon
    meta: dict = field(default_factory=dict)

    @property
    def start(self) -> np.ndarray:
        return self.segments[0].points[0].copy()

    @property
    def end(self) -> np.ndarray:
        return self.segments[-1].points[-1].copy()

    @property
    def path(self) -> np.ndarray:
        """Concatenated polyline (M, 2) of all segments (shared joints not repeated)."""
        parts = [self.segments[0].points]
        parts += [s.points[1:] for s in self.segments[1:]]
        return np.concatenate(parts, axis=0)

    @property
    def length(self) -> float:
        return float(sum(s.length for s in self.segments))

    @property
    def spray_length(self) -> float:
        return float(sum(s.length for s in self.segments if s.spray))

    @property
    def turns(self) -> int:
        return sum(1 for s in self.segments if s.kind == "turn")

    def spray_tracks(self) -> list[np.ndarray]:
        """Nominal sprayed stretches: consecutive spraying segments merged into one polyline."""
        out: list[np.ndarray] = []
        cur: list[np.ndarray] = []
        for s in self.segments:
            if s.spray:
                cur.append(s.points if not cur else s.points[1:])
            elif cur:
                out.append(np.concatenate(cur))
                cur = []
        if cur:
            out.append(np.concatenate(cur))
        return out

    def head(self, length_m: float) -> CoveragePlan:
        """The plan's first ``length_m`` metres of path: the segments up to there, the last one
        cut at that arc length (same kinds, spray flags and segment indices), so that a mission
        cut by time is planned and densified only as far as it can fly. ``meta["head_of_m"]``
        is the whole path's length. The plan itself when it is no longer than ``length_m``."""
        total = self.length
        if not length_m < total:
            return self
        segs: list[Segment] = []
        left = float(length_m)
        for sg in self.segments:
            d = np.hypot(*np.diff(sg.points, axis=0).T)
            cum = np.concatenate([[0.0], np.cumsum(d)])
            if cum[-1] < left:
                segs.append(sg)
                left -= float(cum[-1])
                continue
            j = int(np.searchsorted(cum, left, side="left"))  # cum[j-1] < left <= cum[j]
            if left > 1e-6 and j >= 1:
                f = (left - cum[j - 1]) / max(float(d[j - 1]), 1e-12)
                q = sg.points[j - 1] + f * (sg.points[j] - sg.points[j - 1])
                segs.append(Segment(sg.kind, np.vstack([sg.points[:j], q[None]]), sg.spray))
            break
        return dataclasses.replace(self, segments=segs, meta={**self.meta, "head_of_m": total})

    def summary(self) -> str:
        kinds = {k: sum(1 for s in self.segments if s.kind == k) for k in KINDS}
        return (
            f"{self.field.name}: {self.field.area / 1e4:.3f} ha, swath {self.swath:g} m "
            f"(spacing {self.spacing:.2f} m), direction {self.direction_deg:.1f}°, "
            f"{self.legs} legs in {self.cells} cells, {kinds['headland']} headland laps, "
            f"{kinds['turn']} turns, {kinds['transit']} transits, path {self.length:.0f} m "
            f"({self.spray_length:.0f} m spraying)"
        )


# ---------------------------------------------------------------------------------------------
def _polys(g) -> list[Polygon]:
    if g is None or g.is_empty:
        return []
    if isinstance(g, Polygon):
        return [g]
    return [p for p in getattr(g, "geoms", []) if isinstance(p, Polygon) and not p.is_empty]


def _lines(g) -> list[LineString]:
    if g is None or g.is_empty:
        return []
    if isinstance(g, LineString):
        return [g]
    out = []
    for p in getattr(g, "geoms", []):
        out.extend(_lines(p))
    return out


def _offset(poly: Polygon, d: float):
    """Inward (d > 0) mitred offset."""
    return poly.buffer(-d, join_style="mitre", mitre_limit=5.0)


def _rot(xy: np.ndarray, deg: float) -> np.ndarray:
    c, s = math.cos(math.radians(deg)), math.sin(math.radians(deg))
    return xy @ np.array([[c, s], [-s, c]])


def _strip_legs(interior_r, centre_r, swath: float):
    """Legs for an interior already rotated so the sweep runs along +x.

    Returns (spacing, strips) with strips = [(y, [(x0, x1), ...]), ...] bottom to top."""
    polys = _polys(interior_r)
    if not polys:
        return swath, []
    xmin, ymin, xmax, ymax = interior_r.bounds
    w = ymax - ymin
    n = max(1, math.ceil(w / swath - 1e-9))
    sp = w / n if w > 1e-9 else swath
    strips = []
    for k in range(n):
        yc = ymin + (k + 0.5) * sp
        band = box(xmin - 1.0, yc - 0.5 * sp - 1e-9, xmax + 1.0, yc + 0.5 * sp + 1e-9)
        ivs: list[tuple[float, float]] = []
        for pc in _polys(interior_r.intersection(band)):
            if pc.area < 1e-6:
                continue
            x0, _, x1, _ = pc.bounds
            line = LineString([(x0, yc), (x1, yc)])
            for ls in _lines(line.intersection(centre_r)):
                xs = np.asarray(ls.coords)[:, 0]
                a, b = float(xs.min()), float(xs.max())
                if b - a > 0.05:
                    ivs.append((a, b))
        ivs.sort()
        merged: list[list[float]] = []
        for a, b in ivs:
            if merged and a <= merged[-1][1] + 1e-6:
                merged[-1][1] = max(merged[-1][1], b)
            else:
                merged.append([a, b])
        strips.append((yc, [(a, b) for a, b in merged]))
    return sp, strips


def _cells(strips) -> list[list[tuple[float, float, float]]]:
    """Boustrophedon cells: chains of legs linked one-to-one between adjacent strips."""
    cells: list[list[tuple[float, float, float]]] = []
    prev: list[tuple[float, float]] = []
    prev_cell: list[int] = []
    for yc, ivs in strips:
        cur_cell = [-1] * len(ivs)
        if prev:
            links = [[j for j, p in enumerate(prev) if min(p[1], b) - max(p[0], a) > 0.0]
                     for a, b in ivs]
            succ_count = [0] * len(prev)
            for lk in links:
                for j in lk:
                    succ_count[j] += 1
            for i, lk in enumerate(links):
                if len(lk) == 1 and succ_count[lk[0]] == 1:
                    cur_cell[i] = prev_cell[lk[0]]
        for i, (a, b) in enumerate(ivs):
            if cur_cell[i] < 0:
                cells.append([])
                cur_cell[i] = len(cells) - 1
            cells[cur_cell[i]].append((yc, a, b))
        prev, prev_cell = ivs, cur_cell
    return cells


def _evaluate_direction(interior, centre, swath, deg):
    ir = affinity.rotate(interior, -deg, origin=(0, 0))
    cr = affinity.rotate(centre, -deg, origin=(0, 0))
    sp, strips = _strip_legs(ir, cr, swath)
    n_legs = sum(len(iv) for _, iv in strips)
    return n_legs, sp, strips


def _candidate_angles(poly: Polygon) -> list[tuple[float, int]]:
    cands: list[tuple[float, int]] = []
    mrr = poly.minimum_rotated_rectangle
    if isinstance(mrr, Polygon):
        c = np.asarray(mrr.exterior.coords)
        for p, q in zip(c[:-1], c[1:], strict=True):
            if np.hypot(*(q - p)) > 1e-6:
                cands.append((math.degrees(math.atan2(q[1] - p[1], q[0] - p[0])), 0))
    for ring in [poly.exterior, *poly.interiors]:
        c = np.asarray(ring.coords)
        for p, q in zip(c[:-1], c[1:], strict=True):
            if np.hypot(*(q - p)) > 1.0:
                cands.append((math.degrees(math.atan2(q[1] - p[1], q[0] - p[0])), 1))
    cands += [(float(a), 2) for a in range(0, 180, 5)]
    out: dict[float, int] = {}
    for a, pr in cands:
        a = round(a % 180.0, 4) % 180.0
        out[a] = min(pr, out.get(a, 9))
    return sorted(out.items())


# --- transits (visibility graph in the free region) ------------------------------------------
class _Free:
    """Shortest paths inside a polygonal region (visibility graph over its vertices)."""

    def __init__(self, region):
        self.region = region
        self.check = region.buffer(1e-3)
        shapely.prepare(self.check)
        verts = []
        for p in _polys(region):
            for ring in [p.exterior, *p.interiors]:
                c = np.asarray(ring.simplify(0.05).coords)[:-1]
                verts.extend(map(tuple, c))
        self.verts = np.asarray(verts, float).reshape(-1, 2)
        self._adj: list[list[tuple[int, float]]] | None = None

    def visible(self, a, b) -> bool:
        if np.hypot(b[0] - a[0], b[1] - a[1]) < 1e-9:
            return True
        return bool(self.check.covers(LineString([tuple(a), tuple(b)])))

    def _graph(self):
        if self._adj is None:
            n = len(self.verts)
            self._adj = [[] for _ in range(n)]
            for i in range(n):
                for j in range(i + 1, n):
                    if self.visible(self.verts[i], self.verts[j]):
                        d = float(np.hypot(*(self.verts[i] - self.verts[j])))
                        self._adj[i].append((j, d))
                        self._adj[j].append((i, d))
        return self._adj

    def path(self, a, b) -> np.ndarray:
        a = np.asarray(a, float)
        b = np.asarray(b, float)
        if self.visible(a, b):
            return np.array([a, b])
        adj = self._graph()
        n = len(self.verts)
        va = [(i, float(np.hypot(*(self.verts[i] - a)))) for i in range(n)
              if self.visible(a, self.verts[i])]
        vb = {i: float(np.hypot(*(self.verts[i] - b))) for i in range(n)
              if self.visible(self.verts[i], b)}
        dist = {i: d for i, d in va}
        prev: dict[int, int] = {}
        heap = [(d, i) for i, d in va]
        heapq.heapify(heap)
        best, best_i = math.inf, -1
        done = set()
        while heap:
            d, i = heapq.heappop(heap)
            if i in done or d > dist.get(i, math.inf):
                continue
            done.add(i)
            if d >= best:
                break
            if i in vb and d + vb[i] < best:
                best, best_i = d + vb[i], i
            for j, w in adj[i]:
                nd = d + w
                if nd < dist.get(j, math.inf):
                    dist[j] = nd
                    prev[j] = i
                    heapq.heappush(heap, (nd, j))
        if best_i < 0:  # disconnected free space: straight line (documented shortcut)
            return np.array([a, b])
        chain = [best_i]
        while chain[-1] in prev:
            chain.append(prev[chain[-1]])
        pts = [a] + [self.verts[i] for i in reversed(chain)] + [b]
        return np.array(pts)


def _semicircle_turn(e, s, h, step=0.25):
    """Run-out to the farther end along heading ``h``, then a semicircle to the next leg."""
    ue, us = float(e @ h), float(s @ h)
    m = max(ue, us)
    e2 = e + (m - ue) * h
    s2 = s + (m - us) * h
    d = s2 - e2
    r = 0.5 * float(np.hypot(*d))
    pts = [e]
    if m - ue > 1e-6:
        pts.append(e2)
    if r > 1e-6:
        nh = d / (2 * r)
        c = 0.5 * (e2 + s2)
        k = max(8, math.ceil(math.pi * r / step))
        th = np.linspace(0.0, math.pi, k + 1)[1:]
        arc = c + r * (np.sin(th)[:, None] * h - np.cos(th)[:, None] * nh)
        pts.extend(arc)
    if m - us > 1e-6:
        pts.append(s)
    else:
        pts[-1] = s
    return np.array(pts)


def _ring_from(coords: np.ndarray, target: np.ndarray, overrun: float) -> np.ndarray:
    """Closed ring starting at the vertex nearest ``target``, plus an overrun along edge 1."""
    c = np.asarray(coords)[:-1]
    i = int(np.argmin(np.hypot(*(c - target).T)))
    c = np.roll(c, -i, axis=0)
    ring = np.vstack([c, c[:1]])
    if overrun > 0:
        d = c[1] - c[0]
        ln = float(np.hypot(*d))
        if ln > 1e-9:
            ring = np.vstack([ring, c[0] + d * min(overrun, 0.5 * ln) / ln])
    return ring


# ---------------------------------------------------------------------------------------------
def plan_coverage(
    field: Field,
    swath: float = 6.0,
    headland: float | None = None,
    direction_deg: float | None = None,
    n_headland: int | None = None,
    turn: str = "arc",
) -> CoveragePlan:
    """Plan headland laps + boustrophedon legs over ``field``.

    Args:
        field: the field (local metres).
        swath: spray swath width (m), > 0.
        headland: headland margin (m) swept by laps; default ``n_headland·swath`` or one swath.
        direction_deg: leg heading (deg CCW from east); default minimises the number of turns.
        n_headland: number of headland laps; default ``ceil(headland / swath)``.
        turn: "arc" (run-out + semicircle U-turns) or "stop" (straight hop, stop at corners).

    Raises:
        ValueError: swath ≤ 0, negative headland, unknown turn style, or no pass fits.
    """
    if not (isinstance(swath, (int, float)) and math.isfinite(swath) and swath > 0):
        raise ValueError(f"swath must be a positive number of metres, got {swath!r}")
    if turn not in ("arc", "stop"):
        raise ValueError(f"turn must be 'arc' or 'stop', got {turn!r}")
    if n_headland is not None and (int(n_headland) != n_headland or n_headland < 0):
        raise ValueError(f"n_headland must be a non-negative integer, got {n_headland!r}")
    if headland is None:
        headland = swath * (n_headland if n_headland is not None else 1)
    if not math.isfinite(headland) or headland < 0:
        raise ValueError(f"headland margin must be ≥ 0 m, got {headland!r}")
    if n_headland is None:
        n_headland = math.ceil(headland / swath - 1e-9)
    n_headland = int(n_headland)
    if len(field.parts) > 1:
        return _plan_parts(field, swath, headland, direction_deg, n_headland, turn)
    return _plan_single(field, swath, headland, direction_deg, n_headland, turn)


def _reversed_segments(segs: list[Segment]) -> list[Segment]:
    """The same path flown backwards."""
    return [Segment(s.kind, s.points[::-1].copy(), s.spray) for s in reversed(segs)]


def _plan_parts(field: Field, swath: float, headland: float, direction_deg: float | None,
                n_headland: int, turn: str) -> CoveragePlan:
    """Plan every part of a multi-part field and join the parts with spray-off transits."""
    plans = []
    for k, part in enumerate(field.parts):
        sub = Field(part, name=f"{field.name}[{k + 1}]", origin=field.origin)
        try:
            plans.append(_plan_single(sub, swath, headland, direction_deg, n_headland, turn))
        except ValueError as e:
            raise ValueError(f"part {k + 1} of {len(field.parts)}: {e}") from None
    holes = [Polygon(h) for p in field.parts for h in p.interiors]
    region = field.polygon.convex_hull.buffer(swath, join_style="mitre")
    if holes:
        region = region.difference(shapely.union_all(holes).buffer(0.5 * swath))
    if not isinstance(region, Polygon):  # holes cut the hull apart: keep the piece with most area
        region = max(_polys(region), key=lambda g: g.area)
    free = _Free(region)
    order = [0]
    segments: list[Segment] = list(plans[0].segments)
    left = set(range(1, len(plans)))
    while left:
        pos = segments[-1].points[-1]
        best = None
        for k in sorted(left):
            for rev in (False, True):
                entry = plans[k].end if rev else plans[k].start
                d = float(np.hypot(*(entry - pos)))
                if best is None or d < best[0]:
                    best = (d, k, rev)
        _, k, rev = best
        left.discard(k)
        order.append(k)
        segs = _reversed_segments(plans[k].segments) if rev else list(plans[k].segments)
        a, b = segments[-1].points[-1], segs[0].points[0]
        segments.append(Segment("transit", free.path(a, b), False))
        segments += segs
    first = plans[0]
    return CoveragePlan(
        field=field,
        segments=segments,
        swath=float(swath),
        spacing=float(max(p.spacing for p in plans)),
        headland=float(headland),
        n_headland=n_headland,
        direction_deg=float(first.direction_deg),
        legs=sum(p.legs for p in plans),
        cells=sum(p.cells for p in plans),
        interior=shapely.union_all([p.interior for p in plans]),
        meta={"parts": [{"part": k + 1, "direction_deg": p.direction_deg, "legs": p.legs,
                         "cells": p.cells, "spacing": p.spacing, "area_m2": p.field.area}
                        for k, p in enumerate(plans)],
              "part_order": [k + 1 for k in order]},
    )


def _plan_single(field: Field, swath: float, headland: float, direction_deg: float | None,
                 n_headland: int, turn: str) -> CoveragePlan:
    """:func:`plan_coverage` of a one-part field (arguments already checked)."""
    poly = field.polygon
    centre, interior = _centre_and_interior(poly, swath, headland)
    ang, sp, strips = _direction(poly, interior, centre, swath, direction_deg)
    cells = _cells(strips)
    n_legs = sum(len(c) for c in cells)
    b = _Builder(poly, centre, swath, ang, turn)
    # first cell entry (lowest strip, left end) → start corner
    first_cell = min(range(len(cells)), key=lambda i: (cells[i][0][0], cells[i][0][1]))
    y0, a0, _ = cells[first_cell][0]
    target = b.world(a0, y0)

    # --- headland laps: outer rings first, hole rings as greedy tasks ---
    hole_rings: list[np.ndarray] = []
    outer_rings: list[np.ndarray] = []
    for k in range(n_headland):
        g = _offset(poly, (k + 0.5) * swath)
        for p in _polys(g):
            p = p.simplify(0.01)
            outer_rings.append(np.asarray(p.exterior.coords))
            hole_rings.extend(np.asarray(r.coords) for r in p.interiors)
    pos = target
    for ring in outer_rings:
        pos = b.lap(ring, pos)

    # --- greedy over hole laps and cells ---
    cell_done = [False] * len(cells)
    hole_done = [False] * len(hole_rings)
    if not b.segments:
        pos = target
    while not (all(cell_done) and all(hole_done)):
        what, i, opt = _nearest_task(b, hole_rings, hole_done, cells, cell_done, pos)
        if what == "hole":
            hole_done[i] = True
            pos = b.lap(hole_rings[i], pos)
            continue
        cell_done[i] = True
        pos = b.cell(cells[i], *opt)

    return CoveragePlan(
        field=field,
        segments=b.segments,
        swath=float(swath),
        spacing=float(sp),
        headland=float(headland),
        n_headland=n_headland,
        direction_deg=float(ang),
        legs=n_legs,
        cells=len(cells),
        interior=interior,
    )


def _centre_and_interior(poly: Polygon, swath: float, headland: float) -> tuple[Any, Any]:
    """The field shrunk by half a swath (where pass centres may go) and by the headland
    margin (where the legs go); ValueError when either is empty."""
    centre = _offset(poly, 0.5 * swath)
    if centre.is_empty or centre.area < 1e-6:
        c = polylabel(poly, tolerance=0.05)
        width = 2.0 * poly.boundary.distance(c)
        raise ValueError(
            f"swath {swath:g} m is wider than the field (largest inscribed circle ≈ {width:.1f} m "
            "across): no pass fits"
        )
    interior = _offset(poly, headland) if headland > 0 else poly
    if interior.is_empty or interior.area < 1e-6:
        raise ValueError(
            f"no sweep leg fits: the field shrunk by the {headland:g} m headland margin is empty; "
            "reduce the headland or the swath"
        )
    return centre, interior


def _direction(poly: Polygon, interior: Any, centre: Any, swath: float,
               direction_deg: float | None) -> tuple[float, float, Any]:
    """The sweep direction (the given one, else the candidate with the fewest legs, then
    cells), its pass spacing and strips."""
    if direction_deg is not None:
        ang = float(direction_deg) % 180.0
        n_legs, sp, strips = _evaluate_direction(interior, centre, swath, ang)
        if n_legs == 0:
            raise ValueError(f"no sweep leg fits in the interior at direction {ang:g}°; "
                             "reduce the headland or the swath")
        return ang, sp, strips
    best = None
    for ang, prio in _candidate_angles(poly):
        n_legs, sp, strips = _evaluate_direction(interior, centre, swath, ang)
        if n_legs == 0:
            continue
        n_cells = len(_cells(strips))
        key = (n_legs, n_cells, prio, ang)
        if best is None or key < best[0]:
            best = (key, ang, sp, strips)
    if best is None:
        raise ValueError("no sweep leg fits in the interior at any direction; "
                         "reduce the headland or the swath")
    _, ang, sp, strips = best
    return ang, sp, strips


def _nearest_task(b: _Builder, hole_rings: list[np.ndarray], hole_done: list[bool],
                  cells: list, cell_done: list[bool], pos: np.ndarray) -> tuple[str, int, Any]:
    """The next task, greedily: the hole lap or cell entry (either end, either side) nearest
    to ``pos``: ``("hole", i, None)`` or ``("cell", i, (reversed, from_left))``."""
    best = None
    for i, ring in enumerate(hole_rings):
        if not hole_done[i]:
            c = ring[:-1]
            d = float(np.min(np.hypot(*(c - pos).T)))
            if best is None or d < best[0]:
                best = (d, "hole", i, None)
    for i, cell in enumerate(cells):
        if cell_done[i]:
            continue
        for rev in (False, True):
            yc, x_a, x_b = cell[-1] if rev else cell[0]  # the first strip: (y, x from, x to)
            for left in (True, False):
                e = b.world(x_a if left else x_b, yc)
                d = float(np.hypot(*(e - pos)))
                if best is None or d < best[0]:
                    best = (d, "cell", i, (rev, left))
    _, kind, i, how = best
    return kind, i, how


class _Builder:
    """The plan's segments as they are laid down, in the world frame, with the transits
    between them (around holes) and the turns between legs."""

    def __init__(self, poly: Polygon, centre: Any, swath: float, ang: float, turn: str):
        self.ang, self.turn = ang, turn
        th = math.radians(ang)
        self.ex = np.array([math.cos(th), math.sin(th)])
        self.free = _Free(centre if isinstance(centre, Polygon) else poly.buffer(-0.05))
        self.allowed = poly.buffer(-0.25 * swath)
        shapely.prepare(self.allowed)
        self.overrun = 0.5 * swath
        self.segments: list[Segment] = []

    def world(self, x: float, y: float) -> np.ndarray:
        return _rot(np.array([[x, y]]), self.ang)[0]

    def add(self, kind: str, pts: Any, spray: bool) -> None:
        pts = np.asarray(pts, float)
        if len(pts) >= 2 and float(np.sum(np.hypot(*np.diff(pts, axis=0).T))) > 1e-6:
            keep = np.ones(len(pts), bool)
            keep[1:] = np.hypot(*np.diff(pts, axis=0).T) > 1e-9
            self.segments.append(Segment(kind, pts[keep], spray))

    def goto(self, p: np.ndarray) -> None:
        if self.segments:
            a = self.segments[-1].points[-1]
            if np.hypot(*(a - p)) > 1e-6:
                self.add("transit", self.free.path(a, p), False)

    def lap(self, ring: np.ndarray, pos: np.ndarray) -> np.ndarray:
        """A headland lap of ``ring`` from the point nearest ``pos``; where it ends."""
        lap = _ring_from(ring, pos, self.overrun)
        self.goto(lap[0])
        self.add("headland", lap, True)
        return lap[-1]

    def cell(self, cell: list, rev: bool, left: bool) -> np.ndarray:
        """The legs of a cell (from its last strip when ``rev``, starting at the left end when
        ``left``), joined by turns; where they end."""
        ex = self.ex
        legs = cell[::-1] if rev else cell
        fwd = left
        prev_end = None
        for yc, a, b in legs:
            p0 = self.world(a, yc) if fwd else self.world(b, yc)
            p1 = self.world(b, yc) if fwd else self.world(a, yc)
            if prev_end is None:
                self.goto(p0)
            else:
                h = -ex if fwd else ex  # heading of the previous leg
                tpts = None
                if self.turn == "arc":
                    tpts = _semicircle_turn(prev_end, p0, h)
                    if not self.allowed.covers(LineString(tpts)):
                        tpts = None
                if tpts is None:
                    tpts = self.free.path(prev_end, p0)
                self.add("turn", tpts, False)
            self.add("leg", [p0, p1], True)
            prev_end = p1
            fwd = not fwd
        return prev_end
