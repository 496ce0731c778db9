"""Batch specs mean one thing and failures are never silent: paths against the spec's folder with
content hashes, run-count limits, damaged journals, engine fallbacks reported, failed runs
summed up, full disks in one line."""

from __future__ import annotations

import os
import subprocess
import sys
import time
from pathlib import Path

import pytest
import shapefile  # pyshp
import tomli_w

from ag_uav.config import ConfigError
from ag_uav.jobs.batch import (
    MAX_RUNS,
    BatchOptions,
    Journal,
    expand,
    is_timing_column,
    load_spec,
    read_results_csv,
    run_batch,
    run_chunk,
    run_task,
    spec_from_dict,
    write_rect_field,
    write_results_csv,
)
from ag_uav.jobs.executor import LocalPoolExecutor
from ag_uav.world.field import enu_to_lonlat, load_field

ROOT = Path(__file__).resolve().parents[1]
ENV = {**os.environ, "PYTHONPATH": str(ROOT)}
ORG = (46.7300, -117.0000, 0.0)
TINY = {"sim.max_time_s": 2.0, "estimator.name": "true", "wind.turbulence": "none",
        "mission.headland_m": 0.0}

#: no progress bar, no report
QUIET = BatchOptions(progress=False, report=False)


def ring(w: float, h: float, x0: float = 0.0, reverse: bool = False) -> list[list[float]]:
    """A w × h rectangle at east offset x0 as a closed lon/lat ring about ORG."""
    xy = [(x0, 0.0), (x0 + w, 0.0), (x0 + w, h), (x0, h)]
    xy = xy[::-1] if reverse else xy
    xy = xy + [xy[0]]
    lon, lat = enu_to_lonlat([p[0] for p in xy], [p[1] for p in xy], ORG)
    return [[float(a), float(b)] for a, b in zip(lon, lat, strict=True)]


def write_kml(path: Path, sizes: dict[str, tuple[float, float]]) -> None:
    marks = "".join(
        f"<Placemark><name>{n}</name><Polygon><outerBoundaryIs><LinearRing><coordinates>"
        + " ".join(f"{a:.10f},{b:.10f},0" for a, b in ring(*wh)) +
        "</coordinates></LinearRing></outerBoundaryIs></Polygon></Placemark>"
        for n, wh in sizes.items())
    path.write_text('<?xml version="1.0" encoding="UTF-8"?><kml xmlns="http://www.opengis.net/'
                    f'kml/2.2"><Document>{marks}</Document></kml>')


def write_shp(path: Path, sizes: dict[str, tuple[float, float]]) -> None:
    with shapefile.Writer(str(path), shapeType=shapefile.POLYGON) as w:
        w.field("name", "C", size=20)
        for n, (a, b) in sizes.items():
            w.poly([ring(a, b, reverse=True)])  # shapefile boundaries run clockwise
            w.record(n)


def deterministic(rows: list[dict]) -> list[dict]:
    return [{k: v for k, v in r.items() if not is_timing_column(k)} for r in rows]


# ------------------------------------------------------------------------------------- paths
@pytest.fixture
def farm(tmp_path) -> Path:
    """A spec folder with a shapefile, a KML and a GeoJSON field, and a spec naming them by
    relative paths (``#selector`` forms included); beside it a decoy folder whose files have
    the same names and other shapes."""
    spec_dir = tmp_path / "project"
    decoy = tmp_path / "elsewhere"
    for d, scale in ((spec_dir, 1.0), (decoy, 2.5)):
        (d / "fields").mkdir(parents=True)
        write_shp(d / "fields" / "farm.shp", {"North": (30 * scale, 20), "South": (24, 16)})
        write_kml(d / "fields" / "farm.kml", {"East": (28 * scale, 18), "West": (20, 14)})
        write_rect_field(d / "fields" / "plot.geojson", 18 * scale, 12)
    (spec_dir / "base.toml").write_text('[mission]\nfield = "fields/plot.geojson"\n')
    spec = {"name": "paths", "base": {"config": "base.toml", **TINY},
            "axes": {"mission.field": ["fields/farm.shp#North", "fields/farm.kml#East",
                                       "fields/farm.kml#name=West", "fields/plot.geojson"]},
            "presets": {"other": {"big": {"mission.field": "fields/farm.shp#South"}}}}
    (spec_dir / "spec.toml").write_text(tomli_w.dumps(spec))
    return spec_dir


def test_every_field_path_is_resolved_against_the_spec_folder(farm, monkeypatch):
    expect = {f: load_field(str(farm / f)).area for f in (
        "fields/farm.shp#North", "fields/farm.kml#East", "fields/farm.kml#name=West",
        "fields/plot.geojson")}
    assert len(set(expect.values())) == 4
    monkeypatch.chdir(farm)
    a = expand(load_spec("spec.toml"))
    monkeypatch.chdir(farm.parent / "elsewhere")  # same file names, other shapes
    b = expand(load_spec(farm / "spec.toml"))
    assert [t.config for t in a] == [t.config for t in b]
    assert [t.config_hash for t in a] == [t.config_hash for t in b]
    fields = [t.config["mission"]["field"] for t in b]
    assert all(Path(f.partition("#")[0]).is_absolute() for f in fields)
    assert [load_field(f).area for f in fields] == pytest.approx(list(expect.values()))
    base = load_spec(farm / "spec.toml").base  # a path in the loaded config file: its folder
    assert base["mission"]["field"] == str(farm / "fields" / "plot.geojson")
    preset = load_spec(farm / "spec.toml").presets["other"]["big"]
    assert preset["mission"]["field"] == str(farm / "fields" / "farm.shp") + "#South"


def test_the_same_fields_fly_from_two_working_directories(farm, monkeypatch):
    rows = {}
    for cwd in (farm, farm.parent / "elsewhere"):
        monkeypatch.chdir(cwd)
        rows[cwd.name] = [run_task(t) for t in expand(load_spec(farm / "spec.toml"))]
    a, b = rows.values()
    assert all(r["status"] == "cut" for r in a)  # 2 s of each plan
    assert deterministic(a) == deterministic(b)
    areas = [r["field_area_m2"] for r in a]
    assert areas == pytest.approx([600.0, 504.0, 280.0, 216.0], rel=1e-3)


def test_config_hash_follows_file_content(farm):
    def hashes() -> list[str]:
        return [t.config_hash for t in expand(load_spec(farm / "spec.toml"))]

    h0 = hashes()
    assert hashes() == h0
    time.sleep(0.01)
    dbf = farm / "fields" / "farm.dbf"  # a sidecar: the attribute table renames a record
    write_shp(farm / "fields" / "farm.shp", {"North": (30, 20), "South": (25, 16)})
    h1 = hashes()
    assert h1[0] != h0[0] and h1[1:] == h0[1:]
    data = dbf.read_bytes()
    dbf.write_bytes(data.replace(b"South", b"Sooth"))
    assert hashes()[0] != h1[0]
    write_kml(farm / "fields" / "farm.kml", {"East": (28, 18), "West": (21, 14)})
    h2 = hashes()
    assert h2[1] != h1[1] and h2[2] != h1[2] and h2[3] == h0[3]


def test_a_builtin_field_hashes_as_the_config_alone():
    """Journals written before file hashing still resume when no file is named."""
    import hashlib
    import json

    t = expand(spec_from_dict({"base": TINY}))[0]
    blob = json.dumps(t.config, sort_keys=True, separators=(",", ":"), default=str)
    assert t.config_hash == hashlib.sha256(blob.encode()).hexdigest()[:16]


# -------------------------------------------------------------------------------- run limits
@pytest.mark.parametrize("axes, needle", [
    ({"seed": {"range": [0, 5, 0]}}, "step must not be 0"),
    ({"seed": {"range": [0, 10**9]}}, "1,000,000,000 values, more than the limit of 10,000"),
    ({"seed": {"range": [0, 1e9]}}, "integers"),
    ({"wind.speed_mps": {"linspace": [0, 5, 10**7]}}, "10,000,000 values"),
    ({"seed": {"range": [0, 100]}, "wind.speed_mps": {"linspace": [0, 5, 100]},
      "vehicle.payload_kg": {"linspace": [0, 2, 100]}}, "= 1,000,000 runs, more than the limit"),
])
def test_bad_or_huge_axes_are_refused_at_once(axes, needle):
    t0 = time.perf_counter()
    with pytest.raises(ConfigError) as e:
        spec_from_dict({"axes": axes})
    assert needle in str(e.value) and "\n" not in str(e.value)
    assert time.perf_counter() - t0 < 1.0  # nothing was expanded


def test_the_run_limit_is_configurable():
    axes = {"axes": {"seed": {"range": [0, 50]}, "wind.speed_mps": [0.0, 1.0]}}
    assert spec_from_dict(axes).n_runs == 100 <= MAX_RUNS
    with pytest.raises(ConfigError, match="100 runs, more than the limit of 99"):
        spec_from_dict({**axes, "max_runs": 99})
    assert spec_from_dict({**axes, "max_runs": 99}, max_runs=100).n_runs == 100
    with pytest.raises(ConfigError, match="max_runs"):
        spec_from_dict({**axes, "max_runs": 0})


def test_cli_refuses_a_huge_dry_run_and_a_zero_step_in_one_line(tmp_path):
    p = tmp_path / "s.toml"
    for body, needle in (("[axes]\nseed = {range = [0, 1000000000]}\n", "--max-runs"),
                         ("[axes]\nseed = {range = [0, 5, 0]}\n", "step must not be 0")):
        p.write_text(body)
        r = subprocess.run([sys.executable, "-m", "ag_uav.cli", "batch", str(p), "--dry-run"],
                           env=ENV, capture_output=True, text=True, timeout=60)
        assert r.returncode == 2 and needle in r.stderr
        assert r.stderr.strip().count("\n") == 0 and "Traceback" not in r.stderr


# ------------------------------------------------------------------------------------ journal
def test_a_damaged_journal_is_skipped_with_a_count_and_resume_completes(tmp_path):
    spec = spec_from_dict({"base": TINY, "axes": {"seed": [0, 1, 2]}})
    ref = run_batch(spec, tmp_path / "ref", options=QUIET)
    out = tmp_path / "o"
    run_batch(spec, out, options=QUIET)
    lines = (out / "journal.jsonl").read_bytes().split(b"\n")
    lines[1] = lines[1][:20] + b"\xff\xfe\x80" + lines[1][23:]  # not UTF-8 any more
    (out / "journal.jsonl").write_bytes(b"\n".join(lines) + b'[1, 2]\n{"hash": 5}\n{"row')
    j = Journal(out / "journal.jsonl")
    assert len(j.read()) == 2 and j.skipped == 3  # the torn last line is not counted
    said: list[str] = []
    res = run_batch(spec, out, options=BatchOptions(resume=True, progress=False, report=False,
                                                    warn=said.append))
    assert (res.n_run, res.n_skipped, res.journal_skipped) == (1, 2, 3)
    assert len(said) == 1 and "skipped 3 unreadable line(s)" in said[0]
    assert deterministic(res.rows) == deterministic(ref.rows)


# ------------------------------------------------------------------------- nothing is silent
def test_an_engine_batch_failure_is_a_column_a_warning_and_a_count(tmp_path, monkeypatch):
    """Two control rates cannot share an engine batch: the chunk flies one run at a time, and
    says so (rows equal to the runs flown alone)."""
    spec = spec_from_dict({"base": TINY, "axes": {"sim.control_hz": [100.0, 250.0]}})
    tasks = expand(spec)
    rows = run_chunk(tasks)
    assert all("must share sim.control_hz" in r["engine_fallback"] for r in rows)
    assert all(r["status"] == "cut" for r in rows)
    alone = [run_task(t) for t in tasks]
    assert all(r["engine_fallback"] == "" for r in alone)
    assert deterministic([{**r, "engine_fallback": ""} for r in rows]) == deterministic(alone)
    # through run_batch: warning, column, count in the result and the report
    from ag_uav.jobs import batch

    said: list[str] = []  # the planner keeps them apart; put them in one chunk to see it fail
    monkeypatch.setattr(batch.run, "memory_plan",
                        lambda todo, workers, mem, here: ([list(range(len(todo)))], 0.0))
    res = run_batch(spec, tmp_path / "o", options=BatchOptions(progress=False, warn=said.append))
    assert res.n_fallback == 2 and res.failure_line() is None
    assert len(said) == 1 and "flown one at a time" in said[0] and "ValueError" in said[0]
    csv_rows = read_results_csv(tmp_path / "o" / "results.csv")
    assert all("ValueError" in r["engine_fallback"] for r in csv_rows)
    assert "engine fallbacks: 2 runs" in (tmp_path / "o" / "report.md").read_text()


def test_an_exception_in_the_product_makes_the_batch_fail(tmp_path):
    field = write_rect_field(tmp_path / "f.geojson", 18.0, 12.0)
    spec = spec_from_dict({"base": {**TINY, "mission.field": str(field)},
                           "axes": {"seed": [0, 1]}})
    tasks = expand(spec)
    field.write_text("{}")  # damaged after validation: the run raises in the product
    res = run_batch(spec, tmp_path / "o", options=QUIET, tasks=tasks)
    line = res.failure_line()
    assert line is not None and line.startswith("2 of 2 runs failed: 2 raised in the product")
    assert "\n" not in line
    ok = run_batch(spec_from_dict({"base": {**TINY, "sim.takeoff": False, "sim.max_time_s": 5.0,
                                            "vehicle.payload_kg": 10.0}}),
                   tmp_path / "crash", options=QUIET)
    assert ok.rows[0]["status"] == "crashed" and ok.failure_line() is None  # a result


def die_once(marker: str) -> int:
    """Kill this worker process the first time (the marker file is the memory)."""
    p = Path(marker)
    if not p.exists():
        p.write_text("x")
        os._exit(9)
    return os.getpid()


def test_a_lost_pool_worker_is_retried(tmp_path):
    with LocalPoolExecutor(1, retries=1) as ex:
        got = dict(ex.map_unordered(die_once, [str(tmp_path / "m")], return_exceptions=True))
    assert isinstance(got[0], int)
    with LocalPoolExecutor(1, retries=0) as ex:
        got = dict(ex.map_unordered(die_once, [str(tmp_path / "m2")], return_exceptions=True))
    assert isinstance(got[0], BaseException)


# ---------------------------------------------------------------------------------- disk
@pytest.fixture
def full_disk(tmp_path):
    """A 256 KiB tmpfs filled to the last byte (skipped where the runner may not mount)."""
    mnt = tmp_path / "full"
    mnt.mkdir()
    r = subprocess.run(["mount", "-t", "tmpfs", "-o", "size=256k", "tmpfs", str(mnt)],
                       capture_output=True, text=True)
    if r.returncode != 0:
        pytest.skip(f"cannot mount a tmpfs here: {r.stderr.strip() or r.returncode}")
    try:
        (mnt / "out").mkdir()
        fd = os.open(mnt / "filler", os.O_WRONLY | os.O_CREAT)
        try:
            while os.write(fd, b"\0" * 4096):
                pass
        except OSError:
            pass
        finally:
            os.close(fd)
        yield mnt
    finally:
        subprocess.run(["umount", "-l", str(mnt)], check=False)


def test_a_full_disk_is_one_line_and_leaves_no_tmp(tmp_path, full_disk):
    with pytest.raises(OSError) as e:
        write_results_csv([{"index": 0, "x": 1.0}], full_disk / "out" / "results.csv")
    assert e.value.filename == str(full_disk / "out" / "results.csv")
    spec = tmp_path / "s.toml"
    spec.write_text(tomli_w.dumps({"base": TINY}))
    r = subprocess.run([sys.executable, "-m", "ag_uav.cli", "batch", str(spec), "--out",
                        str(full_disk / "out"), "--workers", "1", "--quiet"], env=ENV,
                       capture_output=True, text=True, timeout=120)
    assert r.returncode == 1, r.stderr
    assert r.stderr.strip().count("\n") == 0 and "No space left on device" in r.stderr
    assert str(full_disk / "out") in r.stderr and "Traceback" not in r.stderr
    assert not [p for p in (full_disk / "out").iterdir() if p.name.endswith(".tmp")]



def test_an_experiment_whose_batch_stops_exits_1_with_one_line(monkeypatch, capsys, tmp_path):
    """The experiments run on run_batch: a batch stopped by a lost scheduler or worker ends the
    command with its one line and exit 1, not a traceback."""
    from ag_uav.cli import main
    from ag_uav.jobs import batch as batch_mod

    def stopped(*a, **k):
        raise batch_mod.BatchStopped("batch table2 stopped: dask: lost the scheduler; "
                                     "0 of 2 runs done; --resume completes it")

    monkeypatch.setattr(batch_mod, "run_batch", stopped)
    rc = main(["experiment", "table2", "--runs", "1", "--out", str(tmp_path / "t2")])
    err = capsys.readouterr().err.strip().splitlines()
    assert rc == 1
    assert err[-1].startswith("ag-uav: batch table2 stopped") and "Traceback" not in "".join(err)


def test_signals_held_defers_a_sigterm_that_reaches_another_thread():
    """A SIGTERM sent while a journal line and its row are being recorded runs its handler
    after both, also when the kernel delivers it to a thread other than the main one."""
    import signal
    import threading

    from ag_uav.jobs.batch import signals_held

    done: list[str] = []

    def handler(signum, frame):
        raise RuntimeError("terminated")

    old = signal.signal(signal.SIGTERM, handler)
    try:
        with pytest.raises(RuntimeError, match="terminated"), signals_held():
            t = threading.Thread(target=os.kill, args=(os.getpid(), signal.SIGTERM))
            t.start()
            t.join()
            time.sleep(0.05)  # the handler would run here, between two bytecodes
            done.append("journal line")
            done.append("row")
        assert done == ["journal line", "row"]
        assert signal.getsignal(signal.SIGTERM) is handler
    finally:
        signal.signal(signal.SIGTERM, old)
