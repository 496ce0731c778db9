"""The house rules (issue 12): no import cycles in ag_uav (function-local imports count), the
libraries (controllers/, estimators/) never import ag_uav or mujoco, a small top level, and the
generated picture in docs/architecture.md matches the code."""

import ast
from pathlib import Path

from ag_uav.jobs import architecture as arch

ROOT = Path(__file__).resolve().parents[1]


def test_the_import_graph_sees_function_local_and_relative_imports():
    g = arch.import_graph()
    # engine.loop imports these inside fly() only; cli imports run inside a command
    assert "ag_uav.vehicle.cascade" in g["ag_uav.engine.loop"]
    assert "ag_uav.record.render" in g["ag_uav.engine.loop"]
    assert "ag_uav.jobs.run" in g["ag_uav.cli"]
    assert "ag_uav.jobs.experiments" in g["ag_uav.jobs.experiments.outage"]  # from . import


def test_a_cycle_is_found():
    g = {"a": {"b"}, "b": {"c"}, "c": {"a"}, "d": {"a"}, "e": {"e"}}
    assert sorted(arch.cycles(g)) == [["a", "b", "c"], ["e"]]


def test_a_function_local_relative_cycle_is_found(tmp_path):
    pkg = tmp_path / "ag_uav"
    (pkg / "sub").mkdir(parents=True)
    (pkg / "__init__.py").write_text("")
    (pkg / "sub" / "__init__.py").write_text('"""a stage"""')
    (pkg / "a.py").write_text("from .sub import b\n")
    (pkg / "sub" / "b.py").write_text("def f():\n    from ..a import x\n")
    g = arch.import_graph(pkg)
    assert g["ag_uav.a"] == {"ag_uav.sub.b"} and g["ag_uav.sub.b"] == {"ag_uav.a"}
    assert arch.cycles(g) == [["ag_uav.a", "ag_uav.sub.b"]]


def test_no_import_cycles():
    found = arch.cycles(arch.import_graph())
    assert not found, "import cycles in ag_uav:\n" + "\n".join(" → ".join(c) for c in found)


def test_libraries_do_not_import_ag_uav_or_mujoco():
    bad = []
    for lib in ("controllers", "estimators"):
        for p in sorted((ROOT / lib).rglob("*.py")):
            for node in ast.walk(ast.parse(p.read_text(encoding="utf-8"))):
                if isinstance(node, ast.Import):
                    names = [a.name for a in node.names]
                elif isinstance(node, ast.ImportFrom) and not node.level:
                    names = [node.module or ""]
                else:
                    continue
                bad += [f"{p.relative_to(ROOT)}:{node.lineno} imports {n}" for n in names
                        if n.split(".")[0] in ("ag_uav", "mujoco")]
    assert not bad, "\n".join(bad)


def test_top_level_is_small_and_every_folder_is_a_stage():
    top = sorted(p.name for p in (ROOT / "ag_uav").glob("*.py"))
    assert len(top) <= 8, top
    folders = {p.name for p in (ROOT / "ag_uav").iterdir()
               if p.is_dir() and (p / "__init__.py").exists()}
    assert folders <= set(arch.STAGES), folders - set(arch.STAGES)


def test_architecture_doc_is_current():
    text = arch.DOC.read_text(encoding="utf-8")
    assert arch.render_doc(text) == text, (
        "docs/architecture.md is stale: run python -m ag_uav.jobs.architecture --write")
