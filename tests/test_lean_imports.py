"""A flight and the command line's parser leave scipy.stats and scipy.signal unimported (about
60 MB of resident memory and half a second at every start; docs/speed.md): the sensors' AR(1)
recursion, the droplet spectrum's Φ and the χ² band come from ``ag_uav.vehicle.ar1`` and
``scipy.special``."""

import json
import subprocess
import sys

HEAVY = ("scipy.stats", "scipy.signal")

SCRIPT = """
import json, sys
from ag_uav import load_config, simulate
from ag_uav.cli import build_parser
build_parser(experiments=False)
cfg = load_config(None, {"sim.max_time_s": 3.0, "log.enabled": False})
res = simulate(cfg)
print(json.dumps({m: m in sys.modules for m in %r}))
"""


def test_a_flight_imports_no_scipy_stats_or_signal():
    p = subprocess.run([sys.executable, "-c", SCRIPT % (HEAVY,)], capture_output=True,
                       text=True, timeout=600)
    assert p.returncode == 0, p.stderr[-2000:]
    loaded = json.loads(p.stdout.strip().splitlines()[-1])
    assert loaded == {m: False for m in HEAVY}
