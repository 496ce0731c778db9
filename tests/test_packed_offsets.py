"""No kernel module indexes a packed array with a bare integer offset ≥ 2.

Every packed array is declared once as a :class:`numkit.Layout` and indexed by name
(``x[S.QUAT:S.QUAT_END]``); a 3-vector's third component by its axis name.  The check walks
every module of the kernel folders and counts the lines where a subscript's index, a slice
bound, or a term of an index sum is an integer literal of magnitude ≥ 2 (``x[6:10]``,
``x[10 + a]``, ``r[:, -3]``; ``a.shape[2]`` and a slice's step are not offsets).

``ALLOWANCE`` would list modules not converted yet with their line counts; it is empty, and it
can only shrink.
"""

from __future__ import annotations

import ast
import pathlib

import pytest

from numkit import Layout

ROOT = pathlib.Path(__file__).resolve().parents[1]
FOLDERS = ("controllers", "estimators", "ag_uav/engine", "ag_uav/world", "ag_uav/navigation")

#: modules still indexing by bare offsets, and how many lines do
ALLOWANCE: dict[str, int] = {}


def _ints(node: ast.AST):
    if isinstance(node, ast.Constant) and type(node.value) is int:
        yield node.value
    elif isinstance(node, ast.UnaryOp) and isinstance(node.op, ast.USub):
        yield from (-v for v in _ints(node.operand))
    elif isinstance(node, ast.BinOp) and isinstance(node.op, (ast.Add, ast.Sub)):
        yield from _ints(node.left)
        yield from _ints(node.right)


def _index_parts(sl: ast.AST):
    if isinstance(sl, ast.Tuple):
        for e in sl.elts:
            yield from _index_parts(e)
    elif isinstance(sl, ast.Slice):
        yield from (b for b in (sl.lower, sl.upper) if b is not None)
    else:
        yield sl


def bare_offset_lines(source: str) -> list[int]:
    """The lines of ``source`` with a subscript indexed by a literal of magnitude ≥ 2."""
    lines = set()
    for node in ast.walk(ast.parse(source)):
        if not isinstance(node, ast.Subscript):
            continue
        if isinstance(node.value, ast.Attribute) and node.value.attr in ("shape", "strides"):
            continue
        if any(abs(v) >= 2 for p in _index_parts(node.slice) for v in _ints(p)):
            lines.add(node.lineno)
    return sorted(lines)


def _found() -> dict[str, list[int]]:
    out = {}
    for folder in FOLDERS:
        for p in sorted((ROOT / folder).rglob("*.py")):
            hits = bare_offset_lines(p.read_text(encoding="utf-8"))
            if hits:
                out[str(p.relative_to(ROOT))] = hits
    return out


def test_the_check_sees_bare_offsets():
    src = "x[6:10]\nx[10 + a]\nr[:, -3]\ny[0]\ny[1:]\nz[::2]\na.shape[2]\nx[S.QUAT]\n"
    assert bare_offset_lines(src) == [1, 2, 3]


def test_no_new_bare_offsets():
    found = _found()
    over = [f"{f}: {len(h)} lines (allowed {ALLOWANCE.get(f, 0)}), first at {h[:5]}"
            for f, h in found.items() if len(h) > ALLOWANCE.get(f, 0)]
    assert not over, "index packed arrays by their Layout's names:\n" + "\n".join(over)


def test_the_allowance_only_shrinks():
    found = _found()
    stale = [f"{f}: allowed {n}, found {len(found.get(f, []))}"
             for f, n in ALLOWANCE.items() if len(found.get(f, [])) < n]
    assert not stale, "lower the allowance to what is left:\n" + "\n".join(stale)


def test_a_layout_lays_its_fields_end_to_end():
    L = Layout("dt g r_ant:3 H:3x15")
    assert L.size == 1 + 1 + 3 + 45 == L.at.SIZE
    assert (L.at.DT, L.at.G, L.at.R_ANT, L.at.H) == (0, 1, 2, 5)
    assert (L.at.R_ANT_END, L.at.H_END) == (5, 50)
    assert L.slice("H") == slice(5, 50) and L.shape["H"] == (3, 15) and L.width["H"] == 45
    assert L.offsets == (0, 1, 2, 5)


@pytest.mark.parametrize("bad", ["a a", "a:0", "1a", "a A"])
def test_a_bad_layout_is_refused(bad):
    with pytest.raises(ValueError):
        Layout(bad)
