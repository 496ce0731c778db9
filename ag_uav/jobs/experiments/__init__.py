"""Experiment commands (``ag-uav experiment NAME``): one module per experiment.

Each module defines ``NAME`` (the sub-command), ``HELP`` (one line), ``add_arguments(parser)``
and ``main(args) -> int``. Add a module name to :data:`MODULES` to register it.
"""

MODULES = ("numerical", "table2", "bearing_tracking", "route_prediction", "langevin",
           "outage", "controllers", "swath", "spray_settings", "ins_nav", "optimisers",
           "drift")


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
