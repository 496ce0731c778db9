"""GPS position sensor with configurable coloured and non-Gaussian error models.

The paper's measurement model is ``y = C x + omega`` with coloured noise
``omega_t = Gamma omega_{t-1} + xi`` (Candan & Li, eqs 1-2) and Gaussian / non-Gaussian xi
(Weibull, Student-t); the tracking paper (Qin, Xu & Liu, eq 4) adds Gaussian mixtures, and
Laplace / alpha-stable impulsive noise.  Here each axis error is a SUM of components:

==================  =========================================================================
type                model (per fix k)
==================  =========================================================================
``gaussian``        sigma * N(0, 1)
``student-t``       sigma * sqrt((nu-2)/nu) * t_nu                     (nu > 2, variance sigma^2)
``laplace``         Laplace(0, b), b = sigma / sqrt(2)                 (variance sigma^2)
``weibull``         +/- lambda * Weibull(k), lambda = sigma / sqrt(Gamma(1 + 2/k)), random sign
``mixture``         (1-eps) N(0, sigma1^2) + eps N(0, sigma2^2)
``alpha-stable``    S(alpha, beta, scale) by Chambers-Mallows-Stuck (scipy ``levy_stable`` S1
                    parametrisation); infinite variance for alpha < 2 (its finite
                    ``spread`` 2 scale^2, the Gaussian variance of the same interquartile
                    range, sets the position failsafe's automatic bound)
``gauss-markov``    b_{k+1} = e^{-dt/tau} b_k + sigma sqrt(1 - e^{-2 dt/tau}) N(0,1) (exact)
``ar1``             v_k = rho v_{k-1} + g(rho) xi_k with xi from a ``driver`` distribution above;
                    g = sqrt(1 - rho^2) keeps the variance (for an alpha-stable driver
                    g = (1 - |rho|^alpha)^(1/alpha) keeps the scale).  Give rho, or tau_s
                    with rho = e^{-dt/tau}
``spikes``          Bernoulli(prob) * amplitude * random sign (multipath); amplitude uniform in
                    [amplitude, amplitude_max] if ``amplitude_max`` is given
==================  =========================================================================

Fix-quality episodes (``fix_quality``, :class:`FixQualityChain`): a semi-Markov chain over
solution types (for ``rtk-m350``: RTK fixed, RTK float, DGPS/SBAS) with geometric dwell times of
exactly the configured means and a jump table; each type adds its own error components, blended
in with a first-order ramp when the solution degrades and snapped out when it re-fixes.  The fix
type of every fix is exposed (``GpsSensor.last_fix_type``, ``fix_type_counts``,
``generate_errors(..., with_fix_type=True)``) so the loop can log it; the filters are NOT told it:
their R is built from :attr:`GpsSensor.variance`, the nominal level (the base components; for
``rtk-m350`` the RTK-fixed datasheet accuracy), the robust-filter premise of the core paper.

Outages are a two-state Markov chain (fix available / no fix) with geometric run lengths whose
means are exactly ``mean_up_s`` and ``mean_down_s`` (per-fix switching probability dt / mean).

Randomness: every component draws from its own Generators, derived from the sensor's
``SeedSequence`` and a stable key (component name, axis), so adding, removing or reordering a
component never changes the draws of another.  All components are also *chunk invariant*: drawing
n1 then n2 values gives the same numbers as drawing n1 + n2 at once, which is why
:meth:`GpsSensor.measure` (which pre-generates errors in blocks) and
:meth:`GpsSensor.generate_errors` produce identical error sequences for the same seed.

Config keys (plain dicts; a TOML table can override any of them)
-----------------------------------------------------------------
Sensor: ``rate_hz`` (float > 0, fixes per second), ``latency_s`` (float >= 0, age of the true
position a fix reports), ``axis_scale`` ([sx, sy, sz] >= 0, multiplies the summed error per axis),
``components`` (list of component tables), ``outage`` (table with ``mean_up_s`` > 0,
``mean_down_s`` > 0 and optional bool ``start_in_outage``; an empty table means no outages).
Component: ``type`` (see above), ``name`` (optional, unique, defaults to the type; it keys the
random stream), ``axis_scale`` (optional [3] multiplier for this component only), and per type:
``sigma`` (gaussian, student-t, laplace, weibull, gauss-markov), ``nu`` (student-t), ``k``
(weibull shape), ``eps``, ``sigma1``, ``sigma2`` (mixture), ``alpha``, ``scale``, ``beta``
(alpha-stable, beta default 0), ``tau_s`` (gauss-markov; ar1 alternative to ``rho``), ``rho``
(ar1), ``driver`` (ar1: a component table of an i.i.d. type, without name), ``prob``,
``amplitude``, ``amplitude_max`` (spikes).  When overriding a preset, ``components`` may be a
list (replaces all) or a table keyed by component name (merges keys into those components; a
new name adds a component, an empty table removes one).
Fix quality: ``fix_quality`` = ``{start = "<mode>", modes = {<mode> = {mean_dwell_s (> 0),
next = {<other mode> = probability, ...} (sums to 1), ramp_s (>= 0, default 0),
components = [...]}}}``; an empty table means no episodes.  Overrides merge by mode name (a
mode's ``components`` merge like the sensor's; an empty mode table removes the mode).

Validation: every value is checked strictly (a string or bool where a number is due, NaN/inf,
out of range, an unknown key or a non-table where a table is due raises ValueError with one line
naming the key, the value and what is allowed); :func:`validate_overrides` runs the same checks
for a preset's overrides without keeping a sensor (for config loading).

Presets (:func:`gps_preset`) are illustrative engineering values, not datasheet figures, except
``rtk-m350``, whose figures cite their sources (datasheets, literature) or say they are
engineering judgement; see ``_PRESETS`` and ``_RTK_M350`` in :mod:`~ag_uav.vehicle.gps.presets`
for the reasoning behind each number.

The package, one idea a module: :mod:`~ag_uav.vehicle.gps.checks` (seeds and strict value
checks), :mod:`~ag_uav.vehicle.gps.noise` (the components and building them from config),
:mod:`~ag_uav.vehicle.gps.episodes` (outages and fix-quality episodes),
:mod:`~ag_uav.vehicle.gps.presets` (presets and overrides), :mod:`~ag_uav.vehicle.gps.sensor`
(:class:`GpsSensor`) and :mod:`~ag_uav.vehicle.gps.receiver` (:class:`ReceiverReport`).
"""

from __future__ import annotations

from .checks import SeedLike, derive_seed
from .episodes import FixQualityChain, OutageProcess
from .noise import (
    AR1,
    AlphaStable,
    Gaussian,
    GaussianMixture,
    GaussMarkov,
    Laplace,
    MultipathSpikes,
    NoiseComponent,
    StudentT,
    SymmetricWeibull,
    make_component,
)
from .presets import available_presets, gps_preset
from .receiver import ReceiverReport
from .sensor import MAX_LATENCY_S, MAX_RATE_HZ, GpsSensor, validate_overrides

__all__ = [
    "AR1",
    "AlphaStable",
    "FixQualityChain",
    "GaussMarkov",
    "Gaussian",
    "GaussianMixture",
    "GpsSensor",
    "Laplace",
    "MAX_LATENCY_S",
    "MAX_RATE_HZ",
    "MultipathSpikes",
    "NoiseComponent",
    "OutageProcess",
    "ReceiverReport",
    "SeedLike",
    "StudentT",
    "SymmetricWeibull",
    "available_presets",
    "derive_seed",
    "gps_preset",
    "make_component",
    "validate_overrides",
]
