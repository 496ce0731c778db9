"""Experiment commands (``ag-uav experiment NAME``): one module per experiment.

Each module defines ``NAME`` (the sub-command), ``HELP`` (one line), ``add_arguments(parser)``
and ``main(args) -> int``. Add a module name to :data:`MODULES` to register it.
"""

MODULES = ("numerical", "table2", "bearing_tracking", "route_prediction", "langevin",
           "outage")
