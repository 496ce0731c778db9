"""BatchSprayer (ag_uav.engine.spray_batched): N Sprayers per control tick in one numba kernel equal
the plain-Python reference tick (tests/oracles/sprayer_ref.py) of each vehicle, bit for bit
(the lockstep engine; the kernel is the product's only per-tick law)."""

from __future__ import annotations

import dataclasses
import math

import mujoco
import numpy as np
import pytest
from oracles import sprayer_ref

from ag_uav.config import load_config
from ag_uav.engine.missions import build_reference
from ag_uav.engine.spray_batched import BatchSprayer, MassSink
from ag_uav.engine.sprayer import Sprayer
from ag_uav.vehicle.mjcf import build_vehicle
from ag_uav.world.mission import build_field, build_plan

NOLOG = {"log.enabled": False, "log.render": False}
BODY = ("body_mass", "body_inertia", "body_ipos", "body_subtreemass")


class RecordingCascade:
    """The two attributes Sprayer.set_liquid_mass writes, and reset(); records (mass, J) and
    resets."""

    def __init__(self):
        self.calls: list[tuple[float, tuple[float, float, float]]] = []
        self.mass = math.nan
        self.attitude = self
        self._J = None
        self.resets = 0

    @property
    def J(self):
        return self._J

    @J.setter
    def J(self, v):
        self._J = v
        self.calls.append((float(self.mass), tuple(float(x) for x in v)))

    def reset(self):
        self.resets += 1


class RecordingLog:
    """Records the spray state each way the log takes it (the reference's keywords, the
    engine's row) as the one row the log writes."""

    def __init__(self):
        self.calls: list[tuple] = []

    def spray_state(self, t, *, tank_l, mass_kg, flow_lps, nozzles, power_w, energy_wh, soc,
                    sortie, ground):
        self.spray_row(t, (tank_l, mass_kg, flow_lps, 1.0 if nozzles else 0.0, power_w,
                           energy_wh, soc, sortie, 1.0 if ground else 0.0))

    def spray_row(self, t, values):
        self.calls.append((t, tuple(float(v) for v in values)))

    def spray_slot(self, t):  # the engine's way: a row it fills in place
        self._row = np.full(10, np.nan)
        self._row[0] = t
        return self._row

    def spray_commit(self):
        self.calls.append((float(self._row[0]), tuple(float(v) for v in self._row[1:])))


@dataclasses.dataclass
class Case:
    cfg: object
    ref: object
    tab: dict
    n: int
    dt: float
    fill_l: float | None = None  # the actual fill when it differs from the planned one
    log: bool = False
    gap: tuple[int, int] | None = None  # ticks the engine leaves the vehicle out (inactive)


def _case(over: dict, n_max: int | None = None, plan=None, **kw) -> Case:
    cfg = load_config(None, {**NOLOG, **over})
    if plan is None:
        plan = build_plan(cfg, build_field(cfg))
    ref = build_reference(cfg, plan)
    dt = 1.0 / cfg.sim.control_hz
    n = int(math.ceil(ref.duration / dt - 1e-9))
    if n_max is not None:
        n = min(n, n_max)
    return Case(cfg, ref, ref.sample_all(np.arange(n) * dt), n, dt, **kw)


@pytest.fixture(scope="module")
def cases() -> list[Case]:
    """Five vehicles: different fields, tanks, batteries, rates, job lengths, a single-sortie
    job cut short, a tank that runs dry before the planned return, a log, a gap."""
    a = _case({"spray.tank_l": 0.5, "spray.service_s": 5.0}, gap=(3000, 3150))
    b = _case({"mission.field": "hole", "spray.tank_l": 0.3, "battery.capacity_wh": 60.0,
               "spray.rate_l_per_ha": 1.5, "mission.swath_m": 5.0, "spray.service_s": 3.0,
               "spray.min_height_m": 1.0}, log=True)
    c = _case({}, n_max=12000, plan=None)
    d = dataclasses.replace(a, fill_l=0.3, gap=None)
    e = dataclasses.replace(b, log=False, n=b.n - 7777, tab={k: v[:b.n - 7777]
                                                              for k, v in b.tab.items()})
    assert len(a.ref.spray_job.sorties) == 3 and len(b.ref.spray_job.sorties) >= 3
    assert "ground" not in c.tab  # the plain Reference: one sortie, no tables
    return [a, b, c, d, e]


def _inputs(case: Case, seed: int) -> dict[str, np.ndarray]:
    """Synthetic per-tick inputs: heights in and out of the nozzle band, speeds with rare
    bursts (large volumes per tick: the 1 g threshold and an empty tank within a tick), the
    plan's spray flag with random flips, random rotor commands and actuator states (some <= 0)."""
    rng = np.random.default_rng(seed)
    n = case.n
    pz = np.where(rng.random(n) < 0.9, 3.0 + rng.normal(0, 0.3, n),
                  rng.choice([0.0, 0.2, 0.75, 6.5, 9.0], n))
    vx = rng.normal(0.0, 5.0, n)
    vy = rng.normal(0.0, 5.0, n)
    burst = rng.random(n) < 0.003
    vx[burst] *= 200.0
    spray = case.tab["spray"] ^ (rng.random(n) < 0.03)
    f = rng.uniform(0.0, 40.0, (n, 4))
    act = rng.uniform(-3.0, 30.0, (n, 4))
    act[rng.random((n, 4)) < 0.01] = 0.0
    return {"pz": pz, "vx": vx, "vy": vy, "spray": spray, "f": f, "act": act}


def _sprayer(case: Case, cascade) -> tuple[Sprayer, object]:
    veh = build_vehicle(case.cfg)
    data = mujoco.MjData(veh.model)
    job = case.ref.spray_job
    if case.fill_l is not None:
        job = dataclasses.replace(job, fill_l=case.fill_l)
    log = RecordingLog() if case.log else None
    return Sprayer(case.cfg, veh, data, cascade, case.tab, job, case.n, case.dt, log), veh


def _active(case: Case, k: int) -> bool:
    return k < case.n and not (case.gap and case.gap[0] <= k < case.gap[1])


def _fly_scalar(case: Case, inp: dict) -> dict:
    casc = RecordingCascade()
    sp, veh = _sprayer(case, casc)
    n = case.n
    out = {"f": np.full((n, 4), np.nan), "on": np.zeros(n, bool), "reset": np.zeros(n, bool)}
    act = sp.data.act
    pz, vx, vy = inp["pz"].tolist(), inp["vx"].tolist(), inp["vy"].tolist()
    spray, f_in = inp["spray"].tolist(), inp["f"].tolist()
    for k in range(n):
        if not _active(case, k):
            continue
        act[:] = inp["act"][k]
        r0 = casc.resets
        f, on = sprayer_ref.step(sp, k, k * case.dt, pz[k], vx[k], vy[k], spray[k],
                                 list(f_in[k]))
        out["f"][k] = f
        out["on"][k] = on
        out["reset"][k] = casc.resets > r0
    return {"sp": sp, "veh": veh, "calls": casc.calls, **out}


def _fly_batch(cs: list[Case], inps: list[dict]) -> dict:
    calls: dict[int, list] = {i: [] for i in range(len(cs))}
    made = [_sprayer(c, RecordingCascade()) for c in cs]
    sps = [m[0] for m in made]
    orig = [sp.cascade for sp in sps]
    batch = BatchSprayer.from_sprayers(
        sps, lambda i, m, J: calls[i].append((m, J)))
    N, T = len(cs), max(c.n for c in cs)
    dt = cs[0].dt

    def col(key, shape=()):
        a = np.zeros((T, N, *shape), inp_dtype[key])
        for i, (c, inp) in enumerate(zip(cs, inps, strict=True)):
            a[:c.n, i] = inp[key]
        return a

    inp_dtype = {"pz": float, "vx": float, "vy": float, "spray": bool, "f": float, "act": float}
    pz, vx, vy, spray = col("pz"), col("vx"), col("vy"), col("spray")
    f_in, act = col("f", (4,)), col("act", (4,))
    active = np.array([[_active(c, k) for c in cs] for k in range(T)])
    out = {"f": np.full((T, N, 4), np.nan), "on": np.zeros((T, N), bool),
           "reset": np.zeros((T, N), bool)}
    for k in range(T):
        f = f_in[k].copy()
        on, reset = batch.step(k, k * dt, pz[k], vx[k], vy[k], spray[k], f, act[k], active[k])
        out["f"][k] = f
        out["on"][k] = on
        out["reset"][k] = reset
        assert not np.any((on | reset) & ~active[k])
        assert np.array_equal(f[~active[k]], f_in[k][~active[k]])  # inactive rows untouched
    assert batch.finish() is batch.sprayers
    for sp, c in zip(sps, orig, strict=True):
        assert sp.cascade is c  # the Sprayers' own cascades back
        # the records stay views of the batch's (no copies)
        assert type(sp.rec_tank) is memoryview and type(sp.rec_on) is memoryview
    return {"sps": sps, "vehs": [m[1] for m in made], "calls": calls, "active": active, **out}


def _same_row(case: Case, scal_or_row: dict, batch: dict, i: int) -> None:
    """Row i of the batch equals the scalar flight (or another batch's row 0)."""
    n = case.n
    ref = scal_or_row
    act = batch["active"][:n, i]
    np.testing.assert_array_equal(batch["f"][:n, i][act], ref["f"][act])
    np.testing.assert_array_equal(batch["on"][:n, i], ref["on"])
    np.testing.assert_array_equal(batch["reset"][:n, i], ref["reset"])
    s1, s2 = ref["sp"], batch["sps"][i]
    if "t_end_s" not in s2.per[-1]:  # (summary() closes the last sortie: the fixture is shared)
        assert s1.per == s2.per
    t_end = n * case.dt
    assert s1.summary(t_end) == s2.summary(t_end)
    assert s1.per == s2.per
    assert [list(p) for p in s1.per] == [list(p) for p in s2.per]  # the same keys, same order
    a1, a2 = s1.series(n), s2.series(n)
    assert a1.keys() == a2.keys()
    for key in a1:
        np.testing.assert_array_equal(a1[key], a2[key], err_msg=key)
    for attr in ("tank", "energy_j", "energy_total_j", "litres_total", "cur", "mass_set",
                 "gated_s", "dry_s", "next_log"):
        assert getattr(s1, attr) == getattr(s2, attr), attr
    assert ref["calls"] == batch["calls"][i]
    for name in BODY:
        np.testing.assert_array_equal(getattr(ref["veh"].model, name),
                                      getattr(batch["vehs"][i].model, name), err_msg=name)
    if s1.log is not None:
        assert s1.log.calls == s2.log.calls and len(s1.log.calls) > 100


@pytest.fixture(scope="module")
def flown(cases):
    inps = [_inputs(c, seed) for seed, c in enumerate(cases)]
    scalar = [_fly_scalar(c, inp) for c, inp in zip(cases, inps, strict=True)]
    batch = _fly_batch(cases, inps)
    return inps, scalar, batch


def test_batch_equals_the_scalar_sprayers(cases, flown):
    """Five different jobs in one batch: rotor commands, nozzles, resets, records, per-sortie
    dicts, summaries, set_mass calls, the MjModel liquid body and the log, all bit for bit."""
    _, scalar, batch = flown
    for i, case in enumerate(cases):
        _same_row(case, scalar[i], batch, i)


def test_the_inputs_cross_sorties_the_empty_tank_the_gates_and_the_mass_threshold(cases, flown):
    """What the comparison covers (so that it is not vacuous)."""
    _, scalar, batch = flown
    s = [r["sp"].summary(c.n * c.dt) for r, c in zip(scalar, cases, strict=True)]
    assert s[0]["sorties"] == 3 and s[1]["sorties"] >= 3
    assert s[2]["sorties"] == 1
    assert s[3]["tank_ran_dry"] and s[0]["tank_ran_dry"]  # empty tanks (bursts, a 0.3 L fill)
    assert all(x["spray_gated_by_height_s"] > 1.0 for x in s)
    assert scalar[0]["reset"].sum() > 400 and batch["reset"].sum() > 1000  # on the ground
    assert all(len(r["calls"]) > 50 for r in scalar)  # mass updates (1 g steps and refills)
    assert batch["on"].sum() > 50000
    assert (~batch["active"]).sum() > 50000  # finished rows and a gap


def test_row_independence(cases, flown):
    """A vehicle flown alone in a batch of one equals the same vehicle in the batch of five."""
    inps, _, batch = flown
    for i in (1, 3):
        alone = _fly_batch([cases[i]], [inps[i]])
        row = {"f": alone["f"][:, 0], "on": alone["on"][:, 0], "reset": alone["reset"][:, 0],
               "sp": alone["sps"][0], "veh": alone["vehs"][0], "calls": alone["calls"][0]}
        _same_row(cases[i], row, batch, i)


def test_wrap_mid_job_and_hand_back(cases):
    """Scalar for a while, then the batch across a sortie change, then scalar again after
    finish(): the same as scalar all the way."""
    case = cases[0]
    inp = _inputs(case, 11)
    ref = _fly_scalar(case, inp)
    casc = RecordingCascade()
    sp, veh = _sprayer(case, casc)
    change = np.flatnonzero(np.diff(case.tab["sortie"]))
    k1, k2 = int(change[0]) - 5000, int(change[0]) + 5000   # the batch flies the first change
    assert k1 > 0 and np.any((change > k1) & (change < k2))
    calls: list = []

    def scalar_ticks(ks):
        for k in ks:
            if _active(case, k):
                sp.data.act[:] = inp["act"][k]
                sprayer_ref.step(sp, k, k * case.dt, float(inp["pz"][k]), float(inp["vx"][k]),
                                 float(inp["vy"][k]), bool(inp["spray"][k]), list(inp["f"][k]))

    scalar_ticks(range(k1))
    batch = BatchSprayer.from_sprayers([sp], lambda i, m, J: calls.append((m, J)),
                                       push_initial=False)
    for k in range(k1, k2):
        f = inp["f"][k:k + 1].copy()
        batch.step(k, k * case.dt, inp["pz"][k:k + 1], inp["vx"][k:k + 1], inp["vy"][k:k + 1],
                   inp["spray"][k:k + 1], f, inp["act"][k:k + 1],
                   np.array([_active(case, k)]))
    batch.finish()
    n_before = len(casc.calls)
    scalar_ticks(range(k2, case.n))
    assert casc.calls[:n_before] + calls + casc.calls[n_before:] == ref["calls"]
    assert sp.per == ref["sp"].per
    t_end = case.n * case.dt
    assert sp.summary(t_end) == ref["sp"].summary(t_end)
    for key, v in ref["sp"].series(case.n).items():
        np.testing.assert_array_equal(sp.series(case.n)[key], v, err_msg=key)
    for name in BODY:
        np.testing.assert_array_equal(getattr(veh.model, name), getattr(ref["veh"].model, name))


def test_mass_sink_as_the_cascade_and_the_errors(cases):
    """Sprayers built with MassSink(i, set_mass) push their initial mass themselves; a tick
    past a vehicle's tables raises before anything changes; wrong shapes and a step after
    finish() raise."""
    case = cases[2]
    calls: list = []
    cb = lambda i, m, J: calls.append((i, m, J))  # noqa: E731
    sps = [_sprayer(case, MassSink(i, cb))[0] for i in range(2)]
    ref = RecordingCascade()
    _sprayer(case, ref)
    assert [c[1:] for c in calls] == ref.calls * 2 and [c[0] for c in calls] == [0, 1]
    batch = BatchSprayer.from_sprayers(sps, cb, push_initial=False)
    assert len(calls) == 2
    z, f, act = np.zeros(2), np.ones((2, 4)), np.full((2, 4), 20.0)
    on = np.ones(2, bool)
    batch.step(0, 0.0, z + 3.0, z + 5.0, z, on, f, act)
    st = batch._st.copy()
    with pytest.raises(IndexError, match="vehicle 1"):
        batch.step(case.n, case.n * case.dt, z, z, z, on, f, act, np.array([False, True]))
    np.testing.assert_array_equal(batch._st, st)
    batch.step(case.n, case.n * case.dt, z, z, z, on, f, act, np.array([False, False]))
    with pytest.raises(ValueError, match="leading axis of 2"):
        batch.step(1, 0.01, np.zeros(3), z, z, on, f, act)
    batch.finish()
    # v · dt · R · w / 10⁴ (5 m/s, one tick, 1 L/ha over the plan's lanes)
    w = case.ref.plan.swath
    assert sps[0].litres_total == pytest.approx(5.0 * 0.01 * 1.0 * w / 1e4, rel=1e-12)
    assert sps[0].summary(0.01)["sorties"] == 1
    with pytest.raises(RuntimeError):
        batch.step(1, 0.01, z, z, z, on, f, act)
