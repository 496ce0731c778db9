"""The INS bank's flat arrays, each declared once by name and size.

A :class:`Layout` lists an array's fields in order (``"name"`` one slot, ``"name:3"`` three,
``"name:3x15"`` a 3 × 15 block); the offsets and the total size follow from it, so no offset
is kept by hand.  The kernels read the offsets as module constants (numba freezes them into the
compiled code), named ``<ARRAY>_<FIELD>``:

* ``PRM``: the bank's shared parameters (``INSConfig.prm``);
* ``INTS``: each row's counters and queue state; ``DG``: each row's diagnostics and the
  adaptive kernel's state; ``MPAR``: each row's MCKF parameters;
* ``REC``: one record of the delayed-fusion queue; ``GIN``, ``RIN``: one GNSS, one radar
  input row (``<ARRAY>_N``: the size where a kernel needs it);
* ``SCRATCH``: the tick's work, one flat buffer per bank shared by its rows (the per-tick path
  allocates nothing); :func:`view2` / :func:`view3` give its blocks' views.
"""

from __future__ import annotations

from .._jit import njit
from ..mckf import mckf_work_size

__all__ = ["DG", "GIN", "INTS", "MPAR", "PRM", "REC", "RIN", "SCRATCH", "Layout", "view2",
           "view3"]


class Layout:
    """Named fields of a flat array, in order: ``Layout("dt g r_ant:3 H:3x15")``.

    ``offsets`` (in declaration order), ``offset[name]``, ``shape[name]``, ``size``."""

    def __init__(self, fields: str) -> None:
        self.offset: dict[str, int] = {}
        self.shape: dict[str, tuple[int, ...]] = {}
        o = 0
        for f in fields.split():
            name, _, dims = f.partition(":")
            shape = tuple(int(d) for d in dims.split("x")) if dims else (1,)
            self.offset[name], self.shape[name] = o, shape
            n = 1
            for d in shape:
                n *= d
            o += n
        self.size = o
        self.offsets = tuple(self.offset.values())

    def slice(self, name: str) -> slice:
        """The field's slots."""
        n = 1
        for d in self.shape[name]:
            n *= d
        return slice(self.offset[name], self.offset[name] + n)


#: shared parameters: Δt, g, the Q impulses (δv, δθ, δb_a, δb_g), lever arm, heading baseline,
#: radar offset, ground height, cos(max tilt), max range, delay D (ticks), delayed (0/1), ring
#: length B = D + 2 (the core's sample and the one before it, for the coning correction),
#: queue length, the innovation gate (σ; inf = off), its reset time (ticks), the step latch's
#: hold limit (ticks; 0 = no latch, inf = no limit), the PCA block's window (fixes), the
#: coning and sculling corrections (0/1)
PRM = Layout("dt g qv qt qba qbg r_ant:3 r_b:3 r_rad:3 z_g cos_max r_max delay delayed ring "
             "queue gate gate_reset gate_latch pca_window coning")
(PRM_DT, PRM_G, PRM_QV, PRM_QT, PRM_QBA, PRM_QBG, PRM_RANT, PRM_RB, PRM_RRAD, PRM_ZG,
 PRM_COSMAX, PRM_RMAX, PRM_D, PRM_DELAYED, PRM_B, PRM_QC, PRM_GATE, PRM_GRESET,
 PRM_GLATCH, PRM_PCAW, PRM_CONING) = PRM.offsets

#: per row: ticks now and of the core, queued records, output dirty (0/1), records fused late,
#: records dropped (queue full), the MCKF state (n_rejected, n_iter, rejected, recovered),
#: GNSS / radar fused, radar dropped; the gate: position / velocity / heading fixes rejected,
#: position resets to the receiver, the core ticks of the last fused (or reset) position and
#: of the last fused velocity, of the last position reset (0: the filter's start); the step
#: latch: its state (none / candidate / on), the core tick it opened, its releases, the fixes
#: fused relative to the latched step, the fixes still to come whose PCA window spans a held one
INTS = Layout("now core qn dirty late qdrop mst:4 ngnss nrad rdrop grejp grejv grejy greset "
              "glast glastv grst glatch glat0 grel gnrel graw")
(INTS_NOW, INTS_CORE, INTS_QN, INTS_DIRTY, INTS_LATE, INTS_QDROP, INTS_MST, INTS_NGNSS,
 INTS_NRAD, INTS_RDROP, INTS_GREJP, INTS_GREJV, INTS_GREJY, INTS_GRESET, INTS_GLAST,
 INTS_GLASTV, INTS_GRST, INTS_GLATCH, INTS_GLAT0, INTS_GREL, INTS_GNREL,
 INTS_GRAW) = INTS.offsets

#: per row: the last NIS of position / velocity / heading / radar, diag C_y of the last MCKF
#: update, ŝ of the adaptive bandwidth rule (1 after a reset), the last fix's position (0
#: fused, 1 rejected by the gate, 2 reset, 3 held by the step latch; NaN: none), the radar
#: NIS summed over the fused ranges and their number, the latched step b (the innovation of
#: the fix that opened the latch), its variance (that fix's innovation variance per axis) and
#: the latch's CUSUM of the evidence against the step, the latched fix's reported east variance
DG = Layout("nisp nisv nisy nisr wy:3 s2 gate rsum rn gb:3 gs:3 gc gr")
(DG_NISP, DG_NISV, DG_NISY, DG_NISR, DG_WY, DG_S2, DG_GATE, DG_RSUM, DG_RN, DG_GB,
 DG_GS, DG_GC, DG_GR) = DG.offsets

#: per row MCKF parameters: kernel coefficients kx (15 states), ky (3 position rows), fpar,
#: apar = (adaptive, λ, clip), the 18 base widths σ
MPAR = Layout("kx:15 ky:3 f:5 a:3 sig:18")
MPAR_KX, MPAR_KY, MPAR_F, MPAR_A, MPAR_SIG = MPAR.offsets
MPAR_N = MPAR.size

#: a queue record: tick, kind (0 GNSS, 1 radar), z (GNSS p, v, yaw; radar range), the PCA'd
#: position, the variances of z
REC = Layout("t kind z:7 zp:3 var:7")
REC_T, REC_K, REC_Z, REC_ZP, REC_V = REC.offsets
REC_N = REC.size

#: a GNSS input row: age (s; NaN: no fix), p, v, yaw, their variances (NaN parts: absent)
GIN = Layout("age p:3 v:3 yaw var_p:3 var_v:3 var_yaw")
GIN_AGE, GIN_P, GIN_V, GIN_YAW, GIN_VARP, GIN_VARV, GIN_VARYAW = GIN.offsets
GIN_N = GIN.size

#: a radar input row: range (NaN: none / dropout), its variance, its age (s)
RIN = Layout("range var age")
RIN_RANGE, RIN_VAR, RIN_AGE = RIN.offsets

#: the tick's work: H, ν, R for m = 3 and m = 1, δx, the models' (3, 3, 3) and vector, the
#: adaptive MCKF kernels kx, ky; F P (9, 15), the prediction's (5, 3, 3) and vector, the PCA'd
#: fix, three NaNs, the raw fix's innovation (the step latch's); the KF / MCKF work of one
#: update (``mckf_work_size(15, 3)`` floats, whose head is the KF work: the two updates never
#: run at once)
SCRATCH = Layout("H3:3x15 nu3:3 R3:3x3 H1:1x15 nu1:1 R1:1x1 dx:15 S3:3x3x3 v:8 kx:15 ky:3 "
                 f"M:9x15 S3P:5x3x3 w:18 zp:3 nan:3 nur:3 "
                 f"kf:{getattr(mckf_work_size, 'py_func', mckf_work_size)(15, 3)}")
(W_H3, W_NU3, W_R3, W_H1, W_NU1, W_R1, W_DX, W_S3, W_V, W_KX, W_KY, W_M, W_S3P, W_W, W_ZP,
 W_NAN, W_NUR, W_KF) = SCRATCH.offsets


@njit(inline="always")
def view2(fb, o, r, c):
    """The (r, c) view of the scratch at offset o."""
    return fb[o:o + r * c].reshape((r, c))


@njit(inline="always")
def view3(fb, o, n):
    """The (n, 3, 3) view of the scratch at offset o."""
    return fb[o:o + 9 * n].reshape((n, 3, 3))
