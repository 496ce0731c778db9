"""The helper process of :mod:`ag_uav.jobs.warm`: ``python -m ag_uav.jobs.warm_helper FOLDER``
compiles the MCKF's update (:func:`ag_uav.jobs.warm.compile_mckf_row`) and writes
``FOLDER/``:data:`~ag_uav.jobs.warm.MCKF_DONE`, then flies ``FOLDER/config.toml`` with
:data:`ag_uav.jobs.warm.HELPER_OVERRIDES` into ``FOLDER``, at low priority, so that the kernels
it runs land in numba's cache."""

from __future__ import annotations

import contextlib
import os
import sys
from pathlib import Path


def main(folder: str) -> None:
    """The MCKF's update, then the run's config on the true state, briefly, into ``folder``."""
    with contextlib.suppress(OSError, AttributeError):
        os.nice(10)  # the run comes first where cores are short
    from .warm import MCKF_DONE, compile_mckf_row

    compile_mckf_row()
    (Path(folder) / MCKF_DONE).touch()
    from ..config import load_config
    from .run import fly
    from .warm import HELPER_OVERRIDES

    cfg = load_config(Path(folder) / "config.toml", dict(HELPER_OVERRIDES))
    fly(cfg, out_root=folder, run_id="helper", progress=False, log_writer="inline")


if __name__ == "__main__":
    main(sys.argv[1])
