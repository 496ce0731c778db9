"""The quad rotor-failure campaigns of docs/vehicles.md ("A quad on three rotors").

    python -m tools.rotor_loss_campaign half [PRESET]      # rotor seed mod 4 stopped at half the
                                                           # default mission, seeds 0-9
    python -m tools.rotor_loss_campaign high VARIANT ...   # at 20 s of the default plan flown at
                                                           # 20 m; VARIANT: m350, tau15, spinner
    python -m tools.rotor_loss_campaign limits [PRESET]    # what a quad on three rotors is up
                                                           # against at the half-mission fault
    python -m tools.rotor_loss_campaign trace PRESET SEED  # tick by tick around that fault

Arguments ``KEY=VALUE`` set a config key on every flight (e.g.
``vehicle.rotor_fault.detector=esc-rpm``). Each flight: the seed, the rotor, when the fault was
detected and the body's roll/pitch rate then (and its peak within 0.5 s of the fault), the
touchdown speed, the landing time or the
crash; then the count that touched down below 1 m/s without a crash.
"""

from __future__ import annotations

import json
import math
import sys
import time
from typing import Any

import mujoco
import numpy as np

import ag_uav
from ag_uav.engine.missions import mission_setup, simulate_many
from ag_uav.engine.rotor_fault import GEAR_THRUST
from numkit.axes import Z
from numkit.geometry import RZZ

VARIANTS = {
    "m350": {},
    "tau15": {"vehicle.motor_tau_s": 0.015},
    "spinner": {"vehicle.motor_tau_s": 0.015, "vehicle.yaw_torque_coeff_m": 0.04,
                "vehicle.thrust_to_weight": 2.5},
}
SEEDS = range(10)


def _configs(case: str, name: str, over: dict[str, Any], tail_s: float = 60.0
             ) -> list[ag_uav.Config]:
    base: dict[str, Any] = {"log.enabled": False, **over}
    if case == "half":
        base["vehicle.preset"] = name
        at = round(mission_setup(ag_uav.load_config(None, base))[2].duration / 2.0, 1)
    else:
        base.update({"mission.altitude_m": 20.0, "spray.max_height_m": 30.0, **VARIANTS[name]})
        at = 20.0
    return [ag_uav.load_config(None, {**base, "seed": s, "vehicle.rotor_fault.rotor": s % 4,
                                      "vehicle.rotor_fault.at_s": at,
                                      "sim.max_time_s": at + tail_s}) for s in SEEDS]


def limits(name: str, over: dict[str, Any]) -> None:
    """The figures of docs/vehicles.md's table of what a quad on three rotors is up against at
    the half-mission fault: seed 0 flown 1 s past it, the three-rotor law's mass, inertia and
    rotors read as it starts (module docstring of controllers.rotor_loss for the laws)."""
    from ag_uav.engine.rotor_fault import RotorFaults

    seen: dict[str, Any] = {}
    plain = RotorFaults.after_control

    def probe(self: RotorFaults, t: float) -> None:
        plain(self, t)
        for i, law in self.relaxed.items():
            seen.setdefault("law", law)
            seen.setdefault("k", self.vehs[i].k_yaw)

    RotorFaults.after_control = probe  # type: ignore[method-assign]
    try:
        simulate_many(_configs("half", name, over, tail_s=1.0)[:1])
    finally:
        RotorFaults.after_control = plain  # type: ignore[method-assign]
    law, k = seen["law"], seen["k"]
    w = law.mass * law.g
    i_d, i_z = 0.5 * (law.J[0] + law.J[1]), law.J[2]
    cap = law.F_SHARE * law.f_max
    alpha_d = 0.25 * w * law.arm_o / i_d
    alpha_z = 2.0 * k * cap / i_z
    r = next((r / 10 for r in range(1, 1000) if law.hover(w, r / 10)[3] >= w - 1e-9), math.inf)
    fall = max(0.0, 1.0 - 2.0 * cap / w) * law.g
    print(f"limits {name}: mass {law.mass:.2f} kg, weight {w:.1f} N; the pair at its limit "
          f"{2 * law.f_max / w:.2f} of the weight (at {law.F_SHARE:.0%}: {2 * cap / w:.2f}; "
          f"from 3 m with the attitude held: {math.sqrt(2 * fall * 3.0):.1f} m/s); "
          f"alpha_d {alpha_d:.1f} rad/s2; rate left >= {alpha_d * (0.09 + law.tau_m):.2f} "
          f"(px4) / {alpha_d * (0.01 + law.tau_m):.2f} rad/s (esc-rpm); 80 deg at the latter "
          f"in {math.radians(80) / (alpha_d * (0.01 + law.tau_m)):.2f} s; a quarter turn "
          f"{math.sqrt(math.pi / alpha_z):.2f} s; the weight on three rotors from r = {r:.1f} "
          f"rad/s ({r / alpha_z:.1f} s of spin-up at {alpha_z:.2f} rad/s2)")


def trace(name: str, seed: int, over: dict[str, Any]) -> None:
    """Tick by tick from 0.02 s before the half-mission fault to 0.3 s after it (seed ``seed``):
    the rotors' commands and the thrust they deliver (N, the motors' lagged state times the
    actuator's gain), the body rates (rad/s), the tilt (deg), the height and vertical speed
    (m, m/s), whether the fault was detected."""
    from ag_uav.engine.rotor_fault import RotorFaults

    plain = RotorFaults.after_control
    lag = (mujoco.mjtState.mjSTATE_TIME, mujoco.mjtState.mjSTATE_QPOS, mujoco.mjtState.mjSTATE_QVEL)

    def probe(self: RotorFaults, t: float) -> None:
        plain(self, t)
        b, m = self.b, self.vehs[0].model
        since = t - float(self.at[0])
        if not b.act[0] or not -0.02 <= since <= 0.3:
            return
        a0 = sum(mujoco.mj_stateSize(m, int(k)) for k in lag)  # the actuators' state follows
        given = m.actuator_gear[:, GEAR_THRUST] * b.S[0, a0:a0 + m.nu]
        tilt = math.degrees(math.acos(max(-1.0, min(1.0, float(b.R[0, RZZ])))))
        print(f"{since:+.2f} s  command {np.round(b.f[0], 1).tolist()}  delivered "
              f"{np.round(given, 1).tolist()}  rates {np.round(b.omega[0], 2).tolist()}  tilt "
              f"{tilt:.1f}  z {b.p[0, Z]:.2f}  vz {b.v[0, Z]:+.2f}  detected {self.detected[0]}")

    RotorFaults.after_control = probe  # type: ignore[method-assign]
    try:
        simulate_many(_configs("half", name, over, tail_s=1.0)[seed:seed + 1])
    finally:
        RotorFaults.after_control = plain  # type: ignore[method-assign]


def main(argv: list[str]) -> int:
    if not argv or argv[0] not in ("half", "high", "limits", "trace"):
        print(__doc__)
        return 2
    over = {}
    for a in argv[1:]:
        if "=" in a:
            k, v = a.split("=", 1)
            try:
                over[k] = json.loads(v)
            except ValueError:
                over[k] = v
    names = [a for a in argv[1:] if "=" not in a]
    case = argv[0]
    names = names or (list(VARIANTS) if case == "high" else ["m350"])
    if case == "trace":
        trace(names[0], int(names[1]), over)
        return 0
    if case == "limits":
        for name in names:
            limits(name, over)
        return 0
    for name in names:
        t0 = time.time()
        soft = 0
        for s, r in zip(SEEDS, simulate_many(_configs(case, name, over)), strict=True):
            sm, rf = r.summary, r.summary["rotor_fault"]
            ok = not sm["crashed"] and (rf["touchdown_mps"] or 9.0) < 1.0
            soft += ok
            print(f"{case} {name} seed {s} rotor {rf['rotor']} at {rf['at_s']} s detected "
                  f"{rf['detected_s']} s (roll/pitch rate {rf['rate_at_detection_rad_s']} "
                  f"rad/s, peak {rf['rate_peak_rad_s']}) touchdown {rf['touchdown_mps']} m/s "
                  f"landed {rf['landed_s']} {sm.get('crash_reason') or ''}", flush=True)
        print(f"{case} {name}: {soft} of {len(SEEDS)} below 1 m/s ({time.time() - t0:.0f} s)")
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
