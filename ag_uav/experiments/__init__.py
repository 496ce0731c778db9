"""Experiment commands (``ag-uav experiment NAME``): one module per experiment.

Each module defines ``NAME`` (the sub-command), ``HELP`` (one line), ``add_arguments(parser)``
and ``main(args) -> int``. Add a module name to :data:`MODULES` to register it.
"""

MODULES = ("numerical", "table2", "bearing_tracking", "route_prediction", "langevin",
           "outage", "controllers")


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
