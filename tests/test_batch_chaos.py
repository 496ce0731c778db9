"""Batches under failure, with real processes on loopback: Dask workers and schedulers killed,
SIGTERM, a bad ``--dask`` address, damaged journals, lost pool workers. Every run is a tiny
mission (true state, a few seconds of sim time) so that the failures, not the flights, are what
takes the time."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
import tomli_w

from ag_uav.jobs.batch import is_timing_column, read_results_csv

ROOT = Path(__file__).resolve().parents[1]
DASK = Path(sys.executable).with_name("dask")
ENV = {**os.environ, "PYTHONPATH": str(ROOT), "MUJOCO_GL": "egl"}


def write_spec(path: Path, seeds: int = 2, **axes) -> Path:
    """Four lockstep groups (estimator × spray) of ``seeds`` runs: four chunks on one worker,
    so a batch is killed between chunks."""
    spec = {"name": "chaos",
            "base": {"sim.max_time_s": 3.0, "wind.turbulence": "none"},
            "axes": {"estimator.name": ["true", "kf"], "spray.enabled": [True, False],
                     "seed": list(range(seeds)), **axes}}
    path.write_text(tomli_w.dumps(spec))
    return path


def cli(*args: str, cwd: Path | None = None) -> list[str]:
    return [sys.executable, "-m", "ag_uav.cli", *args]


def deterministic(rows: list[dict]) -> list[dict]:
    return [{k: v for k, v in r.items() if not is_timing_column(k)} for r in rows]


def journal_lines(path: Path) -> int:
    return len(path.read_bytes().splitlines()) if path.exists() else 0


def wait_for(cond, timeout: float, proc: subprocess.Popen | None = None) -> bool:
    t0 = time.monotonic()
    while time.monotonic() - t0 < timeout:
        if cond():
            return True
        if proc is not None and proc.poll() is not None:
            return False
        time.sleep(0.05)
    return False


class Cluster:
    """``dask scheduler`` and ``dask worker`` subprocesses on 127.0.0.1 (no nanny: killing the
    worker process kills the worker)."""

    def __init__(self, tmp: Path, n_workers: int = 1) -> None:
        self.file = tmp / "scheduler.json"
        self.scheduler = subprocess.Popen(
            [str(DASK), "scheduler", "--host", "127.0.0.1", "--port", "0", "--no-dashboard",
             "--scheduler-file", str(self.file)], env=ENV, stdout=subprocess.DEVNULL,
            stderr=subprocess.DEVNULL)
        assert wait_for(self.file.exists, 30, self.scheduler), "scheduler did not start"
        time.sleep(0.2)
        self.address = json.loads(self.file.read_text())["address"]
        self.workers = [subprocess.Popen(
            [str(DASK), "worker", self.address, "--nthreads", "1", "--no-nanny",
             "--no-dashboard", "--host", "127.0.0.1"], env=ENV, stdout=subprocess.DEVNULL,
            stderr=subprocess.DEVNULL) for _ in range(n_workers)]
        from distributed import Client

        with Client(self.address, timeout="20s") as c:
            c.wait_for_workers(n_workers, timeout=60)

    def close(self) -> None:
        for p in [*self.workers, self.scheduler]:
            if p.poll() is None:
                p.kill()
            p.wait()


@pytest.fixture
def cluster(tmp_path):
    c = Cluster(tmp_path)
    yield c
    c.close()


def test_bad_dask_address_is_one_line_exit_2(tmp_path):
    spec = write_spec(tmp_path / "spec.toml")
    r = subprocess.run(cli("batch", str(spec), "--dask", "notanaddress", "--out",
                           str(tmp_path / "o")), env=ENV, capture_output=True, text=True,
                       timeout=60)
    assert r.returncode == 2
    assert r.stderr.strip().count("\n") == 0 and "notanaddress" in r.stderr
    assert "tcp://HOST:PORT" in r.stderr and "Traceback" not in r.stderr


def test_last_dask_worker_killed_stops_within_60_s(tmp_path, cluster):
    spec = write_spec(tmp_path / "spec.toml", seeds=4)
    out = tmp_path / "o"
    proc = subprocess.Popen(cli("batch", str(spec), "--dask", cluster.address, "--out",
                                str(out), "--quiet", "--no-report", "--dask-timeout", "5"),
                            env=ENV, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    assert wait_for((out / "journal.jsonl").exists, 60, proc)
    time.sleep(0.5)
    t_kill = time.monotonic()
    cluster.workers[0].kill()
    _, err = proc.communicate(timeout=60)
    assert time.monotonic() - t_kill < 60
    assert proc.returncode == 1
    lines = err.strip().splitlines()
    assert len(lines) == 1 and "no worker left" in lines[0] and "--resume" in lines[0], err
    assert (out / "results.csv").exists()


@pytest.mark.slow
def test_dask_scheduler_killed_then_resume_equals_a_clean_run(tmp_path, cluster):
    spec = write_spec(tmp_path / "spec.toml")
    out = tmp_path / "o"
    journal = out / "journal.jsonl"
    proc = subprocess.Popen(cli("batch", str(spec), "--dask", cluster.address, "--out",
                                str(out), "--quiet", "--no-report"),
                            env=ENV, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    assert wait_for(lambda: journal_lines(journal) >= 2, 120, proc), proc.communicate()
    cluster.scheduler.kill()
    _, err = proc.communicate(timeout=60)
    assert proc.returncode == 1
    lines = err.strip().splitlines()
    assert len(lines) == 1 and "lost the scheduler" in lines[0], err
    n_done = journal_lines(journal)
    assert 2 <= n_done < 8, "the kill must land half-way"
    assert len(read_results_csv(out / "results.csv")) == n_done
    r = subprocess.run(cli("batch", str(spec), "--out", str(out), "--resume", "--workers", "1",
                           "--quiet", "--no-report"), env=ENV, capture_output=True, text=True,
                       timeout=300)
    assert r.returncode == 0, r.stderr
    clean = subprocess.run(cli("batch", str(spec), "--out", str(tmp_path / "clean"),
                               "--workers", "1", "--quiet", "--no-report"), env=ENV,
                           capture_output=True, text=True, timeout=300)
    assert clean.returncode == 0, clean.stderr
    got = read_results_csv(out / "results.csv")
    assert len(got) == 8 and all(row["status"] == "cut" for row in got)  # 3 s of a plan
    assert deterministic(got) == deterministic(read_results_csv(tmp_path / "clean" /
                                                                "results.csv"))


def test_sigterm_writes_results_and_resume_completes(tmp_path):
    spec = write_spec(tmp_path / "spec.toml")
    out = tmp_path / "o"
    journal = out / "journal.jsonl"
    args = ("batch", str(spec), "--out", str(out), "--workers", "1", "--quiet", "--no-report")
    proc = subprocess.Popen(cli(*args), env=ENV, stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True)
    assert wait_for(lambda: journal_lines(journal) >= 2, 120, proc), proc.communicate()
    proc.send_signal(signal.SIGTERM)
    _, err = proc.communicate(timeout=60)
    assert proc.returncode == 143
    assert err.strip().count("\n") == 0 and "SIGTERM" in err and "--resume" in err
    n_done = journal_lines(journal)
    assert 2 <= n_done < 8
    rows = read_results_csv(out / "results.csv")
    assert len(rows) == n_done and all(r["status"] == "cut" for r in rows)
    r = subprocess.run(cli(*args, "--resume"), env=ENV, capture_output=True, text=True,
                       timeout=300)
    assert r.returncode == 0, r.stderr
    assert len(read_results_csv(out / "results.csv")) == 8
    assert journal_lines(journal) == 8  # nothing that had finished was run twice
