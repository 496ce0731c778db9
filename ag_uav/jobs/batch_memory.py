"""How much memory a batch takes, and the chunks that keep it within a bound.

A worker flies one lockstep chunk at a time (:func:`ag_uav.jobs.batch.run_chunk`); the engine's
memory of a run grows with its control ticks and filters, and its dose map with the field.
:func:`plan_chunks` groups the runs that can share an engine batch into chunks of about a
given size, and :func:`memory_plan` sizes them so that the whole process tree (this process as
it is, and the workers, each :data:`WORKER_BASE_MB` before its runs) fits ``--memory-mb``.
"""

from __future__ import annotations

from typing import Any

from ..config import ConfigError, config_from_dict

#: a :class:`ag_uav.jobs.batch.RunTask` (its ``config`` dict is all that is read here)
RunTask = Any

#: bytes the engine keeps per vehicle and control tick: records, IMU and spray job, plus
#: ``ENGINE_BYTES_PER_FILTER_TICK`` per filter of the bank (estimates, NEES/NIS records, the
#: per-run objects); measured: ~22 MB per 48,500-tick mission with one filter, ~31 MB with four
ENGINE_BYTES_PER_TICK = 420
ENGINE_BYTES_PER_FILTER_TICK = 120
#: memory one chunk's records may take (a worker holds one chunk at a time)
CHUNK_BYTES = 384 * 2**20
#: a worker process's own memory with a short run flown in it: the interpreter, numpy, MuJoCo
#: and the kernels (on the 2-core development machine a worker of short runs peaks at about
#: 306 MB with the kernels cached and at 555-576 MB when it compiles all of them from an empty
#: cache; tests/test_chaos_memory.py measures the whole tree)
WORKER_BASE_MB = 650


def default_memory_mb() -> float:
    """The process tree's memory bound when none is given: 80 % of what the machine has
    available now."""
    import psutil

    return 0.8 * psutil.virtual_memory().available / 2**20


def run_bytes(t: RunTask) -> tuple[Any, int]:
    """(engine-batch key, bytes) of one run: its per-tick records and filters over the
    mission's length, and its dose map (:func:`ag_uav.engine.missions.dose_map_mb`)."""
    from ..engine.missions import batch_key, dose_map_mb, mission_setup

    cfg = config_from_dict(t.config)
    fld, _, ref = mission_setup(cfg)
    e = cfg.estimator
    n_filters = len({*([e.name] if e.name != "true" else []), *e.shadow})
    n = (int(min(ref.duration, cfg.sim.max_time_s) * cfg.sim.control_hz) + 1) * (
        ENGINE_BYTES_PER_TICK + ENGINE_BYTES_PER_FILTER_TICK * n_filters)
    return batch_key(cfg), n + int(dose_map_mb(cfg, fld) * 2**20)


def measure(tasks: list[RunTask]) -> list[tuple[Any, int]]:
    """:func:`run_bytes` of every task; a task whose config cannot be read flies alone
    (``("alone", j)``, 1 byte: it becomes an error row when it runs)."""
    out = []
    for j, t in enumerate(tasks):
        try:
            out.append(run_bytes(t))
        except Exception:  # noqa: BLE001 - a bad run flies alone (and becomes an error row)
            out.append((("alone", j), 1))
    return out


def plan_chunks(tasks: list[RunTask], workers: int, max_runs: int = 64,
                budget_bytes: int = CHUNK_BYTES,
                measured: list[tuple[Any, int]] | None = None) -> list[list[int]]:
    """Indices of ``tasks`` in lockstep chunks: runs that can share an engine batch
    (:func:`ag_uav.engine.missions.batch_key`), at most ``max_runs`` and about ``budget_bytes`` of
    records and dose maps per chunk (from each mission's length and field), and at least as
    many chunks as ``workers`` when there are enough runs. ``measured``: :func:`measure` of
    ``tasks`` when the caller has it."""
    groups: dict[Any, list[int]] = {}
    nbytes: dict[Any, int] = {}  # per run: the longest mission's engine memory
    for j, (key, n) in enumerate(measure(tasks) if measured is None else measured):
        groups.setdefault(key, []).append(j)
        nbytes[key] = max(nbytes.get(key, 0), n)
    chunks: list[list[int]] = []
    for key, idx in groups.items():
        size = max(1, min(max_runs, budget_bytes // max(nbytes[key], 1),
                          -(-len(idx) // max(workers, 1))))
        chunks += [idx[i:i + size] for i in range(0, len(idx), size)]
    return chunks


def this_process_mb() -> float:
    """This process's resident memory now (MB)."""
    import psutil

    return psutil.Process().memory_info().rss / 2**20


def memory_plan(tasks: list[RunTask], workers: int, memory_mb: float,
                here_mb: float) -> tuple[list[list[int]], float]:
    """(chunks, the process tree's bound in MB) within ``memory_mb``: this process as it is now
    (``here_mb``, :func:`this_process_mb`) and ``workers`` worker processes of
    :data:`WORKER_BASE_MB` each, every worker holding one chunk at a time (``workers = 0``:
    the runs fly in this process, which holds the chunk). A chunk may take what is left over
    the workers (at most :data:`CHUNK_BYTES`). Raises :class:`ConfigError` (one line) when even
    one run per worker does not fit."""
    holders = max(workers, 1)
    base = here_mb + workers * WORKER_BASE_MB
    measured = measure(tasks)
    sizes = [n for _, n in measured]
    largest = max(sizes, default=0)
    per = (memory_mb - base) / holders
    if per * 2**20 < largest:
        raise ConfigError(f"--memory-mb = {memory_mb:.0f}: {workers} workers need about "
                          f"{base + holders * largest / 2**20:.0f} MB (this process "
                          f"{here_mb:.0f} MB, {WORKER_BASE_MB} MB a worker and "
                          f"{largest / 2**20:.0f} MB for the largest run); lower --workers or "
                          "raise --memory-mb")
    chunks = plan_chunks(tasks, holders, budget_bytes=int(min(CHUNK_BYTES, per * 2**20)),
                         measured=measured)
    biggest = max((sum(sizes[j] for j in ch) for ch in chunks), default=0)
    return chunks, base + holders * biggest / 2**20
