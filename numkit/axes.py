"""Component names of 3-vectors and quaternions, so kernels index by name (``v[Z]``, ``q[QW]``,
``pts[:, XY]``).

Vectors are ``(x, y, z)`` in the frame the caller states (the world frame is ENU: x east,
y north, z up); quaternions are scalar-first ``(w, x, y, z)``, as MuJoCo stores them (the
entries of a flat row-major rotation matrix are named in :mod:`numkit.geometry`: ``R[RZX]``).
"""

X, Y, Z = 0, 1, 2
QW, QX, QY, QZ = 0, 1, 2, 3
#: the horizontal components (x, y): ``v[XY]``, ``points[:, XY]``
XY = slice(X, Z)

__all__ = ["QW", "QX", "QY", "QZ", "XY", "X", "Y", "Z"]
