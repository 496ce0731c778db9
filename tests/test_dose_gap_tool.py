"""tools/dose_gap.py: the replay's wind variants take out what they say they take out (no
flight: synthetic input rows)."""

import importlib.util
import math
import sys
from pathlib import Path

import numpy as np

import ag_uav
from ag_uav.world.deposition_layout import INPUT

ROOT = Path(__file__).resolve().parents[1]


def _tool():
    spec = importlib.util.spec_from_file_location("dose_gap", ROOT / "tools" / "dose_gap.py")
    mod = importlib.util.module_from_spec(spec)
    sys.modules["dose_gap"] = mod
    spec.loader.exec_module(mod)
    return mod


def _rows(n: int = 400, dt: float = 0.01):
    rng = np.random.default_rng(3)
    inp = rng.normal(size=(n, INPUT.size))
    mean = np.zeros((n, 3))
    mean[:, 0], mean[:, 1] = 2.0, -1.0
    wind = slice(INPUT.at.WIND, INPUT.at.WIND + 3)
    inp[:, wind] = mean + rng.normal(0.0, 0.6, size=(n, 3))
    return inp, mean, dt, wind


def test_the_wind_variants_take_out_their_parts():
    tool = _tool()
    cfg = ag_uav.load_config(None, {"wind.speed_mps": 3.0, "wind.direction_deg": 240.0})
    inp, mean, dt, wind = _rows()
    legs = 120.0
    v = tool.variant_rows(inp, mean, dt, cfg, legs)
    assert set(v) == set(tool.VARIANTS)
    np.testing.assert_array_equal(v["flown"], inp)
    np.testing.assert_array_equal(v["no gust"][:, wind], mean)
    d = math.radians(240.0)
    np.testing.assert_allclose(v["steady"][:, wind],
                               np.tile([-3.0 * math.sin(d), -3.0 * math.cos(d), 0.0],
                                       (len(inp), 1)))
    # along + across = the horizontal gust; each lies along its own axis of the legs
    g_al = v["gust along"][:, wind] - mean
    g_ac = v["gust across"][:, wind] - mean
    g = inp[:, wind] - mean
    np.testing.assert_allclose((g_al + g_ac)[:, :2], g[:, :2], atol=1e-12)
    t = math.radians(legs)
    np.testing.assert_allclose(g_al[:, :2] @ [-math.sin(t), math.cos(t)], 0.0, atol=1e-12)
    np.testing.assert_allclose(g_ac[:, :2] @ [math.cos(t), math.sin(t)], 0.0, atol=1e-12)
    # everything but the wind (and, where smoothed, attitude and thrust) is the flown row
    keep = np.ones(INPUT.size, bool)
    keep[wind] = False
    for name in ("no gust", "steady", "gust along", "gust across"):
        np.testing.assert_array_equal(v[name][:, keep], inp[:, keep])


def test_the_low_pass_holds_a_constant_and_smooths_a_step():
    tool = _tool()
    x = np.ones((50, 2))
    np.testing.assert_allclose(tool.lowpass(x, 0.01, 1.0), x)
    step = np.zeros((300, 1))
    step[100:] = 1.0
    y = tool.lowpass(step, 0.01, 1.0)
    # one time constant after the step: 1 - e^-1 of the way (first order, exact per step)
    assert abs(y[199, 0] - (1.0 - math.exp(-1.0))) < 1e-9


def test_edges_name_the_upwind_edge_and_its_under_dosed_cells():
    import shapely

    tool = _tool()

    class Fld:
        polygon = shapely.Polygon([(0, 0), (20, 0), (20, 20), (0, 20)])

    class Map:
        xc = np.arange(0.25, 20.0, 0.5)
        l_per_ha = np.where(xc[None, :] < 4.0, 0.5, 1.0) * np.ones((40, 1))

        def centres(self):
            return self.xc, self.xc

        def field_mask(self, fld):
            return np.ones((40, 40), bool)

    out = tool.edges(Map(), Fld(), np.array([1.0, 0.0]))     # the wind blows to the east
    assert len(out) == 4
    west = [e for e in out if e.startswith("upwind 270°")]
    east = [e for e in out if e.startswith("downwind 90°")]
    assert len(west) == 1 and len(east) == 1
    assert " 0 % under" not in west[0] and east[0].startswith("downwind 90°: 0 % under")
