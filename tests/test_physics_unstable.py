"""MuJoCo's instability: its warnings come to the engine (no MUJOCO_LOG.TXT in the working
directory) and a vehicle MuJoCo reset is found and named, on both steppers."""

from __future__ import annotations

import mujoco
import numpy as np
import pytest

import ag_uav
from ag_uav.engine.physics import (
    STATE_SPEC,
    DirectStepper,
    RolloutStepper,
    physics_warnings,
    reset_rows,
    unstable_reason,
)
from ag_uav.vehicle.mjcf import build_vehicle


def _state(model: mujoco.MjModel, t: float) -> np.ndarray:
    d = mujoco.MjData(model)
    d.time = t
    mujoco.mj_forward(model, d)
    s = np.empty(mujoco.mj_stateSize(model, STATE_SPEC))
    mujoco.mj_getState(model, d, s, STATE_SPEC)
    return s


@pytest.mark.parametrize("n", [1, 3])
def test_an_unstable_step_is_found_named_and_writes_no_file(tmp_path, monkeypatch, n):
    monkeypatch.chdir(tmp_path)
    veh = build_vehicle(ag_uav.load_config(None, {"log.render": False}))
    m = veh.model
    S = np.stack([_state(m, 5.0)] * n)
    sens = np.zeros((n, m.nsensordata))
    f = np.full((n, 4), 10.0)
    xf = np.zeros((n, 3))
    xf[-1] = [0.0, 0.0, 1e15]           # a force no airframe survives: qacc ~1e14
    act = np.ones(n, dtype=bool)
    stepper = (DirectStepper(m, veh.body_id, 5, S[0]) if n == 1
               else RolloutStepper([m] * n, veh.body_id, 5, 0))
    t0 = S[:, 0].copy()
    stepper.step(S, sens, f, xf, act)
    assert list(reset_rows(t0, S, act)) == [n - 1]
    assert np.all(S[: n - 1, 0] > t0[: n - 1])          # the others flew on
    assert any("unstable" in w for w in physics_warnings())
    why = unstable_reason(5.0)
    assert why.startswith("diverged: the physics went unstable at t=5.00s") and "MuJoCo:" in why
    assert not (tmp_path / "MUJOCO_LOG.TXT").exists()
    stepper.close()
