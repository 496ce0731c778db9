"""Error-state INS/GNSS filter with delayed fusion; the bank's four laws as its GNSS update.

Frames and conventions (those of the simulator: ``ag_uav/vehicle/imu.py``): world ENU (z up),
gravity ``g_w = (0, 0, −g)``; the IMU reports the body-frame **specific force**
``f̃ = Rᵀ(a − g_w) + b_a + n_a`` (+g along body z at rest) and the body rate
``ω̃ = ω + b_g + n_g``; ``q = (w, x, y, z)`` is the Hamilton body-to-world quaternion
(MuJoCo's), ``R = R(q)``.

Nominal state (16) and error state (15), after Solà, *Quaternion kinematics for the error-state
Kalman filter* (2017, arXiv:1711.02508), §5 with the local (body) angular error
``q_true = q ⊗ Exp(δθ)``::

    x = [p, v, q, b_a, b_g]                δx = [δp, δv, δθ, δb_a, δb_g]

Prediction, one IMU sample (Solà eqs 5.3.3 / 260 without the gravity state; a = f̃ − b_a,
ω = ω̃ − b_g, R at the start of the step)::

    p ← p + v Δt + ½ (R Δv/Δt + g_w) Δt²,   v ← v + R Δv + g_w Δt,   q ← q ⊗ Exp(φ)
    φ  = ω Δt + (1/12) α' × ω Δt                                  (coning)
    Δv = a Δt + ½ ω Δt × a Δt + (1/12) (α' × a Δt + ν' × ω Δt)      (rotation + sculling)

with α' = ω' Δt, ν' = a' Δt of the previous sample (the IMU's samples are the means of its
delta-angles and delta-velocities over Δt; ``INSConfig.coning = False``: φ = ω Δt, Δv = a Δt,
rates held over the step; :func:`estimators.ins.model.increments` has the sources)
    P ← F P Fᵀ + Q,   F = I + blocks:  F_pv = I Δt,  F_vθ = −R [a]× Δt,  F_vba = −R Δt,
                                       F_θθ = Exp(ω Δt)ᵀ (replaces I),  F_θbg = −I Δt
    Q = diag(σ_a² Δt² I, σ_g² Δt² I, σ_ba² Δt I, σ_bg² Δt I)   on (δv, δθ, δb_a, δb_g)

(Solà eqs 5.4.3 / 269-270: the impulses V_i = σ_ãn² Δt², Θ_i = σ_ω̃n² Δt², A_i = σ_aw² Δt,
Ω_i = σ_ωw² Δt).  ``σ_a``, ``σ_g`` are the per-sample white-noise standard deviations of the
IMU (density over the Nyquist band of the sample rate, plus vibration, as the simulator's IMU
draws them: :meth:`INSConfig.from_imu`), ``σ_ba``, ``σ_bg`` the bias random walks.
``F P Fᵀ`` is written out on F's blocks (``M = F P`` on its first 9 rows, then the upper
triangle of ``M Fᵀ``, mirrored; the bias block, where F = I, is P's own), each entry summed in
F's column order.

Measurements (h, and H = ∂h/∂δx; R [r]× from ∂(R Exp(δθ) r)/∂δθ = −R [r]×):

* GNSS position at the antenna (lever arm ``r_ant`` in body axes)::

      h = p + R r_ant,               H = [I, 0, −R [r_ant]×, 0, 0]

* GNSS velocity at the antenna (ω from the gyro sample of that step)::

      h = v + R (ω × r_ant),         H = [0, I, −R [ω × r_ant]×, 0, R [r_ant]×]

* Dual-antenna heading: azimuth of the antenna baseline ``r_b`` (body) in the world,
  ``b = R r_b``, less the baseline's body azimuth (PX4's ``heading_offset``), so that the
  measurement is the vehicle yaw: ``ψ = atan2(b_y, b_x) − atan2(r_b,y, r_b,x)``::

      H_θ = [−b_y, b_x, 0] / (b_x² + b_y²) · (−R [r_b]×),   ν wrapped to (−π, π]

  This is the default yaw source (the DJI Matrice 350 RTK class carries two GNSS antennas;
  PX4 supports dual-antenna RTK heading "as an alternative to compass-based heading
  estimation", docs.px4.io, *RTK GPS Heading with Dual u-blox F9P*): a magnetometer on a spray
  drone sits among motor and pump currents and steel, whose disturbance is neither white nor
  known, while the baseline heading's error is σ_ψ ≈ σ_b / L (relative-position error over the
  baseline length).  Default σ_ψ = 0.5° is that ratio for σ_b ≈ 5 mm and L ≈ 0.6 m
  (engineering judgement; no DJI datasheet figure was found); receivers report it per fix
  (PX4 ``VehicleGnssHeading.heading_accuracy``), which the caller can pass as the variance.
* Radar altimeter, a narrow beam along body −z from ``r_rad`` to flat ground at ``z_g``
  (slant range over a tilted vehicle: ρ = h / cos(tilt))::

      s = p + R r_rad,   c = (R e_z)_z = cos(tilt),   h = s_z − z_g,   ρ = h / c
      ∂ρ/∂δp_z = 1/c,    ∂ρ/∂δθ = (1/c) (−R [r_rad]×)_z − (h/c²) (−R [e_z]×)_z

  Not fused (a dropout, counted) for a NaN range, c < cos(max tilt) or ρ above the maximum
  range.  (A wide-beam radar returns the nearest echo, ≈ h not h/c: not modelled.)

Update rules of the GNSS **position** (``rule``): ``"kf"`` the Joseph update; ``"mckf"`` the
correntropy fixed point on the position innovation (Chen, Liu, Zhao, Principe, Automatica 80,
2017; σ → ∞ is the KF; lock-out recovery as :class:`estimators.MCKF`); ``"pca-kf"``,
``"pca-mckf"`` the same after the PCA block (Candan & Li §III.C) on the window of antenna
fixes, run once per vehicle when a fix arrives.  The MCKF kernel (``INSConfig.mckf_kernel``):
``"fixed"`` σ per row as given, ``"adaptive"`` the adaptive bandwidth of :class:`estimators.MCKF`
(one row function for both, :func:`estimators.mckf.mckf_adaptive_update_row`; state ŝ per
row), ``"multi"`` σ on the fix's rows, ∞ on the prior's.  Velocity, heading and radar use the
KF update.  **The gate** in front of every rule (PX4 EKF2's innovation test, ``EKF2_GPS_GATE``
= 5 σ; :func:`gate_ratio`): a fix's position, velocity or heading whose innovation exceeds
``gate_sigma`` standard deviations on any axis is not fused; after ``gate_reset_s`` with
neither position nor velocity fused, or with no position fused for twice that, a rejected fix
resets the position to it (PX4 EKF2's two timeouts). **The step latch**
behind the gate (``gate_latch_s`` > 0; not in PX4 EKF2): a false RTK fix (wrong integer
ambiguities) is a constant step in a receiver that still reports cm accuracy, and the
single-epoch test re-admits it once the position variance, fed only by the velocities, has grown
to the step (10–20 s).  So a position the gate rejects, once the filter has fused fixes for
``gate_reset_s`` since it was set on one (its start, a reset) and while it knows the antenna's
horizontal position at least as well as the fix does (S_ii ≤ 2 R_ii: a filter less sure than
its fixes, out of a float or DGPS period, is more likely wrong itself), opens a candidate step
b = its innovation, with its innovation variance as b's.  The next fix confirms it when the
gate rejects it too and it lies nearer the step than the filter (a lone outlier does not).
While the latch holds, every fix is held: its position is not taken, and it is fused relative
to the step (ν − b, R + diag var b, through the gate again), as a relative position from a
receiver whose integers are wrong but constant.  Page's CUSUM of the evidence for the
unstepped receiver (the log-likelihood ratio ½ [Σ (ν_i − b_i)²/S_ii − Σ ν_i²/S_ii],
:func:`step_llr`, each fix's clipped to ±γ²/2) releases it at γ², and so does a fix whose
reported variance leaves a factor 2 of the latched one's (a new solution); held for
``gate_latch_s`` (default 60 s), the receiver is believed: the position resets to it.  A filter
anchored this way is tied to the step's estimate, whose error (the fix's and the filter's at
the step, ~1–2 cm) the held fixes cannot see.  The PCA rules gate and latch on the raw fix, and
fuse the raw fix while their PCA window spans a fix whose raw position the gate rejected or the
latch held: the window's reconstruction rings after such a fix by centimetres.  Each
measurement is fused sequentially (R block-diagonal), then injected and reset
(Solà §6.2-6.3, eqs 282-287)::

      p += δp, v += δv, q ← q ⊗ Exp(δθ), b += δb;   P ← G P Gᵀ, G_θθ = I − [½ δθ]×

The laws live in :mod:`estimators._ins_laws` (the bank's own row functions).

**Delayed fusion** (PX4 EKF2: "The EKF runs on a delayed 'fusion time horizon' … an output
predictor … uses buffered IMU data to propagate the states forward to the current time",
docs.px4.io *Using the ECL EKF*; ``EKF2_GPS_DELAY`` default 110 ms, ekf2_params.c): the core
filter (nominal + P) runs ``D = round(delay / Δt)`` IMU samples behind now, from a ring of the
last D+2 samples (the core's previous sample feeds its coning and sculling corrections).
Every measurement carries its time tag (``now − age``) into a queue and is fused when the
core reaches it (at once if it is already late, counted in ``n_late``).  The output for the
controller is the core nominal propagated through the buffered samples (the same nominal
step, so with no new correction it advances one sample per tick).  With
``delayed = False`` (fuse at receipt) D = 0 and every fix is fused as if it were current.

Everything is one compiled kernel per tick over the rows (vehicles × filters): the
single-vehicle :class:`INS` is a :class:`BatchINS` of one vehicle, so a row's arithmetic is the
same whatever the batch (bit-identical rows).

The package, one idea a module: :mod:`~estimators.ins.layout` (the bank's flat arrays, each
declared once by name and size), :mod:`~estimators.ins.model` (prediction, injection, the
measurement models and the gate; its quaternion algebra is :mod:`numkit.geometry`'s),
:mod:`~estimators.ins.fusion` (one measurement, the delayed-fusion queue, the tick),
:mod:`~estimators.ins.config` (:class:`INSConfig`) and :mod:`~estimators.ins.bank`
(:class:`BatchINS`, :class:`INS`).
"""

from __future__ import annotations

from . import layout
from .bank import INS, BatchINS
from .config import DEG, G_STD, KERNELS, RULES, INSConfig
from .model import (
    cov_step,
    gate_ratio,
    h_gnss_pos,
    h_gnss_vel,
    h_heading,
    h_radar,
    increments,
    inject_reset,
    nominal_step,
    quat_exp,
    quat_log_err,
    quat_mul,
    quat_to_rot,
)

__all__ = ["DEG", "G_STD", "KERNELS", "RULES", "BatchINS", "INS", "INSConfig", "cov_step",
           "gate_ratio", "h_gnss_pos", "h_gnss_vel", "h_heading", "h_radar", "increments",
           "inject_reset",
           "layout", "nominal_step", "quat_exp", "quat_log_err", "quat_mul", "quat_to_rot"]
