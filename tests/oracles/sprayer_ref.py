"""Reference for one control tick of a spray job: the per-tick law of
:func:`ag_uav.engine.spray_batched._spray_kernel`, written out in plain Python on one
:class:`~ag_uav.engine.sprayer.Sprayer`'s state (the former ``Sprayer.step``; the product has
only the kernel). ``tests/test_batched_spray.py`` compares the two bit for bit.

Per tick ``k`` at time ``t``, from the job's tables ``sortie[k]`` and ``ground[k]``:

* a new sortie closes the last one, refills the tank (``fill_l``) and swaps the battery
  (``energy = 0``), and sets the liquid mass; a new per-sortie dict is opened;
* on the ground at the base: rotor commands 0, controller reset, landing time noted;
* nozzles on iff the plan sprays, the tank is not empty and ``h_min < z < h_max`` (else the
  time is counted as ran-dry or height-gated);
* flow ``dV = L/m · |v_xy| · dt`` (at most the tank), the liquid mass re-set when it fell by
  1 g or the tank is empty (a Sprayer without the nozzle model; with it, the litres of the
  nozzle model are drawn the same way after it);
* power ``P = P_avionics + k_P Σ a^{3/2}`` over the positive actuator states (0 on the
  ground), energy ``E += P dt``, state of charge ``1 − E / capacity``;
* the per-tick records and, every 0.1 s, ``log.spray_state``.
"""

from __future__ import annotations

import math

from ag_uav.engine.sprayer import Sprayer


def step(sp: Sprayer, k: int, t: float, pz: float, vx: float, vy: float, spray_ref: bool,
         f: list[float]) -> tuple[list[float], bool]:
    """One control tick of ``sp``: (rotor commands, nozzles on), reading the actuator states
    from ``sp.data.act`` and resetting ``sp.cascade`` on the ground."""
    s = sp.sortie[k]
    if s != sp.cur:
        if sp.cur >= 0:
            sp.close_sortie(t)
        sp.cur = s
        if s > 0:  # refilled and a fresh battery at the base
            sp.tank = sp.job.fill_l
            sp.energy_j = 0.0
            sp.set_liquid_mass(sp.tank * sp.rho)
        sp.per.append({"sortie": s + 1, "t_takeoff_s": t, "litres": 0.0, "energy_j": 0.0,
                       "min_soc": 1.0, "ran_dry_s": None, "t_land_s": None})
    if sp.ground[k]:
        sp.cascade.reset()
        f = [0.0, 0.0, 0.0, 0.0]
        per = sp.per[-1]
        if per["t_land_s"] is None:
            per["t_land_s"] = t
    on = False
    if spray_ref:
        if sp.tank <= 0.0:
            sp.dry_s += sp.dt
            if sp.per[-1]["ran_dry_s"] is None:
                sp.per[-1]["ran_dry_s"] = t
        elif sp.h_min < pz < sp.h_max:
            on = True
        else:
            sp.gated_s += sp.dt
    flow = 0.0
    if on:
        dv = sp.lpm * math.sqrt(vx * vx + vy * vy) * sp.dt
        if dv > sp.tank:
            dv = sp.tank
        sp.tank -= dv
        flow = dv / sp.dt
        sp.litres_total += dv
        sp.per[-1]["litres"] += dv
        m_liq = sp.tank * sp.rho
        if sp.mass_set - m_liq >= 1e-3 or sp.tank <= 0.0:
            sp.set_liquid_mass(m_liq)
    # electrical power of the actual rotor thrusts (actuator states after the motor lag)
    p = sp.p_av
    kp = sp.k_p
    for a in sp.data.act.tolist():
        if a > 0.0:
            p += kp * a * math.sqrt(a)
    if sp.ground[k]:
        p = 0.0  # powered down for the swap
    e = p * sp.dt
    sp.energy_j += e
    sp.energy_total_j += e
    sp.per[-1]["energy_j"] += e
    soc = 1.0 - sp.energy_j / sp.cap_j
    if soc < sp.per[-1]["min_soc"]:
        sp.per[-1]["min_soc"] = soc
    sp.rec_tank[k] = sp.tank
    sp.rec_mass[k] = sp.dry + sp.tank * sp.rho
    sp.rec_power[k] = p
    sp.rec_soc[k] = soc
    sp.rec_on[k] = on
    log = sp.log
    if log is not None and t >= sp.next_log and hasattr(log, "spray_state"):
        sp.next_log = t + 0.1 - 1e-9
        log.spray_state(t, tank_l=sp.tank, mass_kg=sp.dry + sp.tank * sp.rho,
                        flow_lps=flow,
                        nozzles=on, power_w=p, energy_wh=sp.energy_total_j / 3600.0,
                        soc=soc, sortie=s + 1, ground=sp.ground[k])
    return f, on

