"""``ag-uav experiment controllers`` (spec building, paired statistics) and the controller
figures of ``ag-uav plot --controller``."""

from __future__ import annotations

import argparse

import pytest

from ag_uav.config import AxisGains, ConfigError
from ag_uav.jobs.experiments import controllers as ex

IT2 = ('[controller]\ntype = "it2-fpid"\n[controller.xy]\nreducer = "nt"\nke = 1.2\n'
       'kd = 1.3\nk0 = 6.0\nk1 = 3.0\nalpha = 0.3\ncm = 0.6\n[controller.z]\nreducer = "nt"\n'
       'ke = 2.2\nkd = 1.5\nk0 = 8.0\nk1 = 3.1\nalpha = 0.75\ncm = 0.6\n')


def _args(tmp_path, **kw):
    for c, fname in ex.CONTROLLERS.items():
        body = {"PID": '[controller]\ntype = "pid"\n',
                "T1-FPID": '[controller]\ntype = "t1-fpid"\n'}.get(c, IT2)
        (tmp_path / fname).write_text(body)
    p = argparse.ArgumentParser()
    ex.add_arguments(p)
    a = p.parse_args([])
    a.presets = str(tmp_path)
    a.out = str(tmp_path / "out")
    for k, v in kw.items():
        setattr(a, k, v)
    return a


def test_spec_conditions_and_presets(tmp_path):
    from ag_uav.jobs.batch import expand

    spec, ctrls, conds = ex.build_spec(_args(tmp_path, runs=2))
    assert ctrls == ex.ALL and len(ctrls) == 10
    assert conds == ["nominal", "unknown-model-error", "motor-failure", "weak-rotor"]
    tasks = expand(spec)
    assert len(tasks) == 2 * 10 * 4
    by = {(t.axis_values["condition"], t.axis_values["controller"], t.axis_values["seed"]): t
          for t in tasks}
    nom = by[("nominal", "PID", 100)].config
    me = by[("unknown-model-error", "IT2-KM", 101)].config
    mf = by[("motor-failure", "T1@NT", 100)].config
    wr = by[("weak-rotor", "IT2-BMM", 100)].config
    # the default navigation chain (INS, the default GNSS preset), no shadow filters
    assert nom["gps"]["preset"] == "rtk-m350" and nom["estimator"]["nav"] == "ins"
    assert nom["estimator"]["shadow"] == [] and nom["controller"]["type"] == "pid"
    assert nom["wind"]["speed_mps"] == 3.0 and nom["vehicle"]["unknown_payload_kg"] == 0.0
    assert me["vehicle"]["unknown_payload_kg"] == 1.0 and me["vehicle"]["payload_kg"] == 0.0
    assert me["spray"]["tank_l"] == 1.7
    assert me["vehicle"]["motor_tau_s"] == pytest.approx(0.08)
    assert me["wind"]["speed_mps"] == 6.0
    assert me["controller"]["type"] == "it2-fpid" and me["controller"]["xy"]["reducer"] == "nt"
    assert me["seed"] == 101
    assert mf["vehicle"]["rotor_thrust_loss"] == [0.25, 0.0, 0.0, 0.0]
    assert mf["controller"]["type"] == "t1-fpid" and mf["controller"]["xy"]["ke"] == 1.2
    # the weak rotor as the autopilot meets it: the fault, the detector and response on
    assert wr["vehicle"]["rotor_fault"] == {"rotor": 0, "at_s": 0.0, "efficiency": 0.75,
                                            "response": "auto", "detector": "px4"}
    assert wr["vehicle"]["rotor_thrust_loss"] == [0.0] * 4
    assert nom["vehicle"]["rotor_fault"]["rotor"] == -1
    with pytest.raises(ConfigError, match="seed0"):
        ex.build_spec(_args(tmp_path, seed0=11))


def test_spec_rejects_unknown_controller_and_missing_preset(tmp_path):
    with pytest.raises(ConfigError, match="controllers"):
        ex.build_spec(_args(tmp_path, controllers="PID,LQR"))
    a = _args(tmp_path)
    (tmp_path / "controller_t1.toml").unlink()
    with pytest.raises(ConfigError, match="controller_t1.toml"):
        ex.build_spec(a)


def test_paired_difference_and_counts():
    rows = []
    for s, (a, b) in enumerate([(1.0, 2.0), (2.0, 2.5), (3.0, 3.0), (1.5, 4.0)]):
        rows.append({"condition": "nominal", "controller": "IT2-KM", "seed": s, "status": "ok",
                     "tracking_rmse_m": a})
        rows.append({"condition": "nominal", "controller": "T1-FPID", "seed": s, "status": "ok",
                     "tracking_rmse_m": b})
    # a crashed flight drops its pair
    rows.append({"condition": "nominal", "controller": "IT2-KM", "seed": 9, "status": "crashed",
                 "tracking_rmse_m": 0.1})
    rows.append({"condition": "nominal", "controller": "T1-FPID", "seed": 9, "status": "ok",
                 "tracking_rmse_m": 5.0})
    m, h, mb, n, better = ex.paired(rows, "nominal", "IT2-KM", "T1-FPID", "tracking_rmse_m")
    assert n == 4 and better == 3
    assert m == pytest.approx(-1.0)
    assert mb == pytest.approx(2.875)
    assert h > 0
    _, lines, recs = ex.paired_table(rows, ["T1-FPID", "IT2-KM"], ["nominal"])
    assert lines[0][:3] == ["nominal", "IT2-KM", "T1-FPID"]
    assert recs[0]["pct"] == pytest.approx(-100.0 / 2.875)
    assert recs[0]["diff"] == pytest.approx(-1000.0)  # in mm


def test_controller_surfaces_at_half_alpha():
    """α = 0.5: NT and BMM equal the type-1 core, ζ = 0.5 halves it, only KM differs."""
    from ag_uav.analysis.controller_plots import surface_stats, surfaces

    g = AxisGains(alpha=0.5, cm=0.7, zeta=0.5)
    st = surface_stats(g)
    assert st["max|IT2-NT - T1|"] < 1e-12 and st["max|IT2-BMM - T1|"] < 1e-12
    assert 0.05 < st["max|IT2-KM - T1|"] < 0.07
    _, _, s, G = surfaces(g, "km", "it2-fpid")
    assert abs(s["IT2-zeta"] - 0.5 * s["T1"]).max() < 1e-12
    assert G == pytest.approx(0.35 * (4.0 + 0.25))
    g2 = AxisGains(alpha=0.3, cm=0.7)
    assert surface_stats(g2)["max|IT2-NT - T1|"] > 0.01


def test_plot_controller_writes_figures(tmp_path):
    from ag_uav.analysis.controller_plots import plot_controller

    paths, stats = plot_controller(None, tmp_path, {"controller.xy.alpha": 0.3,
                                                    "controller.z.alpha": 0.5,
                                                    "controller.z.cm": 0.7})
    assert sorted(p.name for p in paths) == ["fou_xy.png", "fou_z.png", "surfaces_xy.png",
                                             "surfaces_z.png"]
    assert all(p.stat().st_size > 1000 for p in paths)
    assert stats["xy"]["max|IT2-NT - T1|"] > 0.01 > stats["z"]["max|IT2-NT - T1|"]


def test_cli_plot_controller(tmp_path, capsys):
    from ag_uav.cli import main

    cfg = tmp_path / "c.toml"
    cfg.write_text('[controller]\ntype = "t1-fpid"\n[controller.xy]\nalpha = 0.5\ncm = 0.7\n')
    assert main(["plot", "--controller", str(cfg), "-o", str(tmp_path / "p")]) == 0
    out = capsys.readouterr().out
    assert "max|IT2-NT - T1| = 2.22e-16" in out or "max|IT2-NT - T1| = 0" in out
    assert (tmp_path / "p" / "surfaces_z.png").is_file()
    assert main(["plot", "--controller", "nope.toml"]) == 2
