"""One run end to end: config → run folder → (log + renderer) → simulate → summary.json."""

from __future__ import annotations

import json
import re
import time
from pathlib import Path
from typing import Any

from .config import Config
from .sim import RunResult, simulate


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
    log = renderer = None
    notes: list[str] = []
    try:
        if cfg.log.enabled and cfg.log.channels != "none":
            from .logging_setup import open_log_and_renderer

            log, renderer, notes = open_log_and_renderer(cfg, run_dir)
    except ModuleNotFoundError:
        log = renderer = None
    try:
        res = simulate(cfg, feedback=feedback, progress=progress, log=log, renderer=renderer)
    finally:
        if log is not None:
            log.close()
        if renderer is not None:
            renderer.close()
    res.summary["run_dir"] = str(run_dir)
    if notes:
        res.summary["notes"] = notes
    write_summary(res.summary, run_dir / "summary.json")
    return res, run_dir
