"""The estimator channels of a :class:`~ag_uav.record.runlog.RunLog` (one of its writers):
``/estimator/<name>``, one filter at a time or a bank of filters at once."""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np

from .channels import Channels
from .log_ticks import TickWriter
from .wire import (
    INF,
    NAN,
    EstBank,
    EstChan,
    FlatSchema,
    as_floats,
    fit,
    sanitize_name,
)


class EstimateWriter:
    """The ``estimator`` group of a run log, written through ``ch``; ``ticks``: the log's tick
    writer (the true position an estimate's ``err`` is measured against)."""

    def __init__(self, ch: Channels, ticks: TickWriter) -> None:
        self._ch, self._ticks = ch, ticks
        self._p_est = ch.period["estimator"] - 1e-9
        self._est: dict[str, EstChan] = {}
        self._banks: dict[tuple[str, ...], EstBank] = {}

    def names(self) -> list[str]:
        """The estimators declared so far (one channel each)."""
        return [*self._est, *(n for b in self._banks for n in b)]

    def want(self, name: str, t: float) -> bool:
        """Would :meth:`estimator` log ``name`` at sim time ``t``? (no side effects)"""
        ec = self._est.get(name)
        if ec is not None:
            return t >= ec.next_t
        return not self._ch.closed and self._ch.on("estimator")

    def stop(self) -> None:
        """Log nothing more (:class:`~ag_uav.record.channels.Source`)."""
        for ec in self._est.values():
            ec.next_t = INF
        for bank in self._banks.values():
            bank.next_t = INF

    def take(self, partial: bool) -> list[tuple[Any, ...]]:
        """Nothing of its own: its rows are flat-schema blocks the hand-over takes."""
        return []

    def counts_into(self, out: dict[str, int]) -> None:
        """Add the messages of its topics written so far to ``out`` (topic -> count)."""
        for ec in self._est.values():
            if ec.count:
                out[ec.topic] = ec.count
        for bank in self._banks.values():
            if bank.count:
                out.update(dict.fromkeys(bank.topics, bank.count))

    def estimator(
        self,
        t: float,
        name: str,
        x: Sequence[float],
        p_diag: Sequence[float],
        innovation: Sequence[float] | None = None,
        extra: dict[str, float] | None = None,
        *,
        pos: Sequence[float] | None = None,
    ) -> None:
        """One estimator's state after an update -> ``/estimator/<name>``.

        ``pos`` is the estimator's position estimate (2 or 3 values); default ``x[:3]`` (pass it
        when the state is not ordered position-first).  ``err`` = pos - the last true position
        given to :meth:`tick`.  The schema is fixed at the first call per name (vector lengths,
        ``extra`` keys); later missing values are written as NaN.  float64 numpy vectors are
        copied into the message as they are (a packed ``repeated double`` is their raw bytes).
        """
        ec = self._est.get(name)
        if ec is None:
            if self._ch.closed or not self._ch.on("estimator"):
                return
            xs = as_floats(x)
            ec = self._est[name] = self._make_est(name, len(xs), innovation, extra)
        elif t < ec.next_t:  # inf once closed
            return
        ec.next_t = t + self._p_est
        n = ec.n
        xa = type(x) is np.ndarray and x.ndim == 1 and x.size == n
        if pos is None:
            pl = x[:3].tolist() if xa else as_floats(x)[:3]
        else:
            pl = pos if len(pos) == 3 else as_floats(pos)
        tx, ty, tz = self._ticks.truth()
        if len(pl) == 3:
            px, py, pz = pl
        else:
            pf = fit(list(pl), 2)
            px, py, pz = pf[0], pf[1], (tz if len(pl) == 2 else NAN)
        row = ec.rows.open_row()
        row[0] = t
        row[ec.ix:ec.ip] = x if xa else fit(as_floats(x), n)
        if type(p_diag) is np.ndarray and p_diag.ndim == 1 and p_diag.size <= n:
            k = ec.ip + p_diag.size  # shorter (an error-state covariance): NaN-padded
            row[ec.ip:k] = p_diag
            row[k:ec.ii] = NAN
        else:
            row[ec.ip:ec.ii] = fit(as_floats(p_diag), n)
        if ec.m:
            row[ec.ii:ec.it] = NAN if innovation is None else fit(as_floats(innovation), ec.m)
        row[ec.it:ec.it + 7] = (px, py, pz, tx, ty, tz, NAN)  # err: at the flush (EstChan)
        if ec.keys:
            g = (extra or {}).get
            row[ec.it + 7:] = [g(k, NAN) for k in ec.keys]
        ec.rows.commit()
        ec.count += 1

    def estimator_bank(self, t: float, names: Sequence[str], x: np.ndarray,
                       p_diag: np.ndarray, p_true: Sequence[float]) -> None:
        """:meth:`estimator` for a bank of filters of one vehicle at once (no innovation, no
        extras; position first in the state): row j of ``x`` (k, n) and of ``p_diag`` (k, m ≤ n,
        NaN-padded to n; the shapes of the bank's first call) is filter ``names[j]`` on
        ``/estimator/<name>``, ``err`` against ``p_true``.  A fix is one compact row of the
        bank (:class:`EstBank`); the writer makes the messages of a flush's rows in one call."""
        key = tuple(names)
        bank = self._banks.get(key)
        if bank is None:
            if self._ch.closed or not self._ch.on("estimator"):
                return
            bank = self._banks[key] = self._make_bank(key, x.shape[1], p_diag.shape[1])
        if t < bank.next_t:  # inf once closed
            return
        bank.next_t = t + self._p_est
        bank.put_fix(t, x, p_diag, p_true)

    def _make_bank(self, names: tuple[str, ...], n: int, m: int) -> EstBank:
        schema = FlatSchema("ag_uav.EstimatorState", [("t", 0), ("x", n), ("p_diag", n)]
                            + [(f"pos.{a}", 0) for a in "xyz"]
                            + [(f"err.{a}", 0) for a in ("x", "y", "z", "horiz")])
        topics = [f"/estimator/{sanitize_name(nm)}" for nm in names]
        lids = [self._ch.declare(tp, "ag_uav.EstimatorState", schema.schema_data)
                for tp in topics]
        return self._ch.register_flat(EstBank(schema, lids, topics, n, m))

    def _make_est(self, name: str, n: int, innovation: Any, extra: Any) -> EstChan:
        m = len(as_floats(innovation)) if innovation is not None else 0
        keys = tuple(extra or {})
        fields = [("t", 0), ("x", n), ("p_diag", n)]
        if m:
            fields.append(("innovation", m))
        fields += [(f"pos.{a}", 0) for a in "xyz"]
        fields += [(f"err.{a}", 0) for a in ("x", "y", "z", "horiz")]
        fields += [(f"extra.{k}", 0) for k in keys]
        try:
            schema = FlatSchema("ag_uav.EstimatorState", fields)
        except ValueError:
            keys = ()
            schema = FlatSchema("ag_uav.EstimatorState", [f for f in fields
                                                           if not f[0].startswith("extra.")])
        topic = f"/estimator/{sanitize_name(name)}"
        lid = self._ch.declare(topic, "ag_uav.EstimatorState", schema.schema_data)
        return self._ch.register_flat(EstChan(schema, lid, topic, n, m, keys))
