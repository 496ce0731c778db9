"""ag-uav: agricultural UAV simulator (MuJoCo quadrotor, coverage planning, IT2 fuzzy PID,
robust Kalman filters in the loop, MCAP logs).

Python API::

    import ag_uav
    cfg = ag_uav.load_config("mission.toml")   # or ag_uav.load_config() for the defaults
    result = ag_uav.simulate(cfg)
    result.summary["cross_track_rmse_m"]
"""

import os

os.environ.setdefault("MUJOCO_GL", "egl")  # off-screen renders; must precede `import mujoco`

from .config import Config, ConfigError, default_config, load_config

__version__ = "0.1.0"


def simulate(config: Config | None = None, **kwargs):
    """Fly ``config`` once (no files written); returns a
    :class:`~ag_uav.engine.missions.RunResult`."""
    from .engine.missions import simulate as _simulate

    return _simulate(config if config is not None else default_config(), **kwargs)


__all__ = ["Config", "ConfigError", "load_config", "default_config", "simulate", "__version__"]
