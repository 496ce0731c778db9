"""One executor seam for batches and tuning: serial, a local process pool, or Dask distributed.

Every parallel consumer (``ag-uav batch``, ``ag-uav tune``, ``ag-uav experiment table2``,
:func:`ag_uav.jobs.batch.bench_workers`) goes through :class:`Executor`:

- ``submit(fn, *args)`` → a :class:`concurrent.futures.Future`-like object with ``result()``;
- ``map_unordered(fn, items)`` → yields ``(index, result)`` pairs in completion order; with
  ``return_exceptions=True`` an exception raised by ``fn`` (or by the machinery: a worker process
  that died) is yielded in place of the result instead of being raised;
- ``map(fn, items)`` → the results as a list in item order.

Implementations: :class:`SerialExecutor` (in-process, for tests and debugging),
:class:`LocalPoolExecutor` (``concurrent.futures.ProcessPoolExecutor``, spawn start method) and
:class:`DaskExecutor` (``dask.distributed``: a ``LocalCluster`` of single-threaded process
workers, or a running scheduler at ``tcp://host:port``). ``fn`` and the items must be picklable
(top-level functions and plain data).

Results never depend on the executor: a run's outcome is a function of its config and seed only
(every random draw comes from a Generator seeded from the config). Worker processes run with
one BLAS/OpenMP thread each (:data:`THREAD_ENV`), so N workers use N cores.
"""

from __future__ import annotations

import os
from collections.abc import Callable, Iterable, Iterator, Sequence
from concurrent.futures import FIRST_COMPLETED, Future, ProcessPoolExecutor, wait
from typing import Any

#: Environment that pins numerical libraries to one thread in every worker process.
THREAD_ENV = {
    "OMP_NUM_THREADS": "1",
    "OPENBLAS_NUM_THREADS": "1",
    "MKL_NUM_THREADS": "1",
    "NUMEXPR_NUM_THREADS": "1",
    "VECLIB_MAXIMUM_THREADS": "1",
    "BLIS_NUM_THREADS": "1",
    "LP_NUM_THREADS": "1",
    "NUMBA_NUM_THREADS": "1",
    "AG_UAV_ENGINE_THREADS": "1",
    "MUJOCO_GL": "egl",
}


def _worker_init(env: dict[str, str], watch_parent: bool = False) -> None:
    """Process-pool initializer: apply the thread environment (inherited anyway under spawn);
    with ``watch_parent``, exit when the parent process dies (e.g. a SIGKILLed batch), instead
    of waiting forever on the task queue."""
    os.environ.update(env)
    if watch_parent:
        import threading
        import time

        ppid = os.getppid()

        def watch() -> None:
            while True:
                time.sleep(0.5)
                if os.getppid() != ppid:
                    os._exit(0)

        threading.Thread(target=watch, name="ag-uav-parent-watch", daemon=True).start()


def _push_env(env: dict[str, str]) -> dict[str, str | None]:
    """Set ``env`` in this process (children inherit it); return the previous values."""
    old = {k: os.environ.get(k) for k in env}
    os.environ.update(env)
    return old


def _pop_env(old: dict[str, str | None]) -> None:
    for k, v in old.items():
        if v is None:
            os.environ.pop(k, None)
        else:
            os.environ[k] = v


def default_workers() -> int:
    """CPU cores available to this process."""
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except AttributeError:  # pragma: no cover - not Linux
        return max(1, os.cpu_count() or 1)


class Executor:
    """The seam. Subclasses implement :meth:`submit`, :meth:`map_unordered` and :meth:`close`."""

    #: a short description for logs and reports ("serial", "pool:2", "dask:tcp://...")
    name = "executor"
    #: number of tasks that run at the same time
    workers = 1

    def submit(self, fn: Callable[..., Any], *args: Any) -> Any:
        raise NotImplementedError

    def map_unordered(self, fn: Callable[[Any], Any], items: Iterable[Any], *,
                      return_exceptions: bool = False) -> Iterator[tuple[int, Any]]:
        raise NotImplementedError

    def map(self, fn: Callable[[Any], Any], items: Iterable[Any]) -> list[Any]:
        """``[fn(x) for x in items]`` evaluated on the executor (order kept; raises)."""
        items = list(items)
        out: list[Any] = [None] * len(items)
        for i, r in self.map_unordered(fn, items):
            out[i] = r
        return out

    def map_fn(self) -> Callable[[Callable[[Any], Any], Sequence[Any]], list[Any]]:
        """A ``map_fn(fun, xs)`` for :func:`controllers.optim.bbbc_minimize`."""
        return lambda fun, xs: self.map(fun, xs)

    def close(self) -> None:
        pass

    def __enter__(self) -> Executor:
        return self

    def __exit__(self, *exc: Any) -> None:
        self.close()


class SerialExecutor(Executor):
    """Runs everything in this process, in item order (reference behaviour, debugging)."""

    name = "serial"
    workers = 1

    def submit(self, fn: Callable[..., Any], *args: Any) -> Future:
        f: Future = Future()
        try:
            f.set_result(fn(*args))
        except Exception as e:  # noqa: BLE001 - delivered through the future
            f.set_exception(e)
        return f

    def map_unordered(self, fn, items, *, return_exceptions=False):
        for i, x in enumerate(items):
            try:
                r = fn(x)
            except Exception as e:
                if not return_exceptions:
                    raise
                r = e
            yield i, r


class LocalPoolExecutor(Executor):
    """A ``ProcessPoolExecutor`` of ``workers`` processes (spawn start method).

    At most ``2 × workers`` tasks are in flight at once, so a long item list is fed lazily and an
    interrupted batch has little queued work to throw away. A worker that dies (segfault, OOM
    kill) breaks the pool: its in-flight tasks are reported as exceptions (``BrokenProcessPool``),
    the pool is rebuilt and the remaining items go on.
    """

    def __init__(self, workers: int | None = None, env: dict[str, str] | None = None) -> None:
        import multiprocessing as mp

        self.workers = default_workers() if workers is None else int(workers)
        if self.workers < 1:
            raise ValueError("workers must be >= 1")
        self.name = f"pool:{self.workers}"
        self._env = dict(THREAD_ENV if env is None else env)
        self._ctx = mp.get_context("spawn")
        self._pool: ProcessPoolExecutor | None = None

    def _get_pool(self) -> ProcessPoolExecutor:
        if self._pool is None:
            old = _push_env(self._env)
            try:
                self._pool = ProcessPoolExecutor(self.workers, mp_context=self._ctx,
                                                 initializer=_worker_init,
                                                 initargs=(self._env, True))
            finally:
                _pop_env(old)
        return self._pool

    def warm_up(self) -> None:
        """Start every worker process now (imports included), e.g. before timing."""
        pool = self._get_pool()
        list(pool.map(_warm, range(self.workers * 2)))

    def submit(self, fn: Callable[..., Any], *args: Any) -> Future:
        return self._get_pool().submit(fn, *args)

    def map_unordered(self, fn, items, *, return_exceptions=False):
        from concurrent.futures.process import BrokenProcessPool

        it = iter(enumerate(items))
        pending: dict[Future, int] = {}
        depth = 2 * self.workers
        exhausted = False

        def fill() -> None:
            nonlocal exhausted
            while not exhausted and len(pending) < depth:
                try:
                    i, x = next(it)
                except StopIteration:
                    exhausted = True
                    return
                pending[self._get_pool().submit(fn, x)] = i

        try:
            fill()
            while pending:
                done, _ = wait(pending, return_when=FIRST_COMPLETED)
                broken = False
                for f in done:
                    i = pending.pop(f)
                    try:
                        r = f.result()
                    except BrokenProcessPool as e:
                        broken = True
                        if not return_exceptions:
                            raise
                        r = e
                    except Exception as e:
                        if not return_exceptions:
                            raise
                        r = e
                    yield i, r
                if broken:
                    # every other in-flight task of the dead pool fails the same way
                    for f in list(pending):
                        i = pending.pop(f)
                        exc = f.exception() if f.done() else BrokenProcessPool("pool broken")
                        yield i, exc if exc is not None else f.result()
                    self._discard_pool()
                fill()
        finally:
            for f in pending:
                f.cancel()

    def _discard_pool(self) -> None:
        if self._pool is not None:
            self._pool.shutdown(wait=False, cancel_futures=True)
            self._pool = None

    def close(self) -> None:
        if self._pool is not None:
            self._pool.shutdown(wait=True, cancel_futures=True)
            self._pool = None


def _warm(_: int) -> int:
    import time

    import ag_uav.engine.missions  # noqa: F401 - import the heavy modules once per worker

    time.sleep(0.05)
    return os.getpid()


class DaskExecutor(Executor):
    """``dask.distributed``: ``address="local"`` starts a ``LocalCluster`` of ``workers``
    single-threaded process workers (loopback only, no dashboard); ``"tcp://host:port"``
    connects to a running scheduler (its workers should import ``ag_uav`` from the same code
    and run one thread each, e.g. ``dask worker ADDR --nthreads 1``)."""

    def __init__(self, address: str = "local", workers: int | None = None,
                 env: dict[str, str] | None = None) -> None:
        try:
            from distributed import Client, LocalCluster
        except ImportError as e:  # pragma: no cover - optional dependency
            raise RuntimeError("the Dask executor needs `pip install dask distributed`") from e
        import logging

        self._env = dict(THREAD_ENV if env is None else env)
        self._cluster = None
        if address == "local":
            n = default_workers() if workers is None else int(workers)
            if n < 1:
                raise ValueError("workers must be >= 1")
            old = _push_env(self._env)
            try:
                self._cluster = LocalCluster(n_workers=n, threads_per_worker=1, processes=True,
                                             host="127.0.0.1", dashboard_address=None,
                                             silence_logs=logging.ERROR)
            finally:
                _pop_env(old)
            self._client = Client(self._cluster)
            self.name = f"dask:local:{n}"
        else:
            self._client = Client(address, timeout="20s")
            self.name = f"dask:{address}"
        nthreads = self._client.nthreads()
        self.workers = max(1, sum(nthreads.values()))
        self._client.run(_worker_init, self._env)

    @property
    def client(self) -> Any:
        return self._client

    def submit(self, fn: Callable[..., Any], *args: Any) -> Any:
        return self._client.submit(fn, *args, pure=False)

    def map_unordered(self, fn, items, *, return_exceptions=False):
        from distributed import as_completed

        items = list(items)
        if not items:
            return
        futures = self._client.map(fn, items, pure=False)
        index = {f.key: i for i, f in enumerate(futures)}
        try:
            for f in as_completed(futures):
                i = index[f.key]
                if f.status == "error":
                    exc = f.exception()
                    if not return_exceptions:
                        raise exc
                    r: Any = exc
                else:
                    try:
                        r = f.result()
                    except Exception as e:  # e.g. a cancelled future or a lost worker
                        if not return_exceptions:
                            raise
                        r = e
                f.release()
                yield i, r
        finally:
            for f in futures:
                if not f.done():
                    f.cancel()

    def close(self) -> None:
        try:
            self._client.close()
        finally:
            if self._cluster is not None:
                self._cluster.close()
                self._cluster = None


def make_executor(workers: int | None = None, dask: str | None = None) -> Executor:
    """The executor the CLI flags ask for: ``--dask ADDR`` → :class:`DaskExecutor`;
    ``--workers 1`` → :class:`SerialExecutor`; otherwise :class:`LocalPoolExecutor`."""
    if dask:
        return DaskExecutor(dask, workers)
    n = default_workers() if workers is None else int(workers)
    if n < 1:
        raise ValueError("workers must be >= 1")
    return SerialExecutor() if n == 1 else LocalPoolExecutor(n)


__all__ = ["Executor", "SerialExecutor", "LocalPoolExecutor", "DaskExecutor", "make_executor",
           "default_workers", "THREAD_ENV"]
