"""Component names of 3-vectors and quaternions, so kernels index by name (``v[Z]``, ``q[QW]``).

Vectors are ``(x, y, z)`` in the frame the caller states (the world frame is ENU: x east,
y north, z up); quaternions are scalar-first ``(w, x, y, z)``, as MuJoCo stores them.
"""

X, Y, Z = 0, 1, 2
QW, QX, QY, QZ = 0, 1, 2, 3

__all__ = ["QW", "QX", "QY", "QZ", "X", "Y", "Z"]
