"""The summary's drift past the buffer with its bounds (ag_uav.world.drift_bounds)."""

import numpy as np
import pytest

from ag_uav.config import load_config
from ag_uav.world.deposition import DepositionConfig
from ag_uav.world.drift_bounds import drift_ratios, pass_profile, strip_tail


def test_the_bounds_bracket_the_central_drift():
    dep = DepositionConfig.from_config(load_config(None, {}), swath_m=3.0)
    r = drift_ratios(dep, 3.0, 3.0, 5.0, 3.0, 9.17, 10.0)
    assert 0.1 < r["low"] < 0.9 and 1.2 < r["high"] < 5.0


def test_strip_tail_is_the_share_beyond_the_distance():
    dep = DepositionConfig.from_config(load_config(None, {}), swath_m=3.0)
    y, dens, book = pass_profile(dep, 3.0, 3.0, 5.0)
    near, far = (strip_tail(y, dens, 0.0, 3.0, 4, d) for d in (0.0, 10.0))
    assert 0.0 < far < near < 1.0
    # a meandering direction sees the strip obliquely: less lands beyond a fixed distance
    assert strip_tail(y, dens, 0.0, 3.0, 4, 10.0, sigma_deg=20.0) < far
    # what stays aloft counts as drift past any buffer
    assert strip_tail(y, dens, 0.05, 3.0, 4, 10.0) == pytest.approx(far + 0.05)
    # one pass at the edge: the share beyond 0 is the landed density beyond 1.5 m
    one = strip_tail(y, dens, 0.0, 3.0, 1, 0.0)
    assert one == pytest.approx(np.sum(dens[y >= 1.5]) * (y[1] - y[0]), rel=0.02)
