"""``ag-uav experiment optimisers``: BB-BC, PSO and CMA-ES tuned at an equal budget."""

from __future__ import annotations

import argparse
import csv
import math

import numpy as np
import pytest
import tomli_w

from ag_uav.config import ConfigError
from ag_uav.jobs.experiments import optimisers as ex

TINY = {"name": "tiny", "noise_seed": 0, "base": {"wind.turbulence": "none"},
        "params": {"controller.xy.k0": {"lo": 0.5, "hi": 12.0},
                   "controller.xy.ke": {"lo": 0.2, "hi": 5.0, "log": True}},
        "scenarios": [{"kind": "step", "axis": "x", "size": 1.0, "duration": 2.0,
                       "t_step": 0.5}]}


def _args(tmp_path, *argv: str) -> argparse.Namespace:
    spec = tmp_path / "tiny.toml"
    spec.write_text(tomli_w.dumps(TINY))
    p = argparse.ArgumentParser()
    ex.add_arguments(p)
    return p.parse_args(["--spec", str(spec), "--out", str(tmp_path / "out"), "--workers", "1",
                         "-q", *argv])


def test_tiny_experiment_writes_table_csv_plot_and_resumes(tmp_path):
    a = _args(tmp_path, "--pop", "4", "--iters", "2", "--seeds", "2")
    assert ex.main(a) == 0
    out = tmp_path / "out"
    rows = list(csv.DictReader((out / "optimisers.csv").open()))
    assert len(rows) == 3 * 2 * 2  # optimisers × seeds × iterations
    assert {r["optimizer"] for r in rows} == {"bbbc", "pso", "cmaes"}
    assert [int(r["evaluations"]) for r in rows[:2]] == [4, 8]
    for o in ex.OPTIMISERS:
        ev, best = ex.curves([{**r, "seed": int(r["seed"]), "evaluations": int(r["evaluations"]),
                               "best_so_far": float(r["best_so_far"])} for r in rows], o)
        assert best.shape == (2, 2) and np.all(np.diff(best, axis=1) <= 0.0)  # best-so-far
        assert np.all(np.isfinite(best)) and np.all(best > 0.0)
    md = (out / "optimisers.md").read_text()
    for label in ("BB-BC", "PSO", "CMA-ES", "Mann–Whitney", "8 evaluations per tuning"):
        assert label in md
    assert (out / "optimisers.png").stat().st_size > 10_000
    # every tuning is an ordinary checkpointed tune; --resume re-reads them, flies nothing new
    assert (out / "runs" / "cmaes-s2" / "checkpoint.json").exists()
    before = (out / "optimisers.csv").read_text()
    assert ex.main(_args(tmp_path, "--pop", "4", "--iters", "2", "--seeds", "2",
                         "--resume")) == 0
    assert (out / "optimisers.csv").read_text() == before


def test_evals_to_reach_and_summary():
    ev = np.array([10, 20, 30])
    best = np.array([[5.0, 1.04, 1.0], [3.0, 3.0, 2.0]])
    assert ex.evals_to_reach(ev, best, 1.05) == [20.0, math.inf]
    rows = [{"optimizer": o, "seed": s, "iteration": k + 1, "evaluations": int(ev[k]),
             "best_so_far": float(b[k]), "wall_s": 1.0}
            for o, bb in (("bbbc", best), ("pso", best + 1.0)) for s, b in enumerate(bb)
            for k in range(3)]
    header, lines, overall = ex.summary(rows, ["bbbc", "pso"])
    assert overall == 1.0
    assert lines[0][:6] == ["BB-BC", "2", "1.5", "1–2", "> 30", "1/2"]
    assert lines[1][4:6] == ["> 30", "0/2"] and lines[1][-1] == "3.0"


def test_bad_arguments(tmp_path):
    for argv in (["--optimizers", "ga"], ["--pop", "3"], ["--seeds", "0"],
                 ["--resume", "--fresh"]):
        with pytest.raises(ConfigError):
            ex.main(_args(tmp_path, *argv))
