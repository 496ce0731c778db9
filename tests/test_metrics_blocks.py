"""The summary's metrics computed a block or a segment at a time equal the whole-array
formulas bit for bit (ag_uav.analysis.metrics)."""

from types import SimpleNamespace

import numpy as np
import shapely

from ag_uav.analysis.metrics import (
    _masked,
    _path_length,
    _rate_rms,
    _rms,
    _rms_in_place,
    cross_track,
)


def test_path_length_in_blocks_equals_the_whole_array_formula():
    rng = np.random.default_rng(3)
    p = np.cumsum(rng.normal(size=(200_003, 3)), axis=0)
    whole = float(np.sum(np.linalg.norm(np.diff(p, axis=0), axis=1)))
    assert _path_length(p, block=4096) == whole
    assert _path_length(p) == whole
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


def test_masked_blocks_and_rates_equal_the_whole_array_formulas():
    rng = np.random.default_rng(8)
    n = 150_001
    p, r = rng.normal(size=(n, 3)), rng.normal(size=(n, 3))
    mask = rng.random(n) < 0.7
    whole = _rms(np.hypot(p[mask, 0] - r[mask, 0], p[mask, 1] - r[mask, 1]))
    for block in (1000, 1 << 16, 10 * n):
        got = _masked(mask, lambda a, b, m: np.hypot(p[a:b, 0][m] - r[a:b, 0][m],
                                                      p[a:b, 1][m] - r[a:b, 1][m]), block)
        assert _rms_in_place(got) == whole
    f = rng.normal(size=(n, 4)) * 5.0
    rate = np.diff(f, axis=0).ravel() * 100.0
    whole = _rms(rate)
    for block in (777, 1 << 16):   # the squares summed by blocks: equal to rounding
        assert abs(_rate_rms(f, 100.0, block=block) - whole) <= 1e-13 * whole
    assert _rate_rms(f[:1], 100.0) is None
    assert _rms_in_place(np.empty(0)) is None
