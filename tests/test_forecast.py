"""The plan made on a forecast, the flight in the wind of the day (ag_uav.world.forecast)."""

import math

import numpy as np
import pytest

from ag_uav.config import ConfigError, load_config
from ag_uav.world import pattern
from ag_uav.world.forecast import forecast_errors, meander_angles, plan_wind
from ag_uav.world.wind import Wind

EXACT = {"forecast.speed_sigma_mps": 0.0, "forecast.direction_sigma_deg": 0.0}


def test_the_forecast_error_is_drawn_from_the_seed():
    a, b = plan_wind(load_config(None, {"seed": 3})), plan_wind(load_config(None, {"seed": 3}))
    assert a == b and a.source == "drawn"
    z1, z2 = forecast_errors(3)
    assert a.speed_mps == pytest.approx(max(0.0, 3.0 + 1.5 * z1), abs=0.051)
    assert a.direction_deg == pytest.approx((240.0 + 30.0 * z2) % 360.0, abs=0.51)
    assert plan_wind(load_config(None, {"seed": 4})) != a
    # the spread of the draws over seeds is the configured one
    z = np.array([forecast_errors(s) for s in range(400)])
    assert abs(z.mean()) < 0.15 and np.all(np.abs(z.std(axis=0) - 1.0) < 0.1)


def test_exact_and_given_forecasts():
    ex = plan_wind(load_config(None, EXACT))
    assert (ex.speed_mps, ex.direction_deg, ex.source) == (3.0, 240.0, "exact")
    given = plan_wind(load_config(None, {"forecast.speed_mps": 4.0,
                                         "forecast.direction_deg": 200.0}))
    assert (given.speed_mps, given.direction_deg, given.source) == (4.0, 200.0, "given")
    assert "error +1.0 m/s, -40°" in given.text()
    with pytest.raises(ConfigError, match="forecast.direction_sigma_deg"):
        load_config(None, {"forecast.direction_sigma_deg": -1.0})


def test_the_plan_takes_the_forecast_not_the_flown_wind():
    cfg = load_config(None, {"forecast.direction_deg": 330.0, **EXACT})
    assert pattern.mission_direction(cfg) == pytest.approx(pattern.crosswind_heading(330.0))
    assert pattern.mission_direction(load_config(None, EXACT)) == pytest.approx(120.0)
    # a calm forecast: no crosswind to plan on, whatever blows in flight
    calm = load_config(None, {"forecast.speed_mps": 0.0, **EXACT})
    assert pattern.mission_direction(calm) is None


def test_meander_is_a_stationary_gauss_markov_angle():
    rng = np.random.default_rng(1)
    phi = meander_angles(rng, 10.0, 20.0, 200_000.0)
    assert len(phi) == 200_001
    assert np.degrees(phi.std()) == pytest.approx(10.0, rel=0.05)
    lag = 20          # one time constant at 1 s steps
    r = np.corrcoef(phi[:-lag], phi[lag:])[0, 1]
    assert r == pytest.approx(math.exp(-1.0), abs=0.04)
    assert not meander_angles(rng, 0.0, 20.0, 100.0).any()


def test_batch_wind_turns_the_mean_and_keeps_its_speed():
    from ag_uav.vehicle.sensors_batched import BatchWind

    bw = BatchWind.from_winds([Wind(3.0, 240.0), Wind(2.0, 90.0)])
    m0 = bw.mean.copy()
    bw.turn(np.radians([30.0, -90.0]))
    assert np.hypot(*bw.mean[:, :2].T) == pytest.approx([3.0, 2.0])
    ang = np.degrees(np.arctan2(bw.mean[:, 1], bw.mean[:, 0]) -
                     np.arctan2(m0[:, 1], m0[:, 0]))
    assert (ang + 180.0) % 360.0 - 180.0 == pytest.approx([30.0, -90.0])
    w = bw.step(0.01, np.full(2, 3.0), np.full(2, 5.0))
    assert w[:, :2] == pytest.approx(bw.mean[:, :2])          # no turbulence: the mean
    bw.turn(np.zeros(2))
    assert bw.mean == pytest.approx(m0)
