"""Run configuration: typed dataclasses, strict TOML loading and one-line errors.

A config is a TOML file whose tables mirror the dataclasses below. Every key is optional (defaults
are the shipped mission); an unknown key, a wrong type or a value out of range raises
:class:`ConfigError` whose message names the key, the value and what is allowed, e.g.::

    mission.swath_m = -3.0: must be > 0

``ag-uav config`` prints the full default config with a comment per key.
"""

from __future__ import annotations

import dataclasses
import math
import tomllib
import types
import typing
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import tomli_w


class ConfigError(ValueError):
    """A bad config value. The message is one line: ``key = value: what is allowed``."""


def _f(default: Any, help: str, *, gt: float | None = None, ge: float | None = None,
       le: float | None = None, lt: float | None = None, choices: tuple | None = None,
       length: int | None = None) -> Any:
    meta = {"help": help, "gt": gt, "ge": ge, "le": le, "lt": lt, "choices": choices,
            "length": length}
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
    field: str = _f("default", "built-in field name (default, l-shape, hole) or path to a "
                    "GeoJSON polygon in lon/lat")
    swath_m: float = _f(6.0, "spray swath width (m)", gt=0)
    headland_m: float = _f(6.0, "headland margin swept by laps along the boundary (m); 0 = none",
                           ge=0)
    direction_deg: float | str = _f("auto", "sweep direction in degrees from east "
                                    "(counter-clockwise), or \"auto\" (fewest turns)")
    speed_mps: float = _f(5.0, "cruise ground speed on legs (m/s)", gt=0, le=15)
    altitude_m: float = _f(3.0, "spray altitude above ground (m)", gt=0.5, le=50)
    accel_max_mps2: float = _f(1.5, "acceleration bound of the reference (m/s^2)", gt=0, le=8)


@dataclass
class VehicleConfig:
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


@dataclass
class SimConfig:
    timestep_s: float = _f(0.002, "MuJoCo physics step (s)", gt=0, le=0.01)
    control_hz: float = _f(100.0, "control rate (Hz); must divide the physics rate", gt=0,
                           le=1000)
    max_time_s: float = _f(1800.0, "hard cap on simulated time (s)", gt=0)
    hover_after_s: float = _f(3.0, "hover time at the end of the path (s)", ge=0)
    takeoff: bool = _f(True, "start on the ground and climb to spray altitude")


@dataclass
class AxisGains:
    """Gains of one position-axis controller (the keys used depend on ``controller.type``)."""

    ke: float = _f(1.151, "IT2/T1-FPID: error scaling Ke (1/m)", gt=0)
    kd: float = _f(1.103, "IT2/T1-FPID: error-rate scaling Kd (s/m)", gt=0)
    k0: float = _f(5.465, "IT2/T1-FPID: PD-part output gain K0 (m/s^2)", ge=0)
    k1: float = _f(2.943, "IT2/T1-FPID: PI-part output gain K1 (m/s^3)", ge=0)
    alpha: float = _f(0.4638, "IT2-FPID: lower-MF height parameter (h_Z = alpha, h_N = h_P = "
                      "1 - alpha)", gt=0, le=1)
    zeta: float = _f(0.5, "IT2-FPID: weight of the zeta type reducer", ge=0, le=1)
    cm: float = _f(0.6447, "FPID: consequent of the off-diagonal rules", gt=0, le=1)
    reducer: str = _f("km", "IT2-FPID type reducer", choices=REDUCERS)
    kp: float = _f(2.2, "PID: proportional gain (1/s^2)", ge=0)
    ki: float = _f(0.3, "PID: integral gain (1/s^3)", ge=0)
    kdd: float = _f(2.4, "PID: derivative gain (1/s)", ge=0)
    i_limit: float = _f(2.0, "anti-windup: bound of the integral contribution (m/s^2)", gt=0)


@dataclass
class AttitudeGains:
    wn: list[float] = _f([9.0, 9.0, 3.0], "attitude loop natural frequency roll, pitch, yaw "
                         "(rad/s)", gt=0, length=3)
    zeta: list[float] = _f([0.9, 0.9, 0.9], "attitude loop damping ratio roll, pitch, yaw",
                           gt=0, length=3)


@dataclass
class ControllerConfig:
    type: str = _f("it2-fpid", "position controller", choices=CONTROLLER_TYPES)
    tilt_max_deg: float = _f(30.0, "tilt limit of the thrust vector (deg)", gt=0, lt=80)
    accel_feedforward: bool = _f(True, "add the reference acceleration to the command")
    # defaults: BB-BC tuned (examples/tune_default.toml: ITAE on 1 m steps with a soft 5 %
    # overshoot bound + the first 35 s of the default mission, 30 x 40, seed 1; gains, alpha, c_m)
    xy: AxisGains = field(default_factory=AxisGains, metadata={"help": "horizontal axes"})
    z: AxisGains = field(default_factory=lambda: AxisGains(ke=2.188, kd=1.317, k0=7.983,
                                                           k1=3.342, alpha=0.6106,
                                                           cm=0.6388),
                         metadata={"help": "vertical axis"})
    attitude: AttitudeGains = field(default_factory=AttitudeGains,
                                    metadata={"help": "geometric attitude controller"})


@dataclass
class WindConfig:
    speed_mps: float = _f(3.0, "mean wind speed (m/s)", ge=0, le=25)
    direction_deg: float = _f(240.0, "direction the wind blows FROM (deg, 0 = north, clockwise)")
    turbulence: str = _f("light", "Dryden turbulence: MIL-F-8785C W20 of 15/30/45 kt for "
                         "light/moderate/severe, or \"mean\" (W20 = the mean wind speed)",
                         choices=("none", "light", "moderate", "severe", "mean"))


GPS_PRESETS = ("perfect", "rtk", "sbas", "standalone", "paper-numerical", "student-t", "laplace",
               "weibull", "mixture", "alpha-stable", "coloured", "coloured-impulsive")
ESTIMATORS = ("true", "kf", "mckf", "pca-kf", "pca-mckf", "kf-bias", "kf-diff")


@dataclass
class GpsConfig:
    preset: str = _f("perfect", "GPS error preset (see ag_uav.gps)", choices=GPS_PRESETS)
    rate_hz: float = _f(0.0, "fix rate (Hz); 0 = the preset's", ge=0, le=100)
    multipath_prob: float = _f(0.0, "extra multipath spikes: probability per fix", ge=0, le=1)
    multipath_amplitude_m: float = _f(5.0, "extra multipath spikes: amplitude (m)", ge=0)
    altitude_source: str = _f("radar", "height channel of each fix: a radar altimeter (as on "
                              "spray drones) or the GPS's own vertical", choices=("radar", "gps"))
    radar_sigma_m: float = _f(0.05, "radar altimeter noise std (m), white", gt=0)
    overrides: dict[str, Any] = _f({}, "raw overrides of the preset's keys (rate_hz, latency_s, "
                                   "axis_scale, components, outage), see ag_uav.gps")


@dataclass
class EstimatorConfig:
    source: str = _f("gps", "what the drone localises from: GPS fixes, or bearings to four "
                     "field landmarks (GPS-denied; ag_uav.bearing)", choices=("gps", "bearings"))
    name: str = _f("true", "what the controller flies on: true state or an estimator",
                   choices=ESTIMATORS)
    bearing_filter: str = _f("mcc-ekf", "source = bearings: the filter flown on",
                             choices=("mcc-ekf", "ekf", "ukf"))
    bearing_noise_scale: float = _f(0.1, "source = bearings: scale of the paper's mixture "
                                    "bearing noise (1 = 5.7 deg nominal; 0.1 = 0.57 deg)", gt=0)
    shadow: list[str] = _f([], "more estimators fed the very same fixes, for comparison "
                           f"({', '.join(ESTIMATORS[1:])})")
    model: str = _f("cv", "motion model: constant velocity or constant acceleration",
                    choices=("cv", "ca"))
    q: float = _f(0.05, "process noise: white acceleration (cv) or jerk (ca) PSD per axis "
                  "(m^2/s^3); with imu = false the model alone must carry the manoeuvres (~2)",
                  gt=0)
    r_scale: float = _f(1.0, "R = r_scale x the GPS preset's nominal error variance per axis",
                        gt=0)
    imu: bool = _f(True, "accelerometer-aided prediction: the measured acceleration drives "
                   "the motion model between fixes (GPS/INS loose coupling)")
    imu_sigma_mps2: float = _f(0.1, "accelerometer white noise std per axis (m/s^2)", ge=0)
    sigma: float = _f(2.0, "MCKF kernel bandwidth (dimensionless, whitened residuals)", gt=0)
    max_iter: int = _f(10, "MCKF fixed-point iteration cap", ge=1, le=100)
    window: int = _f(20, "PCA window N (fixes)", ge=3, le=1000)
    pca_mode: str = _f("hankel", "PCA reading", choices=("hankel", "channels"))


@dataclass
class LogConfig:
    enabled: bool = _f(True, "write runs/<run-id>/run.mcap")
    channels: str = _f("full", "channel set", choices=("full", "light", "none"))
    render: bool = _f(True, "off-screen camera renders into the log")
    render_hz: float = _f(2.0, "camera frame rate in sim time (Hz)", gt=0, le=60)
    width: int = _f(320, "frame width (px)", ge=16, le=1920)
    height: int = _f(240, "frame height (px)", ge=16, le=1080)
    cameras: list[str] = _f(["chase", "down"], "cameras to render (chase, down)")


@dataclass
class Config:
    seed: int = _f(0, "seed of every random draw in the run", ge=0)
    mission: MissionConfig = field(default_factory=MissionConfig,
                                   metadata={"help": "field and coverage plan"})
    vehicle: VehicleConfig = field(default_factory=VehicleConfig,
                                   metadata={"help": "M350-class quadrotor"})
    sim: SimConfig = field(default_factory=SimConfig, metadata={"help": "simulation loop"})
    controller: ControllerConfig = field(default_factory=ControllerConfig,
                                         metadata={"help": "position cascade"})
    wind: WindConfig = field(default_factory=WindConfig, metadata={"help": "mean wind + Dryden"})
    gps: GpsConfig = field(default_factory=GpsConfig, metadata={"help": "GPS sensor and errors"})
    estimator: EstimatorConfig = field(default_factory=EstimatorConfig,
                                       metadata={"help": "state estimation in the loop"})
    log: LogConfig = field(default_factory=LogConfig, metadata={"help": "MCAP log and renders"})

    def to_dict(self) -> dict[str, Any]:
        return dataclasses.asdict(self)

    def to_toml(self) -> str:
        return tomli_w.dumps(self.to_dict())


# ------------------------------------------------------------------------------------ parsing
def _type_name(tp: Any) -> str:
    origin = typing.get_origin(tp)
    if origin in (typing.Union, types.UnionType):
        return " or ".join(_type_name(a) for a in typing.get_args(tp))
    if origin is list:
        return f"list of {_type_name(typing.get_args(tp)[0])}"
    return {float: "number", int: "integer", str: "string", bool: "true/false"}.get(tp, str(tp))


def _fmt(v: Any) -> str:
    if isinstance(v, str):
        return f'"{v}"'
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, dict):
        return "{...}"
    return repr(v)


def _coerce(tp: Any, v: Any, key: str) -> Any:
    origin = typing.get_origin(tp)
    if origin in (typing.Union, types.UnionType):
        for a in typing.get_args(tp):
            try:
                return _coerce(a, v, key)
            except ConfigError:
                continue
        raise ConfigError(f"{key} = {_fmt(v)}: expected {_type_name(tp)}")
    if origin is list:
        (inner,) = typing.get_args(tp)
        if not isinstance(v, list):
            raise ConfigError(f"{key} = {_fmt(v)}: expected {_type_name(tp)}")
        return [_coerce(inner, x, f"{key}[{i}]") for i, x in enumerate(v)]
    if tp is float:
        if isinstance(v, bool) or not isinstance(v, int | float):
            raise ConfigError(f"{key} = {_fmt(v)}: expected a number")
        if not math.isfinite(v):
            raise ConfigError(f"{key} = {_fmt(v)}: expected a finite number")
        return float(v)
    if tp is int:
        if isinstance(v, bool) or not isinstance(v, int):
            raise ConfigError(f"{key} = {_fmt(v)}: expected an integer")
        return v
    if tp is bool:
        if not isinstance(v, bool):
            raise ConfigError(f"{key} = {_fmt(v)}: expected true or false")
        return v
    if tp is dict or typing.get_origin(tp) is dict:
        if not isinstance(v, dict):
            raise ConfigError(f"{key} = {_fmt(v)}: expected a table")
        return v
    if tp is str:
        if not isinstance(v, str):
            raise ConfigError(f"{key} = {_fmt(v)}: expected a string")
        return v
    raise TypeError(tp)


def _check_range(meta: dict, v: Any, key: str) -> None:
    vals = v if isinstance(v, list) else [v]
    if meta.get("length") is not None and isinstance(v, list) and len(v) != meta["length"]:
        raise ConfigError(f"{key} = {_fmt(v)}: expected a list of {meta['length']} values")
    for x in vals:
        if isinstance(x, str):
            ch = meta.get("choices")
            if ch and x not in ch:
                raise ConfigError(f"{key} = {_fmt(x)}: allowed: {', '.join(ch)}")
            continue
        if isinstance(x, bool):
            continue
        for op, bound, ok in (("gt", ">", lambda a, b: a > b), ("ge", ">=", lambda a, b: a >= b),
                              ("lt", "<", lambda a, b: a < b), ("le", "<=", lambda a, b: a <= b)):
            b = meta.get(op)
            if b is not None and not ok(x, b):
                raise ConfigError(f"{key} = {_fmt(x)}: must be {bound} {b}")


def _build(cls: type, data: Any, prefix: str, base: Any = None) -> Any:
    """Dataclass ``cls`` from ``data``, starting from ``base`` (default: ``cls()``)."""
    if not isinstance(data, dict):
        raise ConfigError(f"{prefix or 'config'} = {_fmt(data)}: expected a table")
    hints = typing.get_type_hints(cls)
    fields = {f.name: f for f in dataclasses.fields(cls)}
    unknown = [k for k in data if k not in fields]
    if unknown:
        k = unknown[0]
        where = f"{prefix}.{k}" if prefix else k
        raise ConfigError(f"{where} = {_fmt(data[k])}: unknown key; allowed in "
                          f"[{prefix or 'top level'}]: {', '.join(fields)}")
    base_obj = base if base is not None else cls()
    kwargs = {}
    for name, value in data.items():
        key = f"{prefix}.{name}" if prefix else name
        tp = hints[name]
        if dataclasses.is_dataclass(tp):
            kwargs[name] = _build(tp, value, key, base=getattr(base_obj, name))
        else:
            v = _coerce(tp, value, key)
            _check_range(fields[name].metadata, v, key)
            kwargs[name] = v
    return dataclasses.replace(base_obj, **kwargs)


def _validate(cfg: Config) -> None:
    d = cfg.mission.direction_deg
    if isinstance(d, str) and d != "auto":
        raise ConfigError(f'mission.direction_deg = "{d}": expected a number or "auto"')
    steps = 1.0 / (cfg.sim.timestep_s * cfg.sim.control_hz)
    if abs(steps - round(steps)) > 1e-6 or round(steps) < 1:
        raise ConfigError(f"sim.control_hz = {cfg.sim.control_hz}: must divide the physics rate "
                          f"1/timestep_s = {1.0 / cfg.sim.timestep_s:g} Hz")
    for name in cfg.estimator.shadow:
        if name not in ESTIMATORS[1:]:
            raise ConfigError(f'estimator.shadow = "{name}": allowed: {", ".join(ESTIMATORS[1:])}')
    for cam in cfg.log.cameras:
        if cam not in ("chase", "down"):
            raise ConfigError(f'log.cameras = "{cam}": allowed: chase, down')


def config_from_dict(data: dict[str, Any]) -> Config:
    """Build and validate a :class:`Config` from a (TOML-shaped) dict."""
    cfg = _build(Config, data, "")
    _validate(cfg)
    return cfg


def parse_set_items(items: list[str]) -> dict[str, Any]:
    """``["wind.speed_mps=5", ...]`` (``--set`` arguments) -> dotted-key overrides; the value is
    read as TOML, or kept as a bare string."""
    out: dict[str, Any] = {}
    for item in items:
        if "=" not in item:
            raise ConfigError(f'--set "{item}": expected KEY=VALUE')
        k, v = item.split("=", 1)
        try:
            out[k.strip()] = tomllib.loads(f"v = {v}")["v"]
        except tomllib.TOMLDecodeError:
            out[k.strip()] = v  # a bare string
    return out


def load_config(path: str | Path | None = None, overrides: dict[str, Any] | None = None) -> Config:
    """Load a TOML config file (``None`` = defaults) and apply dotted-key ``overrides``."""
    data: dict[str, Any] = {}
    if path is not None:
        p = Path(path)
        if not p.is_file():
            raise ConfigError(f"config file = {_fmt(str(p))}: no such file")
        try:
            data = tomllib.loads(p.read_text())
        except tomllib.TOMLDecodeError as e:
            raise ConfigError(f"config file = {_fmt(str(p))}: not valid TOML ({e})") from None
    for k, v in (overrides or {}).items():
        node = data
        parts = k.split(".")
        for part in parts[:-1]:
            node = node.setdefault(part, {})
        node[parts[-1]] = v
    return config_from_dict(data)


def default_config() -> Config:
    return Config()


def _toml_value(v: Any) -> str:
    if isinstance(v, dict):
        if not v:
            return "{}"
        return "{ " + ", ".join(f"{k} = {_toml_value(x)}" for k, x in v.items()) + " }"
    if isinstance(v, list):
        return "[" + ", ".join(_toml_value(x) for x in v) + "]"
    return tomli_w.dumps({"k": v}).strip()[4:]


def config_toml_with_comments(cfg: Config | None = None) -> str:
    """The config as TOML with a comment per key (what ``ag-uav config`` prints)."""
    cfg = cfg or Config()
    lines: list[str] = ["# ag-uav run configuration (every key optional; these are the defaults)"]

    def emit(obj: Any, prefix: str) -> None:
        subs = []
        for f in dataclasses.fields(obj):
            v = getattr(obj, f.name)
            if dataclasses.is_dataclass(v):
                subs.append((f, v))
                continue
            help_ = f.metadata.get("help", "")
            ch = f.metadata.get("choices")
            if ch:
                help_ += f" [{' | '.join(ch)}]"
            lines.append(f"# {help_}")
            lines.append(f"{f.name} = {_toml_value(v)}")
        for f, v in subs:
            name = f"{prefix}.{f.name}" if prefix else f.name
            lines.append("")
            lines.append(f"[{name}]  # {f.metadata.get('help', '')}")
            emit(v, name)

    emit(cfg, "")
    return "\n".join(lines) + "\n"
