"""Straight-line (unrolled) MCKF fixed point for small n, m: generated Python source.

Why: at the sizes of the bank (n = 4-9 states, m = 2-3 measurements) every numpy call costs
~0.5 µs whatever the size, and one fixed-point iteration needs ~25 of them; the same iteration
written as straight-line float arithmetic (no loops, no containers) is ~100-250 scalar
operations at ~30 ns.  The source of one function per (n, m) is generated from the formulas
below, compiled once and cached (:func:`kernel`); ``MCKF`` uses it for m ≤ 3, n ≤ 12 and falls
back to its vectorised path otherwise or when the Cholesky pivot test fails.

What the generated ``_kernel(Pf, xbl, nul, Gf, Rf, kx, ky, floor, eps2, max_iter, rel)``
computes (the same steps as ``MCKF._fixed_point_numpy``; inputs are flat row-major lists:
``Pf`` = P̄, ``Gf`` = B_r⁻¹H, ``Rf`` = B_r⁻¹; ``kx``, ``ky`` = −1/(2σ²) for the state rows and
−1/(4σ²) for the measurement rows)::

    L = chol(P̄)   (lower; returns None if a pivot d ≤ rel · P̄_jj, or NaN)
    A = B_r⁻¹ H L,   ν_w = B_r⁻¹ ν,   p_ik,j = A_ij A_kj   (i ≤ k)
    iteration 1:  q = 1 (C_x = I), s_i = exp(ν_w,i² ky_i)             (s = √C_y)
    every iteration:
        T_ik = Σ_j p_ik,j q_j            (T = A C_x⁻¹ Aᵀ)
        M = I + S T S,  Mi = M⁻¹ (closed form, m ≤ 3)
        β = S Mi S ν_w,   u = C_x⁻¹ Aᵀ β,   x̂ = x̄ + L u
    next iteration (while ‖x̂ − x̂_prev‖² > ε² max(‖x̂_prev‖², 1) and it < max_iter):
        e_y = ν_w − A u,  c_j = max(exp(u_j² kx_j), floor),  q = 1/c,  s_i = exp(e_y,i² ky_i)
    K̃ = L C_x⁻¹ Aᵀ N,   N = S Mi S B_r⁻¹

Returns ``None`` (pivot test failed) or ``(x̂, K̃ flat, C_y, C_x or None, n_iter)``, with
C_x ``None`` when only the first iteration ran (C_x = I).
"""

from __future__ import annotations

import math
from collections.abc import Callable

__all__ = ["kernel", "kernel_source", "REL_PIVOT"]

#: Cholesky pivots below REL_PIVOT · P̄_jj are left to LAPACK (and ``safe_cholesky``), so the
#: positive-definite decision never hinges on the summation order
REL_PIVOT = 1e-8

_cache: dict[tuple[int, int], Callable] = {}


def _names(fmt: str, *ranges) -> str:
    if len(ranges) == 1:
        return ", ".join(fmt.format(a) for a in ranges[0])
    return ", ".join(fmt.format(a, b) for a in ranges[0] for b in ranges[1])


def kernel_source(n: int, m: int) -> str:
    """Python source of the unrolled fixed point for n states and m ≤ 3 measurements."""
    if not 1 <= m <= 3 or n < 1:
        raise ValueError("kernel needs n >= 1 and 1 <= m <= 3")
    rn, rm = range(n), range(m)
    pairs = [(i, k) for i in rm for k in range(i, m)]
    out: list[str] = []

    def w(line: str, ind: int = 1) -> None:
        out.append("    " * ind + line)

    def inv(i: int, k: int) -> str:
        return f"i{min(i, k)}{max(i, k)}"

    def solve(first: bool, ind: int) -> None:
        for i, k in pairs:
            terms = (f"p{i}{k}_{j}" if first else f"p{i}{k}_{j} * q{j}" for j in rn)
            w(f"t{i}{k} = " + " + ".join(terms), ind)
        for i, k in pairs:
            w(f"m{i}{k} = " + ("1.0 + " if i == k else "") + f"s{i} * s{k} * t{i}{k}", ind)
        if m == 1:
            w("i00 = 1.0 / m00", ind)
        elif m == 2:
            w("det = m00 * m11 - m01 * m01", ind)
            w("i00 = m11 / det; i01 = -m01 / det; i11 = m00 / det", ind)
        else:
            w("f00 = m11 * m22 - m12 * m12; f01 = m12 * m02 - m01 * m22", ind)
            w("f02 = m01 * m12 - m11 * m02; f11 = m00 * m22 - m02 * m02", ind)
            w("f12 = m01 * m02 - m00 * m12; f22 = m00 * m11 - m01 * m01", ind)
            w("det = m00 * f00 + m01 * f01 + m02 * f02", ind)
            w("; ".join(f"i{i}{k} = f{i}{k} / det" for i, k in pairs), ind)
        for i in rm:
            w(f"sn{i} = s{i} * nw{i}", ind)
        for i in rm:
            w(f"be{i} = s{i} * (" + " + ".join(f"{inv(i, k)} * sn{k}" for k in rm) + ")", ind)
        for j in rn:
            expr = " + ".join(f"a{i}_{j} * be{i}" for i in rm)
            w(f"u{j} = " + (f"{expr}" if first else f"q{j} * ({expr})"), ind)
        for j in rn:
            w(f"x{j} = xb{j} + " + " + ".join(f"L{j}_{k} * u{k}" for k in range(j + 1)), ind)

    w("def _kernel(Pf, xbl, nul, Gf, Rf, kx, ky, floor, eps2, max_iter, rel):", 0)
    w(_names("P{}_{}", rn, rn) + ", = Pf")
    w(_names("xb{}", rn) + ", = xbl")
    w(_names("nu{}", rm) + ", = nul")
    w(_names("g{}_{}", rm, rn) + ", = Gf")
    w(_names("r{}_{}", rm, rm) + ", = Rf")
    w(_names("kx{}", rn) + ", = kx")
    w(_names("ky{}", rm) + ", = ky")
    for j in rn:  # Cholesky, column by column, from the lower triangle
        acc = " + ".join(f"L{j}_{k} * L{j}_{k}" for k in range(j))
        w(f"d = P{j}_{j}" + (f" - ({acc})" if acc else ""))
        w(f"if not d > rel * P{j}_{j}:")
        w("return None", 2)
        w(f"L{j}_{j} = sqrt(d)")
        for i in range(j + 1, n):
            acc = " + ".join(f"L{i}_{k} * L{j}_{k}" for k in range(j))
            w(f"L{i}_{j} = (P{i}_{j}" + (f" - ({acc})" if acc else "") + f") / L{j}_{j}")
    for i in rm:
        for j in rn:
            w(f"a{i}_{j} = " + " + ".join(f"g{i}_{k} * L{k}_{j}" for k in range(j, n)))
    for i in rm:
        w(f"nw{i} = " + " + ".join(f"r{i}_{h} * nu{h}" for h in rm))
    for i, k in pairs:
        for j in rn:
            w(f"p{i}{k}_{j} = a{i}_{j} * a{k}_{j}")
    for i in rm:  # iteration 1: C_x = I, e_y = ν_w
        w(f"s{i} = exp(nw{i} * nw{i} * ky{i})")
    solve(True, 1)
    w(" = ".join(f"q{j}" for j in rn) + " = 1.0")
    w(_names("o{}", rn) + " = " + _names("xb{}", rn))
    w("nrm2 = " + " + ".join(f"xb{j} * xb{j}" for j in rn))
    w("it = 1")
    w("while it < max_iter:")
    w("d2 = " + " + ".join(f"(x{j} - o{j}) * (x{j} - o{j})" for j in rn), 2)
    w("if d2 <= eps2 * (nrm2 if nrm2 > 1.0 else 1.0):", 2)
    w("break", 3)
    w("it += 1", 2)
    w(_names("o{}", rn) + " = " + _names("x{}", rn), 2)
    w("nrm2 = " + " + ".join(f"x{j} * x{j}" for j in rn), 2)
    for i in rm:
        w(f"e{i} = nw{i} - (" + " + ".join(f"a{i}_{j} * u{j}" for j in rn) + ")", 2)
    for j in rn:
        w(f"c{j} = exp(u{j} * u{j} * kx{j})", 2)
        w(f"if c{j} < floor:", 2)
        w(f"c{j} = floor", 3)
        w(f"q{j} = 1.0 / c{j}", 2)
    for i in rm:
        w(f"s{i} = exp(e{i} * e{i} * ky{i})", 2)
    solve(False, 2)
    for i in rm:  # K̃ = L C_x⁻¹ Aᵀ N, N = S Mi S B_r⁻¹
        for col in rm:
            terms = " + ".join(f"{inv(i, h)} * s{h} * r{h}_{col}" for h in rm)
            w(f"N{i}_{col} = s{i} * ({terms})")
    for k in rn:
        for col in rm:
            terms = " + ".join(f"a{i}_{k} * N{i}_{col}" for i in rm)
            w(f"V{k}_{col} = q{k} * ({terms})")
    K = [" + ".join(f"L{j}_{k} * V{k}_{col}" for k in range(j + 1)) for j in rn for col in rm]
    w("K = [" + ", ".join(K) + "]")
    w("c = [" + _names("c{}", rn) + "] if it > 1 else None")
    w("return [" + _names("x{}", rn) + "], K, [" + ", ".join(f"s{i} * s{i}" for i in rm)
      + "], c, it")
    return "\n".join(out) + "\n"


def kernel(n: int, m: int) -> Callable:
    """The compiled kernel for (n, m), generated on first use and cached."""
    f = _cache.get((n, m))
    if f is None:
        ns: dict = {"exp": math.exp, "sqrt": math.sqrt}
        exec(compile(kernel_source(n, m), f"<mckf kernel n={n} m={m}>", "exec"), ns)  # noqa: S102
        f = _cache[(n, m)] = ns["_kernel"]
    return f
