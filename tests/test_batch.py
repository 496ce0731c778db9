"""Batches: spec validation, expansion, rows, journal/resume (SIGKILL), executor independence."""

from __future__ import annotations

import json
import math
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from ag_uav.config import Config, ConfigError
from ag_uav.jobs.batch import (
    BatchOptions,
    Journal,
    RunTask,
    expand,
    is_timing_column,
    load_spec,
    mean_ci,
    read_results_csv,
    run_batch,
    run_task,
    spec_from_dict,
    write_rect_field,
    write_report,
)
from ag_uav.jobs.executor import DaskExecutor, LocalPoolExecutor, SerialExecutor

ROOT = Path(__file__).resolve().parents[1]

#: no progress bar, no report
QUIET = BatchOptions(progress=False, report=False)


@pytest.fixture(scope="module")
def tiny_field(tmp_path_factory) -> str:
    """An 18 m x 12 m field: two short legs."""
    return str(write_rect_field(tmp_path_factory.mktemp("field") / "tiny.geojson", 18.0, 12.0))


def tiny_spec(field: str, seeds=(0, 1), extra_axes: dict | None = None) -> dict:
    return {"name": "tiny",
            "base": {"mission.field": field, "mission.headland_m": 0.0, "sim.max_time_s": 6.0,
                     "wind.turbulence": "light"},
            "axes": {"wind.speed_mps": [0.0, 4.0], "seed": list(seeds), **(extra_axes or {})}}


def deterministic(rows: list[dict]) -> list[dict]:
    return [{k: v for k, v in r.items() if not is_timing_column(k)} for r in rows]


# ------------------------------------------------------------------------------------- spec
def test_expand_product_order_presets_and_base_file(tmp_path):
    (tmp_path / "base.toml").write_text('[wind]\nturbulence = "none"\nspeed_mps = 1.5\n')
    (tmp_path / "gains.toml").write_text("[controller.xy]\nk0 = 2.5\n")
    spec = spec_from_dict({
        "name": "t",
        "base": {"config": "base.toml", "sim.max_time_s": 5.0},
        "axes": {"controller": ["default", "soft"], "seed": {"range": [3, 6]}},
        "presets": {"controller": {"soft": {"config": "gains.toml", "controller.z.k1": 0.5}}},
    }, base_dir=tmp_path)
    tasks = expand(spec)
    assert spec.n_runs == len(tasks) == 6
    assert [t.axis_values["seed"] for t in tasks] == [3, 4, 5, 3, 4, 5]  # last axis fastest
    assert [t.index for t in tasks] == list(range(6))
    d0, d5 = tasks[0].config, tasks[5].config
    assert d0["wind"]["speed_mps"] == 1.5 and d0["wind"]["turbulence"] == "none"
    assert d0["sim"]["max_time_s"] == 5.0 and d0["seed"] == 3
    assert d0["controller"]["xy"]["k0"] == Config().controller.xy.k0  # default preset
    assert d5["controller"]["xy"]["k0"] == 2.5 and d5["controller"]["z"]["k1"] == 0.5
    assert d5["seed"] == 5 and tasks[5].axis_values == {"controller": "soft", "seed": 5}
    assert len({t.config_hash for t in tasks}) == 6
    assert expand(spec)[4].config_hash == tasks[4].config_hash


@pytest.mark.parametrize("data, needle", [
    ({"axes": {"wind.speedy": [1.0]}}, "speedy"),
    ({"axes": {"seed": {"range": [0]}}}, "range"),
    ({"axes": {"seed": []}}, "at least one"),
    ({"axes": {"controller": ["nope"]}}, "no preset"),
    ({"axes": {"wind.speed_mps": [1.0, -2.0]}}, "wind.speed_mps = -2.0: must be >= 0 (run 1"),
    ({"axes": {"mission.field": ["no-such-field"]}}, "mission.field"),
    ({"bogus": 1}, "unknown key"),
    ({"base": {"config": "missing.toml"}}, "no such file"),
    ({"name": "has space"}, "name"),
    ({"base": {"mission.swath_m": 500.0}}, "mission.swath_m = 500.0"),
])
def test_spec_errors_are_one_line(tmp_path, data, needle):
    with pytest.raises(ConfigError) as e:
        expand(spec_from_dict(data, base_dir=tmp_path))
    msg = str(e.value)
    assert needle in msg and "\n" not in msg


def test_cli_bad_spec_exits_2(tmp_path, capsys):
    from ag_uav.cli import main

    p = tmp_path / "bad.toml"
    p.write_text('[axes]\n"wind.speed_mps" = [-1.0]\n')
    assert main(["batch", str(p), "--out", str(tmp_path / "o")]) == 2
    err = capsys.readouterr().err.strip()
    assert err.count("\n") == 0 and "wind.speed_mps" in err
    p.write_text("[axes\n")
    assert main(["batch", str(p)]) == 2


# -------------------------------------------------------------------------------------- rows
def test_run_task_exception_and_crash_become_rows(tiny_field):
    bad = RunTask(index=7, run_id="0007", axis_values={"x": 1}, config={"wind": {"bogus": 1}},
                  config_hash="h")
    row = run_task(bad)
    assert row["status"] == "error" and row["index"] == 7 and row["x"] == 1
    assert row["crash_reason"].startswith("ConfigError") and row["completed"] is False
    spec = spec_from_dict({"base": {"mission.field": tiny_field, "mission.headland_m": 0.0,
                                    "sim.takeoff": False,
                                    "vehicle.payload_kg": 10.0, "sim.max_time_s": 5.0}})
    row = run_task(expand(spec)[0])
    assert row["status"] == "crashed" and row["crashed"] is True
    assert "ground contact" in row["crash_reason"]
    assert "config" not in row and math.isfinite(row["sim_time_s"])


def test_mean_ci_student_t():
    m, h, n = mean_ci([1.0, 2.0, 3.0, None, "", float("nan")])
    assert n == 3 and m == pytest.approx(2.0)
    assert h == pytest.approx(4.302652729911275 / math.sqrt(3.0))
    assert math.isnan(mean_ci([5.0])[1]) and mean_ci([])[2] == 0


# --------------------------------------------------------------------------- journal / resume
def test_journal_ignores_and_repairs_a_torn_line(tmp_path):
    j = Journal(tmp_path / "journal.jsonl")
    j.open()
    j.append("a", {"index": 0})
    j.append("b", {"index": 1}, retry=True)
    j.close()
    with j.path.open("a") as f:
        f.write('{"hash": "c", "row": {"ind')
    assert j.read() == {"a": {"index": 0}}
    j.open()
    j.append("d", {"index": 3})
    j.close()
    assert set(j.read()) == {"a", "d"}
    assert all(json.loads(line) for line in j.path.read_text().splitlines())


def test_resume_reuses_finished_runs_by_config_hash(tmp_path, tiny_field):
    out = tmp_path / "o"
    r1 = run_batch(spec_from_dict(tiny_spec(tiny_field, seeds=(0,))), out, options=QUIET)
    assert r1.n_run == 2
    with pytest.raises(ConfigError, match="--resume"):
        run_batch(spec_from_dict(tiny_spec(tiny_field, seeds=(0,))), out,
                  options=BatchOptions(progress=False))
    r2 = run_batch(spec_from_dict(tiny_spec(tiny_field, seeds=(0, 1))), out,
                   options=BatchOptions(resume=True, progress=False, report=False))
    assert (r2.n_run, r2.n_skipped) == (2, 2)
    assert [r["index"] for r in r2.rows] == [0, 1, 2, 3]
    assert deterministic([r2.rows[0], r2.rows[2]]) == deterministic(
        [{**r1.rows[0], "index": 0, "run_id": "0000"}, {**r1.rows[1], "index": 2,
                                                          "run_id": "0002"}])
    r3 = run_batch(spec_from_dict(tiny_spec(tiny_field, seeds=(0,))), out,
                   options=BatchOptions(fresh=True, progress=False, report=False))
    assert r3.n_run == 2


def test_same_results_serial_pool_and_dask(tmp_path, tiny_field):
    """One spec, three executors: identical results.csv apart from the timing columns."""
    spec = spec_from_dict(tiny_spec(tiny_field, seeds=(0, 1)))
    outs = {}
    ex_serial = SerialExecutor()
    with LocalPoolExecutor(2) as ex_pool, DaskExecutor("local", 2) as ex_dask:
        for name, ex in (("serial", ex_serial), ("pool", ex_pool), ("dask", ex_dask)):
            res = run_batch(spec, tmp_path / name, ex, QUIET)
            assert res.n_run == 4 and res.executor == ex.name
            outs[name] = read_results_csv(tmp_path / name / "results.csv")
    ref = deterministic(outs["serial"])
    assert [r["index"] for r in outs["serial"]] == ["0", "1", "2", "3"]
    assert all(r["status"] == "cut" for r in outs["serial"])  # 6 s of a 32 s plan
    assert len({r["tracking_rmse_m"] for r in outs["serial"]}) == 4  # the runs really differ
    assert deterministic(outs["pool"]) == ref
    assert deterministic(outs["dask"]) == ref


def test_report_files(tmp_path):
    spec = spec_from_dict({"axes": {"estimator.name": ["kf", "mckf"],
                                    "gps.preset": ["standalone", "coloured-impulsive"],
                                    "seed": [0, 1, 2]}})
    rows = []
    for t in expand(spec):
        k = t.index
        rows.append({"index": k, **t.axis_values, "status": "crashed" if k == 5 else "ok",
                     "crash_reason": "tilt" if k == 5 else "", "tracking_rmse_m": 0.1 + 0.01 * k,
                     "estimate_rmse_m": 0.05 + 0.01 * k, "coverage_fraction": 0.9 + 0.001 * k})
    files = write_report(rows, spec, tmp_path)
    names = {f.name for f in files}
    assert names == {"report.md", "rmse.png", "tracking_vs_estimate.png", "coverage.png"}
    md = (tmp_path / "report.md").read_text()
    assert "1 crashed" in md and "| kf | standalone | 3 | 3 |" in md
    assert "| mckf | coloured-impulsive | 3 | 2 | 1 |" not in md  # crash was in kf/coloured
    # runs, ok, ended early, crashed, error
    assert "| kf | coloured-impulsive | 3 | 2 | 0 | 1 | 0 |" in md


def _children(pid: int) -> list[int]:
    out = []
    for st in Path("/proc").glob("[0-9]*/stat"):
        try:
            fields = st.read_text().rsplit(")", 1)[1].split()
        except OSError:
            continue
        if int(fields[1]) == pid:
            out.append(int(st.parent.name))
    return out


def _alive(pid: int) -> bool:
    try:
        state = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0]
    except OSError:
        return False
    return state not in ("Z", "X")


def _journal_hashes(path: Path) -> list[str]:
    out = []
    for line in path.read_text().splitlines():
        try:
            out.append(json.loads(line)["hash"])
        except json.JSONDecodeError:
            pass
    return out


def test_sigkill_then_resume_equals_uninterrupted(tmp_path, tiny_field):
    spec_d = tiny_spec(tiny_field, seeds=range(8))
    import tomli_w

    spec_path = tmp_path / "spec.toml"
    spec_path.write_text(tomli_w.dumps(spec_d))
    n = load_spec(spec_path).n_runs
    out = tmp_path / "killed"
    cmd = [sys.executable, "-m", "ag_uav.cli", "batch", str(spec_path), "--out", str(out),
           "--workers", "2", "--quiet", "--no-report"]
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    proc = subprocess.Popen(cmd, env=env, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    journal = out / "journal.jsonl"
    t0 = time.monotonic()
    while time.monotonic() - t0 < 60:
        if journal.exists() and len(_journal_hashes(journal)) >= 3:
            break
        if proc.poll() is not None:
            break
        time.sleep(0.005)
    workers = _children(proc.pid)
    proc.send_signal(signal.SIGKILL)
    proc.wait()
    done_before = len(_journal_hashes(journal))
    assert workers, "the pool's worker processes"
    t0 = time.monotonic()  # orphaned pool workers notice the dead parent and exit
    while time.monotonic() - t0 < 10 and any(_alive(p) for p in workers):
        time.sleep(0.05)
    assert not any(_alive(p) for p in workers)
    assert 3 <= done_before < n, "the kill must land half-way"
    assert subprocess.run(cmd + ["--resume"], env=env, capture_output=True).returncode == 0
    hashes = _journal_hashes(journal)
    assert len(hashes) == n == len(set(hashes))  # nothing finished was run twice
    ref = run_batch(load_spec(spec_path), tmp_path / "ref", options=QUIET)
    assert deterministic(read_results_csv(out / "results.csv")) == deterministic(
        read_results_csv(tmp_path / "ref" / "results.csv"))
    assert len(ref.rows) == n
