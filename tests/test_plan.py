"""Tests for ag_uav.world.plan: coverage of the nominal path, direction choice, validation."""

import math

import numpy as np
import pytest
from shapely import affinity
from shapely.geometry import LineString, Polygon

from ag_uav.analysis.coverage import spray_coverage
from ag_uav.world.field import BUILTIN_FIELDS, Field, load_field
from ag_uav.world.plan import KINDS, plan_coverage

SINGLE_PART = [n for n in BUILTIN_FIELDS if n != "two-part"]  # two-part: tests/test_fields_io.py


@pytest.fixture(scope="module", params=SINGLE_PART)
def planned(request):
    f = load_field(request.param)
    return f, plan_coverage(f)


def test_nominal_path_covers_field(planned):
    f, p = planned
    cov, ov = spray_coverage(f, p.spray_tracks(), p.swath)
    assert cov >= 0.99
    assert 0.0 <= ov < 0.15


def test_plan_structure(planned):
    f, p = planned
    assert p.legs >= 8
    assert p.legs == sum(1 for s in p.segments if s.kind == "leg")
    for a, b in zip(p.segments[:-1], p.segments[1:], strict=True):
        assert np.allclose(a.points[-1], b.points[0], atol=1e-6)
    for s in p.segments:
        assert s.kind in KINDS
        assert s.points.shape[1] == 2 and len(s.points) >= 2
        assert s.spray == (s.kind in ("leg", "headland"))
    assert np.allclose(p.start, p.path[0])
    # the whole path stays inside the field and never crosses a hole
    inside = f.polygon.buffer(1e-6)
    for s in p.segments:
        assert inside.covers(LineString(s.points)), s.kind
    for h in f.polygon.interiors:
        hole = Polygon(h)
        assert not any(LineString(s.points).intersects(hole.buffer(-1e-6)) for s in p.segments)
    # the start is at a corner of the first headland lap
    lap0 = f.polygon.buffer(-p.swath / 2, join_style="mitre")
    corners = np.asarray(lap0.exterior.coords)
    assert np.min(np.hypot(*(corners - p.start).T)) < 1e-6


def test_default_field_size():
    f = load_field("default")
    p = plan_coverage(f)
    assert f.area >= 1e4 and p.legs >= 8


@pytest.mark.parametrize("angle", [0.0, 30.0, 125.0])
def test_direction_minimises_turns_on_long_thin_rectangle(angle):
    rect = Polygon([(0, 0), (200, 0), (200, 30), (0, 30)])
    rect = affinity.rotate(rect, angle, origin=(0, 0))
    f = Field.from_coords(np.asarray(rect.exterior.coords))
    p = plan_coverage(f, swath=6.0)
    d = abs((p.direction_deg - angle + 90.0) % 180.0 - 90.0)
    assert d < 1e-3
    across = plan_coverage(f, swath=6.0, direction_deg=angle + 90.0)
    assert p.legs < across.legs
    assert p.legs == math.ceil((30 - 12) / 6)


def test_stop_turns_and_more_headland_laps():
    f = load_field("l-shape")
    p = plan_coverage(f, turn="stop", n_headland=2)
    assert sum(1 for s in p.segments if s.kind == "headland") == 2
    assert p.headland == pytest.approx(12.0)
    for s in p.segments:
        if s.kind == "turn":
            assert len(s.points) <= 4
    cov, _ = spray_coverage(f, p.spray_tracks(), p.swath)
    assert cov >= 0.99


def test_holes_split_legs_into_cells():
    f = Field.from_coords([(0, 0), (120, 0), (120, 80), (0, 80)],
                          holes=[[(50, 30), (70, 30), (70, 50), (50, 50)]])
    p = plan_coverage(f, swath=5.0, direction_deg=0.0)
    assert p.cells >= 3
    cov, _ = spray_coverage(f, p.spray_tracks(), p.swath)
    assert cov >= 0.99


def test_invalid_inputs():
    f = Field.from_coords([(0, 0), (50, 0), (50, 40), (0, 40)])
    for bad in (0.0, -1.0, float("nan")):
        with pytest.raises(ValueError, match="swath"):
            plan_coverage(f, swath=bad)
    with pytest.raises(ValueError, match="wider than the field"):
        plan_coverage(f, swath=100.0)
    with pytest.raises(ValueError, match="no sweep leg fits"):
        plan_coverage(f, swath=6.0, headland=25.0)
    with pytest.raises(ValueError, match="turn"):
        plan_coverage(f, turn="loop")
    with pytest.raises(ValueError, match="headland"):
        plan_coverage(f, headland=-1.0)
