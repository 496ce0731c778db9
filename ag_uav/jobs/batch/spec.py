"""A batch spec: reading and validating it (fragments, presets, paths resolved against
the spec's folder), the config hash of a run (the content of every file it reads included),
and its expansion into :class:`RunTask` s (:mod:`ag_uav.jobs.batch`)."""

from __future__ import annotations

import copy
import hashlib
import itertools
import json
import math
import os
import re
import time
import tomllib
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from ...config import ConfigError, config_from_dict

SPEC_KEYS = ("name", "description", "base", "axes", "presets", "max_runs")
#: most runs a spec may expand to unless it (``max_runs = N``) or ``--max-runs`` says more:
#: every run is validated before anything flies, so a typo'd range is refused, not expanded
MAX_RUNS = 10_000

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
    from ...world.field import BUILTIN_FIELDS, FIELD_FILE_SUFFIXES

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
    from ...world.field import split_field_spec

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
    from ...engine.missions import build_field, build_plan
    from ...world.pattern import mission_direction, mission_headland, mission_swath

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
            key = (m.field, mission_swath(cfg), mission_headland(cfg), mission_direction(cfg))
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
