"""Settings for the whole suite.

The first run's helper process (:mod:`ag_uav.engine.warm`) is off in the tests: the suite's workers
already keep every core busy, so a helper would only contend with them (``AG_UAV_WARM=0`` unless
the environment sets it). ``tests/test_warm.py`` turns it on where it tests it.

With several workers (pytest-xdist) and an empty kernel cache, the default flight's kernels are
compiled once, before the workers start, by a short flight with that helper on (the first run's
two-process compile); each worker would otherwise compile them on its own."""

from __future__ import annotations

import os
import subprocess
import sys

import pytest

os.environ.setdefault("AG_UAV_WARM", "0")

_WARM_FLIGHT = """
import tempfile
from ag_uav.config import load_config
from ag_uav.jobs.run import fly
with tempfile.TemporaryDirectory() as out:
    fly(load_config(None, {"sim.max_time_s": 2.0, "log.render": False}), out_root=out,
        run_id="warm", progress=False)
"""


def pytest_configure(config: pytest.Config) -> None:
    if hasattr(config, "workerinput") or not getattr(config.option, "numprocesses", 0):
        return  # a worker, or no workers
    from ag_uav.engine import warm

    if warm._ins_kernel_cached():
        return
    print("compiling the flight kernels once for the workers (empty cache) ...", file=sys.stderr)
    rc = subprocess.run([sys.executable, "-c", _WARM_FLIGHT], check=False,
                        env={**os.environ, "AG_UAV_WARM": "1"},
                        stdout=subprocess.DEVNULL).returncode
    if rc:
        print(f"the warm-up flight failed (exit {rc}): each worker compiles on its own",
              file=sys.stderr)
