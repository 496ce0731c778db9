"""The statistics of the INS feedback's consistency scores (:mod:`ag_uav.navigation.ins_feedback`):
the mean of a score series, the 95 % χ² band of a mean NEES or NIS, and the effective number of
independent values of a correlated series."""

from __future__ import annotations

import numpy as np

__all__ = ["chi2_band", "effective_n", "finite_mean", "finite_rms_max"]

#: values per block of :func:`finite_rms_max` (bounds its temporaries)
BLOCK = 1 << 16


def finite_mean(a: np.ndarray) -> float | None:
    """The mean of the finite values (3 decimals, summed in float64), None if there are
    none."""
    a = a[np.isfinite(a)]
    return round(float(a.mean(dtype=np.float64)), 3) if a.size else None


def finite_rms_max(a: np.ndarray, scale: float = 1.0,
                   block: int = BLOCK) -> tuple[float | None, float | None, int]:
    """``(RMS, max, count)`` of the finite values of ``a / scale`` (computed in ``a``'s dtype,
    as a whole-array division would), a block at a time: the squares summed in float64 by
    blocks (equal to the whole-array mean to rounding), so that a whole job's float32 errors
    need no float64 copy; RMS and max rounded to 4 decimals, None where no value is finite."""
    sq, mx, cnt = 0.0, -np.inf, 0
    for i in range(0, len(a), block):
        x = a[i:i + block] if scale == 1.0 else a[i:i + block] / scale
        x = x[np.isfinite(x)]
        if not x.size:
            continue
        mx = max(mx, float(x.max()))
        x = x.astype(np.float64)
        sq += float(np.sum(np.multiply(x, x, out=x)))
        cnt += x.size
    if not cnt:
        return None, None, 0
    return round(float(np.sqrt(sq / cnt)), 4), round(mx, 4), cnt


def chi2_band(dof: int, n: float) -> list[float] | None:
    """The 95 % two-sided band of the mean of ``n`` independent χ²(dof) values (``n`` may be
    an effective number, :func:`effective_n`)."""
    if n <= 0:
        return None
    from scipy.special import gammaincinv  # χ²(k) quantile q: 2·P⁻¹(k/2, q), as scipy.stats

    k = dof * n
    return [round(float(2.0 * gammaincinv(0.5 * k, 0.025) / n), 3),
            round(float(2.0 * gammaincinv(0.5 * k, 0.975) / n), 3)]


def effective_n(x: np.ndarray) -> float:
    """The effective number of independent values in the series ``x`` for its mean: N / τ,
    τ = 1 + 2 Σ ρ_k the integrated autocorrelation time, summed over Geyer's initial positive
    sequence (pairs ρ_2m + ρ_2m+1 while positive; Geyer, Statistical Science 7, 1992).
    Successive fixes' NEES are correlated (the filter's error is), so the band of their mean
    is that of N / τ independent values, not N."""
    x = np.asarray(x, dtype=float)
    n = x.size
    if n < 4 or not np.any(x != x[0]):
        return float(n)
    d = x - x.mean()
    # zero-padded to a power of two ≥ 2n − 1 (no wrap-around): any other length may take
    # pocketfft's Bluestein path, whose buffers (tens of MB for a whole job's fixes) the
    # allocator then keeps
    nfft = 1 << (2 * n - 1).bit_length()
    f = np.fft.rfft(d, nfft)
    acf = np.fft.irfft(f * np.conj(f), nfft)[:n]
    rho = acf / acf[0]
    tau = -1.0                      # 2 Σ_{m} (ρ_2m + ρ_2m+1) − 1, from ρ_0 = 1
    for m in range(n // 2):
        g = rho[2 * m] + rho[2 * m + 1]
        if g <= 0.0:
            break
        tau += 2.0 * g
    return float(n / max(tau, 1.0))
