"""The sortie planner fills the tank with what the battery can carry and spray in one sortie
(ag_uav.world.spray_job.sortie_fill): a full tank where the tank binds, less where the battery
would cut a full-tank sortie."""

from __future__ import annotations

import pytest

import ag_uav
from ag_uav.engine.missions import mission_setup
from ag_uav.world.spray_job import hover_endurance_min


def _job(**over):
    cfg = ag_uav.load_config(None, {"log.enabled": False, **over})
    _, _, ref = mission_setup(cfg)
    return cfg, ref, ref.spray_job


def test_the_m350_still_takes_off_with_its_full_tank():
    cfg, _, job = _job()
    assert job.fill_l == cfg.spray.tank_l == 2.7
    assert "fill_l" not in job.summary()  # the default summary keeps its keys
    assert len(job.sorties) == 1


def test_the_octocopter_fills_what_its_battery_can_spray():
    """A full 40 L tank (90 kg) hovers 7.5 min: the default field at 1 L/ha needs two
    battery-bound sorties with it; filled with what one battery can spray, it is one sortie
    with little liquid left."""
    cfg, ref, job = _job(**{"vehicle.preset": "x8-40l"})
    assert hover_endurance_min(cfg, 90.0) < 8.0
    assert job.fill_l < 5.0 < cfg.spray.tank_l
    assert job.summary()["fill_l"] == pytest.approx(job.fill_l)
    assert len(job.sorties) == 1
    litres = sum(s.litres for s in job.sorties)
    assert litres <= job.fill_l and job.fill_l - litres < 0.2
    full = ag_uav.load_config(None, {"vehicle.preset": "x8-40l"})
    e_use = full.battery.capacity_wh * (1.0 - full.battery.reserve_frac)
    assert all(s.energy_wh <= e_use + 1e-6 for s in job.sorties)


@pytest.mark.slow
def test_the_38_ha_job_on_the_octocopter_fits_the_time_limit():
    cfg, ref, job = _job(**{"vehicle.preset": "x8-40l",
                            "mission.field": "examples/field_38ha.geojson"})
    assert ref.duration < cfg.sim.max_time_s
    e_use = cfg.battery.capacity_wh * (1.0 - cfg.battery.reserve_frac)
    first = job.sorties[0]
    # the first sortie ends on the battery with the tank nearly sprayed out
    assert first.energy_wh == pytest.approx(e_use, rel=0.01)
    assert first.litres > (1.0 - 2.0 * cfg.spray.plan_margin) * job.fill_l
    assert sum(s.litres for s in job.sorties) > 38.0
