"""The reference rows the engine's kernels read, a block of ticks at a time.

Each distinct reference of a batch has one table of rows (pos 3, vel 3, acc 3, yaw, seg,
spray: :data:`COLUMNS`), sampled at the control ticks ``k·dt`` for ``k`` in the current block
(:data:`BLOCK` ticks). Where a flight is shorter than the longest one sharing its reference, the
table keeps the reference's last row (tick ``n − 1``) from there on. A block is refilled when
the loop reaches its end (:meth:`RefTable.at`), so the table's memory is a few blocks whatever
the job's length; each row equals the row of a whole-job table (the same times, sampled
element by element).

The spray job's per-tick sortie and ground tables (``job_tabs``) are whole-job: the sprayer
keeps them in its records.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np

from numkit import Layout

__all__ = ["BLOCK", "COLUMNS", "REF", "RF", "RefTable"]

#: ticks per block of rows
BLOCK = 4096
#: a row's fields (position, velocity, acceleration, yaw, segment, nozzles 0/1), and its
#: columns by name
REF = Layout("p:3 v:3 a:3 yaw seg spray")
RF = REF.at
COLUMNS = ("px", "py", "pz", "vx", "vy", "vz", "ax", "ay", "az", "yaw", "seg", "spray")


class RefTable:
    """Rows of ``references`` (one per distinct reference; ``n_ticks`` each, the longest flight
    on it) for ticks ``k0 .. k0 + BLOCK − 1``: ``tab[r, k − k0]``; ``k0`` is a one-element array
    the kernels read."""

    def __init__(self, references: Sequence[Any], n_ticks: Sequence[int], dt: float,
                 block: int = BLOCK) -> None:
        self.refs, self.dt, self.block = list(references), float(dt), int(block)
        self.n = np.asarray(n_ticks, dtype=np.int64)
        self.tab = np.zeros((len(self.refs), self.block, REF.size))
        self.k0 = np.zeros(1, dtype=np.int64)
        self._fill(0)

    @classmethod
    def of(cls, flights: Sequence[Any], n_ticks: np.ndarray, dt: float, block: int = BLOCK
           ) -> tuple[RefTable, np.ndarray, list[dict[str, np.ndarray]]]:
        """The table of ``flights``' distinct references (by identity), each vehicle's row of
        it, and each reference's whole-job spray tables (``sortie``, ``ground``; empty
        without a spray job)."""
        refs: list[Any] = []
        longest: list[int] = []
        index: dict[int, int] = {}
        ids = np.empty(len(flights), dtype=np.int64)
        for i, fl in enumerate(flights):
            rid = index.setdefault(id(fl.reference), len(refs))
            if rid == len(refs):
                refs.append(fl.reference)
                longest.append(0)
            longest[rid] = max(longest[rid], int(n_ticks[i]))
            ids[i] = rid
        job_tabs = [_job_tables(r, n, dt) for r, n in zip(refs, longest, strict=True)]
        return cls(refs, longest, dt, block), ids, job_tabs

    def at(self, k: int) -> None:
        """Make tick ``k``'s rows current (a new block when ``k`` is outside this one; the
        engine checks ``k >= end`` itself first, a tick's cheapest test)."""
        if not self.start <= k < self.end:
            self._fill(k)

    def _fill(self, k0: int) -> None:
        self.k0[0] = k0
        self.start, self.end = k0, k0 + self.block
        ks = np.arange(k0, k0 + self.block)
        for r, (ref, n) in enumerate(zip(self.refs, self.n.tolist(), strict=True)):
            if n == 0:
                self.tab[r] = 0.0
                continue
            tab = ref.sample_all(np.minimum(ks, n - 1) * self.dt)
            self.tab[r] = np.column_stack([tab["pos"], tab["vel"], tab["acc"], tab["yaw"],
                                           tab["seg"], tab["spray"]])


def _job_tables(ref: Any, n: int, dt: float) -> dict[str, np.ndarray]:
    """A spray job's whole-job ``sortie`` and ``ground`` per tick (``{}`` for a plain
    reference)."""
    if not hasattr(ref, "sortie_ground"):
        return {}
    sortie, ground = ref.sortie_ground(np.arange(n) * dt)
    return {"ground": ground, "sortie": sortie.astype(np.int32)}
