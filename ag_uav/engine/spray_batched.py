"""N spray jobs in lockstep: the per-tick law of a spray job, over a batch of
:class:`~ag_uav.engine.sprayer.Sprayer` objects.

The lockstep engine advances N missions at once (leading batch axis N) at the control rate.
The per-tick law (sortie table, tank and flow, nozzle gating by height, power from the actuator
states, energy, state of charge, per-tick records) is written once, in the compiled kernel
:func:`_spray_kernel` (numba, no fastmath) that :class:`BatchSprayer` runs over all rows; one
vehicle is a batch of one. The Sprayer keeps the setup, the liquid body
(:meth:`Sprayer.set_liquid_mass <ag_uav.engine.sprayer.Sprayer.set_liquid_mass>`) and the
reports. The independent plain-Python reference of the tick is ``tests/oracles/sprayer_ref.py``
(``tests/test_batched_spray.py`` compares them bit for bit). Python does only what happens on a
few ticks, found from the kernel's per-row flags:

* a sortie change: the finished sortie's dict gets its totals and ``t_end_s``, a new dict is
  appended (keys ``sortie, t_takeoff_s, litres, energy_j, min_soc, ran_dry_s, t_land_s``);
* a liquid mass change (a refill, or the tank down by the threshold of 1 g, or empty): the
  Sprayer's :meth:`~ag_uav.engine.sprayer.Sprayer.set_liquid_mass` runs for that vehicle (the
  MjModel body updates); its cascade is replaced by a :class:`MassSink`, which forwards the
  composite mass and the attitude inertia to the engine's ``set_mass(i, total_mass_kg, J_xyz)``
  callback;
* the optional log (``log.spray_row`` every 0.1 s).

The per-sortie totals (litres, energy, minimum state of charge, ran-dry and landing times) are
accumulated in the kernel's state and written into the Sprayers' ``per`` dicts when a sortie
closes and by :meth:`BatchSprayer.finish`. The per-tick records live in one flat buffer per record
(all vehicles, each at its own offset); each Sprayer's ``rec_*`` attributes are replaced by views
of its slice while the batch runs (so their memory is not held twice), and :meth:`finish` puts
plain ``array('d')`` / ``bytearray`` copies back, with the tank, energy and the other state, so that
:meth:`Sprayer.summary <ag_uav.engine.sprayer.Sprayer.summary>` and :meth:`Sprayer.series
<ag_uav.engine.sprayer.Sprayer.series>` work unchanged for each vehicle.

Rows on the ground at the base get ``f = 0`` and ``reset = True``; the engine resets that
vehicle's controller state.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from typing import Any, NamedTuple

import numpy as np

from numkit import Layout, X, Y, Z

from .._jit import njit
from .kernels import zeros_touched
from .sprayer import Sprayer

SetMass = Callable[[int, float, tuple[float, float, float]], None]

# ---- the per-vehicle constants (float64, (N, PAR.size)): litres per metre, liquid density,
# the nozzles' height gate (min, max), the power law's gain and hover power, the battery's
# capacity (J), Δt, the tank's fill (L), the dry mass; ``nozzles`` 1: the nozzle model (valve,
# pressure lag) gives the litres (:meth:`BatchSprayer.draw`)
PAR = Layout("lpm rho hmin hmax kp pav cap dt fill dry nozzles")
PA = PAR.at
# ---- the float state (float64, (N, STATE.size)); NaN stands for None in ran-dry/landing:
# tank (L), energy of the battery (J), of the job, litres of the job, the liquid mass last set,
# time gated and dry; the current sortie's totals (lit .. tland) and those of the sortie closed
# on this tick (c_*); the liquid masses to set this tick (refill, then spray); this tick's flow
# (L/s)
STATE = Layout("tank e etot ltot mset gated dry lit ej minsoc randry tland "
               "c_lit c_ej c_minsoc c_randry c_tland mrefill mspray flow")
ST = STATE.at
# ---- the integer state (int64, (N, INTS.size)): current sortie, offset into the flat tables,
# ticks available, this tick's event flags
INTS = Layout("cur off lim flags")
IS = INTS.at
# ---- the rows of the flat tables ``tab`` (int32) and of the per-tick records ``rec``, of
# ``out`` (nozzles on, controller reset) and of the log's spray row (``RunLog.SPRAY_FIELDS``)
TABS = Layout("sortie ground")
RECS = Layout("tank mass power soc")
OUTS = Layout("on reset")
LOG_ROW = Layout("t tank_l mass_kg flow_lps nozzles power_w energy_wh battery_frac sortie ground")
TB, RR, OU, LR = TABS.at, RECS.at, OUTS.at, LOG_ROW.at
# ---- the event flags (bits of ist[:, IS.FLAGS])
F_CHANGE, F_CLOSE, F_REFILL, F_MASS = 1, 2, 4, 8


class SprayArrays(NamedTuple):
    """A batch's own arrays that :func:`_spray_kernel` reads and writes, declared once: the
    per-vehicle constants ``par`` (N, :data:`PAR`), the float and integer state ``st`` (N,
    :data:`STATE`) and ``ist`` (N, :data:`INTS`), the flat sortie and ground tables ``tab``
    (:data:`TABS`, total), the per-tick records ``rec`` (:data:`RECS`, total) and ``rec_on``
    (total,), and ``out`` (:data:`OUTS`, N): nozzles on and controller reset. Passed as a
    plain tuple in field order and named again in the kernel (as :mod:`ag_uav.engine.kernels`
    does)."""

    par: np.ndarray
    st: np.ndarray
    ist: np.ndarray
    tab: np.ndarray
    rec: np.ndarray
    rec_on: np.ndarray
    out: np.ndarray


@njit(cache=True)
def _spray_log_row(row, st, rec, tab, rec_on, ist, i, j):
    """Vehicle ``i``'s spray state at its record ``j`` -> ``row`` (:data:`LOG_ROW`, the
    :attr:`ag_uav.record.runlog.RunLog.SPRAY_FIELDS`; its time is the caller's): tank, mass,
    flow (the tick's litres per second), nozzles, power, energy (Wh), battery fraction, sortie
    (from 1), on the ground."""
    on = rec_on[j]
    row[LR.TANK_L] = st[i, ST.TANK]
    row[LR.MASS_KG] = rec[RR.MASS, j]
    row[LR.FLOW_LPS] = st[i, ST.FLOW]
    row[LR.NOZZLES] = 1.0 if on else 0.0
    row[LR.POWER_W] = rec[RR.POWER, j]
    row[LR.ENERGY_WH] = st[i, ST.ETOT] / 3600.0
    row[LR.BATTERY_FRAC] = rec[RR.SOC, j]
    row[LR.SORTIE] = ist[i, IS.CUR] + 1
    row[LR.GROUND] = tab[TB.GROUND, j]


@njit(cache=True)
def _sortie_row(i, s, par, st, ist):  # pragma: no cover
    """A sortie change: close the last one, refill and a fresh battery, open the new one.
    Returns the event flags."""
    fl = F_CHANGE
    if ist[i, IS.CUR] >= 0:
        fl |= F_CLOSE
        st[i, ST.C_LIT] = st[i, ST.LIT]
        st[i, ST.C_EJ] = st[i, ST.EJ]
        st[i, ST.C_MINSOC] = st[i, ST.MINSOC]
        st[i, ST.C_RANDRY] = st[i, ST.RANDRY]
        st[i, ST.C_TLAND] = st[i, ST.TLAND]
    ist[i, IS.CUR] = s
    if s > 0:
        st[i, ST.TANK] = par[i, PA.FILL]
        st[i, ST.E] = 0.0
        m = st[i, ST.TANK] * par[i, PA.RHO]
        st[i, ST.MREFILL] = m
        st[i, ST.MSET] = m
        fl |= F_REFILL
    st[i, ST.LIT] = 0.0
    st[i, ST.EJ] = 0.0
    st[i, ST.MINSOC] = 1.0
    st[i, ST.RANDRY] = np.nan
    st[i, ST.TLAND] = np.nan
    return fl


@njit(cache=True)
def _nozzle_row(i, t, pz, vx, vy, spray_ref, par, st):  # pragma: no cover
    """The nozzle command: the plan sprays, the tank is not empty, the height is within the
    band. Without the nozzle model the flow follows the command at once (per ground distance,
    :func:`_draw_row`); with it, :func:`_draw_kernel` draws what the nozzles let out. Returns
    (command, event flags)."""
    dt = par[i, PA.DT]
    on = False
    if spray_ref[i]:
        if st[i, ST.TANK] <= 0.0:
            st[i, ST.DRY] += dt
            if math.isnan(st[i, ST.RANDRY]):
                st[i, ST.RANDRY] = t
        elif par[i, PA.HMIN] < pz[i] < par[i, PA.HMAX]:
            on = True
        else:
            st[i, ST.GATED] += dt
    if par[i, PA.NOZZLES] > 0.5:
        return on, 0
    dv = par[i, PA.LPM] * math.sqrt(vx[i] * vx[i] + vy[i] * vy[i]) * dt if on else 0.0
    return on, _draw_row(i, dv, par, st)


@njit(cache=True)
def _draw_row(i, dv, par, st):  # pragma: no cover
    """``dv`` litres out of the tank (at most what is in it): the totals, the tick's flow, and
    the liquid mass re-set when it fell by 1 g or the tank is empty. Returns the event flags."""
    st[i, ST.FLOW] = 0.0
    if dv <= 0.0:
        return 0
    tank = st[i, ST.TANK]
    if dv > tank:
        dv = tank
    tank -= dv
    st[i, ST.TANK] = tank
    st[i, ST.LTOT] += dv
    st[i, ST.LIT] += dv
    st[i, ST.FLOW] = dv / par[i, PA.DT]
    m_liq = tank * par[i, PA.RHO]
    if st[i, ST.MSET] - m_liq >= 1e-3 or tank <= 0.0:
        st[i, ST.MSET] = m_liq
        st[i, ST.MSPRAY] = m_liq
        return F_MASS
    return 0


@njit(cache=True)
def _draw_kernel(k, rows, litres, nozzles, on_col, spray, active, arrays):  # pragma: no cover
    """After the nozzle model's tick: vehicle ``rows[j]`` let ``litres[j]`` out, its valve open
    when ``nozzles[j, on_col]`` > 0.5; ``spray[rows[j]]`` ← valve open and vehicle active; the
    tank, the liquid mass and the records of the active rows follow them (:func:`_draw_row`).
    The step's event flags are cleared first. ``arrays``: :class:`SprayArrays` (a plain tuple).
    Returns the number of rows with an event flag."""
    a = SprayArrays(*arrays)
    par, st, ist, rec, rec_on = a.par, a.st, a.ist, a.rec, a.rec_on
    for i in range(ist.shape[0]):
        ist[i, IS.FLAGS] = 0
    nev = 0
    for j in range(rows.shape[0]):
        i = rows[j]
        on = nozzles[j, on_col] > 0.5
        spray[i] = on and active[i]
        if not active[i]:
            continue
        fl = _draw_row(i, litres[j], par, st)
        r = ist[i, IS.OFF] + k
        tank = st[i, ST.TANK]
        rec[RR.TANK, r] = tank
        rec[RR.MASS, r] = par[i, PA.DRY] + tank * par[i, PA.RHO]   # m = m_dry + V ρ
        rec_on[r] = 1 if on else 0
        ist[i, IS.FLAGS] = fl
        if fl:
            nev += 1
    return nev


@njit(cache=True)
def _energy_row(i, g, act, par, st):  # pragma: no cover
    """Electrical power of the actual rotor thrusts (zero on the ground), energy, state of
    charge. Returns (power, state of charge)."""
    p = par[i, PA.PAV]
    kp = par[i, PA.KP]
    for c in range(act.shape[1]):
        a = act[i, c]
        if a > 0.0:
            p += kp * a * math.sqrt(a)
    if g:
        p = 0.0
    e = p * par[i, PA.DT]
    st[i, ST.E] += e
    st[i, ST.ETOT] += e
    st[i, ST.EJ] += e
    soc = 1.0 - st[i, ST.E] / par[i, PA.CAP]
    if soc < st[i, ST.MINSOC]:
        st[i, ST.MINSOC] = soc
    return p, soc


@njit(cache=True)
def _spray_kernel(k, t, pz, vx, vy, spray_ref, f, act, active, arrays):  # pragma: no cover
    """One control tick of the spray job for every active row: the per-tick law (module docstring;
    its plain-Python reference is ``tests/oracles/sprayer_ref.py``).

    Returns the number of rows with an event flag (0 on most ticks), or ``-(i + 1)`` without
    touching anything when tick ``k`` is outside active row i's tables. ``arrays``: the batch's
    :class:`SprayArrays` (a plain tuple in field order)."""
    a = SprayArrays(*arrays)
    par, st, ist, tab, rec, rec_on, out = a.par, a.st, a.ist, a.tab, a.rec, a.rec_on, a.out
    n = pz.shape[0]
    for i in range(n):
        if active[i] and (k < 0 or k >= ist[i, IS.LIM]):
            return -(i + 1)
    nev = 0
    for i in range(n):
        out[OU.ON, i] = False
        out[OU.RESET, i] = False
        ist[i, IS.FLAGS] = 0
        if not active[i]:
            continue
        j = ist[i, IS.OFF] + k
        s = tab[TB.SORTIE, j]
        fl = _sortie_row(i, s, par, st, ist) if s != ist[i, IS.CUR] else 0
        g = tab[TB.GROUND, j] != 0
        if g:  # on the ground at the base: motors off, controller reset
            out[OU.RESET, i] = True
            for c in range(f.shape[1]):
                f[i, c] = 0.0
            if math.isnan(st[i, ST.TLAND]):
                st[i, ST.TLAND] = t
        on, fm = _nozzle_row(i, t, pz, vx, vy, spray_ref, par, st)
        fl |= fm
        p, soc = _energy_row(i, g, act, par, st)
        tank = st[i, ST.TANK]
        rec[RR.TANK, j] = tank
        rec[RR.MASS, j] = par[i, PA.DRY] + tank * par[i, PA.RHO]   # m = m_dry + V ρ
        rec[RR.POWER, j] = p
        rec[RR.SOC, j] = soc
        rec_on[j] = 1 if on else 0
        out[OU.ON, i] = on
        if fl:
            ist[i, IS.FLAGS] = fl
            nev += 1
    return nev


def _set_mass(sp: Sprayer, t: float, m_liq: float) -> None:
    """The liquid mass of ``sp``'s vehicle from tick time ``t`` on (recorded when the engine
    captures the flight for a physics replay)."""
    sp.set_liquid_mass(m_liq)
    if sp.mass_events is not None:
        sp.mass_events.append((t, m_liq))


def _none_nan(v: float | None) -> float:
    return math.nan if v is None else float(v)


def _nan_none(v: float) -> float | None:
    return None if math.isnan(v) else float(v)


class _JSink:
    """``cascade.attitude`` of a :class:`MassSink`: setting ``J`` calls the engine's callback."""

    __slots__ = ("_owner",)

    def __init__(self, owner: MassSink):
        self._owner = owner

    @property
    def J(self) -> tuple[float, float, float]:
        return self._owner.J

    @J.setter
    def J(self, value: Sequence[float]) -> None:
        o = self._owner
        o.J = (float(value[X]), float(value[Y]), float(value[Z]))
        o.set_mass(o.index, float(o.mass), o.J)


class MassSink:
    """Stands in for a Sprayer's cascade: :meth:`Sprayer.set_liquid_mass` writes
    ``cascade.mass`` and then ``cascade.attitude.J``; the second write calls
    ``set_mass(index, mass, J)``.

    The engine may pass ``MassSink(i, set_mass)`` as the ``cascade`` argument when it builds
    Sprayer i (its ``__init__`` then pushes the initial mass straight to the callback; use
    ``push_initial=False`` in :meth:`BatchSprayer.from_sprayers`). ``reset()`` does nothing (the
    batch reports resets in ``step``'s ``reset`` array)."""

    __slots__ = ("index", "set_mass", "mass", "J", "attitude")

    def __init__(self, index: int, set_mass: SetMass):
        self.index = int(index)
        self.set_mass = set_mass
        self.mass = math.nan
        self.J: tuple[float, float, float] = (math.nan, math.nan, math.nan)
        self.attitude = _JSink(self)

    def reset(self) -> None:
        """No-op (the engine resets its own controller state from ``reset``)."""


def _table(values: Sequence[Any], n: int, dtype: Any) -> np.ndarray:
    """``values[:n]`` as an array of ``n`` (zero-padded; the padding is never read)."""
    a = np.zeros(n, dtype)
    m = min(n, len(values))
    if m:
        a[:m] = np.asarray(values[:m] if len(values) > m else values, dtype=dtype)
    return a


class BatchSprayer:
    """The per-tick work of N :class:`~ag_uav.engine.sprayer.Sprayer` objects, advanced together.

    Build with :meth:`from_sprayers`, call :meth:`step` once per control tick (after the
    controller, before the rotor commands go to MuJoCo), then :meth:`finish` to write the state
    and records back into the Sprayers. Vehicles may have different configs, jobs and table
    lengths; ``active`` masks out the finished ones.
    """

    def __init__(self, sprayers: Sequence[Sprayer], set_mass: SetMass, *,
                 push_initial: bool = True):
        """See :meth:`from_sprayers`."""
        self.sprayers: list[Sprayer] = list(sprayers)
        self.set_mass = set_mass
        n = len(self.sprayers)
        self.n = n
        self._finished = False
        self._k = 0  # the tick being stepped (the log reads its records)
        self._cascades: list[Any] = []
        n_rec = [len(sp.rec_tank) for sp in self.sprayers]
        off = np.zeros(n + 1, np.int64)
        off[1:] = np.cumsum(n_rec)
        total = int(off[-1])
        self._off = off
        self._n_rec = n_rec
        self._par = np.zeros((n, PA.SIZE))
        self._st = np.zeros((n, ST.SIZE))
        self._ist = np.zeros((n, IS.SIZE), np.int64)
        self._tab = np.zeros((TABS.size, total), np.int32)
        self._rec = zeros_touched((RECS.size, total))  # written tick by tick: faulted in now
        self._rec_on = np.zeros(total, np.uint8)
        for i, sp in enumerate(self.sprayers):
            a, b = int(off[i]), int(off[i + 1])
            nr = b - a
            par = {"lpm": sp.lpm, "rho": sp.rho, "hmin": sp.h_min, "hmax": sp.h_max, "kp": sp.k_p,
                   "pav": sp.p_av, "cap": sp.cap_j, "dt": sp.dt, "fill": sp.job.fill_l,
                   "dry": sp.dry, "nozzles": float(sp.nozzle_model)}
            for f, v in par.items():   # by name (PAR)
                self._par[i, PAR.offset[f]] = v
            ints = {"cur": sp.cur, "off": a, "lim": min(nr, len(sp.sortie), len(sp.ground)),
                    "flags": 0}
            for f, v in ints.items():   # by name (INTS)
                self._ist[i, INTS.offset[f]] = v
            st = self._st[i]
            st[ST.TANK], st[ST.E], st[ST.ETOT] = sp.tank, sp.energy_j, sp.energy_total_j
            st[ST.LTOT], st[ST.MSET] = sp.litres_total, sp.mass_set
            st[ST.GATED], st[ST.DRY] = sp.gated_s, sp.dry_s
            st[ST.C_LIT:ST.C_TLAND_END] = math.nan
            if sp.cur >= 0:  # wrapped mid-job: the current sortie's totals so far
                if not sp.per:
                    raise ValueError(f"sprayer {i}: sortie {sp.cur} without a per-sortie dict")
                per = sp.per[-1]
                st[ST.LIT], st[ST.EJ], st[ST.MINSOC] = per["litres"], per["energy_j"], \
                    per["min_soc"]
                st[ST.RANDRY] = _none_nan(per["ran_dry_s"])
                st[ST.TLAND] = _none_nan(per["t_land_s"])
            self._tab[TB.SORTIE, a:b] = _table(sp.sortie, nr, np.int32)
            self._tab[TB.GROUND, a:b] = _table(sp.ground, nr, np.int32)
            # the records so far, then each Sprayer's rec_* become views of its slice
            for field, r in RECS.offset.items():   # rec_tank, rec_mass, rec_power, rec_soc
                name = "rec_" + field
                self._rec[r, a:b] = np.frombuffer(getattr(sp, name), np.float64, count=nr)
                setattr(sp, name, memoryview(self._rec[r, a:b]))
            self._rec_on[a:b] = np.frombuffer(sp.rec_on, np.uint8, count=nr)
            sp.rec_on = memoryview(self._rec_on[a:b])
            self._cascades.append(sp.cascade)
            sp.cascade = MassSink(i, set_mass)
        self._all = np.ones(n, bool)
        self._out = np.zeros((OUTS.size, n), bool)
        self._arrays = (self._par, self._st, self._ist, self._tab, self._rec, self._rec_on,
                        self._out)  # SprayArrays, as a plain tuple
        self._on, self._reset = self._out[OU.ON], self._out[OU.RESET]
        self._logged = [(i, sp) for i, sp in enumerate(self.sprayers)
                        if sp.log is not None and hasattr(sp.log, "spray_row")]
        self._log_next = -math.inf  # the earliest time a logged vehicle's spray state is due
        # with the nozzle model, the tick's litres (and the log) come after it: :meth:`draw`
        self.nozzle_model = bool(self._par[:, PA.NOZZLES].any()) if n else False
        if push_initial:
            for sp in self.sprayers:
                if sp.mass_set >= 0.0:
                    sp.set_liquid_mass(sp.mass_set)

    @classmethod
    def from_sprayers(cls, sprayers: Sequence[Sprayer], set_mass: SetMass, *,
                      push_initial: bool = True) -> BatchSprayer:
        """Wrap N Sprayers (each built with its own vehicle model, ``data`` and job).

        ``set_mass(i, total_mass_kg, (Jx, Jy, Jz))`` receives vehicle i's composite mass and
        inertia (about the composite centre of mass) whenever its liquid mass changes; it is
        what :meth:`Sprayer.set_liquid_mass` writes to ``cascade.mass`` and
        ``cascade.attitude.J``. Each Sprayer's cascade is replaced by a :class:`MassSink` until
        :meth:`finish`.
        ``push_initial``: call ``set_mass`` once per vehicle now with its current mass (what
        ``Sprayer.__init__`` gave its cascade); pass ``False`` when the Sprayers were built
        with ``MassSink(i, set_mass)`` as their cascade (they already pushed it).

        The Sprayers may already have stepped (the state, the current sortie's totals and the
        records so far are taken over). ``job.fill_l`` is read here (later changes are not
        seen). Each ``data.act`` is not read: ``step`` takes the actuator states as ``act``.
        """
        return cls(sprayers, set_mass, push_initial=push_initial)

    # ------------------------------------------------------------------------------ per tick
    def step(self, k: int, t: float, pz: np.ndarray, vx: np.ndarray, vy: np.ndarray,
             spray_ref: np.ndarray, f: np.ndarray, act: np.ndarray,
             active: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
        """One control tick of every active vehicle (:func:`_spray_kernel`).

        ``pz``, ``vx``, ``vy``: (N,) float64 height and ground velocity; ``spray_ref``: (N,)
        bool, the plan sprays; ``f``: (N, 4) float64 rotor commands, set to 0 in place on the
        rows on the ground; ``act``: (N, n_act) float64 actuator states (rotor thrusts after the
        motor lag); ``active``: (N,) bool or ``None`` (all). Returns ``(on, reset)``: (N,) bool
        nozzles on, and the rows whose controller must be reset (on the ground at the base);
        both are buffers owned by the batch and overwritten by the next call (copy to keep).
        Inactive rows are left alone (``on`` and ``reset`` False, ``f`` untouched).
        Raises ``IndexError`` (before changing anything) when ``k`` is outside an active
        vehicle's tables."""
        if self._finished:
            raise RuntimeError("BatchSprayer.step after finish()")
        n = self.n
        if active is None:
            active = self._all
        if (pz.shape != (n,) or vx.shape != (n,) or vy.shape != (n,)
                or spray_ref.shape != (n,) or active.shape != (n,) or f.ndim != 2
                or f.shape[0] != n or act.ndim != 2 or act.shape[0] != n):
            raise ValueError(f"BatchSprayer.step: arrays must have a leading axis of {n}")
        self._k = k
        nev = _spray_kernel(k, t, pz, vx, vy, spray_ref, f, act, active, self._arrays)
        if nev:
            if nev < 0:
                i = -nev - 1
                raise IndexError(f"tick {k} is outside vehicle {i}'s tables "
                                 f"({int(self._ist[i, IS.LIM])} ticks)")
            self._events(t)
        if self._logged and not self.nozzle_model and t >= self._log_next:
            self._log(t, active)
        return self._on, self._reset

    def draw(self, k: int, t: float, rows: np.ndarray, litres: np.ndarray,
             nozzles: np.ndarray, on_col: int, spray: np.ndarray, active: np.ndarray) -> None:
        """After the nozzle model's tick (``PA.NOZZLES`` rows): vehicle ``rows[j]`` let
        ``litres[j]`` out with its valve open when ``nozzles[j, on_col]`` > 0.5 (the nozzle
        model's state rows), and ``spray[rows[j]]`` (the nozzles on, for the record and the
        coverage) follows the valve of the active rows. The tank, the liquid mass, the totals
        and the nozzle records follow them (:func:`_draw_kernel`, one compiled call), so that
        the tank, the coverage and the dose count one flow. Then the spray log (every 0.1 s)."""
        if not rows.shape[0]:
            self._ist[:, IS.FLAGS] = 0  # step's events are done
        elif _draw_kernel(k, rows, litres, nozzles, on_col, spray, active, self._arrays):
            self._events(t)
        if self._logged and t >= self._log_next:
            self._log(t, active)

    def _events(self, t: float) -> None:
        """Sortie changes and liquid-mass updates of the rows the kernel flagged (Python)."""
        st, ist = self._st, self._ist
        for i in np.flatnonzero(ist[:, IS.FLAGS]).tolist():
            fl = int(ist[i, IS.FLAGS])
            sp = self.sprayers[i]
            if fl & F_CHANGE:
                if fl & F_CLOSE:
                    per = sp.per[-1]
                    per["litres"] = float(st[i, ST.C_LIT])
                    per["energy_j"] = float(st[i, ST.C_EJ])
                    per["min_soc"] = float(st[i, ST.C_MINSOC])
                    per["ran_dry_s"] = _nan_none(st[i, ST.C_RANDRY])
                    per["t_land_s"] = _nan_none(st[i, ST.C_TLAND])
                    sp.close_sortie(t)
                if fl & F_REFILL:
                    _set_mass(sp, t, float(st[i, ST.MREFILL]))
                s = int(self._ist[i, IS.CUR])
                sp.per.append({"sortie": s + 1, "t_takeoff_s": t, "litres": 0.0,
                               "energy_j": 0.0, "min_soc": 1.0, "ran_dry_s": None,
                               "t_land_s": None})
            if fl & F_MASS:
                _set_mass(sp, t, float(st[i, ST.MSPRAY]))

    def _log(self, t: float, active: np.ndarray) -> None:
        """The spray state row of the vehicles that have a log, every 0.1 s (at most; the log's
        own rate may be lower): filled in place by :func:`_spray_log_row`."""
        for i, sp in self._logged:
            if not active[i] or not t >= sp.next_log:
                continue
            sp.next_log = t + 0.1 - 1e-9
            row = sp.log.spray_slot(t)
            if row is not None:
                _spray_log_row(row, self._st, self._rec, self._tab, self._rec_on, self._ist, i,
                               int(self._off[i]) + self._k)
                sp.log.spray_commit()
        self._log_next = min((sp.next_log for i, sp in self._logged if active[i]),
                             default=math.inf)

    # ------------------------------------------------------------------------------ the end
    def sync(self) -> None:
        """Write the batch state into the Sprayers (tank, energy, totals, current sortie and its
        dict); their ``rec_*`` are already views of the batch's records. ``summary`` and
        ``series`` then work on them; the batch may go on stepping."""
        st, ist = self._st, self._ist
        for i, sp in enumerate(self.sprayers):
            sp.tank = float(st[i, ST.TANK])
            sp.energy_j = float(st[i, ST.E])
            sp.energy_total_j = float(st[i, ST.ETOT])
            sp.litres_total = float(st[i, ST.LTOT])
            sp.mass_set = float(st[i, ST.MSET])
            sp.gated_s = float(st[i, ST.GATED])
            sp.dry_s = float(st[i, ST.DRY])
            sp.cur = int(ist[i, IS.CUR])
            if sp.cur >= 0 and sp.per:
                per = sp.per[-1]
                per["litres"] = float(st[i, ST.LIT])
                per["energy_j"] = float(st[i, ST.EJ])
                per["min_soc"] = float(st[i, ST.MINSOC])
                per["ran_dry_s"] = _nan_none(st[i, ST.RANDRY])
                per["t_land_s"] = _nan_none(st[i, ST.TLAND])

    def finish(self) -> list[Sprayer]:
        """:meth:`sync`, then give each Sprayer its own cascade back; its records stay the
        views of the batch's records they became (no copies: a 38 ha job's are 54 MB). The
        batch cannot step after this; a new batch can take them over from where this one left
        them. Returns the Sprayers."""
        if self._finished:
            return self.sprayers
        self.sync()
        for i, sp in enumerate(self.sprayers):
            sp.cascade = self._cascades[i]
        self._finished = True
        self._rec = self._rec[:, :0]
        self._rec_on = self._rec_on[:0]
        self._arrays = ()  # the records live on in the Sprayers' views
        return self.sprayers
