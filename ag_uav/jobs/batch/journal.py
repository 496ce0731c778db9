"""The batch journal: one JSON line per finished run, flushed and fsynced, read back by
``--resume`` (a torn or damaged line is skipped and counted)."""

from __future__ import annotations

import contextlib
import json
import os
import signal
import threading
from collections.abc import Iterator
from pathlib import Path
from typing import Any


# ------------------------------------------------------------------------------------ journal
class Journal:
    """Append-only JSONL of finished runs, one line per run, flushed and fsynced per line.

    Each line: ``{"hash": config_hash, "retry": bool, "row": {...}}``. A truncated last line
    (the process was killed mid-write) is ignored on reading; any other line that is not a
    journal record (damaged bytes, not UTF-8, not JSON) is skipped and counted in
    :attr:`skipped`, so ``--resume`` re-runs those runs and says how many lines it passed over.
    """

    def __init__(self, path: str | Path) -> None:
        self.path = Path(path)
        self._f = None
        self.skipped = 0

    def read(self) -> dict[str, dict[str, Any]]:
        """config hash → row, for the lines that are final (not marked ``retry``)."""
        done: dict[str, dict[str, Any]] = {}
        self.skipped = 0
        if not self.path.exists():
            return done
        recs, self.skipped = read_jsonl(self.path)
        for rec in recs:
            if not isinstance(rec.get("hash"), str) or not isinstance(rec.get("row"), dict):
                self.skipped += 1
            elif rec.get("retry"):
                done.pop(rec["hash"], None)
            else:
                done[rec["hash"]] = rec["row"]
        return done

    def open(self, fresh: bool = False) -> None:
        self.path.parent.mkdir(parents=True, exist_ok=True)
        if not fresh and self.path.exists():
            self._repair()
        self._f = self.path.open("w" if fresh else "a")

    def _repair(self) -> None:
        """Cut a torn last line so that the next append starts on a line of its own."""
        repair_jsonl(self.path)

    def append(self, h: str, row: dict[str, Any], retry: bool = False) -> None:
        assert self._f is not None, "journal not open"
        try:
            self._f.write(json.dumps({"hash": h, "retry": retry, "row": row},
                                     default=json_default) + "\n")
            self._f.flush()
            os.fsync(self._f.fileno())
        except OSError as e:  # ENOSPC, EIO, ...: name the journal
            raise OSError(e.errno, e.strerror or str(e), str(self.path)) from None

    def close(self) -> None:
        if self._f is not None:
            try:
                self._f.close()
            except OSError:  # a flush that failed was reported by append
                pass
            self._f = None


def read_jsonl(path: Path) -> tuple[list[dict[str, Any]], int]:
    """The JSON objects of a JSONL file, and how many lines were skipped as unreadable (bytes
    that are not UTF-8 or not a JSON object). A torn last line (no newline) is dropped
    without counting: it is what a kill mid-append leaves."""
    data = path.read_bytes()
    lines = data.split(b"\n")
    if lines and lines[-1] and not data.endswith(b"\n"):
        lines = lines[:-1]
    out: list[dict[str, Any]] = []
    bad = 0
    for raw in lines:
        if not raw.strip():
            continue
        try:
            rec = json.loads(raw.decode("utf-8"))
        except (UnicodeDecodeError, json.JSONDecodeError):
            rec = None
        if isinstance(rec, dict):
            out.append(rec)
        else:
            bad += 1
    return out, bad


def repair_jsonl(path: Path) -> None:
    """Cut a torn last line (no newline) so that the next append starts a line of its own."""
    data = path.read_bytes()
    if data and not data.endswith(b"\n"):
        with path.open("r+b") as f:
            f.truncate(data.rfind(b"\n") + 1)


@contextlib.contextmanager
def signals_held() -> Iterator[None]:
    """SIGTERM and SIGINT held back (delivered right after): a run's journal line and its row
    in memory, from which an interrupted batch writes ``results.csv``, are recorded together.

    Held at Python's level: a signal sent to the process may reach any of its threads (a pool's
    manager thread, a progress bar's), and Python runs its handler in the main thread at the
    next bytecode whichever thread the signal reached, so blocking it in the main thread alone
    (``pthread_sigmask``) does not hold it. Here the handlers are swapped for one that notes
    the signal, and the noted signals are raised again, to the handlers restored, at the end.
    Outside the main thread (where no handler can be set, and none runs), or with a handler
    set outside Python, it holds nothing."""
    got: list[int] = []
    sigs = (signal.SIGTERM, signal.SIGINT)
    if (threading.current_thread() is not threading.main_thread()
            or any(signal.getsignal(s) is None for s in sigs)):
        yield
        return
    old = [signal.signal(s, lambda signum, _frame: got.append(signum)) for s in sigs]
    try:
        yield
    finally:
        for s, h in zip(sigs, old, strict=True):
            signal.signal(s, h)
        for s in dict.fromkeys(got):
            signal.raise_signal(s)


def json_default(o: Any) -> Any:
    """``json.dumps``' ``default`` for rows: numpy scalars and arrays as Python values, anything
    else as its ``str``."""
    import numpy as np

    if isinstance(o, np.generic):
        return o.item()
    if isinstance(o, np.ndarray):
        return o.tolist()
    return str(o)
