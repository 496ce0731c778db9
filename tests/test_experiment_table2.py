"""``ag-uav experiment table2``: the paper's setting is position-only, whatever the config's
default navigation; ``--nav ins`` flies the INS."""

from __future__ import annotations

import argparse

from ag_uav.config import load_config
from ag_uav.jobs.batch import expand
from ag_uav.jobs.experiments import table2


def _spec(tmp_path, *extra):
    p = argparse.ArgumentParser()
    table2.add_arguments(p)
    return table2.build_spec(p.parse_args(["--runs", "2", "--out", str(tmp_path), *extra]),
                             tmp_path)


def test_default_is_the_papers_position_only_setting(tmp_path):
    assert load_config(None, {}).estimator.nav == "ins"  # the config's default is not the paper's
    spec = _spec(tmp_path)
    assert spec.base["estimator"]["nav"] == "ideal-attitude"
    tasks = expand(spec)
    assert len(tasks) == 2 * len(table2.ESTIMATORS)
    spec = _spec(tmp_path, "--nav", "ins")
    assert spec.base["estimator"]["nav"] == "ins"
