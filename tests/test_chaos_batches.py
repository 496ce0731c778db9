"""Chaos: batches and the first run's compile helper under the things an overnight user does.

- A run that ends early (the GNSS failsafe landed it, ``sim.max_time_s`` cut it) is not ok:
  its status says why, the report lists it with the failed runs, and the means say how many
  runs they cover.
- A first run SIGKILLed while its compile helper works takes the helper along, and the next run
  removes the helper's folder it left in the temporary directory.
- Provenance: every row and every summary carries the product's version and a hash of its
  sources; a Dask worker running other sources is refused before any run, by name.
"""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
import tomli_w

from ag_uav.jobs.batch import read_results_csv, summary_rows, write_rect_field

ROOT = Path(__file__).resolve().parents[1]
ENV = {**os.environ, "PYTHONPATH": str(ROOT), "MUJOCO_GL": "egl"}

#: the fix lost for good after ~15 s (seed 0: at about 28 s, with four legs flown)
LOST = {"gps.overrides": {"outage": {"mean_up_s": 15.0, "mean_down_s": 3600.0}}}


# ------------------------------------------------------------------- runs that end early
@pytest.fixture(scope="module")
def early_batch(tmp_path_factory) -> tuple[Path, int, str]:
    """A tiny field flown whole, with the fix lost (the failsafe lands it) and cut by
    ``sim.max_time_s``: ``ag-uav batch`` on one worker. (out folder, exit code, stderr)."""
    from ag_uav.cli import main

    tmp = tmp_path_factory.mktemp("early")
    field = str(write_rect_field(tmp / "tiny.geojson", 18.0, 12.0))
    spec = {"name": "early",
            "base": {"mission.field": field, "mission.headland_m": 0.0,
                     "sim.max_time_s": 60.0, "wind.turbulence": "none"},
            "presets": {"case": {"whole": {}, "lost": LOST, "cut": {"sim.max_time_s": 6.0}}},
            "axes": {"case": ["whole", "lost", "cut"]}}
    (tmp / "spec.toml").write_text(tomli_w.dumps(spec))
    out = tmp / "out"
    import contextlib
    import io

    err = io.StringIO()
    with contextlib.redirect_stderr(err):
        rc = main(["batch", str(tmp / "spec.toml"), "--out", str(out), "--workers", "1", "-q"])
    return out, rc, err.getvalue()


def test_a_failsafe_landing_or_a_cut_is_not_ok(early_batch):
    out, rc, err = early_batch
    assert rc == 0, err  # they are results, not failures of the batch
    rows = read_results_csv(out / "results.csv")
    assert [r["status"] for r in rows] == ["ok", "failsafe", "cut"]
    whole, lost, cut = rows
    assert whole["completed"] == "true" and lost["completed"] == cut["completed"] == "false"
    assert lost["incomplete_reason"].startswith("GNSS failsafe (land) at t=")
    assert "; landed at t=" in lost["incomplete_reason"]
    assert 0.0 < float(lost["coverage_fraction"]) < float(whole["coverage_fraction"])
    assert cut["incomplete_reason"].startswith("cut by sim.max_time_s = 6 s")
    (line,) = [ln for ln in err.splitlines() if "ended early" in ln]
    assert line.startswith("ag-uav: warning: batch early: 2 of 3 runs ended early (failsafe 1, "
                           "cut 1; first: run 0001: GNSS failsafe (land) at t=")
    assert "not in the means" in line


def test_the_report_lists_them_and_its_means_say_what_they_cover(early_batch):
    out, _, _ = early_batch
    md = (out / "report.md").read_text()
    assert "- 3 runs: 1 ok, 2 ended early (failsafe 1, cut 1), 0 crashed, 0 error" in md
    assert "over the 1 of 3 runs with status ok" in md
    failed = md.split("## Crashed / failed runs", 1)[1]
    assert "| 1 | failsafe | GNSS failsafe (land) at t=" in failed
    assert "| 2 | cut | cut by sim.max_time_s = 6 s" in failed
    assert "| 0 |" not in failed  # the whole flight is not listed
    # one group over the three runs: the means are the ok run's alone, and say so
    rows = read_results_csv(out / "results.csv")
    header, (line,) = summary_rows(rows, [])
    cells = dict(zip(header, line, strict=True))
    assert (cells["runs"], cells["ok = in the means"], cells["ended early"]) == ("3", "1", "2")
    assert cells["coverage (%)"] == f"{100 * float(rows[0]['coverage_fraction']):.2f}"


def test_a_journal_of_old_statuses_is_read_as_it_is_now(early_batch, tmp_path):
    """A journal written when every flown run that did not crash was "ok" gets the statuses
    the rows' own columns give (``--resume`` flies nothing again)."""
    import json
    import shutil

    from ag_uav.cli import main

    out = tmp_path / "out"
    shutil.copytree(early_batch[0], out)
    lines = (out / "journal.jsonl").read_text().splitlines()
    old = []
    for ln in lines:
        rec = json.loads(ln)
        rec["row"]["status"] = "ok"
        old.append(json.dumps(rec))
    (out / "journal.jsonl").write_text("\n".join(old) + "\n")
    spec = early_batch[0].parent / "spec.toml"
    assert main(["batch", str(spec), "--out", str(out), "--resume", "-q", "--no-report",
                 "--workers", "1"]) == 0
    assert [r["status"] for r in read_results_csv(out / "results.csv")] == [
        "ok", "failsafe", "cut"]


# ------------------------------------------------------------------- the compile helper
def _children(pid: int) -> dict[int, str]:
    """pid → command line of ``pid``'s children."""
    out = {}
    for st in Path("/proc").glob("[0-9]*/stat"):
        try:
            ppid = int(st.read_text().rsplit(")", 1)[1].split()[1])
            if ppid == pid:
                out[int(st.parent.name)] = (st.parent / "cmdline").read_bytes().replace(
                    b"\0", b" ").decode()
        except (OSError, ValueError, IndexError):
            continue
    return out


def _gone(pid: int) -> bool:
    """Dead, or a zombie waiting for a reaper (it runs nothing)."""
    try:
        state = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0]
    except (OSError, IndexError):
        return True
    return state in ("Z", "X")


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="reads /proc")
def test_a_sigkilled_first_run_takes_its_helper_along_and_the_next_run_sweeps(
        tmp_path, monkeypatch):
    from ag_uav.jobs import warm

    if warm._cores() < 2:
        pytest.skip("the helper starts only with two cores or more")
    tmp = tmp_path / "tmp"
    tmp.mkdir()
    env = {**ENV, "TMPDIR": str(tmp), "NUMBA_CACHE_DIR": str(tmp_path / "numba"),
           "AG_UAV_WARM": "1"}
    proc = subprocess.Popen([sys.executable, "-m", "ag_uav.cli", "fly", "--no-log", "-q",
                             "--out", str(tmp_path / "runs"), "--set", "sim.max_time_s=2"],
                            env=env, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    helper = None
    t0 = time.monotonic()
    try:
        while helper is None and time.monotonic() - t0 < 180 and proc.poll() is None:
            helper = next((p for p, cmd in _children(proc.pid).items()
                           if "ag_uav.jobs.warm_helper" in cmd), None)
            time.sleep(0.05)
        assert helper is not None, "the first run started no helper"
        (folder,) = tmp.glob(f"{warm.PREFIX}*")
        time.sleep(0.5)  # the helper is past its start (imports), compiling
    finally:
        proc.send_signal(signal.SIGKILL)
        proc.wait(timeout=30)
    t1 = time.monotonic()
    while not _gone(helper) and time.monotonic() - t1 < 10:
        time.sleep(0.05)
    assert _gone(helper), "the helper outlived its run"
    assert time.monotonic() - t1 < 5.0
    # SIGKILL left the folder, naming its dead owner; the next run removes it, not a live one's
    assert folder.is_dir() and (folder / warm.OWNER).read_text().split()[0] == str(proc.pid)
    monkeypatch.setattr("tempfile.tempdir", str(tmp))
    live = warm.owned_folder()
    reused = warm.owned_folder()  # this pid, but another process's start time: pid reuse
    (reused / warm.OWNER).write_text(f"{os.getpid()} 1\n")
    from ag_uav.config import load_config
    from ag_uav.jobs.run import fly

    fly(load_config(None, {"estimator.name": "true", "sim.max_time_s": 0.2,
                           "log.enabled": False}), out_root=tmp_path / "runs", run_id="next")
    assert not folder.exists() and not reused.exists()
    assert live.is_dir()
    warm.sweep()
    assert live.is_dir()


def test_an_unowned_folder_waits_out_its_grace(tmp_path, monkeypatch):
    """A folder of ours with no owner file (being made, or left by an older version) is kept
    for ``UNOWNED_GRACE_S`` after its last change, then removed."""
    from ag_uav.jobs import warm

    monkeypatch.setattr("tempfile.tempdir", str(tmp_path))
    young = tmp_path / f"{warm.PREFIX}young"
    old = tmp_path / f"{warm.PREFIX}old"
    young.mkdir()
    old.mkdir()
    past = time.time() - warm.UNOWNED_GRACE_S - 5
    os.utime(old, (past, past))
    (tmp_path / f"{warm.PREFIX}file").write_text("not a folder")
    assert warm.sweep() == [old]
    assert young.is_dir() and (tmp_path / f"{warm.PREFIX}file").exists()
