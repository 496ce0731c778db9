"""The helper process's side of :mod:`ag_uav.engine.warm`: :func:`run_helper` compiles the
MCKF's update (:func:`ag_uav.engine.warm.compile_mckf_row`) and writes
``FOLDER/``:data:`~ag_uav.engine.warm.MCKF_DONE` at the run's priority (the run waits for it),
then flies ``FOLDER/config.toml`` with :data:`ag_uav.engine.warm.HELPER_OVERRIDES` into
``FOLDER`` at low priority, so that the kernels it runs land in numba's cache. It ends with the
run that started it (:func:`ag_uav.engine.warm.die_with_parent`), whatever ends the run.

The flight itself (a logged run into a folder) is the caller's: the process is started with the
command :func:`ag_uav.engine.warm.start` is given, whose module calls :func:`run_helper` with
its own ``fly`` (``python -m ag_uav.jobs.run --warm-helper FOLDER``)."""

from __future__ import annotations

import contextlib
import os
from collections.abc import Callable
from pathlib import Path
from typing import Any


def run_helper(folder: str | Path, fly: Callable[[Any, Path], Any]) -> None:
    """The MCKF's update, then ``fly(cfg, folder)``: the run's config on the true state,
    briefly (:data:`~ag_uav.engine.warm.HELPER_OVERRIDES`), into ``folder``."""
    from . import HELPER_OVERRIDES, MCKF_DONE, compile_mckf_row, die_with_parent

    die_with_parent()
    folder = Path(folder)
    compile_mckf_row()  # what the run waits for: at the run's own priority
    (folder / MCKF_DONE).touch()
    with contextlib.suppress(OSError, AttributeError):
        os.nice(10)  # the rest: the run comes first where cores are short
    from ...config import load_config

    fly(load_config(folder / "config.toml", dict(HELPER_OVERRIDES)), folder)
