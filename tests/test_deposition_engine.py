"""The dose on the ground in the engine: every mission with a field has the
dose metrics; mass is conserved in the loop; a vehicle's dose is the same alone and in a batch;
the deposition only observes (the trajectory is the same without it)."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest

import ag_uav
from ag_uav.engine.missions import DOSE_KEYS, simulate, simulate_many
from ag_uav.jobs.batch import write_rect_field


@pytest.fixture(scope="module")
def rect(tmp_path_factory):
    return str(write_rect_field(tmp_path_factory.mktemp("f") / "rect.geojson", 30.0, 18.0))


def _cfg(field: str, seed: int = 0, **over) -> ag_uav.Config:
    # legs along the rectangle's long side (not across the wind): few, long legs
    c = ag_uav.load_config(None, {"log.render": False, "mission.field": field,
                                  "mission.direction_deg": 0.0,
                                  "sim.max_time_s": 45.0, "estimator.name": "true",
                                  "estimator.shadow": [], **over})
    c.log.enabled = False
    c.seed = seed
    return c


@pytest.fixture(scope="module")
def calm(rect):
    return simulate(_cfg(rect))


def test_a_mission_has_the_dose_metrics(calm):
    s = calm.summary
    for k in DOSE_KEYS:
        assert s[k] is not None and math.isfinite(s[k]), k
    # the mean is what landed on the field over its area (30 m x 18 m); the 45 s mission
    # sprays part of it, so the mean is under the 1 L/ha target
    landed = s["litres_sprayed_l"] * (1.0 - s["offtarget_deposit_fraction"] - s["drift_fraction"])
    assert s["dose_mean_l_per_ha"] == pytest.approx(landed / 540.0 * 1e4, rel=0.03)
    assert 0.1 < s["dose_mean_l_per_ha"] < 1.0
    assert 0.0 <= s["underdosed_fraction"] <= 1.0 and 0.0 <= s["overdosed_fraction"] <= 1.0
    assert 0.0 < s["offtarget_deposit_fraction"] < 0.5
    # the tank draws what the nozzle model let out (the summary's litres are rounded to 0.1 mL)
    assert abs(s["nozzle_minus_tank_l"]) <= 1e-12
    assert s["nozzle_sprayed_l"] == pytest.approx(s["litres_sprayed_l"], abs=5e-5)


def test_mass_is_conserved_in_the_loop(calm):
    dm = calm.extra["dose"]
    sprayed = dm.sprayed_l
    assert sprayed > 0.01
    total = float(dm.litres.sum()) + dm.outside_grid_l + dm.drift_l + dm.airborne_l
    assert dm.evaporated_l > 0   # water, booked apart from the mix
    assert abs(sprayed - total) <= 1e-9 * sprayed
    assert abs(calm.summary["dose_mass_balance_error"]) < 1e-9


def test_without_the_nozzle_model_the_tank_follows_the_command(rect, calm):
    """``spray.deposition = false``: no valve delays or pressure lag, so the nozzles are on on
    the very ticks the command is and the tank draws the command's flow; the liquid mass is
    all that differs, so the track differs by millimetres."""
    off = simulate(_cfg(rect, **{"spray.deposition": False}))
    assert "dose_cv" not in off.summary and "dose" not in off.extra
    on_cmd, on_valve = off.extra["spray"]["nozzles"], calm.extra["spray"]["nozzles"]
    assert on_cmd.sum() > on_valve.sum() > 0.9 * on_cmd.sum()  # the 0.1 s opening delay
    assert off.summary["litres_sprayed_l"] == pytest.approx(calm.summary["litres_sprayed_l"],
                                                            rel=0.02)
    assert 0 < np.max(np.abs(calm.p_true - off.p_true)) < 0.02


def test_dose_alone_equals_dose_in_a_batch(rect):
    """Rows of different deposition configs, winds and seeds, in either order: each row's dose
    metrics and map equal the same config flown alone, bit for bit."""
    cfgs = [_cfg(rect, 1, **{"wind.speed_mps": 3.0, "sim.max_time_s": 30.0}),
            _cfg(rect, 2, **{"spray.nozzle_on_delay_s": 0.5, "sim.max_time_s": 30.0}),
            _cfg(rect, 3, **{"sim.max_time_s": 20.0})]
    many = simulate_many(cfgs)
    back = simulate_many(cfgs[::-1])[::-1]
    for c, a, b in zip(cfgs, many, back, strict=True):
        solo = simulate(c)
        keys = (*DOSE_KEYS, "nozzle_sprayed_l", "dose_mass_balance_error")
        want = {k: solo.summary[k] for k in keys}
        assert {k: a.summary[k] for k in keys} == want
        assert {k: b.summary[k] for k in keys} == want
        assert np.array_equal(a.extra["dose"].litres, solo.extra["dose"].litres)
    # the delay and the wind do change the dose (the rows are not all the same)
    assert many[0].summary["dose_cv"] != many[1].summary["dose_cv"]


def test_fly_prints_saves_logs_and_plots_the_dose(rect, tmp_path, capsys):
    """``ag-uav fly`` prints the dose rows and writes dose.npz; the log has the /dose grid (during
    the flight and at the end); ``ag-uav plot`` draws dose.png from either."""
    from ag_uav.analysis.viewing import plot, read_run
    from ag_uav.cli import main
    from ag_uav.world.deposition import DoseMap

    assert main(["fly", "--no-render", "--out", str(tmp_path), "--run-id", "r", "--set",
                 f'mission.field="{rect}"', "--set", "sim.max_time_s=30"]) == 0
    out = capsys.readouterr().out
    assert "dose CV" in out and "under-dosed area" in out and "deposit off the field" in out
    run = tmp_path / "r"
    dm = DoseMap.load(run / "dose.npz")
    d = read_run(run, images=False)
    assert d.channels["/dose"]["count"] >= 1 + 30 // 5 - 1    # every 5 s and the end
    g = d.grids["/dose"]
    last = np.frombuffer(g.data, dtype="<f4").reshape(dm.litres.shape)
    np.testing.assert_allclose(last, dm.l_per_ha, rtol=1e-6, atol=1e-6)
    assert (g.pose.position.x, g.cell_size.x) == (dm.grid.x0, dm.grid.cell)
    st = d.series["/drone/state"]
    valve, flow = st["ctrl.nozzle.valve"], st["ctrl.nozzle.flow_lps"]
    assert valve.max() == 1.0 and valve.min() == 0.0 and flow.max() > 0.0
    w = json.loads((run / "summary.json").read_text())["lanes"]["swath_m"]
    q = 1.0 * w * 5.0 / 1e4                      # R·w·v/10⁴ at the 5 m/s cruise, 1 L/ha
    assert 0.5 * q < flow.max() < 1.1 * q
    assert any(p.name == "dose.png" for p in plot(d, tmp_path / "plots"))
    (run / "dose.npz").unlink()   # from the log alone
    assert any(p.name == "dose.png" for p in plot(run, tmp_path / "plots2"))
