"""Config fuzzing: no bad config is accepted silently, no good one is refused or changed.

Every generated value goes through three doors -- :func:`config_from_dict`, a TOML file
(``ag-uav config --config FILE``) and ``ag-uav config --set KEY=VALUE`` (in-process through
:func:`ag_uav.cli.main`) -- and each door must agree with an oracle derived from the dataclass
metadata in :mod:`ag_uav.config` (type, gt/ge/lt/le, choices, length, unique).  A rejection is
exactly one stderr line ``ag-uav: config error: KEY = VALUE: what is allowed`` and exit code 2; an
acceptance leaves the value in the config unchanged and every other key at its default.

The only rules not in the metadata are written here once: the control rate divides the physics
rate, ``mission.field`` is a built-in field or a GeoJSON file, and ``gps.overrides`` belongs to
:func:`ag_uav.vehicle.gps.validate_overrides` (fuzzed with overrides that are bad whatever the
preset).
"""

from __future__ import annotations

import dataclasses
import json
import math
import os
import subprocess
import sys
import tomllib
import typing
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import pytest
import tomli_w
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from ag_uav import cli
from ag_uav import config as C
from ag_uav.config import load as config_load
from ag_uav.config.vehicles import FRAME_ROTORS, PRESETS
from ag_uav.vehicle.gps import available_presets, gps_preset

FUZZ = settings(max_examples=100, deadline=None, derandomize=True, database=None,
                suppress_health_check=[HealthCheck.function_scoped_fixture,
                                       HealthCheck.too_slow])
INT64 = (-(2**63), 2**63 - 1)
PREFIX = "ag-uav: config error: "


# --------------------------------------------------------------------------- the schema, walked
@dataclasses.dataclass(frozen=True)
class Leaf:
    key: str
    tp: Any
    meta: Mapping[str, Any]


def _walk(cls: type = C.Config, prefix: str = "") -> tuple[list[Leaf], list[tuple[str, type]]]:
    """Every settable key (leaf) and every table (dataclass section, "" = top level)."""
    leaves: list[Leaf] = []
    tables: list[tuple[str, type]] = [(prefix, cls)]
    hints = typing.get_type_hints(cls)
    for f in dataclasses.fields(cls):
        key = f"{prefix}.{f.name}" if prefix else f.name
        if dataclasses.is_dataclass(hints[f.name]):
            sub_l, sub_t = _walk(hints[f.name], key)
            leaves += sub_l
            tables += sub_t
        else:
            leaves.append(Leaf(key, hints[f.name], f.metadata))
    return leaves, tables


LEAVES, TABLES = _walk()
SPECIAL = {"gps.overrides", "mission.field"}  # own tests below
PLAIN = [lf for lf in LEAVES if lf.key not in SPECIAL]
DEFAULT = C.Config()


def _get(obj: Any, key: str) -> Any:
    for part in key.split("."):
        obj = getattr(obj, part)
    return obj


def _nest(key: str, v: Any) -> dict[str, Any]:
    d: Any = v
    for part in reversed(key.split(".")):
        d = {part: d}
    return d


# ------------------------------------------------------------------------------------ the oracle
def _is_union(tp: Any) -> bool:
    return typing.get_origin(tp) in (typing.Union, type(int | str))


def _number(v: Any) -> bool:
    return isinstance(v, int | float) and not isinstance(v, bool)


def meta_ok(tp: Any, meta: Mapping[str, Any], v: Any) -> bool:
    """Whether ``v`` is allowed for a field of type ``tp`` with metadata ``meta``."""
    if _is_union(tp):  # a number is read as the number branch, a string as the string one
        for a in typing.get_args(tp):
            if (a is float and _number(v)) or (a is str and isinstance(v, str)):
                return meta_ok(a, meta, v)
        return False
    if typing.get_origin(tp) is list:
        if not isinstance(v, list):
            return False
        if meta.get("length") is not None and len(v) != meta["length"]:
            return False
        if meta.get("unique") and len({json.dumps(x) for x in v}) != len(v):
            return False
        (inner,) = typing.get_args(tp)
        return all(meta_ok(inner, meta, x) for x in v)
    if tp is bool:
        return isinstance(v, bool)
    if tp is str:
        return isinstance(v, str) and (not meta.get("choices") or v in meta["choices"])
    if tp in (int, float):
        if not _number(v) or (tp is int and not isinstance(v, int)):
            return False
        if isinstance(v, int) and not INT64[0] <= v <= INT64[1]:
            return False
        if not math.isfinite(v) or (tp is float and abs(v) > C.FLOAT_LIMIT):
            return False
        return all(b is None or op(v, b) for b, op in (
            (meta.get("gt"), lambda a, b: a > b), (meta.get("ge"), lambda a, b: a >= b),
            (meta.get("lt"), lambda a, b: a < b), (meta.get("le"), lambda a, b: a <= b)))
    raise AssertionError(f"no oracle for {tp}")


def _divides(timestep_s: float, control_hz: float) -> bool:
    rate = timestep_s * control_hz
    steps = 1.0 / rate if rate > 0 else math.inf
    return math.isfinite(steps) and abs(steps - round(steps)) <= 1e-6 and round(steps) >= 1


def _base(vals: Mapping[str, Any]) -> dict[str, Any]:
    """The defaults as ``vals`` change them: a ``vehicle.preset`` fills the keys of its tables
    that ``vals`` leaves unset."""
    want = DEFAULT.to_dict()
    p = vals.get("vehicle.preset")
    if isinstance(p, str) and p in PRESETS and p != "m350":
        for table, kv in PRESETS[p].items():
            want[table].update(json.loads(json.dumps(kv)))
    return want


def _dotted(d: Mapping[str, Any], key: str) -> Any:
    for part in key.split("."):
        d = d[part]
    return d


def _vehicle_rules(g: Any) -> list[str]:
    """The ``[vehicle]`` rules across keys (ag_uav.config.load._check_vehicle)."""
    n = FRAME_ROTORS.get(g("vehicle.frame"), 4)
    if g("vehicle.atomiser_rpm") > 0 and g("vehicle.sprayer") != "rotary":
        return ["vehicle.atomiser_rpm", "vehicle.sprayer"]
    if len(g("vehicle.rotor_thrust_loss")) != n:
        return ["vehicle.rotor_thrust_loss", "vehicle.frame"]
    if g("vehicle.rotor_fault.rotor") >= n:
        return ["vehicle.rotor_fault.rotor", "vehicle.frame"]
    if len(g("vehicle.inertia_kgm2")) not in (0, 3):
        return ["vehicle.inertia_kgm2"]
    arms = 4 if g("vehicle.frame") == "octo-x8" else n
    parts = n * g("vehicle.rotor_mass_kg") + arms * g("vehicle.arm_mass_kg")
    if parts >= g("vehicle.mass_kg"):
        return ["vehicle.rotor_mass_kg", "vehicle.arm_mass_kg", "vehicle.mass_kg"]
    if g("vehicle.battery_mass_kg") >= g("vehicle.mass_kg") - parts:
        return ["vehicle.battery_mass_kg", "vehicle.mass_kg", "vehicle.rotor_mass_kg",
                "vehicle.arm_mass_kg"]
    return []


def cross_ok(vals: Mapping[str, Any]) -> list[str]:
    """The rules across keys (dotted keys; the rest at their defaults, or their preset's):
    the keys of the first one broken, else []."""
    base = _base(vals)

    def g(k: str) -> Any:
        return vals.get(k, _dotted(base, k))

    broken = _vehicle_rules(g)
    if broken:
        return broken

    if (g("mission.origin_lat_deg") == "auto") != (g("mission.origin_lon_deg") == "auto"):
        return ["mission.origin_lat_deg", "mission.origin_lon_deg"]  # both, or neither
    if not _divides(g("sim.timestep_s"), g("sim.control_hz")):
        return ["sim.control_hz", "sim.timestep_s"]
    from ag_uav.vehicle.gps import gps_preset

    rate = g("gps.rate_hz") or gps_preset(g("gps.preset"))["rate_hz"]
    if rate > g("sim.control_hz") + 1e-9:    # a GNSS rate above the control rate
        return ["gps.rate_hz", "sim.control_hz", "gps.preset"]
    lo, hi, alt = g("spray.min_height_m"), g("spray.max_height_m"), g("mission.altitude_m")
    if lo >= hi:
        return ["spray.min_height_m", "spray.max_height_m"]
    if not lo < alt < hi:
        return ["mission.altitude_m", "spray.min_height_m", "spray.max_height_m"]
    xyz, share = g("spray.nozzle_xyz_m"), g("spray.nozzle_share")
    if not xyz or len(xyz) % 3:
        return ["spray.nozzle_xyz_m"]
    if share and (len(share) != len(xyz) // 3 or abs(sum(share) - 1.0) > 1e-6):
        return ["spray.nozzle_share"]
    if not g("spray.dv10_um") < g("spray.dv50_um") < g("spray.dv90_um"):
        return ["spray.dv50_um", "spray.dv10_um", "spray.dv90_um"]
    return []


CROSS = {"vehicle.preset", "vehicle.frame", "vehicle.rotor_thrust_loss", "vehicle.inertia_kgm2",
         "vehicle.rotor_fault.rotor", "vehicle.atomiser_rpm", "vehicle.sprayer",
         "vehicle.rotor_mass_kg", "vehicle.arm_mass_kg", "vehicle.mass_kg",
         "vehicle.battery_mass_kg",
         "sim.control_hz", "sim.timestep_s", "spray.min_height_m", "spray.max_height_m",
         "mission.altitude_m", "spray.nozzle_xyz_m", "spray.nozzle_share", "spray.dv10_um",
         "spray.dv50_um", "spray.dv90_um", "gps.rate_hz", "gps.preset",
         "mission.origin_lat_deg", "mission.origin_lon_deg"}


def allowed(leaf: Leaf, v: Any) -> bool:
    if not meta_ok(leaf.tp, leaf.meta, v):
        return False
    return leaf.key not in CROSS or not cross_ok({leaf.key: v})


def landed(leaf: Leaf, v: Any) -> Any:
    """What an accepted ``v`` must read back as (an integer given for a number is that number)."""
    if leaf.tp is float or (_is_union(leaf.tp) and _number(v)):
        return float(v)
    if typing.get_origin(leaf.tp) is list and typing.get_args(leaf.tp)[0] is float:
        return [float(x) for x in v]
    return v


# -------------------------------------------------------------------------------- the generators
def _bounds(meta: Mapping[str, Any]) -> list[float]:
    return [meta[k] for k in ("gt", "ge", "lt", "le") if meta.get(k) is not None]


def valid_scalar(tp: Any, meta: Mapping[str, Any]) -> st.SearchStrategy:
    if tp is bool:
        return st.booleans()
    if tp is str:
        return st.sampled_from(meta["choices"])
    lo = meta.get("gt") if meta.get("gt") is not None else meta.get("ge")
    hi = meta.get("lt") if meta.get("lt") is not None else meta.get("le")
    if tp is float:
        lo = -C.FLOAT_LIMIT if lo is None else lo
        hi = C.FLOAT_LIMIT if hi is None else hi
    if tp is int:
        return st.integers(min_value=max(lo if lo is not None else INT64[0], INT64[0]),
                           max_value=min(hi if hi is not None else INT64[1], INT64[1]))
    floats = st.floats(min_value=lo, max_value=hi, exclude_min=meta.get("gt") is not None,
                       exclude_max=meta.get("lt") is not None, allow_nan=False,
                       allow_infinity=False)
    lo_i, hi_i = math.ceil(lo), math.floor(hi)
    return st.one_of(floats, st.integers(lo_i, hi_i)) if lo_i <= hi_i else floats


def edge_values(meta: Mapping[str, Any]) -> list[Any]:
    """Values on and just beside every bound and choice, and the specials TOML can spell."""
    big = C.FLOAT_LIMIT
    out: list[Any] = [math.nan, -math.inf, math.inf, 2**63, -(2**63) - 1, 2**70, 0, -0.0, -1,
                      2**63 - 1, 1e308, 5e-324, big, -big, int(big) + 1,
                      math.nextafter(big, math.inf), math.nextafter(-big, -math.inf)]
    for b in _bounds(meta):
        out += [b, -b, b + 1, b - 1, math.nextafter(b, math.inf), math.nextafter(b, -math.inf)]
        if float(b).is_integer():
            out += [int(b), int(b) + 1, int(b) - 1]
    for c in meta.get("choices") or ():
        out += [c, c.upper(), f" {c}", f"{c} ", c[:-1], c + "\n", c + "\x1e"]
    return out


def edge_scalar(tp: Any, meta: Mapping[str, Any]) -> st.SearchStrategy:
    return st.sampled_from(edge_values(meta))


JUNK = st.one_of(
    st.booleans(), st.integers(), st.floats(), st.text(max_size=6),
    st.lists(st.integers(-3, 3), max_size=4), st.dictionaries(st.text(max_size=3),
                                                              st.integers(), max_size=2),
    st.dates(),
)


def good_values(leaf: Leaf) -> st.SearchStrategy:
    """Values the metadata allows (most of them; the oracle still decides)."""
    tp, meta = leaf.tp, leaf.meta
    if typing.get_origin(tp) is list:
        (inner,) = typing.get_args(tp)
        n = meta.get("length")
        if n is not None:
            return st.lists(valid_scalar(inner, meta), min_size=n, max_size=n)
        return st.lists(valid_scalar(inner, meta), max_size=4, unique=bool(meta.get("unique")))
    if _is_union(tp):
        return st.one_of(valid_scalar(float, meta), st.sampled_from(meta["choices"]))
    if leaf.key == "sim.control_hz":  # valid values are rare here: build rates that divide
        return st.integers(1, 600).map(lambda n: 1.0 / (DEFAULT.sim.timestep_s * n))
    if leaf.key == "sim.timestep_s":
        return st.integers(1, 600).map(lambda n: 1.0 / (DEFAULT.sim.control_hz * n))
    return valid_scalar(tp, meta)


def candidates(leaf: Leaf) -> st.SearchStrategy:
    """Good values (from the metadata), values at the edges, and junk of every TOML type."""
    tp, meta = leaf.tp, leaf.meta
    if typing.get_origin(tp) is list:
        (inner,) = typing.get_args(tp)
        n = meta.get("length")
        elem = st.one_of(valid_scalar(inner, meta), edge_scalar(inner, meta))
        any_len = st.lists(elem, max_size=(n or 2) + 2)
        return st.one_of(good_values(leaf), any_len, JUNK)
    if _is_union(tp):
        return st.one_of(good_values(leaf), edge_scalar(str, meta), edge_scalar(float, {}), JUNK)
    if leaf.key in CROSS:
        return st.one_of(good_values(leaf), valid_scalar(tp, meta), edge_scalar(tp, meta), JUNK)
    return st.one_of(valid_scalar(tp, meta), edge_scalar(tp, meta), JUNK)


def toml_inline(v: Any) -> str:
    """``v`` as one inline TOML value (what ``--set KEY=`` takes)."""
    if isinstance(v, dict):
        return "{" + ", ".join(f"{json.dumps(k)} = {toml_inline(x)}" for k, x in v.items()) + "}"
    if isinstance(v, list):
        return "[" + ", ".join(toml_inline(x) for x in v) + "]"
    return tomli_w.dumps({"v": v})[len("v = "):].strip()


# ------------------------------------------------------------------------------------ the doors
def error_line(err: str, key: str) -> str:
    """The one stderr line of a rejection, checked; its text after the prefix."""
    assert "Traceback" not in err, err
    lines = err.splitlines()
    assert len(lines) == 1, err
    assert lines[0].startswith(PREFIX), err
    body = lines[0][len(PREFIX):]
    assert key in body, (key, body)
    return body


def check_message(body: str, leaf: Leaf, v: Any) -> None:
    """The message names the key, the value (scalars) and what is allowed."""
    if leaf.key in CROSS:  # a rule across keys names them all
        broken = cross_ok({leaf.key: v}) if meta_ok(leaf.tp, leaf.meta, v) else []
        assert all(f"{k} = " in body for k in broken), body
        assert f"{leaf.key} = " in body or f"{leaf.key}[" in body, body  # [i]: a list item
    else:
        assert body.startswith((f"{leaf.key} = ", f"{leaf.key}[")), body
    assert any(w in body for w in ("expected", "must", "allowed", "appears twice",
                                   "outside the 64-bit")), body
    if isinstance(v, bool):
        assert ("true" if v else "false") in body, body
    elif _number(v):
        shown = [repr(v)[:40]] + ([repr(float(v))] if isinstance(v, int) and  # as a number
                                  abs(v) < 2**1000 else [])
        assert any(s in body for s in shown), (shown, body)
    elif isinstance(v, str) and v.isprintable() and '"' not in v and "\\" not in v:
        assert f'"{v}"' in body, body


@pytest.fixture(scope="module", autouse=True)
def _one_parser() -> typing.Iterator[None]:
    """Build the argument parser once for the module (``main`` builds it per call: ~15 ms, most
    of this module's run time); what ``main`` does with the parsed arguments is unchanged."""
    mp = pytest.MonkeyPatch()
    parser = cli.build_parser()
    mp.setattr(cli, "build_parser", lambda experiments=True: parser)
    yield
    mp.undo()


def through_cli(argv: list[str], capsys: pytest.CaptureFixture[str]) -> tuple[int, str]:
    """``ag-uav config ARGV`` in-process: (exit code, stderr); on success the printed TOML must
    load back to the very config the command resolved."""
    rc = cli.main(["config", *argv])
    out, err = capsys.readouterr()
    if rc == 0:
        assert err == "" and out.startswith("# ag-uav run configuration"), err
        resolved = cli._load(cli.build_parser().parse_args(["config", *argv]))
        assert C.config_from_dict(tomllib.loads(out)) == resolved
    return rc, err


def assert_lands(cfg: C.Config, leaf: Leaf, v: Any) -> None:
    """``v`` is in ``cfg`` unchanged and nothing else moved from the defaults."""
    got = _get(cfg, leaf.key)
    assert got == landed(leaf, v) and type(got) is type(landed(leaf, v)), (leaf.key, v, got)
    want = _base({leaf.key: v})
    node = want
    *head, last = leaf.key.split(".")
    for part in head:
        node = node[part]
    node[last] = landed(leaf, v)
    assert cfg.to_dict() == want


def test_schema_walk_sees_every_kind() -> None:
    """The oracle covers every field type in the schema (a new kind would need a rule here)."""
    kinds = {str(lf.tp) for lf in LEAVES}
    assert {"<class 'float'>", "<class 'int'>", "<class 'bool'>", "<class 'str'>",
            "list[float]", "list[str]"} <= kinds
    for lf in PLAIN:  # every plain leaf has an oracle, and its default passes it
        assert allowed(lf, _get(DEFAULT, lf.key)), lf.key
    assert len(PLAIN) > 60 and len(TABLES) == 17  # 12 + [imu] [spray] [battery]
    #                                               + [vehicle.rotor_fault] [forecast]


JUNK_VALUES: list[Any] = [True, False, "", "x", "1", [], [1.0], {}, {"a": 1},
                          __import__("datetime").date(2020, 1, 1)]


def _edge_cases(leaf: Leaf) -> list[Any]:
    """For every leaf: its default, every edge and junk value; lists also get each edge value
    in each slot, one value too few and too many, and a duplicate."""
    default = _get(DEFAULT, leaf.key)
    vals = [default, *edge_values(leaf.meta), *JUNK_VALUES]
    if isinstance(default, list):
        vals = [default, *JUNK_VALUES, [*default, *default[:1]], default[:-1],
                [*default, default[0] if default else "kf"]]
        vals += [[*default[:i], x, *default[i + 1:]] for x in edge_values(leaf.meta)
                 for i in range(max(1, len(default)))]
    return vals


def through_api(leaf: Leaf, v: Any) -> bool:
    """``config_from_dict`` on one key: accepted iff allowed (and the value lands), else the
    one-line message; whether it was accepted."""
    ok = allowed(leaf, v)
    try:
        cfg = C.config_from_dict(_nest(leaf.key, v))
    except C.ConfigError as e:
        assert not ok, f"refused a good value: {leaf.key} = {v!r}: {e}"
        check_message(error_line(PREFIX + str(e), leaf.key), leaf, v)
        return False
    assert ok, f"accepted a bad value silently: {leaf.key} = {v!r}"
    assert_lands(cfg, leaf, v)
    return True


def test_every_leaf_every_edge() -> None:
    """Deterministic sweep (the fuzz below samples): every key, every edge value."""
    n_ok = n_bad = 0
    for leaf in PLAIN:
        for v in _edge_cases(leaf):
            if through_api(leaf, v):
                n_ok += 1
            else:
                n_bad += 1
    assert n_ok > 3 * len(PLAIN) and n_bad > 15 * len(PLAIN)


def test_gps_preset_choices_are_the_gps_modules() -> None:
    assert set(C.GPS_PRESETS) == set(available_presets())


@FUZZ
@given(data=st.data())
def test_every_leaf_value_accepted_iff_allowed(data: st.DataObject, tmp_path: Path,
                                               capsys: pytest.CaptureFixture[str]) -> None:
    leaf = data.draw(st.sampled_from(PLAIN), label="key")
    v = data.draw(candidates(leaf), label="value")
    ok = allowed(leaf, v)

    # door 1: the Python API
    assert through_api(leaf, v) == ok

    # door 2: a TOML file
    path = tmp_path / "fuzz.toml"
    path.write_text(tomli_w.dumps(_nest(leaf.key, v)), encoding="utf-8")
    rc, err = through_cli(["--config", str(path)], capsys)
    assert rc == (0 if ok else 2), (leaf.key, v, err)
    if ok:
        assert_lands(C.load_config(path), leaf, v)
    else:
        check_message(error_line(err, leaf.key), leaf, v)

    # door 3: --set KEY=VALUE
    item = f"{leaf.key}={toml_inline(v)}"
    rc, err = through_cli(["--set", item], capsys)
    assert rc == (0 if ok else 2), (item, err)
    if ok:
        assert_lands(C.load_config(None, C.parse_set_items([item])), leaf, v)
    else:
        check_message(error_line(err, leaf.key), leaf, v)


@FUZZ
@given(data=st.data())
def test_whole_configs(data: st.DataObject, tmp_path: Path,
                       capsys: pytest.CaptureFixture[str]) -> None:
    """Several keys at once, mostly good: accepted iff every one is allowed (and the rates
    divide); then all of them land and nothing else moves; else the one line names a bad key."""
    leaves = data.draw(st.lists(st.sampled_from(PLAIN), min_size=2, max_size=8,
                                unique_by=lambda lf: lf.key), label="keys")
    vals = {lf.key: data.draw(st.one_of(good_values(lf), good_values(lf), good_values(lf),
                                        candidates(lf)), label=lf.key) for lf in leaves}
    bad = [lf.key for lf in leaves if not meta_ok(lf.tp, lf.meta, vals[lf.key])]
    if not bad:
        bad = cross_ok({k: v for k, v in vals.items() if k in CROSS})
    doc: dict[str, Any] = {}
    for k, v in vals.items():
        config_load._apply_override(doc, k, v)
    path = tmp_path / "whole.toml"
    path.write_text(tomli_w.dumps(doc), encoding="utf-8")
    sets = [f"--set={k}={toml_inline(v)}" for k, v in vals.items()]
    for argv in (["--config", str(path)], sets):
        rc, err = through_cli(argv, capsys)
        assert rc == (2 if bad else 0), (vals, err)
        if bad:
            body = error_line(err, "")
            assert any(body.startswith((f"{k} = ", f"{k}[")) for k in bad), (bad, body)
    if not bad:
        cfg = C.config_from_dict(doc)
        want = _base(vals)
        for lf in leaves:
            node = want
            *head, last = lf.key.split(".")
            for part in head:
                node = node[part]
            node[last] = landed(lf, vals[lf.key])
            assert _get(cfg, lf.key) == landed(lf, vals[lf.key])
        assert cfg.to_dict() == want


NAME_RE = __import__("re").compile(r"[a-z_][a-z0-9_]{0,10}")
NAME = st.from_regex(NAME_RE, fullmatch=True)


@FUZZ
@given(data=st.data())
def test_unknown_key_at_every_level(data: st.DataObject, tmp_path: Path,
                                    capsys: pytest.CaptureFixture[str]) -> None:
    """Any key name a TOML file can hold (``"mission.swath_m" = 3`` at the top level is one
    unknown key, shown quoted), in every table."""
    prefix, cls = data.draw(st.sampled_from(TABLES), label="table")
    fields = {f.name for f in dataclasses.fields(cls)}
    name = data.draw(st.one_of(NAME, st.text(max_size=6), st.sampled_from(
        [f"{f}.x" for f in sorted(fields)] + ["", " ", "a b", "é"])).filter(
        lambda n: n not in fields), label="name")
    key = f"{prefix}.{config_load._toml_key(name)}" if prefix else config_load._toml_key(name)
    doc = _nest(prefix, {name: 1}) if prefix else {name: 1}
    with pytest.raises(C.ConfigError, match="unknown key") as e:
        C.config_from_dict(doc)
    assert str(e.value).startswith(f"{key} = ") or not name.isprintable(), str(e.value)
    path = tmp_path / "unknown.toml"
    path.write_text(tomli_w.dumps(doc), encoding="utf-8")
    argvs = [["--config", str(path)]]
    if NAME_RE.fullmatch(name):
        argvs.append(["--set", f"{prefix + '.' if prefix else ''}{name}=1"])
    for argv in argvs:
        rc, err = through_cli(argv, capsys)
        assert rc == 2
        assert "unknown key" in error_line(err, key if name.isprintable() else "")


@FUZZ
@given(data=st.data())
def test_table_given_a_value_and_value_given_a_table(data: st.DataObject,
                                                     capsys: pytest.CaptureFixture[str]) -> None:
    """``mission = 3`` / ``--set mission=3`` and ``--set seed.x=1`` (a scalar is no table)."""
    prefix, _ = data.draw(st.sampled_from(TABLES[1:]), label="table")
    v = data.draw(st.one_of(st.integers(), st.text(max_size=4), st.booleans(),
                            st.lists(st.integers(), max_size=2), st.floats()))
    with pytest.raises(C.ConfigError, match="expected a table"):
        C.config_from_dict(_nest(prefix, v))
    rc, err = through_cli(["--set", f"{prefix}={toml_inline(v)}"], capsys)
    assert rc == 2 and "expected a table" in error_line(err, prefix)

    leaf = data.draw(st.sampled_from([lf for lf in LEAVES if lf.key != "gps.overrides"]))
    sub = data.draw(NAME, label="sub")
    item = f"{leaf.key}.{sub}=1"
    rc, err = through_cli(["--set", item], capsys)
    assert rc == 2 and "not a table" in error_line(err, f"{leaf.key}.{sub}")


def _with_empty_part(key: str, where: int) -> str:
    parts = key.split(".")
    parts.insert(where % (len(parts) + 1), "")
    return ".".join(parts)


@FUZZ
@given(data=st.data())
def test_bad_set_syntax(data: st.DataObject, capsys: pytest.CaptureFixture[str]) -> None:
    """No ``=``, empty key parts (``=1``, ``a..b=1``, ``.seed=1``) and a value that is two
    TOML values (``1\\nseed = 2``) are refused, never read as something else."""
    leaf = data.draw(st.sampled_from(PLAIN))
    kind = data.draw(st.sampled_from(["no-eq", "empty-part", "two-values", "empty-key"]))
    if kind == "no-eq":
        item = data.draw(st.text(max_size=12).filter(lambda s: "=" not in s)) or leaf.key
        want = "expected KEY=VALUE"
    elif kind == "empty-part":
        item = _with_empty_part(leaf.key, data.draw(st.integers(0, 5))) + "=1"
        want = "empty part"
    elif kind == "empty-key":
        item = data.draw(st.sampled_from(["", " ", ".", ".."])) + "=1"
        want = "empty part"
    else:
        item = f"{leaf.key}={toml_inline(_get(DEFAULT, leaf.key))}\nseed = 2"
        want = "more than one TOML value"
    with pytest.raises(C.ConfigError, match=want):
        C.parse_set_items([item])
    rc, err = through_cli([f"--set={item}"], capsys)
    assert rc == 2 and want in error_line(err, "--set")


@FUZZ
@given(text=st.text(max_size=12))
def test_bare_string_values(text: str, capsys: pytest.CaptureFixture[str]) -> None:
    """A ``--set`` value that is not TOML is a bare string: fine for a string key with that
    choice, refused everywhere else, never silently turned into something else."""
    for leaf in (next(lf for lf in PLAIN if lf.key == "controller.type"),
                 next(lf for lf in PLAIN if lf.key == "wind.speed_mps")):
        rc, err = through_cli(["--set", f"{leaf.key}={text}"], capsys)
        try:
            items = C.parse_set_items([f"{leaf.key}={text}"])
        except C.ConfigError:  # a value that is several TOML values
            assert rc == 2 and "more than one TOML value" in error_line(err, "--set")
            continue
        v = items[leaf.key]
        ok = allowed(leaf, v)
        assert rc == (0 if ok else 2), (text, err)
        if ok:
            assert _get(C.load_config(None, items), leaf.key) == landed(leaf, v)
        else:
            error_line(err, leaf.key)


def test_set_merges_into_file_tables(tmp_path: Path) -> None:
    """``--set mission={...}`` over a file's [mission] keeps the file's other mission keys."""
    p = tmp_path / "m.toml"
    p.write_text("[mission]\nspeed_mps = 3.0\n")
    cfg = C.load_config(p, C.parse_set_items(["mission={swath_m = 4}", "seed=7"]))
    assert (cfg.mission.speed_mps, cfg.mission.swath_m, cfg.seed) == (3.0, 4.0, 7)
    p.write_text("mission = 3\n")
    with pytest.raises(C.ConfigError, match=r"^mission = 3: expected a table"):
        C.load_config(p, {"mission.swath_m": 4.0})


# ------------------------------------------------------------------------------ gps.overrides
GOOD_OVERRIDES = [{}, {"rate_hz": 5.0}, {"latency_s": 0.05}, {"axis_scale": [1.0, 1.0, 2.0]},
                  {"outage": {"mean_up_s": 30.0, "mean_down_s": 2.0}}]
NOT_NUMBERS = [math.nan, math.inf, -math.inf, "x", True, [1.0], {"a": 1.0}]


@st.composite
def bad_overrides(draw: st.DrawFn, preset: str) -> dict[str, Any]:
    """Overrides bad for any preset: unknown keys, NaN/inf/strings for numbers, tables where a
    number is due and back, unknown or badly typed component keys, NaN sigmas."""
    comps = gps_preset(preset)["components"]
    kind = draw(st.sampled_from(["unknown", "top-number", "axis", "outage", "comp"]))
    if kind == "unknown" or (kind == "comp" and not comps):
        name = draw(NAME.filter(lambda n: n not in
                                {"rate_hz", "latency_s", "axis_scale", "components", "outage"}))
        return {name: draw(st.integers(0, 5))}
    if kind == "top-number":
        return {draw(st.sampled_from(["rate_hz", "latency_s"])): draw(st.sampled_from(
            NOT_NUMBERS + [-1.0, 0.0 - 5]))}
    if kind == "axis":
        return {"axis_scale": draw(st.sampled_from(["x", 3.0, [1.0, 1.0], [1.0, 1.0, math.nan],
                                                    [1.0, -1.0, 1.0], {"x": 1.0}]))}
    if kind == "outage":
        return {"outage": draw(st.sampled_from([5, "x", {"mean_up_s": math.nan,
                                                         "mean_down_s": 1.0},
                                                {"mean_up_s": 1.0, "mean_down_s": 1.0,
                                                 "bogus": 1}]))}
    comp = draw(st.sampled_from(comps))
    numeric = sorted(k for k, x in comp.items() if _number(x))
    how = draw(st.sampled_from(["nan", "unknown", "axis", "not-table"]))
    if how == "nan" and numeric:
        body: Any = {draw(st.sampled_from(numeric)): draw(st.sampled_from(NOT_NUMBERS))}
    elif how == "axis":
        body = {"axis_scale": "x"}
    elif how == "not-table":
        body = draw(st.sampled_from([3, "x", [1.0]]))
    else:
        body = {draw(NAME.filter(lambda n: n not in comp)): 1.0}
    return {"components": {comp["name"]: body}}


@FUZZ
@given(data=st.data())
def test_gps_overrides(data: st.DataObject, capsys: pytest.CaptureFixture[str]) -> None:
    preset = data.draw(st.sampled_from(C.GPS_PRESETS), label="preset")
    good = data.draw(st.booleans(), label="good")
    ov = data.draw(st.sampled_from(GOOD_OVERRIDES) if good else bad_overrides(preset),
                   label="overrides")
    items = [f"gps.preset={toml_inline(preset)}", f"gps.overrides={toml_inline(ov)}"]
    rc, err = through_cli(["--set", items[0], "--set", items[1]], capsys)
    if good:
        assert rc == 0, err
        cfg = C.load_config(None, C.parse_set_items(items))
        assert cfg.gps.overrides == ov and cfg.gps.preset == preset
    else:
        assert rc == 2, f"bad gps.overrides accepted silently: {ov!r} ({preset})"
        assert error_line(err, "gps.overrides").startswith("gps.overrides = ")


def test_config_prints_loadable_toml_for_any_override_keys() -> None:
    """``ag-uav config`` printed ``{ my comp = ... }`` (not TOML) for a component named with a
    space; every accepted config must print back to itself."""
    ov = {"components": {"my comp": {"type": "gaussian", "sigma": 0.5},
                         'é"x': {"type": "laplace", "sigma": 0.5}}}
    cfg = C.config_from_dict({"gps": {"preset": "sbas", "overrides": ov}})
    assert C.config_from_dict(tomllib.loads(C.config_toml_with_comments(cfg))) == cfg


def test_known_gps_override_holes() -> None:
    """The inputs that exposed the holes, pinned (and a rate set twice: one would win)."""
    for ov in ('{axis_scale="x"}', '{components={white={sigma=nan}}}', "{bogus=1}",
               '{components={white={axis_scale="x"}}}'):
        with pytest.raises(C.ConfigError, match=r"^gps\.overrides = "):
            C.load_config(None, C.parse_set_items(["gps.preset=sbas", f"gps.overrides={ov}"]))
    with pytest.raises(C.ConfigError, match=r"^gps\.overrides\.rate_hz = 10\.0: conflicts"):
        C.config_from_dict({"gps": {"rate_hz": 5.0, "overrides": {"rate_hz": 10.0}}})
    assert C.config_from_dict({"gps": {"rate_hz": 5.0, "overrides": {"rate_hz": 5.0}}})
    with pytest.raises(C.ConfigError, match="gps.multipath_prob"):
        C.config_from_dict({"gps": {"multipath_prob": 0.1,
                                    "overrides": {"components": [{"type": "gaussian",
                                                                  "sigma": 1.0}]}}})


# ---------------------------------------------------------------------------- mission.field
@FUZZ
@given(name=st.one_of(st.sampled_from(["default", "l-shape", "hole", "L_Shape", " hole "]),
                      st.text(max_size=10), st.text(max_size=6).map(lambda s: s + ".geojson")))
def test_mission_field(name: str, capsys: pytest.CaptureFixture[str]) -> None:
    from ag_uav.world.field import BUILTIN_FIELDS

    ok = name.strip().lower().replace("_", "-") in BUILTIN_FIELDS or (
        name.endswith(".geojson") and "\x00" not in name and Path(name).is_file())
    rc, err = through_cli(["--set", f"mission.field={toml_inline(name)}"], capsys)
    assert rc == (0 if ok else 2), (name, err)
    if not ok:
        assert "allowed: default, l-shape, hole" in error_line(err, "mission.field")


def test_mission_field_directory(tmp_path: Path) -> None:
    d = tmp_path / "dir.geojson"
    d.mkdir()
    with pytest.raises(C.ConfigError, match="is a directory"):
        C.config_from_dict({"mission": {"field": str(d)}})


# --------------------------------------------------------------------------------- files
@FUZZ
@given(raw=st.one_of(st.binary(max_size=40),
                     st.text(max_size=30).map(lambda s: s.encode("utf-8")),
                     st.sampled_from([b"\xff\xfe[mission]\n", b"seed = 1\n\x80", b"[mission\n",
                                      b"seed = \n", b"seed = 1\nseed = 2\n", b"\xef\xbb\xbfseed=1",
                                      b"[mission]\n[mission]\n", b"a.b.c = 1\n"])))
def test_any_file_bytes(raw: bytes, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """Any bytes as a config file: accepted (then it was valid TOML of valid keys) or one line,
    exit 2; never a traceback."""
    path = tmp_path / "raw.toml"
    path.write_bytes(raw)
    rc, err = through_cli(["--config", str(path)], capsys)
    try:
        text = raw.decode("utf-8")
    except UnicodeDecodeError:
        assert rc == 2 and "not UTF-8" in error_line(err, str(path))
        return
    try:
        doc = tomllib.loads(text)
    except tomllib.TOMLDecodeError:
        assert rc == 2 and "not valid TOML" in error_line(err, str(path))
        return
    if rc == 0:
        assert C.load_config(path).to_dict() == C.config_from_dict(doc).to_dict()
    else:
        assert rc == 2
        error_line(err, "")


def test_missing_and_unreadable_files(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    for p, why in ((tmp_path / "nope.toml", "no such file"), (tmp_path, "a directory")):
        rc, err = through_cli(["--config", str(p)], capsys)
        assert rc == 2 and why in error_line(err, str(p))


def test_seed_flag(capsys: pytest.CaptureFixture[str]) -> None:
    """``--seed N`` is checked like ``--set seed=N`` (was argparse's two-line usage error for
    ``1.5``, and an unbounded integer)."""
    for seed, ok in (("0", True), (str(2**63 - 1), True), ("-1", False), (str(2**63), False),
                     (str(2**70), False), ("1.5", False), ("abc", False), ("nan", False)):
        rc, err = through_cli([f"--seed={seed}"], capsys)
        assert rc == (0 if ok else 2), (seed, err)
        if ok:
            assert C.load_config(None, cli._overrides(cli.build_parser().parse_args(
                ["config", f"--seed={seed}"]))).seed == int(seed)
        else:
            error_line(err, "seed")


@pytest.mark.parametrize("cmd", ["batch", "tune"])
def test_spec_files_not_utf8(cmd: str, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    p = tmp_path / "spec.toml"
    p.write_bytes(b'name = "x"\n\xff\n')
    assert cli.main([cmd, str(p)]) == 2
    assert "not UTF-8" in error_line(capsys.readouterr().err, f"{cmd} spec")


# ------------------------------------------------------------------ the real command, a few times
REAL = [  # (argv, key the message must name); run side by side, one process each
    (["fly", "--no-log", "-q", "--set", 'gps.overrides={axis_scale="x"}'], "gps.overrides"),
    (["config", "--set", b"controller.type=\xff\n"], "controller.type"),  # not UTF-8, newline
    (["config", "--config", "BADFILE"], "config file"),  # not UTF-8
]


def test_real_command_exit_2_one_line(tmp_path: Path) -> None:
    bad = tmp_path / "bad.toml"
    bad.write_bytes(b"[mission]\nswath_m = 4\n\xff\xfe\n")
    env = {**os.environ, "PYTHONPATH": str(Path(C.__file__).parents[2])}
    procs = [subprocess.Popen([sys.executable, "-m", "ag_uav.cli",
                               *[str(bad) if a == "BADFILE" else a for a in argv]],
                              stdout=subprocess.PIPE, stderr=subprocess.PIPE, cwd=tmp_path,
                              env=env) for argv, _ in REAL]
    for p, (argv, key) in zip(procs, REAL, strict=True):
        out, err = p.communicate(timeout=120)
        assert p.returncode == 2, (argv, err)
        assert out == b"", argv
        error_line(err.decode("utf-8"), key)


@pytest.mark.parametrize("key, value, needle", [
    ("vehicle.mass_kg", 1e300, r"must be between -1e\+09 and 1e\+09"),  # ZeroDivisionError
    ("vehicle.payload_kg", 1e300, "must be between"),  # ZeroDivisionError in flight
    ("gps.radar_sigma_m", 1e300, "must be between"),  # OverflowError in flight
    ("imu.vibration_sigma_mps2", 1e300, "must be between"),  # NaN RMSE (old imu_sigma_mps2)
    ("sim.hover_after_s", 1e6, "must be <= 3600"),  # a reference of 1e8 samples: a hang
    ("mission.speed_mps", 1e-6, "must be >= 0.5"),  # a 1.4 TiB reference: ArrayMemoryError
    ("mission.accel_max_mps2", 1e-9, "must be >= 0.05"),  # 13 GB and counting
    ("sim.timestep_s", 1e-7, "must be >= 1e-05"),  # 5e7 physics steps for 5 s: a hang
    ("sim.control_hz", 0.002, "must be >= 1"),  # one control update per 500 s, silently
    ("mission.direction_deg", math.nan, "expected a finite number"),
    ("seed", 2**70, "64-bit"),
    ("estimator.shadow", ["kf", "kf"], "appears twice"),
    ("log.cameras", ["down", "down"], "appears twice"),
    ("estimator.shadow", ["true"], "allowed: kf"),
])
def test_pinned_holes(key: str, value: Any, needle: str) -> None:
    """Inputs that were accepted (and then crashed, hung or ran wrong), pinned."""
    with pytest.raises(C.ConfigError, match=needle) as e:
        C.load_config(None, {key: value})
    assert str(e.value).startswith((f"{key} = ", f"{key}["))
