"""One run end to end: config → run folder → (log + renderer) → simulate → summary.json (and
dose.npz, the dose map on the ground). The summary and the log's metadata say which code flew
the run (:func:`ag_uav.jobs.provenance.provenance`: version and source hash)."""

from __future__ import annotations

import contextlib
import json
import re
import sys
import time
from pathlib import Path
from typing import Any

from ..config import Config
from ..engine.missions import RunResult, simulate
from .provenance import provenance

#: how :func:`ag_uav.engine.warm.start` runs the first run's helper process (after the
#: interpreter; its folder appended): this module, flying with :func:`fly` (:func:`_warm_helper`)
WARM_HELPER = ("-m", "ag_uav.jobs.run", "--warm-helper")


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


def summary_json(summary: dict) -> str:
    """A run summary as the JSON text of ``summary.json``."""
    return json.dumps(summary, indent=2, default=_json_default)


def write_summary(summary: dict, path: Path) -> None:
    """``summary.json``, written atomically (:mod:`ag_uav.record.atomic`)."""
    from ..record.atomic import atomic_write_text

    atomic_write_text(path, summary_json(summary))


def write_dose(dose: Any, path: Path) -> None:
    """``dose.npz`` (:meth:`ag_uav.world.deposition.DoseMap.arrays`), written atomically."""
    import numpy as np

    from ..record.atomic import atomic_path

    with atomic_path(path) as tmp, open(tmp, "wb") as f:
        np.savez_compressed(f, **dose.arrays())


class RunOutputError(OSError):
    """The flight finished but an output could not be written (summary.json, the end of the
    log): ``result`` and ``run_dir`` hold what was flown, ``summary_written`` says whether
    ``summary.json`` made it to disk.  Same errno, message and file name as the cause."""

    def __init__(self, err: OSError, result: RunResult, run_dir: Path, summary_written: bool):
        super().__init__(err.errno, err.strerror or str(err), err.filename)
        self.result, self.run_dir, self.summary_written = result, run_dir, summary_written


def _open_log(cfg: Config, run_dir: Path, writer: str = "process"):
    if not (cfg.log.enabled and cfg.log.channels != "none"):
        return None
    from .. import __version__
    from ..record.runlog import RunLog

    rates = {"camera": cfg.log.render_hz if cfg.log.render else 0.0}
    return RunLog(run_dir / "run.mcap", channels=cfg.log.channels, rates=rates,
                  metadata={"run_id": run_dir.name, "seed": cfg.seed,
                            "ag_uav": __version__, "source_hash": provenance()["source_hash"],
                            "field": cfg.mission.field,
                            "estimator": cfg.estimator.name},
                  config_toml=cfg.to_toml(), writer=writer)


def fly(cfg: Config, *, out_root: str | Path = "runs", run_id: str | None = None,
        progress: bool = False, feedback=None, log_writer: str = "process",
        overwrite: bool = False, helper: bool = True) -> tuple[RunResult, Path]:
    """Fly ``cfg`` once into ``out_root/run_id``; returns the result and the run folder.
    ``log_writer``: the run log's writer (:class:`ag_uav.record.runlog.RunLog`'s ``writer``:
    ``"process"``, its own process on another core, or ``"inline"``).

    The run folder belongs to this run (:mod:`ag_uav.jobs.outdir`): without ``run_id`` a new
    one is made (time, field, seed, and a counter suffix where that name is taken); a folder
    another run is writing into raises :class:`~ag_uav.jobs.outdir.FolderInUse`, and one that
    holds a previous run's outputs raises :class:`~ag_uav.jobs.outdir.RunFolderExists` unless
    ``overwrite`` (which removes them first).  ``run_id`` is a folder name, not a path
    (:func:`~ag_uav.jobs.outdir.check_run_id`: a separator, ``.``/``..`` or an absolute path
    raises :class:`~ag_uav.config.ConfigError`).

    A log that cannot be written mid-flight (disk full) stops the flight with an
    :class:`OSError` naming it (the log stays readable up to its last complete chunk); a
    finished flight whose log end or ``summary.json`` cannot be written raises
    :class:`RunOutputError`, which carries the result.

    ``helper``: on an empty kernel cache, compile the INS first, here (after the field is
    loaded: a bad field is refused at once), and the kernels the INS does not need in a helper
    process on another core meanwhile (:mod:`ag_uav.engine.warm`; a batch, whose workers keep
    every core busy, says False). The helper dies with this process, and a helper's folder left
    by a run that was killed is removed here (:func:`ag_uav.engine.warm.sweep`)."""
    from .outdir import check_reuse, check_run_id, hold, unique_run_dir

    if run_id is not None:
        check_run_id(run_id)
    run_dir = (Path(out_root) / run_id if run_id else
               unique_run_dir(out_root, default_run_id(cfg)))
    with hold(run_dir, "run", "wait for it to finish, or choose another --run-id"):
        check_reuse(run_dir, overwrite)
        return _fly_into(cfg, run_dir, progress, feedback, log_writer, helper)


def _fly_into(cfg: Config, run_dir: Path, progress: bool, feedback,
              log_writer: str, helper: bool = True) -> tuple[RunResult, Path]:
    from ..engine import warm

    w = None
    if helper:  # the folders of helpers whose runs were killed (SIGKILL) before removing them
        warm.sweep()
    if helper and feedback is None and warm.wanted(cfg):  # an empty kernel cache
        from ..world.mission import build_field

        build_field(cfg)  # a bad field is said at once, not after the compile
        w = warm.start(cfg, WARM_HELPER)
    try:
        if w is not None:  # the INS here while the helper compiles what comes before it
            _compile_ins_ahead(progress, w)
        return _fly_logged(cfg, run_dir, progress, feedback, log_writer)
    finally:
        warm.stop(w)


def _compile_ins_ahead(progress: bool, w: Any) -> None:
    """:func:`warm.compile_ins` with the compile notice, and a line that counts and names the
    kernels as they compile (``progress``)."""
    from tqdm import tqdm

    from ..engine import warm
    from ..engine.compiling import compile_notice

    with tqdm(total=0, desc="compiling the INS", bar_format="{desc}{postfix}", leave=False,
              disable=not progress, file=sys.stderr) as bar, \
            compile_notice(bar if progress else None, ahead=True):
        warm.compile_ins(w)


def _fly_logged(cfg: Config, run_dir: Path, progress: bool, feedback,
                log_writer: str) -> tuple[RunResult, Path]:
    log = _open_log(cfg, run_dir, log_writer)
    try:
        res = simulate(cfg, feedback=feedback, progress=progress, log=log)
    except BaseException as e:
        err = log.write_error(e) if log is not None else None
        if log is not None:
            with contextlib.suppress(Exception):  # the first error is the one to report
                log.close()
        if err is not None:
            raise err from None
        raise
    log_err = None
    if log is not None:
        try:
            log.close()
        except OSError as e:
            log_err = e
        log_err = log.lost or log_err
    if log_err is not None:  # the summary says so too (a log that stops early is no success)
        from ..record.atomic import disk_error_line

        res.summary["log_error"] = (f"the log stops at t = {log.lost_at:.1f} s: "
                                    if log.lost is not None else "") + disk_error_line(log_err)
    res.summary["run_dir"] = str(run_dir)
    res.summary.update(provenance())  # which code flew it: version and source hash
    try:  # the summary first: on a full disk it is the file that must not be lost
        write_summary(res.summary, run_dir / "summary.json")
        if res.extra.get("dose") is not None:  # the dose map, for `ag-uav plot`
            write_dose(res.extra["dose"], run_dir / "dose.npz")
    except OSError as e:
        raise RunOutputError(e, res, run_dir, False) from None
    if log_err is not None:
        raise RunOutputError(log_err, res, run_dir, True) from None
    return res, run_dir


def _helper_flight(cfg: Config, folder: Path) -> None:
    fly(cfg, out_root=folder, run_id="helper", progress=False, log_writer="inline")


def _warm_helper(folder: str) -> None:
    """The first run's helper process (:func:`ag_uav.engine.warm.helper.run_helper`), flying
    into ``folder/helper`` with :func:`fly` (its log written inline: one core is the point)."""
    from ..engine.warm.helper import run_helper

    run_helper(folder, _helper_flight)


if __name__ == "__main__":
    if len(sys.argv) != 3 or sys.argv[1] != "--warm-helper":
        print("usage: python -m ag_uav.jobs.run --warm-helper FOLDER (the first run's helper "
              "process, which a run starts itself)", file=sys.stderr)
        sys.exit(2)
    _warm_helper(sys.argv[2])
