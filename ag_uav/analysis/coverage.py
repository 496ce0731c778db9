"""Spray coverage metric from flown tracks.

Definitions (all areas clipped to the field polygon, holes excluded):

* a **pass** is one contiguous stretch flown with the sprayer on (one polyline in ``tracks``);
* its **footprint** is the polyline buffered by ``swath/2`` on both sides with flat caps (round
  joins), i.e. the ground a boom of width ``swath`` centred on the true position wets;
* **coverage** = area(⋃ footprints ∩ field) / area(field);
* **overlap** (double-covered fraction) = area(⋃_{i<j} (footprint_i ∩ footprint_j) ∩ field) /
  area(field): ground wetted by two or more *different* passes. A pass re-crossing itself (e.g. a
  headland lap's closing overrun) is not counted as double cover.

Efficiency: tracks are first simplified (Douglas–Peucker, ``simplify_tol`` = 5 cm by default;
a jittery track that keeps more than ~1 vertex per metre is simplified further, doubling the
tolerance up to 0.4 m — smooth true tracks are unaffected), only pairs of passes whose bounding
boxes meet are intersected (STRtree), and the pairwise intersections are unioned once.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
import shapely
from shapely.geometry import LineString, Point

from ..world.field import Field

__all__ = ["footprints", "spray_coverage"]


def footprints(tracks: Sequence[np.ndarray], swath: float, simplify_tol: float = 0.05) -> list:
    """Footprint polygons (flat-capped buffers of width ``swath``), one per non-empty pass."""
    out = []
    for tr in tracks:
        a = np.asarray(tr, dtype=float)
        if a.ndim != 2 or len(a) == 0:
            continue
        a = a[:, :2]
        a = a[np.all(np.isfinite(a), axis=1)]
        if len(a) == 0:
            continue
        keep = np.ones(len(a), bool)
        keep[1:] = np.any(np.abs(np.diff(a, axis=0)) > 1e-9, axis=1)
        a = a[keep]
        if len(a) == 1:  # a sprayer blip at one spot: a swath-wide square
            g = Point(a[0]).buffer(0.5 * swath, cap_style="square")
        else:
            raw = LineString(a)
            line = raw.simplify(simplify_tol, preserve_topology=False) if simplify_tol > 0 else raw
            # jittery input (e.g. noisy positions) keeps thousands of vertices after a 5 cm
            # simplification and makes buffering slow: coarsen the tolerance (up to 0.4 m)
            # until there is at most about one vertex per metre of track
            cap = 16 + raw.length
            tol = max(simplify_tol, 0.025)
            while len(line.coords) > cap and tol < 0.4:
                tol *= 2.0
                line = raw.simplify(tol, preserve_topology=False)
            g = line.buffer(0.5 * swath, cap_style="flat", join_style="round", quad_segs=4)
        if not g.is_empty:
            out.append(g)
    return out


def spray_coverage(
    field: Field,
    tracks: Sequence[np.ndarray],
    swath: float,
    simplify_tol: float = 0.05,
) -> tuple[float, float]:
    """(coverage_fraction, overlap_fraction) of ``field`` for the given sprayed ``tracks``.

    Args:
        field: the field.
        tracks: list of (N, 2+) arrays of TRUE positions, each a contiguous spraying stretch.
        swath: swath width (m).
        simplify_tol: Douglas–Peucker tolerance applied to the tracks first (m).
    """
    if swath <= 0:
        raise ValueError(f"swath must be > 0, got {swath}")
    fps = footprints(tracks, swath, simplify_tol)
    area = field.area
    if not fps or area <= 0:
        return 0.0, 0.0
    poly = field.polygon
    union = shapely.union_all(fps)
    covered = union.intersection(poly).area / area
    arr = np.array(fps, dtype=object)
    tree = shapely.STRtree(arr)
    left, right = tree.query(arr, predicate="intersects")
    m = left < right
    if not np.any(m):
        return float(covered), 0.0
    inter = shapely.intersection(arr[left[m]], arr[right[m]])
    inter = [g for g in inter if not g.is_empty and g.area > 0]
    if not inter:
        return float(covered), 0.0
    dbl = shapely.union_all(inter).intersection(poly).area / area
    return float(covered), float(dbl)
