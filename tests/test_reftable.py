"""The engine's reference rows a block at a time (ag_uav.engine.reftable) equal the rows of one
whole-job table, across block edges, past a flight's end, and for a spray job's sorties."""

from types import SimpleNamespace

import numpy as np
import pytest

from ag_uav.config import load_config
from ag_uav.engine.missions import build_reference
from ag_uav.engine.reftable import RefTable
from ag_uav.vehicle.mjcf import build_vehicle
from ag_uav.world.mission import build_field, build_plan
from ag_uav.world.spray_job import plan_job

DT = 0.01


@pytest.fixture(scope="module")
def job_ref():
    """The default field's spray job in 0.5 L tanks: several sorties (a ChainedReference)."""
    cfg = load_config(None, {"log.enabled": False, "spray.tank_l": 0.5})
    fld = build_field(cfg)
    plan = build_plan(cfg, fld)
    ref, job = plan_job(cfg, plan, build_reference(cfg, plan, spray=False), fld,
                        dry_mass_kg=6.47, z_land=build_vehicle(cfg).hover_z - 0.08)
    assert len(job.sorties) >= 3
    return ref


def _whole(ref, n: int) -> np.ndarray:
    """The rows of ticks 0 … n − 1 sampled in one call (what the engine read before blocks)."""
    tab = ref.sample_all(np.arange(n) * DT)
    return np.column_stack([tab["pos"], tab["vel"], tab["acc"], tab["yaw"], tab["seg"],
                            tab["spray"]]).astype(float)


def test_blocks_equal_the_whole_table_bit_for_bit(job_ref):
    n_long, n_short = int(job_ref.duration / DT) - 5, 2500
    flights = [SimpleNamespace(reference=job_ref)] * 2
    rt, ids, job_tabs = RefTable.of(flights, np.array([n_short, n_long]), DT, block=1000)
    assert ids.tolist() == [0, 0] and rt.n.tolist() == [n_long]  # shared: the longest flight
    whole = _whole(job_ref, n_long)
    ks = [0, 999, 1000, 1001, 2499, 2500, n_long // 2, n_long - 1]
    for k in ks:
        rt.at(k)
        assert np.array_equal(rt.tab[0, k - rt.k0[0]], whole[k])
    rt.at(n_long + 1234)  # past the end: the last row, as the padded table held
    assert np.array_equal(rt.tab[0, n_long + 1234 - rt.k0[0]], whole[-1])
    tab = job_ref.sample_all(np.arange(n_long) * DT)
    assert np.array_equal(job_tabs[0]["sortie"], tab["sortie"])
    assert np.array_equal(job_tabs[0]["ground"], tab["ground"])
    assert job_tabs[0]["ground"].any() and job_tabs[0]["sortie"].max() >= 2


def test_sortie_ground_matches_the_samples(job_ref):
    t = np.linspace(-1.0, job_ref.duration + 5.0, 20011)
    sortie, ground = job_ref.sortie_ground(t)
    tab = job_ref.sample_all(t)
    assert np.array_equal(sortie, tab["sortie"]) and np.array_equal(ground, tab["ground"])
    # on the ground exactly between a sortie's end and the next one's start, never in the last
    for i, (ref, _m) in enumerate(job_ref.pieces[:-1]):
        t_end, t_next = job_ref.t0[i] + ref.duration, job_ref.t0[i + 1]
        mid = ground[(t > t_end + 1e-6) & (t < t_next - 1e-6)]
        assert mid.size and mid.all()
    assert not ground[t >= job_ref.t0[-1]].any()


def test_a_plain_reference_has_no_job_tables():
    cfg = load_config(None, {"log.enabled": False, "spray.enabled": False})
    fld = build_field(cfg)
    ref = build_reference(cfg, build_plan(cfg, fld), spray=False)
    rt, _ids, job_tabs = RefTable.of([SimpleNamespace(reference=ref)], np.array([5000]), DT)
    assert job_tabs == [{}]
    rt.at(4999)
    assert np.array_equal(rt.tab[0, 4999 - rt.k0[0]], _whole(ref, 5000)[-1])


def test_sorties_built_in_threads_equal_a_serial_build(job_ref, monkeypatch):
    """``spray_job._references`` builds the sorties' references two at a time in threads; one
    at a time (as on a one-core machine) gives the same grids, bit for bit."""
    import ag_uav.world.spray_job as sj

    cfg = load_config(None, {"log.enabled": False, "spray.tank_l": 0.5})
    fld = build_field(cfg)
    plan = build_plan(cfg, fld)
    monkeypatch.setattr(sj.os, "cpu_count", lambda: 1)
    serial, _ = plan_job(cfg, plan, build_reference(cfg, plan, spray=False), fld,
                         dry_mass_kg=6.47, z_land=build_vehicle(cfg).hover_z - 0.08)
    assert len(serial.pieces) == len(job_ref.pieces)
    t = np.arange(int(job_ref.duration / DT)) * DT
    a, b = job_ref.sample_all(t), serial.sample_all(t)
    assert all(np.array_equal(a[k], b[k]) for k in a)
    assert job_ref.spray_job.sorties == serial.spray_job.sorties
