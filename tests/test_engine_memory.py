"""What the engine holds per control tick of a run on the INS: the loop's record (float64) and
the IMU and INS scoring records (float32), 286 B a tick; the reference rows are a block of
ticks whatever the run's length (docs/speed.md, "Big jobs")."""

import pytest

from ag_uav.config import load_config
from ag_uav.engine import loop, missions
from ag_uav.engine.reftable import BLOCK


def _engine(max_time_s: float):
    cfg = load_config(None, {"sim.max_time_s": max_time_s, "log.enabled": False})
    return loop._build([missions.prepare_run(cfg).flight], None)


@pytest.mark.parametrize("max_time_s", [100.0, 400.0])
def test_records_take_286_bytes_a_tick_and_the_reference_a_block(max_time_s):
    e = _engine(max_time_s)
    n = e.b.n_max
    assert n == round(max_time_s * 100)
    ins = e.feedback.bank
    grows = {"loop": e.recorder.rec, "imu": e.sensing.rec, "ins errors": ins.err,
             "ins scores": ins.nees}
    per_tick = {k: a.nbytes / n for k, a in grows.items()}
    assert per_tick["loop"] == 21 * 8 and per_tick["imu"] == 9 * 4
    assert per_tick["ins errors"] == 4 * 4 * 4            # 4 rules × herr, verr, tilt, yaw
    assert 17.0 < per_tick["ins scores"] < 18.5            # 10 fixes/s × 11 columns × 4 rules
    assert sum(per_tick.values()) < 290                    # was 499 B (float64, whole-job table)
    assert e.b.ref.tab.shape == (1, BLOCK, 12)
