"""ag-uav estimator bank: KF, MCKF, PCA-KF, PCA-MCKF and coloured-noise baselines.

Standalone (numpy/scipy only).  Every filter has ``predict()``, ``update(z) -> bool`` and the
attributes ``x``, ``P`` (and ``y``, ``S``, ``K``, ``nis`` after an update); ``update(None)`` or
a fix with NaN/inf is "no fix".  Build by name with :func:`make` (see :mod:`estimators.registry`),
motion models in :mod:`estimators.models`.
"""

from .coloured import BiasAugmentedKF, DifferencingKF
from .kf import KF
from .mckf import MCKF
from .models import LinearModel, motion_model, paper_numerical_model
from .pca import PCAKF, PCAMCKF, PCABlock
from .registry import available, make

__all__ = [
    "KF",
    "MCKF",
    "PCAKF",
    "PCAMCKF",
    "BiasAugmentedKF",
    "DifferencingKF",
    "LinearModel",
    "PCABlock",
    "available",
    "make",
    "motion_model",
    "paper_numerical_model",
]
