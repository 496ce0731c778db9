"""An MP4 of a run's logged camera frames (:func:`video`, imageio-ffmpeg), written atomically."""

from __future__ import annotations

import io
import math
from pathlib import Path

import numpy as np

from .rundata import RunData, run_data


def _frames(d: RunData, camera: str | None) -> list[tuple[float, bytes]]:
    """The logged frames of ``camera`` (default the first camera); LogError if none."""
    from .logscan import LogError

    if not d.images:
        raise LogError(f"{d.path}: no camera frames in this log (flown with --no-render, "
                       "log.render = false or a channel set without cameras)")
    names = sorted(t.removeprefix("/camera/") for t in d.images)
    topic = f"/camera/{camera}" if camera else f"/camera/{names[0]}"
    if topic not in d.images:
        raise LogError(f"--camera = {camera!r}: no frames of that camera in {d.path}; "
                       f"cameras: {', '.join(names)}")
    return d.images[topic]


def video(run: str | Path | RunData, out_mp4: str | Path, camera: str | None = None,
          fps: float | None = None) -> Path:
    """Encode the logged JPEG frames of one camera into an MP4 (H.264 via imageio-ffmpeg).

    ``camera``: the name used when logging (``/camera/<name>``); default the first camera.
    ``fps``: default the logged frame rate in sim time (so the video plays in real time).
    The MP4 is written atomically.  No frames, an unknown camera or ``fps`` not > 0 raise
    :class:`~ag_uav.analysis.logscan.LogError`.
    """
    import imageio.v2 as imageio
    from PIL import Image

    from ..record.atomic import atomic_path, silent_write_failure
    from .logscan import LogError

    if fps is not None and not (math.isfinite(fps) and fps > 0):
        raise LogError(f"--fps = {fps:g}: must be > 0 (or 0 for the logged rate)")
    frames = _frames(run_data(run, images=True), camera)
    if fps is None:
        ts = np.array([f[0] for f in frames])
        fps = (len(ts) - 1) / (ts[-1] - ts[0]) if len(ts) > 1 and ts[-1] > ts[0] else 10.0
    out = Path(out_mp4)
    first = np.asarray(Image.open(io.BytesIO(frames[0][1])).convert("RGB"))
    h, w = first.shape[:2]
    # H.264 wants even sizes; macro_block_size=1 keeps the size (pad if odd)
    pad_h, pad_w = h % 2, w % 2
    with atomic_path(out) as tmp:
        writer = imageio.get_writer(str(tmp), fps=float(fps), codec="libx264", quality=7,
                                    macro_block_size=1, pixelformat="yuv420p",
                                    ffmpeg_log_level="quiet")
        try:
            for _, jpg in frames:
                img = np.asarray(Image.open(io.BytesIO(jpg)).convert("RGB"))
                if pad_h or pad_w:
                    img = np.pad(img, ((0, pad_h), (0, pad_w), (0, 0)), mode="edge")
                writer.append_data(img)
        finally:
            writer.close()
        if not _mp4_complete(tmp):  # ffmpeg's exit status is not reported: check the file
            raise silent_write_failure(out, "ffmpeg did not finish the video")
    return out


def _mp4_complete(path: Path) -> bool:
    """Whether ``path`` is a whole MP4: top-level boxes (32-bit big-endian size, then the
    4-character type; size 1 = a 64-bit size follows; ISO/IEC 14496-12 section 4.2) that tile
    the file exactly, with an ``mdat`` and the ``moov`` ffmpeg writes last."""
    import struct

    seen, pos = set(), 0
    size = path.stat().st_size if path.exists() else 0
    if size == 0:
        return False
    with open(path, "rb") as f:
        while pos + 8 <= size:
            f.seek(pos)
            n, kind = struct.unpack(">I4s", f.read(8))
            if n == 1:
                (n,) = struct.unpack(">Q", f.read(8))
            if n < 8:
                return False
            seen.add(kind)
            pos += n
    return pos == size > 0 and {b"moov", b"mdat"} <= seen
