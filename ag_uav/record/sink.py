"""The writing half of a run log: the foxglove-sdk MCAP writer, its channels and the block
encoders, fed a list of operations per flush by :class:`ag_uav.record.runlog.RunLog`.

:class:`Backend` executes the operations.  It runs either in the flying process
(:class:`InlineSink`) or in a writer process forked when the log opens (:class:`ProcessSink`,
the default where ``os.fork`` exists), so that a flush's encoding, compression and write to
the OS run on another core while the loop flies on: the loop only fills rows and, at each
flush, copies them into a shared-memory ring (:class:`_Ring`: a small pickle of the operations,
the rows as raw bytes; no system call, so no wake-up of the writer on the loop's core), which
the writer polls every millisecond.  PX4's logger (a writer thread fed from a ring buffer) and
ROS's bag recorder (its own process) split the work the same way; a Python thread cannot here,
because the SDK's calls hold the GIL.  Measured in docs/guides/foxglove.md.

The operations a hand-over carries are listed in :mod:`ag_uav.record.backend`.

Crash safety with the writer process: a SIGKILL of the flying process loses only the rows it
had not handed over (less than ``flush_sim_s`` of flight and one log tick); the writer reads
what is left in the ring, finishes the file (summary, indexes) and exits.  A SIGKILL of both (a
process group) loses also what the writer had not written out, at most one more hand-over.  A
writer that dies on its own is noticed within about a second (an OSError naming the log), and
its error (a full disk) is raised at the flight's next hand-over.
"""

from __future__ import annotations

import errno
import mmap
import os
import pickle
import select
import signal
import struct
import time
import warnings
from typing import Any

import numpy as np

from .backend import Backend

__all__ = ["Backend", "InlineSink", "ProcessSink", "WriterLost", "open_sink"]

_LEN = struct.Struct("<Q")
_F8 = np.dtype(np.float64)
_OPS = "\0ops"  # marks a framed list of operations (replies are tuples of strings)
#: pipes of the writer processes this process holds open (a forked writer closes the others')
_LIVE_FDS: set[int] = set()


class InlineSink:
    """The backend in this process: every hand-over is executed before it returns."""

    process = False
    cpu_s = 0.0  # its CPU time is the flying process's

    def __init__(self, path: str, compression: Any, chunk_size: int):
        self._back = Backend(path, compression, chunk_size)

    def send(self, ops: list[tuple[Any, ...]]) -> None:
        self._back.run(ops)

    def close(self) -> None:
        self._back.run([("close",)])


# ---------------------------------------------------------------------------- the process
def _write_all(fd: int, parts: list[Any]) -> None:
    """Write every byte of ``parts`` (bytes-like) to ``fd`` (one ``writev`` when it fits)."""
    views = [memoryview(p).cast("B") for p in parts]
    while views:
        n = os.writev(fd, views)
        while views and n >= len(views[0]):
            n -= len(views[0])
            views.pop(0)
        if n:
            views[0] = views[0][n:]


def _read_exact(fd: int, n: int) -> bytearray | None:
    """``n`` bytes from ``fd`` (blocking), or None at end of file."""
    buf = bytearray(n)
    view, got = memoryview(buf), 0
    while got < n:
        k = os.readv(fd, [view[got:]])
        if not k:
            return None
        got += k
    return buf


def _frame(obj: Any) -> list[Any]:
    """``obj`` (a list of operations, or a reply) as one framed message: its length, the
    pickle's length, the pickle, then the raw bytes of the operations' row blocks (an
    operation whose last item is a C-contiguous float64 array goes with the array's shape in
    its place: no pickling of numpy arrays in the loop)."""
    raws: list[Any] = []
    if type(obj) is list:
        idx, ops = [], list(obj)  # the caller's list is left as it was
        for j, op in enumerate(ops):
            a = op[-1]
            if type(a) is np.ndarray and a.dtype == _F8 and a.flags.c_contiguous:
                idx.append(j)
                raws.append(a.data)
                ops[j] = op[:-1] + (a.shape,)
        obj = (_OPS, ops, idx)
    data = pickle.dumps(obj, protocol=5)
    total = 8 + len(data) + sum(r.nbytes for r in raws)
    return [_LEN.pack(total), _LEN.pack(len(data)), data, *raws]


def _unframe(buf: bytearray) -> Any:
    """The object of a message framed by :func:`_frame` (its length already read); the row
    blocks are arrays over ``buf`` (writable)."""
    n = _LEN.unpack_from(buf)[0]
    obj = pickle.loads(memoryview(buf)[8:8 + n])
    if obj[0] != _OPS:
        return obj
    _, ops, idx = obj
    o = 8 + n
    for j in idx:
        op = ops[j]
        shape = op[-1]
        k = int(np.prod(shape))
        ops[j] = op[:-1] + (np.frombuffer(buf, dtype=_F8, count=k, offset=o).reshape(shape),)
        o += 8 * k
    return ops


def _read_msg(fd: int) -> Any:
    """The next framed message on ``fd`` (blocking), or None at end of file."""
    head = _read_exact(fd, _LEN.size)
    body = None if head is None else _read_exact(fd, _LEN.unpack(head)[0])
    return None if body is None else _unframe(body)


def _err_tuple(e: BaseException) -> tuple[str, Any]:
    if isinstance(e, OSError):
        return ("OSError", (e.errno, e.strerror, e.filename))
    return (type(e).__name__, str(e))


def _as_exception(err: tuple[str, Any]) -> BaseException:
    kind, args = err
    if kind == "OSError":
        return OSError(*args) if args[2] is not None else OSError(args[0], args[1])
    if kind == "RuntimeError":  # the SDK's errors ("FoxgloveError: ..."): as they were
        return RuntimeError(args)
    return RuntimeError(f"{kind}: {args}")


class _Ring:
    """A one-writer, one-reader byte ring in shared memory, made before the fork: the flying
    process copies a hand-over in and moves its counter (no system call, so no wake-up of the
    writer process on this core); the writer process polls it every millisecond.  The two
    counters (bytes written, bytes read) are aligned 8-byte integers on their own cache lines
    ahead of the data, each written by one side in one store (x86 and ARM keep an aligned
    8-byte store whole; the data is copied before the counter moves)."""

    def __init__(self, size: int = 2 << 20):
        self.mm = mmap.mmap(-1, 128 + size)
        self.mm.write(bytes(128 + size))  # touched now: no page faults in the flight
        # [0] bytes written, [8] bytes read, [15] the reader has replied (an error)
        self.ctr = np.frombuffer(self.mm, dtype=np.int64, count=16)
        self.size = size
        self.pos = 0  # this side's counter (written, or read)

    def put(self, parts: list[Any], wait: Any) -> None:
        """Write ``parts`` (bytes-like) as one piece, publishing as it goes (a piece larger
        than the free space streams through); ``wait()`` is called while the ring is full."""
        mm, size, ctr = self.mm, self.size, self.ctr
        v = memoryview(b"".join(parts))
        while v:
            free = size - (self.pos - int(ctr[8]))
            if not free:
                wait()
                continue
            o = self.pos % size
            k = min(len(v), free, size - o)
            mm[128 + o:128 + o + k] = v[:k]
            v = v[k:]
            self.pos += k
            ctr[0] = self.pos

    def read(self, n: int, wait: Any) -> bytearray | None:
        """``n`` bytes; ``wait()`` is called while none are there and returns False when no
        more will come (then None)."""
        out = bytearray(n)
        mm, size, ctr, got = self.mm, self.size, self.ctr, 0
        while got < n:
            avail = int(ctr[0]) - self.pos
            if not avail:
                if not wait() and int(ctr[0]) == self.pos:
                    return None
                continue
            o = self.pos % size
            k = min(n - got, avail, size - o)
            out[got:got + k] = mm[128 + o:128 + o + k]
            got += k
            self.pos += k
            ctr[8] = self.pos
        return out

    def close(self) -> None:
        del self.ctr
        try:
            self.mm.close()
        except BufferError:  # a view is still held (a traceback's frame): freed with it
            pass


def _child(ring: _Ring, alive_fd: int, reply_fd: int, path: str, compression: Any,
           chunk_size: int) -> None:
    """The writer process: the backend, fed from ``ring`` until ``close``, or until the
    flying process is gone (``alive_fd`` hangs up: the file is finished with what arrived)."""
    code = 0
    try:
        for sig in (signal.SIGINT, signal.SIGTERM):  # the flying process decides when to close
            signal.signal(sig, signal.SIG_IGN)
        for fd in _LIVE_FDS - {alive_fd, reply_fd}:  # other logs' pipes: theirs to hold
            os.close(fd)
        try:
            back = Backend(path, compression, chunk_size)
        except BaseException as e:  # noqa: BLE001 - reported to the flying process
            _write_all(reply_fd, _frame(("error", _err_tuple(e))))
            return
        _write_all(reply_fd, _frame(("ok",)))
        poller = select.poll()
        poller.register(alive_fd, select.POLLIN)

        def wait() -> bool:  # False once the flying process is gone
            return not poller.poll(1)

        _serve(back, ring, wait, reply_fd)
    except BaseException:  # noqa: BLE001
        code = 1
    finally:
        os._exit(code)


def _serve(back: Backend, ring: _Ring, wait: Any, reply_fd: int) -> None:
    """Run the hand-overs until ``close`` (acknowledged) or the end of the flying process."""
    err = None
    while True:
        head = ring.read(_LEN.size, wait)
        body = None if head is None else ring.read(_LEN.unpack(head)[0], wait)
        if body is None:  # the flying process is gone: finish the file
            if err is None:
                back.run([("emit",), ("close",)])
            return
        ops = _unframe(body)
        closing = ops and ops[-1][0] == "close"
        if err is None:
            try:
                back.run(ops)
            except BaseException as e:  # noqa: BLE001 - reported, the rest is dropped
                err = _err_tuple(e)
                _write_all(reply_fd, _frame(("error", err)))
                ring.ctr[15] = 1  # the flying process reads the reply at its next hand-over
        if closing:
            if not back.closed:
                try:
                    back.run([("close",)])
                except BaseException:  # noqa: BLE001 - the first error was reported
                    pass
            _write_all(reply_fd, _frame(("closed",)))
            return


class WriterLost(OSError):
    """The log's writer process is gone (killed, crashed) before finishing the file.  Its own
    class, not the :class:`BrokenPipeError` an ``OSError(EPIPE)`` would be: a broken pipe on
    standard output (``ag-uav show | head``) is not an error, a lost log is."""


class ProcessSink:
    """The backend in a forked writer process, fed through a shared-memory ring (see the
    module docstring).  Its errors (a full disk) are raised at the next hand-over, or at
    :meth:`close`."""

    process = True
    cpu_s = 0.0  #: the writer process's CPU time (user + system), once it has exited
    live = 0  #: writer processes of this process not closed yet

    def __init__(self, path: str, compression: Any, chunk_size: int):
        self.path = path
        self._ring = _Ring()
        alive_r, alive_w = os.pipe()
        rep_r, rep_w = os.pipe()
        pid = os.fork()
        if pid == 0:
            os.close(alive_w)
            os.close(rep_r)
            _child(self._ring, alive_r, rep_w, path, compression, chunk_size)
        os.close(alive_r)
        os.close(rep_w)
        self.pid, self._alive, self._r = pid, alive_w, rep_r
        _LIVE_FDS.update((alive_w, rep_r))
        ProcessSink.live += 1
        self._counted = True
        self._poll = select.poll()
        self._poll.register(rep_r, select.POLLIN)
        self._failed = False
        self._alive_at = time.monotonic()
        first = self._reply(block=True)
        if first is None or first[0] != "ok":
            self._end()
            raise (_as_exception(first[1]) if first else
                   OSError(errno.EPIPE, "the run log's writer process did not start", path))

    def _reply(self, block: bool) -> tuple[Any, ...] | None:
        """The next reply of the writer (None: none yet, or the writer is gone)."""
        while not self._poll.poll(1000 if block else 0):
            if not block or self._exited():
                return None
        return _read_msg(self._r)

    def _exited(self) -> bool:
        """The writer process has exited (reaped now)."""
        if self.pid and os.waitpid(self.pid, os.WNOHANG)[0]:
            self.pid = 0
        return not self.pid

    def _check(self) -> None:
        """Raise the writer's error (once); after it the hand-overs are dropped."""
        if self._failed or not self._ring.ctr[15]:
            return
        msg = self._reply(block=True)
        if msg is not None and msg[0] == "error":
            self._failed = True
            raise _as_exception(msg[1])

    def _gone(self) -> OSError:
        self._failed = True
        return WriterLost(errno.EPIPE, "the run log's writer process exited before finishing "
                                       "the file (`ag-uav recover` indexes what it wrote)",
                          self.path)

    def _full(self) -> None:
        """The ring is full: wait for the writer (or find it gone)."""
        if self._exited():
            raise self._gone()
        time.sleep(0.0005)

    def send(self, ops: list[tuple[Any, ...]]) -> None:
        self._check()
        if self._failed:
            return
        now = time.monotonic()
        if now - self._alive_at > 1.0:  # a writer killed on its own is noticed within ~1 s
            self._alive_at = now
            if self._exited():
                raise self._gone()
        self._ring.put(_frame(ops), self._full)

    def close(self) -> None:
        """Hand over ``close``, wait for the writer to finish the file; raise its error if it
        had one that was not raised yet (or an OSError if it died without finishing)."""
        raised = self._failed  # an error was raised already: not again
        err: BaseException | None = None
        try:
            self._ring.put(_frame([("close",)]), self._full)  # after an error too
            while True:
                msg = self._reply(block=True)
                if msg is None:  # gone without finishing the file
                    err = err or self._gone()
                    break
                if msg[0] == "closed":
                    break
                if msg[0] == "error":
                    err = err or _as_exception(msg[1])
        except OSError as e:  # the writer went away while the ring was full
            err = err or e
        finally:
            self._end()
        if err is not None and not raised:
            self._failed = True
            raise err

    def _end(self) -> None:
        if getattr(self, "_counted", False):
            ProcessSink.live -= 1
            self._counted = False
        for fd in (self._alive, self._r):
            _LIVE_FDS.discard(fd)
            try:
                os.close(fd)
            except OSError:
                pass
        if self.pid:
            try:
                ru = os.wait4(self.pid, 0)[2]
                self.cpu_s = ru.ru_utime + ru.ru_stime
            except ChildProcessError:
                pass
        self._ring.close()


def open_sink(path: str, compression: Any, chunk_size: int, writer: str) -> Any:
    """``writer``: ``"process"`` (a forked writer process) or ``"inline"``.  A writer process
    needs ``os.fork`` and a spare core: where ``os.fork`` is missing, or one writer process per
    spare core is open already (say, a batch of many logged vehicles in one engine), the log
    writes in this process, with a warning naming it."""
    if writer not in ("process", "inline"):
        raise ValueError(f"writer must be 'process' or 'inline', not {writer!r}")
    if writer == "process":
        spare = max(1, (os.cpu_count() or 1) - 1)
        why = ("os.fork is missing here" if not hasattr(os, "fork") else
               f"{spare} writer process(es) are open already, one per spare core"
               if ProcessSink.live >= spare else "")
        if not why:
            return ProcessSink(path, compression, chunk_size)
        warnings.warn(f"run log {path}: written in this process ({why})", stacklevel=3)
    return InlineSink(path, compression, chunk_size)
