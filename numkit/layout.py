"""Flat arrays declared once by name and size.

A :class:`Layout` lists an array's fields in order (``"name"`` one slot, ``"name:3"`` three,
``"name:3x15"`` a 3 × 15 block); the offsets, widths and total size follow from it, so no
offset is kept by hand.  Kernels read a layout's offsets through :attr:`Layout.at`, a named
tuple that numba freezes into the compiled code as constants::

    S = Layout("pos:3 vel:3 quat:4 ba:3 bg:3").at
    q = x[S.QUAT:S.QUAT_END]        # the attitude quaternion
    x[S.VEL + k] += dt * f[k]       # v ← v + Δt f

Each field ``name`` gives ``NAME`` (its offset) and ``NAME_END`` (offset + width); ``SIZE`` is
the array's length.
"""

from __future__ import annotations

from collections import namedtuple
from math import prod

__all__ = ["Layout"]


class Layout:
    """Named fields of a flat array, in order: ``Layout("dt g r_ant:3 H:3x15")``.

    ``offset[name]``, ``shape[name]``, ``width[name]``, ``size``, ``offsets`` (in declaration
    order), ``slice(name)`` and ``at`` (the named tuple of offsets the kernels index by)."""

    def __init__(self, fields: str) -> None:
        self.offset: dict[str, int] = {}
        self.shape: dict[str, tuple[int, ...]] = {}
        self.width: dict[str, int] = {}
        o = 0
        for f in fields.split():
            name, _, dims = f.partition(":")
            if not name.isidentifier() or name in self.offset:
                raise ValueError(f"layout field {name!r}: a new Python identifier is required")
            shape = tuple(int(d) for d in dims.split("x")) if dims else (1,)
            if any(d < 1 for d in shape):
                raise ValueError(f"layout field {name!r}: every dimension must be ≥ 1")
            self.offset[name], self.shape[name], self.width[name] = o, shape, prod(shape)
            o += self.width[name]
        self.size = o
        self.offsets = tuple(self.offset.values())
        names = [n.upper() for n in self.offset]
        if len(set(names)) != len(names):
            raise ValueError(f"layout fields {fields!r}: names must differ in more than case")
        keys = [k for n in names for k in (n, n + "_END")] + ["SIZE"]
        vals = [v for n in self.offset for v in (self.offset[n], self.offset[n] + self.width[n])]
        self.at = namedtuple("LayoutAt", keys)(*vals, self.size)

    def slice(self, name: str) -> slice:
        """The field's slots."""
        return slice(self.offset[name], self.offset[name] + self.width[name])

    def __repr__(self) -> str:
        return "Layout(" + " ".join(
            n + ("" if s == (1,) else ":" + "x".join(map(str, s))) for n, s in self.shape.items()
        ) + ")"
