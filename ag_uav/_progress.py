"""Progress bars for long work (a flight, a batch, a tuning job, an experiment): ``tqdm`` on a
terminal as usual; when standard error is not a terminal (a batch job's log file, CI) the bar
redraws at most every :data:`PIPE_INTERVAL_S` seconds, so a log of a four-hour job holds a few
hundred progress lines, not tens of thousands."""

from __future__ import annotations

import sys
from typing import Any

#: seconds between two redraws of a bar whose output is not a terminal
PIPE_INTERVAL_S = 30.0


def progress_bar(*, file: Any = None, **kw: Any) -> Any:
    """``tqdm(**kw)`` writing to ``file`` (default standard error), with the redraw interval
    of a log file when ``file`` is not a terminal."""
    from tqdm import tqdm

    f = sys.stderr if file is None else file
    isatty = getattr(f, "isatty", None)
    if not (callable(isatty) and isatty()):
        kw["mininterval"] = max(float(kw.get("mininterval", 0.1)), PIPE_INTERVAL_S)
        kw["dynamic_ncols"] = False
    return tqdm(file=f, **kw)
