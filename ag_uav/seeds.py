"""The run's random streams: every random draw of a run comes from a Generator spawned from the
run seed, one stream per consumer, so the same config and seed give the same run, serial or
parallel, and adding a consumer never changes the others' draws."""

from __future__ import annotations

import numpy as np

#: Names of the seeded random streams; appending a name never changes the others' draws.
STREAMS = ("wind", "gps", "estimator", "altimeter", "imu", "attitude", "spare4", "spare5",
           "forecast", "meander")


def seed_sequences(seed: int) -> dict[str, np.random.SeedSequence]:
    """One independent SeedSequence per consumer, spawned from ``SeedSequence(seed)``."""
    children = np.random.SeedSequence(seed).spawn(len(STREAMS))
    return dict(zip(STREAMS, children, strict=True))


def rng_streams(seed: int) -> dict[str, np.random.Generator]:
    """One independent Generator per consumer (see :func:`seed_sequences`)."""
    return {name: np.random.default_rng(s) for name, s in seed_sequences(seed).items()}
