"""The run config's schema: one typed dataclass per TOML table, each field with its default,
help text and what is allowed (:func:`_f`); :mod:`ag_uav.config.load` reads and checks a config
against it."""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field
from typing import Any

import tomli_w


class ConfigError(ValueError):
    """A bad config value. The message is one line: ``key = value: what is allowed``.

    Control characters (a newline in a string value or a key, a non-UTF-8 byte from the command
    line) are escaped, so the message stays one printable line whatever the input.
    """

    def __init__(self, msg: str) -> None:
        super().__init__(_one_line(str(msg)))


def _one_line(msg: str) -> str:
    """``msg`` with every non-printable character escaped (``\\n``, ``\\udcff``, ...)."""
    if msg.isprintable():
        return msg
    return "".join(c if c.isprintable() else repr(c)[1:-1] for c in msg)


INT_MIN, INT_MAX = -(2**63), 2**63 - 1  # TOML integers are 64-bit signed
FLOAT_LIMIT = 1e9  # no number key needs more; beyond it the simulation overflows (mass 1e300)


def _f(default: Any, help: str, *, gt: float | None = None, ge: float | None = None,
       le: float | None = None, lt: float | None = None, choices: tuple | None = None,
       length: int | None = None, unique: bool = False) -> Any:
    """A config field: default, help text and what is allowed (bounds on numbers, ``choices``
    for strings, ``length`` and ``unique`` for lists); :func:`ag_uav.config.config_from_dict`
    enforces them."""
    meta = {"help": help, "gt": gt, "ge": ge, "le": le, "lt": lt, "choices": choices,
            "length": length, "unique": unique}
    if isinstance(default, list | dict):
        return field(default_factory=lambda: _copy(default), metadata=meta)
    return field(default=default, metadata=meta)


def _copy(v: Any) -> Any:
    import copy

    return copy.deepcopy(v)


CONTROLLER_TYPES = ("it2-fpid", "t1-fpid", "pid")
REDUCERS = ("km", "nt", "bmm", "zeta")


@dataclass
class MissionConfig:
    field: str = _f("default", "built-in field (default, l-shape, hole, two-part) or a lon/lat "
                    ".geojson/.kml/.kmz/.shp path; PATH#name=VALUE picks one feature")
    swath_m: float | str = _f("auto", "spray swath width = lane spacing (m; >= 0.5), or "
                              "\"auto\": the widest spacing whose overlaid single-pass deposit "
                              "has CV <= swath_cv_max in the deposition model's pattern test at "
                              "this mission's height, speed, mass, nozzles, droplets and mean "
                              "wind (ag_uav.world.pattern)", ge=0.5, choices=("auto",))
    swath_cv_max: float = _f(0.15, "swath_m = \"auto\": CV limit of the overlaid pattern. 0.15: "
                             "a dose spread normally with this CV leaves about 10 % of the "
                             "field below 80 % of its mean (0.2 / z(0.90) = 0.156); 0.25 is "
                             "the effective swath (ASABE S386 / Martin et al. 2019), a width "
                             "for comparing aircraft, which leaves about 20 % below it",
                             gt=0, lt=1)
    swath_spread: bool = _f(False, "swath_m = \"auto\": the lanes must also hold in the "
                            "forecast's spread: the widest spacing whose CV is <= "
                            "swath_cv_max at the forecast and on average over the four winds "
                            "one sigma off it in speed and in direction "
                            "(forecast.speed_sigma_mps, forecast.direction_sigma_deg)")
    headland_m: float | str = _f("auto", "headland margin swept by laps along the boundary (m; "
                                 "0 = none), or \"auto\": one lap of the lane spacing",
                                 ge=0, choices=("auto",))
    direction_deg: float | str = _f("crosswind", "sweep direction in degrees from east "
                                    "(counter-clockwise); \"crosswind\": legs across the mean "
                                    "wind, as aerial application flies them, so that legs out "
                                    "and back meet the same airspeed and lay the same pattern "
                                    "(\"auto\" in calm air); \"auto\": fewest turns",
                                    choices=("auto", "crosswind"))
    upwind_offset_m: float | str = _f("auto", "the whole plan moved upwind across the legs by "
                                      "this much (m; 0 = none), or \"auto\": by the pattern "
                                      "test's downwind shift in the planning wind (the centre "
                                      "of its deposit's half-peak width, at most half the lanes: "
                                      "the upwind boundary lap at most on the boundary), so "
                                      "that the pattern, not the flight line, lies on the field",
                                      ge=0, le=20, choices=("auto",))
    speed_mps: float = _f(5.0, "cruise ground speed on legs (m/s)", ge=0.5, le=15)
    altitude_m: float = _f(3.0, "spray altitude above ground (m)", gt=0.5, le=50)
    accel_max_mps2: float = _f(1.5, "acceleration bound of the reference (m/s^2)", ge=0.05,
                                  le=8)
    origin_lat_deg: float | str = _f("auto", "latitude of the local frame's origin (WGS-84 "
                                     "degrees), or \"auto\": a lon/lat field's own origin (the "
                                     "mean of its vertices), the built-in default field's "
                                     "46.725 (the Palouse, Idaho); a lon/lat field is projected "
                                     "about the origin given", choices=("auto",), gt=-90, lt=90)
    origin_lon_deg: float | str = _f("auto", "longitude of the origin (WGS-84 degrees), or "
                                     "\"auto\" (with origin_lat_deg: both, or neither); the "
                                     "default field's -117.02", choices=("auto",), ge=-180,
                                     le=180)
    origin_alt_m: float | str = _f("auto", "WGS-84 ellipsoidal height of the origin, the "
                                   "ground (m), or \"auto\": 0 for a lon/lat field, 760 for "
                                   "the default field (approximate)", choices=("auto",),
                                   ge=-500, le=9000)


VEHICLE_PRESETS = ("m350", "quad-10l", "x8-40l")
FRAMES = ("quad-x", "hexa-x", "octo-x8")


@dataclass
class RotorFaultConfig:
    """A rotor that fails in flight (ag_uav.engine.rotor_fault; docs/vehicles.md)."""

    rotor: int = _f(-1, "the rotor that fails, in the frame's order (-1: none)", ge=-1, le=7)
    at_s: float = _f(300.0, "when it fails (s of simulated time)", ge=0)
    efficiency: float = _f(0.0, "the share of its thrust it keeps (0: stopped)", ge=0, lt=1)
    response: str = _f("auto", "after the failure detector: hexa-x, octo-x8 re-allocate "
                       "without the rotor, then continue: fly on; home: spray off, fly to the "
                       "base and land; land: land where it is; auto: continue if the hover "
                       "needs at most 90 % of a rotor's limit, else spray off and land. quad-x: "
                       "give up yaw and land where it is. none: no detector (the fault is a "
                       "model error)", choices=("auto", "continue", "home", "land", "none"))
    detector: str = _f("px4", "the failure detector's motor check: px4: PX4's FailureDetector "
                       "(attitude/rate errors for 0.3 s, a motor under half its command for "
                       "0.1 s); esc-rpm: each motor's speed telemetry against its command "
                       "(400 Hz, 2.5 ms latency, 3 samples under half: ~10 ms)",
                       choices=("px4", "esc-rpm"))


@dataclass
class VehicleConfig:
    """The airframe (ag_uav.vehicle.spec; docs/vehicles.md). ``preset`` fills the keys of
    [vehicle], [battery] and [spray] a config leaves unset (ag_uav.config.vehicles)."""

    preset: str = _f("m350", "vehicle preset: m350 (DJI Matrice 350 RTK class, 4 rotors), "
                     "quad-10l (10 L class spray quad, DJI Agras T10 figures), x8-40l (40 L "
                     "coaxial X8 with rotary atomisers, DJI Agras T40 figures)",
                     choices=VEHICLE_PRESETS)
    frame: str = _f("quad-x", "rotor layout: quad-x (4 rotors fr, fl, rl, rr), hexa-x (6), "
                    "octo-x8 (8: 4 coaxial pairs, upper then lower)", choices=FRAMES)
    arm_m: float = _f(0.4475, "centre to rotor axis (m); M350: 895 mm diagonal wheelbase / 2",
                      gt=0.1, le=3.0)
    rotor_height_m: float = _f(0.08, "rotor plane above the body origin (m; the upper rotors' "
                               "on a coaxial frame)", ge=0.0, le=1.0)
    coaxial_gap_m: float = _f(0.2, "octo-x8: upper to lower rotor plane (m)", gt=0.0, le=1.0)
    coaxial_efficiency: float = _f(0.8, "octo-x8: thrust of a lower rotor per unit command, "
                                   "relative to an isolated rotor (in the upper's slipstream)",
                                   gt=0.3, le=1.0)
    rotor_mass_kg: float = _f(0.575, "motor + propeller + ESC of each rotor (kg; part of "
                              "mass_kg, sets the inertia)", ge=0.0)
    arm_mass_kg: float = _f(0.05, "each arm tube (kg; part of mass_kg)", ge=0.0)
    battery_mass_kg: float = _f(2.7, "batteries (kg; part of mass_kg): M350 two TB65 packs",
                                ge=0.0)
    inertia_kgm2: list[float] = _f([], "body-axis inertia [Ixx, Iyy, Izz] (kg m^2) without "
                                   "liquid; [] = from the components (body box, arms, rotors)",
                                   gt=0.0, le=1000.0)
    sprayer: str = _f("hydraulic", "spray heads: hydraulic nozzles or rotary atomisers (at "
                      "spray.nozzle_xyz_m)", choices=("hydraulic", "rotary"))
    atomiser_rpm: float = _f(0.0, "rotary: the atomiser disc's speed (rpm); sets the spectrum's "
                             "VMD (Walton & Prewett: d = 3.8/w sqrt(sigma/(rho D)); spray.dv10/"
                             "dv50/dv90_um then give only its shape) and the droplets' throw "
                             "from the rim (ag_uav.world.atomiser). 0: the fixed spectrum, no "
                             "throw", ge=0.0, le=30000.0)
    atomiser_radius_m: float = _f(0.04, "rotary: the atomiser disc's radius (m)", gt=0.0,
                                  le=0.5)
    pump_l_per_min: float = _f(1.0, "pump flow limit (L/min); M350 add-on tank: an estimate",
                               gt=0.0, le=100.0)
    mass_kg: float = _f(6.47, "dry mass with batteries (DJI M350 RTK: 6.47 kg)", gt=0.5)
    payload_kg: float = _f(0.0, "spray payload carried in the tank (kg)", ge=0)
    thrust_to_weight: float = _f(2.0, "max total thrust / weight at mass_kg (no payload)", gt=1.05,
                                 le=6)
    motor_tau_s: float = _f(0.04, "first-order motor time constant (s)", gt=0, le=0.5)
    yaw_torque_coeff_m: float = _f(0.016, "rotor yaw reaction torque per newton of thrust (m)",
                                   gt=0, le=0.1)
    drag_linear: list[float] = _f([0.25, 0.25, 0.30], "linear air drag per body-world axis "
                                  "(N per m/s of airspeed; rotor drag)", ge=0, length=3)
    drag_quadratic: list[float] = _f([0.18, 0.18, 0.35], "quadratic air drag per axis "
                                     "(N per (m/s)^2: ½ ρ C_d A)", ge=0, length=3)
    unknown_payload_kg: float = _f(0.0, "model error: mass the vehicle carries that the flight "
                                   "controller's model leaves out (its mass, inertia and rotor "
                                   "arms stay those without it)", ge=0, le=20)
    unknown_payload_pos_m: list[float] = _f([0.0, 0.0, 0.0], "model error: where the unknown "
                                            "payload sits (body frame, m from the airframe "
                                            "origin); off-centre it moves the centre of gravity "
                                            "by m_u r / m_total, unknown to the controller "
                                            "(no effect without unknown_payload_kg)",
                                            ge=-0.5, le=0.5, length=3)
    rotor_fault: RotorFaultConfig = field(default_factory=RotorFaultConfig,
                                          metadata={"help": "a rotor failing in flight"})
    rotor_thrust_loss: list[float] = _f([0.0, 0.0, 0.0, 0.0], "model error: fraction of the "
                                        "commanded thrust (and yaw torque) each rotor (in the "
                                        "frame's order; quad-x: fr, fl, rl, rr) fails to "
                                        "deliver: a failing motor the controller does not "
                                        "know; one value per rotor", ge=0, lt=0.9)


@dataclass
class SimConfig:
    timestep_s: float = _f(0.002, "MuJoCo physics step (s)", ge=1e-5, le=0.01)
    control_hz: float = _f(100.0, "control rate (Hz); must divide the physics rate", ge=1,
                           le=1000)
    max_time_s: float = _f(21600.0, "hard cap on simulated time (s); a mission cut by it "
                           "says so in its summary", gt=0)
    hover_after_s: float = _f(3.0, "hover time at the end of the path (s)", ge=0, le=3600)
    takeoff: bool = _f(True, "start on the ground and climb to spray altitude")
    memory_budget_mb: float = _f(8192.0, "memory budget of one run (MB): a run whose planned "
                                 "reference and per-tick tables would need more is refused "
                                 "before it flies", gt=0)


@dataclass
class SprayConfig:
    """Tank and application (ag_uav.world.spray_job). Defaults: the M350-class payload limit as
    the tank."""

    enabled: bool = _f(True, "model the tank, the flow and sorties (false: the sprayer is an "
                       "on/off flag only, the tank never empties)")
    rate_l_per_ha: float = _f(1.0, "application rate (L/ha); 1 L/ha is an ultra-low-volume "
                              "rate (ULV < 5 L/ha for field crops), as an M350-class payload "
                              "needs; spray drones fly 10-20 L/ha with 20-40 L tanks", gt=0)
    tank_l: float = _f(2.7, "tank volume (L); 2.7 L of water = the DJI M350 RTK's 2.7 kg "
                       "payload limit (9.2 kg max take-off - 6.47 kg)", gt=0)
    density_kg_per_l: float = _f(1.0, "liquid density (kg/L; water-based mixes ~1.0)", gt=0.3,
                                 le=2.0)
    min_height_m: float = _f(0.5, "nozzles off below this height above ground (m): on the "
                             "ground, taking off, landing", ge=0)
    max_height_m: float = _f(6.0, "nozzles off above this height above ground (m)", gt=0)
    offtarget_buffer_m: float = _f(0.5, "spray within this distance outside the field (or "
                                   "inside a hole) is not counted as off-target (m)", ge=0)
    base: list[float] | str = _f("auto", "base point [x, y] (local m) where the drone lands to "
                                 "refill / swap batteries, or \"auto\" (the field corner "
                                 "nearest the take-off point)", choices=("auto",), length=2)
    service_s: float = _f(90.0, "time on the ground at the base per refill and battery swap "
                          "(s); an estimate", ge=0)
    transit_speed_mps: float = _f(8.0, "ground speed to and from the base (m/s)", gt=0, le=20)
    plan_margin: float = _f(0.02, "share of the tank held back when the sortie planner predicts "
                            "where the tank runs dry (actual flow follows the actual speed)",
                            ge=0, lt=0.5)
    max_sorties: int = _f(200, "sortie limit of the planner", ge=1)
    # ---- the dose on the ground (ag_uav.world.deposition; docs/spray_deposition.md)
    deposition: bool = _f(True, "model what lands: nozzles, droplets, downwash, wind and the "
                          "dose map (L/ha) with its summary metrics (false: skip it)")
    deposition_law: str = _f("default", "the downwash law: default (the ground outwash a layer "
                             "calibrated on the T40's swath), hover (the merged jet, wall jet "
                             "and impaction checked on a wind tunnel; sets wake_escape 0.6) or "
                             "wake (hover, and in forward flight the wake rolled up into a "
                             "trailing vortex pair); docs/spray_deposition.md",
                             choices=("default", "hover", "wake"))
    nozzle_on_delay_s: float = _f(0.1, "valve opening delay (s); ArduPilot AC_Sprayer "
                                  "TURN_ON_DELAY 100 ms", ge=0, le=60)
    nozzle_off_delay_s: float = _f(1.0, "valve closing delay (s) when the ground speed drops "
                                   "below speed_min_mps (and on a command off unless "
                                   "cmd_off_immediate); AC_Sprayer SHUT_OFF_DELAY 1000 ms",
                                   ge=0, le=60)
    cmd_off_immediate: bool = _f(True, "a command off closes the valve at once (AC_Sprayer::run"
                                 "(false)); false: after nozzle_off_delay_s")
    speed_min_mps: float = _f(1.0, "no spray below this ground speed (m/s); AC_Sprayer "
                              "SPEED_MIN 100 cm/s", ge=0, le=15)
    flow_min_l_per_s: float = _f(0.0, "floor of the flow while the valve is open (L/s); "
                                 "AC_Sprayer PUMP_MIN 0 %", ge=0, le=10)
    pressure_tau_s: float = _f(0.15, "time constant of the line pressure (flow) lag (s); an "
                               "assumption (settles in ~0.45 s)", ge=0, le=10)
    nozzle_xyz_m: list[float] = _f([0.3164, -0.3164, -0.15, 0.3164, 0.3164, -0.15,
                                    -0.3164, 0.3164, -0.15, -0.3164, -0.3164, -0.15],
                                   "nozzle positions in the body frame (m), x, y, z of each "
                                   "nozzle in turn (default: one under each M350 rotor)",
                                   ge=-10, le=10)
    nozzle_share: list[float] = _f([], "share of the flow of each nozzle (summing to 1); [] = "
                                   "equal shares", ge=0, le=1)
    dv10_um: float = _f(120.0, "droplet spectrum Dv10 (um); 120/250/420 is a medium spray "
                        "(ASABE S572 via GRDC: 19 % of the volume below 150 um)", gt=1, le=5000)
    dv50_um: float = _f(250.0, "volume median diameter Dv50 (um)", gt=1, le=5000)
    dv90_um: float = _f(420.0, "droplet spectrum Dv90 (um)", gt=1, le=5000)
    surface_tension_n_m: float = _f(0.072, "the mix's surface tension (N/m; water 0.072, "
                                    "with surfactants ~0.03-0.05): a rotary atomiser's droplet "
                                    "size", gt=0.01, le=0.1)
    n_classes: int = _f(10, "droplet classes the spectrum is split into (bins even in the "
                        "normal score of ln D, the fine tail that drifts with its own classes)",
                        ge=1, le=40)
    temperature_c: float = _f(20.0, "air temperature (C): with rh_percent, the wet-bulb "
                              "depression that drives evaporation (d2 law)", ge=-20, le=50)
    rh_percent: float = _f(60.0, "relative humidity (%); Stull's wet-bulb fit holds for 5-99",
                           ge=5, le=99)
    nonvolatile_fraction: float = _f(0.05, "volume share of the tank mix that does not "
                                     "evaporate (a droplet stops shrinking at its diameter)",
                                     ge=1e-4, le=1)
    roughness_m: float = _f(0.05, "roughness length z0 of the log-law wind profile (m); "
                            "0.01-0.05 short grass or bare soil, 0.1-0.2 a low crop", ge=1e-4,
                            le=2)
    wake_escape: float = _f(0.3, "share of the spray sheet at the rotor wake's edge, where "
                            "fines escape as the wake skews (an assumed constant, see "
                            "docs/spray_deposition.md)", ge=0, le=1)
    cell_m: float = _f(0.5, "cell of the dose map (m); coarsened (doubling) if the map would "
                       "exceed max_cells", ge=0.05, le=10)
    buffer_m: float = _f(10.0, "the dose map covers the field plus this buffer (m); what lands "
                         "beyond it counts as drift", ge=0, le=1000)
    max_cells: int = _f(4_000_000, "cell limit of one vehicle's dose map (memory: ~11 bytes "
                        "a cell)", ge=1024, le=100_000_000)
    dose_margin_m: float = _f(0.0, "the dose CV and under-/over-dosed area are taken over the "
                              "field this far inside its boundary (m)", ge=0, le=100)


@dataclass
class BatteryConfig:
    """Energy model (ag_uav.world.spray_job.rotor_power): momentum theory with a figure of merit."""

    capacity_wh: float = _f(526.0, "usable battery energy (Wh); two DJI TB65 packs: "
                            "2 x 263 Wh", gt=0)
    reserve_frac: float = _f(0.2, "reserve: return to base so that this share of the capacity "
                             "is left on landing", ge=0, lt=1)
    figure_of_merit: float = _f(0.623, "rotor figure of merit x motor/ESC efficiency; 0.623 "
                                "gives the M350's ~55 min hover on 526 Wh at 6.47 kg with "
                                "avionics_w", gt=0.05, le=1)
    rotor_diameter_m: float = _f(0.533, "rotor diameter (m); M350: 2110s propellers, 21 in",
                                 gt=0.05)
    air_density_kgm3: float = _f(1.225, "air density (kg/m^3; ISA sea level)", gt=0.5, le=1.5)
    avionics_w: float = _f(25.0, "avionics, RTK, radios, pump (W); an estimate", ge=0)
    plan_margin: float = _f(0.05, "the sortie planner predicts hover power x (1 + this): "
                            "manoeuvres cost more than hover (measured +2-3 %)", ge=0, le=1)


@dataclass
class AxisGains:
    """Gains of one position-axis controller (the keys used depend on ``controller.type``)."""

    ke: float = _f(1.024, "IT2/T1-FPID: error scaling Ke (1/m)", gt=0)
    kd: float = _f(0.715, "IT2/T1-FPID: error-rate scaling Kd (s/m)", gt=0)
    k0: float = _f(6.78, "IT2/T1-FPID: PD-part output gain K0 (m/s^2)", ge=0)
    k1: float = _f(3.043, "IT2/T1-FPID: PI-part output gain K1 (m/s^3)", ge=0)
    alpha: float = _f(0.2458, "IT2-FPID: lower-MF height parameter (h_Z = alpha, h_N = h_P = "
                      "1 - alpha)", gt=0, le=1)
    zeta: float = _f(0.5, "IT2-FPID: weight of the zeta type reducer", ge=0, le=1)
    cm: float = _f(0.6411, "FPID: consequent of the off-diagonal rules", gt=0, le=1)
    reducer: str = _f("bmm", "IT2-FPID type reducer", choices=REDUCERS)
    kp: float = _f(2.2, "PID: proportional gain (1/s^2)", ge=0)
    ki: float = _f(0.3, "PID: integral gain (1/s^3)", ge=0)
    kdd: float = _f(2.4, "PID: derivative gain (1/s)", ge=0)
    i_limit: float = _f(2.0, "anti-windup: bound of the integral contribution (m/s^2)", gt=0)


@dataclass
class AttitudeGains:
    wn: list[float] = _f([9.0, 9.0, 3.0], "attitude loop natural frequency roll, pitch, yaw "
                         "(rad/s); a vehicle whose motor lag would leave it damped below 0.3 "
                         "flies every loop slowed by one factor (docs/vehicles.md)",
                         gt=0, length=3)
    zeta: list[float] = _f([0.9, 0.9, 0.9], "attitude loop damping ratio roll, pitch, yaw",
                           gt=0, length=3)


@dataclass
class ControllerConfig:
    type: str = _f("it2-fpid", "position controller", choices=CONTROLLER_TYPES)
    tilt_max_deg: float = _f(30.0, "tilt limit of the thrust vector (deg)", gt=0, lt=80)
    accel_feedforward: bool = _f(True, "add the reference acceleration to the command")
    # defaults: IT2-FPID with the BMM reducer, the winner of `ag-uav experiment controllers`
    # (docs/controllers.md): the median of 5 BB-BC tunings of examples/tune_it2_bmm.toml
    # on the realistic loop = examples/controller_it2_bmm.toml
    xy: AxisGains = field(default_factory=AxisGains, metadata={"help": "horizontal axes"})
    z: AxisGains = field(default_factory=lambda: AxisGains(ke=3.649, kd=2.067, k0=9.117,
                                                           k1=3.59, alpha=0.7384,
                                                           cm=0.6803),
                         metadata={"help": "vertical axis"})
    attitude: AttitudeGains = field(default_factory=AttitudeGains,
                                    metadata={"help": "geometric attitude controller"})


@dataclass
class WindConfig:
    speed_mps: float = _f(3.0, "mean wind speed (m/s)", ge=0, le=25)
    direction_deg: float = _f(240.0, "direction the wind blows FROM (deg, 0 = north, clockwise)")
    turbulence: str = _f("mean", "Dryden turbulence: MIL-F-8785C W20 of 15/30/45 kt for "
                         "light/moderate/severe (a manned aircraft's design gusts: W20 of 15 kt "
                         "is a wind past the spraying limit of most labels), or \"mean\": W20 = "
                         "the mean wind speed, the intensity consistent with the configured "
                         "wind (sigma_u about 20 % of it at 3 m)",
                         choices=("none", "light", "moderate", "severe", "mean"))
    meander_deg: float = _f(10.0, "the flown wind's direction meanders about direction_deg: "
                            "a Gauss-Markov angle of this std (deg; 0 = a steady direction), "
                            "slower than the Dryden gusts (whose lateral gust already turns "
                            "the wind by about 11 deg at 3 m). 10: mid-range of the neutral "
                            "class D sigma-theta, 7.5-12.5 deg (US EPA-454/R-99-005, table "
                            "6-8)", ge=0, le=60)
    meander_tau_s: float = _f(120.0, "the meander's time constant (s): its angle decorrelates "
                              "as exp(-t/tau); 120 s, minutes as the submeso motions of the "
                              "surface layer (chosen)", gt=0, le=3600)


@dataclass
class ForecastConfig:
    """The wind the plan is made on (ag_uav.world.forecast): the lanes (mission.swath_m =
    "auto") and the crosswind heading take it; the flight takes [wind]."""

    speed_mps: float | str = _f("auto", "forecast mean wind speed (m/s), or \"auto\": the "
                                "flown wind.speed_mps plus an error drawn with std "
                                "speed_sigma_mps (clipped at 0)", ge=0, le=25,
                                choices=("auto",))
    direction_deg: float | str = _f("auto", "forecast direction the wind blows FROM (deg), "
                                    "or \"auto\": the flown wind.direction_deg plus an error "
                                    "drawn with std direction_sigma_deg", choices=("auto",))
    speed_sigma_mps: float = _f(1.5, "std of the drawn speed error (m/s; 0 = the plan knows "
                                "the flown speed). 1.5: the 10 m wind RMSE of short-range "
                                "NWP forecasts at stations, 1.5-2.3 m/s", ge=0, le=10)
    direction_sigma_deg: float = _f(30.0, "std of the drawn direction error (deg; 0 = the "
                                    "plan knows the flown direction). 30: the direction MAE of "
                                    "the same forecasts, 22-40 deg (a normal error's MAE is "
                                    "0.8 std)", ge=0, le=180)


GPS_PRESETS = ("perfect", "rtk", "sbas", "standalone", "paper-numerical", "student-t", "laplace",
               "weibull", "mixture", "alpha-stable", "coloured", "coloured-impulsive", "rtk-m350",
               "m8p-rtk-static", "m8p-standalone")
ESTIMATORS = ("true", "kf", "mckf", "pca-kf", "pca-mckf", "kf-bias", "kf-diff")


@dataclass
class GpsConfig:
    preset: str = _f("rtk-m350", "GPS error preset (see ag_uav.vehicle.gps)", choices=GPS_PRESETS)
    rate_hz: float = _f(0.0, "fix rate (Hz); 0 = the preset's", ge=0, le=100)
    multipath_prob: float = _f(0.0, "extra multipath spikes: probability per fix", ge=0, le=1)
    multipath_amplitude_m: float = _f(5.0, "extra multipath spikes: amplitude (m)", ge=0)
    r_from_fix_type: bool = _f(True, "the filters set R from the fix type the receiver "
                               "reports with each fix (RTK fixed / float / DGPS, as u-blox "
                               "UBX-NAV-PVT carrSoln and hAcc; PX4's EKF2 likewise uses the "
                               "reported accuracy); false: R stays at the preset's nominal "
                               "figure (the robust-filter premise of the core paper)")
    altitude_source: str = _f("radar", "height channel of each fix: a radar altimeter (as on "
                              "spray drones) or the GPS's own vertical", choices=("radar", "gps"))
    radar_sigma_m: float = _f(0.05, "radar altimeter noise std (m), white", gt=0)
    latency_s: float = _f(0.11, "receiver latency (s): a fix delivered at t reports the state "
                          "at t - latency_s (u-blox ZED-F9P class; PX4 EKF2_GPS_DELAY default "
                          "110 ms). estimator.nav = ins fuses it on the delayed horizon; the "
                          "ideal-attitude stand-in reads fixes without latency, as it always did",
                          ge=0, le=1)
    velocity_sigma_mps: float = _f(0.05, "estimator.nav = ins: receiver velocity noise per axis "
                                   "(m/s, white; ZED-F9P datasheet velocity accuracy 0.05 m/s)",
                                   gt=0, le=10)
    heading_sigma_deg: float = _f(0.5, "estimator.nav = ins: dual-antenna heading noise (deg, "
                                  "white; sigma_b / L for ~5 mm over a 0.6 m baseline: "
                                  "engineering judgement)", gt=0, le=30)
    radar_hz: float = _f(20.0, "estimator.nav = ins: radar altimeter rate (Hz; slant range over "
                         "flat ground, dropouts beyond 30 deg tilt)", gt=0, le=1000)
    failsafe: str = _f("land", "what the autopilot does in flight once the flown estimate's "
                       "horizontal position 1-sigma passes failsafe_sigma_m (GNSS lost): land "
                       "= descend where it is at 0.7 m/s (PX4 MPC_LAND_SPEED; ArduPilot "
                       "FS_EKF_ACTION 1); hold = hover where it is for failsafe_hold_s, then "
                       "land; off = fly on, dead reckoning. The mission is cut either way "
                       "(the reference is timed)", choices=("land", "hold", "off"))
    failsafe_sigma_m: float | str = _f("auto", "the failsafe's bound on the horizontal "
                                       "position 1-sigma (m), or \"auto\": the receiver's "
                                       "horizontal 1-sigma of one fix of its worst type "
                                       "(alpha-stable: from its scale), clipped to [1, 5] m "
                                       "(rtk-m350: 1.24 m, its DGPS; standalone: 2.04 m; "
                                       "paper-scale presets: 5 m): a filter fed fixes stays "
                                       "below one fix's error, so past it the fixes have "
                                       "stopped (PX4 COM_POS_FS_EPH is 5 m). A value above "
                                       "5 m is warned about: dead reckoning reaches it late",
                                       gt=0, le=1000, choices=("auto",))
    failsafe_hold_s: float = _f(30.0, "failsafe = hold: seconds of hover before landing",
                                ge=0, le=3600)
    receiver: str = _f("honest", "what the receiver reports with each fix (presets with fix "
                       "types only, e.g. rtk-m350): honest = the reported fix type lags the "
                       "true one, the reported accuracy carries a per-episode calibration "
                       "error, and RTK can report fixed on wrong integers (false fixes; see "
                       "docs/gnss.md); ideal = the true fix type and its exact variance",
                       choices=("honest", "ideal"))
    false_fix_per_hour: float = _f(3.0, "receiver = honest: false-fix episodes per hour of RTK "
                                   "fixed (engineering judgement, docs/gnss.md)", ge=0, le=3600)
    false_fix_mean_s: float = _f(30.0, "receiver = honest: mean false-fix duration (s; "
                                 "exponential; judgement)", gt=0, le=3600)
    false_fix_bias_m: list[float] = _f([0.1, 0.4], "receiver = honest: false-fix 3-D bias "
                                       "magnitude range (m, uniform between the two; one "
                                       "L1 cycle is 0.19 m)",
                                       ge=0, le=10, length=2)
    accuracy_calibration_sigma: float = _f(0.3, "receiver = honest: per-episode log-normal "
                                           "error of the reported accuracy (sigma of ln; 0.3 = "
                                           "x/÷1.35; judgement)", ge=0, le=3)
    fix_type_report_lag_s: float = _f(1.0, "receiver = honest: the reported fix type lags the "
                                      "true one by this (s; judgement)", ge=0, le=60)
    overrides: dict[str, Any] = _f({}, "raw overrides of the preset's keys (rate_hz, latency_s, "
                                   "axis_scale, components, outage), see ag_uav.vehicle.gps")


@dataclass
class EstimatorConfig:
    source: str = _f("gps", "what the drone localises from: GPS fixes, or bearings to four "
                     "field landmarks (GPS-denied; ag_uav.navigation.bearing)",
                     choices=("gps", "bearings"))
    name: str = _f("pca-mckf", "what the controller flies on: true state or an estimator",
                   choices=ESTIMATORS)
    nav: str = _f("ins", "navigation chain: ins = the error-state INS/GNSS filter (attitude, "
                  "biases, delayed fusion; estimators.ins) with estimator.name as its GNSS "
                  "update rule, flown on its own attitude; ideal-attitude = the idealised "
                  "stand-in (position filters driven by the true attitude x a Gauss-Markov "
                  "error, fixes without latency)", choices=("ins", "ideal-attitude"))
    ins_recovery: str = _f("kf", "nav = ins, MCKF rules: lock-out recovery after 10 rejected "
                           "fixes (none / inflate / kf; measured in docs/ins.md)",
                           choices=("none", "inflate", "kf"))
    ins_gate_sigma: float = _f(5.0, "nav = ins: innovation gate of the GNSS position, "
                               "velocity and heading, common to the four rules (PX4 "
                               "EKF2_GPS_GATE = 5): a fix fails when an axis's innovation^2 > "
                               "gate^2 x its variance; 0 = no gate", ge=0, le=100)
    ins_gate_reset_s: float = _f(5.0, "nav = ins: after this long (s) without a fused GNSS "
                                 "position or velocity (no horizontal aiding), or twice this "
                                 "long without a fused position, a fix the gate rejects resets "
                                 "the position to the receiver (PX4 EKF2's two timeouts); 0 = "
                                 "never", ge=0, le=3600)
    ins_gate_latch_s: float = _f(60.0, "nav = ins: the step latch behind the gate: a fix the "
                                 "gate rejects opens it with its innovation as a receiver step; "
                                 "later fixes that fit the step better than no step are held "
                                 "(their position not taken, fused relative to the step) until "
                                 "one does not, or for at most this long (s), after which the "
                                 "position resets to the receiver; 0 = no latch (the gate "
                                 "alone, as PX4 EKF2). A false RTK fix is such a step; measured "
                                 "with and without in docs/ins.md", ge=0, le=3600)
    ins_gnss_colour: str = _f("consider", "nav = ins: the GNSS error's Gauss-Markov part: "
                              "white = fused as white noise (R = the whole variance); inflate "
                              "= R's Gauss-Markov part times the variance of its mean over "
                              "ins_gnss_window_s (n f(n, rho), rho = exp(-dt/tau)); consider = "
                              "R = the white part, the Gauss-Markov variance added to the "
                              "position covariance the INS reports (measured in docs/ins.md)",
                              choices=("white", "inflate", "consider"))
    ins_gnss_window_s: float = _f(2.0, "nav = ins, ins_gnss_colour = inflate: the filter's "
                                  "averaging window (s) for the R inflation", gt=0, le=600)
    ins_r_source: str = _f("reported", "nav = ins: where the GNSS position R comes from: "
                           "reported = the receiver's reported accuracy (hAcc / vAcc, with "
                           "the honest receiver's calibration error), split by the configured "
                           "ins_gnss_gm_share / ins_gnss_gm_tau_s; truth = the error "
                           "generator's own white and Gauss-Markov variances (a filter that "
                           "knows the noise; measured against each other in docs/ins.md)",
                           choices=("reported", "truth"))
    ins_gnss_gm_share: float = _f(0.5, "nav = ins, ins_r_source = reported: the share of the "
                                  "reported variance taken as Gauss-Markov (considered or "
                                  "inflated by ins_gnss_colour); engineering judgement: the "
                                  "fitted u-blox M8P logs are 0.96-1.0, the illustrative "
                                  "presets 0.36-0.94 (docs/ins.md)", ge=0, le=1)
    ins_gnss_gm_tau_s: float = _f(30.0, "nav = ins, ins_r_source = reported, ins_gnss_colour "
                                  "= inflate: the Gauss-Markov part's correlation time (s) "
                                  "(engineering judgement: RTK multipath, tens of seconds)",
                                  gt=0, le=1e5)
    ins_q_accel: float = _f(1.0, "nav = ins: the filter's accelerometer white-noise variance "
                            "(incl. vibration) is [imu]'s times this margin (an autopilot's "
                            "noise parameters exceed the data sheet's: vibration, coning, model "
                            "error); calibrated in docs/ins.md", gt=0, le=100)
    ins_q_gyro: float = _f(1.0, "nav = ins: the filter's gyro white-noise variance is [imu]'s "
                           "times this margin; calibrated in docs/ins.md", gt=0, le=100)
    ins_range_aid_m: float = _f(5.0, "nav = ins: range aid (PX4 EKF2_RNG_CTRL = 1, "
                                "conditional; EKF2_RNG_A_HMAX = 5 m): while the radar reads "
                                "less than this (m) and the receiver's horizontal speed is under "
                                "ins_range_aid_mps, the fixes' height is not fused and the radar "
                                "is the height source (take-off, landing, hover); 0 = off",
                                ge=0, le=50)
    ins_range_aid_mps: float = _f(1.0, "nav = ins: the range aid's speed limit (m/s; PX4 "
                                  "EKF2_RNG_A_VMAX = 1 m/s)", gt=0, le=20)
    mckf_kernel: str = _f("fixed", "nav = ins, MCKF rules: kernel of the GNSS position update: "
                          "fixed = estimator.sigma on every row; adaptive = sigma x max(1, "
                          "sqrt(s)), s the clipped running mean of NIS/3 (estimators.mckf); "
                          "multi = sigma on the fix's 3 rows, inf on the 15 prior rows; "
                          "measured in docs/ins.md (nav = ideal-attitude refuses all but fixed)",
                          choices=("fixed", "adaptive", "multi"))
    bearing_filter: str = _f("mcc-ekf", "source = bearings: the filter flown on",
                             choices=("mcc-ekf", "ekf", "ukf"))
    bearing_noise_scale: float = _f(0.1, "source = bearings: scale of the paper's mixture "
                                    "bearing noise (1 = 5.7 deg nominal; 0.1 = 0.57 deg)", gt=0)
    shadow: list[str] = _f(["kf", "mckf", "pca-kf"], "more estimators fed the very same fixes, "
                           f"for comparison ({', '.join(ESTIMATORS[1:])})",
                           choices=ESTIMATORS[1:], unique=True)
    model: str = _f("cvb", "motion model: constant velocity, constant acceleration, or "
                    "constant velocity + IMU input bias states (estimators.models)",
                    choices=("cv", "ca", "cvb"))
    q: float | str = _f("auto", "process noise: white acceleration (cv) or jerk (ca) PSD per "
                        "axis (m^2/s^3), or \"auto\": derived from the [imu] noise figures "
                        "(ag_uav.vehicle.imu.process_noise_psd); with imu = false the model "
                        "alone must carry the manoeuvres (~2)", gt=0, choices=("auto",))
    q_bias: float | str = _f("auto", "model cvb: PSD of the input-bias random walk per axis "
                             "(m^2/s^5), or \"auto\" (from [imu])", gt=0, choices=("auto",))
    r_scale: float = _f(1.0, "R = r_scale x the GPS preset's nominal error variance per axis",
                        gt=0)
    imu: bool = _f(True, "IMU-aided prediction: the accelerometer's specific force, rotated "
                   "by the attitude estimate, drives the motion model between fixes (GPS/INS "
                   "loose coupling); see [imu]")
    sigma: float = _f(2.0, "MCKF kernel bandwidth (dimensionless, whitened residuals)", gt=0)
    mckf_recovery: str = _f("kf", "MCKF lock-out recovery (not part of Chen et al. 2017): after "
                            "10 consecutive rejected fixes, fuse one with a plain KF update "
                            "(kf), or with an inflated prior (inflate); none = the MCKF as "
                            "published", choices=("kf", "inflate", "none"))
    max_iter: int = _f(10, "MCKF fixed-point iteration cap", ge=1, le=100)
    window: int = _f(10, "PCA window N (fixes; 10 = 1 s at the rtk-m350's 10 Hz, the span of "
                     "the paper's N = 20 at 20 Hz)", ge=3, le=1000)
    pca_mode: str = _f("hankel", "PCA reading", choices=("hankel", "channels"))


@dataclass
class ImuConfig:
    """The MEMS IMU at the vehicle's ``imu`` site and the attitude estimate (see
    ag_uav.vehicle.imu).

    Defaults: TDK InvenSense ICM-42688-P class (a common flight-controller IMU): datasheet
    DS-000347 rev 1.8, Table 1-2. Residual biases are what is left after the flight controller's
    calibrations (the raw board-level tolerances are +-20 mg and +-0.5 dps)."""

    model: str = _f("mems", "mems: MuJoCo accelerometer + gyro with noise and biases, attitude "
                    "estimate with a Gauss-Markov error; ideal: the true acceleration (finite "
                    "difference of the velocity) + white noise and the true attitude",
                    choices=("mems", "ideal"))
    sampling: str = _f("increments", "increments: each sample is the mean of the "
                       "delta-velocity and delta-angle over the sample, integrated from the "
                       "physics sub-steps through the anti-alias filter, and the INS applies "
                       "coning and sculling corrections; point: the physics' reading at one "
                       "instant, held over the sample (no coning or sculling terms)",
                       choices=("increments", "point"))
    filter_hz: float = _f(116.0, "anti-alias filter: first-order low-pass, -3 dB bandwidth "
                          "(Hz) on the physics-rate readings before integration (Bosch "
                          "BMI088 gyro at its 1000 Hz output rate: 116 Hz); 0 = none", ge=0, le=1e5)
    accel_noise_density_ug: float = _f(70.0, "accelerometer noise density (ug/sqrt(Hz); "
                                       "ICM-42688-P: 70)", ge=0, le=1e5)
    gyro_noise_density_mdps: float = _f(2.8, "gyro noise density (mdps/sqrt(Hz); ICM-42688-P: "
                                        "2.8)", ge=0, le=1e5)
    vibration_sigma_mps2: float = _f(0.1, "airframe vibration left after the IMU's low-pass, "
                                     "white, per axis (m/s^2; engineering judgement, PX4's "
                                     "EKF2_ACC_NOISE of 0.35 covers vibration too); also the "
                                     "white noise of the ideal model", ge=0, le=10)
    accel_bias_mg: float = _f(5.0, "accelerometer turn-on bias, 1 sigma per axis, left after "
                              "calibration (mg; raw board-level tolerance +-20 mg)", ge=0,
                              le=200)
    accel_bias_rw: float = _f(3e-4, "accelerometer bias random walk ((m/s^2)/sqrt(s))", ge=0,
                              le=1)
    gyro_bias_dps: float = _f(0.05, "gyro turn-on bias, 1 sigma per axis, left after the "
                              "at-rest calibration (deg/s; raw tolerance +-0.5)", ge=0, le=10)
    gyro_bias_rw: float = _f(1e-3, "gyro bias random walk ((deg/s)/sqrt(s))", ge=0, le=1)
    tilt_error_deg: float = _f(0.3, "attitude estimate: roll/pitch error, 1 sigma (deg)", ge=0,
                               le=10)
    yaw_error_deg: float = _f(1.0, "attitude estimate: yaw error, 1 sigma (deg)", ge=0, le=30)
    attitude_error_tau_s: float = _f(30.0, "attitude estimate: correlation time of the "
                                     "Gauss-Markov error (s)", gt=0, le=3600)


@dataclass
class LogConfig:
    enabled: bool = _f(True, "write runs/<run-id>/run.mcap")
    channels: str = _f("full", "channel set", choices=("full", "light", "none"))
    render: bool = _f(True, "off-screen camera renders into the log")
    render_hz: float = _f(2.0, "camera frame rate in sim time (Hz)", gt=0, le=60)
    width: int = _f(320, "frame width (px)", ge=16, le=1920)
    height: int = _f(240, "frame height (px)", ge=16, le=1080)
    cameras: list[str] = _f(["chase", "down"], "cameras to render (chase, down)",
                            choices=("chase", "down"), unique=True)


@dataclass
class Config:
    seed: int = _f(0, "seed of every random draw in the run", ge=0)
    mission: MissionConfig = field(default_factory=MissionConfig,
                                   metadata={"help": "field and coverage plan"})
    vehicle: VehicleConfig = field(default_factory=VehicleConfig,
                                   metadata={"help": "airframe: preset, frame, masses"})
    sim: SimConfig = field(default_factory=SimConfig, metadata={"help": "simulation loop"})
    spray: SprayConfig = field(default_factory=SprayConfig,
                               metadata={"help": "tank, application, off-target, sorties"})
    battery: BatteryConfig = field(default_factory=BatteryConfig,
                                   metadata={"help": "battery energy (momentum theory)"})
    controller: ControllerConfig = field(default_factory=ControllerConfig,
                                         metadata={"help": "position cascade"})
    wind: WindConfig = field(default_factory=WindConfig, metadata={"help": "mean wind + Dryden"})
    forecast: ForecastConfig = field(default_factory=ForecastConfig,
                                     metadata={"help": "the wind the plan is made on"})
    gps: GpsConfig = field(default_factory=GpsConfig, metadata={"help": "GPS sensor and errors"})
    estimator: EstimatorConfig = field(default_factory=EstimatorConfig,
                                       metadata={"help": "state estimation in the loop"})
    imu: ImuConfig = field(default_factory=ImuConfig,
                           metadata={"help": "MEMS IMU and attitude estimate"})
    log: LogConfig = field(default_factory=LogConfig, metadata={"help": "MCAP log and renders"})

    def to_dict(self) -> dict[str, Any]:
        return dataclasses.asdict(self)

    def to_toml(self) -> str:
        return tomli_w.dumps(self.to_dict())
