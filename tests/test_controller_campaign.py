"""Model error the controller does not know, held-out validation of a tuning, the
tuning campaign (resume, median pick) and the shape-vs-gain controls of
``ag-uav experiment controllers``."""

from __future__ import annotations

import json

import numpy as np
import pytest

from ag_uav.config import ConfigError, config_from_dict
from ag_uav.jobs.experiments import controller_tunings as ct
from ag_uav.jobs.experiments import controllers as ex
from ag_uav.jobs.tune import evaluate_candidate, spec_from_dict, top_candidates, validate


# ------------------------------------------------------------- model error the controller lacks
def test_unknown_payload_leaves_the_controllers_model_unchanged():
    from ag_uav.vehicle.cascade import make_cascade
    from ag_uav.vehicle.mjcf import build_vehicle

    known = build_vehicle(config_from_dict({}))
    cfg = config_from_dict({"vehicle": {"unknown_payload_kg": 1.0,
                                        "unknown_payload_pos_m": [0.15, 0.10, 0.0]}})
    veh = build_vehicle(cfg)
    assert veh.mass == pytest.approx(known.mass + 1.0, abs=1e-9)
    assert veh.ctrl_mass == pytest.approx(known.mass, abs=1e-12)
    assert veh.ctrl_inertia == pytest.approx(known.inertia)
    assert np.array(veh.ctrl_rotor_xy) == pytest.approx(np.array(known.rotor_xy))
    # the centre of gravity moved by m_u r / m_total towards the payload: the rotor arms about
    # it changed, the controller's did not
    com_shift = np.array(known.rotor_xy[0]) - np.array(veh.rotor_xy[0])
    assert com_shift == pytest.approx(np.array([0.15, 0.10]) * 1.0 / veh.mass, abs=2e-3)
    cas = make_cascade(cfg, veh)
    assert cas.mass == pytest.approx(known.mass) and cas.mass < veh.mass - 0.99
    # the default vehicle: the controller's model is the vehicle
    assert known.ctrl_mass == known.mass and known.ctrl_rotor_xy == known.rotor_xy


def test_the_spray_jobs_mass_updates_leave_the_unknown_payload_out():
    """On a mission the tank's mass changes reach the controller (Sprayer.set_liquid_mass): it gets
    the liquid, never the unknown payload, while the physics carries both."""
    import mujoco

    from ag_uav.engine.sprayer import Sprayer
    from ag_uav.vehicle.cascade import make_cascade
    from ag_uav.vehicle.mjcf import build_vehicle
    from ag_uav.world.spray_job import SprayJob

    cfg = config_from_dict({"vehicle": {"unknown_payload_kg": 1.0,
                                        "unknown_payload_pos_m": [0.15, 0.10, 0.0]}})
    veh = build_vehicle(cfg)
    data = mujoco.MjData(veh.model)
    casc = make_cascade(cfg, veh)
    job = SprayJob(base_xy=np.zeros(2), sorties=[], fill_l=1.7, dry_mass_kg=6.47, service_s=0.0)
    sp = Sprayer(cfg, veh, data, casc, {}, job, 1, 0.01)
    sp.set_liquid_mass(1.5)
    assert casc.mass == pytest.approx(6.471 + 1.5, abs=1e-5)  # 1 g: the empty tank geom
    assert veh.model.body_subtreemass[veh.body_id] == pytest.approx(6.471 + 1.0 + 1.5, abs=1e-5)


def test_rotor_thrust_loss_scales_one_actuator_not_the_command_range():
    from ag_uav.vehicle.mjcf import build_vehicle

    veh = build_vehicle(config_from_dict({"vehicle": {"rotor_thrust_loss": [0.25, 0, 0, 0]}}))
    m = veh.model
    assert m.actuator("thrust_fr").gear[2] == pytest.approx(0.75)
    assert m.actuator("thrust_fl").gear[2] == 1.0
    assert abs(m.actuator("thrust_fr").gear[5]) == pytest.approx(0.75 * 0.016)
    assert m.actuator("thrust_fr").ctrlrange[1] == pytest.approx(veh.f_max)


@pytest.mark.parametrize("veh, needle", [
    ({"unknown_payload_kg": 1.0, "unknown_payload_pos_m": [0.8, 0.0, 0.0]},
     "unknown_payload_pos_m[0]"),
    ({"rotor_thrust_loss": [0.95, 0, 0, 0]}, "rotor_thrust_loss[0]"),
    ({"rotor_thrust_loss": [0.1, 0.1]}, "one value per rotor"),
])
def test_model_error_keys_are_validated(veh, needle):
    with pytest.raises(ConfigError) as e:
        config_from_dict({"vehicle": veh})
    assert needle in str(e.value) and "\n" not in str(e.value)


def test_experiment_conditions_stay_within_take_off_mass():
    me = ex.CONDITIONS["unknown-model-error"]
    cfg = config_from_dict({})
    total = cfg.vehicle.mass_kg + me["vehicle.unknown_payload_kg"] + me["spray.tank_l"]
    assert total <= ex.MTOW_KG
    assert me["vehicle.motor_tau_s"] == pytest.approx(2 * cfg.vehicle.motor_tau_s)


# ---------------------------------------------------------------------- held-out validation
def _spec(**kw):
    d = {"name": "v", "pop": 3, "iters": 1, "base": {"wind.turbulence": "light"},
         "params": {"controller.xy.k0": {"lo": 0.5, "hi": 12.0}},
         "scenarios": [{"kind": "mission", "max_time_s": 4.0}],  # seeded: wind, GNSS
         "noise_seeds": [1, 2], "validation_seeds": [11, 12], "validate_top": 2}
    d.update(kw)
    return spec_from_dict(d)


def test_validation_seeds_must_be_disjoint_from_the_tuning_seeds():
    with pytest.raises(ConfigError, match="disjoint"):
        _spec(validation_seeds=[2, 11])
    with pytest.raises(ConfigError, match="disjoint"):
        spec_from_dict({**_spec_dict(), "noise_seed": 5, "validation_seeds": [5]})
    with pytest.raises(ConfigError, match="give one"):
        spec_from_dict({**_spec_dict(), "noise_seed": 5, "noise_seeds": [1]})


def _spec_dict():
    return {"params": {"controller.xy.k0": {"lo": 0.5, "hi": 12.0}},
            "scenarios": [{"kind": "step"}]}


def test_validation_flies_the_top_candidates_on_the_held_out_seeds():
    from ag_uav.jobs.executor import SerialExecutor

    spec = _spec()
    assert spec.seeds == [1, 2] and spec.validation_seeds == [11, 12]
    cache = {json.dumps([v]): {"cost": c} for v, c in [(3.0, 2.0), (6.0, 1.0), (9.0, 5.0)]}
    top = top_candidates(spec, cache, 2)
    assert [v for v, _ in top] == [[6.0], [3.0]]
    val = validate(spec, top, SerialExecutor())
    one = [evaluate_candidate({"spec": spec, "values": [6.0], "seeds": [s]})["cost"]
           for s in (11, 12)]
    assert val[0]["validation_cost"] == pytest.approx(np.mean(one), rel=1e-12)
    tune = evaluate_candidate({"spec": spec, "values": [6.0]})["cost"]
    assert val[0]["validation_cost"] != tune  # other seeds, other turbulence


# ------------------------------------------------------------------------------- the campaign
def _finished(out, label, seed, val, *, done=True):
    d = ct.tuning_dir(out, label, seed)
    d.mkdir(parents=True)
    (d / "tune.json").write_text(json.dumps({
        "shipped_tune_cost": val - 0.1, "shipped_validation_cost": val if done else None,
        "best_cost": val - 0.2, "default_cost": 9.0, "wall_s": 50.0,
        "shipped": {"controller.xy.kp": val}}))


def test_campaign_resume_skips_finished_tunings(tmp_path):
    for s, v in [(1, 3.0), (2, 1.0)]:
        _finished(tmp_path, "PID", s, v)
    said = []
    # no spec files in tmp_path / "specs": any tuning that ran would fail to load its spec
    rows = ct.run_campaign(["PID"], [1, 2], tmp_path / "specs", tmp_path, None, said.append)
    assert [r["validation_cost"] for r in rows] == [3.0, 1.0]
    assert all("skipped" in s for s in said)
    _finished(tmp_path, "PID", 3, 2.0, done=False)  # killed before its validation: re-run
    with pytest.raises(ConfigError, match="no such file"):
        ct.run_campaign(["PID"], [1, 2, 3], tmp_path / "specs", tmp_path, None, said.append)


def test_median_pick_by_validation_cost():
    rows = [{"controller": "A", "seed": s, "validation_cost": v}
            for s, v in zip(range(1, 6), [5.0, 1.0, 3.0, 2.0, 4.0], strict=True)]
    rows += [{"controller": "B", "seed": s, "validation_cost": v}
             for s, v in zip(range(1, 5), [4.0, 1.0, 3.0, 2.0], strict=True)]
    picks = ct.median_pick(rows)
    assert picks["A"]["seed"] == 3 and picks["A"]["validation_cost"] == 3.0
    assert picks["B"]["validation_cost"] == 2.0  # even count: the lower median


# ---------------------------------------------------------------------- shape-vs-gain controls
@pytest.mark.parametrize("reducer, alpha", [("bmm", 0.26), ("km", 0.46), ("nt", 0.35),
                                            ("zeta", 0.17)])
def test_t1_control_has_the_it2_linearised_gains(reducer, alpha):
    from controllers.fpid import FPID, IT2FPID

    g = {"ke": 1.2, "kd": 1.3, "k0": 6.0, "k1": 3.0, "alpha": alpha, "cm": 0.62,
         "reducer": reducer, "zeta": 0.36}
    it2 = {"controller": {"type": "it2-fpid", "xy": g, "z": {**g, "alpha": 0.75}}}
    t1 = ex.t1_at_linearised(it2)
    assert t1["controller"]["type"] == "t1-fpid"
    for ax in ("xy", "z"):
        a = it2["controller"][ax]
        ref = IT2FPID(a["ke"], a["kd"], a["k0"], a["k1"], alpha=a["alpha"], cm=a["cm"],
                      reducer=reducer, zeta=a["zeta"]).equivalent_pid()
        b = t1["controller"][ax]
        got = FPID(b["ke"], b["kd"], b["k0"], b["k1"], cm=b["cm"]).equivalent_pid()
        assert got == pytest.approx(ref, rel=1e-5)
        assert 0 < b["cm"] <= 1.0


def test_verdict_keeps_the_simplest_not_worse_controller():
    rows = []
    rng = np.random.default_rng(0)
    for cond in ex.JUDGED:
        for s in range(8):
            base = 0.05 + 0.01 * rng.standard_normal()
            for c, d in [("PID", 0.02), ("T1-FPID", 0.0001 * (-1) ** s), ("IT2-BMM", 0.0)]:
                rows.append({"condition": cond, "controller": c, "seed": s, "status": "ok",
                             "tracking_rmse_m": base + d})
    win, why = ex.verdict(rows, ["PID", "T1-FPID", "IT2-BMM"], list(ex.JUDGED))
    assert win == "T1-FPID"
    assert why[1].split("not worse than it: ")[1].split(", ") == ["T1-FPID", "IT2-BMM"]
    # a flight lost in any condition, the failing motor included, disqualifies
    rows.append({"condition": "motor-failure", "controller": "T1-FPID", "seed": 99,
                 "status": "crashed"})
    win, why = ex.verdict(rows, ["PID", "T1-FPID", "IT2-BMM"], [*ex.JUDGED, "motor-failure"])
    assert win == "IT2-BMM" and "T1-FPID in motor-failure" in why[0]


def test_every_tuning_flown_gives_one_row_per_controller(tmp_path):
    from pathlib import Path

    from ag_uav.jobs.executor import SerialExecutor

    rows = [{"controller": "PID", "seed": s, "spec": "examples/tune_pid.toml",
             "tune_cost": 0.2, "validation_cost": v,
             "gains": {"controller.xy.kp": kp, "controller.z.kp": 5.0}}
            for s, v, kp in [(1, 0.3, 4.0), (2, 0.2, 8.0), (3, 0.25, 6.0)]]
    root = Path(__file__).resolve().parents[1]
    h, lines, recs = ct.fly_every_tuning(rows, root / "examples", tmp_path, SerialExecutor(),
                                         [100], {"sim.max_time_s": 4.0, "log.enabled": False})
    assert [line[0] for line in lines] == ["PID"] and len(recs) == 3
    assert len({r["tracking_mm"] for r in recs}) == 3  # three different tunings flew
    picked = next(r for r in recs if r["seed"] == 3)  # the median by validation cost
    assert lines[0][3] == f"{picked['tracking_mm']:.1f}"
    assert (tmp_path / "every-tuning" / "presets" / "PID_seed2.toml").read_text().count("kp = 8.0")
