"""Tests for ag_uav.world.field: geodetic conversion, GeoJSON loading, validation, built-in
fields."""

import math

import numpy as np
import pytest

from ag_uav.world.field import (
    BUILTIN_FIELDS,
    WGS84_A,
    WGS84_E2,
    Field,
    enu_to_lonlat,
    load_field,
    lonlat_to_enu,
)


def _ellipsoid_box_area(lat1, lat2, lon1, lon2):
    """Exact area of a lat/lon box on the WGS-84 ellipsoid (authalic-latitude formula)."""
    e = math.sqrt(WGS84_E2)
    b2 = WGS84_A**2 * (1 - WGS84_E2)

    def q(lat):
        s = math.sin(math.radians(lat))
        return s / (1 - WGS84_E2 * s * s) + math.log((1 + e * s) / (1 - e * s)) / (2 * e)

    return 0.5 * b2 * math.radians(lon2 - lon1) * (q(lat2) - q(lat1))


def _box_geojson(lat1, lat2, lon1, lon2):
    ring = [[lon1, lat1], [lon2, lat1], [lon2, lat2], [lon1, lat2], [lon1, lat1]]
    return {"type": "Polygon", "coordinates": [ring]}


def test_geojson_area_matches_ellipsoid_area():
    lat1, lat2, lon1, lon2 = 46.730, 46.731, -117.0015, -117.0000
    f = Field.from_geojson(_box_geojson(lat1, lat2, lon1, lon2))
    exact = _ellipsoid_box_area(lat1, lat2, lon1, lon2)
    assert 1e4 < exact < 2e4
    assert abs(f.area - exact) / exact < 1e-3
    assert abs(f.area - exact) / exact < 1e-4  # in fact far better than the 0.1 % requirement


def test_north_offset_matches_meridian_radius():
    lat0, lon0 = 46.73, -117.0
    dlat = 1e-3
    enu = lonlat_to_enu(lon0, lat0 + dlat, (lat0, lon0))
    s = math.sin(math.radians(lat0 + dlat / 2))
    m = WGS84_A * (1 - WGS84_E2) / (1 - WGS84_E2 * s * s) ** 1.5
    assert abs(enu[1] - m * math.radians(dlat)) < 1e-3
    assert abs(enu[0]) < 1e-6


def test_enu_round_trip():
    rng = np.random.default_rng(0)
    origin = (46.73, -117.0, 0.0)
    lon = -117.0 + rng.uniform(-0.01, 0.01, 50)
    lat = 46.73 + rng.uniform(-0.01, 0.01, 50)
    enu = lonlat_to_enu(lon, lat, origin)
    lon2, lat2 = enu_to_lonlat(enu[:, 0], enu[:, 1], origin, enu[:, 2])
    assert np.max(np.abs(lon2 - lon)) < 1e-10
    assert np.max(np.abs(lat2 - lat)) < 1e-10


def test_feature_collection_and_origin():
    poly = _box_geojson(46.730, 46.731, -117.0015, -117.0)
    fc = {"type": "FeatureCollection", "features": [
        {"type": "Feature", "properties": {"name": "box"}, "geometry": poly}]}
    f1 = Field.from_geojson(fc)
    assert f1.name == "box"
    # a different origin only translates the field (area unchanged)
    f2 = Field.from_geojson(poly, origin=(46.7305, -117.001))
    assert abs(f1.area - f2.area) / f1.area < 1e-6
    gj = f1.to_geojson()
    f3 = Field.from_geojson(gj)
    assert abs(f3.area - f1.area) / f1.area < 1e-6


@pytest.mark.parametrize("name", BUILTIN_FIELDS)
def test_builtin_fields(name):
    f = load_field(name)
    if name == "two-part":
        assert len(f.parts) == 2 and f.area == pytest.approx(960.0 + 1080.0, rel=1e-4)
    else:
        assert 1.0e4 <= f.area <= 2.0e4 and len(f.parts) == 1
    assert f.polygon.is_valid
    if name == "hole":
        assert len(f.holes) == 1
    if name in ("l-shape", "hole", "two-part"):
        assert f.origin is not None and abs(f.origin[0] - 46.73) < 0.05


def test_holes_are_subtracted():
    f = Field.from_coords([(0, 0), (100, 0), (100, 50), (0, 50)],
                          holes=[[(10, 10), (20, 10), (20, 20), (10, 20)]])
    assert f.area == pytest.approx(5000 - 100)


@pytest.mark.parametrize(
    "outer,holes,match",
    [
        ([(0, 0), (10, 10), (10, 0), (0, 10)], (), "self-intersect|not a valid"),
        ([(0, 0), (10, 0)], (), "at least 3"),
        ([(0, 0), (5, 0), (10, 0)], (), "zero area"),
        ([(0, 0), (10, 0), (10, 10), (0, 10)], [[(20, 20), (30, 20), (30, 30)]], "hole 0"),
    ],
)
def test_invalid_polygons_raise(outer, holes, match):
    with pytest.raises(ValueError, match=match):
        Field.from_coords(outer, holes)


def test_invalid_geojson_raises():
    two = {"type": "FeatureCollection", "features": [
        {"type": "Feature", "geometry": _box_geojson(0, 0.001, 0, 0.001)},
        {"type": "Feature", "geometry": _box_geojson(1, 1.001, 1, 1.001)}]}
    with pytest.raises(ValueError, match="2 polygon features; pick one"):
        Field.from_geojson(two)
    with pytest.raises(ValueError, match="lon, lat"):
        Field.from_geojson({"type": "Polygon", "coordinates": [[[46.7, -117.0], [46.8, -117.0],
                                                                 [46.8, -117.1]]]})
    with pytest.raises(ValueError, match="unknown field"):
        load_field("no-such-field")
