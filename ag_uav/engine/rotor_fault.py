"""A rotor failing in flight (``vehicle.rotor_fault``), the autopilot's failure detector and
its response by frame: a stage of the engine's tick, before the controller.

* **The fault.** At ``at_s`` the rotor's actuator keeps ``efficiency`` of its thrust and yaw
  torque per unit command (0: stopped): the vehicle's own MuJoCo model is changed, which the
  controller does not know.
* **Detection**, PX4's FailureDetector's two checks, airborne: (1) the attitude and rate
  errors: the controller's attitude error about the roll/pitch axes above
  :attr:`RotorFaults.TILT_ERR_RAD` (10°) or the yaw rate above
  :attr:`RotorFaults.YAW_RATE_RAD_S` (60°/s) for :attr:`RotorFaults.TRIGGER_S` (0.3 s, PX4's
  ``FD_FAIL_R_TTRI``); (2) the motors' ESC telemetry (PX4's actuator failure check,
  ``FD_ACT_EN``, compares each motor's current with its command): a motor delivering less than
  :attr:`RotorFaults.ESC_RATIO` (half) of its command while commanded above 5 % of ``f_max``,
  for :attr:`RotorFaults.ESC_TIMEOUT_S` (0.1 s, ``FD_ACT_MOT_TOUT``); (2') with ``detector =
  "esc-rpm"``, besides: each motor's speed telemetry against the speed its command asks
  (bidirectional DShot returns a motor's eRPM in reply to each command frame; DJI's
  agricultural drones report their motors' speed): a sample every 1 / :attr:`RotorFaults.TEL_HZ`
  (400 Hz, stated), seen :attr:`RotorFaults.TEL_LATENCY_S` later (2.5 ms, stated), and
  :attr:`RotorFaults.TEL_SAMPLES` (3) samples in a row under half: 10 ms, met at the next
  control tick. The plant's fault is a step of the rotor's thrust per unit command at a tick,
  so every sample after it reads the rotor's ``efficiency`` (no telemetry noise is modelled).
  **Isolation**: the motor
  the telemetry reports delivering least of its command (here the actuator's thrust per unit
  command); after an attitude trigger with every motor above half, a false alarm, noted, and
  flown on. A weak rotor that keeps more than half its thrust is left to the attitude check
  and to (3), ArduPilot's thrust-loss check (``Copter::thrust_loss_check``: a motor at the top
  of its range for :attr:`RotorFaults.SAT_S`, 1 s, is a potential thrust loss, the motor the
  one commanded highest): one motor commanded at :attr:`RotorFaults.SAT_FRAC` (99 %) of
  ``f_max`` or more, the highest of all, for 1 s holds the heading where it is (no yaw turns
  at the lane ends: a yaw turn needs that motor higher still, and a quad's attitude loop loses
  roll and pitch in the turn) and flies on; a later detection still responds. Run only on a
  vehicle with a configured fault (without one the stage is not built in its solo run).
* **Response** (``response``), on a hexa or octo always after re-allocating without the rotor
  (:func:`controllers.attitude.fault_allocation`, all four wrench components, the split among
  the remaining rotors balanced for the hover at the current mass, tank included): ``continue``
  — fly on (spraying); ``home`` — the nozzles off, fly to the base (the spray job's, else the
  take-off point) at ``spray.transit_speed_mps`` and land there; ``land`` — land where it is;
  ``auto`` — ``continue`` when the re-allocated hover needs at most
  :attr:`RotorFaults.HOVER_SHARE_MAX` (90 %) of a rotor's limit, else the nozzles off and
  ``land`` (the load-dependent answer: a full tank on seven rotors leaves no margin); ``none``
  — no detector. A quad on any response but ``none`` gives up yaw and flies its three
  rotors with :class:`controllers.rotor_loss.RelaxedHover` (the relaxed hover of Mueller and
  D'Andrea, ICRA 2014: it spins, the spin's gyroscopic torque balancing the opposite rotor's),
  its commands replacing the cascade's (:meth:`RotorFaults.after_control`), and lands where it
  is. The landing is the position failsafe's: brake at 2 m/s², descend at
  0.7 m/s, the last 1.5 m at 0.3 m/s (PX4's ``MPC_LAND_SPEED``, ``MPC_LAND_CRWL``), nozzles off;
  once the set point is on the ground and the vehicle still for 1 s (PX4's land detector) the
  flight ends; the touchdown speed is the largest vertical speed over the last 0.3 m (a skid
  contact above 1 m/s ends the flight as a crash first; a spinning quad's flight ends at its
  skids' first ground contact, motors off). The rotors' yaw damping (:meth:`yaw_damping`) is
  put into the vehicle's model with the fault. The way home: the set point moves
  from where the failure was met towards the base at up to the transit speed (accelerating
  and braking at 1 m/s²), at the height it had.

The run's summary gets ``rotor_fault``: the rotor, when it failed, when it was detected (and the
delay), the response and how it ended (landed at, touchdown vertical speed).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Any

import mujoco
import numpy as np

from controllers.attitude import effectiveness, fault_allocation
from controllers.cascade import P_AINV, P_G, P_MASS, S_ER
from controllers.rotor_loss import RelaxedHover
from numkit.axes import X, Y, Z
from numkit.geometry import rot_to_yaw

from .physics import STATE_SPEC
from .stages import Batch

#: a rotor actuator's gear: its force along body z (the thrust), its torque about body z (yaw)
GEAR_THRUST, GEAR_YAW = 2, 5
#: the free joint's yaw degree of freedom (its sixth: body-frame rate about z)
DOF_YAW = 5
#: the horizontal components of a 3-vector
HORIZ = slice(X, Z)
#: the attitude error's roll and pitch components in the cascade's state row
ER_ROLL_PITCH = slice(S_ER, S_ER + Z)


class RotorFaults:
    """The stage (module docstring); built only when a vehicle of the batch has a fault."""

    TILT_ERR_RAD = math.radians(10.0)
    YAW_RATE_RAD_S = math.radians(60.0)
    TRIGGER_S = 0.3
    ESC_RATIO = 0.5
    ESC_TIMEOUT_S = 0.1
    #: ``detector = "esc-rpm"``: each motor's speed telemetry (module docstring, (2'))
    TEL_HZ = 400.0
    TEL_LATENCY_S = 0.0025
    TEL_SAMPLES = 3
    #: a quad's summary: the largest roll/pitch rate on three rotors within this of the fault
    PEAK_WINDOW_S = 0.5
    SAT_FRAC = 0.99  # thrust-loss check: a motor at the top of its range ...
    SAT_S = 1.0  # ... for this long (ArduPilot THRUST_LOSS_TRIGGER_SEC)
    DESCENT_MPS, CRAWL_MPS, BRAKE_MPS2 = 0.7, 0.3, 2.0
    CRAWL_FROM_M = 1.5  # the crawl's height above the ground (a sortie landing's flare)
    LAND_S = 1.0  # still on the ground this long: landed (PX4 LNDMC_TRIG_TIME)
    HOVER_SHARE_MAX = 0.9  # auto: fly on only if the re-allocated hover needs at most this
    HOME_ACC = 1.0  # m/s², the way home
    C_T = 0.1  # a propeller's thrust coefficient T / (ρ n² D⁴): the rotors' yaw damping
    RHO_AIR = 1.225

    def __init__(self, b: Batch, cfgs: Sequence[Any], vehicles: Sequence[Any], bc: Any,
                 homes: np.ndarray | None = None) -> None:
        self.b, self.bc, self.vehs = b, bc, list(vehicles)
        n = b.n
        #: where ``home`` flies to (the base), and the way's set point and speed
        self.home = np.zeros((n, 2)) if homes is None else np.asarray(homes, float)[:, HORIZ]
        self.v_home = np.array([c.spray.transit_speed_mps for c in cfgs])
        self.going = np.zeros(n, dtype=bool)
        self.yaw_free = np.array([c.vehicle.frame == "quad-x" for c in cfgs])
        self.yaw_hold = np.zeros(n)
        self.hp = np.zeros((n, 3))
        self.hs = np.zeros(n)
        rf = [c.vehicle.rotor_fault for c in cfgs]
        self.rotor = np.array([f.rotor for f in rf])
        self.at = np.array([f.at_s if f.rotor >= 0 else math.inf for f in rf])
        self.eff = [f.efficiency for f in rf]
        self.response = [f.response for f in rf]
        self.frame = [c.vehicle.frame for c in cfgs]
        self.watch = np.array([f.response != "none" for f in rf])
        self.rpm = np.array([f.detector == "esc-rpm" for f in rf])
        self.tel_from = np.full(n, math.inf)  # since when the low motor's telemetry reads low
        self.next_fault = float(self.at.min()) if n else math.inf
        self.applied = np.zeros(n, dtype=bool)
        self.over_s = np.zeros(n)
        self.esc_low = np.full(n, -1)  # the motor whose telemetry reads low (-1: none)
        self.esc_s = np.zeros(n)
        self.detected = np.zeros(n, dtype=bool)
        self.sat_motor = np.full(n, -1)  # thrust-loss check: the motor at its limit, how long
        self.sat_s = np.zeros(n)
        self.heading_held = np.zeros(n, dtype=bool)  # by the thrust-loss check
        self.landing = np.zeros(n, dtype=bool)
        self.at_xy = np.zeros((n, 3))
        self.v0 = np.zeros((n, 3))
        self.t0 = np.zeros(n)
        self.zr = np.zeros(n)
        self.still_s = np.zeros(n)
        #: a quad's three-rotor law (controllers.rotor_loss), once its fault is detected
        self.relaxed: dict[int, RelaxedHover] = {}
        self.contact: dict[int, mujoco.MjData] = {}
        self.info: list[dict[str, Any] | None] = [
            None if f.rotor < 0 else {"rotor": int(f.rotor), "at_s": f.at_s,
                                      "efficiency": f.efficiency, "response": f.response,
                                      "detected_s": None, "detection_delay_s": None,
                                      "action": None, "landed_s": None, "touchdown_mps": None,
                                      "hover_share": None, "thrust_loss_s": None,
                                      "detector": f.detector, "rate_at_detection_rad_s": None,
                                      "rate_peak_rad_s": None}
            for f in rf]

    def step(self, k: int, t: float) -> None:
        b = self.b
        if t >= self.next_fault:
            self._inject(t)
        if self.watch.any():
            self._detect(t)
        held = ((self.detected & ~self.yaw_free) | (self.heading_held & ~self.detected)) & b.act
        b.yaw[held] = self.yaw_hold[held]  # no heading changes on the rotors left
        for i in np.flatnonzero(self.going & b.act):
            self._go_home(int(i), t)
        for i in np.flatnonzero(self.landing & b.act):
            self._land(int(i), t)

    # ------------------------------------------------------------------------------- the fault
    def _inject(self, t: float) -> None:
        for i in np.flatnonzero(~self.applied & (self.at <= t)):
            m, j = self.vehs[i].model, int(self.rotor[i])
            m.actuator_gear[j, GEAR_THRUST] *= self.eff[i]
            m.actuator_gear[j, GEAR_YAW] *= self.eff[i]
            body = self.vehs[i].body_id
            m.dof_damping[m.jnt_dofadr[m.body_jntadr[body]] + DOF_YAW] = self.yaw_damping(i)
            self.applied[i] = True
            if self.eff[i] < self.ESC_RATIO:
                self.esc_low[i] = j
                self.tel_from[i] = t  # the thrust drops with the tick's physics from here
            self.b.notes[i].append(f"rotor {j} failed at t={t:.2f}s (keeps "
                                   f"{self.eff[i]:.0%} of its thrust)")
        rest = self.at[~self.applied]
        self.next_fault = float(rest.min()) if rest.size else math.inf

    # ---------------------------------------------------------------------------- the detector
    def _detect(self, t: float) -> None:
        b, st = self.b, self.bc.state
        eR = st[:, ER_ROLL_PITCH]
        tilt = np.sqrt(eR[:, X] ** 2 + eR[:, Y] ** 2)
        over = (tilt > math.sin(self.TILT_ERR_RAD)) | (np.abs(b.om[:, Z]) > self.YAW_RATE_RAD_S)
        live = self.watch & ~self.detected & b.act & b.airborne
        self.over_s = np.where(live & over, self.over_s + b.dt, 0.0)
        for i in np.flatnonzero(live & (self.esc_low >= 0)):
            j = int(self.esc_low[i])
            on = b.f[i, j] > 0.05 * self.vehs[i].f_max
            self.esc_s[i] = self.esc_s[i] + b.dt if on else 0.0
        fire = (self.over_s >= self.TRIGGER_S - 1e-9) | (self.esc_s >= self.ESC_TIMEOUT_S - 1e-9)
        fire |= self._telemetry(live & self.rpm & (self.esc_low >= 0), t)
        for i in np.flatnonzero(fire & live):
            self._isolate(int(i), t)
        self._thrust_loss(live & (self.rotor >= 0) & ~self.heading_held, t)

    def _telemetry(self, live: np.ndarray, t: float) -> np.ndarray:
        """``detector = "esc-rpm"`` (module docstring, (2')): True where the low motor's last
        ``TEL_SAMPLES`` telemetry samples (taken every ``1 / TEL_HZ`` s, each in the autopilot
        ``TEL_LATENCY_S`` later) all read under ``ESC_RATIO`` of the speed its command asks."""
        b, out = self.b, np.zeros(self.b.n, dtype=bool)
        for i in np.flatnonzero(live):
            if b.f[i, int(self.esc_low[i])] <= 0.05 * self.vehs[i].f_max:
                self.tel_from[i] = t  # commanded off: its speed says nothing
                continue
            seen = (math.floor((t - self.TEL_LATENCY_S) * self.TEL_HZ + 1e-9)
                    - math.floor(self.tel_from[i] * self.TEL_HZ + 1e-9))
            out[i] = seen >= self.TEL_SAMPLES
        return out

    def _thrust_loss(self, live: np.ndarray, t: float) -> None:
        """ArduPilot's thrust-loss check (module docstring, (3)): the highest-commanded motor at
        ``SAT_FRAC`` of ``f_max`` or more, the same one for ``SAT_S``: hold the heading."""
        b = self.b
        for i in np.flatnonzero(live):
            j = int(np.argmax(b.f[i]))
            top = b.f[i, j] >= self.SAT_FRAC * self.vehs[i].f_max
            same = top and j == self.sat_motor[i]
            self.sat_motor[i] = j if top else -1
            self.sat_s[i] = self.sat_s[i] + b.dt if same else (b.dt if top else 0.0)
            if self.sat_s[i] >= self.SAT_S - 1e-9:
                self.heading_held[i] = True
                self.yaw_hold[i] = b.yaw[i]
                info = self.info[i]
                if info is not None:
                    info["thrust_loss_s"] = round(t, 2)
                    info["action"] = info["action"] or f"motor {j} at its limit: heading held"
                b.notes[i].append(f"thrust-loss check: motor {j} at its limit for "
                                  f"{self.SAT_S:g} s at t={t:.2f}s: heading held, flying on")

    def _isolate(self, i: int, t: float) -> None:
        """ESC telemetry: the motor delivering least of its command."""
        b, veh = self.b, self.vehs[i]
        self.over_s[i] = 0.0
        ratio = veh.model.actuator_gear[:, GEAR_THRUST] / np.asarray(veh.eff)
        j = int(np.argmin(ratio))
        if ratio[j] >= self.ESC_RATIO:
            b.notes[i].append(f"failure detector: attitude/rate errors at t={t:.2f}s, every "
                              "motor's telemetry normal: flying on")
            return
        self.detected[i] = True
        self.yaw_hold[i] = b.yaw[i]
        info = self.info[i] if self.info[i] is not None else {"rotor": None}
        self.info[i] = info
        info["detected_s"] = round(t, 2)
        info["rate_at_detection_rad_s"] = round(math.hypot(b.om[i, X], b.om[i, Y]), 3)
        if self.applied[i]:
            info["detection_delay_s"] = round(t - float(self.at[i]), 2)
        if self.frame[i] == "quad-x":
            self.relaxed[i] = RelaxedHover(veh.ctrl_rotor_xy, j, veh.f_max, self.bc.J[i],
                                           self._motor_tau(i), float(self.bc.params[i, P_MASS]),
                                           float(self.bc.params[i, P_G]))
            info["action"] = "gave up yaw: three rotors, spinning (relaxed hover), landing"
            resp = "land"
        else:
            B = effectiveness(veh.ctrl_rotor_xy, veh.spin, veh.k_yaw, veh.eff)
            mg = float(self.bc.params[i, P_MASS] * self.bc.params[i, P_G])
            A = fault_allocation(B, veh.eff, j, keep_yaw=True, hover_share=mg / veh.f_max)
            self.bc.params[i, P_AINV:P_AINV + A.size] = A.ravel()
            share = float((A[:, 0] * mg).max()) / veh.f_max
            what = f"re-allocated without the rotor (hover at {share:.0%} of a rotor's limit)"
            if share > 1.0:  # no hover with yaw held: give yaw up (the vehicle spins)
                A = fault_allocation(B, veh.eff, j, keep_yaw=False, hover_share=mg / veh.f_max)
                self.bc.params[i, P_AINV:P_AINV + A.size] = A.ravel()
                self.yaw_free[i] = True
                share = float((A[:, 0] * mg).max()) / veh.f_max
                what += f"; gave up yaw (hover at {share:.0%})"
            info["hover_share"] = round(share, 3)
            resp = self.response[i]
            if resp == "auto":
                resp = "continue" if share <= self.HOVER_SHARE_MAX else "land"
                if resp == "land":
                    what += (f"; above {self.HOVER_SHARE_MAX:.0%} at "
                             f"{mg / 9.81:.1f} kg: spray stopped")
            info["action"] = what + {"continue": ", flying on", "land": ", landing",
                                     "home": ", spray stopped, returning home"}[resp]
        b.notes[i].append(f"failure detector: rotor {j} at t={t:.2f}s: {info['action']}")
        if resp == "land":
            self._start_landing(i, t)
        elif resp == "home":
            self.going[i] = True
            self.hp[i] = b.p_fb[i]
            self.hs[i] = 0.0

    # ------------------------------------------------------------------- the quad's three rotors
    def after_control(self, t: float) -> None:
        """After the cascade: a quad whose fault is detected flies on :class:`RelaxedHover`
        (its rotor commands replace the cascade's) towards the landing's set points."""
        b = self.b
        for i, law in self.relaxed.items():
            if not b.act[i]:
                continue
            law.mass = float(self.bc.params[i, P_MASS])
            info = self.info[i]
            if info is not None and t - float(self.at[i]) <= self.PEAK_WINDOW_S:
                rate = round(math.hypot(b.om[i, X], b.om[i, Y]), 3)
                info["rate_peak_rad_s"] = max(info.get("rate_peak_rad_s") or 0.0, rate)
            err = np.concatenate([b.rp[i] - b.p_fb[i], b.rv[i] - b.v_fb[i]])
            b.f[i] = law.update(err, b.dt, b.Rc[i], b.om[i], b.ra[i])

    def yaw_damping(self, i: int) -> float:
        """The rotors' yaw damping γ (N m s): a rotor's drag torque ``Q = k f`` grows as the
        square of its airspeed, so a body yaw rate ``r`` changes it by ``2 Q r / Ω``; summed
        over the rotors at hover, ``γ = 2 k Σ f_i / Ω_i`` with ``Ω = 2π √(f / (C_T ρ D⁴))``
        (propeller momentum scaling; ``C_T`` = 0.1 an estimate). The plant's only yaw damping:
        it sets the spin a quad on three rotors reaches. Applied with the fault (the model's
        unfailed flights are unchanged)."""
        veh = self.vehs[i]
        spec = veh.spec
        d = spec.rotor_diameter_m if spec is not None else 0.533
        f = float(self.bc.params[i, P_MASS] * self.bc.params[i, P_G]) / veh.n_rotors
        omega = 2.0 * math.pi * math.sqrt(f / (self.C_T * self.RHO_AIR * d ** 4))
        return 2.0 * veh.k_yaw * veh.n_rotors * f / omega

    def _motor_tau(self, i: int) -> float:
        spec = self.vehs[i].spec
        return spec.motor_tau_s if spec is not None else 0.04

    def _touching(self, i: int) -> bool:
        """Any contact with the ground (the vehicle's own collision pass)."""
        veh = self.vehs[i]
        m = veh.model
        d = self.contact.setdefault(i, mujoco.MjData(m))
        mujoco.mj_setState(m, d, self.b.S[i], STATE_SPEC)
        mujoco.mj_kinematics(m, d)
        mujoco.mj_collision(m, d)
        return any(veh.ground_geom in pair for pair in d.contact.geom[:d.ncon].tolist())

    # ----------------------------------------------------------------------------- the way home
    def _go_home(self, i: int, t: float) -> None:
        """The set point moves towards the base at up to the transit speed (trapezoidal: 1 m/s²
        up, and down so that it stops there), nozzles off; there, the landing."""
        b = self.b
        d = self.home[i] - self.hp[i, HORIZ]
        dist = math.hypot(d[0], d[1])
        b.spray[i] = False
        if dist < 0.05:
            self.going[i] = False
            b.rp[i] = self.hp[i]
            b.rv[i] = 0.0
            b.ra[i] = 0.0
            self._start_landing(i, t)
            self.v0[i] = 0.0
            self.at_xy[i] = self.hp[i]
            return
        u = d / dist
        v = min(self.v_home[i], self.hs[i] + self.HOME_ACC * b.dt,
                math.sqrt(2.0 * self.HOME_ACC * dist))
        self.hs[i] = v
        self.hp[i, HORIZ] += u * min(v * b.dt, dist)
        b.rp[i] = self.hp[i]
        b.rv[i, HORIZ] = u * v
        b.rv[i, Z] = 0.0
        b.ra[i] = 0.0
        if self.yaw_free[i]:
            b.yaw[i] = rot_to_yaw(b.Rc[i])

    # ----------------------------------------------------------------------------- the landing
    def _start_landing(self, i: int, t: float) -> None:
        b = self.b
        self.landing[i] = True
        v0 = b.v_fb[i].copy()
        v0[Z] = 0.0
        self.v0[i], self.at_xy[i], self.t0[i] = v0, b.p_fb[i], t
        self.zr[i] = b.p_fb[i, Z]

    def _land(self, i: int, t: float) -> None:
        """Brake to a stop where the failure was met, descend there (the failsafe's profile);
        a quad's yaw reference follows its heading (yaw given up)."""
        b, v0 = self.b, self.v0[i]
        sp = math.hypot(v0[0], v0[1])
        s = min(t - self.t0[i], sp / self.BRAKE_MPS2)
        a = self.BRAKE_MPS2 / sp if sp > 0.0 else 0.0
        b.rp[i] = self.at_xy[i] + (s - 0.5 * a * s * s) * v0
        b.rv[i] = (1.0 - a * s) * v0
        b.ra[i] = -a * v0 if s < sp / self.BRAKE_MPS2 else 0.0
        ground = b.hover_z[i]
        speed = self.DESCENT_MPS if self.zr[i] > ground + self.CRAWL_FROM_M else self.CRAWL_MPS
        self.zr[i] = max(self.zr[i] - speed * b.dt, ground - 0.5)
        b.rp[i, Z] = self.zr[i]
        b.rv[i, Z] = -speed if self.zr[i] > ground - 0.5 else 0.0
        b.spray[i] = False
        if self.yaw_free[i]:
            b.yaw[i] = rot_to_yaw(b.Rc[i])
        info = self.info[i]
        vz = abs(float(b.v[i, Z]))
        if info is not None and b.p[i, Z] < ground + 0.3:  # the last 0.3 m: the touchdown
            info["touchdown_mps"] = max(info["touchdown_mps"] or 0.0, round(vz, 3))
        if i in self.relaxed:
            if b.p[i, Z] < ground + 0.5 and self._touching(i):  # skids down: motors off
                self._landed(i, t, "touched down spinning, motors off")
            return
        # PX4's land detector: the set point on the ground, still for LAND_S
        still = self.zr[i] <= ground - 0.5 and vz < 0.2 and float(np.abs(b.v[i, HORIZ]).max()) < 0.2
        self.still_s[i] = self.still_s[i] + b.dt if still else 0.0
        if self.still_s[i] >= self.LAND_S - 1e-9:
            self._landed(i, t, "landed")

    def _landed(self, i: int, t: float, how: str) -> None:
        b, info = self.b, self.info[i]
        if info is not None:
            info["landed_s"] = round(t, 2)
            info["landed_xy"] = [round(float(v), 2) for v in b.p[i, HORIZ]]
        b.notes[i].append(f"rotor failure: {how} at t={t:.1f}s")
        b.act[i] = False
