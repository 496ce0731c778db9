"""The paper's numerical experiment: fast batched engine equals the library filters, outputs."""

import subprocess
import sys

import numpy as np
import pytest

from ag_uav.experiments import numerical as num


@pytest.fixture(scope="module")
def small():
    import dataclasses

    return dataclasses.replace(num.Setup(), max_steps=300)


def test_fast_engine_equals_library_filters(small):
    ests = ["kf", "mckf", "pca-kf", "pca-mckf", "kf-bias", "kf-diff"]
    out = num.run_experiment(small, list(num.CASES), ests, 2, workers=1, chunk=2,
                             engine="fast", timing_runs=1)
    assert out["check"] and max(out["check"].values()) < 1e-8
    rows = out["rows"]
    assert {r["estimator"] for r in rows} >= set(ests)
    assert all(np.isfinite(r["rmse_m"]) for r in rows)


def test_serial_equals_parallel(small):
    a = num.run_experiment(small, ["coloured-impulsive"], ["kf", "mckf"], 4, workers=1, chunk=1,
                           timing_runs=0)["rows"]
    b = num.run_experiment(small, ["coloured-impulsive"], ["kf", "mckf"], 4, workers=2, chunk=1,
                           timing_runs=0)["rows"]
    key = lambda r: (r["case"], r["run"], r["estimator"])  # noqa: E731
    strip = lambda r: {k: v for k, v in r.items() if "us" not in k}  # noqa: E731
    assert [strip(r) for r in sorted(a, key=key)] == [strip(r) for r in sorted(b, key=key)]


def test_command_writes_table_csv_and_plots(tmp_path):
    r = subprocess.run([sys.executable, "-m", "ag_uav.cli", "experiment", "numerical", "--runs",
                        "2", "--out", str(tmp_path), "--workers", "1", "--timing-runs", "1"],
                       capture_output=True, text=True, timeout=300)
    assert r.returncode == 0, r.stderr[-2000:]
    for f in ("results.csv", "summary.csv", "numerical.md", "tracks.png", "rmse.png"):
        assert (tmp_path / f).exists(), f
    assert "paper RMSE" in r.stdout
