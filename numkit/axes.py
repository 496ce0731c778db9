"""Component names of 3-vectors, quaternions and flat 3 × 3 matrices, so kernels index by name
(``v[Z]``, ``q[QW]``, ``R[R_ZZ]``, ``pts[:, XY]``).

Vectors are ``(x, y, z)`` in the frame the caller states (the world frame is ENU: x east,
y north, z up); quaternions are scalar-first ``(w, x, y, z)``, as MuJoCo stores them; a 3 × 3
matrix stored flat is row-major, ``R_ij`` at ``3 i + j`` (``R[R_ZX]``: row z, column x).
"""

X, Y, Z = 0, 1, 2
QW, QX, QY, QZ = 0, 1, 2, 3
#: the horizontal components (x, y): ``v[XY]``, ``points[:, XY]``
XY = slice(X, Z)
R_XX, R_XY, R_XZ = 3 * X + X, 3 * X + Y, 3 * X + Z
R_YX, R_YY, R_YZ = 3 * Y + X, 3 * Y + Y, 3 * Y + Z
R_ZX, R_ZY, R_ZZ = 3 * Z + X, 3 * Z + Y, 3 * Z + Z

__all__ = ["QW", "QX", "QY", "QZ", "R_XX", "R_XY", "R_XZ", "R_YX", "R_YY", "R_YZ", "R_ZX", "R_ZY",
           "R_ZZ", "XY", "X", "Y", "Z"]
