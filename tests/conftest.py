"""Settings for the whole suite.

The first run's helper process (:mod:`ag_uav.jobs.warm`) is off here: the suite's workers already
keep every core busy, so a helper would only contend with them (``AG_UAV_WARM=0`` unless the
environment sets it). ``tests/test_warm.py`` turns it on where it tests it."""

import os

os.environ.setdefault("AG_UAV_WARM", "0")
