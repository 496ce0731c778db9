"""Headless batches: a base config times a product of axes, run on an :mod:`~ag_uav.jobs.executor`.

Spec (TOML; ``ag-uav batch SPEC.toml``, see ``examples/batch.toml``)::

    name = "wind-sweep"                 # optional; default: the file's stem
    [base]                              # the base config: a config table, optionally on top of
    config = "base.toml"                #   a config file (path relative to the spec)
    wind.turbulence = "light"
    [axes]                              # the product of these, in this order (last fastest)
    "wind.speed_mps" = [0, 3, 6]        # a dotted config key and its values
    seed = {range = [0, 20]}            # {range = [start, stop(, step)]}: integers, stop excluded
    controller = ["default", "soft"]    # a preset axis: names of config fragments below
    [presets.controller.soft]           # a fragment: config tables and/or dotted keys and/or
    "controller.xy.k0" = 2.0            #   config = "fragment.toml" (e.g. `ag-uav tune` output)
    max_runs = 20000                    # optional: the most runs the spec may expand to
                                        #   (default MAX_RUNS; a bigger product is refused)

Paths mean one thing: every file a spec names (``config = ...`` and ``mission.field`` files of
every format, ``PATH#selector`` included) is resolved against the spec's folder (a path inside a
loaded config file: against that file's folder), never the working directory. The config hash
includes the content of every file a run reads (a shapefile with its sidecars), so a field file
changed in place is a different run for ``--resume``.

An axis is a *preset axis* when ``[presets.<axis>]`` exists (``controller`` always is; its
preset ``default`` is the empty fragment). Every run's config is ``base ⊕ presets ⊕ axis keys``,
validated with the usual one-line :class:`~ag_uav.config.ConfigError` before anything runs.

Each finished run becomes one row (every scalar summary metric, the axis values, ``status`` =
ok | failsafe | cut | incomplete | crashed | error, ``crash_reason``, ``incomplete_reason`` and
``engine_fallback``; :func:`~ag_uav.jobs.batch.worker.run_status`: only a mission flown to its
end is ok, and the report's means cover the ok runs only, saying how many) appended to
``journal.jsonl`` (flushed and fsynced per run). ``results.csv`` is regenerated (atomically)
from the journal, sorted by run index, so it never depends on scheduling; it is written
however the batch ends (Ctrl-C and SIGTERM included). ``--resume`` skips the runs whose
*config hash* is already in the journal (so a spec that grows — more seeds — reuses the
finished runs); unreadable journal lines are skipped with a warning saying how many.

Failures are never silent. A crashed vehicle is a result (status ``crashed``). A run that
raises is a row with status ``error`` and the exception; a chunk whose worker died (after the
executor's bounded retries) is a row per run with status ``error`` and ``worker failure: ...``,
journalled for ``--resume`` to re-run; :meth:`BatchResult.failure_line` sums them up (the CLI
exits non-zero). An executor that is lost (scheduler gone, no worker left) stops the batch with
:class:`BatchStopped`. A lockstep chunk whose engine batch raised is flown one run at a time,
with the exception in each row's ``engine_fallback``, a warning, and a count in the report.

Determinism: a run's row depends only on its config (seed included), never on the worker or the
order; only the timing columns (:func:`is_timing_column`) differ between repeats.

The package, one idea a module: :mod:`~ag_uav.jobs.batch.spec` (reading, validating and
expanding a spec), :mod:`~ag_uav.jobs.batch.worker` (flying a run or a chunk into rows),
:mod:`~ag_uav.jobs.batch.journal` (the journal ``--resume`` reads),
:mod:`~ag_uav.jobs.batch.report` (``results.csv``, the summary table, ``report.md``) and
:mod:`~ag_uav.jobs.batch.run` (:func:`run_batch`). Everything public is importable from
``ag_uav.jobs.batch``.
"""

from ...world.field import write_rect_field
from .journal import Journal, json_default, read_jsonl, repair_jsonl, signals_held
from .report import (
    LEAD_COLUMNS,
    METRIC_ORDER,
    SUMMARY_METRICS,
    as_number,
    group_rows,
    is_timing_column,
    markdown_table,
    mean_ci,
    ordered_columns,
    print_table,
    read_results_csv,
    status_counts,
    summary_rows,
    write_report,
    write_results_csv,
)
from .run import LOST_PREFIX, BatchOptions, BatchResult, BatchStopped, run_batch
from .spec import (
    MAX_RUNS,
    PATH_KEYS,
    SHAPEFILE_PARTS,
    SPEC_KEYS,
    Axis,
    BatchSpec,
    RunTask,
    config_hash,
    deep_merge,
    expand,
    file_digest,
    get_dotted,
    load_spec,
    referenced_files,
    resolve_field,
    resolve_fragment,
    resolve_paths,
    set_dotted,
    spec_from_dict,
)
from .worker import (
    DROP_KEYS,
    EARLY_STATUSES,
    STATUSES,
    exception_line,
    flatten_summary,
    row_reason,
    run_chunk,
    run_status,
    run_task,
)

__all__ = ["Axis", "BatchSpec", "RunTask", "BatchResult", "BatchOptions", "load_spec",
           "spec_from_dict", "expand", "run_task", "run_chunk", "run_batch", "Journal",
           "BatchStopped", "MAX_RUNS", "write_results_csv", "read_results_csv", "resolve_field",
           "resolve_paths", "resolve_fragment", "referenced_files", "file_digest", "write_report",
           "summary_rows", "mean_ci", "write_rect_field", "is_timing_column", "config_hash",
           "deep_merge", "set_dotted", "get_dotted", "as_number", "exception_line",
           "flatten_summary", "group_rows", "markdown_table", "print_table", "ordered_columns",
           "read_jsonl", "repair_jsonl", "json_default", "signals_held", "LEAD_COLUMNS",
           "METRIC_ORDER", "SUMMARY_METRICS", "DROP_KEYS", "LOST_PREFIX", "PATH_KEYS",
           "SHAPEFILE_PARTS", "SPEC_KEYS", "STATUSES", "EARLY_STATUSES", "run_status",
           "row_reason", "status_counts"]
