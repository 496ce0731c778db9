"""The executor seam: serial and process-pool behaviour (the Dask path is in test_batch)."""

from __future__ import annotations

import os
from concurrent.futures.process import BrokenProcessPool

import pytest

from ag_uav.jobs.executor import (
    THREAD_ENV,
    LocalPoolExecutor,
    SerialExecutor,
    default_workers,
    make_executor,
)


def square(x: int) -> int:
    return x * x


def fail_on_three(x: int) -> int:
    if x == 3:
        raise ValueError("three")
    return x


def worker_env(_: int) -> dict[str, str | None]:
    return {k: os.environ.get(k) for k in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS")}


def die_on_two(x: int) -> int:
    if x == 2:
        os._exit(13)
    return x + 100


def test_serial_map_and_unordered():
    ex = SerialExecutor()
    assert ex.map(square, range(5)) == [0, 1, 4, 9, 16]
    assert list(ex.map_unordered(square, [3, 4])) == [(0, 9), (1, 16)]
    assert ex.submit(square, 7).result() == 49
    with pytest.raises(ValueError):
        list(ex.map_unordered(fail_on_three, range(5)))
    got = dict(ex.map_unordered(fail_on_three, range(5), return_exceptions=True))
    assert isinstance(got[3], ValueError) and got[4] == 4 and len(got) == 5


def test_make_executor_kinds():
    assert isinstance(make_executor(1), SerialExecutor)
    ex = make_executor(2)
    assert isinstance(ex, LocalPoolExecutor) and ex.workers == 2
    ex.close()
    assert default_workers() >= 1
    with pytest.raises(ValueError):
        LocalPoolExecutor(0)


def test_pool_results_indices_env_and_errors():
    with LocalPoolExecutor(2) as ex:
        pairs = list(ex.map_unordered(square, range(9)))
        assert sorted(i for i, _ in pairs) == list(range(9))
        assert all(r == i * i for i, r in pairs)
        assert ex.map(square, [5, 6, 7]) == [25, 36, 49]
        assert ex.submit(square, 9).result() == 81
        envs = ex.map(worker_env, range(2))
        assert all(e["OMP_NUM_THREADS"] == THREAD_ENV["OMP_NUM_THREADS"] == "1" for e in envs)
        got = dict(ex.map_unordered(fail_on_three, range(6), return_exceptions=True))
        assert isinstance(got[3], ValueError) and got[5] == 5
        with pytest.raises(ValueError):
            list(ex.map_unordered(fail_on_three, range(6)))


def test_pool_survives_a_dead_worker():
    with LocalPoolExecutor(1) as ex:
        got = dict(ex.map_unordered(die_on_two, range(8), return_exceptions=True))
        assert sorted(got) == list(range(8))
        assert isinstance(got[2], BrokenProcessPool)
        # items submitted after the pool was rebuilt run normally
        assert got[7] == 107 and got[0] == 100
        assert ex.map(square, [3]) == [9]
