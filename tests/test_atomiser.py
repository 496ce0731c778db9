"""The rotary atomiser (ag_uav.world.atomiser): the droplet size that follows the disc speed,
the throw against an independent integration and the Stokes limit, the release it widens, the
hydraulic nozzles unchanged and the mass balance with a throw."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

from ag_uav.config import ConfigError, load_config
from ag_uav.world.atomiser import (
    disc_vmd_m,
    rotary_spectrum,
    throw_radius,
    throw_variances,
    tip_speed_mps,
)
from ag_uav.world.deposition import Deposition, DepositionConfig, footprints, pack_input
from ag_uav.world.droplets import drag_cd
from ag_uav.world.field import Field

RHO_L, RHO_A, MU = 1000.0, 1.225, 1.81e-5
I9 = np.eye(3).ravel()


def test_vmd_follows_one_over_the_disc_speed_and_the_span_is_kept():
    d1 = disc_vmd_m(3000.0, 0.04)
    assert disc_vmd_m(6000.0, 0.04) == pytest.approx(d1 / 2.0, rel=1e-12)
    # Walton & Prewett by hand: d = 3.8 / ω sqrt(σ / (ρ D)), D = 0.08 m, ω = 7200 rpm
    w = 7200.0 * 2.0 * math.pi / 60.0
    assert disc_vmd_m(7200.0, 0.04) == pytest.approx(3.8 / w * math.sqrt(0.072 / 80.0), rel=1e-12)
    d10, d50, d90 = rotary_spectrum(80.0, 150.0, 280.0, 300.0)
    assert (d10, d50, d90) == pytest.approx((160.0, 300.0, 560.0))
    assert (d90 - d10) / d50 == pytest.approx((280.0 - 80.0) / 150.0)


def test_throw_in_the_stokes_limit_is_v0_tau():
    d, v0 = 10e-6, 0.01                       # Re ≈ 0.007: Stokes drag to 0.5 %
    tau = RHO_L * d * d / (18.0 * MU)
    r, _, _ = throw_radius(d, v0, 0.0, RHO_L, RHO_A, MU)
    assert r == pytest.approx(v0 * tau, rel=0.01)


def _reference(d: float, v0: float, w_air: float) -> float:
    """The same equations integrated independently (scipy's adaptive RK45 to u = 1e-7 v0)."""
    from scipy.integrate import solve_ivp

    def rhs(_t, s):
        _, _, u, w = s
        wr = w - w_air
        sp = math.hypot(u, wr)
        k = 3.0 * RHO_A * drag_cd(RHO_A * sp * d / MU) * sp / (4.0 * RHO_L * d)
        return [u, w, -k * u, 9.81 - k * wr]

    def stop(_t, s):
        return s[2] - 1e-7 * v0
    stop.terminal = True  # type: ignore[attr-defined]
    sol = solve_ivp(rhs, (0.0, 50.0), [0.0, 0.0, v0, 0.0], events=stop, rtol=1e-10,
                    atol=1e-13)
    return float(sol.y[0, -1])


@pytest.mark.parametrize("d_um", [80.0, 150.0, 400.0])
def test_throw_equals_an_independent_integration(d_um):
    v0 = tip_speed_mps(7200.0, 0.04)          # 30 m/s: Re up to ~800 at release
    r, t, z = throw_radius(d_um * 1e-6, v0, 7.8, RHO_L, RHO_A, MU)
    assert r == pytest.approx(_reference(d_um * 1e-6, v0, 7.8), rel=2e-3)
    assert t > 0 and z > 0
    # the drag law's non-linearity: far short of the Stokes throw v0 τ
    assert r < 0.5 * v0 * RHO_L * (d_um * 1e-6) ** 2 / (18.0 * MU)


def test_throw_grows_with_the_droplet_and_is_zero_without_a_disc():
    d = np.array([50e-6, 150e-6, 300e-6])
    var = throw_variances(d, 30.0, 7.8)
    assert np.all(np.diff(var) > 0) and var[0] > 0
    assert np.all(throw_variances(d, 0.0, 7.8) == 0.0)


def test_config_rotary_sets_the_spectrum_and_the_throw_hydraulic_unchanged():
    x8 = DepositionConfig.from_config(load_config(None, {"vehicle": {"preset": "x8-40l"}}))
    vmd = 1e6 * disc_vmd_m(7200.0, 0.04)
    assert x8.dv50_um == pytest.approx(vmd) and x8.dv10_um == pytest.approx(80.0 * vmd / 150.0)
    assert x8.throw_speed_mps == pytest.approx(tip_speed_mps(7200.0, 0.04))
    assert x8.throw_air_mps > 5.0
    off = DepositionConfig.from_config(load_config(None, {"vehicle": {
        "preset": "x8-40l", "atomiser_rpm": 0.0}}))
    assert (off.dv50_um, off.throw_speed_mps) == (150.0, 0.0)
    m350 = DepositionConfig.from_config(load_config(None, {}))
    assert m350 == dataclasses.replace(m350, throw_speed_mps=0.0, throw_air_mps=0.0)
    assert (m350.dv10_um, m350.dv50_um, m350.dv90_um) == (120.0, 250.0, 420.0)
    with pytest.raises(ConfigError, match="vehicle.atomiser_rpm"):
        load_config(None, {"vehicle": {"atomiser_rpm": 7000.0}})


def test_the_throw_widens_each_class_by_its_ring_and_nothing_else():
    base = DepositionConfig()
    thrown = dataclasses.replace(base, throw_speed_mps=30.0, throw_air_mps=5.0)
    inp = pack_input([0.0, 0.0, 3.0], [5.0, 0.0, 0.0], I9, 6.47 * 9.81, [0.0, 2.0, 0.0], 1)
    a, b = footprints(base, inp), footprints(thrown, inp)
    assert np.all(a["throw"] == 0.0) and np.all(b["throw"] > 0.0)
    np.testing.assert_allclose(b["wvar"] - a["wvar"], b["throw"], rtol=1e-9, atol=1e-15)
    np.testing.assert_allclose(b["evx"] - a["evx"], b["throw"], rtol=1e-9, atol=1e-15)
    for key in ("wake", "wx", "wy", "esc", "ex", "ey", "mut", "pair", "wland"):
        np.testing.assert_array_equal(a[key], b[key])


def test_mass_balance_closes_with_a_throw():
    cfg = DepositionConfig(buffer_m=3.0, cell_m=0.5, throw_speed_mps=30.0, throw_air_mps=6.0)
    dep = Deposition(cfg, Field.from_coords([(0, 0), (40, 0), (40, 30), (0, 30)]))
    for i in range(1200):
        x = -10.0 + 0.05 * i
        dep.step(0.01, (x, 15.0, 2.5), (5.0, 0.0, 0.0), I9, 6.47 * 9.81, (0.0, 3.0, 0.0),
                 0.0 < x < 40.0)
    dm = dep.dose_map()
    total = dm.litres.sum() + dm.outside_grid_l + dm.drift_l + dm.airborne_l
    assert dm.sprayed_l > 0 and abs(total - dm.sprayed_l) <= 1e-9 * dm.sprayed_l
    assert abs(dep.metrics()["mass_balance_error"]) <= 1e-9
