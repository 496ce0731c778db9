"""What an honest receiver reports beside each fix: its reported type, accuracy and false
fixes."""

from __future__ import annotations

import math
from collections import deque
from collections.abc import Sequence

import numpy as np

from .checks import SeedLike, as_seedseq, derive_seed


class ReceiverReport:
    """What a receiver with fix types reports beside each fix, and its false fixes.

    Called once per delivered fix with the fix type the error chain is in
    (:attr:`GpsSensor.last_fix_type`); returns ``(bias (3), reported type, accuracy scale)``:

    * **False fixes.** While the true type is ``fixed`` (default ``"rtk-fixed"``) a false-fix
      episode starts with probability ``1 − exp(−λ Δt)`` per fix (λ = ``per_hour`` / 3600):
      the receiver resolved wrong integer ambiguities and reports RTK fixed with a constant 3-D
      bias ``b = m u`` (``m ~ U(bias_m)``, ``u`` uniform on the sphere) for ``T ~ Exp(mean_s)``,
      or until the true type leaves fixed. The reported type stays ``fixed`` throughout.
    * **Late fix-type reports.** The reported type is the true type ``lag`` fixes back
      (``lag = round(report_lag_s · rate)``): a receiver declares a loss of fix after its own
      consistency checks fail, not at the first bad epoch.
    * **Accuracy calibration.** Each reported-type episode (a run of one reported type) draws
      ``s = exp(σ_c ξ)``: the reported accuracy is ``s`` times the type's true standard
      deviation (``σ_c`` = ``calibration_sigma``), as a receiver's hAcc is a model, not a
      measurement.

    All figures are engineering judgement (docs/gnss.md). Randomness: three Generators keyed
    ``"false_fix"``, ``"false_fix_shape"``, ``"calibration"`` from ``seed`` (the run's spare
    stream, so no other draw of the run changes).
    """

    def __init__(self, rate_hz: float, seed: SeedLike, *, per_hour: float = 3.0,
                 mean_s: float = 30.0, bias_m: Sequence[float] = (0.1, 0.4),
                 calibration_sigma: float = 0.3, report_lag_s: float = 1.0,
                 fixed: str = "rtk-fixed") -> None:
        ss = as_seedseq(seed)
        self._rng_ff = np.random.Generator(np.random.PCG64(derive_seed(ss, "false_fix")))
        self._rng_shape = np.random.Generator(np.random.PCG64(derive_seed(ss, "false_fix_shape")))
        self._rng_cal = np.random.Generator(np.random.PCG64(derive_seed(ss, "calibration")))
        self.dt = 1.0 / rate_hz
        self.p_start = 1.0 - math.exp(-per_hour / 3600.0 * self.dt)
        self.mean_s, self.bias_m = float(mean_s), (float(bias_m[0]), float(bias_m[1]))
        self.cal_sigma = float(calibration_sigma)
        self.lag = int(round(report_lag_s * rate_hz))
        self.fixed = fixed
        self._types: deque[str | None] = deque()
        self._left = 0                       # fixes left in the current false fix
        self.bias = np.zeros(3)
        self.reported: str | None = None
        self.scale = 1.0
        self.n_false = 0                     # false-fix episodes started
        self.false_fixes = 0                 # fixes delivered inside one
        self.in_false = False                # whether the last fix was inside one

    def step(self, true_type: str | None) -> tuple[np.ndarray, str | None, float]:
        """One delivered fix: (bias to add, reported type, reported accuracy scale)."""
        if true_type != self.fixed:
            self._left = 0
        elif self._left <= 0 and self._rng_ff.random() < self.p_start:
            u = self._rng_shape.standard_normal(3)
            u /= max(float(np.linalg.norm(u)), 1e-12)
            self.bias = u * self._rng_shape.uniform(*self.bias_m)
            self._left = max(1, int(round(self._rng_shape.exponential(self.mean_s) / self.dt)))
            self.n_false += 1
        in_false = self.in_false = self._left > 0
        if in_false:
            self._left -= 1
            self.false_fixes += 1
        self._types.append(true_type)
        rep = self._types.popleft() if len(self._types) > self.lag else self._types[0]
        if rep != self.reported:
            self.reported = rep
            self.scale = math.exp(self.cal_sigma * self._rng_cal.standard_normal())
        return (self.bias if in_false else _ZERO3), rep, self.scale


_ZERO3 = np.zeros(3)
