"""``ag-uav experiment vehicles``: the table's rows from flight summaries, and the command's
files on a short run."""

from __future__ import annotations

import csv

import pytest

from ag_uav.jobs.experiments.vehicles import fault_row, job_row


def test_job_row_work_rate_includes_the_base_visits():
    s = {"completed": True, "field_area_m2": 20000.0, "coverage_fraction": 0.99,
         "job_time_s": 3600.0, "sorties": 3, "energy_wh": 990.0, "dose_cv": 0.1,
         "underdosed_fraction": 0.02, "drift_fraction": 0.001, "fill_l": 2.5}
    r = job_row("x8-40l", "f", s)
    assert r["work_rate_ha_per_h"] == pytest.approx(1.98)
    assert r["energy_wh_per_ha"] == pytest.approx(500.0)
    assert r["underdosed_m2"] == pytest.approx(400.0)
    assert r["batteries"] == 3 and r["fill_l"] == 2.5


def test_fault_row_names_the_end():
    rf = {"rotor": 2, "at_s": 100.0, "detected_s": 100.09, "detection_delay_s": 0.09,
          "action": "re-allocated ..., landing", "landed_s": 110.0, "touchdown_mps": 0.3}
    r = fault_row("x8-40l", 4, {"rotor_fault": rf, "crashed": False, "completed": False})
    assert r["end"].startswith("landed at t=110.0 s") and r["delay_s"] == 0.09
    r = fault_row("m350", 1, {"rotor_fault": rf, "crashed": True, "crash_reason": "x"})
    assert r["end"] == "crashed: x"


@pytest.mark.slow
def test_the_command_writes_its_tables(tmp_path):
    from ag_uav.cli import main

    rc = main(["experiment", "vehicles", "--presets", "m350", "--set", "sim.max_time_s=15",
               "--out", str(tmp_path)])
    assert rc == 0
    rows = list(csv.DictReader(open(tmp_path / "vehicles.csv")))
    assert [r["preset"] for r in rows] == ["m350"]
    assert (tmp_path / "vehicles.png").stat().st_size > 1000


def test_a_bad_preset_is_one_line(capsys):
    from ag_uav.cli import main

    assert main(["experiment", "vehicles", "--presets", "x9"]) == 2
    assert "--presets" in capsys.readouterr().err
