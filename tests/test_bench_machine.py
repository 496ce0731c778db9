"""``ag-uav bench``'s ``machine`` section: what the figures were measured on."""

from __future__ import annotations

import math
import os
import platform

import mujoco
import numba

from ag_uav.jobs.bench.suite import machine_facts, print_bench, python_loop_ns


def test_the_machine_section_names_the_cpu_cores_versions_and_python_speed():
    m = machine_facts()
    assert m["cpu"] and m["llvm_cpu"]
    assert m["cores"] == len(os.sched_getaffinity(0))
    assert (m["python"], m["numba"], m["mujoco"]) == (platform.python_version(),
                                                      numba.__version__, mujoco.__version__)
    assert math.isfinite(m["python_loop_ns"]) and 1.0 < m["python_loop_ns"] < 5000.0


def test_the_python_loop_figure_is_per_iteration():
    """A loop ten times longer takes about ten times as long: the figure stays per iteration."""
    short, long_ = python_loop_ns(20_000, 5), python_loop_ns(200_000, 5)
    assert 0.3 < long_ / short < 3.0


def test_the_machine_section_prints_as_rows(capsys):
    print_bench({"machine": {"cpu": "X", "cores": 2, "python_loop_ns": 40.0}})
    out = capsys.readouterr().out
    assert "machine.cpu" in out and "machine.python_loop_ns" in out
