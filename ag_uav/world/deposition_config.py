"""The spray deposition's parameters (:class:`DepositionConfig`; sources in
:mod:`ag_uav.world.deposition`)."""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

from numkit.axes import Z

_M350_NOZZLES = ((0.3164, -0.3164, -0.15), (0.3164, 0.3164, -0.15),
                 (-0.3164, 0.3164, -0.15), (-0.3164, -0.3164, -0.15))


#: (key, low, high) of the air and tank-mix keys (Stull's wet-bulb fit holds for −20–50 °C and
#: 5–99 % RH)
_LIMITS = (("temperature_c", -20.0, 50.0), ("rh_percent", 5.0, 99.0),
           ("nonvolatile_fraction", 1e-4, 1.0), ("roughness_m", 1e-4, 2.0),
           ("wake_escape", 0.0, 1.0), ("shear_eddy_m", 1e-3, 10.0),
           ("airborne_after_s", 1.0, 1e5), ("n_classes", 1, 40),
           ("outwash_impaction_st50", 0.0, 10.0), ("jet_merge_lengths", 0.0, 100.0),
           ("rotor_arm_m", 0.0, 20.0), ("obukhov_inv_m", -1.0, 1.0),
           ("wall_jet_growth", 0.0, 1.0), ("impingement_diameters", 0.0, 10.0),
           ("vortex_life_tstar", 0.0, 100.0), ("wing_speed_vh", 0.01, 100.0),
           ("throw_speed_mps", 0.0, 300.0), ("throw_air_mps", 0.0, 100.0))


#: the hover law's options (off by default): the merged jet, the impaction cut, the outwash as a
#: radial wall jet, the impinging jet's stagnation zone, and the escape share from the one
#: calibration on the wind tunnel's 2 L rows (docs/spray_deposition.md, "A hover law")
HOVER_LAW = {"jet_merge_lengths": 2.5, "outwash_impaction_st50": 0.24, "wall_jet_growth": 0.098,
             "impingement_diameters": 1.2, "wake_escape": 0.6}
#: the rotor-wake law: the hover law and, in forward flight, the wake rolled up into a trailing
#: vortex pair (blended in by V_a / 2 v_h; the pair lives 4 t*, an assumption); docs/
#: spray_deposition.md, "The forward-flight wake"
WAKE_LAW = {**HOVER_LAW, "vortex_life_tstar": 4.0}
#: the laws ``--law`` selects in the experiments
LAWS = {"default": {}, "hover": HOVER_LAW, "wake": WAKE_LAW}


@dataclass(frozen=True)
class DepositionConfig:
    """Deposition parameters (defaults: the M350-class quad, the ``m350`` vehicle preset, one nozzle
    under each rotor). Sources in the module docstring."""

    rate_l_per_ha: float = 1.0
    swath_m: float = 6.0
    nozzle_xyz_m: tuple = _M350_NOZZLES           # body frame (m), about the body origin
    nozzle_share: tuple = (0.25, 0.25, 0.25, 0.25)
    dv10_um: float = 120.0
    dv50_um: float = 250.0
    dv90_um: float = 420.0
    n_classes: int = 10                           # tail-weighted classes (droplet_classes)
    nozzle_on_delay_s: float = 0.1                # AC_SPRAYER_DEFAULT_TURN_ON_DELAY
    nozzle_off_delay_s: float = 1.0               # AC_SPRAYER_DEFAULT_SHUT_OFF_DELAY
    cmd_off_immediate: bool = True                # AC_Sprayer::run(false) stops at once
    speed_min_mps: float = 1.0                    # AC_SPRAYER_DEFAULT_SPEED_MIN
    flow_min_l_per_s: float = 0.0                 # AC_SPRAYER_DEFAULT_PUMP_MIN = 0 %
    pressure_tau_s: float = 0.15
    rotor_diameter_m: float = 0.533
    n_rotors: int = 4
    rotor_z_m: float = 0.08                       # rotor plane above the body origin
    air_density: float = 1.225
    air_viscosity: float = 1.81e-5
    liquid_density: float = 1000.0
    jet_decay_b: float = 6.0
    rotor_arm_m: float = 0.4475                   # rotor hub from the centre (895 mm wheelbase)
    jet_merge_lengths: float = 0.0                # > 0 (2.5): merged jet beyond that many
                                                  # wheelbases (Bauersfeld); 0: rotor jets only
    wake_turbulence: float = 0.25
    outwash_layer_m: float = 0.17
    outwash_impaction_st50: float = 0.0           # > 0 (0.24): what impacts skips the outwash
    wall_jet_growth: float = 0.0                  # > 0 (0.098): the outwash a radial wall jet,
                                                  # δ = β r (Poreh et al.); 0: the layer δ
    impingement_diameters: float = 0.0            # > 0 (1.2): the jet stagnates over that many
                                                  # merged-jet diameters above the ground
    vortex_life_tstar: float = 0.0                # > 0: in forward flight the wake rolls up
                                                  # into a trailing vortex pair that carries
                                                  # droplets outward for this many t* (wake.py)
    wing_speed_vh: float = 2.0                    # the pair takes the whole wake from V_a =
                                                  # this × v_h on (Leishman: 2), blended below
    release_sigma_m: float = 0.1
    throw_speed_mps: float = 0.0                  # > 0: a rotary atomiser's rim speed ωR, the
                                                  # droplets thrown to a ring (atomiser.py)
    throw_air_mps: float = 0.0                    # the downwash's speed where they are thrown
    ambient_sigma_mps: float = 0.0
    temperature_c: float = 20.0                   # air temperature (°C)
    rh_percent: float = 60.0                      # relative humidity (%)
    nonvolatile_fraction: float = 0.05            # volume share of the mix that never evaporates
    roughness_m: float = 0.05                     # z0 of the log-law wind profile (m)
    obukhov_inv_m: float = 0.0                    # 1/L (1/m): 0 neutral, > 0 stable, < 0 unstable
    wake_escape: float = 0.3                      # ε₀: share of the sheet at the wake's edge
    shear_eddy_m: float = 0.05                    # eddy length of the wake's shear layer (m)
    airborne_after_s: float = 600.0               # still aloft after this: counted airborne
    cell_m: float = 0.5
    buffer_m: float = 10.0
    max_cells: int = 4_000_000
    flush_cells: float = 2.0
    flush_ticks: int = 50
    levels: int = 6
    merge_ratio: float = 2.0
    extra: dict = field(default_factory=dict)

    def __post_init__(self) -> None:
        for key, lo, hi in _LIMITS:
            v = getattr(self, key)
            if not lo <= v <= hi:
                raise ValueError(f"{key} = {v}: must be within [{lo:g}, {hi:g}]")

    @classmethod
    def from_config(cls, cfg: Any, **over: Any) -> DepositionConfig:
        """From the product's :class:`ag_uav.config.Config`: rate, swath, rotor diameter, air and
        liquid density; any ``[spray]`` key that names a field here overrides it."""
        kw: dict[str, Any] = {
            "rate_l_per_ha": cfg.spray.rate_l_per_ha, "swath_m": cfg.mission.swath_m,
            "rotor_diameter_m": cfg.battery.rotor_diameter_m,
            "air_density": cfg.battery.air_density_kgm3,
            "liquid_density": 1000.0 * cfg.spray.density_kg_per_l,
            "rotor_arm_m": cfg.vehicle.arm_m}
        names = set(cls.__dataclass_fields__)
        for k, v in vars(cfg.spray).items():
            if k in names and k not in kw:
                kw[k] = tuple(v) if isinstance(v, list) else v
        xyz = kw.get("nozzle_xyz_m")
        if xyz is not None and xyz and not isinstance(xyz[0], tuple | list):  # flat x, y, z, ..
            n = Z + 1  # x, y, z per nozzle
            kw["nozzle_xyz_m"] = tuple(tuple(xyz[i:i + n]) for i in range(0, len(xyz), n))
        if kw.get("nozzle_share") == ():  # [] in the config: equal shares
            m = len(kw.get("nozzle_xyz_m", _M350_NOZZLES))
            kw["nozzle_share"] = tuple([1.0 / m] * m)
        kw.update(_rotary(cfg, kw))
        kw.update(LAWS[getattr(cfg.spray, "deposition_law", "default")])
        kw.update(over)
        return cls(**kw)


def _rotary(cfg: Any, kw: dict[str, Any]) -> dict[str, Any]:
    """A rotary atomiser's keys (``vehicle.sprayer = "rotary"`` with ``atomiser_rpm`` > 0;
    else none): the spectrum with its VMD from the disc speed (Dv10, Dv90 scaled with it), the
    throw's rim speed ωR and the air's downward speed there, the hover induced velocity
    v_h = sqrt(m g / (2 ρ A)) at the take-off mass with a full tank (A the rotor discs'
    area; :mod:`ag_uav.world.atomiser`)."""
    v = getattr(cfg, "vehicle", None)
    if v is None or getattr(v, "sprayer", "hydraulic") != "rotary" or v.atomiser_rpm <= 0:
        return {}
    from .atomiser import disc_vmd_m, rotary_spectrum, tip_speed_mps

    sp = cfg.spray
    vmd = 1e6 * disc_vmd_m(v.atomiser_rpm, v.atomiser_radius_m, sp.surface_tension_n_m,
                           kw["liquid_density"])
    d10, d50, d90 = rotary_spectrum(sp.dv10_um, sp.dv50_um, sp.dv90_um, vmd)
    mass = v.mass_kg + v.payload_kg + sp.tank_l * sp.density_kg_per_l
    area = kw.get("n_rotors", 4) * math.pi * kw["rotor_diameter_m"] ** 2 / 4.0
    vh = math.sqrt(mass * 9.81 / (2.0 * kw["air_density"] * area))
    return {"dv10_um": d10, "dv50_um": d50, "dv90_um": d90,
            "throw_speed_mps": tip_speed_mps(v.atomiser_rpm, v.atomiser_radius_m),
            "throw_air_mps": vh}
