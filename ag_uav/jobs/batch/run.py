"""Running a batch: :func:`run_batch` journals each finished chunk, shows progress, writes
``results.csv`` however the call ends and the report at the end."""

from __future__ import annotations

import json
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from ...config import ConfigError
from ...record.atomic import atomic_write_text
from ..batch_memory import default_memory_mb, memory_plan, this_process_mb
from ..executor import Executor, ExecutorLost, SerialExecutor, WorkerMismatch
from ..provenance import provenance
from .journal import Journal, json_default, signals_held
from .report import write_report, write_results_csv
from .spec import BatchSpec, RunTask, expand
from .worker import EARLY_STATUSES, exception_line, row_reason, run_chunk, run_status


# ---------------------------------------------------------------------------------- run_batch
class BatchStopped(RuntimeError):
    """The batch stopped before every run had a row (the executor was lost: scheduler gone, no
    worker left). One line; ``results.csv`` holds what finished and ``--resume`` completes it."""


@dataclass
class BatchResult:
    rows: list[dict[str, Any]]       # sorted by index
    out_dir: Path
    n_run: int                       # runs executed in this call
    n_skipped: int                   # runs taken from the journal (--resume)
    wall_s: float
    executor: str
    files: list[Path] = field(default_factory=list)
    n_lost: int = 0                  # runs of this call lost to the machinery (re-run on resume)
    n_fallback: int = 0              # rows flown one at a time after their engine batch failed
    journal_skipped: int = 0         # unreadable journal lines passed over (--resume)
    memory_bound_mb: float = 0.0     # the process tree's bound the chunks were planned for
    memory_mb: float = 0.0           # the budget it had to fit (--memory-mb)

    def failure_line(self) -> str | None:
        """None when every run produced a result (ok or crashed: a crash is a result); else one
        line: how many runs failed, lost to the machinery or by an exception in the product."""
        bad = [r for r in self.rows if r.get("status") == "error"]
        if not bad:
            return None
        lost = [r for r in bad if str(r.get("crash_reason", "")).startswith(LOST_PREFIX)]
        parts = []
        if lost:
            parts.append(f"{len(lost)} lost to the machinery ({lost[0]['crash_reason']}; "
                         "--resume re-runs them)")
        if len(bad) > len(lost):
            first = next(r for r in bad if r not in lost)
            parts.append(f"{len(bad) - len(lost)} raised in the product (first: run "
                         f"{first.get('run_id')}: {first.get('crash_reason')})")
        return f"{len(bad)} of {len(self.rows)} runs failed: " + "; ".join(parts)

    def early_line(self) -> str | None:
        """None when no run ended early; else one line: how many runs ended early and why
        (failsafe, cut, incomplete), the first one's reason; they are results, not in the
        means, and listed with the failed runs in ``report.md``."""
        early = [r for r in self.rows if r.get("status") in EARLY_STATUSES]
        if not early:
            return None
        why = ", ".join(f"{s} {n}" for s in EARLY_STATUSES
                        if (n := sum(r.get("status") == s for r in early)))
        return (f"{len(early)} of {len(self.rows)} runs ended early ({why}; first: run "
                f"{early[0].get('run_id')}: {row_reason(early[0])}): not ok, not in the means")


#: ``crash_reason`` of a row whose run was lost to the machinery (journalled as a retry)
LOST_PREFIX = "worker failure: "


@dataclass(frozen=True)
class BatchOptions:
    """How :func:`run_batch` runs a batch (the spec says what it runs)."""

    #: skip the runs already in ``out_dir/journal.jsonl``
    resume: bool = False
    #: discard an existing journal (with neither, an existing journal is an error)
    fresh: bool = False
    #: log every run (light channels) under ``out_dir/runs``
    logs: bool = False
    #: show a progress bar
    progress: bool = True
    #: write ``report.md`` and its figures at the end
    report: bool = True
    #: called with each row as it is journalled
    on_row: Callable[[dict[str, Any]], None] | None = None
    #: where warnings go (default: one line on stderr)
    warn: Callable[[str], None] | None = None


def run_batch(spec: BatchSpec, out_dir: str | Path, executor: Executor | None = None,
              options: BatchOptions = BatchOptions(), *,
              tasks: list[RunTask] | None = None) -> BatchResult:
    """Run every task of ``spec`` (or ``tasks``) on ``executor`` (default: serial) into
    ``out_dir``, as ``options`` (:class:`BatchOptions`) say.

    The executor's ``memory_mb`` bounds the process tree (this process and the workers;
    ``None``: :func:`~ag_uav.jobs.batch_memory.default_memory_mb`): the runs are chunked to fit
    it (:func:`~ag_uav.jobs.batch_memory.memory_plan`), and a worker count that cannot fit is
    refused before anything runs.

    ``options.resume``: skip runs already in ``out_dir/journal.jsonl``; ``options.fresh``:
    discard an existing journal. With neither, an existing journal is an error (nothing is
    overwritten silently).
    ``out_dir`` belongs to this batch while it runs (:func:`ag_uav.jobs.outdir.hold`: a second
    batch on it raises :class:`~ag_uav.jobs.outdir.FolderInUse`).
    ``results.csv`` is written however the call ends (an interrupt or SIGTERM included). When
    the executor is lost (:class:`~ag_uav.jobs.executor.ExecutorLost`), raises
    :class:`BatchStopped` after writing it. Warnings (unreadable journal lines, engine batches
    that fell back to one run at a time, resumed rows flown by other sources) go to
    ``options.warn`` (default: one line on stderr).

    Every row carries the code that flew it (:func:`ag_uav.jobs.provenance.row_provenance`:
    version, source hash, worker host and pid); a row flown by other code than this process's
    raises :class:`~ag_uav.jobs.executor.WorkerMismatch` (one line; not journalled).
    """
    from ..outdir import hold

    with hold(out_dir, "batch", "wait for it to finish, or choose another --out"):
        return _run_batch(spec, Path(out_dir), executor, options, tasks)


def _run_batch(spec: BatchSpec, out: Path, executor: Executor | None, opt: BatchOptions,
               tasks: list[RunTask] | None) -> BatchResult:
    tasks = tasks if tasks is not None else expand(spec)
    executor = executor or SerialExecutor()
    workers = 0 if isinstance(executor, SerialExecutor) else executor.workers
    mem = executor.memory_mb or default_memory_mb()
    journal = Journal(out / "journal.jsonl")
    resume, fresh = opt.resume, opt.fresh
    if journal.path.exists() and not (resume or fresh):
        raise ConfigError(f'--out = "{out}": already holds a batch journal; use --resume to '
                          "continue it or --fresh to start over")
    out.mkdir(parents=True, exist_ok=True)
    done = journal.read() if resume else {}
    if opt.logs:
        for t in tasks:
            t.logs_dir = str(out / "runs")
    todo = [t for t in tasks if t.config_hash not in done]
    rows_by_index = {t.index: _rebase_row(done[t.config_hash], t) for t in tasks
                     if t.config_hash in done}
    atomic_write_text(out / "batch.json", json.dumps({
        "name": spec.name, "source": spec.source, "n_runs": len(tasks),
        "axes": {a.name: a.values for a in spec.axes}, "base": spec.base,
        "presets": spec.presets}, indent=2, default=json_default))
    chunks, bound = memory_plan(todo, workers, mem, this_process_mb()) if todo else ([], 0.0)
    run = _BatchRun(spec.name, len(tasks), len(tasks) - len(todo), opt)
    if journal.skipped:
        run.warn(f"{journal.path}: skipped {journal.skipped} unreadable line(s); their runs "
                 "are run again")
    other = [r for r in rows_by_index.values() if r.get("source_hash") != run.code["source_hash"]]
    if other:
        run.warn(f"{len(other)} of the {len(rows_by_index)} resumed runs were flown by other "
                 f"ag-uav sources (source hash {other[0].get('source_hash') or 'not recorded'}) "
                 f"than this batch ({run.code['source_hash']}); results.csv's column "
                 "source_hash says which (--fresh flies them all again)")
    t0 = time.perf_counter()
    journal.open(fresh=fresh and not resume)
    stopped = None
    try:
        for c, rs in executor.map_unordered(run_chunk, [[todo[i] for i in ch] for ch in chunks],
                                            return_exceptions=True):
            run.chunk([todo[i] for i in chunks[c]], rs, journal, rows_by_index)
    except ExecutorLost as e:
        stopped = str(e)
    except BaseException:  # interrupted (Ctrl-C, SIGTERM) or a disk error: keep what is done
        run.finish(journal, rows_by_index, out / "results.csv", spec, quiet=True)
        raise
    rows = run.finish(journal, rows_by_index, out / "results.csv", spec)
    if stopped:
        raise BatchStopped(f"batch {spec.name} stopped: {stopped}; {len(rows)} of {len(tasks)} "
                           f"runs done, {out / 'results.csv'} written; --resume completes it")
    wall = time.perf_counter() - t0
    res = BatchResult(rows=rows, out_dir=out, n_run=len(todo), n_skipped=len(tasks) - len(todo),
                      wall_s=wall, executor=executor.name, files=[out / "results.csv"],
                      n_lost=run.n_lost, journal_skipped=journal.skipped,
                      n_fallback=sum(bool(r.get("engine_fallback")) for r in rows),
                      memory_bound_mb=bound, memory_mb=mem)
    if opt.report:
        res.files += write_report(rows, spec, out, info={
            "executor": executor.name, "wall time (this call)": f"{wall:.1f} s",
            "runs executed / resumed": f"{res.n_run} / {res.n_skipped}",
            "runs lost to the machinery (this call)": res.n_lost,
            "memory bound of the process tree": f"{bound:.0f} MB of {mem:.0f} MB"})
    return res


class _BatchRun:
    """The bookkeeping of one :func:`run_batch` call: journal rows, progress bar, warnings."""

    def __init__(self, name: str, n: int, n_done: int, opt: BatchOptions) -> None:
        self.bar = None
        if opt.progress:
            from ..._progress import progress_bar

            self.bar = progress_bar(total=n, initial=n_done, unit="run", desc=f"batch {name}",
                                    dynamic_ncols=True, smoothing=0.05)
        self._warn, self.on_row = opt.warn, opt.on_row
        self.n_bad = self.n_lost = 0
        self.code = provenance()  # the code this batch's rows must come from

    def warn(self, msg: str) -> None:
        if self._warn is not None:
            self._warn(msg)
            return
        import sys

        line = f"ag-uav: warning: {msg}"
        if self.bar is not None:
            self.bar.write(line, file=sys.stderr)
        else:
            print(line, file=sys.stderr)

    def chunk(self, tasks: list[RunTask], rs: Any, journal: Journal,
              rows_by_index: dict[int, dict[str, Any]]) -> None:
        """Journal the rows of one finished chunk (an exception: the machinery lost it)."""
        if isinstance(rs, BaseException):
            # the machinery failed (worker died, retries spent): a row now, re-run by --resume
            reason = f"{LOST_PREFIX}{exception_line(rs)}"[:300]
            rs = [{"index": t.index, "run_id": t.run_id, **t.axis_values, "status": "error",
                   "completed": False, "crashed": True, "crash_reason": reason,
                   "engine_fallback": "", **provenance()} for t in tasks]
            self.n_lost += len(tasks)
            self.warn(f"runs {tasks[0].run_id}..{tasks[-1].run_id}: {reason}")
            retry = True
        else:
            retry = False
            self._check_code(tasks, rs)
            fb = next((r.get("engine_fallback") for r in rs if r.get("engine_fallback")), "")
            if fb:
                self.warn(f"runs {tasks[0].run_id}..{tasks[-1].run_id}: the engine batch failed "
                          f"({fb}); flown one at a time (column engine_fallback)")
        for task, r in zip(tasks, rs, strict=True):
            with signals_held():  # the journal and the rows agree, whenever SIGTERM comes
                journal.append(task.config_hash, r, retry=retry)
                rows_by_index[task.index] = r
            self.n_bad += r.get("status") != "ok"
            if self.on_row is not None:
                self.on_row(r)
            if self.bar is not None:
                self.bar.update(1)
                if self.n_bad:
                    self.bar.set_postfix(not_ok=self.n_bad, refresh=False)

    def _check_code(self, tasks: list[RunTask], rs: list[dict[str, Any]]) -> None:
        """Raise :class:`~ag_uav.jobs.executor.WorkerMismatch` (one line; the rows are not
        journalled) when a row was flown by other code than this client's (a Dask worker that
        joined after the check at the start, or sources edited under a running pool)."""
        for r in rs:
            got = {k: r.get(k) for k in self.code}
            if got != self.code:
                raise WorkerMismatch(
                    f"runs {tasks[0].run_id}..{tasks[-1].run_id} were flown by a worker "
                    f"({r.get('worker_host')}, pid {r.get('worker_pid')}) running other ag-uav "
                    f"sources (version {got['ag_uav_version']}, source hash "
                    f"{got['source_hash']}) than this client (version "
                    f"{self.code['ag_uav_version']}, source hash {self.code['source_hash']}); "
                    "not journalled: start every worker from the same code, then --resume")

    def finish(self, journal: Journal, rows_by_index: dict[int, dict[str, Any]], csv_path: Path,
               spec: BatchSpec, quiet: bool = False) -> list[dict[str, Any]]:
        """Close the bar and the journal and write ``results.csv`` from what is done; with
        ``quiet`` (an exception is already on its way) a write error is a warning only."""
        if self.bar is not None:
            self.bar.close()
            self.bar = None
        journal.close()
        rows = [rows_by_index[k] for k in sorted(rows_by_index)]
        try:
            write_results_csv(rows, csv_path, [a.name for a in spec.axes])
        except OSError as e:
            if not quiet:
                raise
            self.warn(f"cannot write {e.filename or csv_path}: {e.strerror or e}")
        return rows


def _rebase_row(row: dict[str, Any], task: RunTask) -> dict[str, Any]:
    """A journal row under the current spec's index and axis values (same config hash)."""
    r = dict(row)
    r.update({"index": task.index, "run_id": task.run_id, **task.axis_values})
    r.setdefault("engine_fallback", "")
    if r.get("status") in ("ok", *EARLY_STATUSES):  # a journal written before the early statuses
        r["status"] = run_status(r)
    return r
