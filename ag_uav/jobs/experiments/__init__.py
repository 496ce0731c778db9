"""Experiment commands (``ag-uav experiment NAME``): one module per experiment.

Each module defines ``NAME`` (the sub-command), ``HELP`` (one line), ``add_arguments(parser)``
and ``main(args) -> int``. Add a module name to :data:`MODULES` to register it.
"""

MODULES = ("numerical", "table2", "bearing_tracking", "route_prediction", "langevin",
           "outage", "controllers", "swath", "spray_settings", "ins_nav", "optimisers",
           "drift", "wind_tunnel")


def float_list(s: str) -> list[float]:
    """A comma-separated list of numbers (``"2,3,4"``) as floats; empty items are skipped."""
    return [float(v) for v in s.split(",") if v.strip()]


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
