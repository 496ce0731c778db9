"""The blocks a compiled law works on: a controller's parameter block and state block.

Each compiled law of :mod:`controllers` (the axis law, the attitude law, the mixer) reads one
parameter block and advances one state block, flat float64 arrays laid out as its module says.
The Python shells keep theirs behind :class:`RowBlocks`; a
:class:`~controllers.cascade.PositionCascade` adopts them, so they become views of the
cascade's own rows and one compiled call advances the whole cascade.
"""

from __future__ import annotations

import numpy as np

__all__ = ["RowBlocks"]


class RowBlocks:
    """A parameter block and a state block (views that a cascade may adopt)."""

    _p: np.ndarray
    _s: np.ndarray

    @property
    def param_block(self) -> np.ndarray:
        """The parameter block the law reads (a view of the adopting cascade's row)."""
        return self._p

    @property
    def state_block(self) -> np.ndarray:
        """The state block the law advances (a view of the adopting cascade's row)."""
        return self._s

    def adopt_blocks(self, p: np.ndarray, s: np.ndarray, copy: bool) -> None:
        """Work on ``p`` and ``s`` from now on (a cascade's row slices, of the blocks' sizes),
        first copying the current values into them when ``copy``."""
        if copy:
            p[:] = self._p
            s[:] = self._s
        self._p = p
        self._s = s
