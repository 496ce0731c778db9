"""The command line: bad configs give one line naming key, value and what is allowed; exit 2."""

import json
import subprocess
import sys

import pytest

from ag_uav.config import ConfigError, config_from_dict, load_config


def run_cli(*args, cwd=None):
    return subprocess.run([sys.executable, "-m", "ag_uav.cli", *args], capture_output=True,
                          text=True, cwd=cwd, timeout=300)


BOWTIE = {"type": "Polygon", "coordinates": [[[-117.0, 46.73], [-116.998, 46.731],
                                              [-116.998, 46.73], [-117.0, 46.731],
                                              [-117.0, 46.73]]]}


@pytest.mark.parametrize("toml, key, allowed", [
    ("[mission]\nswth_m = 5\n", "mission.swth_m", "unknown key"),
    ("[mission]\nswath_m = \"wide\"\n", "mission.swath_m", "expected a number"),
    ("[mission]\nswath_m = -4.0\n", "mission.swath_m", "must be >= 0.5"),
    ("[mission]\nswath_m = 400.0\n", "mission.swath_m", "wider than the field"),
    ("[controller]\ntype = \"lqr\"\n", "controller.type", "allowed: it2-fpid, t1-fpid, pid"),
    ("[wind]\nturbulence = 3\n", "wind.turbulence", "expected a string"),
    ("seed = -1\n", "seed", "must be >= 0"),
])
def test_bad_config_one_line_exit_2(tmp_path, toml, key, allowed):
    p = tmp_path / "bad.toml"
    p.write_text(toml)
    r = run_cli("fly", "--config", str(p), "--no-log", "-q", "--out", str(tmp_path))
    assert r.returncode == 2
    lines = r.stderr.strip().splitlines()
    assert len(lines) == 1, r.stderr
    assert key in lines[0] and allowed in lines[0]
    assert "Traceback" not in r.stderr


def test_self_intersecting_field_is_rejected(tmp_path):
    gj = tmp_path / "bowtie.geojson"
    gj.write_text(json.dumps(BOWTIE))
    r = run_cli("fly", "--set", f'mission.field="{gj}"', "--no-log", "-q", "--out",
                str(tmp_path))
    assert r.returncode == 2
    assert "mission.field" in r.stderr and "self-intersect" in r.stderr.lower()
    assert len(r.stderr.strip().splitlines()) == 1


def test_config_command_prints_loadable_defaults(tmp_path):
    r = run_cli("config")
    assert r.returncode == 0
    p = tmp_path / "c.toml"
    p.write_text(r.stdout)
    cfg = load_config(p)
    assert cfg == load_config(None)
    assert "# spray swath width" in r.stdout


def test_every_command_has_help():
    for cmd in ("fly", "config", "bench"):
        r = run_cli(cmd, "--help")
        assert r.returncode == 0 and "usage:" in r.stdout


def test_nested_defaults_survive_partial_tables():
    cfg = config_from_dict({"controller": {"z": {"k1": 2.0}}})
    assert cfg.controller.z.k1 == 2.0
    assert cfg.controller.z.ke == load_config(None).controller.z.ke


def test_control_rate_must_divide_physics_rate():
    with pytest.raises(ConfigError, match="sim.control_hz"):
        config_from_dict({"sim": {"control_hz": 33.0}})


def test_progress_bars_redraw_rarely_into_a_log_file(tmp_path):
    """A bar whose output is not a terminal (a batch job's log) redraws at most every 30 s:
    100 quick updates write its first and last state, not 100 lines."""
    from ag_uav._progress import PIPE_INTERVAL_S, progress_bar

    with open(tmp_path / "job.log", "w") as f:
        bar = progress_bar(file=f, total=100, desc="batch x", mininterval=0.1)
        assert bar.mininterval == PIPE_INTERVAL_S == 30.0
        for _ in range(100):
            bar.update(1)
        bar.close()
    text = (tmp_path / "job.log").read_text()
    assert text.count("batch x") <= 3 and "100/100" in text

    class Tty:  # a terminal keeps the caller's interval
        def isatty(self):
            return True

        def write(self, s):
            pass

        def flush(self):
            pass

    assert progress_bar(file=Tty(), total=3, mininterval=0.5, disable=False).mininterval == 0.5
