"""Looking at a run after the fact, from its MCAP log alone.

    show(run)            -> str          metadata, config, metrics, channels with counts and rates
    plot(run, out_dir)   -> list[Path]   map.png (field, plan, sprayed area, true and estimated
                                         tracks, GPS fixes), dose.png (the dose on the ground,
                                         from dose.npz beside the log or the last ``/dose``
                                         grid), errors.png, controller.png, estimators.png
    video(run, out_mp4, camera=None) -> Path   MP4 from the logged JPEG frames (imageio-ffmpeg)
    recover(in_path, out_path) -> ScanReport   rewrite a truncated or damaged log into a
                                         finished, indexed MCAP; messages kept and lost
    write_foxglove_layout(path, ...)     Foxglove layout (app-export JSON: Layouts -> Import from
                                         file) with 3D, camera images and plots
    read_run(run)        -> RunData      decoded channels as numpy arrays (what the above use)

``run`` is a run folder (``runs/<id>/``, containing ``run.mcap``) or the ``.mcap`` file itself.
Everything reads with the ``mcap`` package (+ ``mcap-protobuf-support`` to decode), chunk by
chunk in file order (:mod:`ag_uav.analysis.logscan`): a file that was never finished (no footer),
was cut short or has damaged chunks is read as far as it is intact, and what was skipped is
reported (:func:`skipped_line`); an empty or non-MCAP file raises ``NotMcapError``.  Every output
(plots, video, recovered log, layout) is written atomically (:mod:`ag_uav.record.atomic`).
"""

from __future__ import annotations

from ..record.layout import write_foxglove_layout
from .logscan import LogError, NotMcapError
from .plots import plot
from .recover import recover
from .rundata import PLOT_POINTS, RunData, mcap_path, read_run, read_summary, show, skipped_line
from .video import video

__all__ = [
    "RunData",
    "read_run",
    "read_summary",
    "show",
    "plot",
    "video",
    "recover",
    "write_foxglove_layout",
    "mcap_path",
    "skipped_line",
    "PLOT_POINTS",
    "LogError",
    "NotMcapError",
]
