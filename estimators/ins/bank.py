"""The INS filters: :class:`BatchINS` (vehicles × rules, one compiled call a tick) and
:class:`INS` (a bank of one); see :mod:`estimators.ins`."""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from numkit import QW

from ..pca import PCA_MODE
from . import layout
from .config import DEG, RULE_CODE, RULES, INSConfig
from .fusion import step_kernel
from .layout import DGA, ERR, GI, GIN, IMU, PO, POPT, RIN, STATE, S, U

__all__ = ["COUNTERS", "BatchINS", "INS"]

#: the keys of :attr:`BatchINS.counters`: the field of :data:`layout.INTS` each reads, and the
#: slot in it
COUNTERS = {"gnss_fused": ("ngnss", 0), "radar_fused": ("nrad", 0), "radar_dropped": ("rdrop", 0),
            "late": ("late", 0), "queue_full": ("qdrop", 0), "mckf_n_iter": ("mst", 1),
            "mckf_rejected": ("mst", 2), "mckf_recovered": ("mst", 3),
            "gate_rejected_pos": ("grejp", 0), "gate_rejected_vel": ("grejv", 0),
            "gate_rejected_yaw": ("grejy", 0), "gate_resets": ("greset", 0),
            "gate_latch_releases": ("grel", 0), "gnss_fused_relative": ("gnrel", 0)}


# ------------------------------------------------------------------------ classes
class BatchINS:
    """``n_vehicles`` × ``len(rules)`` INS filters advanced by one compiled call per tick.

    Row ``i`` is vehicle ``i // len(rules)`` with rule ``rules[i % len(rules)]`` (a vehicle's
    bank: one flown filter and its shadows, all fed the same IMU samples and fixes).  Arrays:
    ``x_out`` (N, 16) the output nominal now ``[p, v, q, b_a, b_g]``, ``x_core`` / ``P`` the
    core filter at the fusion horizon (tick ``core_tick``), ``nis`` (N, 4) the last NIS of
    position / velocity / heading / radar.
    """

    def __init__(self, n_vehicles: int, cfg: INSConfig | None = None,
                 rules: Sequence[str] = ("kf",)) -> None:
        self.cfg = cfg = cfg or INSConfig()
        bad = [r for r in rules if r not in RULE_CODE]
        if bad or not rules:
            raise ValueError(f"rules must be among {RULES}, got {list(rules)}")
        if cfg.pca_mode not in PCA_MODE:
            raise ValueError(f"pca_mode must be 'hankel' or 'channels', got {cfg.pca_mode!r}")
        self.NV, self.rules = int(n_vehicles), tuple(rules)
        N = self.N = self.NV * len(rules)
        self.prm = cfg.prm()
        B = int(self.prm[layout.PR.RING])
        self.x_core = np.zeros((N, STATE.size))
        self.x_core[:, S.QUAT + QW] = 1.0
        self.P = np.tile(np.eye(ERR.size), (N, 1, 1))
        self.x_out = self.x_core.copy()
        self._ib = np.zeros((N, B, IMU.size))
        self._ints = np.zeros((N, layout.INTS.size), dtype=np.int64)
        self._mq = np.zeros((N, cfg.queue, layout.REC.size))
        self._dg = np.full((N, layout.DG.size), np.nan)
        self._dg[:, DGA.S2] = 1.0
        self._dg[:, DGA.RSUM:DGA.RN_END] = 0.0
        mpar, ipar = cfg.mckf_params()
        self._mpar = np.tile(mpar, (N, 1))
        self._ipar = np.tile(ipar, (N, 1))
        self._rules = np.tile(np.array([RULE_CODE[r] for r in rules], dtype=np.int64), self.NV)
        Nw = int(cfg.pca_window)
        mode = cfg.pca_mode
        L = (Nw // 2 if cfg.pca_embed is None else int(cfg.pca_embed)) if mode == "hankel" else 0
        r = cfg.pca_components or (2 if mode == "hankel" else 1)
        any_pca = any(x.startswith("pca") for x in rules)
        self._popt = np.empty(POPT.size, dtype=np.int64)
        self._popt[PO.WINDOW], self._popt[PO.EMBED], self._popt[PO.COMPONENTS] = Nw, L, r
        self._popt[PO.MODE], self._popt[PO.ANY_PCA] = PCA_MODE[mode], int(any_pca)
        self._pbuf = np.zeros((self.NV, 3, 2 * Nw))
        self._pcs = np.zeros((self.NV, 2), dtype=np.int64)
        self._no_g = np.full((self.NV, GIN.size), np.nan)
        self._no_r = np.full((self.NV, RIN.size), np.nan)
        self._no_imu = np.zeros((self.NV, IMU.size))
        self._fb = np.empty(layout.SCRATCH.size)
        self._fb[layout.SCRATCH.slice("nan")] = np.nan

    # -- state ------------------------------------------------------------------------------
    def reset(self, p, v, q, ba=None, bg=None, P0=None) -> None:
        """Initial nominal per vehicle ((NV, 3) / (NV, 4) or one row for all) and P0 (15
        standard deviations, or a 15×15 matrix); clears the buffers and queues."""
        NV, nr = self.NV, len(self.rules)
        x = np.zeros((NV, STATE.size))
        x[:, S.POS:S.POS_END], x[:, S.VEL:S.VEL_END], x[:, S.QUAT:S.QUAT_END] = p, v, q
        x[:, S.BA:S.BA_END] = 0.0 if ba is None else ba
        x[:, S.BG:S.BG_END] = 0.0 if bg is None else bg
        x[:, S.QUAT:S.QUAT_END] /= np.linalg.norm(x[:, S.QUAT:S.QUAT_END], axis=1, keepdims=True)
        self.x_core[:] = np.repeat(x, nr, axis=0)
        self.x_out[:] = self.x_core
        P0 = np.eye(ERR.size) if P0 is None else np.asarray(P0, dtype=float)
        self.P[:] = np.diag(P0**2) if P0.ndim == 1 else P0
        self._ib[:] = 0.0
        self._ints[:] = 0
        self._dg[:] = np.nan
        self._dg[:, DGA.S2] = 1.0
        self._dg[:, DGA.RSUM:DGA.RN_END] = 0.0
        self._pcs[:] = 0

    def reset_vehicle(self, iv: int, p, v, q, ba=None, bg=None, P0=None) -> None:
        """:meth:`reset` of vehicle ``iv``'s rows only (the others untouched): a vehicle of a
        batch initialised at its own first fix."""
        nr = len(self.rules)
        rows = slice(iv * nr, (iv + 1) * nr)
        x = np.zeros(STATE.size)
        x[S.POS:S.POS_END], x[S.VEL:S.VEL_END], x[S.QUAT:S.QUAT_END] = p, v, q
        x[S.BA:S.BA_END] = 0.0 if ba is None else ba
        x[S.BG:S.BG_END] = 0.0 if bg is None else bg
        x[S.QUAT:S.QUAT_END] /= np.linalg.norm(x[S.QUAT:S.QUAT_END])
        self.x_core[rows] = x
        self.x_out[rows] = x
        P0 = np.eye(ERR.size) if P0 is None else np.asarray(P0, dtype=float)
        self.P[rows] = np.diag(P0**2) if P0.ndim == 1 else P0
        self._ib[rows] = 0.0
        self._ints[rows] = 0
        self._dg[rows] = np.nan
        self._dg[rows, DGA.S2] = 1.0
        self._dg[rows, DGA.RSUM:DGA.RN_END] = 0.0
        self._pcs[iv] = 0

    # -- ticks ------------------------------------------------------------------------------
    def step(self, imu=None, gnss=None, radar=None) -> None:
        """One tick: predict with ``imu`` (NV, 6) = (f̃, ω̃) if given, then queue the fixes and
        fuse what is due.  ``gnss`` (NV, 15) rows ``[age_s, p(3), v(3), yaw, var_p(3),
        var_v(3), var_yaw]`` (NaN age: no fix; NaN components: absent); ``radar`` (NV, 3)
        rows ``[range, var, age_s]`` (NaN range: none / dropout)."""
        pred = imu is not None
        step_kernel(self._rows(), self.prm, self._popt,
                     self._no_imu if imu is None else np.ascontiguousarray(imu, dtype=float),
                     pred, self._no_g if gnss is None else np.ascontiguousarray(gnss, dtype=float),
                     self._no_r if radar is None else np.ascontiguousarray(radar, dtype=float),
                     self._fb)

    def step_raw(self, imu, gnss, radar) -> None:
        """:meth:`step` with all three inputs given as C-contiguous float64 arrays (the
        caller's own buffers: no conversion), always predicting."""
        step_kernel(self._rows(), self.prm, self._popt, imu, True, gnss, radar, self._fb)

    def _rows(self) -> tuple:
        """The bank's rows as :class:`~estimators.ins.fusion.BankRows` wants them (a plain
        tuple in field order)."""
        return (self.x_core, self.P, self.x_out, self._ib, self._ints, self._mq, self._dg,
                self._mpar, self._ipar, self._pbuf, self._pcs, self._rules)

    def predict(self, imu) -> None:
        self.step(imu)

    def update(self, gnss=None, radar=None) -> None:
        self.step(None, gnss, radar)

    @staticmethod
    def gnss_row(pos=None, vel=None, yaw=None, var_pos=(1e-4,) * 3, var_vel=(1e-4,) * 3,
                 var_yaw=(0.5 * DEG) ** 2, age_s: float = 0.0) -> np.ndarray:
        """One ``gnss`` input row (absent parts NaN)."""
        g = np.full(GIN.size, np.nan)
        g[GI.AGE] = age_s
        if pos is not None:
            g[GI.P:GI.P_END] = pos
        if vel is not None:
            g[GI.V:GI.V_END] = vel
        if yaw is not None:
            g[GI.YAW] = yaw
        g[GI.VAR_P:GI.VAR_P_END], g[GI.VAR_V:GI.VAR_V_END] = var_pos, var_vel
        g[GI.VAR_YAW] = var_yaw
        return g

    # -- views ------------------------------------------------------------------------------
    @property
    def now_tick(self) -> np.ndarray:
        return self._ints[:, layout.CT.NOW]

    @property
    def core_tick(self) -> np.ndarray:
        return self._ints[:, layout.CT.CORE]

    @property
    def nis(self) -> np.ndarray:
        return self._dg[:, DGA.NISP:DGA.NISR_END]

    @property
    def counters(self) -> dict[str, np.ndarray]:
        """(N,) views of the rows' counters (:data:`COUNTERS`)."""
        ints, off = self._ints, layout.INTS.offset
        return {k: ints[:, off[f] + j] for k, (f, j) in COUNTERS.items()}

    @property
    def gate_state(self) -> np.ndarray:
        """(N,) the last fix's position per row: 0 fused, 1 rejected by the gate, 2 rejected
        and reset to the receiver (NaN: no position in the last fix)."""
        return self._dg[:, DGA.GATE]

    @property
    def radar_nis(self) -> np.ndarray:
        """(N, 2) the radar NIS summed over the fused ranges, and their number."""
        return self._dg[:, DGA.RSUM:DGA.RN_END]


class INS:
    """One INS filter with one GNSS rule: a :class:`BatchINS` of one vehicle and one row (the
    same compiled kernel).  1-D views ``x``, ``P``, ``x_core``; ``p``, ``v``, ``q``, ``b_a``,
    ``b_g`` of the output (now)."""

    def __init__(self, cfg: INSConfig | None = None, rule: str = "kf") -> None:
        self.batch = BatchINS(1, cfg, (rule,))
        self.cfg, self.rule = self.batch.cfg, rule
        self._g = np.full((1, GIN.size), np.nan)
        self._r = np.full((1, RIN.size), np.nan)
        self._u = np.zeros((1, IMU.size))

    def reset(self, p, v, q, ba=None, bg=None, P0=None) -> None:
        self.batch.reset(p, v, q, ba, bg, P0)

    def predict(self, f, w) -> None:
        """One IMU sample: specific force f̃ and body rate ω̃ (body axes)."""
        self._u[0, U.F:U.F_END], self._u[0, U.W:U.W_END] = f, w
        self.batch.step(self._u)

    def update_gnss(self, pos=None, vel=None, yaw=None, var_pos=(1e-4,) * 3,
                    var_vel=(1e-4,) * 3, var_yaw=(0.5 * DEG) ** 2, age_s: float = 0.0) -> None:
        self._g[0] = BatchINS.gnss_row(pos, vel, yaw, var_pos, var_vel, var_yaw, age_s)
        self.batch.step(None, self._g, None)

    def update_radar(self, rng: float, var: float = 0.05**2, age_s: float = 0.0) -> None:
        self._r[0] = (rng, var, age_s)
        self.batch.step(None, None, self._r)

    @property
    def x(self) -> np.ndarray:
        return self.batch.x_out[0]

    @property
    def x_core(self) -> np.ndarray:
        return self.batch.x_core[0]

    @property
    def P(self) -> np.ndarray:
        return self.batch.P[0]

    p = property(lambda self: self.x[S.POS:S.POS_END])
    v = property(lambda self: self.x[S.VEL:S.VEL_END])
    q = property(lambda self: self.x[S.QUAT:S.QUAT_END])
    b_a = property(lambda self: self.x[S.BA:S.BA_END])
    b_g = property(lambda self: self.x[S.BG:S.BG_END])
