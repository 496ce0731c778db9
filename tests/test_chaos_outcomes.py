"""Chaos: outcomes say what happened.  A vehicle that never leaves the ground is not a finished
mission; a validated GNSS latency override is flown on the INS chain; a Dask address that is not
a scheduler ends in one line, quickly; a job of several sorties exports one mission per sortie;
the tank and the coverage follow what the nozzles let out, not the command.
Short missions (seconds of sim time) and the default field."""

from __future__ import annotations

import http.server
import json
import threading
import time
from pathlib import Path

import pytest
import tomli_w

import ag_uav
from ag_uav.cli import main
from ag_uav.engine.missions import simulate


def _run(**over) -> dict:
    cfg = ag_uav.load_config(None, {"log.enabled": False, **over})
    return simulate(cfg).summary


def test_a_vehicle_that_cannot_take_off_is_incomplete():
    """vehicle.thrust_to_weight = 1.06 (at the dry mass: under 1 with the tank full)."""
    s = _run(**{"vehicle.thrust_to_weight": 1.06, "sim.max_time_s": 6.0})
    assert not s["completed"] and not s["crashed"]
    assert s["incomplete_reason"].startswith("never took off: the highest point is 0.0"), s
    assert "vehicle.thrust_to_weight = 1.06" in s["incomplete_reason"]
    assert s["mission_time_s"] is None and s["legs_flown"] == 0
    ok = _run(**{"sim.max_time_s": 6.0})  # the same cut with a vehicle that climbs
    assert not ok["incomplete_reason"].startswith("never took off")


def test_the_latency_override_is_flown_on_the_ins_chain():
    base = {"sim.max_time_s": 6.0, "estimator.nav": "ins"}
    a = _run(**base)
    b = _run(**base, **{"gps.overrides": {"latency_s": 0.9}})
    assert (a["gps_latency_s"], b["gps_latency_s"]) == (0.11, 0.9)
    assert b["estimate_rmse_m"] != a["estimate_rmse_m"]
    with pytest.raises(ag_uav.config.ConfigError, match="latency_s"):
        _run(**base, **{"gps.overrides": {"latency_s": 1.5}})


def test_the_tank_and_the_coverage_follow_the_nozzles():
    """30 s valve delays: the valve never opens in a minute of flight, so nothing leaves the
    nozzles, the tank is not drawn and nothing is covered; with the default delays the tank
    draws exactly what the nozzle model let out."""
    base = {"sim.max_time_s": 60.0, "mission.swath_m": 6.0}  # the pattern test needs a valve
    shut = _run(**base, **{"spray.nozzle_on_delay_s": 30.0, "spray.nozzle_off_delay_s": 30.0})
    assert shut["nozzle_sprayed_l"] == 0.0 and shut["litres_sprayed_l"] == 0.0
    assert shut["coverage_fraction"] == 0.0 and shut["dose_mean_l_per_ha"] in (0.0, None)
    assert shut["tank_end_l"] == 2.7
    ok = _run(**base)
    assert ok["litres_sprayed_l"] > 0.1 and ok["coverage_fraction"] > 0.05
    assert abs(ok["nozzle_minus_tank_l"]) <= 1e-9 * ok["litres_sprayed_l"]


class _Quiet(http.server.BaseHTTPRequestHandler):
    def do_GET(self):  # noqa: N802 - the http.server name
        self.send_response(200)
        self.end_headers()

    def log_message(self, *a):
        pass


def test_dask_handshake_against_an_http_port_is_one_line(tmp_path, capsys):
    srv = http.server.ThreadingHTTPServer(("127.0.0.1", 0), _Quiet)
    threading.Thread(target=srv.serve_forever, daemon=True).start()
    spec = tmp_path / "b.toml"
    spec.write_text(tomli_w.dumps({"name": "b", "base": {"sim.max_time_s": 1.0},
                                   "axes": {"seed": [0]}}))
    addr = f"tcp://127.0.0.1:{srv.server_address[1]}"
    t0 = time.monotonic()
    try:
        rc = main(["batch", str(spec), "--out", str(tmp_path / "o"), "-q", "--dask", addr,
                   "--dask-timeout", "2"])
    finally:
        srv.shutdown()
    took = time.monotonic() - t0
    err = capsys.readouterr().err.strip().splitlines()
    assert rc == 2 and len(err) == 1, err
    assert err[0].startswith(f'ag-uav: config error: --dask = "{addr}": cannot connect (the '
                             "endpoint sent nothing in 2 s"), err
    assert "not a scheduler" in err[0] and took < 15


def test_a_job_of_several_sorties_exports_one_mission_per_sortie(tmp_path, capsys):
    out = tmp_path / "job.plan"
    rc = main(["plan", "-o", str(out), "--origin", "46.73,-117.0", "--set", "spray.tank_l=0.6"])
    lines = capsys.readouterr().out.strip().splitlines()
    assert rc == 0
    n = int(lines[-1].split("the job needs ")[1].split(" sorties")[0])
    assert n >= 2 and "one mission per sortie" in lines[-1]
    files = sorted(tmp_path.glob("job-sortie*.plan"))
    assert [f.name for f in files] == [f"job-sortie{i:02d}.plan" for i in range(1, n + 1)]
    whole = json.loads(out.read_text())["mission"]["items"]
    parts = [json.loads(f.read_text())["mission"]["items"] for f in files]
    assert all(len(p) > 3 for p in parts) and sum(map(len, parts)) > len(whole)
    # one sortie: no sortie files, no line
    rc = main(["plan", "-o", str(tmp_path / "one.plan"), "--origin", "46.73,-117.0"])
    assert rc == 0 and "the job needs" not in capsys.readouterr().out
    assert not list(Path(tmp_path).glob("one-sortie*"))
