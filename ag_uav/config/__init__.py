"""Run configuration: typed dataclasses, strict TOML loading and one-line errors.

A config is a TOML file whose tables mirror the dataclasses below. Every key is optional (defaults
are the shipped mission); an unknown key, a wrong type or a value out of range raises
:class:`ConfigError` whose message names the key, the value and what is allowed, e.g.::

    mission.swath_m = -3.0: must be >= 0.5

Numbers must be finite and within ±``FLOAT_LIMIT``; integers are TOML's 64-bit ones (a float is
no integer: ``seed = 1.5`` and ``estimator.max_iter = 1e9`` are refused). ``--set KEY=VALUE``
reads VALUE as one TOML value (else a bare string) and KEY must lead through tables of the
schema (``seed.x=1`` and ``mission=3`` are refused).

``ag-uav config`` prints the full default config with a comment per key.
"""
from .load import (
    config_from_dict,
    config_toml_with_comments,
    default_config,
    load_config,
    parse_set_items,
    toml_repr,
)
from .schema import (
    CONTROLLER_TYPES,
    ESTIMATORS,
    FLOAT_LIMIT,
    GPS_PRESETS,
    INT_MAX,
    INT_MIN,
    REDUCERS,
    AttitudeGains,
    AxisGains,
    BatteryConfig,
    Config,
    ConfigError,
    ControllerConfig,
    EstimatorConfig,
    ForecastConfig,
    GpsConfig,
    ImuConfig,
    LogConfig,
    MissionConfig,
    SimConfig,
    SprayConfig,
    VehicleConfig,
    WindConfig,
)

__all__ = [
    "CONTROLLER_TYPES", "ESTIMATORS", "FLOAT_LIMIT", "GPS_PRESETS", "INT_MAX", "INT_MIN",
    "REDUCERS", "AttitudeGains", "AxisGains", "BatteryConfig", "Config", "ConfigError",
    "ControllerConfig", "EstimatorConfig", "ForecastConfig", "GpsConfig", "ImuConfig",
    "LogConfig", "MissionConfig",
    "SimConfig", "SprayConfig", "VehicleConfig", "WindConfig", "config_from_dict",
    "parse_set_items", "load_config", "default_config", "config_toml_with_comments",
    "toml_repr",
]
