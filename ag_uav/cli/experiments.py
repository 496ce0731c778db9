"""``ag-uav experiment NAME``: the papers' experiments as one command each."""

from __future__ import annotations

import argparse
import importlib

from ..jobs.experiments import MODULES


def register(sub, load: bool = True) -> None:
    """``ag-uav experiment NAME``, each experiment with its own arguments; ``load=False``: the
    command alone, its experiments not imported (the command line holds no ``experiment``)."""
    p = sub.add_parser("experiment", help="reproduce a paper's experiment (see its --help)",
                       description="Reproduce a paper's experiment and print its table next to "
                                   "the paper's numbers. Every axis (--heights 2,3,4, --winds, "
                                   "...) is checked like a config key before anything runs: an "
                                   "empty list, a negative value or one outside what `ag-uav "
                                   "fly` accepts for the key it sets is one line and exit 2.")
    if not load:
        p.add_argument("name", nargs=argparse.REMAINDER, help=argparse.SUPPRESS)
        return
    esub = p.add_subparsers(dest="experiment", required=True, metavar="NAME")
    for name in MODULES:
        try:
            mod = importlib.import_module(f"ag_uav.jobs.experiments.{name}")
        except ModuleNotFoundError as e:
            if e.name != f"ag_uav.jobs.experiments.{name}":
                raise
            continue
        ep = esub.add_parser(mod.NAME, help=mod.HELP, description=mod.HELP,
                             formatter_class=argparse.ArgumentDefaultsHelpFormatter)
        mod.add_arguments(ep)
        ep.set_defaults(func=mod.main)
