"""Interval type-2 (and type-1) fuzzy PD cores Φ(E, dE) for fuzzy PID controllers.

Structure (Kumbasar-group IT2-FPID; Kumbasar & Hagras, Information Sciences 282
(2014), as used by Candan & Li):

* Inputs ``E`` and ``dE`` are clipped to [-1, 1].
* Three sets per input, N / Z / P, with triangular upper membership functions (UMFs)
  N = (-1.8, -1, 0), Z = (-1, 0, 1), P = (0, 1, 1.8); on the clipped domain these are
  ``max(0, -x)``, ``1 - |x|`` and ``max(0, x)`` and they sum to one.
* Lower MF = height × UMF (same support). From Table I's ``alpha``: h_Z = alpha,
  h_N = h_P = 1 - alpha; explicit per-set heights per input are accepted too.
* Product t-norm: upper firing f̄_ij = UMF_i(E)·UMF_j(dE), lower f_ij = h_i·h_j·f̄_ij.
* 3×3 diagonal rule base: consequent y = (-1, -c_m, 0, c_m, 1)[r_i + r_j] with
  r = (0, 1, 2) for (N, Z, P).
* Type reducers:

  - ``"km"`` (Karnik–Mendel, exact):
    y_l = min_k [Σ_{n<=k} f̄_n y_n + Σ_{n>k} f_n y_n] / [Σ_{n<=k} f̄_n + Σ_{n>k} f_n],
    y_r = max_k (same with f and f̄ swapped), U = (y_l + y_r)/2;
  - ``"nt"`` (Nie–Tan): U = Σ(f + f̄) y / Σ(f + f̄);
  - ``"bmm"`` (Begian–Melek–Mendel, m = n = 0.5): U = ½ Σf y/Σf + ½ Σf̄ y/Σf̄;
  - ``"zeta"``: U = [ζ Σf y + (1-ζ) Σf̄ y] / Σ(f + f̄)  (ζ = 0.5 gives NT/2, |U| <= 0.5).

Because the UMFs of each input form a partition of unity, at most two sets per input
fire, i.e. at most four rules, and their consequents fall into three ordered groups
(sums r_i + r_j = m, m+1, m+2; the two middle rules share a consequent). The scalar
evaluation below exploits this: no sorting, no numpy, ~40 float operations, which keeps
one Φ evaluation at a few microseconds. Rules with equal consequents can be merged in
the KM reducer without changing y_l, y_r (the optimal KM weight vector treats equal
consequents alike), so exact KM reduces to comparing two switch points per side.

References: J. M. Mendel, *Uncertain Rule-Based Fuzzy Systems*, 2nd ed., Springer 2017
(KM algorithm); M. Nie & W. W. Tan, FUZZ-IEEE 2008 (NT); M. Begian, W. Melek &
J. Mendel, IEEE TFS 2008 (BMM); T. Kumbasar, "Robust stability analysis and systematic
design of single-input interval type-2 fuzzy logic controllers", IEEE TFS 2016.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from numkit import Layout

from ._jit import njit

__all__ = [
    "REDUCERS",
    "IT2FuzzyPD",
    "T1FuzzyPD",
    "heights_from_alpha",
    "it2_phi",
    "small_signal_gain",
    "t1_phi",
]

REDUCERS = ("km", "nt", "bmm", "zeta")
_RED_CODE = {"km": 0, "nt": 1, "bmm": 2, "zeta": 3}

Heights3 = tuple[float, float, float]

#: the three groups of active rules, by consequent above the lowest active one y[p]: both inputs
#: in their lower active set (r_i + r_j = p), one in each (p + 1), both in the higher (p + 2)
GROUP = Layout("low mid high").at
#: the lower-MF heights (h_N, h_Z, h_P) of E then of dE, flat (``_grid``'s ``h``)
HEIGHTS = Layout("hn_e hz_e hp_e hn_de hz_de hp_de").at


def heights_from_alpha(alpha: float) -> Heights3:
    """Lower-MF heights (h_N, h_Z, h_P) from Table I's ``alpha``: (1-α, α, 1-α)."""
    alpha = float(alpha)
    return (1.0 - alpha, alpha, 1.0 - alpha)


def _check_heights(h: Sequence[float]) -> Heights3:
    if len(h) != 3:
        raise ValueError(f"expected three heights (h_N, h_Z, h_P), got {h!r}")
    out = tuple(float(v) for v in h)
    for v in out:
        if not (0.0 < v <= 1.0):
            raise ValueError(f"lower-MF heights must lie in (0, 1], got {out}")
    return out  # type: ignore[return-value]


def _resolve_heights(
    alpha: float, heights: Sequence[float] | Sequence[Sequence[float]] | None
) -> tuple[Heights3, Heights3]:
    if heights is None:
        h = _check_heights(heights_from_alpha(alpha))
        return h, h
    hs = list(heights)
    if len(hs) == 3 and all(np.isscalar(v) for v in hs):
        h = _check_heights(hs)  # type: ignore[arg-type]
        return h, h
    if len(hs) == 2:
        return _check_heights(hs[0]), _check_heights(hs[1])  # type: ignore[arg-type]
    raise ValueError(
        "heights must be (h_N, h_Z, h_P) or ((h_N, h_Z, h_P) for E, (h_N, h_Z, h_P) for dE)"
    )


def small_signal_gain(
    reducer: str,
    cm: float = 0.7,
    h_z: float = 0.25,
    h_p: float = 0.75,
    zeta: float = 0.5,
) -> float:
    """Closed-form slope G = ∂Φ/∂E = ∂Φ/∂dE at the origin (equal heights on both inputs).

    G_T1 = c_m; G_KM = (c_m/2)(1/h_Z² + h_P h_Z); G_NT = c_m (1 + h_P h_Z)/(1 + h_Z²);
    G_BMM = (c_m/2)(h_P/h_Z + 1); G_zeta = c_m (ζ h_P h_Z + 1 - ζ)/(1 + h_Z²).
    ``reducer="t1"`` gives the type-1 slope. Valid for h_N = h_P (odd core); otherwise it is
    the slope for E > 0.
    """
    hz, hp, cm = float(h_z), float(h_p), float(cm)
    if reducer == "t1":
        return cm
    if reducer == "km":
        return 0.5 * cm * (1.0 / (hz * hz) + hp * hz)
    if reducer == "nt":
        return cm * (1.0 + hp * hz) / (1.0 + hz * hz)
    if reducer == "bmm":
        return 0.5 * cm * (hp / hz + 1.0)
    if reducer == "zeta":
        return cm * (zeta * hp * hz + 1.0 - zeta) / (1.0 + hz * hz)
    raise ValueError(f"unknown reducer {reducer!r}; allowed: {('t1',) + REDUCERS}")


def _memberships_np(x: np.ndarray, h: Heights3) -> tuple[np.ndarray, ...]:
    """Vectorised UMFs (N, Z, P) and heights broadcast for clipped inputs."""
    n = np.maximum(0.0, -x)
    z = 1.0 - np.abs(x)
    p = np.maximum(0.0, x)
    return (n, z, p), h


# ------------------------------------------------------------ scalar cores (pure float functions)
# The one implementation of each core: the classes below call them; :mod:`controllers.axis`
# compiles the same functions with numba for the axis law, and :func:`_grid` for ``phi_grid``.


def t1_phi(E: float, dE: float, y: tuple[float, ...]) -> float:
    """Type-1 core Φ(E, dE) (:class:`T1FuzzyPD`) for consequents ``y = (-1, -c_m, 0, c_m, 1)``."""
    if E > 1.0:
        E = 1.0
    elif E < -1.0:
        E = -1.0
    if dE > 1.0:
        dE = 1.0
    elif dE < -1.0:
        dE = -1.0
    if E < 0.0:
        a0 = -E
        a1 = 1.0 + E
        p = 0
    else:
        a0 = 1.0 - E
        a1 = E
        p = 1
    if dE < 0.0:
        b0 = -dE
        b1 = 1.0 + dE
    else:
        b0 = 1.0 - dE
        b1 = dE
        p += 1
    # Σ f̄ = 1 (partition of unity), so no division is needed.
    return (a0 * b0 * y[p + GROUP.LOW] + (a0 * b1 + a1 * b0) * y[p + GROUP.MID]
            + a1 * b1 * y[p + GROUP.HIGH])


def it2_phi(E: float, dE: float, y: tuple[float, ...], h_e: tuple[float, float, float],
            h_de: tuple[float, float, float], code: int, zeta: float) -> float:
    """IT2 core Φ(E, dE) (:class:`IT2FuzzyPD`): consequents ``y = (-1, -c_m, 0, c_m, 1)``,
    lower-MF heights ``h_e`` = (h_N, h_Z, h_P) of E and ``h_de`` of dE, reducer ``code`` (0 km,
    1 nt, 2 bmm, 3 zeta) and ζ (read by "zeta" only)."""
    hn1, hz1, hp1 = h_e
    hn2, hz2, hp2 = h_de
    if E > 1.0:
        E = 1.0
    elif E < -1.0:
        E = -1.0
    if dE > 1.0:
        dE = 1.0
    elif dE < -1.0:
        dE = -1.0
    # Two active sets per input: "low" (a0, height ha0) and "high" (a1, ha1).
    if E < 0.0:
        a0 = -E
        a1 = 1.0 + E
        ha0 = hn1
        ha1 = hz1
        p = 0
    else:
        a0 = 1.0 - E
        a1 = E
        ha0 = hz1
        ha1 = hp1
        p = 1
    if dE < 0.0:
        b0 = -dE
        b1 = 1.0 + dE
        hb0 = hn2
        hb1 = hz2
    else:
        b0 = 1.0 - dE
        b1 = dE
        hb0 = hz2
        hb1 = hp2
        p += 1
    y0 = y[p + GROUP.LOW]
    y1 = y[p + GROUP.MID]
    y2 = y[p + GROUP.HIGH]
    # Upper firing of the three consequent groups (Σ = 1) ...
    u01 = a0 * b1
    u10 = a1 * b0
    U0 = a0 * b0
    U1 = u01 + u10
    U2 = a1 * b1
    # ... and lower firing.
    L0 = ha0 * hb0 * U0
    L1 = ha0 * hb1 * u01 + ha1 * hb0 * u10
    L2 = ha1 * hb1 * U2
    if code == 0:  # exact KM: switch after group 0 or after group 1
        uy0 = U0 * y0
        uy1 = U1 * y1
        uy2 = U2 * y2
        ly0 = L0 * y0
        ly1 = L1 * y1
        ly2 = L2 * y2
        c1 = (uy0 + ly1 + ly2) / (U0 + L1 + L2)
        c2 = (uy0 + uy1 + ly2) / (U0 + U1 + L2)
        d1 = (ly0 + uy1 + uy2) / (L0 + U1 + U2)
        d2 = (ly0 + ly1 + uy2) / (L0 + L1 + U2)
        yl = c1 if c1 < c2 else c2
        yr = d1 if d1 > d2 else d2
        return 0.5 * (yl + yr)
    sl = L0 * y0 + L1 * y1 + L2 * y2
    su = U0 * y0 + U1 * y1 + U2 * y2
    dl = L0 + L1 + L2
    if code == 1:  # Nie-Tan
        return (sl + su) / (dl + 1.0)
    if code == 2:  # BMM, m = n = 0.5
        return 0.5 * (sl / dl + su)
    return (zeta * sl + (1.0 - zeta) * su) / (dl + 1.0)  # zeta-weighted


#: The cores compiled (the axis law :func:`controllers.axis.axis_step` and :func:`_grid` call
#: these; the core objects call the Python functions: the same operations, the same bits).
t1_phi_jit = njit(t1_phi)
it2_phi_jit = njit(it2_phi)


@njit
def _grid(E: np.ndarray, dE: np.ndarray, y: tuple[float, ...], h: np.ndarray, code: int,
          zeta: float, out: np.ndarray) -> None:
    """Φ over flat arrays: :func:`t1_phi` (``code`` −1) or :func:`it2_phi` (heights ``h``)."""
    for k in range(E.shape[0]):
        if code < 0:
            out[k] = t1_phi_jit(E[k], dE[k], y)
        else:
            h_e = (h[HEIGHTS.HN_E], h[HEIGHTS.HZ_E], h[HEIGHTS.HP_E])
            h_de = (h[HEIGHTS.HN_DE], h[HEIGHTS.HZ_DE], h[HEIGHTS.HP_DE])
            out[k] = it2_phi_jit(E[k], dE[k], y, h_e, h_de, code, zeta)


class _FuzzyPDBase:
    """Shared bits of the type-1 and IT2 PD cores."""

    __slots__ = ("cm", "_y")

    def __init__(self, cm: float) -> None:
        cm = float(cm)
        if not (0.0 <= cm <= 1.0):
            raise ValueError(f"c_m must lie in [0, 1], got {cm}")
        self.cm = cm
        self._y = (-1.0, -cm, 0.0, cm, 1.0)

    def consequents(self) -> np.ndarray:
        """3×3 consequent table, rows = E set (N, Z, P), columns = dE set: y[r_i + r_j]."""
        r = np.array([0, 1, 2])
        return np.asarray(self._y)[r[:, None] + r[None, :]]

    def _grid_args(self) -> tuple[np.ndarray, int, float]:
        return np.ones(HEIGHTS.SIZE), -1, 0.5

    def phi_grid(self, E: np.ndarray, dE: np.ndarray) -> np.ndarray:
        """Φ over broadcast arrays E, dE (for plots): the scalar core, compiled, per point."""
        E, dE = np.broadcast_arrays(np.asarray(E, float), np.asarray(dE, float))
        out = np.empty(E.size)
        h, code, zeta = self._grid_args()
        _grid(np.ascontiguousarray(E).ravel(), np.ascontiguousarray(dE).ravel(), self._y, h,
              code, zeta, out)
        return out.reshape(E.shape)

    def small_signal_gains(self, eps: float = 1e-8) -> tuple[float, float]:
        """Numerical (∂Φ/∂E, ∂Φ/∂dE) at the origin by central differences.

        Central differences average the one-sided slopes (Φ is only piecewise smooth at 0).
        """
        g_e = (self(eps, 0.0) - self(-eps, 0.0)) / (2.0 * eps)  # type: ignore[operator]
        g_de = (self(0.0, eps) - self(0.0, -eps)) / (2.0 * eps)  # type: ignore[operator]
        return g_e, g_de


class T1FuzzyPD(_FuzzyPDBase):
    """Type-1 fuzzy PD core: same rules, UMFs only, weighted average Φ = Σ f̄ y / Σ f̄.

    With c_m = 0.5 this is exactly (E + dE)/2; small-signal slope c_m.
    """

    __slots__ = ()

    def __init__(self, cm: float = 0.7) -> None:
        super().__init__(cm)

    def __call__(self, E: float, dE: float) -> float:
        return t1_phi(E, dE, self._y)


class IT2FuzzyPD(_FuzzyPDBase):
    """Interval type-2 fuzzy PD core Φ(E, dE) with a selectable type reducer.

    Parameters
    ----------
    alpha : Table I's height parameter: h_Z = alpha, h_N = h_P = 1 - alpha (ignored when
        ``heights`` is given).
    cm : consequent of the off-diagonal rules (r_i + r_j = 1 or 3), in [0, 1].
    reducer : "km" (exact Karnik–Mendel), "nt", "bmm" (m = n = 0.5) or "zeta".
    zeta : weight of the lower firing strengths for the "zeta" reducer.
    heights : optional (h_N, h_Z, h_P) for both inputs, or a pair of such triples
        (first for E, second for dE). Heights must lie in (0, 1].

    Calling the object with two floats returns Φ as a float (pure Python, ≤ 4 firing
    rules); :meth:`phi_grid` is the vectorised numpy version.
    """

    __slots__ = (
        "alpha",
        "reducer",
        "zeta",
        "heights_e",
        "heights_de",
        "reducer_code",
    )

    def __init__(
        self,
        alpha: float = 0.25,
        cm: float = 0.7,
        reducer: str = "km",
        zeta: float = 0.5,
        heights: Sequence[float] | Sequence[Sequence[float]] | None = None,
    ) -> None:
        super().__init__(cm)
        if reducer not in _RED_CODE:
            raise ValueError(f"unknown reducer {reducer!r}; allowed: {REDUCERS}")
        zeta = float(zeta)
        if not (0.0 <= zeta <= 1.0):
            raise ValueError(f"zeta must lie in [0, 1], got {zeta}")
        self.alpha = float(alpha)
        self.reducer = reducer
        self.zeta = zeta
        #: the reducer's code in the compiled laws (0 km, 1 nt, 2 bmm, 3 zeta)
        self.reducer_code = _RED_CODE[reducer]
        h1, h2 = _resolve_heights(alpha, heights)
        self.heights_e = h1
        self.heights_de = h2

    def __repr__(self) -> str:
        return (
            f"IT2FuzzyPD(cm={self.cm}, reducer={self.reducer!r}, zeta={self.zeta}, "
            f"heights=({self.heights_e}, {self.heights_de}))"
        )

    def small_signal_gain(self) -> float:
        """Closed-form slope at the origin (requires equal heights on both inputs)."""
        if self.heights_e != self.heights_de:
            raise ValueError(
                "closed form needs equal heights on both inputs; use small_signal_gains()"
            )
        _, hz, hp = self.heights_e
        return small_signal_gain(self.reducer, self.cm, hz, hp, self.zeta)

    def __call__(self, E: float, dE: float) -> float:
        return it2_phi(E, dE, self._y, self.heights_e, self.heights_de, self.reducer_code,
                       self.zeta)

    # ------------------------------------------------ rule-level view (figures and checks)
    def firing(self, E: np.ndarray, dE: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """All nine rules: (y, f_lower, f_upper) with shapes (9,), (9, *S), (9, *S)."""
        E, dE = np.broadcast_arrays(
            np.clip(np.asarray(E, float), -1, 1), np.clip(np.asarray(dE, float), -1, 1)
        )
        (mu_e, h_e), (mu_d, h_d) = (
            _memberships_np(E, self.heights_e),
            _memberships_np(dE, self.heights_de),
        )
        tab = self.consequents()
        ys, fl, fu = [], [], []
        for i in range(3):
            for j in range(3):
                up = mu_e[i] * mu_d[j]
                ys.append(tab[i, j])
                fu.append(up)
                fl.append(h_e[i] * h_d[j] * up)
        return np.array(ys), np.array(fl), np.array(fu)

    def _grid_args(self) -> tuple[np.ndarray, int, float]:
        return np.array([*self.heights_e, *self.heights_de]), self.reducer_code, self.zeta
