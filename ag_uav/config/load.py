"""Reading and checking a run config: strict TOML loading, ``--set`` overrides, one-line
errors, and the default config printed with a comment per key."""


from __future__ import annotations

import dataclasses
import math
import tomllib
import types
import typing
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import tomli_w

from .schema import (
    FLOAT_LIMIT,
    INT_MAX,
    INT_MIN,
    Config,
    ConfigError,
    GpsConfig,
    MissionConfig,
    SprayConfig,
    VehicleConfig,
)

__all__ = ["config_from_dict", "parse_set_items", "load_config", "default_config",
           "config_toml_with_comments", "toml_repr"]


# ------------------------------------------------------------------------------------ parsing
def _type_name(tp: Any, choices: tuple | None = None) -> str:
    origin = typing.get_origin(tp)
    if origin in (typing.Union, types.UnionType):
        return " or ".join(_type_name(a, choices) for a in typing.get_args(tp))
    if origin is list:
        inner = typing.get_args(tp)[0]
        return "a list of " + {float: "numbers", int: "integers", str: "strings"}.get(
            inner, _type_name(inner))
    if tp is str and choices:
        return " or ".join(_fmt(c) for c in choices)
    return {float: "a number", int: "an integer", str: "a string",
            bool: "true or false"}.get(tp, str(tp))


def toml_repr(v: Any) -> str:
    """``v`` as TOML would write it (strings quoted and escaped, tables inline, cut at 120
    characters), for the one-line messages of a bad value."""
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, int | float):
        s = repr(v)
    else:
        try:
            s = _toml_value(v)
        except Exception:  # not TOML-shaped (a Python API caller's object): its repr
            s = repr(v)
    return s if len(s) <= 120 else s[:117] + "..."


_fmt = toml_repr  # the messages' short name


def _is_kind(tp: Any, v: Any) -> bool:
    """Whether ``v`` has the TOML kind of type ``tp`` (so ``tp``'s own message fits it best)."""
    if tp is float:
        return isinstance(v, int | float) and not isinstance(v, bool)
    if tp is int:
        return isinstance(v, int) and not isinstance(v, bool)
    if typing.get_origin(tp) is list:
        return isinstance(v, list)
    if tp is dict or typing.get_origin(tp) is dict:
        return isinstance(v, dict)
    return isinstance(v, tp)


def _check_int64(v: int, key: str) -> None:
    if not INT_MIN <= v <= INT_MAX:
        raise ConfigError(f"{key} = {_fmt(v)}: outside the 64-bit integer range of TOML "
                          "(-2^63 .. 2^63-1)")


def _coerce(tp: Any, v: Any, key: str, choices: tuple | None = None) -> Any:
    """``v`` as type ``tp`` (an int is a valid float, nothing else converts), or ConfigError."""
    origin = typing.get_origin(tp)
    if origin in (typing.Union, types.UnionType):
        for a in typing.get_args(tp):
            if _is_kind(a, v):
                return _coerce(a, v, key, choices)
        raise ConfigError(f"{key} = {_fmt(v)}: expected {_type_name(tp, choices)}")
    if origin is list:
        (inner,) = typing.get_args(tp)
        if not isinstance(v, list):
            raise ConfigError(f"{key} = {_fmt(v)}: expected {_type_name(tp, choices)}")
        return [_coerce(inner, x, f"{key}[{i}]", choices) for i, x in enumerate(v)]
    if tp is float:
        if isinstance(v, bool) or not isinstance(v, int | float):
            raise ConfigError(f"{key} = {_fmt(v)}: expected a number")
        if isinstance(v, int):
            _check_int64(v, key)
        if not math.isfinite(v):
            raise ConfigError(f"{key} = {_fmt(v)}: expected a finite number")
        if abs(v) > FLOAT_LIMIT:
            raise ConfigError(f"{key} = {_fmt(v)}: must be between -{FLOAT_LIMIT:g} and "
                              f"{FLOAT_LIMIT:g}")
        return float(v)
    if tp is int:
        if isinstance(v, bool) or not isinstance(v, int):
            raise ConfigError(f"{key} = {_fmt(v)}: expected an integer")
        _check_int64(v, key)
        return v
    if tp is bool:
        if not isinstance(v, bool):
            raise ConfigError(f"{key} = {_fmt(v)}: expected true or false")
        return v
    if tp is dict or typing.get_origin(tp) is dict:
        if not isinstance(v, dict):
            raise ConfigError(f"{key} = {_fmt(v)}: expected a table")
        return v
    if tp is str:
        if not isinstance(v, str):
            allowed = f"; allowed: {', '.join(choices)}" if choices else ""
            raise ConfigError(f"{key} = {_fmt(v)}: expected a string{allowed}")
        return v
    raise TypeError(tp)


_BOUNDS = (("gt", ">", lambda a, b: a > b), ("ge", ">=", lambda a, b: a >= b),
           ("lt", "<", lambda a, b: a < b), ("le", "<=", lambda a, b: a <= b))


def _check_range(meta: Mapping[str, Any], v: Any, key: str, tp: Any = None) -> None:
    """Enforce a field's metadata (bounds, choices, length, unique) on a coerced value."""
    is_list = isinstance(v, list)
    if meta.get("length") is not None and is_list and len(v) != meta["length"]:
        raise ConfigError(f"{key} = {_fmt(v)}: expected a list of {meta['length']} values")
    if meta.get("unique") and is_list:
        seen: list[Any] = []
        for x in v:
            if x in seen:
                raise ConfigError(f"{key} = {_fmt(v)}: {_fmt(x)} appears twice; each may appear "
                                  "once")
            seen.append(x)
    for i, x in enumerate(v if is_list else [v]):
        where = f"{key}[{i}]" if is_list else key
        if isinstance(x, str):
            ch = meta.get("choices")
            if ch and x not in ch:
                if tp is not None and _is_union_with_number(tp):
                    raise ConfigError(f"{where} = {_fmt(x)}: expected a number or "
                                      f"{' or '.join(_fmt(c) for c in ch)}")
                raise ConfigError(f"{where} = {_fmt(x)}: allowed: {', '.join(ch)}")
            continue
        if isinstance(x, bool):
            continue
        for op, bound, ok in _BOUNDS:
            b = meta.get(op)
            if b is not None and not ok(x, b):
                raise ConfigError(f"{where} = {_fmt(x)}: must be {bound} {b}")


def _is_union_with_number(tp: Any) -> bool:
    return (typing.get_origin(tp) in (typing.Union, types.UnionType)
            and float in typing.get_args(tp))


def _build(cls: type, data: Any, prefix: str, base: Any = None) -> Any:
    """Dataclass ``cls`` from ``data``, starting from ``base`` (default: ``cls()``)."""
    if not isinstance(data, dict):
        raise ConfigError(f"{prefix or 'config'} = {_fmt(data)}: expected a table")
    hints = typing.get_type_hints(cls)
    fields = {f.name: f for f in dataclasses.fields(cls)}
    unknown = [k for k in data if k not in fields]
    if unknown:
        k = unknown[0]
        where = f"{prefix}.{_toml_key(k)}" if prefix else _toml_key(k)  # "a.b": one key
        raise ConfigError(f"{where} = {_fmt(data[k])}: unknown key; allowed in "
                          f"[{prefix or 'top level'}]: {', '.join(fields)}")
    base_obj = base if base is not None else cls()
    kwargs = {}
    for name, value in data.items():
        key = f"{prefix}.{name}" if prefix else name
        tp = hints[name]
        if dataclasses.is_dataclass(tp):
            kwargs[name] = _build(tp, value, key, base=getattr(base_obj, name))
        else:
            meta = fields[name].metadata
            v = _coerce(tp, value, key, meta.get("choices"))
            _check_range(meta, v, key, tp)
            kwargs[name] = v
    return dataclasses.replace(base_obj, **kwargs)


def _check_gps_overrides(g: GpsConfig) -> None:
    """``gps.overrides`` against the preset, by ``ag_uav.vehicle.gps`` (the owner of those keys)."""
    from ..vehicle import gps

    ov_rate = g.overrides.get("rate_hz")
    if g.rate_hz > 0 and ov_rate is not None and ov_rate != g.rate_hz:
        raise ConfigError(f"gps.overrides.rate_hz = {_fmt(ov_rate)}: conflicts with gps.rate_hz = "
                          f"{g.rate_hz} (which would win); set one of them")
    if g.multipath_prob > 0 and isinstance(g.overrides.get("components"), list):
        raise ConfigError(f"gps.multipath_prob = {g.multipath_prob}: cannot be combined with a "
                          "components list in gps.overrides; add the spikes to that list")
    try:
        gps.validate_overrides(g.preset, g.overrides)
    except ValueError as e:
        raise ConfigError(f"gps.overrides = {_fmt(g.overrides)}: {e}") from None


def _check_gps_rate(cfg: Config) -> None:
    """A GNSS rate above the control rate is refused: the loop asks the receiver once per
    control tick, so fixes in between would be dropped silently."""
    from ..vehicle import gps

    g = cfg.gps
    rate = g.rate_hz or g.overrides.get("rate_hz") or gps.gps_preset(g.preset)["rate_hz"]
    if float(rate) > cfg.sim.control_hz + 1e-9:
        raise ConfigError(f"gps.rate_hz = {_fmt(g.rate_hz)} (0 = the rate of gps.preset = "
                          f"{_fmt(g.preset)}): a GNSS rate of {_fmt(rate)} Hz exceeds "
                          f"sim.control_hz = {cfg.sim.control_hz}; the loop takes at most one fix "
                          "per control tick: the GNSS rate must be <= the control rate")


def _check_field(name: str) -> None:
    """``mission.field`` names a built-in field or an existing field file (what
    :func:`ag_uav.world.field.load_field` accepts, with an optional ``#KEY=VALUE`` feature
    selector), so a typo fails at load, not at take-off."""
    from ..world.field import BUILTIN_FIELDS, FIELD_FILE_SUFFIXES

    if name.strip().lower().replace("_", "-") in BUILTIN_FIELDS:
        return
    why = "not a built-in field"
    path = name if Path(name).exists() or "#" not in name else name.partition("#")[0]
    if path.lower().endswith(FIELD_FILE_SUFFIXES):
        p = Path(path)
        if p.is_file():
            return
        why = "is a directory" if p.is_dir() else "no such file"
    raise ConfigError(f"mission.field = {_fmt(name)}: {why}; allowed: "
                      f"{', '.join(BUILTIN_FIELDS)} or the path of a "
                      f"{'/'.join(FIELD_FILE_SUFFIXES)} file (optionally #KEY=VALUE)")


def _check_origin(m: MissionConfig) -> None:
    """``mission.origin_lat_deg`` and ``origin_lon_deg`` are set together (or both "auto")."""
    lat_auto, lon_auto = m.origin_lat_deg == "auto", m.origin_lon_deg == "auto"
    if lat_auto != lon_auto:
        key, v = (("origin_lat_deg", m.origin_lat_deg) if not lat_auto
                  else ("origin_lon_deg", m.origin_lon_deg))
        other = "origin_lon_deg" if not lat_auto else "origin_lat_deg"
        raise ConfigError(f"mission.{key} = {_fmt(v)}: must come with mission.{other} (now "
                          f"mission.{other} = \"auto\"); set both, or leave both \"auto\"")


def _check_nozzles(sp: SprayConfig) -> None:
    """The nozzle layout and the droplet spectrum of ``[spray]`` (rules across keys)."""
    n = len(sp.nozzle_xyz_m)
    if n == 0 or n % 3:
        raise ConfigError(f"spray.nozzle_xyz_m = {_fmt(sp.nozzle_xyz_m)}: expected x, y, z of "
                          "each nozzle in turn (a multiple of 3 numbers, at least 3)")
    if sp.nozzle_share and (len(sp.nozzle_share) != n // 3
                            or abs(sum(sp.nozzle_share) - 1.0) > 1e-6):
        raise ConfigError(f"spray.nozzle_share = {_fmt(sp.nozzle_share)}: expected one share per "
                          f"nozzle ({n // 3}) summing to 1, or [] (equal shares)")
    if not sp.dv10_um < sp.dv50_um < sp.dv90_um:
        raise ConfigError(f"spray.dv50_um = {sp.dv50_um}: must be between spray.dv10_um = "
                          f"{sp.dv10_um} and spray.dv90_um = {sp.dv90_um} (Dv10 < Dv50 < Dv90)")


def _check_vehicle(v: VehicleConfig) -> None:
    """The ``[vehicle]`` keys that depend on the frame (rules across keys)."""
    from .vehicles import FRAME_ROTORS

    n = FRAME_ROTORS[v.frame]
    if v.atomiser_rpm > 0 and v.sprayer != "rotary":
        raise ConfigError(f"vehicle.atomiser_rpm = {_fmt(v.atomiser_rpm)}: must be 0 with "
                          f"vehicle.sprayer = {_fmt(v.sprayer)} (a disc speed is for "
                          "\"rotary\" atomisers)")
    if len(v.rotor_thrust_loss) != n:
        raise ConfigError(f"vehicle.rotor_thrust_loss = {_fmt(v.rotor_thrust_loss)}: expected one "
                          f"value per rotor, {n} for vehicle.frame = {_fmt(v.frame)}")
    if v.rotor_fault.rotor >= n:
        raise ConfigError(f"vehicle.rotor_fault.rotor = {_fmt(v.rotor_fault.rotor)}: must be "
                          f"-1 (none) or a rotor of vehicle.frame = {_fmt(v.frame)}, 0 to {n - 1}")
    if len(v.inertia_kgm2) not in (0, 3):
        raise ConfigError(f"vehicle.inertia_kgm2 = {_fmt(v.inertia_kgm2)}: expected [Ixx, Iyy, "
                          "Izz] (kg m^2) or [] (from the components)")
    arms = 4 if v.frame == "octo-x8" else n
    parts = n * v.rotor_mass_kg + arms * v.arm_mass_kg
    parts_are = (f"vehicle.rotor_mass_kg = {_fmt(v.rotor_mass_kg)} ({n} rotors), "
                 f"vehicle.arm_mass_kg = {_fmt(v.arm_mass_kg)} ({arms} arms)")
    if parts >= v.mass_kg:
        raise ConfigError(f"{parts_are}: {parts:g} kg, must weigh less than vehicle.mass_kg = "
                          f"{_fmt(v.mass_kg)}")
    if v.battery_mass_kg >= v.mass_kg - parts:
        raise ConfigError(f"vehicle.battery_mass_kg = {_fmt(v.battery_mass_kg)}: must be less "
                          f"than vehicle.mass_kg = {_fmt(v.mass_kg)} less the rotors and arms "
                          f"({parts_are}: {parts:g} kg)")


def _validate(cfg: Config) -> None:
    """Checks across fields (one field's own range is :func:`_check_range`'s)."""
    _check_vehicle(cfg.vehicle)
    _check_field(cfg.mission.field)
    _check_origin(cfg.mission)
    s = cfg.sim
    ctrl_steps = 1.0 / (s.timestep_s * s.control_hz) if s.timestep_s * s.control_hz > 0 else 0.0
    if (not math.isfinite(ctrl_steps) or abs(ctrl_steps - round(ctrl_steps)) > 1e-6
            or round(ctrl_steps) < 1):
        raise ConfigError(f"sim.control_hz = {s.control_hz} with sim.timestep_s = "
                          f"{s.timestep_s}: the control rate must divide the physics rate "
                          f"1/timestep_s = {1.0 / s.timestep_s:g} Hz")
    _check_gps_overrides(cfg.gps)
    _check_gps_rate(cfg)
    sp = cfg.spray
    if sp.min_height_m >= sp.max_height_m:
        raise ConfigError(f"spray.min_height_m = {sp.min_height_m}: must be < spray.max_height_m "
                          f"= {sp.max_height_m}")
    if not sp.min_height_m < cfg.mission.altitude_m < sp.max_height_m:
        raise ConfigError(f"mission.altitude_m = {cfg.mission.altitude_m}: must be between "
                          f"spray.min_height_m = {sp.min_height_m} and spray.max_height_m = "
                          f"{sp.max_height_m} (the nozzles spray only there)")
    _check_nozzles(sp)
    if isinstance(sp.base, str):
        if sp.base != "auto":
            raise ConfigError(f'spray.base = "{sp.base}": expected [x, y] or "auto"')
    elif len(sp.base) != 2:
        raise ConfigError(f"spray.base = {sp.base}: expected [x, y] or \"auto\"")


def config_from_dict(data: dict[str, Any]) -> Config:
    """Build and validate a :class:`Config` from a (TOML-shaped) dict; ``vehicle.preset``
    fills the keys the dict leaves unset (:func:`ag_uav.config.vehicles.apply_vehicle_preset`)."""
    from .vehicles import apply_vehicle_preset

    if isinstance(data, dict):
        data = apply_vehicle_preset(data)
    cfg = _build(Config, data, "")
    _validate(cfg)
    return cfg


def parse_set_items(items: list[str]) -> dict[str, Any]:
    """``["wind.speed_mps=5", ...]`` (``--set`` arguments) -> dotted-key overrides; the value is
    read as one TOML value, or kept as a bare string where it is not TOML."""
    out: dict[str, Any] = {}
    for item in items:
        if "=" not in item:
            raise ConfigError(f"--set {_fmt(item)}: expected KEY=VALUE, e.g. "
                              "--set wind.speed_mps=5")
        k, v = item.split("=", 1)
        parts = [p.strip() for p in k.split(".")]
        if not all(parts):
            raise ConfigError(f"--set {_fmt(item)}: KEY {_fmt(k.strip())} has an empty part; "
                              "expected dotted names, e.g. mission.swath_m")
        try:
            doc = tomllib.loads(f"v = {v}")
        except tomllib.TOMLDecodeError:
            out[".".join(parts)] = v  # a bare string
            continue
        if list(doc) != ["v"]:
            raise ConfigError(f"--set {_fmt(item)}: VALUE {_fmt(v)} is more than one TOML value")
        out[".".join(parts)] = doc["v"]
    return out


def _merge_section(cls: type, old: dict[str, Any], new: dict[str, Any]) -> dict[str, Any]:
    """Table ``new`` over table ``old`` of dataclass ``cls``: sub-tables merge key by key,
    everything else (values, ``gps.overrides``) is replaced."""
    hints = typing.get_type_hints(cls)
    out = dict(old)
    for k, v in new.items():
        tp = hints.get(k)
        if (tp is not None and dataclasses.is_dataclass(tp) and isinstance(v, dict)
                and isinstance(out.get(k), dict)):
            out[k] = _merge_section(tp, out[k], v)
        else:
            out[k] = v
    return out


def _apply_override(data: dict[str, Any], key: str, value: Any) -> None:
    """Set dotted ``key`` in the TOML-shaped ``data``; every table on the way must be one in the
    schema (or inside a table-valued key such as ``gps.overrides``)."""
    parts = key.split(".")
    if not all(parts):
        raise ConfigError(f"{_fmt(key)} = {_fmt(value)}: key has an empty part; expected dotted "
                          "names, e.g. mission.swath_m")
    cls: Any = Config  # the schema table we are in; None inside a free-form table
    node = data
    for i, part in enumerate(parts):
        where = ".".join(parts[: i + 1])
        last = i == len(parts) - 1
        tp = None
        if cls is not None:
            hints = typing.get_type_hints(cls)
            if part not in hints:
                prefix = ".".join(parts[:i])
                raise ConfigError(f"{where} = {_fmt(value)}: unknown key; allowed in "
                                  f"[{prefix or 'top level'}]: {', '.join(hints)}")
            tp = hints[part]
        if last:
            if (tp is not None and dataclasses.is_dataclass(tp) and isinstance(value, dict)
                    and isinstance(node.get(part), dict)):
                node[part] = _merge_section(tp, node[part], value)
            else:
                node[part] = value
            return
        if cls is not None:
            if dataclasses.is_dataclass(tp):
                cls = tp
            elif tp is dict or typing.get_origin(tp) is dict:
                cls = None
            else:
                raise ConfigError(f"{key} = {_fmt(value)}: {where} is a single value "
                                  f"({_type_name(tp)}), not a table")
        cur = node.get(part)
        if cur is None:
            cur = node[part] = {}
        elif not isinstance(cur, dict):
            raise ConfigError(f"{where} = {_fmt(cur)}: expected a table (to set {key} in it)")
        node = cur


def _read_toml(path: str | Path) -> dict[str, Any]:
    p = Path(path)
    what = f"config file = {_fmt(str(path))}"
    if not str(path) or not p.exists():
        raise ConfigError(f"{what}: no such file")
    if p.is_dir():  # anything else readable will do: a file, a pipe (<(...), /dev/stdin)
        raise ConfigError(f"{what}: a directory; expected a TOML file")
    try:
        raw = p.read_bytes()
    except OSError as e:
        raise ConfigError(f"{what}: cannot be read ({e.strerror or e})") from None
    try:
        text = raw.decode("utf-8")
    except UnicodeDecodeError as e:
        raise ConfigError(f"{what}: not UTF-8 text (byte {e.start}); TOML files are UTF-8") \
            from None
    try:
        return tomllib.loads(text)
    except tomllib.TOMLDecodeError as e:
        raise ConfigError(f"{what}: not valid TOML ({e})") from None


def load_config(path: str | Path | None = None, overrides: dict[str, Any] | None = None) -> Config:
    """Load a TOML config file (``None`` = defaults) and apply dotted-key ``overrides``."""
    data: dict[str, Any] = {} if path is None else _read_toml(path)
    for k, v in (overrides or {}).items():
        _apply_override(data, str(k), v)
    return config_from_dict(data)


def default_config() -> Config:
    return Config()


def _toml_key(k: Any) -> str:
    """A TOML key: bare where it can be, else a quoted string (``"my comp"``)."""
    k = str(k)
    if k and all(c.isascii() and (c.isalnum() or c in "_-") for c in k):
        return k
    return _toml_value(k)


def _toml_value(v: Any) -> str:
    """``v`` as one inline TOML value (tables inline, keys quoted where they must be)."""
    if isinstance(v, dict):
        if not v:
            return "{}"
        return "{ " + ", ".join(f"{_toml_key(k)} = {_toml_value(x)}" for k, x in v.items()) + " }"
    if isinstance(v, list):
        return "[" + ", ".join(_toml_value(x) for x in v) + "]"
    return tomli_w.dumps({"k": v}).strip()[4:]


def config_toml_with_comments(cfg: Config | None = None) -> str:
    """The config as TOML with a comment per key (what ``ag-uav config`` prints)."""
    cfg = cfg or Config()
    lines: list[str] = ["# ag-uav run configuration (every key optional; these are the defaults)"]

    def emit(obj: Any, prefix: str) -> None:
        subs = []
        for f in dataclasses.fields(obj):
            v = getattr(obj, f.name)
            if dataclasses.is_dataclass(v):
                subs.append((f, v))
                continue
            help_ = f.metadata.get("help", "")
            ch = f.metadata.get("choices")
            if ch and not all(c in help_ for c in ch):  # unless the help lists them already
                help_ += f" [{' | '.join(ch)}]"
            lines.append(f"# {help_}")
            lines.append(f"{f.name} = {_toml_value(v)}")
        for f, v in subs:
            name = f"{prefix}.{f.name}" if prefix else f.name
            lines.append("")
            lines.append(f"[{name}]  # {f.metadata.get('help', '')}")
            emit(v, name)

    emit(cfg, "")
    return "\n".join(lines) + "\n"
