"""The first-order recursion behind every Gauss–Markov and AR(1) error process of the sensors:

    y_k = φ y_{k−1} + g x_k,    y_{−1} given,

per column of a block of drive numbers ``x``. It is what ``scipy.signal.lfilter([g], [1, −φ],
x, zi=[φ y_{−1}])`` computes (its direct form II transposed: ``y_k = z + g x_k``, then
``z = φ y_k``), to the last bit (``tests/test_ar1.py`` holds it to lfilter over random draws).
It is written here so that a flight does not import ``scipy.signal``, which pulls in
``scipy.stats`` and more: about 60 MB of resident memory and half a second at every start
(docs/speed.md)."""

from __future__ import annotations

import numpy as np

from .._jit import njit

__all__ = ["ar1_filter"]


@njit(cache=True)
def _ar1_into(x: np.ndarray, g: float, phi: float, z0: np.ndarray,
              y: np.ndarray) -> None:  # pragma: no cover - compiled
    for j in range(x.shape[1]):
        z = z0[j]
        for k in range(x.shape[0]):
            v = z + g * x[k, j]
            y[k, j] = v
            z = phi * v


def ar1_filter(x: np.ndarray, g: float, phi: float, z0: np.ndarray | float) -> np.ndarray:
    """``y`` with ``y_k = z + g x_k``, ``z ← φ y_k`` down the first axis of ``x`` (1-D, or 2-D
    with one column per process), ``z`` starting at ``z0`` (one value per column: ``φ y_{−1}``,
    as lfilter's ``zi``). Returns an array of ``x``'s shape."""
    x = np.asarray(x, dtype=np.float64)
    x2 = np.ascontiguousarray(x.reshape(x.shape[0], -1))
    z = np.ascontiguousarray(np.broadcast_to(np.asarray(z0, dtype=np.float64).ravel(),
                                             (x2.shape[1],)))
    y = np.empty_like(x2)
    _ar1_into(x2, float(g), float(phi), z, y)
    return y.reshape(x.shape)
