"""Vehicle presets (``vehicle.preset``): the figures of a spray drone class across the
``[vehicle]``, ``[battery]`` and ``[spray]`` tables, each with its source.

A preset fills the keys a config leaves unset (:func:`apply_vehicle_preset`, called by
:func:`ag_uav.config.config_from_dict` before the config is built and checked); a key the config
sets wins. ``m350`` is the schema's defaults (the core paper's DJI Matrice 350 RTK class), so it
changes nothing.

Sources (manufacturer sheets; a figure not on a sheet is marked *estimate* with its reasoning):

* [M350] DJI Matrice 350 RTK specs, https://enterprise.dji.com/matrice-350-rtk/specs: 6.47 kg
  with two TB65 batteries, 9.2 kg max take-off, 895 mm diagonal wheelbase, 2110s propellers
  (21 in), 55 min max flight time; TB65: 5880 mAh, 44.76 V, 263.2 Wh, about 1.35 kg each.
* [T10] DJI Agras T10 specs, https://www.dji.com/support/product/t10: 13.8 kg without battery,
  24.8 kg standard take-off weight (with 8 L), 1480 mm diagonal wheelbase, 33 in propellers,
  4 rotors, 8 L spray tank, 4 hydraulic fan nozzles, max flow 2.4 L/min, battery 9500 mAh at
  51.8 V (492 Wh), hovering 19 min at 16.8 kg (no payload). These T10 figures were not
  re-read from the page when the preset was written (the T40's were), nor since: check them
  there. The least certain is the split of the 16.8 kg into 13.8 kg airframe and 3.0 kg
  battery; it is not flown (the model flies ``mass_kg``; ``battery_mass_kg`` is reported).
* [T40] DJI Agras T40 specs, https://www.dji.com/support/product/t40: 38 kg without battery,
  50 kg with battery, 90 kg max take-off for spraying, 2184 mm max diagonal wheelbase, 54 in
  propellers, 8 rotors (coaxial twin rotors on 4 arms), 40 L operation box, two LX8060SZ
  centrifugal (rotary) atomisers, droplets 50-300 um, max effective spray width 11 m at 2.5 m
  and 7 m/s, hovering 18 min at 50 kg and 7 min at 90 kg on the 30000 mAh DB1560 battery
  (52.22 V, about 1566 Wh); max flow 12 L/min with the two atomisers.

Estimates shared by the presets:

* figure_of_merit: the product's momentum-theory power (``ag_uav.world.spray_job``) solved for
  the sheet's no-payload hover time, :func:`implied_figure_of_merit` (rotor figure of merit
  times motor/ESC efficiency; for the X8 it also carries the coaxial pairs' loss at equal
  power).
* thrust_to_weight: total thrust over the weight without payload such that the max take-off
  weight keeps a thrust-to-weight near 1.5 (autopilots need ~1.4-2 for control authority).
* motor_tau_s: first-order motor lag growing with propeller inertia (0.04 s at 21 in; 0.08 s
  at 33 in, 0.12 s at 54 in).
* yaw_torque_coeff_m: C_Q D / (2π C_T) scales with the diameter D: 0.016 m × D / 0.533 m.
* drag: scaled with the frontal area (about the square of the arm length), capped.
* rotor_mass_kg, arm_mass_kg: motor + propeller + ESC and arm tube; the body box carries the
  rest (batteries, tank, avionics); they set the inertia ("from components").
* coaxial_efficiency 0.8: the lower rotor of a coaxial pair in the upper rotor's slipstream
  gives ~80 % of an isolated rotor's thrust for the same command (Leishman, Principles of
  Helicopter Aerodynamics, 2nd ed. 2006, ch. 4, coaxial rotors: induced-power interference
  factor κ_int ≈ 1.28); an estimate.
* nozzle positions: one hydraulic nozzle under each rotor (T10), the two atomisers under the
  rear rotor pairs (T40); droplet spectrum of the atomisers within DJI's 50-300 um.
"""

from __future__ import annotations

import copy
import math
from typing import Any

#: rotors of each frame
FRAME_ROTORS = {"quad-x": 4, "hexa-x": 6, "octo-x8": 8}
G = 9.81


def _under(arm: float, z: float, quads: tuple[int, ...] = (0, 1, 2, 3)) -> list[float]:
    """x, y, z of a nozzle under each rotor position of an X arm layout (fr, fl, rl, rr)."""
    a = round(arm * math.sqrt(0.5), 4)
    pos = ((a, -a), (a, a), (-a, a), (-a, -a))
    return [v for q in quads for v in (pos[q][0], pos[q][1], z)]


#: the presets: table -> key -> value (``m350``: the schema's defaults, for the record)
PRESETS: dict[str, dict[str, dict[str, Any]]] = {
    "m350": {
        "vehicle": {"frame": "quad-x", "mass_kg": 6.47, "battery_mass_kg": 2.7,
                    "arm_m": 0.4475, "rotor_height_m": 0.08},
        "battery": {"capacity_wh": 526.0, "rotor_diameter_m": 0.533},
        "spray": {"tank_l": 2.7},
    },
    "quad-10l": {
        "vehicle": {
            # [T10]: 24.8 kg − 8 L; 16.8 − 13.8 kg without battery
            "frame": "quad-x", "mass_kg": 16.8, "battery_mass_kg": 3.0,
            "arm_m": 0.74,                       # [T10] 1480 mm / 2
            "rotor_height_m": 0.1323,            # estimate: the M350's 0.08 m × 0.74 / 0.4475
            "thrust_to_weight": 2.4,             # estimate: 1.5 at 26.8 kg max take-off
            "motor_tau_s": 0.08,                 # estimate (33 in propellers)
            "yaw_torque_coeff_m": 0.025,         # estimate: 0.016 × 0.838 / 0.533
            "drag_linear": [0.6, 0.6, 0.8], "drag_quadratic": [0.45, 0.45, 0.9],  # estimate
            "rotor_mass_kg": 0.95, "arm_mass_kg": 0.3,  # estimate
            "rotor_thrust_loss": [0.0, 0.0, 0.0, 0.0],
            "sprayer": "hydraulic", "pump_l_per_min": 2.4,  # [T10]
        },
        "battery": {"capacity_wh": 492.0,        # [T10] 9500 mAh × 51.8 V
                    "rotor_diameter_m": 0.838,   # [T10] 33 in
                    "figure_of_merit": 0.609,    # 19 min hover at 16.8 kg [T10], see module
                    "avionics_w": 60.0},         # estimate: pump, radar, RTK
        "spray": {"tank_l": 8.0,                 # [T10]
                  "nozzle_xyz_m": _under(0.74, -0.25)},  # estimate: under each rotor
    },
    "x8-40l": {
        "vehicle": {
            "frame": "octo-x8", "mass_kg": 50.0, "battery_mass_kg": 12.0,  # [T40] 50; 50 − 38
            "arm_m": 1.092,                      # [T40] 2184 mm / 2
            "rotor_height_m": 0.25,              # estimate: upper rotor plane
            "coaxial_gap_m": 0.3,                # estimate: upper to lower rotor plane
            "coaxial_efficiency": 0.8,           # estimate, see module
            "thrust_to_weight": 2.7,             # estimate: 1.5 at 90 kg max take-off
            "motor_tau_s": 0.12,                 # estimate (54 in propellers)
            "yaw_torque_coeff_m": 0.041,         # estimate: 0.016 × 1.3716 / 0.533
            "drag_linear": [1.5, 1.5, 2.0], "drag_quadratic": [1.1, 1.1, 2.2],  # estimate
            "rotor_mass_kg": 1.5, "arm_mass_kg": 0.8,  # estimate (100×33 mm stator motors)
            "rotor_thrust_loss": [0.0] * 8,
            "sprayer": "rotary", "pump_l_per_min": 12.0,  # [T40]
            # estimate: an 80 mm disc at 7200 rpm gives a 151 um VMD (Walton & Prewett), inside
            # [T40]'s 50-300 um; the sheet states neither the disc nor its speed
            "atomiser_rpm": 7200.0, "atomiser_radius_m": 0.04,
        },
        "battery": {"capacity_wh": 1566.0,       # [T40] DB1560: 30000 mAh × 52.22 V
                    "rotor_diameter_m": 1.372,   # [T40] 54 in
                    "figure_of_merit": 0.462,    # 18 min hover at 50 kg [T40], see module
                    "avionics_w": 100.0},        # estimate: pumps, atomiser motors, radar
        "spray": {"tank_l": 40.0,                # [T40]
                  "nozzle_xyz_m": _under(1.092, -0.35, (2, 3)),  # estimate: rear pairs
                  # estimate in [T40]'s 50-300 um; with atomiser_rpm > 0 only the shape (the
                  # VMD follows the disc speed, ag_uav.world.atomiser)
                  "dv10_um": 80.0, "dv50_um": 150.0, "dv90_um": 280.0},
    },
}


#: the manufacturer's stated area rate (ha/h) of a preset's class, with where it comes from
STATED_WORK_RATE: dict[str, tuple[float, str]] = {
    "x8-40l": (27.7, "DJI Agras T40 sheet: 11 m max effective spray width at 7 m/s "
                     "(11 m × 7 m/s = 27.7 ha/h spraying, without turns or base visits)"),
}


def apply_vehicle_preset(data: dict[str, Any]) -> dict[str, Any]:
    """``data`` (a TOML-shaped config) with the keys of its ``vehicle.preset`` filled in where
    it leaves them unset (a copy; ``data`` is not changed). An unknown preset is left for the
    schema's check to name."""
    veh = data.get("vehicle")
    name = veh.get("preset", "m350") if isinstance(veh, dict) else "m350"
    if not isinstance(name, str) or name not in PRESETS or name == "m350":
        return data
    out = copy.copy(data)
    for table, values in PRESETS[name].items():
        cur = out.get(table)
        if cur is not None and not isinstance(cur, dict):
            continue  # not a table: the schema's check names it
        merged = dict(cur or {})
        for k, v in values.items():
            merged.setdefault(k, copy.deepcopy(v))
        out[table] = merged
    return out


def rotor_thrust_sum(frame: str, coaxial_efficiency: float) -> float:
    """Σ e_i: the frame's total thrust per unit of a common rotor command (the lower rotors of
    coaxial pairs count ``coaxial_efficiency``)."""
    n = FRAME_ROTORS[frame]
    if frame == "octo-x8":
        return 4.0 + 4.0 * coaxial_efficiency
    return float(n)


def implied_figure_of_merit(capacity_wh: float, hover_min: float, mass_kg: float,
                            rotor_diameter_m: float, avionics_w: float, frame: str = "quad-x",
                            coaxial_efficiency: float = 0.8, air_density: float = 1.225) -> float:
    """The FM for which ``capacity_wh`` hovers ``mass_kg`` for ``hover_min`` minutes on
    ``frame``: hover power ``n k (m g / Σe)^{3/2} + P_av`` with ``k = 1 / (FM sqrt(2 ρ A))``
    (momentum theory; each rotor's command ``m g / Σe``)."""
    n = FRAME_ROTORS[frame]
    se = rotor_thrust_sum(frame, coaxial_efficiency)
    p_total = capacity_wh / (hover_min / 60.0)
    area = math.pi * rotor_diameter_m ** 2 / 4.0
    ideal = n * (mass_kg * G / se) ** 1.5 / math.sqrt(2.0 * air_density * area)
    return ideal / (p_total - avionics_w)
