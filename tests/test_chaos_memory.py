"""Chaos: memory guards.  The per-run budget counts the dose map; a tune's population and a
batch's worker count are bounded, one line each; more workers than cores is said; a batch's
whole process tree stays within the bound its chunks were planned for."""

from __future__ import annotations

import os
import threading
import time

import psutil
import pytest
import tomli_w

import ag_uav
from ag_uav.cli import batch as cli_batch
from ag_uav.cli import main
from ag_uav.config import ConfigError
from ag_uav.engine.missions import check_memory_budget, dose_map_mb
from ag_uav.world.mission import build_field, build_plan


def _need(cfg) -> tuple[float, object]:
    fld = build_field(cfg)
    return build_plan(cfg, fld).length / cfg.mission.speed_mps, fld


def test_the_budget_counts_the_dose_map():
    fine = ag_uav.load_config(None, {"spray.cell_m": 0.05})
    coarse = ag_uav.load_config(None, {"spray.cell_m": 0.5})
    d_fine, d_coarse = dose_map_mb(fine, build_field(fine)), dose_map_mb(coarse,
                                                                        build_field(coarse))
    # 0.05 m over this field passes spray.max_cells, so the map coarsens to 0.1 m: 25x the cells
    # of 0.5 m (up to the grid's block rounding)
    assert 18 < d_fine / d_coarse < 30 and d_fine > 30
    dur, fld = _need(fine)
    tables = dur * fine.sim.control_hz * 1536 / 2**20
    budget = tables + 0.5 * d_fine  # enough for the tables, not for the map
    fine.sim.memory_budget_mb = coarse.sim.memory_budget_mb = budget
    with pytest.raises(ConfigError, match=r"MB of dose map \(spray.cell_m = 0.05\)"):
        check_memory_budget(fine, dur, "the plan", fld)
    check_memory_budget(coarse, dur, "the plan", fld)  # the coarse map fits
    off = ag_uav.load_config(None, {"spray.cell_m": 0.05, "spray.deposition": False})
    off.sim.memory_budget_mb = budget
    check_memory_budget(off, dur, "the plan", fld)  # no dose model, no map


def _tune_spec(tmp_path, pop) -> str:
    p = tmp_path / "t.toml"
    p.write_text(tomli_w.dumps({"name": "t", "pop": pop, "iters": 1,
                                "params": {"controller.xy.k0": {"lo": 0.5, "hi": 15.0}},
                                "scenarios": [{"kind": "step", "axis": "x", "size": 1.0,
                                               "duration": 2.0}]}))
    return str(p)


def test_pop_is_bounded(tmp_path, capsys):
    rc = main(["tune", _tune_spec(tmp_path, 100_000_000), "--out", str(tmp_path / "o")])
    err = capsys.readouterr().err.strip().splitlines()
    assert rc == 2 and len(err) == 1, err
    assert err[0].startswith("ag-uav: config error: pop = 100000000: expected an integer in "
                             "[2, 10000]"), err
    rc = main(["tune", _tune_spec(tmp_path, 20), "--pop", "20000", "--out",
               str(tmp_path / "o")])
    err = capsys.readouterr().err.strip().splitlines()
    assert rc == 2 and err[0].startswith("ag-uav: config error: --pop = 20000: expected"), err
    assert not (tmp_path / "o").exists()


def test_workers_are_bounded_and_oversubscription_is_said(tmp_path, capsys):
    spec = tmp_path / "b.toml"
    spec.write_text(tomli_w.dumps({"name": "b", "base": {"sim.max_time_s": 1.0},
                                   "axes": {"seed": [0]}}))
    cores = os.cpu_count() or 1
    too_many = cli_batch.MAX_WORKERS_PER_CORE * cores + 1
    rc = main(["batch", str(spec), "--out", str(tmp_path / "o"), "-j", str(too_many)])
    err = capsys.readouterr().err.strip().splitlines()
    assert rc == 2 and len(err) == 1, err
    assert err[0] == (f"ag-uav: config error: --workers = {too_many}: must be in "
                      f"[1, {too_many - 1}] (4 per core, {cores} cores here)")
    cli_batch._check_workers(cores)
    assert capsys.readouterr().err == ""
    cli_batch._check_workers(cores + 1)
    (line,) = capsys.readouterr().err.strip().splitlines()
    assert line.startswith(f"ag-uav: warning: --workers = {cores + 1} on {cores} cores: "
                           "oversubscribed")


def _tree_peak(stop: threading.Event, out: dict[int, float]) -> None:
    """The peak RSS (MB) of this process and all its children, sampled every 20 ms."""
    me = psutil.Process()
    while not stop.is_set():
        rss = 0
        for p in [me, *me.children(recursive=True)]:
            try:
                r = p.memory_info().rss
            except psutil.Error:
                continue
            rss += r
            out[p.pid] = max(out.get(p.pid, 0), r / 2**20)
        out[0] = max(out[0], rss / 2**20)
        time.sleep(0.02)


def test_the_batch_tree_stays_within_its_bound(tmp_path):
    """Sixteen short runs on two worker processes: the whole process tree's peak stays under
    the bound the batch planned its chunks for, and that bound under --memory-mb. (With an
    empty numba cache, ``NUMBA_CACHE_DIR`` pointed at a new folder, the workers compile the
    kernels: a peak of 1,452 MB against a bound of about 1,590 MB.)"""
    from ag_uav.jobs.batch import BatchOptions, load_spec, run_batch
    from ag_uav.jobs.executor import LocalPoolExecutor

    spec = tmp_path / "b.toml"
    spec.write_text(tomli_w.dumps({"name": "m", "base": {"sim.max_time_s": 4.0},
                                   "axes": {"seed": list(range(16))}}))
    peak, stop = {0: 0.0}, threading.Event()
    th = threading.Thread(target=_tree_peak, args=(stop, peak))
    th.start()
    try:
        with LocalPoolExecutor(2) as ex:
            ex.memory_mb = 3000.0
            res = run_batch(load_spec(str(spec)), tmp_path / "o", ex,
                            BatchOptions(progress=False, report=False))
    finally:
        stop.set()
        th.join()
    assert len(res.rows) == 16 and all(r["status"] == "cut" for r in res.rows)
    assert peak[0] <= res.memory_bound_mb <= 3000.0, (peak, res.memory_bound_mb)
    # a bound, not a guess far above it: workers are counted as if they compiled the kernels
    # (about 1.1x the peak then), so with the kernels cached it is about 1.8x the peak
    assert res.memory_bound_mb < 2.0 * peak[0]


def test_a_worker_count_that_cannot_fit_is_refused(tmp_path, capsys):
    spec = tmp_path / "b.toml"
    spec.write_text(tomli_w.dumps({"name": "b", "base": {"sim.max_time_s": 1.0},
                                   "axes": {"seed": [0, 1]}}))
    rc = main(["batch", str(spec), "--out", str(tmp_path / "o"), "-j", "2",
               "--memory-mb", "900", "-q"])
    (line,) = capsys.readouterr().err.strip().splitlines()
    assert rc == 2 and line.startswith("ag-uav: config error: --memory-mb = 900: 2 workers "
                                       "need about"), line
    assert not (tmp_path / "o" / "results.csv").exists()
