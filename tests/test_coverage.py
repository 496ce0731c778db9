"""Tests for ag_uav.analysis.coverage against analytic areas."""

import numpy as np
import pytest

from ag_uav.analysis.coverage import spray_coverage
from ag_uav.world.field import Field

RECT = Field.from_coords([(0, 0), (100, 0), (100, 30), (0, 30)])


def test_single_pass_analytic():
    cov, ov = spray_coverage(RECT, [np.array([[-10.0, 15.0], [110.0, 15.0]])], 6.0)
    assert cov == pytest.approx(6 * 100 / 3000, rel=1e-9)
    assert ov == 0.0


def test_partial_pass_and_flat_caps():
    cov, _ = spray_coverage(RECT, [np.array([[20.0, 10.0], [60.0, 10.0]])], 6.0)
    assert cov == pytest.approx(6 * 40 / 3000, rel=1e-9)  # flat caps: no half-disc at the ends


def test_two_overlapping_passes():
    tr = [np.array([[-5.0, 10.0], [105.0, 10.0]]), np.array([[105.0, 14.0], [-5.0, 14.0]])]
    cov, ov = spray_coverage(RECT, tr, 6.0)
    assert cov == pytest.approx(10 * 100 / 3000, rel=1e-9)
    assert ov == pytest.approx(2 * 100 / 3000, rel=1e-9)


def test_self_overlap_within_one_pass_not_double():
    back_and_forth = np.array([[-5.0, 10.0], [50.0, 10.0], [50.0, 12.0], [-5.0, 12.0]])
    _, ov = spray_coverage(RECT, [back_and_forth], 6.0)
    assert ov == 0.0
    _, ov2 = spray_coverage(RECT, [back_and_forth[:2], back_and_forth[2:]], 6.0)
    assert ov2 == pytest.approx(4 * 50 / 3000, rel=1e-6)


def test_clipped_to_field_and_holes():
    f = Field.from_coords([(0, 0), (100, 0), (100, 30), (0, 30)],
                          holes=[[(40, 12), (50, 12), (50, 18), (40, 18)]])
    cov, _ = spray_coverage(f, [np.array([[-50.0, 15.0], [150.0, 15.0]])], 6.0)
    assert cov == pytest.approx((600 - 60) / (3000 - 60), rel=1e-9)


def test_noisy_dense_track_and_empty():
    rng = np.random.default_rng(3)
    x = np.linspace(-5, 105, 5000)
    y = 15 + rng.normal(0, 0.01, x.size)
    cov, _ = spray_coverage(RECT, [np.column_stack([x, y])], 6.0)
    assert cov == pytest.approx(0.2, abs=2e-3)
    assert spray_coverage(RECT, [], 6.0) == (0.0, 0.0)
    with pytest.raises(ValueError):
        spray_coverage(RECT, [], 0.0)
