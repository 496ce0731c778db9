"""The worker's side of a batch: fly one run (:func:`run_task`) or a lockstep chunk
(:func:`run_chunk`) and turn each result into a row (never raising: a failing run is a row)."""

from __future__ import annotations

import json
import math
import time
from typing import Any

from ...config import config_from_dict
from ..provenance import row_provenance
from .journal import json_default
from .spec import RunTask

#: summary keys that are not row columns (the config is summarised by the axis values)
DROP_KEYS = {"config", "run_dir"}


# ------------------------------------------------------------------------------------- worker
def flatten_summary(summary: dict[str, Any]) -> dict[str, Any]:
    """Scalar columns of a run summary: nested tables become ``a.b`` keys, lists JSON."""
    out: dict[str, Any] = {}

    def walk(d: dict[str, Any], prefix: str) -> None:
        for k, v in d.items():
            if not prefix and k in DROP_KEYS:
                continue
            key = f"{prefix}{k}"
            if isinstance(v, dict):
                walk(v, key + ".")
            elif isinstance(v, list | tuple):
                out[key] = json.dumps(v, default=json_default)
            else:
                out[key] = _scalar(v)

    walk(summary, "")
    return out


def _scalar(v: Any) -> Any:
    try:
        import numpy as np

        if isinstance(v, np.generic):
            v = v.item()
    except ImportError:  # pragma: no cover
        pass
    if isinstance(v, float) and not math.isfinite(v):
        return None if math.isnan(v) else v
    return v


def run_task(task: RunTask) -> dict[str, Any]:
    """Worker entry point: fly one run, return its row. Never raises: an exception inside the run
    becomes a row with ``status = "error"`` and the reason."""
    t0 = time.perf_counter()
    try:
        cfg = config_from_dict(task.config)
        if task.logs_dir:
            from ..run import fly

            cfg.log.enabled = True
            cfg.log.channels = "light"
            cfg.log.render = False
            # inline: a batch keeps every core busy already (and a Dask worker's threads
            # make a fork unsafe)
            res, _ = fly(cfg, out_root=task.logs_dir, run_id=task.run_id, log_writer="inline",
                         overwrite=True, helper=False)  # a re-run (--resume) replaces it
        else:
            from ...engine.missions import simulate

            cfg.log.enabled = False
            res = simulate(cfg)
        return _row(task, res, t0)
    except Exception as e:  # noqa: BLE001 - a failing run is a row, the batch goes on
        return _error_row(task, e, t0)


def run_chunk(tasks: list[RunTask]) -> list[dict[str, Any]]:
    """Worker entry point: fly a chunk of runs as one lockstep engine batch
    (:func:`ag_uav.engine.missions.simulate_many`) and return their rows, in order. Never raises: a
    run that cannot be set up is an error row; if the batch itself fails, the chunk falls back to
    one run at a time so the failing run is isolated and the others still fly. The fallback is
    not silent: every row of the chunk carries the batch's exception in ``engine_fallback``
    (empty when the chunk flew as one batch), and :func:`run_batch` warns and counts it."""
    if len(tasks) == 1 or any(t.logs_dir for t in tasks):
        return [run_task(t) for t in tasks]
    from ...engine.missions import simulate_many

    t0 = time.perf_counter()
    rows: list[dict[str, Any] | None] = [None] * len(tasks)
    cfgs, where = [], []
    for j, task in enumerate(tasks):
        try:
            cfg = config_from_dict(task.config)
            cfg.log.enabled = False
            cfgs.append(cfg)
            where.append(j)
        except Exception as e:  # noqa: BLE001
            rows[j] = _error_row(task, e, t0)
    try:
        results = simulate_many(cfgs, errors="return",
                                reduce=lambda k, res: _row(tasks[where[k]], res, t0)
                                ) if cfgs else []
    except Exception as e:  # noqa: BLE001 - isolate the failing run, and say so
        reason = exception_line(e)
        return [{**run_task(t), "engine_fallback": reason} for t in tasks]
    for j, res in zip(where, results, strict=True):
        rows[j] = _error_row(tasks[j], res, t0) if isinstance(res, BaseException) else res
    return rows  # type: ignore[return-value]


def exception_line(e: BaseException) -> str:
    """``Type: first line of the message`` (at most 300 characters)."""
    msg = str(e).splitlines()[0] if str(e) else ""
    return f"{type(e).__name__}: {msg}"[:300]


#: a row's ``status``: ``ok`` only for a mission flown to its end; the others say why not
STATUSES = ("ok", "failsafe", "cut", "incomplete", "crashed", "error")
#: the statuses of a run that ended early without crashing (not ok, not in the report's means)
EARLY_STATUSES = ("failsafe", "cut", "incomplete")


def run_status(summary: dict[str, Any]) -> str:
    """The ``status`` of a flown run from its (flattened) summary: ``crashed``; ``ok`` when the
    mission was completed; else why it ended early: ``failsafe`` (the GNSS failsafe landed or
    held it), ``cut`` (``sim.max_time_s`` cut the plan) or ``incomplete`` (any other reason: no
    take-off, the pre-flight check, legs not flown, ended off the plan's end; the reason is in
    ``incomplete_reason``)."""
    if summary.get("crashed"):
        return "crashed"
    if summary.get("completed"):
        return "ok"
    if summary.get("failsafe"):
        return "failsafe"
    if str(summary.get("incomplete_reason") or "").startswith("cut by sim.max_time_s"):
        return "cut"
    return "incomplete"


def row_reason(row: dict[str, Any]) -> str:
    """Why a row is not ok, in one line: its crash or error reason, else its
    ``incomplete_reason`` ("" for an ok row)."""
    return str(row.get("crash_reason") or row.get("incomplete_reason") or "")


def _row(task: RunTask, res: Any, t0: float) -> dict[str, Any]:
    row: dict[str, Any] = {"index": task.index, "run_id": task.run_id, **task.axis_values}
    summ = flatten_summary(res.summary)
    for k in task.axis_values:
        summ.pop(k, None)
    status = run_status(summ)
    row.update({"status": status, "crash_reason": summ.pop("crash_reason", None) or ""})
    row.update(summ)
    row["engine_fallback"] = ""
    row.update(row_provenance())
    return row


def _error_row(task: RunTask, e: BaseException, t0: float) -> dict[str, Any]:
    return {"index": task.index, "run_id": task.run_id, **task.axis_values, "status": "error",
            "crash_reason": exception_line(e), "completed": False,
            "crashed": True, "wall_time_s": round(time.perf_counter() - t0, 3),
            "engine_fallback": "", **row_provenance()}
