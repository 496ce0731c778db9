"""The mission's world from the config: the field (``mission.field``), the coverage plan over it
and the field's outline. (The reference flown along the plan, which needs the vehicle for the
spray job's landing height, is built by :func:`ag_uav.engine.missions.build_reference`.)"""

from __future__ import annotations

import numpy as np

from ..config import Config, ConfigError
from .field import Field, load_field
from .plan import CoveragePlan, plan_coverage


def build_field(cfg: Config) -> Field:
    try:
        return load_field(cfg.mission.field)
    except ValueError as e:
        raise ConfigError(f'mission.field = "{cfg.mission.field}": {e}') from None


def build_plan(cfg: Config, fld: Field) -> CoveragePlan:
    m = cfg.mission
    direction = None if m.direction_deg == "auto" else float(m.direction_deg)
    try:
        return plan_coverage(fld, swath=m.swath_m, headland=m.headland_m,
                             direction_deg=direction)
    except ValueError as e:
        raise ConfigError(f"mission.swath_m = {m.swath_m}: {e}") from None


def field_outline(fld: Field) -> list[np.ndarray]:
    """Closed rings of the field: every part's boundary and its holes (local metres)."""
    return [np.asarray(r) for outer, holes in fld.rings() for r in (outer, *holes)]
