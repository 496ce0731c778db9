"""One executor seam for batches and tuning: serial, a local process pool, or Dask distributed.

Every parallel consumer (``ag-uav batch``, ``ag-uav tune``, ``ag-uav experiment table2``,
:func:`ag_uav.jobs.bench.workers.bench_workers`) goes through :class:`Executor`:

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

Failures of the machinery are never silent and never hang:

- a worker that dies is retried a bounded number of times (the pool resubmits the tasks of a
  broken pool up to :attr:`LocalPoolExecutor.retries` times; Dask reschedules a lost worker's
  tasks up to its ``distributed.scheduler.allowed-failures``), then its tasks are yielded as
  exceptions (``return_exceptions=True``);
- when the executor can run nothing more (the Dask scheduler is gone, or no Dask worker has been
  connected for ``lost_timeout_s``), ``map_unordered`` raises :class:`ExecutorLost` with one line
  saying why; what finished before was yielded.

Results never depend on the executor: a run's outcome is a function of its config and seed only
(every random draw comes from a Generator seeded from the config). Worker processes run with
one BLAS/OpenMP thread each (:data:`THREAD_ENV`), so N workers use N cores.
"""

from __future__ import annotations

import os
from collections.abc import Callable, Iterable, Iterator, Sequence
from concurrent.futures import FIRST_COMPLETED, Future, ProcessPoolExecutor, wait
from typing import Any

from ..config import ConfigError

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


class ExecutorLost(RuntimeError):
    """The executor can run nothing more (scheduler gone, no worker left); one line."""


class WorkerMismatch(ConfigError):
    """A worker runs other code than this client (another ``ag_uav`` version or other
    sources): one line naming the worker; nothing has run."""


def _first_line(e: BaseException) -> str:
    return (str(e).splitlines() or [""])[0][:120]


def _worker_sources() -> dict[str, Any]:
    """What a Dask worker reports to :meth:`DaskExecutor.check_sources`."""
    from .provenance import row_provenance, source_root

    return {**row_provenance(), "source_root": source_root()}


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
    #: the bound a batch keeps its process tree within (MB; None: 80 % of what is available)
    memory_mb: float | None = None

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
    kill) breaks the pool: the pool is rebuilt and its in-flight tasks are resubmitted, up to
    ``retries`` times each, then reported as exceptions (``BrokenProcessPool``); the remaining
    items go on. An interrupted ``map_unordered`` terminates the workers (no waiting on them).
    """

    def __init__(self, workers: int | None = None, env: dict[str, str] | None = None,
                 retries: int = 2) -> None:
        import multiprocessing as mp

        self.workers = default_workers() if workers is None else int(workers)
        if self.workers < 1:
            raise ValueError("workers must be >= 1")
        self.name = f"pool:{self.workers}"
        self.retries = int(retries)
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
        pending: dict[Future, tuple[int, Any]] = {}
        tries: dict[int, int] = {}
        again: list[tuple[int, Any]] = []  # tasks of a broken pool, to resubmit
        depth = 2 * self.workers
        exhausted = False

        def fill() -> None:
            nonlocal exhausted
            while len(pending) < depth and (again or not exhausted):
                if again:
                    i, x = again.pop(0)
                else:
                    try:
                        i, x = next(it)
                    except StopIteration:
                        exhausted = True
                        return
                pending[self._get_pool().submit(fn, x)] = (i, x)

        ok = False
        try:
            fill()
            while pending:
                done, _ = wait(pending, return_when=FIRST_COMPLETED)
                broken = any(isinstance(f.exception(), BrokenProcessPool) for f in done)
                if broken:  # every other in-flight task of the dead pool fails the same way
                    done = set(pending)
                for f in done:
                    i, x = pending.pop(f)
                    exc = (f.exception() if f.done() and not f.cancelled()
                           else BrokenProcessPool("pool broken"))
                    if isinstance(exc, BrokenProcessPool) and tries.get(i, 0) < self.retries:
                        tries[i] = tries.get(i, 0) + 1
                        again.append((i, x))
                        continue
                    if exc is not None and not return_exceptions:
                        raise exc
                    yield i, exc if exc is not None else f.result()
                if broken:
                    self._discard_pool()
                fill()
            ok = True
        finally:
            for f in pending:
                f.cancel()
            if not ok:  # interrupted (Ctrl-C, SIGTERM, a consumer's error): stop the workers
                self._discard_pool(kill=True)

    def _discard_pool(self, kill: bool = False) -> None:
        if self._pool is not None:
            procs = list(getattr(self._pool, "_processes", {}).values()) if kill else []
            self._pool.shutdown(wait=False, cancel_futures=True)
            for p in procs:  # running tasks are abandoned, not awaited
                p.terminate()
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
    connects to a running scheduler (its workers must import ``ag_uav`` from the same code,
    which :meth:`check_sources` checks before anything runs, and should run one thread each,
    e.g. ``dask worker ADDR --nthreads 1``).

    ``map_unordered`` watches the cluster every ``poll_s``: a scheduler that is gone, or no
    worker connected for ``lost_timeout_s``, raises :class:`ExecutorLost` (one line) instead of
    waiting forever. Dask's own connection-loss log lines and tracebacks are muted while the
    client is open (the one line replaces them)."""

    def __init__(self, address: str = "local", workers: int | None = None,
                 env: dict[str, str] | None = None, lost_timeout_s: float = 30.0,
                 poll_s: float = 0.5) -> None:
        try:
            from distributed import Client, LocalCluster
        except ImportError as e:  # pragma: no cover - optional dependency
            raise RuntimeError("the Dask executor needs `pip install dask distributed`") from e
        import logging

        if not lost_timeout_s > 0:
            raise ValueError(f"lost_timeout_s = {lost_timeout_s}: must be > 0")
        self.lost_timeout_s = float(lost_timeout_s)
        self.poll_s = float(poll_s)
        self._env = dict(THREAD_ENV if env is None else env)
        self._cluster = None
        self._muted: dict[str, int] = {}
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
            _check_address(address)
            self._mute_logs()
            try:
                _probe_scheduler(address, min(10.0, self.lost_timeout_s))
                self._client = Client(address, timeout=f"{min(20.0, self.lost_timeout_s):g}s")
            except BaseException:
                self._unmute_logs()
                raise
            self.name = f"dask:{address}"
        self.address = address
        try:
            nthreads = self._client.nthreads()
            self.workers = max(1, sum(nthreads.values()))
            self._client.run(_worker_init, self._env)
            self.check_sources()
        except BaseException:
            self.close()
            raise

    @property
    def client(self) -> Any:
        return self._client

    def check_sources(self) -> None:
        """Raise :class:`WorkerMismatch` (one line naming the worker) unless every connected
        worker runs the same ``ag_uav`` version and sources as this client (the
        :func:`~ag_uav.jobs.provenance.source_hash` of its ``ag_uav``, ``controllers``,
        ``estimators`` and ``jitcache``), as Dask's own version check does for packages."""
        from .provenance import provenance, source_root

        mine = provenance()
        theirs = self._client.run(_worker_sources, on_error="return")
        names = {a: w.get("name") for a, w in
                 self._client.scheduler_info().get("workers", {}).items()}
        for addr, got in sorted(theirs.items()):
            name = f" ({names[addr]})" if names.get(addr) not in (None, addr) else ""
            if isinstance(got, BaseException):
                raise WorkerMismatch(f"worker {addr}{name} cannot tell which ag-uav sources it "
                                     f"runs ({type(got).__name__}: {_first_line(got)}); start it "
                                     f"from the same code as this client ({source_root()})")
            if {k: got.get(k) for k in mine} != mine:
                raise WorkerMismatch(
                    f"worker {addr}{name} on {got.get('worker_host')}, pid "
                    f"{got.get('worker_pid')}, runs "
                    f"other ag-uav sources than this client: version {got.get('ag_uav_version')}"
                    f", source hash {got.get('source_hash')} from {got.get('source_root')} "
                    f"against version {mine['ag_uav_version']}, source hash "
                    f"{mine['source_hash']} from {source_root()}; start every worker from the "
                    "same code")

    def submit(self, fn: Callable[..., Any], *args: Any) -> Any:
        return self._client.submit(fn, *args, pure=False)

    def map_unordered(self, fn, items, *, return_exceptions=False):
        items = list(items)
        if not items:
            return
        futures = self._client.map(fn, items, pure=False)
        index = {f.key: i for i, f in enumerate(futures)}
        pending = set(futures)
        self._no_worker_since: float | None = None
        try:
            while pending:
                self._wait_some(pending)
                done = [f for f in pending if f.status in ("finished", "error", "cancelled")]
                for f in done:
                    pending.discard(f)
                    if f.status == "cancelled":
                        self._check_alive()
                    yield index[f.key], self._outcome(f, return_exceptions)
                if not done:
                    self._check_alive()
        finally:
            for f in futures:
                try:
                    if not f.done():
                        f.cancel()
                except Exception:  # noqa: BLE001, S110 - a client that lost its scheduler
                    pass

    def _wait_some(self, pending: set[Any]) -> None:
        """Block until a future of ``pending`` is done or ``poll_s`` has passed."""
        from distributed import wait
        from distributed.client import FuturesCancelledError

        try:
            wait(list(pending), timeout=self.poll_s, return_when="FIRST_COMPLETED")
        except (TimeoutError, FuturesCancelledError):
            pass

    @staticmethod
    def _outcome(f: Any, return_exceptions: bool) -> Any:
        try:
            r = f.result()
        except Exception as e:  # the task's error, a cancelled future, a lost worker
            if not return_exceptions:
                raise
            r = e
        f.release()
        return r

    def _check_alive(self) -> None:
        """Raise :class:`ExecutorLost` when the scheduler is gone or no worker has been
        connected for ``lost_timeout_s``."""
        import time

        if self._client.status != "running":
            raise ExecutorLost(f"dask: lost the scheduler at {self.address}")
        try:
            n_workers = len(self._client.nthreads())
        except Exception as e:  # noqa: BLE001 - the scheduler went away between the calls
            raise ExecutorLost(f"dask: lost the scheduler at {self.address} "
                               f"({type(e).__name__})") from None
        now = time.monotonic()
        if n_workers:
            self._no_worker_since = None
        elif self._no_worker_since is None:
            self._no_worker_since = now
        elif now - self._no_worker_since >= self.lost_timeout_s:
            raise ExecutorLost(f"dask: no worker left at {self.address} for "
                               f"{self.lost_timeout_s:g} s")

    def close(self) -> None:
        try:
            self._client.close(timeout=5)
        except Exception:  # noqa: BLE001, S110 - closing a client whose scheduler is gone
            pass
        finally:
            if self._cluster is not None:
                self._cluster.close()
                self._cluster = None
            self._unmute_logs()

    def _mute_logs(self) -> None:
        import logging

        names = ["distributed", *(n for n in logging.root.manager.loggerDict
                                  if n.startswith("distributed."))]
        for n in names:
            lg = logging.getLogger(n)
            self._muted[n] = lg.level
            lg.setLevel(logging.CRITICAL + 1)

    def _unmute_logs(self) -> None:
        import logging

        for n, level in self._muted.items():
            logging.getLogger(n).setLevel(level)
        self._muted.clear()


def _check_address(address: str) -> None:
    """A scheduler address is ``local`` or ``[PROTOCOL://]HOST:PORT``; anything else is one
    ValueError line (Dask's own message is a traceback deep in its comm layer)."""
    import re

    if not re.fullmatch(r"([a-z]+://)?[^\s:/]+:\d{1,5}", address):
        raise ValueError(f'"{address}": not a Dask scheduler address; expected "local" or '
                         "tcp://HOST:PORT")


def _probe_scheduler(address: str, timeout_s: float) -> None:
    """Raise :class:`TimeoutError` (one line) unless the ``tcp://`` endpoint at ``address``
    speaks first, as a Dask scheduler does: its listener writes its handshake as soon as a
    connection opens (``distributed.comm.core.Listener.on_connection``), whereas an HTTP
    server (a dashboard port, say) waits for a request, and Dask's client, which reads first,
    would wait on it with no bound.  Other protocols are left to Dask."""
    import socket

    if "://" in address and not address.startswith("tcp://"):
        return
    host, port = address.rsplit("/", 1)[-1].rsplit(":", 1)
    with socket.create_connection((host, int(port)), timeout=timeout_s) as s:
        s.settimeout(timeout_s)
        try:
            first = s.recv(1)
        except TimeoutError:
            first = None
    if not first:
        why = "closed the connection" if first == b"" else f"sent nothing in {timeout_s:g} s"
        raise TimeoutError(f"the endpoint {why}, where a Dask scheduler sends its handshake at "
                           "once: not a scheduler (a dashboard or other HTTP port?)")


def make_executor(workers: int | None = None, dask: str | None = None,
                  dask_timeout_s: float = 30.0) -> Executor:
    """The executor the CLI flags ask for: ``--dask ADDR`` → :class:`DaskExecutor`;
    ``--workers 1`` → :class:`SerialExecutor`; otherwise :class:`LocalPoolExecutor`."""
    if dask:
        return DaskExecutor(dask, workers, lost_timeout_s=dask_timeout_s)
    n = default_workers() if workers is None else int(workers)
    if n < 1:
        raise ValueError("workers must be >= 1")
    return SerialExecutor() if n == 1 else LocalPoolExecutor(n)


__all__ = ["Executor", "SerialExecutor", "LocalPoolExecutor", "DaskExecutor", "make_executor",
           "default_workers", "THREAD_ENV", "ExecutorLost", "WorkerMismatch"]
