"""The summary's metrics computed a block or a segment at a time equal the whole-array
formulas (ag_uav.analysis.metrics): bit for bit where the values are kept per tick, to
rounding where the sums go by blocks."""

from types import SimpleNamespace

import numpy as np
import shapely

from ag_uav.analysis.metrics import (
    _cross_track_stats,
    _path_length,
    _rate_rms,
    _root_mean,
    _sumsq,
    cross_track,
    polyline_distance,
)


def _rms(x):
    return float(np.sqrt(np.mean(x * x)))


def test_path_length_in_blocks_equals_the_whole_array_formula():
    rng = np.random.default_rng(3)
    p = np.cumsum(rng.normal(size=(200_003, 3)), axis=0)
    whole = float(np.sum(np.linalg.norm(np.diff(p, axis=0), axis=1)))
    assert abs(_path_length(p, block=4096) - whole) <= 1e-12 * whole
    assert abs(_path_length(p) - whole) <= 1e-12 * whole
    assert _path_length(p[:1]) == 0.0


def test_cross_track_grouped_by_segment_equals_one_segment_at_a_time():
    rng = np.random.default_rng(5)
    n = 30_000
    segs = [SimpleNamespace(points=np.array([[0.0, 6.0 * j], [100.0, 6.0 * j + 1.0]]))
            for j in range(7)]
    plan = SimpleNamespace(segments=segs)
    seg = np.repeat(np.array([-1, 0, 1, -1, 2, 3, 9, 4, 5, 6, 0]), n // 11 + 1)[:n]
    spray = rng.random(n) < 0.8
    p = np.column_stack([rng.uniform(0, 100, n), rng.uniform(0, 40, n), np.full(n, 3.0)])
    res = SimpleNamespace(t=np.arange(n) * 0.01, p_true=p, seg=seg, spray=spray)
    want = np.full(n, np.nan)
    for s in np.unique(seg[spray]):
        if 0 <= s < len(segs):
            idx = np.flatnonzero((seg == s) & spray)
            want[idx] = shapely.distance(shapely.points(p[idx, :2]),
                                         shapely.LineString(segs[s].points))
    got = cross_track(res, plan)
    assert np.array_equal(got, want, equal_nan=True)
    assert np.isfinite(got).sum() > n // 2
    rms, mx = _cross_track_stats(res, plan)
    f = want[np.isfinite(want)]
    assert abs(rms - _rms(f)) <= 1e-13 * rms and mx == float(f.max())


def test_block_sums_and_rates_equal_the_whole_array_formulas():
    rng = np.random.default_rng(8)
    n = 150_001
    p, r = rng.normal(size=(n, 3)), rng.normal(size=(n, 3))
    mask = rng.random(n) < 0.7
    whole = _rms(np.hypot(p[mask, 0] - r[mask, 0], p[mask, 1] - r[mask, 1]))
    for block in (1000, 1 << 16, 10 * n):
        got = _root_mean(*_sumsq(mask, lambda a, b, m: np.hypot(
            p[a:b, 0][m] - r[a:b, 0][m], p[a:b, 1][m] - r[a:b, 1][m]), block))
        assert abs(got - whole) <= 1e-13 * whole
    assert _root_mean(*_sumsq(np.zeros(5, bool), lambda a, b, m: p[a:b, 0][m])) is None
    f = rng.normal(size=(n, 4)) * 5.0
    rate = np.diff(f, axis=0).ravel() * 100.0
    whole = _rms(rate)
    for block in (777, 1 << 16):   # the squares summed by blocks: equal to rounding
        assert abs(_rate_rms(f, 100.0, block=block) - whole) <= 1e-13 * whole
    assert _rate_rms(f[:1], 100.0) is None


def test_ins_scores_rms_and_max_by_blocks_equal_the_whole_array_formulas():
    from ag_uav.navigation.nees_stats import finite_rms_max

    rng = np.random.default_rng(11)
    a = (rng.normal(size=200_001) * 0.02).astype(np.float32)
    a[rng.random(a.size) < 0.1] = np.nan
    for scale in (1.0, np.pi / 180.0):
        x = a / scale if scale != 1.0 else a
        f = x[np.isfinite(x)]
        want_rms = round(float(np.sqrt(np.mean(f.astype(np.float64) ** 2))), 4)
        for block in (999, 1 << 16):
            rms, mx, n = finite_rms_max(a, scale, block)
            assert (rms, mx, n) == (want_rms, round(float(f.max()), 4), f.size)
    assert finite_rms_max(np.full(5, np.nan, np.float32)) == (None, None, 0)


def test_polyline_distance_equals_shapely_to_the_bit():
    """Polylines of 2–7 vertices, a repeated vertex among them, points on every side (before
    an edge's start, beyond its end, alongside)."""
    rng = np.random.default_rng(11)
    for trial in range(60):
        line = np.cumsum(rng.normal(0, 50, (rng.integers(2, 8), 2)), axis=0)
        if trial % 5 == 0:
            line[1] = line[0]
        p = line[0] + rng.normal(0, 80, (400, 2))
        want = shapely.distance(shapely.points(p), shapely.LineString(line))
        assert np.array_equal(polyline_distance(p, line), want)
