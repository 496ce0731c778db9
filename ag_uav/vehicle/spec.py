"""The vehicle spec: every figure of the airframe in one dataclass, read from the config.

:func:`vehicle_spec` gathers what the MJCF generator (:mod:`ag_uav.vehicle.mjcf`), the mixer,
the energy model and the sprayer need from ``[vehicle]``, ``[battery]`` and ``[spray]``
(``vehicle.preset`` has filled the keys a config leaves unset: :mod:`ag_uav.config.vehicles`).

Frames (body frame x forward, y left, z up; angles from x towards y):

* ``quad-x``: rotors fr, fl, rl, rr at −45°, 45°, 135°, −135°;
* ``hexa-x``: rotors fr, fl, l, rl, rr, r at −30°, 30°, 90°, 150°, −150°, −90°;
* ``octo-x8``: four coaxial pairs on the quad-x arms, the upper rotors (fr_u … rr_u) then the
  lower ones (fr_l … rr_l), ``vehicle.coaxial_gap_m`` below.

Around the circle the spin alternates (rotor ``i`` of a planar frame reacts with ``s_i k f``,
``s = −1, +1, −1, …``), so same-spin rotors sit opposite each other and a pure yaw command rolls
and pitches nothing; a coaxial pair's lower rotor spins against its upper one. A lower rotor
gives ``vehicle.coaxial_efficiency`` of an isolated rotor's thrust and yaw torque per unit
command (its ``eff``), which the mixer knows.

Rotor positions are rounded to 0.1 mm and the other airframe coordinates too (the M350's
0.4475 m arm gives its rotors at ±0.3164 m); the airframe's boxes, skids and tank scale with the
arm, ``s = arm_m / 0.4475 m`` (the M350's layout, ``s = 1``).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from ..config import Config

#: the M350's arm (m): the airframe's layout scales with arm_m / M350_ARM
M350_ARM = 0.4475
G = 9.81

_PLANAR = {
    "quad-x": (("fr", -45.0), ("fl", 45.0), ("rl", 135.0), ("rr", -135.0)),
    "hexa-x": (("fr", -30.0), ("fl", 30.0), ("l", 90.0), ("rl", 150.0), ("rr", -150.0),
               ("r", -90.0)),
}


@dataclass(frozen=True)
class Rotor:
    """One rotor: name, hub position (body frame, m), spin sign ``s`` (yaw reaction ``s k f``),
    thrust per unit command ``eff`` and its arm's index."""

    name: str
    x: float
    y: float
    z: float
    spin: int
    eff: float
    arm: int


@dataclass(frozen=True)
class VehicleSpec:
    """The airframe's figures (see the module docstring and docs/vehicles.md)."""

    preset: str
    frame: str
    rotors: tuple[Rotor, ...]
    arms: tuple[tuple[float, float], ...]   # arm tips (x, y), m
    scale: float                            # airframe layout / the M350's
    rotor_diameter_m: float
    mass_kg: float                          # empty + batteries (no liquid)
    battery_mass_kg: float
    rotor_mass_kg: float
    arm_mass_kg: float
    inertia_kgm2: tuple[float, float, float] | None   # None: from the components
    thrust_to_weight: float
    motor_tau_s: float
    k_yaw: float
    tank_l: float
    full_tank_kg: float
    pump_l_per_min: float
    sprayer: str
    nozzles: tuple[tuple[float, float, float], ...]
    capacity_wh: float
    reserve_frac: float

    @property
    def n_rotors(self) -> int:
        return len(self.rotors)

    @property
    def empty_mass_kg(self) -> float:
        """Without batteries and liquid."""
        return self.mass_kg - self.battery_mass_kg

    @property
    def body_mass_kg(self) -> float:
        """The central box's mass: mass_kg less the rotors and arms (to the milligram)."""
        return round(self.mass_kg - self.n_rotors * self.rotor_mass_kg
                     - len(self.arms) * self.arm_mass_kg, 6)

    @property
    def disc_count(self) -> int:
        """Distinct rotor discs (a coaxial pair is one disc): what a downwash model's disc
        area counts, ``disc_count · π D² / 4``."""
        return len({(r.x, r.y) for r in self.rotors})

    @property
    def thrust_sum(self) -> float:
        """Σ e_i: total thrust per unit of a common command."""
        return sum(r.eff for r in self.rotors)

    @property
    def f_max(self) -> float:
        """Per-rotor command limit (N): ``thrust_to_weight · m g / Σ e_i``."""
        return self.thrust_to_weight * self.mass_kg * G / self.thrust_sum

    def info(self) -> dict:
        return {"preset": self.preset, "frame": self.frame, "rotors": self.n_rotors,
                "rotor_discs": self.disc_count,
                "rotor_diameter_m": self.rotor_diameter_m,
                "mass_empty_kg": round(self.empty_mass_kg, 4),
                "mass_battery_kg": self.battery_mass_kg,
                "mass_full_tank_kg": round(self.full_tank_kg, 4),
                "mass_max_takeoff_kg": round(self.mass_kg + self.full_tank_kg, 4),
                "tank_l": self.tank_l, "pump_l_per_min": self.pump_l_per_min,
                "sprayer": self.sprayer, "battery_wh": self.capacity_wh}


def _r4(v: float) -> float:
    return round(v, 4)


def rotor_layout(frame: str, arm: float, height: float, gap: float,
                 coaxial_efficiency: float) -> tuple[tuple[Rotor, ...], tuple]:
    """The rotors and arm tips of ``frame`` (module docstring)."""
    base = _PLANAR["quad-x" if frame == "octo-x8" else frame]
    tips = []
    for _, ang in base:
        if frame != "hexa-x":  # X layouts: ±arm/√2 (exactly the M350's ±0.3164 m)
            a = _r4(arm * math.sqrt(0.5))
            tips.append((math.copysign(a, math.cos(math.radians(ang))),
                         math.copysign(a, math.sin(math.radians(ang)))))
        else:
            tips.append((_r4(arm * math.cos(math.radians(ang))),
                         _r4(arm * math.sin(math.radians(ang)))))
    rotors = [Rotor(name + ("_u" if frame == "octo-x8" else ""), x, y, height,
                    -1 if k % 2 == 0 else 1, 1.0, k)
              for k, ((name, _), (x, y)) in enumerate(zip(base, tips, strict=True))]
    if frame == "octo-x8":
        rotors += [Rotor(r.name[:-2] + "_l", r.x, r.y, _r4(height - gap), -r.spin,
                         coaxial_efficiency, r.arm) for r in list(rotors)]
    return tuple(rotors), tuple(tips)


def vehicle_spec(cfg: Config) -> VehicleSpec:
    """The spec of ``cfg``'s vehicle."""
    v, b, sp = cfg.vehicle, cfg.battery, cfg.spray
    rotors, arms = rotor_layout(v.frame, v.arm_m, v.rotor_height_m, v.coaxial_gap_m,
                                v.coaxial_efficiency)
    noz = sp.nozzle_xyz_m
    return VehicleSpec(
        preset=v.preset, frame=v.frame, rotors=rotors, arms=arms, scale=v.arm_m / M350_ARM,
        rotor_diameter_m=b.rotor_diameter_m, mass_kg=v.mass_kg,
        battery_mass_kg=v.battery_mass_kg, rotor_mass_kg=v.rotor_mass_kg,
        arm_mass_kg=v.arm_mass_kg,
        inertia_kgm2=tuple(v.inertia_kgm2) if v.inertia_kgm2 else None,  # type: ignore[arg-type]
        thrust_to_weight=v.thrust_to_weight, motor_tau_s=v.motor_tau_s,
        k_yaw=v.yaw_torque_coeff_m, tank_l=sp.tank_l,
        full_tank_kg=sp.tank_l * sp.density_kg_per_l if sp.enabled else v.payload_kg,
        pump_l_per_min=v.pump_l_per_min, sprayer=v.sprayer,
        nozzles=tuple((noz[i], noz[i + 1], noz[i + 2]) for i in range(0, len(noz), 3)),
        capacity_wh=b.capacity_wh, reserve_frac=b.reserve_frac)
