"""Chaos: output folders shared by two writers, a killed log writer, SIGTERM.  Every case ends
in one line naming what happened, and no run's outputs are mixed with another's.

Real ``ag-uav`` processes where the case is about processes (two flights at once, a killed
writer, a signal); the in-process API where a clock or a lock can be arranged directly."""

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
from mcap.reader import make_reader

import ag_uav
from ag_uav.cli import main
from ag_uav.jobs import outdir
from ag_uav.jobs.run import fly

ROOT = Path(__file__).resolve().parents[1]
ENV = {**os.environ, "PYTHONPATH": str(ROOT), "MUJOCO_GL": "egl"}
SHORT = ["--no-render", "-q", "--set", "wind.turbulence='none'"]


def _cli(*args) -> list[str]:
    return [sys.executable, "-m", "ag_uav.cli", *map(str, args)]


def _lines(err: str) -> list[str]:
    """stderr's lines, less the pre-flight notice of a mission cut by sim.max_time_s and the
    first run's compile notices (the process may be the first to fly on an empty cache)."""
    return [ln for ln in err.strip().splitlines() if "the plan needs at least" not in ln
            and not ln.startswith(("compiling the log's encoders",
                                   "compiling kernels: first run only",
                                   "compiled the kernels in"))]


def _one(err: str) -> str:
    lines = _lines(err)
    assert len(lines) == 1 and "Traceback" not in err, err
    return lines[0]


def _wait(cond, timeout: float, proc: subprocess.Popen) -> None:
    t0 = time.monotonic()
    while not cond():
        assert proc.poll() is None, proc.communicate()
        assert time.monotonic() - t0 < timeout, "timed out"
        time.sleep(0.05)


def _messages(path: Path) -> int:
    with open(path, "rb") as f:
        return sum(1 for _ in make_reader(f).iter_messages())


def _children(pid: int) -> list[int]:
    p = Path(f"/proc/{pid}/task/{pid}/children")
    return [int(x) for x in p.read_text().split()] if p.exists() else []


def test_two_flights_into_one_run_folder(tmp_path):
    """The second ``fly`` into a folder the first is writing is refused with one line (before
    it touches anything there); the first run goes on, and its log is whole."""
    first = subprocess.Popen(_cli("fly", *SHORT, "--set", "sim.max_time_s=400", "--out",
                                  tmp_path, "--run-id", "x"), env=ENV, stdout=subprocess.PIPE,
                             stderr=subprocess.PIPE, text=True)
    log = tmp_path / "x" / "run.mcap"
    _wait(lambda: log.exists() and log.stat().st_size > 20000, 600, first)
    second = subprocess.run(_cli("fly", *SHORT, "--set", "sim.max_time_s=2", "--out", tmp_path,
                                 "--run-id", "x", "--overwrite"), env=ENV,
                            capture_output=True, text=True, timeout=600)
    assert first.poll() is None, "the first flight ended before the second started"
    assert second.returncode == 1, second.stderr
    line = _one(second.stderr)
    assert line.startswith(f"ag-uav: {tmp_path / 'x'} is in use by another run (pid "
                           f"{first.pid} holds"), line
    assert log.exists()  # not cleared by the second's --overwrite
    first.send_signal(signal.SIGINT)  # the first closes its log
    first.communicate(timeout=60)
    assert first.returncode == 130
    assert _messages(log) > 1000  # read through with CRCs checked: one writer


def test_default_run_id_twice_in_one_second(tmp_path, monkeypatch):
    """Two runs whose default ids fall in the same second get two folders."""
    monkeypatch.setattr(time, "strftime", lambda fmt, *a: "20261126-120000")
    cfg = ag_uav.load_config(None, {"sim.max_time_s": 1.0, "log.enabled": False})
    _, a = fly(cfg, out_root=tmp_path)
    _, b = fly(cfg, out_root=tmp_path)
    assert (a.name, b.name) == ("20261126-120000-default-s0", "20261126-120000-default-s0-2")
    assert (a / "summary.json").exists() and (b / "summary.json").exists()
    c = outdir.unique_run_dir(tmp_path, a.name)
    assert c.name.endswith("-3") and c.is_dir()


def test_rerun_into_a_run_folder_needs_overwrite(tmp_path, capsys):
    """A rerun with ``--no-log`` into a folder with an old log is refused; with
    ``--overwrite`` the old log is removed, so ``show`` cannot report the old run."""
    base = ["fly", "--no-render", "-q", "--out", str(tmp_path), "--run-id", "r"]
    assert main([*base, "--set", "sim.max_time_s=1"]) == 0
    assert (tmp_path / "r" / "run.mcap").exists()
    capsys.readouterr()
    assert main([*base, "--no-log", "--set", "sim.max_time_s=2"]) == 2
    line = _one(capsys.readouterr().err)
    assert line.startswith(f"ag-uav: {tmp_path / 'r'} holds a previous run's outputs ("), line
    assert "--overwrite" in line
    assert main([*base, "--no-log", "--overwrite", "--set", "sim.max_time_s=2"]) == 0
    assert sorted(os.listdir(tmp_path / "r")) == ["dose.npz", "summary.json"]
    summ = json.loads((tmp_path / "r" / "summary.json").read_text())
    assert summ["sim_time_s"] == pytest.approx(2.0, abs=0.05)


def test_a_held_run_folder_is_refused_in_process(tmp_path):
    with outdir.hold(tmp_path / "r", "run", "hint"):
        with pytest.raises(outdir.FolderInUse, match="in use by another run .this process"):
            fly(ag_uav.load_config(None, {"sim.max_time_s": 1.0, "log.enabled": False}),
                out_root=tmp_path, run_id="r")
    # released: the same folder is free again
    fly(ag_uav.load_config(None, {"sim.max_time_s": 0.5, "log.enabled": False}),
        out_root=tmp_path, run_id="r")


def test_killed_log_writer_is_an_error_with_the_summary_kept(tmp_path):
    proc = subprocess.Popen(_cli("fly", *SHORT, "--set", "sim.max_time_s=60", "--out", tmp_path,
                                 "--run-id", "k"), env=ENV, stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True)
    log = tmp_path / "k" / "run.mcap"
    # past the log's head (field, plan and map topics: tens of kB before the first tick)
    _wait(lambda: log.exists() and log.stat().st_size > 150000 and _children(proc.pid), 600,
          proc)
    (writer,) = _children(proc.pid)
    os.kill(writer, signal.SIGKILL)
    _, err = proc.communicate(timeout=600)
    assert proc.returncode == 1, err
    line = _one(err)
    assert line.startswith(f"ag-uav: {log}: the run log's writer process exited"), line
    summ = json.loads((tmp_path / "k" / "summary.json").read_text())
    assert summ["sim_time_s"] == pytest.approx(60.0, abs=0.05)  # the flight went on
    lost_at = float(summ["log_error"].split("t = ")[1].split(" s")[0])
    assert 0.0 < lost_at < 60.0 and str(log) in summ["log_error"]


def test_sigterm_prints_one_line(tmp_path):
    proc = subprocess.Popen(_cli("fly", *SHORT, "--set", "sim.max_time_s=60", "--out", tmp_path,
                                 "--run-id", "t"), env=ENV, stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True)
    log = tmp_path / "t" / "run.mcap"
    _wait(lambda: log.exists() and log.stat().st_size > 150000, 600, proc)
    proc.send_signal(signal.SIGTERM)
    _, err = proc.communicate(timeout=60)
    assert proc.returncode == 143
    line = _one(err)
    assert line.startswith("ag-uav: terminated (SIGTERM) after "), line
    assert _messages(log) > 10  # the log was finished (its summary section read)


def test_second_batch_on_one_out_is_refused(tmp_path):
    spec = tmp_path / "b.toml"
    spec.write_text(tomli_w.dumps({"name": "b", "base": {"sim.max_time_s": 1.0},
                                   "axes": {"seed": [0, 1]}}))
    out = tmp_path / "out"
    for extra in ([], ["--resume"]):
        with outdir.hold(out, "batch", "hint"):  # held by this process: another batch runs
            r = subprocess.run(_cli("batch", spec, "--out", out, "-q", "-j", "1", *extra),
                               env=ENV, capture_output=True, text=True, timeout=600)
        assert r.returncode == 1
        line = _one(r.stderr)
        assert line.startswith(f"ag-uav: {out} is in use by another batch (pid {os.getpid()} "
                               "holds"), line
        assert not (out / "journal.jsonl").exists()
    r = subprocess.run(_cli("batch", spec, "--out", out, "-q", "-j", "1", "--resume"), env=ENV,
                       capture_output=True, text=True, timeout=600)
    assert r.returncode == 0, r.stderr
    assert len((out / "journal.jsonl").read_text().splitlines()) == 2
