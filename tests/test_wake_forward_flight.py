"""The forward-flight wake (ag_uav.world.wake: the trailing vortex pair, its ground effect and
the blend with the hover law) in the deposition kernels and the pattern test."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

from ag_uav.world.deposition import (
    Deposition,
    DepositionBatch,
    DepositionConfig,
    footprints,
    pack_input,
    rotor_span,
)
from ag_uav.world.deposition_config import HOVER_LAW, LAWS, WAKE_LAW
from ag_uav.world.pattern import cv_vs_spacing, effective_swath, pass_states, single_pass
from ag_uav.world.wake import vortex_landing, vortex_pair, wing_share


def test_the_wake_law_is_the_hover_law_with_the_vortex_pair():
    assert LAWS["wake"] is WAKE_LAW
    assert {k: v for k, v in WAKE_LAW.items() if k != "vortex_life_tstar"} == HOVER_LAW
    assert WAKE_LAW["vortex_life_tstar"] > 0 and DepositionConfig().vortex_life_tstar == 0


def test_vortex_pair_is_the_lifting_line_and_lambs_images():
    t, rho, va, b0, zr = 883.0, 1.225, 7.0, 2.3, 2.85
    gam, w0, c, u, tstar = vortex_pair(t, rho, va, b0, zr)
    assert gam == pytest.approx(t / (rho * va * b0))
    assert w0 == pytest.approx(gam / (2 * math.pi * b0))
    assert tstar == pytest.approx(b0 / w0)
    # Lamb's trajectory 1/y² + 1/z² = const through (b0/2, zr); the asymptote's height c
    assert 1 / c ** 2 == pytest.approx(1 / (b0 / 2) ** 2 + 1 / zr ** 2)
    assert u == pytest.approx(gam / (4 * math.pi * c))
    assert vortex_pair(t, rho, 0.0, b0, zr) == (0.0, 0.0, 0.0, 0.0, 0.0)
    # Γ ∝ 1/V: half the speed, twice the circulation
    assert vortex_pair(t, rho, 3.5, b0, zr)[0] == pytest.approx(2 * gam)


def test_wing_share_blends_hover_to_wing_by_the_advance_ratio():
    vh = 5.4
    assert wing_share(0.0, vh) == 0.0
    assert wing_share(2 * vh, vh) == pytest.approx(1.0) and wing_share(30.0, vh) == 1.0
    f = [wing_share(v, vh) for v in np.linspace(0, 2 * vh, 50)]
    assert np.all(np.diff(f) > 0)
    assert wing_share(vh, vh) == pytest.approx(0.5)


@pytest.mark.parametrize("vt,life", [(0.3, 100.0), (0.3, 1.2), (1.5, 100.0), (0.05, 3.0)])
def test_vortex_landing_matches_sampling(vt, life):
    b0, zn, w0, c, u = 1.0, 2.0, 1.8, 0.45, 2.0
    t_mean, var = vortex_landing(vt, b0, zn, w0, c, u, life)
    rng = np.random.default_rng(1)
    t_d = (zn - c) / (w0 + vt)
    s = rng.uniform(0.0, c / vt, 400_000)                 # settles out evenly in height
    t_l = max(min(c / vt, life - t_d), 0.0)
    y = b0 / 2 + u * np.minimum(s, t_l)
    assert var == pytest.approx(np.mean(y ** 2), rel=5e-3)
    assert t_mean == pytest.approx(t_d + np.mean(s), rel=5e-3)


def test_no_vortex_part_unless_the_option_is_on():
    R, thrust = pass_states(5.0, 2.0, 0.0, 6.47, 0.25, 0.18)
    inp = pack_input([0, 0, 2.0], [5.0, 0, 0], R, thrust, [0, 0, 0], 1)
    off = footprints(DepositionConfig(**HOVER_LAW), inp)
    on = footprints(DepositionConfig(**WAKE_LAW), inp)
    assert np.all(off["vort"] == 0.0)
    assert np.all(on["vort"] > 0.0)
    np.testing.assert_allclose(on["wake"] + on["vort"], off["wake"], rtol=1e-12)
    # the pair spreads across the flight (y), not along it
    assert np.all(on["vvy"] > on["vvx"])


def test_mass_balance_closes_and_a_batch_equals_its_rows_with_the_wake_law():
    from ag_uav.world.field import Field

    fld = Field.from_coords([(0, 0), (40, 0), (40, 30), (0, 30)])
    cfg = DepositionConfig(**WAKE_LAW, buffer_m=4.0)
    n = 2
    batch = DepositionBatch(cfg, fld, n)
    singles = [Deposition(cfg, fld) for _ in range(n)]
    R = np.tile(np.eye(3).ravel(), (n, 1))
    vel = np.array([[5.0, 0.0, 0.0], [3.0, 1.0, 0.0]])
    wind = np.array([[0.0, 3.0, 0.0], [-2.0, 1.0, 0.0]])
    for i in range(300):
        p = np.array([[5.0, 15.0, 3.0], [8.0, 5.0, 2.0]]) + vel * 0.02 * i
        out = batch.step(0.02, p, vel, R, np.full(n, 63.5), wind, np.ones(n, bool)).copy()
        for j, s in enumerate(singles):
            assert s.step(0.02, p[j], vel[j], R[j], 63.5, wind[j], True) == out[j]
    for j, s in enumerate(singles):
        assert np.array_equal(batch.dose_map(j).litres, s.dose_map().litres)
        m = s.metrics()
        assert m["sprayed_l"] > 0 and abs(m["mass_balance_error"]) < 1e-12


def _swath(cfg, v, h=2.0, mass=6.47):
    y, p, _ = single_pass(cfg, v, h, 0.0, mass)
    sp = np.arange(0.5, 20.01, 0.25)
    return effective_swath(sp, cv_vs_spacing(y, p, sp))


def test_the_swath_widens_with_speed_by_the_wake_law_and_not_by_the_hover_law():
    wake, hover = DepositionConfig(**WAKE_LAW), DepositionConfig(**HOVER_LAW)
    assert _swath(wake, 7.0) > _swath(wake, 3.0)
    assert _swath(wake, 7.0) > _swath(hover, 7.0)
    assert _swath(hover, 7.0) <= _swath(hover, 3.0)


def test_rotor_span_of_the_layouts():
    assert rotor_span(4, 0.4475, 0.533) == pytest.approx(math.sqrt(2) * 0.4475 + 0.533)
    assert rotor_span(8, 0.75, 0.533) == pytest.approx(2 * 0.75 * math.sin(3 * math.pi / 8)
                                                       + 0.533)


def test_wind_tunnel_medium_with_the_wake_law():
    from ag_uav.jobs.experiments import wind_tunnel as wt

    base = DepositionConfig(**WAKE_LAW)
    _, summ = wt.compare(base, wt.Trial(), wt.read_measured(None), [4.5], ["medium"], [2.0])
    s = summ[0]
    assert 0.5 < s["ratio"] < 2.0
    assert s["peak_model_m"] == s["peak_measured_m"] == 1.0
    hover = dataclasses.replace(base, vortex_life_tstar=0.0)
    _, sh = wt.compare(hover, wt.Trial(), wt.read_measured(None), [4.5], ["medium"], [2.0])
    assert s["downwind_model"] > sh[0]["downwind_model"]     # the pair carries some downwind


def test_a_flight_selects_the_law_and_the_vehicle_arm():
    from ag_uav.config import load_config

    d = DepositionConfig.from_config(load_config(None, {"spray.deposition_law": "wake"}))
    assert d.vortex_life_tstar == WAKE_LAW["vortex_life_tstar"] and d.wake_escape == 0.6
    assert DepositionConfig.from_config(load_config(None)).vortex_life_tstar == 0.0
    x8 = DepositionConfig.from_config(load_config(None, {"vehicle.preset": "x8-40l"}))
    assert x8.rotor_arm_m == pytest.approx(1.092) and x8.rotor_diameter_m == pytest.approx(1.372)


def test_swath_cli_with_a_vehicle_preset(tmp_path, capsys):
    from ag_uav.cli import main

    rc = main(["experiment", "swath", "--law", "wake", "--set", "vehicle.preset=x8-40l",
               "--heights", "2.5", "--speeds", "7", "--winds", "0", "--out", str(tmp_path)])
    assert rc == 0
    import csv

    row = next(csv.DictReader((tmp_path / "swath.csv").open()))
    assert 3.0 < float(row["effective_swath_m"]) < 11.0 * 1.3
    assert main(["experiment", "swath", "--set", "vehicle.preset=nope", "--out",
                 str(tmp_path)]) == 2
    assert "vehicle.preset" in capsys.readouterr().err
