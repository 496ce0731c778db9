"""Build any filter of the bank by name: ``estimators.make(name, **params)``.

Names (``available()``)::

    "kf"        KF                      "pca-kf"    PCAKF (PCA block + KF)
    "mckf"      MCKF                    "pca-mckf"  PCAMCKF (PCA block + MCKF)
    "kf-bias"   BiasAugmentedKF         "kf-diff"   DifferencingKF

Two ways to give the model:

1. Explicit matrices: ``make("kf", F=F, H=H, Q=Q, R=R, x0=x0, P0=P0)``.
2. A motion model (see :mod:`estimators.models`)::

       make("pca-mckf", model="cv", dim=2, dt=0.05, q=1.0, r=4.0, x0=x0, sigma=2.0, window=20)

   ``model`` ("cv" | "ca" | "cvb"), ``dim`` (1, 2, 3, "2d+alt"), ``dt`` (the ``predict()`` period),
   ``q``, ``r`` (scalars or per axis), ``q_form``, ``q_alt``, ``r_alt`` build F, Q, H, R;
   any of F, H, Q, R given explicitly overrides the model's.  ``P0`` defaults to ``p0 · I``
   (``p0`` = 100, i.e. 10 m / 10 m/s std) and ``x0`` to zeros.  The model is attached to the
   filter as ``filt.model`` (``None`` for explicit builds) for ``pos_idx``/``vel_idx``.

Every other keyword goes to the filter's constructor (e.g. ``sigma``, ``max_iter``,
``recovery`` for the MCKFs; ``window``, ``mode``, ``n_components``, ``embed`` for the PCA
filters; ``tau``, ``sigma_b`` for "kf-bias"; ``gamma`` or ``tau`` for "kf-diff").  For
"kf-bias" and "kf-diff" with ``tau`` the model's ``dt`` is passed on as ``dt`` unless given.
An unknown name raises ``ValueError`` listing the allowed ones; an unknown keyword raises the
constructor's ``TypeError``.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from .coloured import BiasAugmentedKF, DifferencingKF
from .kf import KF
from .mckf import MCKF
from .models import motion_model
from .pca import PCAKF, PCAMCKF

__all__ = ["FILTERS", "available", "make"]

FILTERS: dict[str, type] = {
    "kf": KF,
    "mckf": MCKF,
    "pca-kf": PCAKF,
    "pca-mckf": PCAMCKF,
    "kf-bias": BiasAugmentedKF,
    "kf-diff": DifferencingKF,
}

_MODEL_KEYS = ("dim", "q", "r", "q_form", "q_alt", "r_alt", "q_bias")


def available() -> list[str]:
    """Names accepted by :func:`make`."""
    return list(FILTERS)


def make(name: str, **params: Any):
    """Construct the filter ``name``; see the module docstring for the parameters."""
    key = name.lower() if isinstance(name, str) else name
    if key not in FILTERS:
        raise ValueError(f"unknown estimator {name!r}; allowed: {', '.join(FILTERS)}")
    cls = FILTERS[key]
    kind = params.pop("model", None)
    p0 = params.pop("p0", 100.0)
    mdl = None
    if kind is not None:
        margs = {k: params.pop(k) for k in _MODEL_KEYS if k in params}
        dt = params.pop("dt", 0.05)
        mdl = motion_model(kind, dt=dt, **margs)
        for mat in ("F", "H", "Q", "R"):
            params.setdefault(mat, getattr(mdl, mat))
        params.setdefault("x0", np.zeros(mdl.n))
        params.setdefault("P0", p0 * np.eye(mdl.n))
        if key == "kf-bias" or (key == "kf-diff" and "tau" in params):
            params.setdefault("dt", dt)
    else:
        leftover = [k for k in _MODEL_KEYS if k in params]
        if leftover:
            raise ValueError(f"{leftover} need model='cv' or 'ca'")
    missing = [k for k in ("F", "H", "Q", "R") if k not in params]
    if missing:
        raise ValueError(f"{name}: give model=... or the matrices {missing}")
    filt = cls(**params)
    filt.model = mdl
    return filt
