"""The quad rotor-failure campaigns of docs/vehicles.md ("A quad on three rotors").

    python -m tools.rotor_loss_campaign half [PRESET]      # rotor seed mod 4 stopped at half the
                                                           # default mission, seeds 0-9
    python -m tools.rotor_loss_campaign high VARIANT ...   # at 20 s of the default plan flown at
                                                           # 20 m; VARIANT: m350, tau15, spinner

Arguments ``KEY=VALUE`` set a config key on every flight (e.g.
``vehicle.rotor_fault.detector=esc-rpm``). Each flight: the seed, the rotor, when the fault was
detected and the body's roll/pitch rate then, the touchdown speed, the landing time or the
crash; then the count that touched down below 1 m/s without a crash.
"""

from __future__ import annotations

import json
import sys
import time
from typing import Any

import ag_uav
from ag_uav.engine.missions import mission_setup, simulate_many

VARIANTS = {
    "m350": {},
    "tau15": {"vehicle.motor_tau_s": 0.015},
    "spinner": {"vehicle.motor_tau_s": 0.015, "vehicle.yaw_torque_coeff_m": 0.04,
                "vehicle.thrust_to_weight": 2.5},
}
SEEDS = range(10)


def _configs(case: str, name: str, over: dict[str, Any]) -> list[ag_uav.Config]:
    base: dict[str, Any] = {"log.enabled": False, **over}
    if case == "half":
        base["vehicle.preset"] = name
        at = round(mission_setup(ag_uav.load_config(None, base))[2].duration / 2.0, 1)
    else:
        base.update({"mission.altitude_m": 20.0, "spray.max_height_m": 30.0, **VARIANTS[name]})
        at = 20.0
    return [ag_uav.load_config(None, {**base, "seed": s, "vehicle.rotor_fault.rotor": s % 4,
                                      "vehicle.rotor_fault.at_s": at,
                                      "sim.max_time_s": at + 60.0}) for s in SEEDS]


def main(argv: list[str]) -> int:
    if not argv or argv[0] not in ("half", "high"):
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
    names = names or (["m350"] if case == "half" else list(VARIANTS))
    for name in names:
        t0 = time.time()
        soft = 0
        for s, r in zip(SEEDS, simulate_many(_configs(case, name, over)), strict=True):
            sm, rf = r.summary, r.summary["rotor_fault"]
            ok = not sm["crashed"] and (rf["touchdown_mps"] or 9.0) < 1.0
            soft += ok
            print(f"{case} {name} seed {s} rotor {rf['rotor']} at {rf['at_s']} s detected "
                  f"{rf['detected_s']} s (roll/pitch rate {rf['rate_at_detection_rad_s']} "
                  f"rad/s) touchdown {rf['touchdown_mps']} m/s landed "
                  f"{rf['landed_s']} {sm.get('crash_reason') or ''}", flush=True)
        print(f"{case} {name}: {soft} of {len(SEEDS)} below 1 m/s ({time.time() - t0:.0f} s)")
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
