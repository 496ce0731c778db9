"""Independent references for the estimator laws, written here in plain numpy (the product's
laws live once, as the compiled row functions of ``estimators``; these do not import them).

- KF: filterpy's ``KalmanFilter`` (Joseph form), in the tests themselves.
- MCKF: :class:`tests.oracles.mckf.OracleMCKF`, the vectorised whitened fixed point with the
  Cholesky handling, the lock-out recovery rules and the adaptive bandwidth.
- PCA: :class:`tests.oracles.pca.OraclePCABlock` (LAPACK ``dsyevr`` / ``eigh`` readings of
  both modes) and the PCA-KF / PCA-MCKF compositions.
"""
