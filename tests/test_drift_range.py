"""Buffers with an error bar: the surface layer's stability (Monin–Obukhov) and the bounds of
the drift trial (ag_uav.jobs.experiments.drift_range)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from ag_uav.jobs.experiments import drift, drift_range
from ag_uav.world.deposition import DepositionConfig
from ag_uav.world.surface_layer import STABILITY, eddy_k, layer_wind, phi_h, psi_m

CASE = drift.Case(3.0, 2.0, 5.0, "medium", 20.0, 60.0)


def test_neutral_layer_is_the_log_law():
    ust, fu = layer_wind(3.0, 3.0, 2.0, 0.05, 0.0)
    assert ust == pytest.approx(0.41 * 3.0 / math.log(3.0 / 0.05))
    mean = (2.0 * math.log(2.0 / 0.05) - 2.0 + 0.05) / (2.0 - 0.05)
    assert fu == pytest.approx(mean / math.log(3.0 / 0.05))
    assert eddy_k(ust, 2.0, 0.0) == pytest.approx(0.41 * ust * 1.0)


@pytest.mark.parametrize("inv_l", [1 / 20, -1 / 20])
def test_layer_mean_wind_matches_quadrature_of_the_profile(inv_l):
    z0, pz, zn, w = 0.05, 3.0, 2.0, 3.0
    ust, fu = layer_wind(w, pz, zn, z0, inv_l)
    z = np.linspace(z0, zn, 20001)
    u = ust / 0.41 * (np.log(z / z0) - np.array([psi_m(v * inv_l) for v in z]) + psi_m(z0 * inv_l))
    assert ust / 0.41 * (math.log(pz / z0) - psi_m(pz * inv_l) + psi_m(z0 * inv_l)) == \
        pytest.approx(w)
    assert fu * w == pytest.approx(np.trapezoid(u, z) / (zn - z0), rel=1e-5)
    # a stable layer mixes less, an unstable one more
    assert (phi_h(0.5 * inv_l) > 1.0) == (inv_l > 0)


def test_stability_orders_the_drift_far_out():
    far = {}
    for name, il in STABILITY.items():
        _, summ, curves = drift.run_cases(DepositionConfig(obukhov_inv_m=il), [CASE], 10, 6.47)
        x, dep = curves[CASE]
        far[name] = (dep[np.argmin(np.abs(x - 120.0))], summ[0]["buffer_0p1pct_m"])
    assert far["stable"][0] > far["neutral"][0] > far["unstable"][0]
    assert far["stable"][1] >= far["neutral"][1] >= far["unstable"][1]
    assert far["stable"][1] > far["unstable"][1]


def test_meander_lowers_a_falling_deposit_and_keeps_a_flat_one():
    x = np.arange(0.5, 400.0, 0.5)
    # x^-n seen obliquely: E[cos^(n-1) θ] x^-n, below x^-n for n > 1 and equal for n = 1
    dep2 = 1.0 / x ** 2
    m2 = drift_range.meander(x, dep2, 20.0)
    assert np.all(m2[10:500] < dep2[10:500])   # (the first metres: the grid is too coarse)
    th = np.radians(20.0)
    assert m2[200] / dep2[200] == pytest.approx(math.exp(-th ** 2 / 2), rel=2e-3)
    dep1 = 1.0 / x
    assert drift_range.meander(x, dep1, 20.0)[200] == pytest.approx(dep1[200], rel=2e-3)
    assert drift_range.meander(x, dep1, 0.0) == pytest.approx(dep1)


def test_bounds_bracket_the_central_buffers():
    base = DepositionConfig()
    rng = drift.bound_buffers(base, [CASE], 10, 6.47)[CASE]
    _, summ, _ = drift.run_cases(base, [CASE], 10, 6.47)
    for i, key in enumerate(("buffer_1pct_m", "buffer_0p1pct_m")):
        assert rng["low"][i] < summ[0][key] < rng["high"][i]
