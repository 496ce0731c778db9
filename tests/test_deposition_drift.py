"""The drift physics of the deposition model: evaporation (the d² law), the wet-bulb depression,
the first-passage law, mass conservation with airborne and evaporated volume, the skewed wake's
escape, and the drift trial's far-field tail and trends (ag_uav.jobs.experiments.drift)."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

from ag_uav.jobs.experiments.drift import (
    DISTANCES,
    Case,
    single_pass_profile,
    strip_deposit,
)
from ag_uav.jobs.experiments.swath import pass_states
from ag_uav.world.deposition import (
    Air,
    Deposition,
    DepositionBatch,
    DepositionConfig,
    evaporation,
    footprints,
    pack_input,
    wet_bulb_c,
)
from ag_uav.world.deposition_kernels import _ig_cdf
from ag_uav.world.field import Field

SQUARE = Field.from_coords([(0, 0), (40, 0), (40, 30), (0, 30)])


def test_wet_bulb_matches_stulls_worked_example():
    # Stull (2011): T = 20 °C, RH = 50 % -> Tw = 13.7 °C
    assert wet_bulb_c(20.0, 50.0) == pytest.approx(13.7, abs=0.05)
    assert wet_bulb_c(20.0, 99.0) == pytest.approx(20.0, abs=0.4)     # saturated: no depression
    assert wet_bulb_c(30.0, 30.0) < wet_bulb_c(30.0, 60.0)


def test_single_droplet_follows_the_analytic_d2_law():
    air = Air(t_c=30.0, rh_percent=30.0, nonvolatile=0.02)
    lam = 84.76 * (30.0 - wet_bulb_c(30.0, 30.0)) * 1e-12
    d0 = 100e-6
    t = np.linspace(0.0, 15.0, 31)
    d, _ = evaporation(np.array([d0]), t, air, ventilation=False)
    dres = d0 * 0.02 ** (1 / 3)
    want = np.sqrt(np.maximum(d0 * d0 - lam * t, dres * dres))
    np.testing.assert_allclose(d[0], want, rtol=1e-9)
    assert d[0, -1] == pytest.approx(dres, rel=1e-12)     # stops at the non-volatile residue


def test_ventilated_evaporation_matches_an_ode_solver():
    from scipy.integrate import solve_ivp

    from ag_uav.world.deposition import terminal_velocity

    air = Air(t_c=25.0, rh_percent=40.0, nonvolatile=0.05)
    lam = air.lam_m2
    d0 = 150e-6
    dmin = d0 * 0.05 ** (1 / 3)

    def rhs(_t, y):
        d = math.sqrt(max(y[0], dmin * dmin))
        re = air.rho_a * terminal_velocity(d, air.rho_l, air.rho_a, air.mu) * d / air.mu
        return [-lam * (1 + 0.27 * math.sqrt(re)) if y[0] > dmin * dmin else 0.0]

    t = np.array([0.0, 2.0, 5.0, 10.0, 20.0])
    sol = solve_ivp(rhs, (0, 20), [d0 * d0], t_eval=t, rtol=1e-10, atol=1e-20)
    d, _ = evaporation(np.array([d0]), t, air)
    np.testing.assert_allclose(d[0], np.sqrt(np.maximum(sol.y[0], dmin * dmin)), rtol=3e-3)


def test_first_passage_cdf_matches_scipy():
    from scipy.stats import invgauss

    for mu, lam in ((2.0, 0.5), (5.0, 23.0), (400.0, 14.0), (1.0, 2000.0)):
        for t in (0.1, 1.0, 5.0, 50.0, 600.0):
            want = invgauss.cdf(t, mu / lam, scale=lam)
            assert _ig_cdf(t, mu, lam) == pytest.approx(want, abs=1e-9), (mu, lam, t)


def _fly(cfg, wind, h=3.0):
    dep = Deposition(cfg, SQUARE)
    R, thrust = pass_states(5.0, h, wind, 6.47, 0.25, 0.18)
    x = -10.0
    for _ in range(1200):
        x += 0.05
        dep.step(0.01, (x, 15.0, h), (5.0, 0.0, 0.0), R, thrust, (0.0, wind, 0.0), 0 < x < 40)
    return dep.dose_map()


def test_mass_conserved_sprayed_mix_is_landed_plus_airborne_and_water_evaporates_apart():
    """The map counts the tank mix (its tracer): sprayed = landed + airborne, whatever
    evaporates; the water lost is booked apart, at most the volatile share of the spray."""
    cfg = DepositionConfig(buffer_m=3.0, dv10_um=60, dv50_um=130, dv90_um=250,
                           temperature_c=35.0, rh_percent=20.0, nonvolatile_fraction=0.01)
    dm = _fly(cfg, 5.0)
    landed = float(dm.litres.sum()) + dm.outside_grid_l + dm.drift_l
    assert dm.evaporated_l > 1e-3 * dm.sprayed_l and dm.airborne_l > 0 and dm.drift_l > 0
    assert abs(dm.sprayed_l - landed - dm.airborne_l) <= 1e-12 * dm.sprayed_l
    assert dm.evaporated_l < 0.99 * dm.sprayed_l
    # a humid day evaporates less of the same spray
    wet = _fly(dataclasses.replace(cfg, rh_percent=90.0, temperature_c=15.0), 5.0)
    assert wet.evaporated_l < 0.5 * dm.evaporated_l


def test_batch_row_equals_the_vehicle_alone_with_drift_physics():
    cfg = DepositionConfig(temperature_c=30.0, rh_percent=30.0)
    solo = _fly(cfg, 4.0)
    batch = DepositionBatch(cfg, SQUARE, 3)
    R, thrust = pass_states(5.0, 3.0, 4.0, 6.47, 0.25, 0.18)
    x = -10.0
    for _ in range(1200):
        x += 0.05
        pos = np.array([[x, 15.0, 3.0], [x, 5.0, 2.0], [x, 15.0, 3.0]])
        batch.step(0.01, pos, np.tile([5.0, 0, 0], (3, 1)), np.tile(R, (3, 1)),
                   np.full(3, thrust), np.array([[0, 4.0, 0], [0, 1.0, 0], [0, 4.0, 0]]),
                   np.full(3, 0 < x < 40))
    for i in (0, 2):
        dm = batch.dose_map(i)
        assert np.array_equal(dm.litres, solo.litres)
        assert (dm.evaporated_l, dm.airborne_l, dm.drift_l) == (
            solo.evaporated_l, solo.airborne_l, solo.drift_l)


def _fp(wind, speed=5.0, h=3.0, **over):
    cfg = DepositionConfig(**over)
    R, thrust = pass_states(speed, h, wind, 6.47, 0.25, 0.18)
    return footprints(cfg, pack_input([0, 0, h], [speed, 0, 0], R, thrust, [0, wind, 0], 1))


def test_the_wake_skews_and_lets_fines_escape():
    hover = _fp(0.0, speed=0.0)
    fast = _fp(0.0, speed=5.0)
    assert np.all(hover["esc"] == 0.0)                 # no skew in hover: nothing escapes
    assert np.all(fast["esc"] > 0.0)
    assert np.all(np.diff(fast["esc"]) < 0)            # the fines escape most
    windy = _fp(5.0)
    assert np.all(windy["esc"] > fast["esc"])          # a crosswind skews the wake further
    assert np.all(windy["ey"][:-1] > windy["ey"][1:])  # the finer, the further downwind


def _trial(wind=3.0, height=2.0, spectrum="medium", rh=60.0, temp=20.0, **over):
    from ag_uav.jobs.experiments.drift import SPECTRA

    dv = SPECTRA[spectrum]
    cfg = DepositionConfig(dv10_um=dv[0], dv50_um=dv[1], dv90_um=dv[2], temperature_c=temp,
                           rh_percent=rh, **over)
    y, dens, _ = single_pass_profile(cfg, Case(wind, height, 5.0, spectrum, temp, rh))
    far = np.arange(5.0, 200.0, 0.5)
    return (strip_deposit(y, dens, cfg.swath_m, 10, np.asarray(DISTANCES)),
            strip_deposit(y, dens, cfg.swath_m, 10, far))


@pytest.mark.parametrize("height,wind", [(2.0, 3.0), (3.0, 5.0)])
def test_far_field_tail_is_positive_monotone_and_smooth(height, wind):
    dep, far = _trial(wind, height)
    assert np.all(dep > 0) and np.all(np.diff(dep) < 0)
    assert np.all(far > 0) and np.all(np.diff(far) < 0)
    # no cut-off: between neighbouring points 0.5 m apart the deposit never drops by more than
    # a fifth beyond 5 m
    assert np.all(far[1:] / far[:-1] > 0.8)


def test_drift_rises_with_wind_with_finer_droplets_and_with_drier_air():
    d1, _ = _trial(wind=1.0)
    d3, _ = _trial(wind=3.0)
    d5, _ = _trial(wind=5.0)
    assert np.all(d1 < d3) and np.all(d3 < d5)
    fine, _ = _trial(spectrum="fine")
    coarse, _ = _trial(spectrum="coarse")
    assert np.all(fine > d3) and np.all(d3 > coarse)
    dry, _ = _trial(rh=40.0)
    humid, _ = _trial(rh=80.0)
    far = np.asarray(DISTANCES) >= 15
    assert np.all(dry[far] > d3[far]) and np.all(d3[far] > humid[far])


def test_bad_air_keys_name_the_key():
    with pytest.raises(ValueError, match="rh_percent = 120"):
        DepositionConfig(rh_percent=120.0)
    with pytest.raises(ValueError, match="nonvolatile_fraction"):
        DepositionConfig(nonvolatile_fraction=0.0)


def test_the_experiment_writes_its_tables_and_refuses_bad_input(tmp_path, capsys):
    import argparse
    import csv

    from ag_uav.jobs.experiments import drift

    p = argparse.ArgumentParser()
    drift.add_arguments(p)
    args = p.parse_args(["--winds", "3", "--heights", "2", "--spectra", "medium", "--rhs", "60",
                         "--passes", "4", "--out", str(tmp_path)])
    assert drift.main(args) == 0
    rows = list(csv.DictReader((tmp_path / "drift.csv").open()))
    assert [float(r["distance_m"]) for r in rows] == list(DISTANCES)
    assert {"crosswind_mps", "release_height_m", "speed_mps", "spectrum", "temperature_c",
            "rh_percent", "deposit_percent"} <= set(rows[0])
    case = next(csv.DictReader((tmp_path / "cases.csv").open()))
    assert 0 < float(case["buffer_1pct_m"]) < float(case["buffer_0p1pct_m"])
    assert "JKI field crops" in (tmp_path / "drift.md").read_text()
    assert "In the band of the JKI curves" in (tmp_path / "drift.md").read_text()
    assert case["jki_band"] and case["jki_band_low"] and case["jki_band_high"]
    assert (tmp_path / "drift.png").stat().st_size > 0
    bad = p.parse_args(["--rhs", "120", "--out", str(tmp_path / "x")])
    from ag_uav.config import ConfigError

    with pytest.raises(ConfigError, match="rh_percent = 120"):  # the CLI: one line, exit 2
        drift.main(bad)


def test_the_band_check_places_a_synthetic_profile():
    """Inside, above the early-fruit edge and below the field-crop edge, with the ratio to the
    nearest edge; the verdict names the side, the distances and the furthest ratio."""
    from ag_uav.jobs.experiments.drift import BAND, BAND_DISTANCES, JKI, band_check, band_verdict

    lo, hi = JKI[BAND[0]], JKI[BAND[1]]
    assert BAND_DISTANCES == (5.0, 10.0, 15.0, 20.0, 30.0, 50.0)
    # 1.5 x the field-crop curve: inside everywhere, nearer F with ratio 1.5
    mid = {d: 1.5 * lo[d] for d in BAND_DISTANCES}
    checks = band_check(mid)
    assert [c[1] for c in checks] == ["inside"] * 6
    assert all(c[3] == "F" and c[2] == pytest.approx(1.5) for c in checks)
    assert band_verdict(checks) == "inside"
    # 0.8 x early fruit is nearer the E edge
    assert band_check({10.0: 0.8 * hi[10]})[0][1:] == ("inside", pytest.approx(0.8), "E")
    # above E at the last two distances, below F at 5 m
    prof = dict(mid)
    prof[30.0], prof[50.0], prof[5.0] = 1.2 * hi[30], 1.6 * hi[50], 0.5 * lo[5]
    checks = band_check(prof)
    assert checks[-1] == (50.0, "above", pytest.approx(1.6), "E")
    assert checks[0] == (5.0, "below", pytest.approx(0.5), "F")
    assert band_verdict(checks) == ("above E at 30, 50 m (up to 1.6 ×); "
                                    "below F at 5 m (down to 0.50 ×)")
    # distances the band has no value at (1-3 m) are not checked
    assert band_check({1.0: 1e3, 3.0: 1e3}) == []
