"""Tests of ``ag-uav experiment numerical`` (ag_uav/jobs/experiments/numerical.py).

The fast paths (fixed-gain KFs, batched PCA, batched MCKF) are checked against the library
filters step by step; the command is run end to end on a tiny setup.
"""

from __future__ import annotations

import argparse
import csv
import math

import numpy as np
import pytest

import estimators
from ag_uav.jobs.experiments import numerical as num

TINY = num.Setup(max_steps=160)


def _library_track(name: str, Z: np.ndarray, x0, P0, setup=TINY) -> np.ndarray:
    return num.run_library(name, setup, Z, x0, P0)[0]


def _data(case: str, runs=(0, 1, 2), setup=TINY):
    pos, vel = num.truth(setup)
    x0, P0 = num.initial(setup, pos, vel)
    Z = np.stack([num.fixes(case, r, pos, setup.dt) for r in runs])
    return pos, x0, P0, Z


def test_lawnmower_is_constant_speed_with_straight_legs_and_turns():
    pos, vel = num.lawnmower(n_legs=3, leg_m=40.0, spacing_m=10.0, speed=5.0, dt=0.05)
    length = 3 * 40.0 + 2 * math.pi * 5.0
    assert len(pos) == int(length / 0.25) + 1
    assert np.allclose(pos[0], [0.0, 0.0])
    assert np.allclose(np.hypot(vel[:, 0], vel[:, 1]), 5.0)
    step = np.hypot(*np.diff(pos, axis=0).T)
    assert np.all(step <= 0.25 + 1e-9) and np.all(step > 0.24)  # chords on the arcs
    assert set(np.round(pos[vel[:, 1] == 0.0, 1], 6)) == {0.0, 10.0, 20.0}  # legs at y = i·s
    assert pos[:, 0].min() >= -5.0 - 1e-9 and pos[:, 0].max() <= 45.0 + 1e-9


def test_fixed_gain_kf_equals_library_kf_step_by_step():
    pos, x0, P0, Z = _data("white")
    m = num.model()
    Ks = num.gain_sequence("kf", TINY, len(pos), x0, P0)
    fast = num.kf_fixed_gain(m.F, m.H, Ks, x0, Z)
    for b in range(len(Z)):
        kf = estimators.KF(m.F, m.H, m.Q, m.R, x0, P0)
        for k in range(len(pos)):
            if k:
                kf.predict()
            kf.update(Z[b, k])
            np.testing.assert_allclose(fast[b, k], kf.x, rtol=0, atol=1e-9)


@pytest.mark.parametrize("name", ["kf-bias", "kf-diff"])
def test_fixed_gain_baselines_equal_library(name):
    pos, x0, P0, Z = _data("coloured")
    _, tracks = num.fast_tracks(TINY, "coloured", [0, 1, 2], [name],
                                {name: num.gain_sequence(name, TINY, len(pos), x0, P0)})
    for b in range(3):
        lib = _library_track(name, Z[b], x0, P0)
        np.testing.assert_allclose(tracks[name][b], lib, rtol=0, atol=1e-9)


@pytest.mark.parametrize("mode", ["hankel", "channels"])
def test_pca_batch_equals_pca_block(mode):
    setup = num.Setup(max_steps=120, pca_mode=mode, window=15)
    _, _, _, Z = _data("coloured-impulsive", runs=(3, 4), setup=setup)
    fast = num.pca_batch(Z, setup)
    for b in range(2):
        blk = estimators.PCABlock(2, 15, None, mode)
        lib = np.array([blk(z) for z in Z[b]])
        np.testing.assert_array_equal(fast[b], lib)  # the same row function, bit for bit
    assert np.array_equal(fast[:, :14], Z[:, :14])  # pass-through before the window is full
    assert not np.allclose(fast[:, 14:], Z[:, 14:])


def test_mckf_batch_equals_library_mckf_including_rejections_and_recovery():
    m = num.model()
    T, B = 150, 4
    rng = np.random.default_rng(7)
    x0 = np.array([0.0, 5.0, 0.0, 0.0])
    P0 = np.diag([10.0, 1.0, 100.0, 1.0])
    t = np.arange(T) * 0.05
    Z = np.stack([np.c_[5 * t, 0 * t] for _ in range(B)])
    Z = Z + rng.standard_normal((B, T, 2)) * [math.sqrt(10), 10]
    Z[:, rng.random(T) < 0.1] *= 8.0  # impulsive outliers (shared times)
    Z[1, 60:80] += [0.0, 150.0]  # a jump: 20 rejected fixes in a row -> KF recovery
    fast = num.mckf_batch(m, x0, P0, Z, sigma=2.0)
    n_rec = n_rej = 0
    iters = set()
    for b in range(B):
        f = estimators.MCKF(m.F, m.H, m.Q, m.R, x0, P0, sigma=2.0)
        for k in range(T):
            if k:
                f.predict()
            f.update(Z[b, k])
            n_rec += f.recovered
            n_rej += f.rejected
            iters.add(f.n_iter)
            np.testing.assert_array_equal(fast[b, k], f.x)  # the same row function
    assert n_rec >= 1 and n_rej >= 10 and len(iters) >= 3  # the branches were exercised


def test_mckf_batch_large_sigma_is_the_kf():
    pos, x0, P0, Z = _data("impulsive", runs=(0, 1))
    m = num.model()
    a = num.mckf_batch(m, x0, P0, Z, sigma=1e6)
    b = num.kf_fixed_gain(m.F, m.H, num.gain_sequence("kf", TINY, len(pos), x0, P0), x0, Z)
    np.testing.assert_allclose(a, b, rtol=0, atol=1e-6)


def _rows_without_timing(rows):
    return sorted((r["case"], r["run"], r["estimator"], r["rmse_m"], r["rmse_x_m"],
                   r["rmse_y_m"]) for r in rows)


def test_serial_parallel_and_library_engine_agree():
    setup = num.Setup(max_steps=100)
    cases, ests = ["white", "coloured-impulsive"], list(num.ESTIMATORS)
    kw = dict(chunk=2, timing_runs=1)
    serial = num.run_experiment(setup, cases, ests, 3, workers=1, **kw)
    par = num.run_experiment(setup, cases, ests, 3, workers=2, **kw)
    assert _rows_without_timing(serial["rows"]) == _rows_without_timing(par["rows"])  # exact
    assert max(serial["check"].values()) < 1e-9
    lib = num.run_experiment(setup, cases, ests, 3, workers=1, engine="library", **kw)
    a, b = _rows_without_timing(serial["rows"]), _rows_without_timing(lib["rows"])
    assert [x[:3] for x in a] == [x[:3] for x in b]
    np.testing.assert_allclose([x[3:] for x in a], [x[3:] for x in b], rtol=0, atol=1e-9)
    # every library row was timed, in the fast engine only the timing runs
    assert all(math.isfinite(r["update_us"]) for r in lib["rows"] if r["estimator"] != "gps")
    timed = {r["run"] for r in serial["rows"] if math.isfinite(r["update_us"])}
    assert timed == {0}


def test_common_random_numbers_and_seed_per_run():
    pos, _, _, Z = _data("impulsive", runs=(0, 1))
    _, _, _, Z0 = _data("impulsive", runs=(0,))
    assert np.array_equal(Z[0], Z0[0])  # run r is seed r, whatever else is run
    assert not np.allclose(Z[0], Z[1])
    err = Z - pos
    assert 0.5 < np.var(err[..., 1]) / np.var(err[..., 0]) / 10 < 2.0  # R = diag(10, 100)


def test_command_end_to_end(tmp_path, capsys):
    from ag_uav.cli import main

    rc = main(["experiment", "numerical", "--runs", "2", "--steps", "120", "--out",
               str(tmp_path), "-q", "--workers", "1", "--timing-runs", "1"])
    assert rc == 0
    for f in ("results.csv", "summary.csv", "numerical.md", "tracks.png", "rmse.png"):
        assert (tmp_path / f).stat().st_size > 0
    with (tmp_path / "results.csv").open() as f:
        rows = list(csv.DictReader(f))
    assert len(rows) == 2 * len(num.CASES) * (len(num.ESTIMATORS) + 1)
    assert {r["estimator"] for r in rows} == {"gps", *num.ESTIMATORS}
    assert all(float(r["rmse_m"]) > 0 for r in rows)
    out = capsys.readouterr().out
    assert "paper" in out and "self-check" in out
    with (tmp_path / "summary.csv").open() as f:
        summ = list(csv.DictReader(f))
    kf = [r for r in summ if r["estimator"] == "kf"]
    assert all(float(r["paper_matlab_rmse_m"]) == 0.328 for r in kf)
    # filters beat the raw fixes on white noise
    white = {r["estimator"]: float(r["rmse_m"]) for r in summ if r["case"] == "white"}
    assert white["kf"] < white["gps"] and white["mckf"] < white["gps"]


def test_bad_arguments_are_config_errors(tmp_path):
    from ag_uav.config import ConfigError

    p = argparse.ArgumentParser()
    num.add_arguments(p)
    with pytest.raises(ConfigError):
        num.main(p.parse_args(["--cases", "pink", "--out", str(tmp_path)]))
    with pytest.raises(ConfigError):
        num.main(p.parse_args(["--estimators", "ukf", "--out", str(tmp_path)]))


def test_kernel_sweep_names_and_infinite_sigma_is_the_kf():
    """``mckf@inf`` gives the KF's estimates; ``mckf-adaptive`` follows the hand-written
    reference MCKF (tests/oracles) with the adaptive bandwidth; ``mckf-multi@2`` is σ = ∞ on the
    state rows and 2 on the measurement rows, batched and library alike."""
    from tests.oracles.mckf import OracleMCKF

    assert num.parse_estimator("pca-mckf-norec-adaptive@4") == ("pca-mckf-norec", "adaptive",
                                                                 4.0)
    assert num.parse_estimator("mckf@inf") == ("mckf", "fixed", math.inf)
    for bad in ("kf@2", "mckf@0", "mckf@x", "kf-adaptive", "mckf-huber"):
        with pytest.raises(ValueError):
            num.parse_estimator(bad)
    pos, x0, P0, Z = _data("impulsive", runs=(0, 1))
    gains = {"kf": num.gain_sequence("kf", TINY, len(pos), x0, P0)}
    ests = ["kf", "mckf@inf", "mckf-adaptive", "mckf-multi@2", "mckf@1"]
    _, tr = num.fast_tracks(TINY, "impulsive", [0, 1], ests, gains)
    np.testing.assert_allclose(tr["mckf@inf"], tr["kf"], rtol=0, atol=1e-9)
    assert np.abs(tr["mckf@1"] - tr["kf"]).max() > 0.1
    m = num.model()
    for b in range(2):
        ref = OracleMCKF(m.F, m.H, m.Q, m.R, x0, P0, sigma=2.0, adaptive_sigma=True)
        for k in range(len(pos)):
            if k:
                ref.predict()
            ref.update(Z[b, k])
            np.testing.assert_allclose(tr["mckf-adaptive"][b, k], ref.x[[0, 2]], rtol=0,
                                       atol=1e-8)
        lib = _library_track("mckf-multi@2", Z[b], x0, P0)
        np.testing.assert_allclose(tr["mckf-multi@2"][b], lib, rtol=0, atol=1e-9)
    f = num.make_filter("mckf-multi@2", TINY, x0, P0)
    assert np.all(np.isinf(f.sigma[:4])) and np.all(f.sigma[4:] == 2.0)
    assert np.abs(tr["mckf-multi@2"] - tr["mckf-adaptive"]).max() > 1e-3


def test_bad_kernel_names_are_config_errors(tmp_path):
    from ag_uav.config import ConfigError

    p = argparse.ArgumentParser()
    num.add_arguments(p)
    with pytest.raises(ConfigError, match="NAME\\[-adaptive"):
        num.main(p.parse_args(["--estimators", "kf@3", "--out", str(tmp_path)]))
