"""The N / Z / P input sets of the fuzzy PD cores, described with scikit-fuzzy primitives.

This module is the *reference* description of the antecedents (the Kumbasar-group IT2-FPID,
see :mod:`controllers.fpid`) for figures and checks; it is never used in the per-tick loop (the
cores in :mod:`controllers.fuzzy` evaluate the same functions in a few scalar float operations).

Sets on the clipped input domain [-1, 1], built with :func:`skfuzzy.trimf`:

    UMF_N = trimf(x, [-1.8, -1, 0]),  UMF_Z = trimf(x, [-1, 0, 1]),  UMF_P = trimf(x, [0, 1, 1.8])
    LMF_i = h_i · UMF_i,   (h_N, h_Z, h_P) = (1 - α, α, 1 - α)   (Candan & Li, Table I's α)

The footprint of uncertainty (FOU) of set i is the band between LMF_i and UMF_i.

:class:`SkfuzzyT1FPD` is a type-1 fuzzy PD core built from these primitives in skfuzzy's
functional style (membership by ``trimf``, product t-norm of the grades, weighted average of
the singleton consequents). It is written independently of
:class:`controllers.fuzzy.T1FuzzyPD` and serves as its oracle (tests: equal to 1e-9 on a grid).
:func:`firing_strengths` gives the IT2 upper and lower firing strengths of the nine rules from
the same primitives (oracle of :meth:`controllers.fuzzy.IT2FuzzyPD.firing`).
Importing this module needs scikit-fuzzy (a runtime dependency); :mod:`controllers` itself does
not import it, so the control loop never loads it.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
import skfuzzy as fuzz

__all__ = [
    "SET_NAMES",
    "UMF_ABC",
    "SkfuzzyT1FPD",
    "firing_strengths",
    "lower_memberships",
    "upper_memberships",
]

SET_NAMES = ("N", "Z", "P")
#: Triangle feet/peak (a, b, c) of the upper membership functions.
UMF_ABC: dict[str, tuple[float, float, float]] = {
    "N": (-1.8, -1.0, 0.0),
    "Z": (-1.0, 0.0, 1.0),
    "P": (0.0, 1.0, 1.8),
}
_RANK = {"N": 0, "Z": 1, "P": 2}


def _heights(alpha: float, heights: Sequence[float] | None) -> tuple[float, float, float]:
    if heights is not None:
        return tuple(float(h) for h in heights)  # type: ignore[return-value]
    return (1.0 - float(alpha), float(alpha), 1.0 - float(alpha))


def upper_memberships(x: np.ndarray) -> dict[str, np.ndarray]:
    """UMF_N, UMF_Z, UMF_P of the clipped input ``clip(x, -1, 1)`` (skfuzzy ``trimf``)."""
    xc = np.clip(np.asarray(x, dtype=float), -1.0, 1.0)
    flat = xc.reshape(-1)
    return {s: fuzz.trimf(flat, list(UMF_ABC[s])).reshape(xc.shape) for s in SET_NAMES}


def lower_memberships(
    x: np.ndarray, alpha: float = 0.5, heights: Sequence[float] | None = None
) -> dict[str, np.ndarray]:
    """LMF_i = h_i · UMF_i with (h_N, h_Z, h_P) = (1-α, α, 1-α) or explicit ``heights``."""
    h = dict(zip(SET_NAMES, _heights(alpha, heights), strict=True))
    return {s: h[s] * m for s, m in upper_memberships(x).items()}


def firing_strengths(
    E: np.ndarray,
    dE: np.ndarray,
    alpha: float = 0.5,
    cm: float = 0.7,
    heights: Sequence[float] | None = None,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Nine rules (E set i, dE set j, row-major N/Z/P): (y, f_lower, f_upper).

    Product t-norm: f̄_ij = UMF_i(E)·UMF_j(dE), f_ij = LMF_i(E)·LMF_j(dE); consequent
    y_ij = (-1, -c_m, 0, c_m, 1)[r_i + r_j] with r = (0, 1, 2) for (N, Z, P).
    """
    E, dE = np.broadcast_arrays(np.asarray(E, float), np.asarray(dE, float))
    ue, ud = upper_memberships(E), upper_memberships(dE)
    le, ld = lower_memberships(E, alpha, heights), lower_memberships(dE, alpha, heights)
    table = (-1.0, -float(cm), 0.0, float(cm), 1.0)
    ys, fl, fu = [], [], []
    for i in SET_NAMES:
        for j in SET_NAMES:
            ys.append(table[_RANK[i] + _RANK[j]])
            fu.append(ue[i] * ud[j])
            fl.append(le[i] * ld[j])
    return np.array(ys), np.array(fl), np.array(fu)


class SkfuzzyT1FPD:
    """Type-1 fuzzy PD core from skfuzzy primitives (reference, not for the control loop).

    Φ(E, dE) = Σ_ij μ_i(E) μ_j(dE) y_ij / Σ_ij μ_i(E) μ_j(dE)

    with μ the skfuzzy ``trimf`` UMFs above, product t-norm of the membership grades and
    singleton consequents (zero-order Takagi–Sugeno, weighted-average
    defuzzification). Same rule base as :class:`controllers.fuzzy.T1FuzzyPD`.
    """

    def __init__(self, cm: float = 0.7) -> None:
        self.cm = float(cm)

    def __call__(self, E: np.ndarray, dE: np.ndarray) -> np.ndarray:
        E, dE = np.broadcast_arrays(np.asarray(E, float), np.asarray(dE, float))
        shape = E.shape
        ue, ud = upper_memberships(E.reshape(-1)), upper_memberships(dE.reshape(-1))
        table = (-1.0, -self.cm, 0.0, self.cm, 1.0)
        num = np.zeros(E.size)
        den = np.zeros(E.size)
        for i in SET_NAMES:
            for j in SET_NAMES:
                w = ue[i] * ud[j]  # product t-norm of the two membership grades
                num += w * table[_RANK[i] + _RANK[j]]
                den += w
        return (num / den).reshape(shape)
