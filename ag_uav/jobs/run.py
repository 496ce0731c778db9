"""One run end to end: config → run folder → (log + renderer) → simulate → summary.json."""

from __future__ import annotations

import json
import re
import time
from pathlib import Path
from typing import Any

from ..config import Config
from ..engine.missions import RunResult, simulate


def default_run_id(cfg: Config) -> str:
    field = re.sub(r"[^A-Za-z0-9_-]+", "_", Path(cfg.mission.field).stem)
    return f"{time.strftime('%Y%m%d-%H%M%S')}-{field}-s{cfg.seed}"


def _json_default(o: Any) -> Any:
    try:
        import numpy as np

        if isinstance(o, np.generic):
            return o.item()
        if isinstance(o, np.ndarray):
            return o.tolist()
    except ImportError:  # pragma: no cover
        pass
    raise TypeError(type(o))


def write_summary(summary: dict, path: Path) -> None:
    tmp = path.with_suffix(".json.tmp")
    tmp.write_text(json.dumps(summary, indent=2, default=_json_default))
    tmp.replace(path)


def fly(cfg: Config, *, out_root: str | Path = "runs", run_id: str | None = None,
        progress: bool = False, feedback=None) -> tuple[RunResult, Path]:
    """Fly ``cfg`` once into ``out_root/run_id``; returns the result and the run folder."""
    run_dir = Path(out_root) / (run_id or default_run_id(cfg))
    run_dir.mkdir(parents=True, exist_ok=True)
    log = None
    if cfg.log.enabled and cfg.log.channels != "none":
        from .. import __version__
        from ..record.runlog import RunLog

        rates = {"camera": cfg.log.render_hz if cfg.log.render else 0.0}
        log = RunLog(run_dir / "run.mcap", channels=cfg.log.channels, rates=rates,
                     metadata={"run_id": run_dir.name, "seed": cfg.seed,
                               "ag_uav": __version__, "field": cfg.mission.field,
                               "estimator": cfg.estimator.name},
                     config_toml=cfg.to_toml())
    try:
        res = simulate(cfg, feedback=feedback, progress=progress, log=log)
    finally:
        if log is not None:
            log.close()
    res.summary["run_dir"] = str(run_dir)
    write_summary(res.summary, run_dir / "summary.json")
    return res, run_dir
