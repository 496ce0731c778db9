"""Seeds and strict value checks shared by the GPS models.

Every stream of a sensor is a child :class:`numpy.random.SeedSequence` keyed by a stable path
(:func:`derive_seed`); every config value is checked strictly, and a bad one raises a
ValueError with one line naming the key, the value and what is allowed (:func:`bad`).
"""

from __future__ import annotations

import math
import zlib
from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np

SeedLike = np.random.SeedSequence | int


def as_seedseq(seed: SeedLike) -> np.random.SeedSequence:
    if isinstance(seed, np.random.SeedSequence):
        return seed
    if isinstance(seed, (int, np.integer)) and not isinstance(seed, bool) and seed >= 0:
        return np.random.SeedSequence(int(seed))
    raise ValueError(f"seed = {seed!r} is invalid; must be a numpy SeedSequence or an int >= 0")


def derive_seed(root: SeedLike, *key: str | int) -> np.random.SeedSequence:
    """Child SeedSequence of ``root`` keyed by a stable path (strings hashed with CRC32).

    Unlike ``SeedSequence.spawn`` the child does not depend on how many children were made before,
    so streams keyed by name are independent of the set and order of components.
    """
    ss = as_seedseq(root)
    parts = tuple(zlib.crc32(k.encode()) if isinstance(k, str) else int(k) for k in key)
    return np.random.SeedSequence(entropy=ss.entropy, spawn_key=tuple(ss.spawn_key) + parts)


def rngs(seed: SeedLike, n: int) -> list[np.random.Generator]:
    """``n`` independent Generators (one per random role of a component) from ``seed``."""
    ss = as_seedseq(seed)
    return [
        np.random.Generator(np.random.PCG64(derive_seed(ss, "role", i))) for i in range(n)
    ]


def bad(who: str, key: str, value: Any, allowed: str) -> ValueError:
    return ValueError(f"{who}: {key} = {value!r} is invalid; {allowed}")


def real(who: str, key: str, value: Any, allowed: str = "must be a number") -> float:
    """``value`` as a float, strictly: a bool, a string or anything else that is not a real
    number is refused (``float("0.5")`` and ``float(True)`` would silently accept them)."""
    if isinstance(value, (bool, np.bool_)) or not isinstance(value, (int, float, np.integer,
                                                                      np.floating)):
        raise bad(who, key, value, allowed)
    return float(value)


def check_pos(
    who: str, key: str, value: Any, *, allow_zero: bool = False, le: float | None = None
) -> float:
    rng = (">= 0" if allow_zero else "> 0") + ("" if le is None else f" and <= {le:g}")
    v = real(who, key, value, f"must be a finite number {rng}")
    ok = math.isfinite(v) and (v >= 0.0 if allow_zero else v > 0.0)
    if ok and le is not None:
        ok = v <= le
    if not ok:
        raise bad(who, key, value, f"must be finite and {rng}")
    return v


def check_axis_scale(who: str, value: Any) -> tuple[float, float, float]:
    allowed = "must be a list of 3 finite numbers >= 0"
    if isinstance(value, (str, bytes, Mapping)) or not isinstance(value, (Sequence, np.ndarray)):
        raise bad(who, "axis_scale", value, allowed)
    if len(value) != 3:
        raise bad(who, "axis_scale", value, allowed)
    out = []
    for x in value:
        if isinstance(x, (bool, np.bool_)) or not isinstance(x, (int, float, np.integer,
                                                                 np.floating)):
            raise bad(who, "axis_scale", value, allowed)
        f = float(x)
        if not (math.isfinite(f) and f >= 0.0):
            raise bad(who, "axis_scale", value, allowed)
        out.append(f)
    return out[0], out[1], out[2]
