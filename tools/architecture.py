"""The house plan, read from the code: the import graph of ``ag_uav`` (static, with ``ast``:
every ``import`` and ``from … import`` of every module, function-local ones included, relative
ones resolved) and the picture of the flow in ``docs/architecture.md``.

A development tool of the repository, not part of the installed package (it reads the source
tree): ``python tools/architecture.py`` prints the generated section; ``--write`` puts it into
``docs/architecture.md`` between the markers; ``--check`` exits 1 when the doc is stale or the
graph has a cycle (``tests/test_architecture.py`` loads it and does the same).

The picture has one box per stage (a folder of ``ag_uav``, or a top-level module) listing its
modules, in :data:`STAGES` order (the flow). An arrow ``A --> B`` means "B builds on A": some
module of B imports one of A. Arrows are transitively reduced (``A --> C`` is left out when
``A --> B --> C`` is drawn); ``config`` and ``seeds``, which nearly every stage reads, get no
arrows. An import against the flow (a stage using a later one, e.g. the engine rendering camera
frames with ``record.render``) is drawn dotted from the user and listed under the picture.
"""

from __future__ import annotations

import argparse
import ast
import sys
import textwrap
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
PACKAGE = ROOT / "ag_uav"
DOC = ROOT / "docs" / "architecture.md"
BEGIN = "<!-- BEGIN GENERATED: python tools/architecture.py --write -->"
END = "<!-- END GENERATED -->"

#: the stages in flow order: top-level modules and the folders of ag_uav
STAGES = ("config", "seeds", "_jit", "_progress", "world", "vehicle", "navigation", "engine",
          "record", "analysis", "jobs", "cli")
#: stages every other one may read; no arrows are drawn for them
SHARED = ("config", "seeds", "_jit", "_progress")
#: the stage of the modules at the top level that are not stages themselves (the package)
TOP = "ag_uav"


def modules(package: Path = PACKAGE) -> dict[str, Path]:
    """Dotted module name → file, for every ``.py`` under ``package``."""
    out = {}
    for p in sorted(package.rglob("*.py")):
        rel = p.relative_to(package.parent).with_suffix("")
        parts = rel.parts[:-1] if rel.name == "__init__" else rel.parts
        out[".".join(parts)] = p
    return out


def imported_names(path: Path, module: str) -> list[tuple[str, list[str], int]]:
    """Every import statement of ``path`` (at any depth) as (absolute dotted module, the names
    a ``from`` import takes from it, line)."""
    is_pkg = path.name == "__init__.py"
    pkg = module if is_pkg else module.rpartition(".")[0]
    out = []
    for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"), str(path))):
        if isinstance(node, ast.Import):
            out += [(a.name, [], node.lineno) for a in node.names]
        elif isinstance(node, ast.ImportFrom):
            base = node.module or ""
            if node.level:
                up = pkg.split(".")
                up = up[: len(up) - node.level + 1]
                base = ".".join(up + ([base] if base else []))
            out.append((base, [a.name for a in node.names], node.lineno))
    return out


def import_graph(package: Path = PACKAGE) -> dict[str, set[str]]:
    """Module → the modules of the package it imports. ``import a.b.c`` and ``from a.b.c import
    x`` count as importing module ``a.b.c`` (the nearest enclosing module that exists), ``from
    a.b import c`` with ``c`` a module as importing ``a.b.c``; the implicit import of the parent
    packages' ``__init__`` does not count."""
    mods = modules(package)
    graph: dict[str, set[str]] = {m: set() for m in mods}

    def nearest(name: str) -> str:
        while name and name not in mods:
            name = name.rpartition(".")[0]
        return name

    for m, p in mods.items():
        for base, names, _ in imported_names(p, m):
            targets = [f"{base}.{n}" for n in names if f"{base}.{n}" in mods]
            if not names or len(targets) < len(names):
                targets.append(nearest(base))
            graph[m].update(t for t in targets if t and t != m)
    return graph


def cycles(graph: dict[str, set[str]]) -> list[list[str]]:
    """The import cycles: strongly connected components with more than one module (Tarjan),
    plus any module importing itself."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on: set[str] = set()
    out: list[list[str]] = []
    counter = [0]

    def visit(v: str) -> None:
        index[v] = low[v] = counter[0]
        counter[0] += 1
        stack.append(v)
        on.add(v)
        for w in sorted(graph[v]):
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in on:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            comp = []
            while True:
                w = stack.pop()
                on.discard(w)
                comp.append(w)
                if w == v:
                    break
            if len(comp) > 1 or v in graph[v]:
                out.append(sorted(comp))

    limit = sys.getrecursionlimit()
    sys.setrecursionlimit(max(limit, 10 * len(graph) + 100))
    try:
        for v in sorted(graph):
            if v not in index:
                visit(v)
    finally:
        sys.setrecursionlimit(limit)
    return out


def stage_of(module: str) -> str:
    parts = module.split(".")
    return parts[1] if len(parts) > 1 else TOP


def _first_sentence(path: Path) -> str:
    doc = ast.get_docstring(ast.parse(path.read_text(encoding="utf-8"))) or ""
    para = " ".join(doc.split("\n\n")[0].split())
    return para.split(". ")[0].rstrip(".") + "."


def section(package: Path = PACKAGE) -> str:
    """The generated part of docs/architecture.md (between the markers, markers excluded)."""
    mods = modules(package)
    graph = import_graph(package)
    members: dict[str, list[str]] = {s: [] for s in STAGES}
    for m in mods:
        s = stage_of(m)
        if s == TOP or m.endswith(".__main__"):
            continue
        if m.count(".") < 2:
            continue
        short = m.split(".")[2] + ("/" if m.count(".") > 2 or mods[m].name == "__init__.py"
                                   else "")
        if short not in members.setdefault(s, []):
            members[s].append(short)
    unknown = sorted(set(members) - set(STAGES))
    if unknown:
        raise ValueError(f"ag_uav/{unknown[0]}: not a stage; add it to STAGES in {__name__}")
    order = {s: i for i, s in enumerate(STAGES)}
    # stage edges: user → used, with the module pairs behind each
    uses: dict[tuple[str, str], list[str]] = {}
    for m, ts in graph.items():
        a = stage_of(m)
        for t in ts:
            b = stage_of(t)
            if a != b and TOP not in (a, b):
                uses.setdefault((a, b), []).append(f"{m[7:]} → {t[7:]}")
    forward = {(b, a) for (a, b) in uses if order[b] < order[a] and b not in SHARED}
    backward = sorted(((a, b) for (a, b) in uses if order[b] > order[a]),
                      key=lambda e: (order[e[0]], order[e[1]]))
    # transitive reduction of the forward (flow-order) edges
    succ: dict[str, set[str]] = {s: set() for s in STAGES}
    for a, b in forward:
        succ[a].add(b)

    def reachable(a: str, skip: tuple[str, str]) -> set[str]:
        seen, todo = set(), [a]
        while todo:
            x = todo.pop()
            for y in succ[x]:
                if (x, y) != skip and y not in seen:
                    seen.add(y)
                    todo.append(y)
        return seen

    drawn = sorted((e for e in forward if e[1] not in reachable(e[0], e)),
                   key=lambda e: (order[e[0]], order[e[1]]))
    lines = ["```mermaid", "flowchart LR"]
    for s in STAGES:
        if s in members and members[s]:
            body = "<br/>".join(" · ".join(members[s][i:i + 3])
                                for i in range(0, len(members[s]), 3))
            lines.append(f'    {s}["<b>{s}/</b><br/>{body}"]')
        else:
            lines.append(f'    {s}["<b>{s}.py</b>"]')
    lines += [f"    {a} --> {b}" for a, b in drawn]
    lines += [f"    {a} -.-> {b}" for a, b in backward]
    lines.append("```")
    lines.append("")
    lines.append("Arrows: `A --> B`, B builds on A (transitively reduced; every stage reads "
                 "`config`, and `seeds` gives each random consumer its stream). Dotted "
                 "`A -.-> B`: A uses B, a later stage:")
    lines.append("")
    for a, b in backward:
        lines.append(f"- {a} uses {b}: " + ", ".join(f"`{x}`" for x in sorted(uses[(a, b)])))
    lines.append("")
    lines.append("| stage | its job |")
    lines.append("|---|---|")
    for s in STAGES:
        p = package / s / "__init__.py" if (package / s).is_dir() else package / f"{s}.py"
        lines.append(f"| `{p.relative_to(package.parent).as_posix()}` | {_first_sentence(p)} |")
    n_mod = len(mods)
    n_edges = sum(len(v) for v in graph.values())
    lines.append("")
    lines.append(f"{n_mod} modules, {n_edges} imports between them, "
                 f"{len(cycles(graph))} import cycles.")
    return "\n".join(lines) + "\n"


def render_doc(text: str, package: Path = PACKAGE) -> str:
    """``text`` (the doc) with the generated section replaced."""
    head, sep, rest = text.partition(BEGIN)
    if not sep:
        raise ValueError(f"{DOC}: no {BEGIN!r} marker")
    _, sep2, tail = rest.partition(END)
    if not sep2:
        raise ValueError(f"{DOC}: no {END!r} marker")
    return f"{head}{BEGIN}\n{section(package)}{END}{tail}"


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="python tools/architecture.py",
                                 description=textwrap.dedent(__doc__ or "").split("\n\n")[0])
    g = ap.add_mutually_exclusive_group()
    g.add_argument("--write", action="store_true", help=f"rewrite the section of {DOC.name}")
    g.add_argument("--check", action="store_true", help="exit 1 if the doc is stale or a "
                   "cycle exists")
    args = ap.parse_args(argv)
    if args.write:
        DOC.write_text(render_doc(DOC.read_text(encoding="utf-8")), encoding="utf-8")
        print(f"wrote {DOC}")
        return 0
    if args.check:
        cyc = cycles(import_graph())
        text = DOC.read_text(encoding="utf-8")
        stale = render_doc(text) != text
        for c in cyc:
            print("import cycle:", " → ".join(c))
        if stale:
            print(f"{DOC} is stale: run python tools/architecture.py --write")
        return 1 if cyc or stale else 0
    sys.stdout.write(section())
    return 0


if __name__ == "__main__":
    sys.exit(main())
