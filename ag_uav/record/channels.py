"""What the writers of a :class:`~ag_uav.record.runlog.RunLog` share: the groups' periods and
clocks, the channels declared so far, and the hand-over of rows and messages to the MCAP writer
(:mod:`ag_uav.record.sink`).

A run log is a few small writers (the tick rows, the estimators, the scene, the geographic
topics: :mod:`~ag_uav.record.log_ticks`, :mod:`~ag_uav.record.log_estimates`,
:mod:`~ag_uav.record.log_scene`, :mod:`~ag_uav.record.log_geo`), each owning its own state and
reaching the file only through one :class:`Channels`: :meth:`Channels.declare` a channel (its
index names it in the writer's operations), :meth:`Channels.post` an encoded message,
:meth:`Channels.register_flat` a block of flat-schema rows (encoded by the writer at each
hand-over), ``ops`` for declarations that go with the next hand-over, :meth:`Channels.drain` to
hand everything over. A writer with rows of its own to hand over, or clocks to stop, is one of
the :class:`Source`\\ s of the hand-over.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from typing import Any, Protocol

from .sink import WriterLost
from .wire import INF, FlatRows

_perf_counter = time.perf_counter


class Source(Protocol):
    """A writer with rows of its own to hand over (:meth:`take`) and clocks to stop."""

    def take(self, partial: bool) -> list[tuple[Any, ...]]:
        """The operations that hand over its rows (``partial``: drop a row being filled)."""
        ...

    def stop(self) -> None:
        """Log nothing more: its clocks to infinity."""
        ...


class Channels:
    """The hand-over shared by a run log's writers (module docstring).

    :param period: sim seconds between two messages of each group (``0.0`` every call, ``inf``
        off): the log's rates.
    :param enabled: whether anything is logged at all (else every clock stays at infinity and
        no writer is opened).
    """

    def __init__(self, period: dict[str, float], enabled: bool) -> None:
        self.period = period
        self.enabled = enabled
        self.closed = not enabled
        #: next sim time each group is due (inf = off or closed): the hot paths test only this
        self.next = {g: (-INF if p < INF and enabled else INF) for g, p in period.items()}
        self.t_last = 0.0  #: the sim time of the last tick row handed out
        self.M: Any = None  #: ``foxglove.messages`` once :meth:`open`
        self.sink: Any = None  #: the MCAP writer (:func:`ag_uav.record.sink.open_sink`)
        #: the writer died mid-flight (:class:`~ag_uav.record.sink.WriterLost`): the log ends
        #: there; ``lost_at`` is the sim time of the last hand-over before it
        self.lost: OSError | None = None
        self.lost_at = 0.0
        self.ops: list[tuple[Any, ...]] = []  #: declarations for the writer's next hand-over
        #: encoded messages (channel index, bytes, log_time) not yet handed to the writer (the
        #: dose maps, GeoJSON): they go with the rows at the next hand-over
        self.pending: list[tuple[int, bytes, int]] = []
        self.flat_rows: list[FlatRows] = []  #: flat-schema row blocks, encoded at each flush
        self.counts: dict[str, int] = {}  #: messages of the rare topics (the frequent count apart)
        self.sources: list[Source] = []  #: the writers with rows of their own (:class:`Source`)
        #: called when a new channel changes what the Foxglove layout shows (the owner's)
        self.on_layout: Callable[[], None] = _nothing
        self._n_chan = 0
        self._flush_wall_s = self._flush_sim_s = INF
        self._last_flush_wall = self._last_flush_sim = -INF

    def open(self, sink: Any, flush_wall_s: float, flush_sim_s: float) -> None:
        """Write through ``sink``, handing over at least every ``flush_wall_s`` of wall time
        and ``flush_sim_s`` of sim time (:class:`~ag_uav.record.runlog.LogIO`)."""
        import foxglove

        self.M = foxglove.messages
        self.sink = sink
        self._flush_wall_s = float(flush_wall_s)
        self._flush_sim_s = float(flush_sim_s)
        self._last_flush_wall = _perf_counter()
        self._last_flush_sim = -INF

    def on(self, group: str) -> bool:
        """Whether ``group`` is logged at all."""
        return self.period[group] < INF

    # ---------------------------------------------------------------- declarations
    def declare(self, topic: str, schema: Any, data: bytes | None = None) -> int:
        """A new channel on ``topic`` -> its index, which the writer's operations name.
        ``schema``: a foxglove message class (its well-known schema), or the schema's name
        with ``data`` (a protobuf FileDescriptorSet)."""
        if data is None:
            sc = schema.get_schema()
            name, enc, data = sc.name, sc.encoding, bytes(sc.data)
        else:
            name, enc = schema, "protobuf"
        self.ops.append(("chan", topic, name, enc, data))
        self._n_chan += 1
        return self._n_chan - 1

    def register_flat(self, fr: FlatRows) -> Any:
        """Register a flat-schema channel's row block with the writer (its encoding); returns
        ``fr``."""
        from .wire import EstBank

        fr.fid = len(self.flat_rows)
        bank = ((fr.k, fr.n, fr.m, fr.lids.astype(int).tolist()) if isinstance(fr, EstBank)
                else None)
        self.ops.append(("flat", fr.fid, fr.tmpl, fr.slots, fr.lid, fr.it, bank))
        self.flat_rows.append(fr)
        return fr

    def count(self, topic: str) -> None:
        """One more message on a rare topic."""
        self.counts[topic] = self.counts.get(topic, 0) + 1

    def post(self, lid: int, msg: bytes, t_ns: int) -> None:
        """An encoded message on channel ``lid`` at log time ``t_ns``, handed over with the next
        rows."""
        self.pending.append((lid, msg, t_ns))

    def ts(self, t_ns: int) -> Any:
        """``foxglove.messages.Timestamp`` of ``t_ns``."""
        return self.M.Timestamp(sec=t_ns // 1_000_000_000, nsec=t_ns % 1_000_000_000)

    # ---------------------------------------------------------------- hand-over
    def send(self, ops: list[tuple[Any, ...]]) -> None:
        """Hand the declarations made since the last hand-over, then ``ops``, to the writer."""
        if self.ops:
            ops = self.ops + ops
            self.ops = []
        try:
            self.sink.send(ops)
        except WriterLost as e:  # the flight goes on unlogged; its summary names the loss
            self.lose(e)

    def lose(self, err: OSError) -> None:
        """The writer is gone: record ``err`` in :attr:`lost`, log nothing more (every clock
        goes to infinity), reap the writer."""
        self.lost, self.lost_at = err, self.t_last
        self.stop_clocks()
        try:
            self.sink.close()
        except Exception:  # noqa: BLE001 - reaping the dead writer is best effort
            pass

    def stop_clocks(self) -> None:
        """Log nothing more: every group's and every source's clock to infinity."""
        self.closed = True
        for g in self.next:
            self.next[g] = INF
        for s in self.sources:
            s.stop()

    def drain(self, partial: bool = False, flush: bool = False) -> None:
        """Hand the rows and messages waiting since the last hand-over to the writer (it
        encodes them and writes them merged by log time; ``flush``: then finishes the chunk and
        writes it to the OS).  ``partial``: a row still being filled (a signal arrived
        mid-tick) is dropped, not written half-done."""
        ops: list[tuple[Any, ...]] = []
        if self.pending:
            ops.append(("msgs", self.pending))
            self.pending = []  # swapped first: a signal handler's close() sends only the rest
        for fr in self.flat_rows:
            r = fr.take()
            if r is not None:
                ops.append(("block", fr.fid, r))
        for s in self.sources:
            ops += s.take(partial)
        ops.append(("emit",))
        if flush:
            ops.append(("flush",))
        self.send(ops)

    def maybe_flush(self, t: float) -> None:
        """:meth:`drain` and flush when a flush period has passed (at sim time ``t``)."""
        now = _perf_counter()
        if now - self._last_flush_wall >= self._flush_wall_s or (
            t - self._last_flush_sim >= self._flush_sim_s
        ):
            self.drain(flush=True)
            self._last_flush_wall = now
            self._last_flush_sim = t

    def flush(self) -> None:
        """Finish the current chunk and hand everything to the OS now."""
        if not self.closed:
            self.drain(flush=True)
            self._last_flush_wall = _perf_counter()


def _nothing() -> None:
    pass
