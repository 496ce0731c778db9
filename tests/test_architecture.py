"""The house rules: no import cycles in ag_uav (function-local imports count), the libraries
(controllers/, estimators/) never import ag_uav or mujoco, a small top level, the generated
picture in docs/architecture.md matches the code, and product text says what is true now (no
issue or session numbers, no clock times of single runs: history belongs in git)."""

import ast
import re
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


#: product text: what a reader of the code, docs and examples sees (globs under ROOT)
PRODUCT_TEXT = ("README.md", "mkdocs.yml", "pyproject.toml", "docs/**/*.md", "ag_uav/**/*.py",
                "controllers/**/*.py", "estimators/**/*.py", "examples/**/*", "models/**/*",
                "tests/*.py")
#: left out of the history check (none)
NOT_YET: set[str] = set()
_CLOCK = r"[0-2]\d:[0-5]\d(?::[0-5]\d)?"
#: history words: "issue" or "session" and a number (any case, "-" or "#" between), a clock
#: time (or span) followed by UTC, or an ISO date with a time of day; a date alone is fine
HISTORY = re.compile(
    rf"\b(?:issues?|sessions?)[\s#-]*\d+"
    rf"|\b{_CLOCK}(?:\s*[–-]\s*{_CLOCK})?\s*(?:UTC|GMT)\b"
    rf"|\d{{4}}-\d\d-\d\dT{_CLOCK}", re.IGNORECASE)
#: in Markdown prose (outside code) any HH:MM is a clock time ("a run at 00:53 read ...")
PROSE_CLOCK = re.compile(rf"(?<![\w:.\[]){_CLOCK}(?![\w:\]])")
_MD_CODE = re.compile(r"```.*?```|`[^`\n]*`", re.DOTALL)


def _text_files(root: Path, globs=PRODUCT_TEXT):
    seen = set()
    for g in globs:
        for p in sorted(root.glob(g)):
            rel = p.relative_to(root).as_posix()
            if not p.is_file() or rel in seen or "node_modules" in p.parts \
                    or "__pycache__" in p.parts:
                continue
            seen.add(rel)
            raw = p.read_bytes()
            if b"\0" in raw:
                continue  # binary (models/crop_rows.png)
            try:
                yield rel, raw.decode("utf-8")
            except UnicodeDecodeError:
                continue


def history_in_text(root: Path = ROOT, skip=NOT_YET, globs=PRODUCT_TEXT) -> list[str]:
    """``file:line: excerpt`` for every issue or session number and clock time in product text."""
    bad = []
    for rel, text in _text_files(root, globs):
        if rel in skip:
            continue
        if rel.endswith(".md"):  # blank code (keeping line breaks) before the prose check
            prose = _MD_CODE.sub(lambda m: re.sub(r"[^\n]", " ", m.group()), text)
        for n, line in enumerate(text.splitlines(), 1):
            hits = [m.group() for m in HISTORY.finditer(line)]
            if rel.endswith(".md"):
                more = [m.group() for m in PROSE_CLOCK.finditer(prose.splitlines()[n - 1])]
                hits += [h for h in more if not any(h in x for x in hits)]
            bad += [f"{rel}:{n}: {h!r}" for h in dict.fromkeys(hits)]
    return bad


def test_the_history_check_finds_issue_and_session_numbers_and_clock_times(tmp_path):
    iss, ses = "Iss" + "ue", "sess" + "ion"  # spelt apart so this file passes its own check
    (tmp_path / "docs").mkdir()
    (tmp_path / "docs" / "a.md").write_text(
        f"ok: 2026-11-25, `x[10:13]`, 1:2\n{iss} 13 redoes it\n{iss.lower()}-17's target\n"
        f"a run at 00:53 read 1.13\n```\nt = 12:30\n```\nthe next {ses} 4\n")
    utc, iso = "08" + ":34 UTC", "2026-11-25T" + "01:28"
    (tmp_path / "m.py").write_text(f"x[10:13] = 0  # {utc}\ny = '{iso}'\n")
    (tmp_path / "skip.py").write_text(f"# {iss} 9\n")
    bad = history_in_text(tmp_path, {"skip.py"}, ("docs/*.md", "*.py"))
    assert bad == [f"docs/a.md:2: '{iss} 13'", f"docs/a.md:3: '{iss.lower()}-17'",
                   "docs/a.md:4: '00:53'", f"docs/a.md:8: '{ses} 4'", f"m.py:1: '{utc}'",
                   f"m.py:2: '{iso}'"]


def test_product_text_has_no_history():
    bad = history_in_text()
    assert not bad, ("product text says what is true now (history belongs in git); "
                     "rewrite:\n" + "\n".join(bad))
