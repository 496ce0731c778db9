"""Experiment commands (``ag-uav experiment NAME``): one module per experiment.

Each module defines ``NAME`` (the sub-command), ``HELP`` (one line), ``add_arguments(parser)``
and ``main(args) -> int``. Add a module name to :data:`MODULES` to register it.

An experiment's axes (``--heights 2,3,4``, ``--spectra fine,coarse``) are read with
:func:`number_axis` / :func:`name_axis` and, where they are mission settings, checked against
the config's own rules with :func:`check_on_config`: an empty, non-numeric, negative or
out-of-envelope axis is one line and exit 2, like a bad config key.
"""

import math
from collections.abc import Iterable
from typing import Any

MODULES = ("numerical", "table2", "bearing_tracking", "route_prediction", "langevin",
           "outage", "controllers", "swath", "spray_settings", "ins_nav", "optimisers",
           "drift", "wind_tunnel", "vehicles")


def number_axis(flag: str, text: str, *, lo: float | None = None, lo_open: bool = False,
                hi: float | None = None, inf: bool = False) -> list[float]:
    """An experiment axis ``"2,3,4"`` as floats, checked like a config key: a
    :class:`~ag_uav.config.ConfigError` (one line naming ``flag``, the value and what is
    allowed) for an empty list, an item that is not a number, a non-finite one (``inf`` allows
    +inf), or one below ``lo`` (at or below, with ``lo_open``) or above ``hi``."""
    from ...config import ConfigError

    items = [v.strip() for v in str(text).split(",") if v.strip()]
    rule = ("numbers" + (f" {'>' if lo_open else '>='} {lo:g}" if lo is not None else "")
            + (f" and <= {hi:g}" if hi is not None else ""))
    if not items:
        raise ConfigError(f"{flag} = {text!r}: empty; expected comma-separated {rule}")
    out = []
    for v in items:
        try:
            x = float(v)
        except ValueError:
            raise ConfigError(f"{flag} = {text!r}: {v!r} is not a number; expected comma-"
                              f"separated {rule}") from None
        bad = (math.isnan(x) or (math.isinf(x) and not (inf and x > 0))
               or (lo is not None and (x < lo or (lo_open and x == lo)))
               or (hi is not None and x > hi))
        if bad:
            raise ConfigError(f"{flag} = {text!r}: {v} is out of range; expected {rule}"
                              + (" (or inf)" if inf else ""))
        out.append(x)
    return out


def name_axis(flag: str, text: str, allowed: Iterable[str]) -> list[str]:
    """An axis of names ``"fine,coarse"``: one line (ConfigError) for an empty list or a name
    not in ``allowed``."""
    from ...config import ConfigError

    allowed = list(allowed)
    items = [v.strip() for v in str(text).split(",") if v.strip()]
    bad = [v for v in items if v not in allowed]
    if bad or not items:
        what = f"{bad[0]!r} unknown" if bad else "empty"
        raise ConfigError(f"{flag} = {text!r}: {what}; allowed: {', '.join(allowed)} "
                          "(comma-separated)")
    return items


def check_on_config(flag: str, values: Iterable[Any], key: str, config: str | None = None,
                    sets: Iterable[str] = ()) -> None:
    """Each axis value set on the config key ``key`` of the base config (``config`` and its
    ``--set`` items), checked as ``ag-uav fly`` checks it: an experiment searches only what a
    flight accepts (the flight envelope: heights between ``spray.min_height_m`` and
    ``max_height_m``, speeds, winds, lane spacings within their keys' ranges).  A value the
    config refuses raises :class:`~ag_uav.config.ConfigError` naming ``flag`` and the key's
    rule."""
    from ...config import ConfigError, load_config, parse_set_items

    ov = parse_set_items(list(sets))
    for v in dict.fromkeys(values):
        try:
            load_config(config, {**ov, key: v})
        except ConfigError as e:
            raise ConfigError(f"{flag}: {v:g} is not a value `ag-uav fly` accepts: {e}"
                              ) from None


def toml_overrides(items: list[str]) -> dict:
    """``KEY=VALUE`` items (VALUE one TOML value) as a dict; lists become tuples (of tuples)."""
    import tomllib

    out: dict = {}
    for it in items:
        k, _, v = it.partition("=")
        out[k.strip()] = tomllib.loads(f"v = {v}")["v"]
        if isinstance(out[k.strip()], list):
            out[k.strip()] = tuple(tuple(x) if isinstance(x, list) else x
                                   for x in out[k.strip()])
    return out


def write_csv(path, rows) -> None:
    """Rows (dicts) to a CSV whose columns are every key, in first-seen order."""
    import csv
    from pathlib import Path

    keys: list[str] = []
    for r in rows:
        keys += [k for k in r if k not in keys]
    with Path(path).open("w", newline="") as fh:
        w = csv.DictWriter(fh, fieldnames=keys)
        w.writeheader()
        w.writerows(rows)


def add_batch_arguments(p, out: str) -> None:
    """The options of an experiment that runs as a batch job: ``--set``, ``--out``,
    ``--workers``, ``--dask``, ``--resume``, ``--fresh``, ``--quiet``."""
    p.add_argument("--set", action="append", default=[], metavar="KEY=VALUE",
                   help="override any config key of the base config (TOML value)")
    p.add_argument("--out", default=out, metavar="DIR", help="output folder")
    p.add_argument("--workers", "-j", type=int, default=None, help="worker processes "
                   "(default: CPU count)")
    p.add_argument("--dask", default=None, metavar="ADDR", help='"local" or tcp://host:port')
    p.add_argument("--resume", action="store_true", help="continue an interrupted run")
    p.add_argument("--fresh", action="store_true", help="discard an earlier run in --out")
    p.add_argument("--quiet", "-q", action="store_true", help="no progress bar")


def flight_axes(args: Any) -> tuple[list[float], list[float], list[float]]:
    """``--winds``, ``--heights``, ``--speeds`` of a deposition experiment (drift, swath) and its
    ``--mass``, checked against the default config's flight envelope (``wind.speed_mps``,
    ``mission.altitude_m`` between ``spray.min_height_m`` and ``max_height_m``,
    ``mission.speed_mps``, ``vehicle.mass_kg``); returns (winds, heights, speeds)."""
    winds = number_axis("--winds", args.winds, lo=0.0)
    heights = number_axis("--heights", args.heights, lo=0.0, lo_open=True)
    speeds = number_axis("--speeds", args.speeds, lo=0.0, lo_open=True)
    check_on_config("--winds", winds, "wind.speed_mps")
    check_on_config("--heights", heights, "mission.altitude_m")
    check_on_config("--speeds", speeds, "mission.speed_mps")
    if args.mass is not None:
        check_on_config("--mass", [args.mass], "vehicle.mass_kg")
    return winds, heights, speeds
