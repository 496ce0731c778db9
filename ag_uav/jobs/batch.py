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
ok | crashed | error, ``crash_reason`` and ``engine_fallback``) appended to ``journal.jsonl``
(flushed and fsynced per run). ``results.csv`` is regenerated (atomically) from the journal,
sorted by run index, so it never depends on scheduling; it is written however the batch ends
(Ctrl-C and SIGTERM included). ``--resume`` skips the runs whose *config hash* is already in
the journal (so a spec that grows — more seeds — reuses the finished runs); unreadable journal
lines are skipped with a warning saying how many.

Failures are never silent. A crashed vehicle is a result (status ``crashed``). A run that
raises is a row with status ``error`` and the exception; a chunk whose worker died (after the
executor's bounded retries) is a row per run with status ``error`` and ``worker failure: ...``,
journalled for ``--resume`` to re-run; :meth:`BatchResult.failure_line` sums them up (the CLI
exits non-zero). An executor that is lost (scheduler gone, no worker left) stops the batch with
:class:`BatchStopped`. A lockstep chunk whose engine batch raised is flown one run at a time,
with the exception in each row's ``engine_fallback``, a warning, and a count in the report.

Determinism: a run's row depends only on its config (seed included), never on the worker or the
order; only the timing columns (:func:`is_timing_column`) differ between repeats.
"""

from __future__ import annotations

import contextlib
import copy
import csv
import hashlib
import itertools
import json
import math
import os
import re
import signal
import time
import tomllib
from collections.abc import Callable, Iterable, Iterator, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from ..config import ConfigError, config_from_dict
from ..record.atomic import atomic_open, atomic_write_text, savefig
from .batch_memory import default_memory_mb, memory_plan, this_process_mb
from .executor import Executor, ExecutorLost, SerialExecutor

SPEC_KEYS = ("name", "description", "base", "axes", "presets", "max_runs")
#: most runs a spec may expand to unless it (``max_runs = N``) or ``--max-runs`` says more:
#: every run is validated before anything flies, so a typo'd range is refused, not expanded
MAX_RUNS = 10_000
#: columns that lead results.csv, before the axis columns
LEAD_COLUMNS = ("index", "run_id")
#: summary metrics in display order (any other scalar metric follows, sorted by name)
METRIC_ORDER = ("status", "crash_reason", "engine_fallback", "completed", "crashed",
                "crash_time_s", "mission_time_s",
                "tracking_rmse_m", "estimate_rmse_m", "cross_track_rmse_m", "cross_track_max_m",
                "altitude_rmse_m", "coverage_fraction", "overlap_fraction", "path_length_m",
                "planned_path_length_m", "legs", "legs_flown", "final_position_error_m",
                "field_area_m2", "sim_time_s", "wall_time_s", "loop_wall_time_s",
                "real_time_factor")
#: summary keys that are not row columns (the config is summarised by the axis values)
DROP_KEYS = {"config", "run_dir"}


def is_timing_column(name: str) -> bool:
    """Columns that measure the machine (or how the run was scheduled: ``batch_size``, the size
    of the lockstep chunk it flew in), not the run (excluded from determinism checks)."""
    n = name.lower()
    return ("wall" in n or "real_time_factor" in n or n.endswith(("_per_s", "_us"))
            or "timing" in n or n == "batch_size")


# ------------------------------------------------------------------------------ spec / expand
@dataclass
class Axis:
    name: str                      # a dotted config key, or a preset-axis name
    values: list[Any]
    preset: bool = False


@dataclass
class BatchSpec:
    name: str
    base: dict[str, Any]
    axes: list[Axis]
    presets: dict[str, dict[str, dict[str, Any]]] = field(default_factory=dict)
    description: str = ""
    source: str | None = None      # the spec file, if any

    @property
    def n_runs(self) -> int:
        return math.prod(len(a.values) for a in self.axes) if self.axes else 1


@dataclass
class RunTask:
    index: int
    run_id: str
    axis_values: dict[str, Any]
    config: dict[str, Any]         # the full validated config (Config.to_dict())
    config_hash: str
    logs_dir: str | None = None


def _fmt(v: Any) -> str:
    if isinstance(v, str):
        return f'"{v}"'
    if isinstance(v, dict):
        return "{" + ", ".join(f"{k} = {_fmt(x)}" for k, x in v.items()) + "}"
    if isinstance(v, bool):
        return "true" if v else "false"
    return repr(v)


def deep_merge(a: dict[str, Any], b: dict[str, Any]) -> dict[str, Any]:
    """``a`` updated recursively by ``b`` (new dict; tables merge, everything else replaces)."""
    out = copy.deepcopy(a)
    for k, v in b.items():
        if isinstance(v, dict) and isinstance(out.get(k), dict):
            out[k] = deep_merge(out[k], v)
        else:
            out[k] = copy.deepcopy(v)
    return out


def set_dotted(d: dict[str, Any], key: str, value: Any) -> None:
    """``d["a"]["b"]["c"] = value`` for ``key = "a.b.c"`` (creating tables)."""
    parts = key.split(".")
    node = d
    for p in parts[:-1]:
        nxt = node.get(p)
        if not isinstance(nxt, dict):
            nxt = {}
            node[p] = nxt
        node = nxt
    node[parts[-1]] = copy.deepcopy(value)


def get_dotted(d: dict[str, Any], key: str, default: Any = None) -> Any:
    node: Any = d
    for p in key.split("."):
        if not isinstance(node, dict) or p not in node:
            return default
        node = node[p]
    return node


def _read_toml(path: Path, what: str) -> dict[str, Any]:
    if not path.is_file():
        raise ConfigError(f'{what} = "{path}": no such file')
    try:
        return tomllib.loads(path.read_text())
    except tomllib.TOMLDecodeError as e:
        raise ConfigError(f'{what} = "{path}": not valid TOML ({e})') from None


def resolve_fragment(frag: Any, where: str, base_dir: Path) -> dict[str, Any]:
    """A config fragment (table) → a nested config dict. ``config = "file.toml"`` loads a file
    (relative to ``base_dir``) first; keys with dots are dotted config keys. Field paths are made
    absolute: those of the fragment against ``base_dir``, those of the loaded file against the
    file's folder (:func:`resolve_paths`)."""
    if not isinstance(frag, dict):
        raise ConfigError(f"{where} = {_fmt(frag)}: expected a table (config fragment)")
    out: dict[str, Any] = {}
    if "config" in frag:
        p = frag["config"]
        if not isinstance(p, str):
            raise ConfigError(f"{where}.config = {_fmt(p)}: expected a path to a TOML file")
        path = Path(p) if Path(p).is_absolute() else base_dir / p
        out = resolve_paths(_read_toml(path, f"{where}.config"), path.parent)
    nested: dict[str, Any] = {}
    for k, v in frag.items():
        if k == "config":
            continue
        if "." in k:
            set_dotted(nested, k, v)
        else:
            nested = deep_merge(nested, {k: v})
    return deep_merge(out, resolve_paths(nested, base_dir))


#: config keys that name files (resolved against the folder of the TOML that names them)
PATH_KEYS = ("mission.field",)


def resolve_paths(d: dict[str, Any], base_dir: Path) -> dict[str, Any]:
    """``d`` (a nested config dict, changed in place and returned) with every file path of
    :data:`PATH_KEYS` made absolute against ``base_dir``."""
    for key in PATH_KEYS:
        v = get_dotted(d, key)
        if v is not None:
            set_dotted(d, key, resolve_field(v, base_dir))
    return d


def resolve_field(v: Any, base_dir: Path) -> Any:
    """A field file (any of ``FIELD_FILE_SUFFIXES``, with or without a ``#selector``) relative
    to ``base_dir`` → its absolute path (selector kept). Built-in names stay; anything else is
    left for the config's own one-line check. As in ``load_field``, a file whose name holds a
    ``#`` wins over a selector."""
    from ..world.field import BUILTIN_FIELDS, FIELD_FILE_SUFFIXES

    if not isinstance(v, str) or v.strip().lower().replace("_", "-") in BUILTIN_FIELDS:
        return v
    path, sel = v, None
    if "#" in v and not (base_dir / Path(v).expanduser()).exists():
        path, _, sel = v.partition("#")
    if not path.lower().endswith(FIELD_FILE_SUFFIXES):
        return v
    p = Path(path).expanduser()
    p = Path(os.path.abspath(p if p.is_absolute() else base_dir / p))
    return str(p) + (f"#{sel}" if sel is not None else "")


def _axis_values(name: str, raw: Any, max_runs: int = MAX_RUNS) -> list[Any]:
    where = f"axes.{name}" if "." not in name else f'axes."{name}"'
    if isinstance(raw, dict):
        if set(raw) == {"range"}:
            r = raw["range"]
            if (not isinstance(r, list) or len(r) not in (2, 3)
                    or not all(isinstance(x, int) and not isinstance(x, bool) for x in r)):
                raise ConfigError(f"{where} = {_fmt(raw)}: range needs [start, stop] or "
                                  "[start, stop, step] integers (stop excluded)")
            if len(r) == 3 and r[2] == 0:
                raise ConfigError(f"{where} = {_fmt(raw)}: range step must not be 0")
            _check_count(where, raw, len(range(*r)), max_runs)
            vals = list(range(*r))
        elif set(raw) == {"linspace"}:
            r = raw["linspace"]
            if (not isinstance(r, list) or len(r) != 3 or not isinstance(r[2], int)
                    or isinstance(r[2], bool) or r[2] < 1
                    or not all(isinstance(x, int | float) and not isinstance(x, bool)
                               and math.isfinite(x) for x in r[:2])):
                raise ConfigError(f"{where} = {_fmt(raw)}: linspace needs [start, stop, count] "
                                  "(finite numbers, count >= 1)")
            _check_count(where, raw, r[2], max_runs)
            a, b, n = float(r[0]), float(r[1]), r[2]
            vals = [a + (b - a) * i / (n - 1) if n > 1 else a for i in range(n)]
        else:
            raise ConfigError(f"{where} = {_fmt(raw)}: expected a list of values, "
                              "{range = [start, stop]} or {linspace = [start, stop, count]}")
    elif isinstance(raw, list):
        _check_count(where, "[...]", len(raw), max_runs)
        vals = list(raw)
    else:
        vals = [raw]
    if not vals:
        raise ConfigError(f"{where} = {_fmt(raw)}: expected at least one value")
    return vals


def _check_count(where: str, raw: Any, n: int, max_runs: int) -> None:
    if n > max_runs:
        shown = raw if isinstance(raw, str) else _fmt(raw)
        raise ConfigError(f"{where} = {shown}: {n:,} values, more than the limit of "
                          f"{max_runs:,} runs (raise it with max_runs = N in the spec or "
                          "--max-runs N)")


def _max_runs(data: dict[str, Any], override: int | None) -> int:
    if override is not None:
        if isinstance(override, bool) or not isinstance(override, int) or override < 1:
            raise ConfigError(f"--max-runs = {override}: expected an integer >= 1")
        return override
    v = data.get("max_runs", MAX_RUNS)
    if isinstance(v, bool) or not isinstance(v, int) or v < 1:
        raise ConfigError(f"max_runs = {_fmt(v)}: expected an integer >= 1")
    return v


def spec_from_dict(data: dict[str, Any], *, base_dir: str | Path = ".",
                   name: str | None = None, source: str | None = None,
                   max_runs: int | None = None) -> BatchSpec:
    """Validate a batch spec given as a (TOML-shaped) dict. Raises one-line ConfigError.

    Every file path (``config = ...`` and field files of every format, selectors kept) is
    resolved against ``base_dir`` (the spec's folder), never the working directory. A spec of
    more than ``max_runs`` runs (default: the spec's ``max_runs``, else :data:`MAX_RUNS`) is
    refused before anything is expanded."""
    base_dir = Path(base_dir)
    if not isinstance(data, dict):
        raise ConfigError(f"batch spec = {_fmt(data)}: expected a table")
    for k in data:
        if k not in SPEC_KEYS:
            raise ConfigError(f"{k} = {_fmt(data[k])}: unknown key in a batch spec; allowed: "
                              f"{', '.join(SPEC_KEYS)}")
    nm = data.get("name", name or "batch")
    if not isinstance(nm, str) or not re.fullmatch(r"[A-Za-z0-9_.-]+", nm):
        raise ConfigError(f"name = {_fmt(nm)}: expected letters, digits, '_', '-', '.'")
    base = resolve_fragment(data.get("base", {}), "base", base_dir)
    presets_raw = data.get("presets", {})
    if not isinstance(presets_raw, dict):
        raise ConfigError(f"presets = {_fmt(presets_raw)}: expected tables "
                          "[presets.<axis>.<name>]")
    presets: dict[str, dict[str, dict[str, Any]]] = {"controller": {"default": {}}}
    for axis, table in presets_raw.items():
        if not isinstance(table, dict):
            raise ConfigError(f"presets.{axis} = {_fmt(table)}: expected tables "
                              f"[presets.{axis}.<name>]")
        presets.setdefault(axis, {})
        for pname, frag in table.items():
            presets[axis][pname] = resolve_fragment(frag, f"presets.{axis}.{pname}", base_dir)
    axes_raw = data.get("axes", {})
    if not isinstance(axes_raw, dict):
        raise ConfigError(f"axes = {_fmt(axes_raw)}: expected a table of key = [values]")
    limit = _max_runs(data, max_runs)
    axes: list[Axis] = []
    for key, raw in axes_raw.items():
        vals = _axis_values(key, raw, limit)
        is_preset = key in presets_raw or key == "controller"
        if is_preset:
            for v in vals:
                if not isinstance(v, str) or v not in presets[key]:
                    raise ConfigError(f"axes.{key} = {_fmt(v)}: no preset of that name; "
                                      f"defined: {', '.join(presets[key])}")
        elif key in PATH_KEYS:
            vals = [resolve_field(v, base_dir) for v in vals]
        axes.append(Axis(key, vals, is_preset))
    n = math.prod(len(a.values) for a in axes)
    if n > limit:
        raise ConfigError("axes: " + " × ".join(f"{a.name} {len(a.values)}" for a in axes)
                          + f" = {n:,} runs, more than the limit of {limit:,} (raise it with "
                          "max_runs = N in the spec or --max-runs N)")
    return BatchSpec(name=nm, base=base, axes=axes, presets=presets,
                     description=str(data.get("description", "")), source=source)


def load_spec(path: str | Path, max_runs: int | None = None) -> BatchSpec:
    """Read and validate a batch spec file (paths in it are relative to its folder)."""
    p = Path(path)
    data = _read_toml(p, "batch spec")
    return spec_from_dict(data, base_dir=p.parent, name=data.get("name", p.stem), source=str(p),
                          max_runs=max_runs)


def config_hash(cfg_dict: dict[str, Any]) -> str:
    """Stable hash of a full config dict and of the content of every file it names (what
    makes a run a run): a field file changed in place is a different run. A config that names
    no file hashes as the config alone (journals written before file hashing still resume)."""
    blob = json.dumps(cfg_dict, sort_keys=True, separators=(",", ":"), default=str)
    files = referenced_files(cfg_dict)
    if files:
        blob += json.dumps({str(f): file_digest(f) for f in files}, sort_keys=True)
    return hashlib.sha256(blob.encode()).hexdigest()[:16]


#: the files a shapefile is read with (``.shp`` geometry, ``.shx`` index, ``.dbf`` attributes,
#: ``.prj`` projection, ``.cpg`` code page)
SHAPEFILE_PARTS = (".shp", ".shx", ".dbf", ".prj", ".cpg")


def referenced_files(cfg_dict: dict[str, Any]) -> list[Path]:
    """The existing files a config dict reads (field files; a shapefile with its sidecars)."""
    from ..world.field import split_field_spec

    out: list[Path] = []
    for key in PATH_KEYS:
        v = get_dotted(cfg_dict, key)
        if not isinstance(v, str):
            continue
        p = Path(split_field_spec(v)[0])
        if not p.is_file():
            continue
        out.append(p)
        if p.suffix.lower() == ".shp":
            for ext in SHAPEFILE_PARTS[1:]:
                out += [q for q in (p.with_suffix(ext), p.with_suffix(ext.upper())) if q.is_file()]
    return out


_DIGESTS: dict[tuple[str, int, int], str] = {}


def file_digest(path: Path) -> str:
    """SHA-256 of a file's bytes. Memoised per path, size and modification time, but only for
    a file unchanged for a second or more: file times are coarse, so a file rewritten within
    the same tick at the same size is read again rather than trusted (as git does)."""
    st = path.stat()
    key = (str(path.resolve()), st.st_size, st.st_mtime_ns)
    if key in _DIGESTS:
        return _DIGESTS[key]
    h = hashlib.sha256()
    with path.open("rb") as f:
        for block in iter(lambda: f.read(1 << 20), b""):
            h.update(block)
    if time.time_ns() - st.st_mtime_ns > 1_000_000_000:
        _DIGESTS[key] = h.hexdigest()
    return h.hexdigest()


def expand(spec: BatchSpec) -> list[RunTask]:
    """All runs of the spec, validated (one-line ConfigError naming the failing run)."""
    from ..engine.missions import build_field, build_plan
    from ..world.pattern import mission_headland, mission_swath

    tasks: list[RunTask] = []
    names = [a.name for a in spec.axes]
    width = max(4, len(str(spec.n_runs - 1)))
    plans_ok: set[tuple[Any, ...]] = set()
    for index, combo in enumerate(itertools.product(*[a.values for a in spec.axes])):
        d = copy.deepcopy(spec.base)
        for ax, v in zip(spec.axes, combo, strict=True):
            if ax.preset:
                d = deep_merge(d, spec.presets[ax.name][v])
        for ax, v in zip(spec.axes, combo, strict=True):
            if not ax.preset:
                set_dotted(d, ax.name, v)
        axis_values = dict(zip(names, combo, strict=True))
        try:
            cfg = config_from_dict(d)
            m = cfg.mission
            key = (m.field, mission_swath(cfg), mission_headland(cfg), m.direction_deg)
            if key not in plans_ok:  # the field loads and the coverage plan exists
                build_plan(cfg, build_field(cfg))
                plans_ok.add(key)
        except ConfigError as e:
            where = ", ".join(f"{k}={v}" for k, v in axis_values.items())
            raise ConfigError(f"{e} (run {index}{': ' + where if where else ''})") from None
        cd = cfg.to_dict()
        tasks.append(RunTask(index=index, run_id=f"{index:0{width}d}", axis_values=axis_values,
                             config=cd, config_hash=config_hash(cd)))
    return tasks


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
                out[key] = json.dumps(v, default=_json_default)
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


def _json_default(o: Any) -> Any:
    import numpy as np

    if isinstance(o, np.generic):
        return o.item()
    if isinstance(o, np.ndarray):
        return o.tolist()
    return str(o)


def run_task(task: RunTask) -> dict[str, Any]:
    """Worker entry point: fly one run, return its row. Never raises: an exception inside the run
    becomes a row with ``status = "error"`` and the reason."""
    t0 = time.perf_counter()
    try:
        cfg = config_from_dict(task.config)
        if task.logs_dir:
            from .run import fly

            cfg.log.enabled = True
            cfg.log.channels = "light"
            cfg.log.render = False
            # inline: a batch keeps every core busy already (and a Dask worker's threads
            # make a fork unsafe)
            res, _ = fly(cfg, out_root=task.logs_dir, run_id=task.run_id, log_writer="inline",
                         overwrite=True)  # a re-run (--resume) replaces what it left
        else:
            from ..engine.missions import simulate

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
    from ..engine.missions import simulate_many

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


def _row(task: RunTask, res: Any, t0: float) -> dict[str, Any]:
    row: dict[str, Any] = {"index": task.index, "run_id": task.run_id, **task.axis_values}
    summ = flatten_summary(res.summary)
    for k in task.axis_values:
        summ.pop(k, None)
    status = "crashed" if summ.get("crashed") else "ok"
    row.update({"status": status, "crash_reason": summ.pop("crash_reason", None) or ""})
    row.update(summ)
    row["engine_fallback"] = ""
    return row


def _error_row(task: RunTask, e: BaseException, t0: float) -> dict[str, Any]:
    return {"index": task.index, "run_id": task.run_id, **task.axis_values, "status": "error",
            "crash_reason": exception_line(e), "completed": False,
            "crashed": True, "wall_time_s": round(time.perf_counter() - t0, 3),
            "engine_fallback": ""}


# ------------------------------------------------------------------------------------ journal
class Journal:
    """Append-only JSONL of finished runs, one line per run, flushed and fsynced per line.

    Each line: ``{"hash": config_hash, "retry": bool, "row": {...}}``. A truncated last line
    (the process was killed mid-write) is ignored on reading; any other line that is not a
    journal record (damaged bytes, not UTF-8, not JSON) is skipped and counted in
    :attr:`skipped`, so ``--resume`` re-runs those runs and says how many lines it passed over.
    """

    def __init__(self, path: str | Path) -> None:
        self.path = Path(path)
        self._f = None
        self.skipped = 0

    def read(self) -> dict[str, dict[str, Any]]:
        """config hash → row, for the lines that are final (not marked ``retry``)."""
        done: dict[str, dict[str, Any]] = {}
        self.skipped = 0
        if not self.path.exists():
            return done
        recs, self.skipped = read_jsonl(self.path)
        for rec in recs:
            if not isinstance(rec.get("hash"), str) or not isinstance(rec.get("row"), dict):
                self.skipped += 1
            elif rec.get("retry"):
                done.pop(rec["hash"], None)
            else:
                done[rec["hash"]] = rec["row"]
        return done

    def open(self, fresh: bool = False) -> None:
        self.path.parent.mkdir(parents=True, exist_ok=True)
        if not fresh and self.path.exists():
            self._repair()
        self._f = self.path.open("w" if fresh else "a")

    def _repair(self) -> None:
        """Cut a torn last line so that the next append starts on a line of its own."""
        repair_jsonl(self.path)

    def append(self, h: str, row: dict[str, Any], retry: bool = False) -> None:
        assert self._f is not None, "journal not open"
        try:
            self._f.write(json.dumps({"hash": h, "retry": retry, "row": row},
                                     default=_json_default) + "\n")
            self._f.flush()
            os.fsync(self._f.fileno())
        except OSError as e:  # ENOSPC, EIO, ...: name the journal
            raise OSError(e.errno, e.strerror or str(e), str(self.path)) from None

    def close(self) -> None:
        if self._f is not None:
            try:
                self._f.close()
            except OSError:  # a flush that failed was reported by append
                pass
            self._f = None


def read_jsonl(path: Path) -> tuple[list[dict[str, Any]], int]:
    """The JSON objects of a JSONL file, and how many lines were skipped as unreadable (bytes
    that are not UTF-8 or not a JSON object). A torn last line (no newline) is dropped
    without counting: it is what a kill mid-append leaves."""
    data = path.read_bytes()
    lines = data.split(b"\n")
    if lines and lines[-1] and not data.endswith(b"\n"):
        lines = lines[:-1]
    out: list[dict[str, Any]] = []
    bad = 0
    for raw in lines:
        if not raw.strip():
            continue
        try:
            rec = json.loads(raw.decode("utf-8"))
        except (UnicodeDecodeError, json.JSONDecodeError):
            rec = None
        if isinstance(rec, dict):
            out.append(rec)
        else:
            bad += 1
    return out, bad


def repair_jsonl(path: Path) -> None:
    """Cut a torn last line (no newline) so that the next append starts a line of its own."""
    data = path.read_bytes()
    if data and not data.endswith(b"\n"):
        with path.open("r+b") as f:
            f.truncate(data.rfind(b"\n") + 1)


# ------------------------------------------------------------------------------------ results
def ordered_columns(rows: Sequence[dict[str, Any]], axis_names: Sequence[str]) -> list[str]:
    keys: set[str] = set()
    for r in rows:
        keys.update(r)
    cols = [c for c in LEAD_COLUMNS if c in keys] + [a for a in axis_names if a in keys]
    cols += [c for c in METRIC_ORDER if c in keys and c not in cols]
    cols += sorted(k for k in keys if k not in cols)
    return cols


def _csv_value(v: Any) -> str:
    if v is None:
        return ""
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, float):
        return repr(v)
    return str(v)


@contextlib.contextmanager
def _signals_held() -> Iterator[None]:
    """SIGTERM and SIGINT held back (delivered right after): a run's journal line and its row
    in memory, from which an interrupted batch writes ``results.csv``, are recorded together."""
    sigs = {signal.SIGTERM, signal.SIGINT}
    try:
        old = signal.pthread_sigmask(signal.SIG_BLOCK, sigs)
    except (AttributeError, ValueError, OSError):  # pragma: no cover - not POSIX
        yield
        return
    try:
        yield
    finally:
        signal.pthread_sigmask(signal.SIG_SETMASK, old)


def write_results_csv(rows: Sequence[dict[str, Any]], path: str | Path,
                      axis_names: Sequence[str] = ()) -> list[str]:
    """Write rows sorted by run index (atomic replace); returns the columns."""
    rows = sorted(rows, key=lambda r: r.get("index", 0))
    cols = ordered_columns(rows, axis_names)

    def write(f: Any) -> None:
        w = csv.writer(f)
        w.writerow(cols)
        for r in rows:
            w.writerow([_csv_value(r.get(c)) for c in cols])

    with atomic_open(path, "w", newline="") as f:
        write(f)
    return cols


def read_results_csv(path: str | Path) -> list[dict[str, str]]:
    with Path(path).open(newline="") as f:
        return list(csv.DictReader(f))


# ------------------------------------------------------------------------------------- stats
def mean_ci(values: Iterable[Any], level: float = 0.95) -> tuple[float, float, int]:
    """Mean and the half-width of its Student-t confidence interval over the finite values."""
    xs = [float(v) for v in values if v is not None and v != "" and math.isfinite(float(v))]
    n = len(xs)
    if n == 0:
        return math.nan, math.nan, 0
    m = sum(xs) / n
    if n == 1:
        return m, math.nan, 1
    from scipy import stats

    s = math.sqrt(sum((x - m) ** 2 for x in xs) / (n - 1))
    return m, float(stats.t.ppf(0.5 + level / 2, n - 1)) * s / math.sqrt(n), n


def group_rows(rows: Sequence[dict[str, Any]], keys: Sequence[str]
               ) -> dict[tuple[Any, ...], list[dict[str, Any]]]:
    out: dict[tuple[Any, ...], list[dict[str, Any]]] = {}
    for r in rows:
        out.setdefault(tuple(r.get(k) for k in keys), []).append(r)
    return out


#: (column, label, scale, format) of the summary table
SUMMARY_METRICS = (
    ("mission_time_s", "mission time (s)", 1.0, "{:.1f}"),
    ("tracking_rmse_m", "tracking RMSE (m)", 1.0, "{:.3f}"),
    ("estimate_rmse_m", "estimate RMSE (m)", 1.0, "{:.3f}"),
    ("cross_track_rmse_m", "cross-track RMSE (m)", 1.0, "{:.3f}"),
    ("coverage_fraction", "coverage (%)", 100.0, "{:.2f}"),
)


def summary_rows(rows: Sequence[dict[str, Any]], group_keys: Sequence[str]
                 ) -> tuple[list[str], list[list[str]]]:
    """The batch summary table: per group, runs, ok/crashed/error and mean ± 95 % CI."""
    metrics = [m for m in SUMMARY_METRICS if any(r.get(m[0]) not in (None, "") for r in rows)]
    header = list(group_keys) + ["runs", "ok", "crashed", "error"] + [m[1] for m in metrics]
    table = []
    for key, rs in sorted(group_rows(rows, group_keys).items(), key=lambda kv: _natural(kv[0])):
        line = [str(k) for k in key]
        line += [str(len(rs)), str(sum(r.get("status") == "ok" for r in rs)),
                 str(sum(r.get("status") == "crashed" for r in rs)),
                 str(sum(r.get("status") == "error" for r in rs))]
        for col, _, scale, fmt in metrics:
            m, h, n = mean_ci(r.get(col) for r in rs if r.get("status") == "ok")
            if n == 0:
                line.append("–")
            elif math.isnan(h):
                line.append(fmt.format(m * scale))
            else:
                line.append(f"{fmt.format(m * scale)} ± {fmt.format(h * scale)}")
        table.append(line)
    return header, table


def _natural(key: tuple[Any, ...]) -> tuple[tuple[int, float, str], ...]:
    """Sort key: numbers numerically, then strings."""
    out = []
    for k in key:
        x = _num(k)
        out.append((0, x, "") if x is not None else (1, 0.0, str(k)))
    return tuple(out)


def print_table(header: Sequence[str], table: Sequence[Sequence[str]], title: str) -> None:
    from rich.console import Console
    from rich.table import Table

    t = Table(title=title, header_style="bold")
    for i, h in enumerate(header):
        t.add_column(h, justify="left" if i == 0 else "right")
    for line in table:
        t.add_row(*line)
    import sys

    Console(width=None if sys.stdout.isatty() else 160).print(t)


def markdown_table(header: Sequence[str], table: Sequence[Sequence[str]]) -> str:
    lines = ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
    lines += ["| " + " | ".join(line) + " |" for line in table]
    return "\n".join(lines) + "\n"


# ------------------------------------------------------------------------------------- report
def _num(v: Any) -> float | None:
    try:
        x = float(v)
    except (TypeError, ValueError):
        return None
    return x if math.isfinite(x) else None


def _saved(fig: Any, path: Path, plt: Any) -> Path:
    """Lay out, write (110 dpi) and close a report figure; its path."""
    fig.tight_layout()
    savefig(fig, path, dpi=110)
    plt.close(fig)
    return path


def _rmse_figure(ok: list[dict[str, Any]], noise_key: str | None, label: Callable[[dict], str],
                 out: Path, plt: Any) -> Path | None:
    """``rmse.png``: RMSE distributions per group, one column per noise case (None: no data)."""
    metrics = [m for m in ("tracking_rmse_m", "estimate_rmse_m")
               if any(_num(r.get(m)) is not None for r in ok)]
    cases = sorted({str(r.get(noise_key)) for r in ok}) if noise_key else ["all"]
    if not (metrics and ok):
        return None
    fig, axs = plt.subplots(len(metrics), len(cases), squeeze=False,
                            figsize=(max(5.0, 4.2 * len(cases)), 3.4 * len(metrics)))
    for j, case in enumerate(cases):
        sel = [r for r in ok if not noise_key or str(r.get(noise_key)) == case]
        labels = sorted({label(r) for r in sel})
        for i, m in enumerate(metrics):
            data = [[_num(r.get(m)) for r in sel if label(r) == lb
                     and _num(r.get(m)) is not None] for lb in labels]
            ax = axs[i][j]
            if any(data):
                ax.boxplot([d or [math.nan] for d in data], showmeans=True)
                ax.set_xticks(range(1, len(labels) + 1), labels, rotation=20, fontsize=8)
            ax.set_ylabel(m.replace("_m", " (m)").replace("_", " "))
            ax.set_title(f"{noise_key} = {case}" if noise_key else "RMSE distribution",
                         fontsize=9)
            ax.grid(alpha=0.3)
    return _saved(fig, out / "rmse.png", plt)


def _tracking_figure(ok: list[dict[str, Any]], label: Callable[[dict], str], out: Path,
                     plt: Any) -> Path | None:
    """``tracking_vs_estimate.png``: tracking against estimate error per run (None: no data)."""
    pairs = [(r, _num(r.get("estimate_rmse_m")), _num(r.get("tracking_rmse_m"))) for r in ok]
    pairs = [(r, e, t) for r, e, t in pairs if e is not None and t is not None]
    if not pairs:
        return None
    fig, ax = plt.subplots(figsize=(5.5, 4.2))
    for lb in sorted({label(r) for r, _, _ in pairs}):
        xs = [e for r, e, _ in pairs if label(r) == lb]
        ys = [t for r, _, t in pairs if label(r) == lb]
        ax.scatter(xs, ys, s=12, label=lb, alpha=0.7)
    lim = max(max(e for _, e, _ in pairs), max(t for _, _, t in pairs)) * 1.05
    ax.plot([0, lim], [0, lim], "k--", lw=0.8, label="y = x")
    ax.set_xlabel("estimate RMSE (m)")
    ax.set_ylabel("tracking RMSE (m)")
    ax.legend(fontsize=7)
    ax.grid(alpha=0.3)
    return _saved(fig, out / "tracking_vs_estimate.png", plt)


def _coverage_figure(ok: list[dict[str, Any]], label: Callable[[dict], str], out: Path,
                     plt: Any) -> Path | None:
    """``coverage.png``: spray coverage per group (None: no data)."""
    cov = [(label(r), _num(r.get("coverage_fraction"))) for r in ok]
    cov = [(lb, c) for lb, c in cov if c is not None]
    if not cov:
        return None
    labels = sorted({lb for lb, _ in cov})
    fig, ax = plt.subplots(figsize=(max(5.0, 1.1 * len(labels) + 2), 3.6))
    ax.boxplot([[100 * c for lb2, c in cov if lb2 == lb] for lb in labels], showmeans=True)
    ax.set_xticks(range(1, len(labels) + 1), labels, rotation=20, fontsize=8)
    ax.set_ylabel("spray coverage (%)")
    ax.grid(alpha=0.3)
    return _saved(fig, out / "coverage.png", plt)


def _report_markdown(rows: Sequence[dict[str, Any]], spec: BatchSpec, group_keys: list[str],
                     info: dict[str, Any], figures: list[Path]) -> str:
    """The text of ``report.md``: counts, axes, the summary table, failed runs, the figures."""
    header, table = summary_rows(rows, group_keys)
    md = [f"# Batch `{spec.name}`", ""]
    if spec.description:
        md += [spec.description, ""]
    md += [f"- runs: {len(rows)} ({sum(r.get('status') == 'ok' for r in rows)} ok, "
           f"{sum(r.get('status') == 'crashed' for r in rows)} crashed, "
           f"{sum(r.get('status') == 'error' for r in rows)} error)"]
    n_fb = sum(bool(r.get("engine_fallback")) for r in rows)
    md += [f"- engine fallbacks: {n_fb} runs flown one at a time after their engine batch "
           "failed (column `engine_fallback`)" if n_fb else "- engine fallbacks: 0"]
    md += ["- axes: " + "; ".join(f"`{a.name}` × {len(a.values)}" for a in spec.axes)]
    for k, v in info.items():
        md.append(f"- {k}: {v}")
    md += ["", "Mean ± 95 % confidence half-width (Student t) over the runs with status ok.", "",
           markdown_table(header, table)]
    bad = [r for r in rows if r.get("status") != "ok"]
    if bad:
        md += ["## Crashed / failed runs", "",
               markdown_table(["index", "status", "reason"],
                              [[str(r.get("index")), str(r.get("status")),
                                str(r.get("crash_reason"))] for r in bad[:50]])]
        if len(bad) > 50:
            md.append(f"... and {len(bad) - 50} more (see results.csv)\n")
    for p in figures:
        md += [f"![{p.stem}]({p.name})", ""]
    return "\n".join(md)


def write_report(rows: Sequence[dict[str, Any]], spec: BatchSpec, out_dir: str | Path,
                 info: dict[str, Any] | None = None) -> list[Path]:
    """``report.md`` and PNG figures: RMSE distributions per estimator and noise case, tracking
    vs estimate error, coverage. Returns the files written."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    out = Path(out_dir)
    group_keys = [a.name for a in spec.axes if a.name != "seed" and len(a.values) > 1]
    noise_key = "gps.preset" if "gps.preset" in group_keys else None
    box_keys = [k for k in group_keys if k != noise_key]
    ok = [r for r in rows if r.get("status") == "ok"]

    def label(r: dict[str, Any]) -> str:
        return " / ".join(str(r.get(k)) for k in box_keys) or "all"

    figures = [_rmse_figure(ok, noise_key, label, out, plt), _tracking_figure(ok, label, out, plt),
               _coverage_figure(ok, label, out, plt)]
    written = [p for p in figures if p is not None]
    rp = out / "report.md"
    atomic_write_text(rp, _report_markdown(rows, spec, group_keys, info or {}, written))
    written.insert(0, rp)
    return written


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


#: ``crash_reason`` of a row whose run was lost to the machinery (journalled as a retry)
LOST_PREFIX = "worker failure: "


def run_batch(spec: BatchSpec, out_dir: str | Path, executor: Executor | None = None, *,
              resume: bool = False, fresh: bool = False, logs: bool = False,
              progress: bool = True, report: bool = True,
              tasks: list[RunTask] | None = None,
              on_row: Callable[[dict[str, Any]], None] | None = None,
              warn: Callable[[str], None] | None = None) -> BatchResult:
    """Run every task of ``spec`` on ``executor`` (default: serial) into ``out_dir``.

    The executor's ``memory_mb`` bounds the process tree (this process and the workers;
    ``None``: :func:`~ag_uav.jobs.batch_memory.default_memory_mb`): the runs are chunked to fit
    it (:func:`~ag_uav.jobs.batch_memory.memory_plan`), and a worker count that cannot fit is
    refused before anything runs.

    ``resume``: skip runs already in ``out_dir/journal.jsonl``; ``fresh``: discard an existing
    journal. With neither, an existing journal is an error (nothing is overwritten silently).
    ``out_dir`` belongs to this batch while it runs (:func:`ag_uav.jobs.outdir.hold`: a second
    batch on it raises :class:`~ag_uav.jobs.outdir.FolderInUse`).
    ``results.csv`` is written however the call ends (an interrupt or SIGTERM included). When
    the executor is lost (:class:`~ag_uav.jobs.executor.ExecutorLost`), raises
    :class:`BatchStopped` after writing it. Warnings (unreadable journal lines, engine batches
    that fell back to one run at a time) go to ``warn`` (default: one line on stderr).
    """
    from .outdir import hold

    with hold(out_dir, "batch", "wait for it to finish, or choose another --out"):
        return _run_batch(spec, Path(out_dir), executor, resume=resume, fresh=fresh, logs=logs,
                          progress=progress, report=report, tasks=tasks, on_row=on_row,
                          warn=warn)


def _run_batch(spec: BatchSpec, out: Path, executor: Executor | None, *, resume: bool,
               fresh: bool, logs: bool, progress: bool, report: bool,
               tasks: list[RunTask] | None, on_row: Callable[[dict[str, Any]], None] | None,
               warn: Callable[[str], None] | None) -> BatchResult:
    tasks = tasks if tasks is not None else expand(spec)
    executor = executor or SerialExecutor()
    workers = 0 if isinstance(executor, SerialExecutor) else executor.workers
    mem = executor.memory_mb or default_memory_mb()
    journal = Journal(out / "journal.jsonl")
    if journal.path.exists() and not (resume or fresh):
        raise ConfigError(f'--out = "{out}": already holds a batch journal; use --resume to '
                          "continue it or --fresh to start over")
    out.mkdir(parents=True, exist_ok=True)
    done = journal.read() if resume else {}
    if logs:
        for t in tasks:
            t.logs_dir = str(out / "runs")
    todo = [t for t in tasks if t.config_hash not in done]
    rows_by_index = {t.index: _rebase_row(done[t.config_hash], t) for t in tasks
                     if t.config_hash in done}
    atomic_write_text(out / "batch.json", json.dumps({
        "name": spec.name, "source": spec.source, "n_runs": len(tasks),
        "axes": {a.name: a.values for a in spec.axes}, "base": spec.base,
        "presets": spec.presets}, indent=2, default=_json_default))
    chunks, bound = memory_plan(todo, workers, mem, this_process_mb()) if todo else ([], 0.0)
    run = _BatchRun(spec.name, len(tasks), len(tasks) - len(todo), progress, warn, on_row)
    if journal.skipped:
        run.warn(f"{journal.path}: skipped {journal.skipped} unreadable line(s); their runs "
                 "are run again")
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
    if report:
        res.files += write_report(rows, spec, out, info={
            "executor": executor.name, "wall time (this call)": f"{wall:.1f} s",
            "runs executed / resumed": f"{res.n_run} / {res.n_skipped}",
            "runs lost to the machinery (this call)": res.n_lost,
            "memory bound of the process tree": f"{bound:.0f} MB of {mem:.0f} MB"})
    return res


class _BatchRun:
    """The bookkeeping of one :func:`run_batch` call: journal rows, progress bar, warnings."""

    def __init__(self, name: str, n: int, n_done: int, progress: bool,
                 warn: Callable[[str], None] | None,
                 on_row: Callable[[dict[str, Any]], None] | None) -> None:
        self.bar = None
        if progress:
            from .._progress import progress_bar

            self.bar = progress_bar(total=n, initial=n_done, unit="run", desc=f"batch {name}",
                                    dynamic_ncols=True, smoothing=0.05)
        self._warn, self.on_row = warn, on_row
        self.n_bad = self.n_lost = 0

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
                   "engine_fallback": ""} for t in tasks]
            self.n_lost += len(tasks)
            self.warn(f"runs {tasks[0].run_id}..{tasks[-1].run_id}: {reason}")
            retry = True
        else:
            retry = False
            fb = next((r.get("engine_fallback") for r in rs if r.get("engine_fallback")), "")
            if fb:
                self.warn(f"runs {tasks[0].run_id}..{tasks[-1].run_id}: the engine batch failed "
                          f"({fb}); flown one at a time (column engine_fallback)")
        for task, r in zip(tasks, rs, strict=True):
            with _signals_held():  # the journal and the rows agree, whenever SIGTERM comes
                journal.append(task.config_hash, r, retry=retry)
                rows_by_index[task.index] = r
            self.n_bad += r.get("status") != "ok"
            if self.on_row is not None:
                self.on_row(r)
            if self.bar is not None:
                self.bar.update(1)
                if self.n_bad:
                    self.bar.set_postfix(failed=self.n_bad, refresh=False)

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
    return r


# ------------------------------------------------------------------------- geometry helper
def write_rect_field(path: str | Path, width_m: float, height_m: float,
                     lat0: float = 46.7300, lon0: float = -117.0000, name: str = "rect") -> Path:
    """Write a ``width_m × height_m`` rectangular field (east × north) as a GeoJSON polygon about
    (lat0, lon0): short missions for tests, benchmarks and quick experiments."""
    from ..world.field import enu_to_lonlat

    e = [0.0, width_m, width_m, 0.0, 0.0]
    n = [0.0, 0.0, height_m, height_m, 0.0]
    lon, lat = enu_to_lonlat(e, n, (lat0, lon0, 0.0))
    ring = [[round(float(a), 10), round(float(b), 10)] for a, b in zip(lon, lat, strict=True)]
    gj = {"type": "Feature", "properties": {"name": name},
          "geometry": {"type": "Polygon", "coordinates": [ring]}}
    p = Path(path)
    p.parent.mkdir(parents=True, exist_ok=True)
    p.write_text(json.dumps(gj))
    return p


__all__ = ["Axis", "BatchSpec", "RunTask", "BatchResult", "load_spec", "spec_from_dict", "expand",
           "run_task", "run_batch", "Journal", "BatchStopped", "MAX_RUNS", "write_results_csv",
           "read_results_csv", "resolve_field", "resolve_paths", "referenced_files",
           "write_report", "summary_rows", "mean_ci", "write_rect_field",
           "is_timing_column", "config_hash", "deep_merge", "set_dotted", "get_dotted"]
