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
import socket
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
    from ag_uav.engine import warm

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
                           if "--warm-helper" in cmd), None)
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
    from ag_uav.engine import warm

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


# ------------------------------------------------------------------------------ provenance
DASK = Path(sys.executable).with_name("dask")


def _tiny_spec(path: Path, seeds: int = 2) -> Path:
    path.write_text(tomli_w.dumps({
        "name": "prov", "base": {"sim.max_time_s": 1.0, "estimator.name": "true",
                                 "wind.turbulence": "none"},
        "axes": {"seed": list(range(seeds))}}))
    return path


def _copy_sources(dst: Path, edit: str | None) -> Path:
    """The product's packages copied to ``dst`` (a tree a worker imports from), with a line
    appended to the file ``edit``."""
    import shutil

    from ag_uav.jobs.provenance import PACKAGES

    for pkg in PACKAGES:
        shutil.copytree(ROOT / pkg, dst / pkg, ignore=shutil.ignore_patterns("__pycache__"))
    if edit:
        with (dst / edit).open("a") as f:
            f.write("# edited on this worker only\n")
    return dst


class _Cluster:
    """A ``dask scheduler`` and named ``dask worker`` processes on 127.0.0.1, each worker
    importing the product from its own folder (no nanny: the worker is the process)."""

    def __init__(self, tmp: Path) -> None:
        self.file = tmp / "scheduler.json"
        self.procs: list[subprocess.Popen] = []
        self.workers: dict[str, subprocess.Popen] = {}
        self.procs.append(subprocess.Popen(
            [str(DASK), "scheduler", "--host", "127.0.0.1", "--port", "0", "--no-dashboard",
             "--scheduler-file", str(self.file)], env=ENV, stdout=subprocess.DEVNULL,
            stderr=subprocess.DEVNULL))
        t0 = time.monotonic()
        while not self.file.exists() and time.monotonic() - t0 < 30:
            time.sleep(0.05)
        time.sleep(0.2)
        import json

        self.address = json.loads(self.file.read_text())["address"]

    def worker(self, name: str, root: Path) -> subprocess.Popen:
        p = subprocess.Popen([str(DASK), "worker", self.address, "--nthreads", "1",
                              "--no-nanny", "--no-dashboard", "--host", "127.0.0.1",
                              "--name", name], cwd=root, env={**ENV, "PYTHONPATH": str(root)},
                             stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
        self.procs.append(p)
        self.workers[name] = p
        return p

    def wait_for(self, n: int) -> None:
        from distributed import Client

        with Client(self.address, timeout="20s") as c:
            c.wait_for_workers(n, timeout=60)

    def close(self) -> None:
        for p in reversed(self.procs):
            if p.poll() is None:
                p.send_signal(signal.SIGKILL)
            p.wait(timeout=30)


@pytest.fixture
def cluster(tmp_path):
    c = _Cluster(tmp_path)
    yield c
    c.close()


def _batch(spec: Path, out: Path, *args: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "ag_uav.cli", "batch", str(spec), "--out",
                           str(out), "-q", *args], env=ENV, capture_output=True, text=True,
                          timeout=300)


def test_a_worker_on_edited_sources_is_refused_before_any_run(cluster, tmp_path):
    from ag_uav.jobs.provenance import provenance

    edited = _copy_sources(tmp_path / "edited", "ag_uav/jobs/batch/worker.py")
    cluster.worker("same", ROOT)
    bad = cluster.worker("edited", edited)
    cluster.wait_for(2)
    out = tmp_path / "out"
    r = _batch(_tiny_spec(tmp_path / "spec.toml"), out, "--dask", cluster.address)
    assert r.returncode == 2, r.stderr
    (line,) = r.stderr.strip().splitlines()
    mine = provenance()["source_hash"]
    assert line.startswith(f'ag-uav: config error: --dask = "{cluster.address}": worker tcp://')
    assert f"(edited) on {socket.gethostname()}, pid {bad.pid}, runs other" in line
    assert f"from {edited}" in line and f"source hash {mine} from {ROOT}" in line
    assert not out.exists()  # nothing ran, nothing written
    # with the edited worker gone, the same cluster flies, and every row says which code
    bad.send_signal(signal.SIGKILL)
    bad.wait(timeout=30)
    time.sleep(1.0)
    r = _batch(tmp_path / "spec.toml", out, "--dask", cluster.address, "--logs")
    assert r.returncode == 0, r.stderr
    rows = read_results_csv(out / "results.csv")
    assert len(rows) == 2
    for row in rows:
        assert (row["ag_uav_version"], row["source_hash"]) == (provenance()["ag_uav_version"],
                                                               mine)
        assert row["worker_pid"] == str(cluster.workers["same"].pid)
    import json

    summ = json.loads((out / "runs" / rows[0]["run_id"] / "summary.json").read_text())
    assert summ["source_hash"] == mine and summ["ag_uav_version"] == rows[0]["ag_uav_version"]


def test_the_source_hash_sees_one_edited_file(tmp_path):
    """The hash of a copied tree equals this tree's; one line appended to one file changes it."""
    code = ("from ag_uav.jobs.provenance import source_hash, source_root; "
            "print(source_hash(), source_root())")

    def hash_of(root: Path) -> list[str]:
        return subprocess.run([sys.executable, "-c", code], cwd=root,
                              env={**ENV, "PYTHONPATH": str(root)}, capture_output=True,
                              text=True, timeout=120, check=True).stdout.split()

    from ag_uav.jobs.provenance import source_hash

    same = hash_of(_copy_sources(tmp_path / "same", None))
    edited = hash_of(_copy_sources(tmp_path / "edited", "controllers/pid.py"))
    assert same == [source_hash(), str(tmp_path / "same")]
    assert edited[0] != source_hash() and edited[1] == str(tmp_path / "edited")


def test_a_row_from_other_code_stops_the_batch_unjournalled(tmp_path):
    """A worker that joins after the check (or sources edited under a running pool): its first
    row stops the batch with one line; nothing of it is journalled."""
    from ag_uav.config import ConfigError
    from ag_uav.jobs.batch import BatchOptions, load_spec, run_batch
    from ag_uav.jobs.executor import SerialExecutor

    class Other(SerialExecutor):
        def map_unordered(self, fn, items, *, return_exceptions=False):
            for i, rows in super().map_unordered(fn, items, return_exceptions=return_exceptions):
                yield i, [{**r, "source_hash": "0" * 16} for r in rows]

    out = tmp_path / "out"
    with pytest.raises(ConfigError) as e:
        run_batch(load_spec(str(_tiny_spec(tmp_path / "s.toml", seeds=1))), out, Other(),
                  BatchOptions(progress=False, report=False))
    msg = str(e.value)
    assert "\n" not in msg and "source hash 0000000000000000" in msg and "--resume" in msg
    assert (out / "journal.jsonl").read_text() == ""
    assert read_results_csv(out / "results.csv") == []
