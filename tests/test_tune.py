"""Tuning: spec validation, the cost, default gains in the population, outputs, SIGKILL + resume."""

from __future__ import annotations

import json
import math
import os
import signal
import subprocess
import sys
import time
import tomllib
from pathlib import Path

import numpy as np
import pytest
import tomli_w

from ag_uav.config import ConfigError, load_config
from ag_uav.jobs.tune import (
    default_values,
    evaluate_candidate,
    gains_toml,
    load_spec,
    run_tune,
    spec_from_dict,
)

ROOT = Path(__file__).resolve().parents[1]


def tiny(**kw) -> dict:
    d = {"name": "tiny", "pop": 4, "iters": 3, "seed": 3,
         "base": {"wind.turbulence": "none"},
         "params": {"controller.xy.k0": {"lo": 0.5, "hi": 12.0},
                    "controller.xy.ke": {"lo": 0.2, "hi": 5.0, "log": True}},
         "scenarios": [{"kind": "step", "axis": "x", "size": 1.0, "duration": 2.0,
                        "t_step": 0.5}]}
    d.update(kw)
    return d


@pytest.mark.parametrize("patch, needle", [
    ({"bogus": 1}, "unknown key"),
    ({"optimizer": "ga"}, "optimizer"),
    ({"metric": "iae"}, "metric"),
    ({"params": {}}, "params"),
    ({"params": {"controller.xy.ke": {"lo": 2.0, "hi": 1.0}}}, "lo < hi"),
    ({"params": {"controller.xy.ke": {"lo": 0.0, "hi": 1.0, "log": True}}}, "log = true"),
    ({"params": {"controller.xy.k1": {"lo": -1.0, "hi": 1.0}}}, "controller.xy.k1 = -1.0"),
    ({"params": {"controller.type": {"lo": 0.0, "hi": 1.0}}}, "numeric"),
    ({"scenarios": [{"kind": "spin"}]}, "kind"),
    ({"scenarios": [{"kind": "step", "axis": "w"}]}, "axis"),
    ({"scenarios": [{"kind": "step", "axis": {"a": 1}}]}, "scenarios[0].axis = { a = 1 }"),
    ({"scenarios": [{"kind": ["step"]}]}, "scenarios[0].kind = [\"step\"]"),
    ({"scenarios": [{"kind": "step"}, {"kind": "step"}]}, "duplicate"),
    ({"optimizer_options": {"c1": 2.0}}, "optimizer_options.c1"),
    ({"pop": 1}, "pop"),
    ({"dose_weights": {"dose_rmse": 1.0}}, "dose_weights.dose_rmse"),
    ({"dose_weights": {"dose_cv": -1.0}}, "dose_weights.dose_cv"),
    ({"dose_weights": {"dose_cv": 1.0}, "base": {"spray.deposition": False}}, "deposition"),
])
def test_spec_errors_are_one_line(patch, needle):
    with pytest.raises(ConfigError) as e:
        spec_from_dict(tiny(**patch))
    assert needle in str(e.value) and "\n" not in str(e.value)


def test_cost_is_deterministic_and_crash_is_penalised():
    spec = spec_from_dict(tiny())
    task = {"spec": spec, "values": default_values(spec)}
    a, b = evaluate_candidate(task), evaluate_candidate(task)
    assert a["cost"] == b["cost"] and 0 < a["cost"] < spec.crash_penalty and not a["crash"]
    worse = evaluate_candidate({"spec": spec, "values": [0.5, 0.2]})  # sluggish gains
    assert worse["cost"] > a["cost"]
    itae = evaluate_candidate({"spec": spec_from_dict(tiny(metric="itae")),
                               "values": default_values(spec)})
    assert itae["cost"] != a["cost"]
    # too heavy to hover: it falls; a crash costs between 1x and 2x the penalty
    heavy = spec_from_dict(tiny(base={"vehicle.payload_kg": 10.0}, crash_penalty=50.0))
    r = evaluate_candidate({"spec": heavy, "values": default_values(heavy)})
    assert "ground contact" in r["crash"] and 50.0 < r["cost"] <= 100.0


def test_tune_keeps_default_in_population_and_writes_outputs(tmp_path):
    spec = spec_from_dict(tiny(iters=2))
    seen: list[dict] = []
    res = run_tune(spec, tmp_path, progress=False, on_iteration=lambda k, s: seen.append(s))
    assert res.iterations == 2 and len(seen) == 2 and len(res.history) == 2
    assert res.history[1] <= res.history[0]
    assert res.best_cost <= res.default_cost  # the default gains were candidate 0
    evals = [json.loads(line) for line in (tmp_path / "evals.jsonl").read_text().splitlines()]
    first = [e for e in evals if e["iter"] == 1 and e["i"] == 0][0]
    x0 = [p.to_internal(v) for p, v in zip(spec.params, default_values(spec), strict=True)]
    assert first["u"] == pytest.approx(x0) and first["result"]["cost"] == pytest.approx(
        res.default_cost)
    # the TOML fragment is a config that `fly --config` accepts, with the tuned values
    frag = tmp_path / "best_gains.toml"
    cfg = load_config(frag)
    assert cfg.controller.xy.k0 == pytest.approx(res.best_values[0], rel=0, abs=0)
    assert cfg.controller.xy.ke == pytest.approx(res.best_values[1], rel=0, abs=0)
    assert tomllib.loads(frag.read_text())["controller"]["xy"]["k0"] == res.best_values[0]
    for f in ("convergence.png", "before_after.md", "tune.json", "checkpoint.json"):
        assert (tmp_path / f).stat().st_size > 0
    assert "controller.xy.k0" in (tmp_path / "before_after.md").read_text()
    with pytest.raises(ConfigError, match="--resume"):
        run_tune(spec, tmp_path, progress=False)
    # more iterations on resume continue the same run
    more = run_tune(spec, tmp_path, resume=True, iters=3, progress=False, outputs=False)
    assert more.iterations == 3 and more.history[:2] == res.history


def test_pso_runs_and_gains_toml():
    spec = spec_from_dict(tiny(optimizer="pso", pop=3, iters=2))
    import tempfile

    with tempfile.TemporaryDirectory() as d:
        res = run_tune(spec, d, progress=False, outputs=False)
    assert res.iterations == 2 and math.isfinite(res.best_cost)
    text = gains_toml(spec, [2.0, 0.5], comment="x")
    assert text.startswith("# x") and tomllib.loads(text) == {
        "controller": {"xy": {"k0": 2.0, "ke": 0.5}}}


def test_cmaes_tune_keeps_default_and_resumes_identically(tmp_path):
    spec = spec_from_dict(tiny(optimizer="cmaes", pop=4, iters=2,
                               optimizer_options={"sigma": 0.2}))
    ref = run_tune(spec, tmp_path / "ref", progress=False, outputs=False)
    assert ref.iterations == 2 and ref.n_evals == 8 and math.isfinite(ref.best_cost)
    run_tune(spec, tmp_path / "cut", iters=1, progress=False, outputs=False)
    evals = [json.loads(ln) for ln in (tmp_path / "cut" / "evals.jsonl").read_text().splitlines()]
    x0 = [p.to_internal(v) for p, v in zip(spec.params, default_values(spec), strict=True)]
    assert [e["u"] for e in evals if e["iter"] == 1 and e["i"] == 0] == [x0]  # default gains
    more = run_tune(spec, tmp_path / "cut", resume=True, progress=False, outputs=False)
    assert more.history == ref.history and more.best_values == ref.best_values
    with pytest.raises(ConfigError, match="optimizer_options.spread"):
        spec_from_dict(tiny(optimizer="cmaes", optimizer_options={"spread": 0.5}))


def _eval_keys(path: Path) -> list[tuple[int, int]]:
    out = []
    for line in path.read_text().splitlines():
        try:
            e = json.loads(line)
        except json.JSONDecodeError:
            continue
        out.append((e["iter"], e["i"]))
    return out


def test_sigkill_then_resume_equals_uninterrupted(tmp_path):
    d = tiny(iters=8)
    spec_path = tmp_path / "tune.toml"
    spec_path.write_text(tomli_w.dumps(d))
    out = tmp_path / "killed"
    cmd = [sys.executable, "-m", "ag_uav.cli", "tune", str(spec_path), "--out", str(out),
           "--workers", "1", "--quiet"]
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    proc = subprocess.Popen(cmd, env=env, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    ck = out / "checkpoint.json"
    t0 = time.monotonic()
    while time.monotonic() - t0 < 60 and proc.poll() is None:
        try:
            if json.loads(ck.read_text())["optimizer"]["iteration"] >= 2:
                break
        except (FileNotFoundError, json.JSONDecodeError, KeyError):
            pass
        time.sleep(0.005)
    proc.send_signal(signal.SIGKILL)
    proc.wait()
    it_killed = json.loads(ck.read_text())["optimizer"]["iteration"]
    assert 2 <= it_killed < 8, "the kill must land half-way"
    r = subprocess.run(cmd + ["--resume"], env=env, capture_output=True, text=True)
    assert r.returncode == 0, r.stderr
    keys = _eval_keys(out / "evals.jsonl")
    assert len(keys) == len(set(keys))  # no evaluation was run twice
    ref = run_tune(load_spec(spec_path), tmp_path / "ref", progress=False, outputs=False)
    got = json.loads(ck.read_text())["optimizer"]
    assert got["iteration"] == ref.iterations == 8
    assert got["history"] == ref.history
    ref_ck = json.loads((tmp_path / "ref" / "checkpoint.json").read_text())["optimizer"]
    assert np.array_equal(np.array(got["best_x"]), np.array(ref_ck["best_x"]))
    assert got["population"] == ref_ck["population"] and got["rng"] == ref_ck["rng"]
    assert sorted(keys) == sorted(_eval_keys(tmp_path / "ref" / "evals.jsonl"))
    gains = tomllib.loads((out / "best_gains.toml").read_text())
    assert gains["controller"]["xy"]["k0"] == pytest.approx(ref.best_values[0], rel=1e-12)


def test_mission_fast_path_equals_simulate(tmp_path):
    from ag_uav.engine.missions import simulate
    from ag_uav.jobs.batch import write_rect_field
    from ag_uav.jobs.tune import mission_trajectory

    f = write_rect_field(tmp_path / "f.geojson", 18.0, 12.0)
    cfg = load_config(None, {"mission.field": str(f), "mission.headland_m": 0.0,
                             "sim.max_time_s": 8.0, "log.enabled": False, "seed": 5})
    res = simulate(cfg)
    for _ in range(2):  # the second call uses the cached plan and reference
        t, p_true, p_ref, motors, crash, _, full = mission_trajectory(cfg)
        assert np.array_equal(t, res.t) and np.array_equal(p_true, res.p_true)
        assert np.array_equal(p_ref, res.p_ref) and np.array_equal(motors, res.motors)
        assert crash is None and full == 8.0


def test_integer_keys_get_integer_candidates():
    """The optimisers search reals; an integer config key (estimator.window) gets the nearest
    integer, so the candidate loads (it was refused as "expected an integer")."""
    from ag_uav.config import config_from_dict
    from ag_uav.jobs.tune import candidate_config, spec_from_dict

    spec = spec_from_dict({"params": {"estimator.window": {"lo": 5, "hi": 30},
                                      "controller.xy.ke": {"lo": 0.5, "hi": 3.0}},
                           "scenarios": [{"kind": "step", "axis": "x"}]})
    d = candidate_config(spec, [12.6, 1.25])
    cfg = config_from_dict(d)
    assert cfg.estimator.window == 13 and isinstance(cfg.estimator.window, int)
    assert cfg.controller.xy.ke == 1.25


def test_an_engine_batch_failure_is_logged_and_counted(tmp_path):
    """Candidates of different control rates cannot share an engine batch: the chunk is
    evaluated one candidate at a time, with a warning and a counter (never silently)."""
    spec = spec_from_dict(tiny(
        pop=3, iters=1, base={"wind.turbulence": "none", "estimator.name": "true"},
        params={"sim.control_hz": {"lo": 100.0, "hi": 100.00001}},
        scenarios=[{"kind": "step", "axis": "x", "size": 1.0, "duration": 0.5,
                    "t_step": 0.2}]))
    said: list[str] = []
    res = run_tune(spec, tmp_path, progress=False, warn=said.append)
    assert res.n_fallback == 3
    assert len(said) == 1 and "evaluated one at a time" in said[0]
    assert "must share sim.control_hz" in said[0]
    ck = json.loads((tmp_path / "checkpoint.json").read_text())
    assert ck["iterations"][0]["engine_fallbacks"] == 3
    assert json.loads((tmp_path / "tune.json").read_text())["engine_fallbacks"] == 3
    evals = [json.loads(line) for line in (tmp_path / "evals.jsonl").read_text().splitlines()]
    assert all("ValueError" in e["result"]["engine_fallback"] for e in evals)
    alone = evaluate_candidate({"spec": spec, "values": [100.0]})
    assert "engine_fallback" not in alone
    assert [e["result"]["cost"] for e in evals if e["i"] == 0] == [alone["cost"]]


def test_damaged_tune_files_are_one_line_or_skipped(tmp_path):
    spec = spec_from_dict(tiny(iters=1, pop=2))
    run_tune(spec, tmp_path, progress=False, outputs=False)
    ev = tmp_path / "evals.jsonl"
    ev.write_bytes(ev.read_bytes() + b"\xff\xfe not json\n")
    said: list[str] = []
    more = run_tune(spec, tmp_path, resume=True, iters=2, progress=False, outputs=False,
                    warn=said.append)
    assert more.iterations == 2 and len(said) == 1 and "skipped 1 unreadable line" in said[0]
    (tmp_path / "checkpoint.json").write_bytes(b"\x00\xff{")
    with pytest.raises(ConfigError, match="damaged") as e:
        run_tune(spec, tmp_path, resume=True, iters=3, progress=False, outputs=False)
    assert "\n" not in str(e.value)


def test_a_dose_cost_term_weighs_the_missions_dose_metrics(tmp_path):
    """``[dose_weights]`` adds Σ w·m over the flown mission's dose metrics (the summary's own
    figures); ``metric = "none"`` leaves the tracking error out."""
    from ag_uav.engine.missions import simulate
    from ag_uav.jobs.batch import write_rect_field

    f = str(write_rect_field(tmp_path / "f.geojson", 24.0, 12.0))
    base = {"mission.field": f, "wind.turbulence": "none", "estimator.name": "true",
            "estimator.shadow": []}
    sc = [{"kind": "mission", "name": "m", "max_time_s": 25.0}]
    w = {"dose_cv": 1.0, "underdosed_fraction": 2.0, "offtarget_deposit_fraction": 3.0}
    plain = spec_from_dict(tiny(base=base, scenarios=sc, metric="none"))
    dosed = spec_from_dict(tiny(base=base, scenarios=sc, metric="none", dose_weights=w))
    assert plain.hash() != dosed.hash()
    a = evaluate_candidate({"spec": plain, "values": default_values(plain)})
    b = evaluate_candidate({"spec": dosed, "values": default_values(dosed)})
    cfg = load_config(None, {**base, "sim.max_time_s": 25.0, "log.enabled": False, "seed": 0})
    s = simulate(cfg).summary
    want = sum(v * s[k] for k, v in w.items())
    assert a["cost"] == 0.0 and not b["crash"]
    assert want > 0.1 and b["cost"] == pytest.approx(want, rel=1e-12)
