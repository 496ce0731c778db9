"""The physics stage: one control period of MuJoCo for every active vehicle of a batch.

One interface, two steppers:

* :class:`DirectStepper` steps one vehicle's own ``MjData`` with ``mj_step`` (no rollout
  overhead);
* :class:`RolloutStepper` steps many with ``mujoco.rollout`` on a persistent thread pool, one
  ``MjModel`` per vehicle (mass, payload, motor lag and drag may differ per vehicle).

Both start every control period from the vehicle's full physics state with a zero warm start
and hold the rotor commands and the applied force over the period, so they give the same bits
(tested). The rollout runs with ``skip_checks=True`` for speed, which makes it the engine's job
to hand every model scratch data made for a model of the same sizes: a batch's models must share
:func:`model_signature` (the field is scenery, not physics, so they do), and models or data of
other sizes are refused with a clear error rather than stepped (memory safety).

MuJoCo's warnings come to :func:`physics_warnings`, not to the ``MUJOCO_LOG.TXT`` file MuJoCo
writes into the working directory by default. When a step goes unstable (a non-finite or huge
``qacc``, ``qvel`` or ``qpos``), MuJoCo resets that vehicle's data to the model's initial state
and goes on; its clock restarts at 0. :func:`reset_rows` finds those vehicles after a step, and
the engine ends their flights with MuJoCo's message as the reason.
"""

from __future__ import annotations

import math
import os
import threading
from collections import deque
from collections.abc import Sequence

import mujoco
import numpy as np
from mujoco import rollout as _rollout

from numkit import Layout, X, Y, Z

from .kernels import controls

STATE_SPEC = int(mujoco.mjtState.mjSTATE_FULLPHYSICS)
CTRL_SPEC = int(mujoco.mjtState.mjSTATE_CTRL | mujoco.mjtState.mjSTATE_XFRC_APPLIED)
#: a body's row of MuJoCo's ``xfrc_applied``: the force (world, at the body's centre of mass),
#: then the torque
XFRC = Layout("force:3 torque:3")
XF = XFRC.at

#: four contiguous chunks of vehicles per thread: at N = 64 on 2 threads this measured ~1000
#: vehicle-sim-s/s against 950-985 with one chunk per thread (uneven vehicles: some on the
#: ground, with contacts)
CHUNKS_PER_THREAD = 4


_WARNINGS: deque[str] = deque(maxlen=32)
_WARN_LOCK = threading.Lock()
_WARN_INSTALLED = [False]


def _on_warning(message: str) -> None:
    with _WARN_LOCK:
        _WARNINGS.append(message)


def capture_warnings() -> None:
    """Send MuJoCo's warnings to :func:`physics_warnings` from now on, in this process (instead
    of MuJoCo's default, a ``MUJOCO_LOG.TXT`` file in the working directory)."""
    if not _WARN_INSTALLED[0]:
        mujoco.set_mju_user_warning(_on_warning)
        _WARN_INSTALLED[0] = True


def physics_warnings() -> list[str]:
    """MuJoCo's latest warnings in this process (at most 32, oldest first)."""
    with _WARN_LOCK:
        return list(_WARNINGS)


def reset_rows(t_before: np.ndarray, S: np.ndarray, act: np.ndarray) -> np.ndarray:
    """Indices of the active vehicles whose clock went back over a step (``S[:, 0]``, the
    state's time, below ``t_before``): MuJoCo found their simulation unstable and reset it."""
    return np.flatnonzero(act & (S[:, 0] < t_before))


def unstable_reason(t: float) -> str:
    """The crash reason of a vehicle MuJoCo reset, with its latest warning."""
    last = physics_warnings()
    said = f": MuJoCo: {last[-1]}" if last else ""
    return f"diverged: the physics went unstable at t={t:.2f}s and MuJoCo reset it{said}"


def model_signature(model: mujoco.MjModel) -> tuple[int, ...]:
    """Every size field of ``model`` (``nq``, ``nv``, ``ngeom``, ``nsensordata``, …): two models
    with equal signatures have ``MjData`` of the same layout."""
    return tuple(getattr(model, k) for k in sorted(dir(model))
                 if k.startswith("n") and isinstance(getattr(model, k, None), int))


def check_data(model: mujoco.MjModel, data: mujoco.MjData, what: str = "data") -> None:
    """Raise ``ValueError`` unless ``data`` was made for a model of ``model``'s sizes."""
    if data.model is not model and model_signature(data.model) != model_signature(model):
        d = data.model
        raise ValueError(f"engine physics: {what} was made for a model of other sizes "
                         f"(nq/nv/nbody/ngeom {d.nq}/{d.nv}/{d.nbody}/{d.ngeom} vs "
                         f"{model.nq}/{model.nv}/{model.nbody}/{model.ngeom}); one batch "
                         "needs one model layout, refusing to step it")


def default_threads(n: int) -> int:
    """Rollout threads for ``n`` vehicles: ``$AG_UAV_ENGINE_THREADS`` or the machine's cores, at
    most ``n``; 0 (step in the caller's thread) for one vehicle or one thread, since a pool
    thread's hand-off costs ~20 %."""
    nthread = int(os.environ.get("AG_UAV_ENGINE_THREADS", 0)) or (os.cpu_count() or 1)
    nthread = min(nthread, n) if n > 1 else 0
    return 0 if nthread == 1 else nthread


class Stepper:
    """Advances the full physics state ``S`` (N, ns) and the sensor readings ``sens``
    (N, nsensordata) of the active rows by one control period of ``nsub`` steps, holding the
    rotor commands ``f`` (N, rotors) and the applied force ``xf`` (N, 3)."""

    def step(self, S: np.ndarray, sens: np.ndarray, f: np.ndarray, xf: np.ndarray,
             act: np.ndarray, sub: np.ndarray | None = None) -> None:
        """``sub`` (N, nsub, nsensordata), when given: the sensor readings of every sub-step
        of the active rows (row j: at the start of sub-step j, as ``mj_step`` computes them
        before it integrates; the last is ``sens``), for the IMU's integration
        (:func:`ag_uav.vehicle.imu.imu_integrate_row`)."""
        raise NotImplementedError

    def close(self) -> None:
        """Release threads and buffers."""


class DirectStepper(Stepper):
    """One vehicle, its own ``MjData``, ``mj_step(m, d, nsub)`` per control period."""

    nthread = 0

    def set_threads(self, nthread: int) -> None:
        """One vehicle steps in the caller's thread whatever it is offered."""

    def __init__(self, model: mujoco.MjModel, body: int, nsub: int, S0: np.ndarray) -> None:
        capture_warnings()
        self.model, self.nsub = model, nsub
        self.data = mujoco.MjData(model)
        mujoco.mj_setState(model, self.data, S0, STATE_SPEC)
        self._xfrc = self.data.xfrc_applied[body, XF.FORCE:XF.FORCE_END]

    def step(self, S, sens, f, xf, act, sub=None) -> None:
        m, d = self.model, self.data
        d.ctrl[:] = f[0]
        self._xfrc[:] = xf[0]
        d.qacc_warmstart[:] = 0.0
        if sub is None:
            mujoco.mj_step(m, d, self.nsub)
        else:  # one sub-step at a time: the same steps, each one's sensor readings kept
            for j in range(self.nsub):
                mujoco.mj_step(m, d)
                sub[0, j] = d.sensordata
        mujoco.mj_getState(m, d, S[0], STATE_SPEC)
        sens[0] = d.sensordata


class RolloutStepper(Stepper):
    """Many vehicles through ``mujoco.rollout``, one call per control period. The models must
    share their sizes (:func:`model_signature`: an engine batch's vehicles do, since the field
    is scenery); models of other sizes are refused, never stepped on data made for another."""

    def __init__(self, models: Sequence[mujoco.MjModel], body: int, nsub: int,
                 nthread: int) -> None:
        capture_warnings()
        self.models, self.nsub = list(models), nsub
        m0 = self.models[0]
        self.data = [mujoco.MjData(m0)]
        for i, m in enumerate(self.models):
            check_data(m, self.data[0], f"the rollout's data (vehicle 0's layout, vehicle {i})")
        N = len(self.models)
        self.xcol = m0.nu + 6 * body
        self.runner = None
        self.set_threads(nthread)
        self.U = np.zeros((N, nsub, mujoco.mj_stateSize(m0, CTRL_SPEC)))
        self.S_out = np.empty((N, nsub, mujoco.mj_stateSize(m0, STATE_SPEC)))
        self.sens_out = np.empty((N, nsub, m0.nsensordata))
        self.warm = np.zeros((N, m0.nv))
        self.idx = np.arange(N)

    def set_threads(self, nthread: int) -> None:
        """Step on ``nthread`` threads from now on (0: the caller's); the results do not
        depend on it (each vehicle's steps are its own)."""
        nthread = 0 if nthread == 1 else nthread  # a one-thread pool only adds its hand-off
        if self.runner is not None:
            self.runner.close()
        self.nthread = nthread
        self.runner = _rollout.Rollout(nthread=nthread)
        m0 = self.models[0]
        self.data += [mujoco.MjData(m0) for _ in range(max(nthread, 1) - len(self.data))]
        self.n_chunks = CHUNKS_PER_THREAD * max(nthread, 1)

    def step(self, S, sens, f, xf, act, sub=None) -> None:
        controls(self.U, f, xf, self.xcol, act)
        if act.all():
            self._run(self.models, S, self.U, S, sens, None, sub)
            return
        ii = self.idx[act]
        if not ii.size:  # every vehicle ended in this tick's earlier stages (a landing)
            return
        self._run([self.models[i] for i in ii], S[ii], self.U[ii], S, sens, ii, sub)

    def _run(self, models, S0, U, S, sens, ii, sub) -> None:
        n = len(models)
        so, se = self.S_out[:n], self.sens_out[:n]
        self.runner.rollout(models, self.data[:max(self.nthread, 1)], S0, U,
                            control_spec=CTRL_SPEC, nstep=self.nsub,
                            initial_warmstart=self.warm[:n], state=so, sensordata=se,
                            skip_checks=True, chunk_size=-(-n // self.n_chunks))
        if ii is None:
            S[:] = so[:, -1]
            sens[:] = se[:, -1]
            if sub is not None:
                sub[:] = se
        else:
            S[ii] = so[:, -1]
            sens[ii] = se[:, -1]
            if sub is not None:
                sub[ii] = se

    def close(self) -> None:
        self.runner.close()


def make_stepper(models: Sequence[mujoco.MjModel], body: int, nsub: int, S: np.ndarray,
                 nthread: int | None) -> Stepper:
    """The direct stepper for one vehicle, the rollout stepper for more."""
    if len(models) == 1:
        return DirectStepper(models[0], body, nsub, S[0])
    if nthread is None:
        nthread = default_threads(len(models))
    return RolloutStepper(models, body, nsub, 0 if nthread == 1 else nthread)


def ground_contact(model: mujoco.MjModel, data: mujoco.MjData, s: np.ndarray, ground: int,
                   skids: set[int], vel: np.ndarray, t: float) -> str | None:
    """Ground contact other than the skids, or any at more than 1 m/s (a crash), else None.
    A skid's speed counts the horizontal and the downward motion: a vehicle lifting off with a
    skid still touching (a heavy take-off climbs at up to 1.5 m/s) is not a crash."""
    mujoco.mj_setState(model, data, s, STATE_SPEC)
    mujoco.mj_kinematics(model, data)
    mujoco.mj_collision(model, data)
    if not data.ncon:
        return None
    speed = math.sqrt(float(vel[X]) ** 2 + float(vel[Y]) ** 2 + min(float(vel[Z]), 0.0) ** 2)
    # the geom pairs as one array: a Python object per contact costs more than the collision
    for g1, g2 in data.contact.geom[:data.ncon].tolist():
        if ground not in (g1, g2):
            continue
        other = g2 if g1 == ground else g1
        if other not in skids or speed > 1.0:
            return (f"ground contact at {speed:.1f} m/s ({model.geom(other).name}) "
                    f"at t={t:.2f}s")
    return None
