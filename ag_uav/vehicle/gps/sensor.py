"""The GPS sensor: fixes at its rate, with latency, outages and fix-quality episodes."""

from __future__ import annotations

from collections import deque
from collections.abc import Iterable, Mapping, Sequence
from typing import Any

import numpy as np

from .checks import SeedLike, as_seedseq, bad, check_axis_scale, check_pos, derive_seed
from .episodes import FIXQ_KEYS, FixQualityChain, OutageProcess
from .noise import Built, build_components, comp_variance, sum_components
from .presets import SENSOR_KEYS, apply_overrides

_OUTAGE_KEYS = {"mean_up_s", "mean_down_s", "start_in_outage"}
#: upper bounds of the sensor keys (no GNSS receiver in this class outputs > 100 Hz, the loop's
#: control rate; a GNSS latency is tens of milliseconds, 1 s is a generous ceiling)
MAX_RATE_HZ = 100.0
MAX_LATENCY_S = 1.0


class GpsSensor:
    """GPS position sensor: fixes at multiples of ``1/rate_hz``, optional latency, outages and
    fix-quality episodes.

    Error of fix k (per axis, before ``axis_scale``):
    ``e_k = sum_c e^{(c)}_k + sum_i w_{k,i} sum_{c in mode i} e^{(c)}_k`` -- the base components
    plus, with ``fix_quality``, every mode's own components weighted by the episode chain's
    blending weights (:class:`FixQualityChain`).

    Args:
        rate_hz: fix rate in (0, 100] Hz (paper: Ts = 0.05 s -> 20 Hz).
        latency_s: in [0, 1] s; a fix delivered at time t reports the true position at
            ``t - latency_s`` (linear interpolation in a small buffer of past ``measure`` inputs).
        components: component config tables (dicts, see module docstring).  Each gets one
            independent scalar process per axis, seeded by ``(name, axis)``.
        seed: SeedSequence or int; the root of every stream of this sensor (keyword-only).
        axis_scale: per-axis multiplier of the summed error, e.g. vertical 1.5-2x horizontal.
        outage: ``{"mean_up_s": ..., "mean_down_s": ..., "start_in_outage": False}`` or None/{}.
        fix_quality: ``{"start": mode, "modes": {name: {"mean_dwell_s", "next", "ramp_s",
            "components"}}}`` or None/{} (no episodes).

    The fix type is exposed (:attr:`last_fix_type`, :attr:`fix_type_counts`,
    ``generate_errors(..., with_fix_type=True)``) for logging only: the filters are not told it.
    Their ``R`` comes from :attr:`variance`, the *nominal* error (the base components: for
    ``rtk-m350`` the RTK-fixed datasheet level) -- the robust-filter premise of the core paper,
    where R is fixed and the filter must cope with whatever the noise does.
    """

    BLOCK = 1024

    def __init__(
        self,
        rate_hz: float = 20.0,
        latency_s: float = 0.0,
        components: Iterable[Mapping[str, Any]] = (),
        *,
        seed: SeedLike,
        axis_scale: Sequence[float] = (1.0, 1.0, 1.0),
        outage: Mapping[str, Any] | None = None,
        fix_quality: Mapping[str, Any] | None = None,
    ) -> None:
        self.rate_hz = check_pos("gps", "rate_hz", rate_hz, le=MAX_RATE_HZ)
        self.latency_s = check_pos("gps", "latency_s", latency_s, allow_zero=True,
                                    le=MAX_LATENCY_S)
        self.axis_scale = check_axis_scale("gps", axis_scale)
        self.dt = 1.0 / self.rate_hz
        self.seed = as_seedseq(seed)
        if isinstance(components, (str, bytes, Mapping)) or not isinstance(components, Iterable):
            raise bad("gps", "components", components, "must be a list of component tables")
        self.config_components = [dict(c) if isinstance(c, Mapping) else c for c in components]
        #: (name, per-axis processes, per-axis scale) of the base components
        self.components: Built = build_components(self.config_components, self.seed, "gps",
                                                    "component")
        self.outage: OutageProcess | None = None
        if outage is not None and not isinstance(outage, Mapping):
            raise bad("gps", "outage", outage, "must be a table with mean_up_s, mean_down_s "
                       "(an empty table means no outages)")
        if outage:
            extra = set(outage) - _OUTAGE_KEYS
            if extra:
                k = sorted(extra, key=str)[0]
                raise bad("gps outage", k, outage[k],
                           "unknown key; allowed: mean_up_s, mean_down_s, start_in_outage")
            for k in ("mean_up_s", "mean_down_s"):
                if k not in outage:
                    raise bad("gps outage", k, None, "is required when outages are enabled")
            self.outage = OutageProcess(
                outage["mean_up_s"], outage["mean_down_s"], derive_seed(self.seed, "outage"),
                start_in_outage=outage.get("start_in_outage", False),
            )
        self.fix_quality: FixQualityChain | None = None
        #: per mode of the chain, its extra components
        self.mode_components: list[Built] = []
        if fix_quality is not None and not isinstance(fix_quality, Mapping):
            raise bad("gps", "fix_quality", fix_quality, "must be a table with start, modes "
                       "(an empty table means no episodes)")
        if fix_quality:
            for k in fix_quality:
                if k not in FIXQ_KEYS:
                    raise bad("gps fix_quality", k, fix_quality[k],
                               f"unknown key; allowed: {', '.join(sorted(FIXQ_KEYS))}")
            if "modes" not in fix_quality:
                raise bad("gps fix_quality", "modes", None, "is required")
            self.fix_quality = FixQualityChain(
                fix_quality["modes"], derive_seed(self.seed, "fix_quality"),
                start=fix_quality.get("start"))
            for nm in self.fix_quality.names:
                self.mode_components.append(build_components(
                    fix_quality["modes"][nm].get("components", []), self.seed,
                    f"gps fix_quality mode {nm!r}", "mode", nm))
        # measure() state
        self._next_k = 0
        self._block: list[list[float]] = []
        self._block_types: list[int] = []
        self._block_start = 0
        self._hist: deque[tuple[float, float, float, float]] = deque()
        self.last_fix_time: float | None = None
        #: the true position the last fix measured (at ``last_fix_time - latency_s``)
        self.last_truth: tuple[float, float, float] | None = None
        #: fix type of the last delivered fix (None without fix_quality or before any fix)
        self.last_fix_type: str | None = None
        #: delivered fixes per fix type (empty without fix_quality)
        self.fix_type_counts: dict[str, int] = dict.fromkeys(self.fix_types, 0)

    @property
    def next_fix_t(self) -> float:
        """The time (s) from which the next fix is due: :meth:`measure` returns None before it
        (less 1 ns of rounding slack). The engine's batches read it to call the receivers of
        the vehicles with a fix due only."""
        return self._next_k * self.dt

    @property
    def fix_types(self) -> tuple[str, ...]:
        """Names of the fix types (the modes of ``fix_quality``; empty without it)."""
        return self.fix_quality.names if self.fix_quality is not None else ()

    # -- construction from config ---------------------------------------------------------
    @classmethod
    def from_config(cls, cfg: Mapping[str, Any], seed: SeedLike) -> GpsSensor:
        """Build from a config dict with the sensor keys documented in the module docstring."""
        if not isinstance(cfg, Mapping):
            raise bad("gps config", "table", cfg, "must be a table/dict")
        for k in cfg:
            if k not in SENSOR_KEYS:
                raise bad("gps config", k, cfg[k], f"unknown key; allowed: "
                           f"{', '.join(sorted(SENSOR_KEYS))}")
        return cls(
            rate_hz=cfg.get("rate_hz", 20.0),
            latency_s=cfg.get("latency_s", 0.0),
            components=cfg.get("components", ()),
            seed=seed,
            axis_scale=cfg.get("axis_scale", (1.0, 1.0, 1.0)),
            outage=cfg.get("outage"),
            fix_quality=cfg.get("fix_quality"),
        )

    @classmethod
    def from_preset(cls, name: str, seed: SeedLike, **overrides: Any) -> GpsSensor:
        """Preset ``name`` with top-level keys replaced by ``overrides``; ``components`` may be a
        list (replace) or a dict keyed by component name (merge), ``fix_quality`` merges by mode
        (see module docstring).  Every override is checked (see :func:`validate_overrides`)."""
        return cls.from_config(apply_overrides(name, overrides), seed)

    # -- error generation -------------------------------------------------------------------
    def generate_errors(
        self, n: int, dt: float | None = None, *, with_fix_type: bool = False
    ) -> np.ndarray | tuple[np.ndarray, np.ndarray]:
        """Next ``n`` per-fix errors as an (n, 3) array (metres); rows are NaN during outages.

        With ``with_fix_type`` also the fix type of each fix: an int8 array indexing
        :attr:`fix_types` (-1 everywhere without ``fix_quality``).  Vectorised (numpy / lfilter).
        Continues this sensor's random streams: use a fresh sensor for a reproducible offline
        series.  ``dt`` defaults to ``1 / rate_hz``.
        """
        if isinstance(n, (bool, np.bool_)) or not isinstance(n, (int, np.integer)) or n < 0:
            raise bad("gps.generate_errors", "n", n, "must be an int >= 0")
        n = int(n)
        step = self.dt if dt is None else check_pos("gps.generate_errors", "dt", dt)
        err = sum_components(self.components, n, step)
        types = np.full(n, -1, dtype=np.int8)
        if self.fix_quality is not None:
            types, w = self.fix_quality.sample(n, step)
            for i, comps in enumerate(self.mode_components):
                if comps:
                    err += w[:, i : i + 1] * sum_components(comps, n, step)
        err *= np.asarray(self.axis_scale)
        if self.outage is not None:
            err[self.outage.sample(n, step)] = np.nan
        return (err, types) if with_fix_type else err

    # -- streaming --------------------------------------------------------------------------
    def _truth_at(self, t: float) -> tuple[float, float, float]:
        hist = self._hist
        while len(hist) >= 2 and hist[1][0] <= t:
            hist.popleft()
        t0, x0, y0, z0 = hist[0]
        if len(hist) == 1 or t <= t0:
            return x0, y0, z0
        t1, x1, y1, z1 = hist[1]
        a = (t - t0) / (t1 - t0)
        return x0 + a * (x1 - x0), y0 + a * (y1 - y0), z0 + a * (z1 - z0)

    def measure(self, t: float, p_true_xyz: Sequence[float]) -> np.ndarray | None:
        """Call at control rate with the current time and true position (ENU, m).

        Returns a fix (np.ndarray(3)) when one is due -- at the first call with t at or after
        k / rate_hz -- otherwise None; also None when the fix is lost to an outage.  Fix k uses
        error row k (skipped epochs consume their rows, so the error series is a function of the
        epoch index only).  Calls must have non-decreasing t.  A delivered fix updates
        :attr:`last_fix_type` and :attr:`fix_type_counts`.
        """
        z = self.measure_xyz(t, p_true_xyz)
        return None if z is None else np.array(z)

    def measure_xyz(self, t: float, p_true_xyz: Sequence[float]
                    ) -> tuple[float, float, float] | None:
        """:meth:`measure` with the fix as a tuple of three floats (the same law and values;
        no array made: the INS batch calls it per vehicle at the fix rate)."""
        if self.latency_s > 0.0:
            self._hist.append((t, float(p_true_xyz[0]), float(p_true_xyz[1]),
                               float(p_true_xyz[2])))
        if t < self._next_k * self.dt - 1e-9:
            return None
        k = int(t * self.rate_hz + 1e-9)
        self._next_k = k + 1
        j = k - self._block_start
        while j >= len(self._block):
            self._block_start += len(self._block)
            j = k - self._block_start
            err, types = self.generate_errors(self.BLOCK, with_fix_type=True)
            self._block = err.tolist()
            self._block_types = types.tolist()
        ex, ey, ez = self._block[j]
        if ex != ex:  # NaN: outage
            if self.latency_s > 0.0:
                self._truth_at(t - self.latency_s)  # prune the buffer anyway
            return None
        self.last_fix_time = t
        ti = self._block_types[j]
        if ti >= 0:
            ft = self.fix_types[ti]
            self.last_fix_type = ft
            self.fix_type_counts[ft] += 1
        if self.latency_s > 0.0:
            x, y, z = self._truth_at(t - self.latency_s)
        else:
            x, y, z = p_true_xyz[0], p_true_xyz[1], p_true_xyz[2]
        self.last_truth = (x, y, z)
        return (x + ex, y + ey, z + ez)

    @property
    def variance(self) -> tuple[float, float, float]:
        """Per-axis *nominal* error variance: that of the base components (inf for
        alpha-stable), times ``axis_scale**2``.  With ``fix_quality`` the episodes' extra error
        is left out on purpose: this is what the estimators' ``R`` is built from
        (``R = r_scale * variance``), and it stands for the accuracy the receiver is specified
        at in its nominal mode (for ``rtk-m350``: RTK fixed, 1 cm + 1 ppm), which is also the
        mode it is in most of the time.  See :meth:`mode_variance` for each mode's level."""
        v = comp_variance(self.components) * np.asarray(self.axis_scale) ** 2
        return float(v[0]), float(v[1]), float(v[2])

    def mode_variance(self, mode: str) -> tuple[float, float, float]:
        """Per-axis error variance while fully in fix type ``mode`` (after its ramp): base plus
        the mode's own components, times ``axis_scale**2``."""
        if mode not in self.fix_types:
            raise bad("gps.mode_variance", "mode", mode,
                       f"allowed: {', '.join(self.fix_types) or '(no fix_quality)'}")
        i = self.fix_types.index(mode)
        v = (comp_variance(self.components) + comp_variance(self.mode_components[i])) \
            * np.asarray(self.axis_scale) ** 2
        return float(v[0]), float(v[1]), float(v[2])

    def spread_variance(self, mode: str | None = None) -> tuple[float, float, float]:
        """Per-axis variance of a fix (:attr:`variance`, or fix type ``mode``'s
        :meth:`mode_variance`) with each component's finite spread in place of an infinite
        variance (:attr:`~ag_uav.vehicle.gps.noise.NoiseComponent.spread`: alpha-stable's
        ``2 scale²``); the position failsafe's automatic bound is built from it."""
        v = comp_variance(self.components, spread=True)
        if mode is not None:
            if mode not in self.fix_types:
                raise bad("gps.spread_variance", "mode", mode,
                          f"allowed: {', '.join(self.fix_types) or '(no fix_quality)'}")
            v = v + comp_variance(self.mode_components[self.fix_types.index(mode)], spread=True)
        v = v * np.asarray(self.axis_scale) ** 2
        return float(v[0]), float(v[1]), float(v[2])

    def reported_variance(self, mode: str | None) -> tuple[float, float, float]:
        """The per-axis variance a receiver reports with a fix of type ``mode``: the mode's
        (:meth:`mode_variance`), or the nominal :attr:`variance` for no or an unknown type
        (memoised: the run log asks at every fix)."""
        memo = self.__dict__.setdefault("_reported", {})
        v = memo.get(mode)
        if v is None:
            v = memo[mode] = (self.mode_variance(mode) if mode in self.fix_types
                              else self.variance)
        return v


def validate_overrides(preset: str, overrides: Any) -> None:
    """Check ``gps.overrides`` for preset ``preset`` without keeping a sensor.

    Raises ValueError with a one-line message naming the key, the value and what is allowed for
    any unknown key, wrong type (a string or bool where a number is due, a non-table where a
    table is due), NaN/inf, out-of-range value or badly nested table.  It merges the overrides
    into the preset and builds the sensor's components once (cheap: nothing is drawn), so every
    check the run would make is made here.
    """
    GpsSensor.from_config(apply_overrides(preset, overrides), 0)
