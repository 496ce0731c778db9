"""``ag-uav batch`` and ``ag-uav tune``: headless runs on a process pool or Dask.

Exit codes: 0 when every run produced a result (a crashed vehicle is a result, and so is a run
that ended early: a warning line counts those); 1 with one line
when runs failed (lost to the machinery, or an exception in the product), when the executor was
lost (Dask scheduler gone, no worker left: the journal is kept and ``--resume`` completes the
job), or when an output could not be written (no space, no permission: the line names the
path); 2 for a bad spec, flag or ``--dask`` address, or a Dask worker that runs other
ag-uav sources than this client (named; before any run); 130 on Ctrl-C and 143 on SIGTERM, after
writing ``results.csv`` (batch) from what is done.
"""

from __future__ import annotations

import argparse
import contextlib
import signal
import sys
import time
from collections.abc import Iterator
from pathlib import Path

from ..config import ConfigError


class Terminated(BaseException):
    """SIGTERM, raised in the main thread so that ``finally`` blocks (results.csv, journal,
    checkpoint) run; a BaseException so that no ``except Exception`` turns it into a row."""


@contextlib.contextmanager
def _sigterm_raises() -> Iterator[None]:
    def handler(signum: int, frame: object) -> None:
        raise Terminated()

    try:
        old = signal.signal(signal.SIGTERM, handler)
    except ValueError:  # not the main thread: leave SIGTERM alone
        yield
        return
    try:
        yield
    finally:
        signal.signal(signal.SIGTERM, old)


def _fail(msg: str, code: int = 1) -> int:
    print(f"ag-uav: {msg}", file=sys.stderr)
    return code


def _guarded(what: str, out: Path, job, kept: str) -> tuple[int | None, object]:
    """``job()`` with SIGTERM raising; the known ways a job stops become one line and an exit
    code: ``(code, None)``; a job that ran: ``(None, result)``."""
    from ..jobs.batch import BatchStopped
    from ..jobs.executor import ExecutorLost
    from ..jobs.tune import TuneStopped
    from ..record.atomic import DISK_ERRNOS, disk_error_line

    t0 = time.perf_counter()
    try:
        with _sigterm_raises():
            return None, job()
    except Terminated:
        return _fail(f"{what} terminated (SIGTERM) after {time.perf_counter() - t0:.1f} s; "
                     f"{kept}; --resume in {out} continues", 143), None
    except (BatchStopped, TuneStopped, ExecutorLost) as e:
        extra = "" if isinstance(e, BatchStopped | TuneStopped) else (
            f"; {what} stopped, --resume in {out} continues")
        return _fail(f"{e}{extra}"), None
    except OSError as e:
        if e.errno not in DISK_ERRNOS:
            raise
        return _fail(f"cannot write {disk_error_line(e)}"), None


def _add_exec_args(p: argparse.ArgumentParser) -> None:
    p.add_argument("--workers", "-j", type=int, default=None, metavar="N",
                   help="parallel worker processes (default: CPU count; 1 = in this process)")
    p.add_argument("--dask", metavar="ADDR", default=None,
                   help='run on Dask distributed: "local" starts a LocalCluster of --workers '
                        "single-threaded process workers; tcp://host:port uses a running "
                        "scheduler, whose workers must run this client's ag-uav version and "
                        "sources (checked before any run: exit 2 naming a worker that does "
                        "not)")
    p.add_argument("--resume", action="store_true",
                   help="continue an interrupted job in --out (finished work is not re-run)")
    p.add_argument("--fresh", action="store_true",
                   help="discard what --out holds from an earlier job and start over")
    p.add_argument("--dask-timeout", type=float, default=30.0, metavar="S",
                   help="with --dask: stop (exit 1, --resume continues) when no worker has been "
                        "connected for S seconds (default 30); a lost scheduler stops at once")
    p.add_argument("--quiet", "-q", action="store_true", help="no progress bar")


def _add_memory_arg(p: argparse.ArgumentParser) -> None:
    p.add_argument("--memory-mb", type=float, default=None, metavar="MB",
                   help="bound on the process tree's memory (this process and the workers); "
                        "the runs are chunked to fit it and a --workers that cannot fit is "
                        "refused (default: 80%% of the memory available now)")


#: more worker processes per core than this is refused (each is a process with its own engine)
MAX_WORKERS_PER_CORE = 4


def _check_workers(n: int | None) -> None:
    """``--workers``: >= 1 and at most :data:`MAX_WORKERS_PER_CORE` per core (one line, exit
    2); more than the cores is a warning (they compete for the cores: no speed-up, and the
    process tree holds workers × one run's memory)."""
    import os

    if n is None:
        return
    cores = os.cpu_count() or 1
    if n < 1 or n > MAX_WORKERS_PER_CORE * cores:
        raise ConfigError(f"--workers = {n}: must be in [1, {MAX_WORKERS_PER_CORE * cores}] "
                          f"({MAX_WORKERS_PER_CORE} per core, {cores} cores here)")
    if n > cores:
        print(f"ag-uav: warning: --workers = {n} on {cores} cores: oversubscribed (the workers "
              "share the cores, so no speed-up, and memory grows with each worker)",
              file=sys.stderr)


def _executor(args: argparse.Namespace):
    from ..jobs.executor import WorkerMismatch, make_executor

    _check_workers(args.workers)
    if args.resume and args.fresh:
        raise ConfigError("--resume and --fresh: choose one")
    if not args.dask_timeout > 0:
        raise ConfigError(f"--dask-timeout = {args.dask_timeout}: must be > 0")
    try:
        return make_executor(args.workers, args.dask, dask_timeout_s=args.dask_timeout)
    except WorkerMismatch as e:
        raise ConfigError(f'--dask = "{args.dask}": {e}') from None
    except ValueError as e:
        if not args.dask:
            raise
        raise ConfigError(f"--dask = {e}") from None
    except (OSError, TimeoutError) as e:
        raise ConfigError(f'--dask = "{args.dask}": cannot connect ({e})') from None


def _load_spec(load_spec, path: str, what: str):
    """``load_spec(path)``; a file that is not UTF-8 is a one-line ConfigError (not a
    traceback)."""
    try:
        return load_spec(path)
    except UnicodeDecodeError as e:
        raise ConfigError(f'{what} spec = "{path}": not UTF-8 text (byte {e.start}); TOML files '
                          "are UTF-8") from None


def cmd_batch(args: argparse.Namespace) -> int:
    from ..jobs.batch import BatchOptions, expand, load_spec, print_table, run_batch, summary_rows

    spec = _load_spec(lambda p: load_spec(p, max_runs=args.max_runs), args.spec, "batch")
    tasks = expand(spec)
    out = Path(args.out or f"runs/batch-{spec.name}")
    if args.dry_run:
        print(f"batch {spec.name}: {len(tasks)} runs; axes: "
              + "; ".join(f"{a.name} × {len(a.values)}" for a in spec.axes) + f"; out: {out}")
        return 0
    if args.memory_mb is not None and not args.memory_mb > 0:
        raise ConfigError(f"--memory-mb = {args.memory_mb:g}: must be > 0")
    with _executor(args) as ex:
        ex.memory_mb = args.memory_mb
        code, res = _guarded(f"batch {spec.name}", out, lambda: run_batch(
            spec, out, ex, BatchOptions(resume=args.resume, fresh=args.fresh, logs=args.logs,
                                        progress=not args.quiet, report=not args.no_report),
            tasks=tasks),
            kept=f"finished runs kept, {out / 'results.csv'} written")
    if code is not None:
        return code
    group = [a.name for a in spec.axes if a.name != "seed" and len(a.values) > 1]
    header, table = summary_rows(res.rows, group)
    print_table(header, table, f"batch {spec.name}: {len(res.rows)} runs "
                f"({res.n_run} run now, {res.n_skipped} resumed) in {res.wall_s:.1f} s "
                f"on {res.executor}")
    print(f"results: {out / 'results.csv'}" + ("" if args.no_report else
                                                f"; report: {out / 'report.md'}"))
    if res.n_run:
        print(f"memory: the process tree was planned within {res.memory_bound_mb:.0f} MB "
              f"(--memory-mb {res.memory_mb:.0f})")
    if res.n_fallback:
        print(f"ag-uav: warning: batch {spec.name}: {res.n_fallback} runs flown one at a time "
              "after their engine batch failed (column engine_fallback)", file=sys.stderr)
    early = res.early_line()
    if early:
        where = "results.csv (column status)" + ("" if args.no_report else " and report.md")
        print(f"ag-uav: warning: batch {spec.name}: {early}; see {where}", file=sys.stderr)
    line = res.failure_line()
    return 0 if line is None else _fail(f"batch {spec.name}: {line}")


def cmd_tune(args: argparse.Namespace) -> int:
    import dataclasses

    from ..jobs.tune import load_spec, run_tune

    spec = _load_spec(load_spec, args.spec, "tune")
    if args.optimizer and args.optimizer != spec.optimizer:
        spec = dataclasses.replace(spec, optimizer=args.optimizer, optimizer_options={})
    if args.pop is not None:
        from ..jobs.tune import check_pop

        spec = dataclasses.replace(spec, pop=check_pop(args.pop, "--pop"))
    if args.iters is not None and args.iters < 1:
        raise ConfigError(f"--iters = {args.iters}: must be >= 1")
    out = Path(args.out or f"runs/tune-{spec.name}")
    with _executor(args) as ex:
        code, res = _guarded(f"tune {spec.name}", out, lambda: run_tune(
            spec, out, ex, resume=args.resume, fresh=args.fresh, iters=args.iters,
            progress=not args.quiet), kept="finished iterations and evaluations kept")
    if code is not None:
        return code
    print(f"best cost {res.best_cost:.6g} (default gains {res.default_cost:.6g}) after "
          f"{res.iterations} iterations; {res.n_evals} evaluations in {res.wall_s:.1f} s")
    print(f"gains: {out / 'best_gains.toml'}; plot: {out / 'convergence.png'}; "
          f"table: {out / 'before_after.md'}")
    return 0


def register(sub) -> None:
    b = sub.add_parser(
        "batch", help="run a base config × axes (seeds, estimators, noise, wind, ...) in parallel",
        description="Run every combination of a batch spec's axes on a process pool or Dask; "
                    "write results.csv (one row per run), report.md and PNG figures, and print a "
                    "summary table. See examples/batch.toml. A run's status is ok only when its "
                    "mission was flown to its end; one that ended early says why (failsafe, cut "
                    "by sim.max_time_s, incomplete), is listed with the failed runs, and the "
                    "means cover the ok runs only, saying how many. Every row names the code "
                    "that flew it (ag_uav_version, source_hash, worker_host, worker_pid); a "
                    "Dask worker running other sources is refused before any run (exit 2).")
    b.add_argument("spec", metavar="SPEC.toml", help="batch spec: [base] and [axes]")
    b.add_argument("--out", metavar="DIR", help="output folder (default: runs/batch-<name>)")
    b.add_argument("--logs", action="store_true",
                   help="write a light MCAP log per run under OUT/runs/")
    b.add_argument("--no-report", action="store_true", help="results.csv only, no report")
    b.add_argument("--dry-run", action="store_true",
                   help="validate the spec and print the run count")
    b.add_argument("--max-runs", type=int, default=None, metavar="N",
                   help="refuse a spec of more than N runs (default: the spec's max_runs, else "
                        "10000)")
    _add_exec_args(b)
    _add_memory_arg(b)
    b.set_defaults(func=cmd_batch)

    t = sub.add_parser(
        "tune", help="tune controller gains with BB-BC (or PSO, CMA-ES) on simulated scenarios",
        description="Minimise an ISE/ITAE cost over step responses and a short mission with "
                    "BB-BC (or PSO, CMA-ES), evaluating each population in parallel; checkpoint "
                    "after every iteration; write best_gains.toml, convergence.png and a "
                    "before/after table. See examples/tune.toml.")
    t.add_argument("spec", metavar="SPEC.toml", help="tune spec: [params] bounds, [[scenarios]]")
    t.add_argument("--out", metavar="DIR", help="output folder (default: runs/tune-<name>)")
    t.add_argument("--optimizer", choices=("bbbc", "pso", "cmaes"),
                   help="override the spec's optimizer")
    t.add_argument("--iters", type=int, help="iterations in total (override the spec)")
    t.add_argument("--pop", type=int, help="population size (override the spec)")
    _add_exec_args(t)
    t.set_defaults(func=cmd_tune)
