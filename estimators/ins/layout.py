"""The INS's flat arrays, each declared once by name and size (:class:`numkit.Layout`).

A layout lists an array's fields in order (``"name"`` one slot, ``"name:3"`` three,
``"name:3x15"`` a 3 × 15 block); the offsets and the total size follow from it, so no offset
is kept by hand.  The kernels index through each layout's :attr:`~numkit.Layout.at`, a named
tuple of offsets that numba freezes into the compiled code (``x[S.QUAT:S.QUAT_END]``,
``prm[PR.DT]``, ``fb[W.DX:W.DX_END]``):

* ``STATE`` (``S``): the nominal state x = [p, v, q, b_a, b_g]; ``ERR`` (``E``): the error
  state δx = [δp, δv, δθ, δb_a, δb_g], the rows and columns of P;
* ``PRM`` (``PR``): the bank's shared parameters (``INSConfig.prm``);
* ``INTS`` (``CT``): each row's counters and queue state; ``DG`` (``DGA``): each row's
  diagnostics and the adaptive kernel's state; ``MPAR`` (``MP``): each row's MCKF parameters;
* ``REC`` (``RC``): one record of the delayed-fusion queue, its measurement laid out as
  ``GZ``; ``GIN`` (``GI``), ``RIN`` (``RI``): one GNSS, one radar input row; ``IMU`` (``U``):
  one IMU sample; ``POPT`` (``PO``): the PCA block's options;
* ``SCRATCH`` (``W``): the tick's work, one flat buffer per bank shared by its rows (the
  per-tick path allocates nothing); :func:`view2` / :func:`view3` give its blocks' views, and
  ``STEP`` (``WS``), ``RESET`` (``RS``), ``PMAT`` (``PM``), ``HMAT`` (``HM``) name the slots of
  the prediction's and the injection's vectors and of the stacks of 3×3 matrices.
"""

from __future__ import annotations

from numkit import Layout

from .._jit import njit
from ..mckf import MCKF_A, MCKF_F, MCKF_ST, mckf_work_size

__all__ = ["CT", "DG", "DGA", "E", "ERR", "GI", "GIN", "GZ", "HM", "HMAT", "IMU", "INTS", "Layout",
           "MP", "MPAR", "NZ", "PM", "PMAT", "PO", "POPT", "PR", "PRM", "RC", "REC", "RESET", "RI",
           "RIN", "RS", "S", "SCRATCH", "STATE", "STEP", "U", "W", "WS", "view2", "view3"]

#: the nominal state: position, velocity (world, m, m/s), attitude quaternion (w, x, y, z; body
#: to world), accelerometer and gyro biases (body)
STATE = Layout("pos:3 vel:3 quat:4 ba:3 bg:3")
S = STATE.at

#: the error state (the rows and columns of P): δp, δv, the local attitude error δθ
#: (q_true = q ⊗ Exp(δθ)), δb_a, δb_g
ERR = Layout("pos:3 vel:3 theta:3 ba:3 bg:3")
E = ERR.at

#: the prediction's scratch (``W.W``): the increments Δv, φ (:func:`~.model.increments`),
#: Exp(φ), the new quaternion, and the previous sample's rotation and velocity increments
STEP = Layout("dv:3 dth:3 dq:4 qn:4 dth_p:3 dv_p:3")
WS = STEP.at

#: the error injection's scratch (``W.V``): Exp(δθ) and the new quaternion
RESET = Layout("dq:4 qn:4")
RS = RESET.at

#: the prediction's 3×3 matrices (the (n, 3, 3) scratch ``W.S3P``): R(q), F_vθ, F_vba, F_θθ,
#: R [a]×
PMAT = Layout("r fv fba fth ra")
PM = PMAT.at

#: the measurement models' 3×3 matrices (``W.S3``): R(q) and two skew products
HMAT = Layout("r s1 s2")
HM = HMAT.at

#: the GNSS position fix's size (the rows of the position update)
NZ = 3

#: one IMU sample: specific force f̃ and body rate ω̃ (body axes)
IMU = Layout("f:3 w:3")
U = IMU.at

#: shared parameters: Δt, g, the Q impulses (δv, δθ, δb_a, δb_g, in the order of the error state's
#: blocks: :func:`~.model.cov_step` adds ``prm[PR.QV + b]`` to block b), lever arm, heading
#: baseline, radar offset, ground height, cos(max tilt), max range, delay D (ticks), delayed (0/1),
#: ring length B = D + 2 (the core's sample and the one before it, for the coning correction),
#: queue length, the innovation gate (σ; inf = off), its reset time (ticks), the step latch's hold
#: limit (ticks; 0 = no latch, inf = no limit), the PCA block's window (fixes), the coning and
#: sculling corrections (0/1)
PRM = Layout("dt g qv qt qba qbg r_ant:3 r_b:3 r_rad:3 z_g cos_max r_max delay delayed ring "
             "queue gate gate_reset gate_latch pca_window coning")
PR = PRM.at

#: per row: ticks now and of the core, queued records, output dirty (0/1), records fused late,
#: records dropped (queue full), the MCKF state (n_rejected, n_iter, rejected, recovered),
#: GNSS / radar fused, radar dropped; the gate: position / velocity / heading fixes rejected,
#: position resets to the receiver, the core ticks of the last fused (or reset) position and
#: of the last fused velocity, of the last position reset (0: the filter's start); the step
#: latch: its state (none / candidate / on), the core tick it opened, its releases, the fixes
#: fused relative to the latched step, the fixes still to come whose PCA window spans a held one
INTS = Layout(f"now core qn dirty late qdrop mst:{MCKF_ST.size} ngnss nrad rdrop grejp grejv "
              "grejy greset glast glastv grst glatch glat0 grel gnrel graw")
CT = INTS.at

#: per row: the last NIS of position / velocity / heading / radar, diag C_y of the last MCKF
#: update, ŝ of the adaptive bandwidth rule (1 after a reset), the last fix's position (0
#: fused, 1 rejected by the gate, 2 reset, 3 held by the step latch; NaN: none), the radar
#: NIS summed over the fused ranges and their number, the latched step b (the innovation of
#: the fix that opened the latch), its variance (that fix's innovation variance per axis) and
#: the latch's CUSUM of the evidence against the step, the latched fix's reported east variance
DG = Layout(f"nisp nisv nisy nisr wy:{NZ} s2 gate rsum rn gb:{NZ} gs:{NZ} gc gr")
DGA = DG.at

#: per row MCKF parameters: kernel coefficients kx (15 states), ky (3 position rows), fpar,
#: apar = (adaptive, λ, clip), the 18 base widths σ
MPAR = Layout(f"kx:{ERR.size} ky:{NZ} f:{MCKF_F.size} a:{MCKF_A.size} sig:{ERR.size + NZ}")
MP = MPAR.at

#: a GNSS measurement z (and its variances, laid out alike): position, velocity, yaw
GZ = Layout("p:3 v:3 yaw").at

#: a queue record: tick, kind (0 GNSS, 1 radar), z (GNSS as ``GZ``; radar range), the PCA'd
#: position, the variances of z
REC = Layout(f"t kind z:{GZ.SIZE} zp:{NZ} var:{GZ.SIZE}")
RC = REC.at

#: a GNSS input row: age (s; NaN: no fix), p, v, yaw, their variances (NaN parts: absent)
GIN = Layout("age p:3 v:3 yaw var_p:3 var_v:3 var_yaw")
GI = GIN.at

#: a radar input row: range (NaN: none / dropout), its variance, its age (s)
RIN = Layout("range var age")
RI = RIN.at

#: the PCA block's options (shared by the bank): window N, embedding L, components r, mode
#: (``estimators.pca.PCA_MODE``), whether any row has a PCA rule (0/1)
POPT = Layout("window embed components mode any_pca")
PO = POPT.at

#: the tick's work: H, ν, R for m = 3 and m = 1, δx, the models' (3, 3, 3) (``HMAT``) and
#: vector (``RESET``), the adaptive MCKF kernels kx, ky; F P (its δp, δv, δθ rows), the
#: prediction's (5, 3, 3) (``PMAT``) and vector (``STEP``), the PCA'd
#: fix, three NaNs, the raw fix's innovation (the step latch's); the KF / MCKF work of one
#: update (``mckf_work_size(15, 3)`` floats, whose head is the KF work: the two updates never
#: run at once)
_NE = ERR.size
SCRATCH = Layout(f"H3:{NZ}x{_NE} nu3:{NZ} R3:{NZ}x{NZ} H1:1x{_NE} nu1:1 R1:1x1 dx:{_NE} "
                 f"S3:{HMAT.size}x3x3 v:{RESET.size} kx:{_NE} ky:{NZ} M:{ERR.offset['ba']}x{_NE} "
                 f"S3P:{PMAT.size}x3x3 w:{STEP.size} zp:{NZ} nan:{NZ} nur:{NZ} "
                 f"kf:{getattr(mckf_work_size, 'py_func', mckf_work_size)(_NE, NZ)}")
W = SCRATCH.at


@njit(inline="always")
def view2(fb, o, r, c):
    """The (r, c) view of the scratch at offset o."""
    return fb[o:o + r * c].reshape((r, c))


@njit(inline="always")
def view3(fb, o, n):
    """The (n, 3, 3) view of the scratch at offset o."""
    return fb[o:o + 9 * n].reshape((n, 3, 3))
