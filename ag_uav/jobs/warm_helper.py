"""The helper process of :mod:`ag_uav.jobs.warm`: ``python -m ag_uav.jobs.warm_helper FOLDER``
compiles the MCKF's update (:func:`ag_uav.jobs.warm.compile_mckf_row`) and writes
``FOLDER/``:data:`~ag_uav.jobs.warm.MCKF_DONE` at the run's priority (the run waits for it), then
flies ``FOLDER/config.toml`` with :data:`ag_uav.jobs.warm.HELPER_OVERRIDES` into ``FOLDER`` at
low priority, so that the kernels it runs land in numba's cache. It ends with the run that
started it (:func:`ag_uav.jobs.warm.die_with_parent`), whatever ends the run."""

from __future__ import annotations

import contextlib
import os
import sys
from pathlib import Path


def main(folder: str) -> None:
    """The MCKF's update, then the run's config on the true state, briefly, into ``folder``."""
    from .warm import MCKF_DONE, compile_mckf_row, die_with_parent

    die_with_parent()
    compile_mckf_row()  # what the run waits for: at the run's own priority
    (Path(folder) / MCKF_DONE).touch()
    with contextlib.suppress(OSError, AttributeError):
        os.nice(10)  # the rest: the run comes first where cores are short
    from ..config import load_config
    from .run import fly
    from .warm import HELPER_OVERRIDES

    cfg = load_config(Path(folder) / "config.toml", dict(HELPER_OVERRIDES))
    fly(cfg, out_root=folder, run_id="helper", progress=False, log_writer="inline")


if __name__ == "__main__":
    main(sys.argv[1])
