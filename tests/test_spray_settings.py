"""``ag-uav experiment spray-settings``: the edge and drift shares, the Pareto front and a small
search end to end."""

import csv

import numpy as np
import pytest

from ag_uav.cli import main
from ag_uav.jobs.experiments import spray_settings as ss
from ag_uav.world import pattern


def _box():
    y = np.arange(-20.0, 20.0, 0.25) + 0.125      # collectors every 0.25 m, as the test's
    return y, (np.abs(y) < 1.0).astype(float)     # a 2 m wide flat pass


def test_edge_shares_of_a_flat_pass():
    y, p = _box()
    # lanes 2 m: the outer pass covers [-2, 0]: nothing beyond the edge
    assert ss.edge_shares(y, p, 0.0, 2.0, 5.0) == (0.0, 0.0)
    # lanes 1 m: the outer pass (of 100) covers [-1.5, 0.5]: a quarter of it beyond the edge
    off, drift = ss.edge_shares(y, p, 0.0, 1.0, 0.25)
    assert off == pytest.approx(0.25 / 100) and drift == pytest.approx(0.125 / 100)
    # 10 % of every pass carried airborne past the collectors: drift past any buffer
    off, drift = ss.edge_shares(y, p, 0.1, 1.0, 5.0)
    assert off == pytest.approx(0.9 * 0.25 / 100 + 0.1) and drift == pytest.approx(0.1)


def test_case_rows_under_dosed_share_and_work_rate():
    y, p = _box()
    rows = ss.case_rows(ss.Case(3.0, 5.0, "medium"), y, p, 0.0, 0.0, np.array([2.0, 3.0]), 5.0)
    assert [r["work_rate_ha_h"] for r in rows] == pytest.approx([3.6, 5.4])
    assert rows[0]["cv"] == pytest.approx(0.0) and rows[0]["underdosed"] == 0.0
    # 3 m lanes of a 2 m pass: a third of the ground gets nothing
    assert rows[1]["underdosed"] == pytest.approx(1 / 3)


def test_pareto_front():
    rows = [{"work_rate_ha_h": w, "cv": c, "drift_past_buffer": d}
            for w, c, d in [(5, 0.1, 0.01), (6, 0.2, 0.01), (5, 0.2, 0.02), (4, 0.05, 0.0),
                            (6, 0.2, 0.02)]]
    front = ss.pareto(rows)
    assert [(r["work_rate_ha_h"], r["cv"]) for r in front] == [(6, 0.2), (5, 0.1), (4, 0.05)]


def test_search_end_to_end(tmp_path, capsys):
    out = tmp_path / "o"
    assert main(["experiment", "spray-settings", "--heights", "3", "--speeds", "5",
                 "--spectra", "medium", "--spacings", "3:8:0.25", "--wind", "0", "-q",
                 "--draws", "0", "--out", str(out)]) == 0
    for f in ("settings.csv", "pareto.csv", "spray_settings.md", "pareto.png"):
        assert (out / f).stat().st_size > 0
    rows = list(csv.DictReader((out / "settings.csv").open()))
    assert len(rows) == 21
    # the widest spacing with CV <= 25 % is the mission's automatic lanes in calm air
    from ag_uav.config import load_config

    lanes = pattern.lane_choice(load_config(None, {"wind.speed_mps": 0.0,
                                                   "mission.swath_cv_max": 0.25, **EXACT}))
    ok = [float(r["spacing_m"]) for r in rows if float(r["cv"]) <= 0.25]
    assert max(ok) == lanes.swath_m
    assert "Pareto front" in capsys.readouterr().out


def test_bad_spectrum_is_a_config_error(capsys):
    assert main(["experiment", "spray-settings", "--spectra", "misty"]) == 2
    assert "--spectra" in capsys.readouterr().err


EXACT = {"forecast.speed_sigma_mps": 0.0, "forecast.direction_sigma_deg": 0.0}


def test_search_in_a_crosswind_is_the_lanes_test(tmp_path):
    """In a crosswind the search's exact-wind CV is the mission's lanes test's (the pass back
    lays the pass out's profile on the ground, not its mirror image)."""
    from ag_uav.config import load_config

    cfg = load_config(None, {"wind.speed_mps": 3.0, **EXACT})
    rows = ss.search(cfg, [ss.Case(3.0, 5.0, "medium")], 3.0, np.array([3.0, 4.0]), 5.0,
                     progress=False)
    lanes = pattern.lane_choice(cfg)
    for r in rows:
        # the lanes test meets the wind on the legs' right (-3 m/s), the search on their left
        # (the grid's cells are not quite symmetric about the track: 0.1 %)
        assert r["cv"] == pytest.approx(lanes.cv_at(r["spacing_m"]), rel=0.01)


def test_flown_winds_spread_about_the_forecast():
    w = ss.flown_winds(3.0, 0.0, 400, 1.5, 30.0, seed=0)
    assert w == ss.flown_winds(3.0, 0.0, 400, 1.5, 30.0, seed=0)     # seeded
    speed = np.hypot(*np.array(w).T)
    ang = np.degrees(np.arctan2(np.array(w)[:, 1], np.array(w)[:, 0]))
    assert abs(speed.mean() - 3.0) < 0.25 and 1.3 < speed.std() < 1.7
    assert abs(ang.mean()) < 5.0 and 26.0 < ang.std() < 34.0
    assert ss.flown_winds(3.0, 0.0, 3, 0.0, 0.0, seed=1) == [(3.0, 0.0)] * 3
