"""The spray job's loop part: the tank, mass and energy of one flight (:class:`Sprayer`). The job
itself (application, energy model, sorties) is planned before the flight by
:mod:`ag_uav.world.spray_job`, whose docstring has the physics.

:class:`Sprayer` holds one flight's setup and state, sets the liquid body's mass and inertia
(:meth:`Sprayer.set_liquid_mass`) and reports (:meth:`Sprayer.summary`, :meth:`Sprayer.series`). The
per-tick law (sortie table, nozzle gating by height, flow, tank, power, energy, state of charge,
records) is written once, in :func:`ag_uav.engine.spray_batched._spray_kernel`, which
:class:`~ag_uav.engine.spray_batched.BatchSprayer` runs over N Sprayers (one vehicle is a batch
of one). The independent reference of that tick is ``tests/oracles/sprayer_ref.py``."""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from numkit import X, Y, Z

from ..config import Config
from ..world.spray_job import SprayJob, liquid_l_per_m, rotor_power_coeff


class Sprayer:
    """Tank, mass and energy of a spray job (one object per flight; see the module docstring).

    ``cascade`` receives the composite mass and inertia (``cascade.mass``,
    ``cascade.attitude.J``) whenever the liquid mass is set; ``data`` (a ``MjData``, or
    ``None``) is kept for the per-tick reference in ``tests/oracles``, which reads the actuator
    states from it. :class:`~ag_uav.engine.spray_batched.BatchSprayer` advances it per tick."""

    def __init__(self, cfg: Config, veh, data, cascade, tab: dict[str, np.ndarray],
                 job: SprayJob, n_ticks: int, dt: float, log: Any = None,
                 nozzle_model: bool = False):
        sp, b = cfg.spray, cfg.battery
        #: the litres come from the nozzle model (valve, pressure lag; the dose map's), not
        #: from the command at once (see :meth:`BatchSprayer.draw
        #: <ag_uav.engine.spray_batched.BatchSprayer.draw>`)
        self.nozzle_model = bool(nozzle_model)
        self.cfg = cfg
        self.model = veh.model
        self.data = data
        self.cascade = cascade
        self.job = job
        self.dt = dt
        self.log = log
        self.lpm = liquid_l_per_m(cfg)
        self.rho = sp.density_kg_per_l
        self.h_min, self.h_max = sp.min_height_m, sp.max_height_m
        self.k_p = rotor_power_coeff(b.figure_of_merit, b.rotor_diameter_m, b.air_density_kgm3)
        self.p_av = b.avionics_w
        self.cap_j = b.capacity_wh * 3600.0
        self.reserve_j = self.cap_j * b.reserve_frac
        self.liq = self.model.body("liquid").id
        #: the liquid's box (half sizes, m): the tank geom's footprint (the vehicle's)
        self.tank_half = tuple(float(x) for x in self.model.geom("tank").size)
        self.drone = veh.body_id
        self.dry = float(self.model.body_subtreemass[self.drone] - self.model.body_mass[self.liq])
        self.com_dry_z = float(self.model.body_ipos[self.drone][Z])
        self.liq_z = float(self.model.body_pos[self.liq][Z])
        self.J_dry = tuple(float(v) for v in veh.ctrl_inertia)  # the controller's model
        self.unknown = veh.mass - veh.ctrl_mass  # vehicle.unknown_payload_kg: not told to it
        # the model's arrays the liquid's mass changes write (views, looked up once)
        m = self.model
        self._mass_views = (m.body_mass, m.body_inertia[self.liq], m.body_ipos[self.liq],
                            m.body_subtreemass)
        n = n_ticks
        self.ground = (np.asarray(tab["ground"], dtype=bool) if "ground" in tab
                       else np.zeros(n, dtype=bool))
        self.sortie = (np.asarray(tab["sortie"], dtype=np.int32) if "sortie" in tab
                       else np.zeros(n, dtype=np.int32))
        self.tank = job.fill_l
        self.energy_j = 0.0          # used from the current battery
        self.energy_total_j = 0.0
        self.litres_total = 0.0
        self.cur = -1
        self.mass_set = -1.0
        # per-tick records as C doubles / bytes (no Python float objects: 1.7 M ticks on 38 ha);
        # zeros that take memory only where written (a batch hands out views of its own)
        self.rec_tank = np.zeros(n)
        self.rec_mass = np.zeros(n)
        self.rec_power = np.zeros(n)
        self.rec_soc = np.zeros(n)
        self.rec_on = np.zeros(n, np.uint8)
        self.per: list[dict[str, Any]] = []
        self.gated_s = 0.0
        self.dry_s = 0.0
        #: the time the next spray log row is due (the batch sprayer moves it on)
        self.next_log = -math.inf
        #: (t, liquid kg) of every mass change in flight, when the engine captures the flight
        self.mass_events: list[tuple[float, float]] | None = None
        self.set_liquid_mass(self.tank * self.rho)

    def set_liquid_mass(self, m_liq: float) -> None:
        """Liquid body mass and inertia (a box of liquid filling the tank's footprint from the
        bottom; parallel-axis terms about the composite centre of mass go to the controller)."""
        body_mass, inertia, ipos, subtree = self._mass_views
        a, c, h = self.tank_half
        vol = self.job.tank_l if self.job.tank_l is not None else self.job.fill_l
        frac = min(1.0, m_liq / max(vol * self.rho, 1e-9))
        hz = max(h * frac, 1e-3)  # liquid half-height
        body_mass[self.liq] = max(m_liq, 1e-6)
        ml = max(m_liq, 1e-6)
        inertia[:] = (ml * ((2 * c) ** 2 + (2 * hz) ** 2) / 12,
                      ml * ((2 * a) ** 2 + (2 * hz) ** 2) / 12,
                      ml * ((2 * a) ** 2 + (2 * c) ** 2) / 12)
        ipos[Z] = -h + hz
        total = self.dry + ml
        subtree[self.liq] = ml
        subtree[self.drone] = total
        subtree[0] = total
        # controller: mass and inertia about the composite centre of mass (parallel axis)
        zl = self.liq_z - h + hz
        zc = (self.dry * self.com_dry_z + ml * zl) / total
        dz2 = self.dry * (self.com_dry_z - zc) ** 2 + ml * (zl - zc) ** 2
        Ix, Iy, Iz = self.J_dry
        li = inertia
        self.cascade.mass = total - self.unknown
        self.cascade.attitude.J = (Ix + li[X] + dz2, Iy + li[Y] + dz2, Iz + li[Z])
        self.mass_set = m_liq

    def close_sortie(self, t: float) -> None:
        """The current sortie ends at time ``t`` (its dict gets ``t_end_s``)."""
        per = self.per[-1]
        per["t_end_s"] = t

    def series(self, n: int) -> dict[str, np.ndarray]:
        """Per-tick records of the first ``n`` ticks (the ticks flown): read-only views of the
        records (a 38 ha job's four are 54 MB) and of the sortie table, the nozzle flags a copy."""
        def f(a: Any, dtype: Any = np.float64) -> np.ndarray:
            v = np.frombuffer(a, dtype=dtype, count=n)
            v.flags.writeable = False
            return v

        return {"tank_l": f(self.rec_tank), "mass_kg": f(self.rec_mass),
                "power_w": f(self.rec_power), "soc": f(self.rec_soc),
                "nozzles": np.frombuffer(self.rec_on, dtype=np.uint8, count=n).astype(bool),
                "sortie": f(self.sortie, np.int32),
                "ground": np.asarray(self.ground[:n], bool)}

    def summary(self, t_end: float) -> dict[str, Any]:
        """Summary keys: actual against planned, per sortie and in total."""
        if self.per and "t_end_s" not in self.per[-1]:
            self.per[-1]["t_end_s"] = t_end
        reserve = self.cfg.battery.reserve_frac
        rows = []
        for per, plan in zip(self.per, self.job.sorties, strict=False):
            t_off = per["t_takeoff_s"]
            t_land = per["t_land_s"] if per["t_land_s"] is not None else per["t_end_s"]
            rows.append({
                "sortie": per["sortie"],
                "t_takeoff_s": round(t_off, 2),
                "flight_time_s": round(t_land - t_off, 2),
                "litres": round(per["litres"], 4),
                "litres_planned": round(plan.litres, 4),
                "energy_wh": round(per["energy_j"] / 3600.0, 2),
                "energy_planned_wh": round(plan.energy_wh, 2),
                "min_battery_frac": round(per["min_soc"], 4),
                "below_reserve": bool(per["min_soc"] < reserve),
                "ran_dry_s": None if per["ran_dry_s"] is None else round(per["ran_dry_s"], 2),
            })
        flight = sum(r["flight_time_s"] for r in rows)
        return {
            "sorties": len(rows),
            "litres_sprayed_l": round(self.litres_total, 4),
            "energy_wh": round(self.energy_total_j / 3600.0, 2),
            "flight_time_s": round(flight, 2),
            "job_time_s": round(t_end, 2),
            "mass_start_kg": round(float(self.rec_mass[0]), 4) if len(self.rec_mass) else None,
            "mass_end_kg": round(self.dry + self.tank * self.rho, 4),
            "tank_end_l": round(self.tank, 4),
            "battery_below_reserve": any(r["below_reserve"] for r in rows),
            "tank_ran_dry": any(r["ran_dry_s"] is not None for r in rows),
            "spray_gated_by_height_s": round(self.gated_s, 2),
            "sortie_table": rows,
            **self.job.summary(),
        }
