"""Inner loops of the multirotor cascade: thrust vectoring, attitude control and the mixer.

The laws are compiled functions (numba via :mod:`controllers._jit`), each written once:
:func:`thrust_attitude`, :func:`geometric_torque` and its row form :func:`attitude_step`, and the
mixer :func:`mix_step`. The classes :class:`GeometricAttitudeController` and :class:`XMixer` are
thin shells that call them on their own small parameter/state blocks; the cascade row
(:func:`controllers.cascade.vehicle_step`) and the batch kernel (:mod:`controllers.batched`) call
the same functions on slices of a vehicle's row.

Frames: world ENU (x east, y north, z up), body FLU (x forward, y left, z up). A rotation matrix
``R`` maps body to world and is stored row-major as a 9-tuple ``(r00, r01, r02, r10, ...)``.

References
----------
T. Lee, M. Leok, N. H. McClamroch, "Geometric tracking control of a quadrotor UAV on SE(3)",
IEEE CDC 2010 (attitude error e_R = ½ vee(R_dᵀR − RᵀR_d), thrust f = (m a_d)·R e3).
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np

from numkit import Layout, X, Y, Z
from numkit.geometry import RXX, RXY, RXZ, RYX, RYY, RYZ, RZX, RZY, RZZ

from ._jit import njit
from .rows import RowBlocks

Mat3 = tuple[float, float, float, float, float, float, float, float, float]
Vec3 = tuple[float, float, float]


@njit
def thrust_attitude(ax: float, ay: float, az: float, yaw: float, mass: float, g: float,
                    tilt_max: float) -> tuple[Mat3, float, float]:
    """Desired attitude and collective thrust for a desired acceleration (world frame).

    The desired force is ``f = m (a + g e3)``; its horizontal part is scaled down so that the tilt
    stays below ``tilt_max`` (rad) and its vertical part is kept ≥ 0.2 m g. The desired body z axis
    is ``f/|f|``; the body x axis is the heading ``yaw`` projected into the plane normal to it.

    Returns ``(R_d, |f|, tilt)`` with ``R_d`` row-major.
    """
    fx, fy, fz = mass * ax, mass * ay, mass * (az + g)
    fz_min = 0.2 * mass * g
    if fz < fz_min:
        fz = fz_min
    fh = math.hypot(fx, fy)
    fh_max = fz * math.tan(tilt_max)
    if fh > fh_max:
        s = fh_max / fh
        fx *= s
        fy *= s
        fh = fh_max
    fn = math.sqrt(fx * fx + fy * fy + fz * fz)
    b3x, b3y, b3z = fx / fn, fy / fn, fz / fn
    cx, cy = math.cos(yaw), math.sin(yaw)
    # b2 = b3 × c, c = (cx, cy, 0)
    b2x, b2y, b2z = -b3z * cy, b3z * cx, b3x * cy - b3y * cx
    n2 = math.sqrt(b2x * b2x + b2y * b2y + b2z * b2z)
    b2x, b2y, b2z = b2x / n2, b2y / n2, b2z / n2
    # b1 = b2 × b3
    b1x = b2y * b3z - b2z * b3y
    b1y = b2z * b3x - b2x * b3z
    b1z = b2x * b3y - b2y * b3x
    R_d = (b1x, b2x, b3x, b1y, b2y, b3y, b1z, b2z, b3z)
    return R_d, fn, math.atan2(fh, fz)


@njit
def geometric_torque(R: Mat3, omega: Sequence[float], R_d: Mat3, J: Sequence[float],
                     kR: Sequence[float], kw: Sequence[float]) -> tuple[Vec3, Vec3]:
    """The law of :class:`GeometricAttitudeController`: ``(τ, e_R)`` for attitude R, body rates
    omega, target R_d, inertia J and gains kR, kw (any indexables of floats)."""
    r = R
    d = R_d
    # M = R_dᵀ R  (only the off-diagonal entries are needed for vee(M − Mᵀ))
    # m_ij = Σ_k d_ki r_kj
    m01 = d[RXX] * r[RXY] + d[RYX] * r[RYY] + d[RZX] * r[RZY]
    m02 = d[RXX] * r[RXZ] + d[RYX] * r[RYZ] + d[RZX] * r[RZZ]
    m10 = d[RXY] * r[RXX] + d[RYY] * r[RYX] + d[RZY] * r[RZX]
    m12 = d[RXY] * r[RXZ] + d[RYY] * r[RYZ] + d[RZY] * r[RZZ]
    m20 = d[RXZ] * r[RXX] + d[RYZ] * r[RYX] + d[RZZ] * r[RZX]
    m21 = d[RXZ] * r[RXY] + d[RYZ] * r[RYY] + d[RZZ] * r[RZY]
    ex = 0.5 * (m21 - m12)
    ey = 0.5 * (m02 - m20)
    ez = 0.5 * (m10 - m01)
    wx, wy, wz = omega[X], omega[Y], omega[Z]
    Jx, Jy, Jz = J[X], J[Y], J[Z]
    # ω × Jω
    gx = wy * Jz * wz - wz * Jy * wy
    gy = wz * Jx * wx - wx * Jz * wz
    gz = wx * Jy * wy - wy * Jx * wx
    # τ = −k_R e_R − k_ω ω + ω × Jω
    return (
        (-kR[X] * ex - kw[X] * wx + gx, -kR[Y] * ey - kw[Y] * wy + gy,
         -kR[Z] * ez - kw[Z] * wz + gz),
        (ex, ey, ez),
    )


#: attitude block: parameters J, kR, kw (3 each); state τ, e_R (3 each)
ATT_PARAMS = Layout("j:3 kr:3 kw:3")
ATT_STATE = Layout("tau:3 er:3")
#: the wrench ``[T, τx, τy, τz]`` a rotor's allocation row weighs
WRENCH = Layout("t tx ty tz")
#: mixer block: parameters Ainv (MIX_NMAX × 4, row-major, one :data:`WRENCH` row per rotor),
#: f_max, number of rotors n; state: saturated flag
MIX_NMAX = 8
MIX_PARAMS = Layout(f"ainv:{MIX_NMAX}x{WRENCH.size} fmax n")
MIX_STATE = Layout("sat")
#: the scalar attitude shell's packed inputs: R, ω, R_d
_ATT_IN = Layout("r:9 omega:3 rd:9").at
_AP, _AS, _W = ATT_PARAMS.at, ATT_STATE.at, WRENCH.at
_MP, _MS = MIX_PARAMS.at, MIX_STATE.at


@njit
def attitude_step(prm: np.ndarray, st: np.ndarray, R: Sequence[float], omega: Sequence[float],
                  R_d: Sequence[float]) -> tuple[float, float, float]:
    """:func:`geometric_torque` on an attitude block (``prm``: J, kR, kw; ``st``: τ, e_R written
    here); returns τ."""
    tau, eR = geometric_torque(R, omega, R_d, prm[_AP.J:_AP.J_END], prm[_AP.KR:_AP.KR_END],
                               prm[_AP.KW:_AP.KW_END])
    st[_AS.TAU + X] = tau[X]
    st[_AS.TAU + Y] = tau[Y]
    st[_AS.TAU + Z] = tau[Z]
    st[_AS.ER + X] = eR[X]
    st[_AS.ER + Y] = eR[Y]
    st[_AS.ER + Z] = eR[Z]
    return tau


@njit
def _alloc_one(a: np.ndarray, i: int, T: float, tx: float, ty: float, tz: float) -> float:
    """Rotor ``i``'s thrust ``(Ainv [T, τx, τy, τz]ᵀ)_i`` (``a``: Ainv row-major)."""
    j = _W.SIZE * i
    return a[j + _W.T] * T + a[j + _W.TX] * tx + a[j + _W.TY] * ty + a[j + _W.TZ] * tz


@njit
def _yaw_frac(s: float, a: float, b: float, fmax: float) -> float:
    """One rotor's bound on the kept yaw fraction ``s`` (yaw-free thrust a, full thrust b)."""
    d = b - a
    if d > 0.0 and b > fmax:
        x = (fmax - a) / d
        if x < s:
            s = x
    elif d < 0.0 and b < 0.0:
        x = -a / d
        if x < s:
            s = x
    return s


@njit
def _clip0(v: float, fmax: float) -> float:
    """``min(fmax, max(0.0, v))``."""
    x = v if v > 0.0 else 0.0
    return x if x < fmax else fmax


@njit
def _yaw_free_range(a: np.ndarray, n: int, T: float, tx: float, ty: float) -> tuple[float, float]:
    """Lowest and highest rotor thrust of the yaw-free allocation ``Ainv [T, τx, τy, 0]``."""
    lo0 = math.inf
    hi0 = -math.inf
    for i in range(n):
        g = _alloc_one(a, i, T, tx, ty, 0.0)
        lo0 = min(lo0, g)
        hi0 = max(hi0, g)
    return lo0, hi0


@njit
def mix_step(prm: np.ndarray, st: np.ndarray, T: float, tx: float, ty: float, tz: float,
             out: np.ndarray) -> None:
    """The allocation with its saturation priority (:class:`XMixer`) on a mixer block
    (``prm``: Ainv, f_max, n; ``st``: saturated flag written here); writes the ``n`` rotor
    thrusts to ``out[:n]``.

    Not saturated: ``f = Ainv [T, τ]``. Otherwise, with ``g`` the yaw-free allocation: if ``g``
    fits ``[0, f_max]``, keep the largest yaw fraction s that fits (``g + s (f − g)``, linear in
    τz); else if its spread fits, shift the collective (the same thrust on every rotor; the
    frame's rows of ``Ainv`` for T are equal where the allocation is symmetric); else clip ``g``
    to ``[0, f_max]``. Roll and pitch come first, then the collective, then yaw (PX4's and
    Betaflight's priority).
    """
    a = prm[_MP.AINV:_MP.AINV_END]
    fmax = prm[_MP.FMAX]
    n = int(prm[_MP.N])
    lo = math.inf
    hi = -math.inf
    for i in range(n):
        f = _alloc_one(a, i, T, tx, ty, tz)
        out[i] = f
        lo = min(lo, f)
        hi = max(hi, f)
    sat = lo < 0.0 or hi > fmax
    st[_MS.SAT] = 1.0 if sat else 0.0
    if not sat:
        return
    lo0, hi0 = _yaw_free_range(a, n, T, tx, ty)  # 1. drop yaw
    if lo0 >= 0.0 and hi0 <= fmax:
        s = 1.0
        for i in range(n):
            s = _yaw_frac(s, _alloc_one(a, i, T, tx, ty, 0.0), out[i], fmax)
        for i in range(n):
            g = _alloc_one(a, i, T, tx, ty, 0.0)
            out[i] = g + s * (out[i] - g)
    elif hi0 - lo0 <= fmax:  # 2. shift the collective to keep roll/pitch
        shift = -lo0 if lo0 < 0.0 else fmax - hi0
        for i in range(n):
            out[i] = _alloc_one(a, i, T, tx, ty, 0.0) + shift
    else:  # 3. roll/pitch alone exceed the range: clip
        for i in range(n):
            out[i] = _clip0(_alloc_one(a, i, T, tx, ty, 0.0), fmax)


@njit
def _attitude_call(prm: np.ndarray, st: np.ndarray, x: np.ndarray) -> tuple[float, float, float]:
    """:func:`attitude_step` with R, ω, R_d packed in ``x`` (``_ATT_IN``)."""
    return attitude_step(prm, st, x[_ATT_IN.R:_ATT_IN.R_END], x[_ATT_IN.OMEGA:_ATT_IN.OMEGA_END],
                         x[_ATT_IN.RD:_ATT_IN.RD_END])


def _vec3(arr: np.ndarray) -> Vec3:
    return (float(arr[X]), float(arr[Y]), float(arr[Z]))


class GeometricAttitudeController(RowBlocks):
    """PD attitude control on SO(3) (Lee et al. 2010) with gyroscopic compensation.

    ``τ = J (−ω_n² e_R − 2ζω_n e_ω) + ω × Jω`` per body axis, with
    ``e_R = ½ vee(R_dᵀR − RᵀR_d)`` and ``e_ω = ω`` (the set point's angular rate is taken as zero,
    which is what a cascade with a slower outer loop needs). Law: :func:`attitude_step`.

    Parameters
    ----------
    inertia: principal moments (Jx, Jy, Jz) in kg m² (body axes).
    wn: natural frequencies (rad/s) for roll, pitch, yaw.
    zeta: damping ratios for roll, pitch, yaw.

    ``J`` (writable: a draining tank changes it; the gains ``kR``, ``kw`` stay as built), ``kR``,
    ``kw`` and ``eR`` (last attitude error) live in the blocks ``_p`` (ATT_PARAMS) and ``_s``
    (ATT_STATE), which a :class:`~controllers.cascade.PositionCascade` adopts.
    """

    def __init__(self, inertia: Sequence[float], wn: Sequence[float] = (9.0, 9.0, 3.0),
                 zeta: Sequence[float] = (0.9, 0.9, 0.9)) -> None:
        J = tuple(float(v) for v in inertia)
        self._p = np.zeros(ATT_PARAMS.size)
        self._s = np.zeros(ATT_STATE.size)
        self._x = np.zeros(_ATT_IN.SIZE)
        self._p[ATT_PARAMS.slice("j")] = J
        # k_R = J ω_n², k_ω = 2 J ζ ω_n per axis
        self._p[ATT_PARAMS.slice("kr")] = [j * w * w for j, w in zip(J, wn, strict=True)]
        self._p[ATT_PARAMS.slice("kw")] = [2.0 * j * z * w
                                          for j, z, w in zip(J, zeta, wn, strict=True)]

    @property
    def J(self) -> Vec3:
        """Principal inertia (kg m²); writable."""
        return _vec3(self._p[ATT_PARAMS.slice("j")])

    @J.setter
    def J(self, value: Sequence[float]) -> None:
        self._p[ATT_PARAMS.slice("j")] = [float(v) for v in value]

    @property
    def kR(self) -> Vec3:
        """Attitude gains J ω_n²."""
        return _vec3(self._p[ATT_PARAMS.slice("kr")])

    @property
    def kw(self) -> Vec3:
        """Rate gains 2 J ζ ω_n."""
        return _vec3(self._p[ATT_PARAMS.slice("kw")])

    @property
    def eR(self) -> Vec3:
        """Last attitude error e_R."""
        return _vec3(self._s[ATT_STATE.slice("er")])

    def update(self, R: Mat3, omega: Sequence[float], R_d: Mat3) -> tuple[float, float, float]:
        """Body torques (τx, τy, τz) in N m for attitude R, body rates omega, target R_d."""
        x = self._x
        x[_ATT_IN.R:_ATT_IN.R_END] = R
        x[_ATT_IN.OMEGA:_ATT_IN.OMEGA_END] = omega
        x[_ATT_IN.RD:_ATT_IN.RD_END] = R_d
        return _attitude_call(self._p, self._s, x)


#: the least damping ratio the attitude loop keeps with the motor lag (:func:`lag_time_scale`)
LAG_DAMPING_MIN = 0.3


def lag_damping(r: float, zeta: float) -> float:
    """Damping ratio of the least-damped pole pair of one attitude axis with a motor lag.

    The axis ``J θ̈ = τ_a`` under the PD torque ``τ = −J (ω_n² θ + 2ζω_n θ̇)`` of
    :class:`GeometricAttitudeController` delivered through the first-order motor lag
    ``τ_m τ̇_a = τ − τ_a`` (the actuators' ``vehicle.motor_tau_s``) has the characteristic
    polynomial ``τ_m s³ + s² + 2ζω_n s + ω_n²``; in ``σ = τ_m s`` it is
    ``σ³ + σ² + 2ζ r σ + r²`` with ``r = ω_n τ_m``, so the damping depends on ``r`` and ``ζ``
    alone. Returns 1 when every pole is real."""
    roots = np.roots([1.0, 1.0, 2.0 * zeta * r, r * r])
    pair = roots[np.abs(roots.imag) > 1e-12]
    return float(np.min(-pair.real / np.abs(pair))) if pair.size else 1.0


def lag_time_scale(tau_m: float, wn: Sequence[float], zeta: Sequence[float],
                   zeta_min: float = LAG_DAMPING_MIN) -> float:
    """The time scale ``s`` in (0, 1] of the cascade for a motor lag ``tau_m`` (s).

    1 when every axis of ``wn``, ``zeta`` (rad/s and damping ratios of the attitude loop, the
    roll and pitch axes) keeps a closed-loop damping of at least ``zeta_min`` with the lag
    (:func:`lag_damping`); else the largest ``s`` with ``lag_damping(s ω_n τ_m, ζ) ≥ ζ_min`` on
    every axis (bisection). The cascade is then slowed as a whole by ``s`` (every loop's
    bandwidth times ``s``), so the position loop stays as much slower than the attitude loop as
    the tuning had it (a cascade's outer loop must stay well below its inner loop's bandwidth:
    Åström & Hägglund, *Advanced PID Control*, ISA 2006, on cascade control). The lag caps
    the bandwidth of a PD loop: with the default ``ω_n = 9`` rad/s and ``ζ = 0.9`` the damping
    is 0.53 at 0.04 s, 0.25 at 0.08 s and 0.12 at 0.12 s.

    A tuning damped below ``zeta_min`` without the lag (some ``ζ < zeta_min``) is the tuning's
    own choice, not the lag's doing: it is left as configured (1), and no ``s`` could reach
    ``zeta_min`` for it (the damping tends to ``ζ`` as ``s → 0``)."""
    if tau_m <= 0.0 or min(zeta) < zeta_min:
        return 1.0
    if all(lag_damping(w * tau_m, z) >= zeta_min for w, z in zip(wn, zeta, strict=True)):
        return 1.0
    lo, hi = 0.0, 1.0
    for _ in range(60):
        mid = 0.5 * (lo + hi)
        ok = all(lag_damping(mid * w * tau_m, z) >= zeta_min
                 for w, z in zip(wn, zeta, strict=True))
        lo, hi = (mid, hi) if ok else (lo, mid)
    return lo


def effectiveness(positions: Sequence[Sequence[float]], spin: Sequence[int], k_yaw: float,
                  eff: Sequence[float] | None = None) -> np.ndarray:
    """The frame's effectiveness matrix ``B`` (4 × n): ``[T, τx, τy, τz]ᵀ = B f``.

    Rotor ``i`` at ``(x_i, y_i)`` (body frame) pushes ``e_i f_i`` along body z (``e_i``: its
    thrust per unit of command, 1 for an isolated rotor, the coaxial efficiency for the lower
    rotor of a coaxial pair) with the yaw reaction torque ``s_i k e_i f_i``; column ``i`` is
    ``e_i [1, y_i, −x_i, s_i k]``.
    """
    n = len(positions)
    e = [1.0] * n if eff is None else [float(v) for v in eff]
    # (× 1.0 is exact: a four-rotor frame's B is the plain X-mixer matrix, bit for bit)
    return np.array([
        [e[i] for i in range(n)],
        [e[i] * p[1] for i, p in enumerate(positions)],
        [e[i] * -p[0] for i, p in enumerate(positions)],
        [e[i] * (s * k_yaw) for i, s in enumerate(spin)],
    ])


def allocation(B: np.ndarray, eff: Sequence[float] | None = None) -> np.ndarray:
    """The allocation ``Ainv`` (n × 4) of an effectiveness matrix ``B`` (4 × n): its inverse
    when square (four rotors), else the weighted pseudo-inverse
    ``W⁻¹ Bᵀ (B W⁻¹ Bᵀ)⁻¹``, ``W = diag(e_i)`` (the rotors' thrust per unit command), the
    split of a wrench over more rotors than it has components that minimises ``Σ e_i f_i²``.
    With all ``e_i = 1`` it is the Moore–Penrose pseudo-inverse ``Bᵀ (B Bᵀ)⁻¹``; on a coaxial
    frame it gives both rotors of a pair the same command for thrust, roll and pitch (the
    plain pseudo-inverse would load the upper rotors more, ``f ∝ e``, and saturate them first:
    the collective would top out at ``f_max Σ e_i² / max e`` instead of ``f_max Σ e_i``)."""
    if B.shape[0] == B.shape[1]:
        return np.linalg.inv(B)
    w_inv = np.ones(B.shape[1]) if eff is None else 1.0 / np.asarray(eff, dtype=float)
    BW = B * w_inv  # B W⁻¹
    return BW.T @ np.linalg.inv(BW @ B.T)


def fault_allocation(B: np.ndarray, eff: Sequence[float] | None, failed: int,
                     keep_yaw: bool, hover_share: float | None = None) -> np.ndarray:
    """The allocation (n × 4) without rotor ``failed`` (its row zero): the other rotors'
    columns of ``B`` allocated by :func:`allocation` (five or more rotors keep all four
    components); with ``keep_yaw`` False, the rows ``T, τx, τy`` only (a quad's three rotors
    cannot balance yaw: it gives yaw up, its ``τz`` column zero, and spins, as in Mueller and
    D'Andrea, "Stability and control of a quadrocopter despite the complete loss of one, two,
    or three propellers", ICRA 2014).

    ``hover_share`` (five or more rotors): the hover thrust over ``f_max`` (``m g / f_max``).
    When the weighted pseudo-inverse puts a rotor's hover command above 0.8 ``f_max``, the
    weights are redistributed (:func:`balanced_weights`) so that the highest hover command is
    as low as the frame allows: still a right inverse of the remaining columns (the wrench is
    reproduced exactly when nothing saturates), only the split among the rotors changes."""
    n = B.shape[1]
    keep = [i for i in range(n) if i != failed]
    e = [1.0] * n if eff is None else list(eff)
    out = np.zeros((n, 4))
    if keep_yaw:
        w = [e[i] for i in keep]
        sub = B[:, keep]
        if hover_share is not None:
            w = balanced_weights(sub, w, hover_share, 0.8)
        out[keep] = allocation(sub, w)
    else:
        sub_b = B[:_W.TZ, keep]  # the rows T, τx, τy
        w = [e[i] for i in keep]
        if hover_share is not None and len(keep) > 3:
            w = balanced_weights(sub_b, w, hover_share, 0.8)
        a3 = np.linalg.inv(sub_b) if len(keep) == 3 else allocation(sub_b, w)
        out[keep, :_W.TZ] = a3
    return out


def balanced_weights(B: np.ndarray, w0: Sequence[float], hover: float, limit: float,
                     iters: int = 200) -> list[float]:
    """Weights ``w`` of :func:`allocation` (``f = W⁻¹Bᵀ(BW⁻¹Bᵀ)⁻¹ u``, the split minimising
    ``Σ w_i f_i²``) for which the hover command ``f_h = A [hover, 0, 0, 0]`` (in units of
    ``f_max``) keeps every rotor at or below ``limit`` when it can, else makes the largest as
    small as it can: iteratively reweighted least squares towards the minimax split, each
    rotor's weight multiplied by ``f_i / mean f`` while the largest exceeds ``limit`` (a
    heavily loaded rotor costs more, so the others take its share). ``w0`` unchanged when its
    split already fits."""
    w = np.asarray(w0, dtype=float).copy()
    u = np.zeros(B.shape[0])
    u[0] = hover
    best, best_w = math.inf, w.copy()
    for _ in range(iters):
        f = allocation(B, w) @ u
        top = float(f.max())
        if top < best and float(f.min()) >= 0.0:
            best, best_w = top, w.copy()
        if top <= limit:
            break
        fp = np.maximum(f, 1e-3 * top)
        w = np.clip(w * fp / float(fp.mean()), 1e-3, 1e3)
        w = w / float(w.mean())
    return [float(v) for v in best_w]


class XMixer(RowBlocks):
    """Allocation of collective thrust and body torques to n rotors (4 to :data:`MIX_NMAX`),
    with saturation: one law for every frame (quad X, hexa X, coaxial octo X8).

    ``[T, τx, τy, τz]ᵀ = B f`` with the frame's effectiveness matrix ``B``
    (:func:`effectiveness`: rotor ``i`` at ``(x_i, y_i)`` pushes ``e_i f_i`` along body z with
    the yaw reaction torque ``s_i k e_i f_i``, ``s_i = ±1``); the allocation is
    ``f = B⁺ [T, τ]`` (:func:`allocation`: the inverse for four rotors, the efficiency-weighted
    pseudo-inverse for more).

    Saturation priority (as in PX4's and Betaflight's mixers): roll/pitch first, then collective
    thrust, then yaw. Yaw torque is scaled down until the rotors fit, then the collective is
    shifted, then the result is clipped to ``[0, f_max]`` (law: :func:`mix_step`).
    """

    def __init__(self, positions: Sequence[Sequence[float]], spin: Sequence[int], k_yaw: float,
                 f_max: float, eff: Sequence[float] | None = None) -> None:
        n = len(positions)
        if not 4 <= n <= MIX_NMAX or len(spin) != n or (eff is not None and len(eff) != n):
            raise ValueError(f"XMixer: 4 to {MIX_NMAX} rotors, one spin (and efficiency) each; "
                             f"got {n} positions, {len(spin)} spins")
        A = effectiveness(positions, spin, k_yaw, eff)
        self.A = A
        self.n = n
        self._p = np.zeros(MIX_PARAMS.size)
        self._s = np.zeros(MIX_STATE.size)
        self._out = np.zeros(n)
        self._p[_MP.AINV:_MP.AINV + WRENCH.size * n] = allocation(A, eff).ravel()
        self._p[_MP.N] = n
        self.f_max = f_max

    @property
    def Ainv(self) -> tuple[tuple[float, ...], ...]:
        """The allocation (n × 4, rows per rotor)."""
        n = int(self._p[_MP.N])
        rows = self._p[_MP.AINV:_MP.AINV + WRENCH.size * n].reshape(n, WRENCH.size)
        return tuple(tuple(r) for r in rows.tolist())

    @property
    def f_max(self) -> float:
        """Rotor thrust limit (N); writable."""
        return float(self._p[_MP.FMAX])

    @f_max.setter
    def f_max(self, value: float) -> None:
        self._p[_MP.FMAX] = float(value)

    @property
    def saturated(self) -> bool:
        """Whether the last :meth:`mix` saturated."""
        return bool(self._s[_MS.SAT] != 0.0)

    def mix(self, T: float, tx: float, ty: float, tz: float) -> list[float]:
        """Rotor thrusts (N) for collective ``T`` (N) and body torques (N m)."""
        out = self._out
        mix_step(self._p, self._s, T, tx, ty, tz, out)
        return out.tolist()
