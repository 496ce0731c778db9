"""GPS availability and fix-quality episodes: the outage chain and the semi-Markov chain
over solution types (RTK fixed, RTK float, DGPS/SBAS) with the blending weights of their error."""

from __future__ import annotations

import math
from collections.abc import Mapping
from typing import Any

import numpy as np

from .checks import SeedLike, as_seedseq, bad, check_pos, derive_seed, rngs


class OutageProcess:
    """Two-state Markov chain of GPS availability.  Run lengths (in fixes) are geometric with
    success probability ``dt / mean`` (clipped to 1), so the mean time in each state is exactly
    ``mean_up_s`` / ``mean_down_s`` when ``mean >= dt``.  ``sample(n, dt)`` returns a bool array,
    True where the fix is lost; state carries across calls.  Up and down durations come from
    separate streams."""

    def __init__(
        self, mean_up_s: float, mean_down_s: float, seed: SeedLike, start_in_outage: bool = False
    ) -> None:
        self.mean_up_s = check_pos("outage", "mean_up_s", mean_up_s)
        self.mean_down_s = check_pos("outage", "mean_down_s", mean_down_s)
        if not isinstance(start_in_outage, (bool, np.bool_)):
            raise bad("outage", "start_in_outage", start_in_outage, "must be true or false")
        self._rng_up, self._rng_down = rngs(seed, 2)
        self._down = bool(start_in_outage)
        self._left = 0  # fixes left in the current run; 0 = draw a new run for the current state
        self._fresh = True

    def _draw_run(self, dt: float) -> int:
        if self._down:
            return int(self._rng_down.geometric(min(1.0, dt / self.mean_down_s)))
        return int(self._rng_up.geometric(min(1.0, dt / self.mean_up_s)))

    def sample(self, n: int, dt: float = 0.05) -> np.ndarray:
        out = np.empty(n, dtype=bool)
        i = 0
        while i < n:
            if self._left <= 0:
                if not self._fresh:
                    self._down = not self._down
                self._fresh = False
                self._left = self._draw_run(dt)
            m = min(self._left, n - i)
            out[i : i + m] = self._down
            i += m
            self._left -= m
        return out

    @property
    def availability(self) -> float:
        """Stationary fraction of time with a fix."""
        return self.mean_up_s / (self.mean_up_s + self.mean_down_s)


_MODE_KEYS = {"mean_dwell_s", "ramp_s", "next", "components"}
FIXQ_KEYS = {"start", "modes"}


class FixQualityChain:
    """Fix-quality episodes: a semi-Markov chain over solution types (e.g. RTK fixed, RTK float,
    DGPS/SBAS) and the blending weights of their extra error.

    Dwell: a run in mode ``i`` lasts ``L ~ Geometric(p_i)`` fixes, ``p_i = min(1, dt / T_i)``,
    so ``E[L] dt = T_i`` exactly (``T_i = mean_dwell_s``, for ``T_i >= dt``).  On leaving ``i``
    the next mode is ``j`` with probability ``P_ij`` (``next``; ``P_ii = 0``).  With ``nu`` the
    stationary law of the jump chain (``nu P = nu``), the long-run fraction of fixes in mode ``i``
    is ``pi_i = nu_i T_i / sum_j nu_j T_j`` (renewal-reward; :meth:`occupancy`).

    Transitions: each mode ``i`` has a time constant ``ramp_s = r_i``; while mode ``i`` is active
    the weight vector moves towards the one-hot ``e_i`` at every fix,
    ``w_k = e_i + (w_{k-1} - e_i) a_i``, ``a_i = exp(-dt / r_i)`` (``a_i = 0`` for ``r_i = 0``: a
    snap).  The sensor adds ``sum_i w_{k,i} e^{(i)}_k`` (each mode's own error processes, always
    running) to the base error.  So a degradation grows smoothly (the receiver's navigation
    filter carries the previous solution) while an ambiguity fix snaps back in one epoch, as a
    real receiver's position does when the integers are resolved.

    Randomness: per mode one dwell stream and one next-mode stream, keyed by the mode's name.
    ``sample`` is chunk invariant (the weights are computed in closed form within a run,
    ``w_{k0+j} = e_i + (w_{k0} - e_i) a_i^j``, equal to the recursion to rounding).
    """

    def __init__(
        self, modes: Mapping[str, Mapping[str, Any]], seed: SeedLike, start: str | None = None
    ) -> None:
        who = "gps fix_quality"
        if not isinstance(modes, Mapping) or len(modes) < 2:
            raise bad(who, "modes", modes, "must be a table of >= 2 mode tables keyed by name")
        names = list(modes)
        for nm in names:
            if not isinstance(nm, str) or not nm:
                raise bad(who, "modes", nm, "mode names must be non-empty strings")
        self.names: tuple[str, ...] = tuple(names)
        m = len(names)
        self.mean_dwell_s = np.empty(m)
        self.ramp_s = np.empty(m)
        self.P = np.zeros((m, m))
        for i, nm in enumerate(names):
            cfg = modes[nm]
            mw = f"{who} mode {nm!r}"
            if not isinstance(cfg, Mapping):
                raise bad(who, f"modes.{nm}", cfg, "must be a table with mean_dwell_s, next, "
                           "ramp_s, components")
            for k in cfg:
                if k not in _MODE_KEYS:
                    raise bad(mw, k, cfg[k],
                               f"unknown key; allowed: {', '.join(sorted(_MODE_KEYS))}")
            for k in ("mean_dwell_s", "next"):
                if k not in cfg:
                    raise bad(mw, k, None, "is required")
            self.mean_dwell_s[i] = check_pos(mw, "mean_dwell_s", cfg["mean_dwell_s"])
            self.ramp_s[i] = check_pos(mw, "ramp_s", cfg.get("ramp_s", 0.0), allow_zero=True)
            nxt = cfg["next"]
            allowed = (f"must be a table of probabilities (>= 0, summing to 1) over the other "
                       f"modes ({', '.join(x for x in names if x != nm)})")
            if not isinstance(nxt, Mapping) or not nxt:
                raise bad(mw, "next", nxt, allowed)
            for tgt, pr in nxt.items():
                if tgt not in names or tgt == nm:
                    raise bad(mw, f"next.{tgt}", pr, allowed)
                self.P[i, names.index(tgt)] = check_pos(mw, f"next.{tgt}", pr, allow_zero=True,
                                                         le=1.0)
            if abs(self.P[i].sum() - 1.0) > 1e-9:
                raise bad(mw, "next", dict(nxt), allowed)
        if start is None:
            start = names[0]
        if start not in names:
            raise bad(who, "start", start, f"must be one of the modes: {', '.join(names)}")
        self.start = start
        ss = as_seedseq(seed)
        self._rng_dwell = [np.random.Generator(np.random.PCG64(derive_seed(ss, "dwell", nm)))
                           for nm in names]
        self._rng_next = [np.random.Generator(np.random.PCG64(derive_seed(ss, "next", nm)))
                          for nm in names]
        self.P /= self.P.sum(axis=1, keepdims=True)
        self._cum = np.cumsum(self.P, axis=1)
        self._last = [int(np.flatnonzero(row > 0.0)[-1]) for row in self.P]
        self._mode = names.index(start)
        self._left = 0
        self._fresh = True
        self._w = np.zeros(m)
        self._w[self._mode] = 1.0

    @property
    def mode(self) -> str:
        """The current mode (that of the last fix sampled; the start mode before any)."""
        return self.names[self._mode]

    def occupancy(self) -> dict[str, float]:
        """Long-run fraction of fixes in each mode: ``pi_i = nu_i T_i / sum_j nu_j T_j``."""
        m = len(self.names)
        a = np.vstack([(self.P.T - np.eye(m)), np.ones((1, m))])
        b = np.zeros(m + 1)
        b[-1] = 1.0
        nu = np.linalg.lstsq(a, b, rcond=None)[0]
        occ = nu * self.mean_dwell_s
        occ = occ / occ.sum()
        return {nm: float(v) for nm, v in zip(self.names, occ, strict=True)}

    def sample(self, n: int, dt: float) -> tuple[np.ndarray, np.ndarray]:
        """Next ``n`` fixes: (mode index per fix (int8), blending weights (n, modes))."""
        m = len(self.names)
        idx = np.empty(n, dtype=np.int8)
        w = np.empty((n, m))
        i = 0
        while i < n:
            if self._left <= 0:
                if not self._fresh:
                    u = self._rng_next[self._mode].random()
                    j = int(np.searchsorted(self._cum[self._mode], u, side="right"))
                    self._mode = min(j, self._last[self._mode])
                self._fresh = False
                p = min(1.0, dt / self.mean_dwell_s[self._mode])
                self._left = int(self._rng_dwell[self._mode].geometric(p))
            k = min(self._left, n - i)
            cur = self._mode
            idx[i : i + k] = cur
            e = np.zeros(m)
            e[cur] = 1.0
            r = self.ramp_s[cur]
            if r > 0.0:
                a = math.exp(-dt / r)
                pw = a ** np.arange(1, k + 1, dtype=float)
                w[i : i + k] = e + (self._w - e)[None, :] * pw[:, None]
            else:
                w[i : i + k] = e
            self._w = w[i + k - 1].copy()
            i += k
            self._left -= k
        return idx, w
