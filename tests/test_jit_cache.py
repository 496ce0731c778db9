"""numba's cache is keyed on a kernel's own file: the packages sweep a module's kernels when any
source it imports changes (jitcache.sweep_stale_caches), so a kernel never keeps running
an old law, and an edit that no kernel reaches recompiles nothing."""

from __future__ import annotations

import os
import subprocess
import sys
import textwrap
from pathlib import Path

import pytest

from jitcache import STAMP, module_closures, sweep_stale_caches


def _fake_cache(pkg: Path) -> list[Path]:
    (pkg / "__pycache__").mkdir(parents=True, exist_ok=True)
    files = [pkg / "__pycache__" / "k.f-3.py311.nbi", pkg / "__pycache__" / "k.f-3.py311.1.nbc"]
    for f in files:
        f.write_bytes(b"x")
    return files


def test_sweep_deletes_a_modules_cache_when_a_source_it_imports_changes(tmp_path: Path) -> None:
    pkg, dep = tmp_path / "pkg", tmp_path / "dep"
    pkg.mkdir()
    dep.mkdir()
    (pkg / "k.py").write_text("from dep.law import B\n")
    (pkg / "cli.py").write_text("from . import k\n")
    (dep / "law.py").write_text("B = 1\n")
    (dep / "other.py").write_text("C = 1\n")
    files = _fake_cache(pkg)
    (pkg / "__pycache__" / "k.cpython-311.pyc").write_bytes(b"keep")
    assert sweep_stale_caches(pkg, [pkg, dep]) == 2   # no stamp yet: the cache's sources unknown
    assert not any(f.exists() for f in files)
    assert (pkg / "__pycache__" / "k.cpython-311.pyc").exists()   # Python's own cache stays
    assert (pkg / "__pycache__" / STAMP).is_file()
    files = _fake_cache(pkg)
    assert sweep_stale_caches(pkg, [pkg, dep]) == 0   # same sources: the cache is kept
    (pkg / "cli.py").write_text("from . import k\nX = 2\n")   # a module importing k changed
    (dep / "other.py").write_text("C = 2\n")                    # a file k does not import
    assert sweep_stale_caches(pkg, [pkg, dep]) == 0
    assert all(f.exists() for f in files)
    (dep / "law.py").write_text("B = 2\n")            # another package's law k imports
    assert sweep_stale_caches(pkg, [pkg, dep]) == 2
    assert not any(f.exists() for f in files)


def test_closures_follow_relative_function_local_and_parent_imports(tmp_path: Path) -> None:
    pkg = tmp_path / "pkg"
    (pkg / "sub").mkdir(parents=True)
    (pkg / "__init__.py").write_text("")
    (pkg / "sub" / "__init__.py").write_text("")
    (pkg / "sub" / "a.py").write_text("def f():\n    from ..b import g\n    return g\n")
    (pkg / "b.py").write_text("G = 1\n")
    (pkg / "c.py").write_text("H = 1\n")
    before = module_closures([pkg])
    (pkg / "b.py").write_text("G = 2\n")
    after = module_closures([pkg])
    changed = {m for m in before if before[m] != after[m]}
    assert changed == {"pkg.b", "pkg.sub.a"}
    (pkg / "__init__.py").write_text("X = 1\n")   # a parent package runs before its modules
    assert module_closures([pkg])["pkg.c"] != after["pkg.c"]


_LAW = "from controllers._jit import njit\n\n\n@njit\ndef law(x):\n    return x + {}\n"
_KERNEL = """
from pathlib import Path
from controllers._jit import njit
from jitcache import sweep_stale_caches
sweep_stale_caches(Path(__file__).parent, [Path(__file__).parent])
from .law import law


@njit
def kernel(x):
    return law(x) * 10
"""


@pytest.mark.parametrize("where", ["__pycache__", "NUMBA_CACHE_DIR"])
def test_a_kernel_follows_a_law_changed_in_another_file(tmp_path: Path, where: str) -> None:
    """The real thing: a cached kernel inlines a law from another file; the law's file alone
    changes; the next process runs the new law (numba alone would load the stale kernel), with
    the cache in the package's ``__pycache__`` or in ``$NUMBA_CACHE_DIR``."""
    pkg = tmp_path / "lawpkg"
    pkg.mkdir()
    (pkg / "__init__.py").write_text(textwrap.dedent(_KERNEL))
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(tmp_path), *sys.path])}
    env.pop("NUMBA_CACHE_DIR", None)
    cached = pkg / "__pycache__"
    if where == "NUMBA_CACHE_DIR":
        env["NUMBA_CACHE_DIR"] = str(tmp_path / "numba-cache")
        cached = tmp_path / "numba-cache"

    def run() -> str:
        out = subprocess.run([sys.executable, "-c", "import lawpkg; print(lawpkg.kernel(1))"],
                             env=env, capture_output=True, text=True, check=True)
        return out.stdout.strip()

    (pkg / "law.py").write_text(_LAW.format(1))
    assert run() == "20"
    assert list(cached.rglob("*.nbi"))   # the kernel was cached there
    (pkg / "law.py").write_text(_LAW.format(2) + "# changed\n")
    assert run() == "30"


def test_the_compile_is_said_before_the_wait(monkeypatch, capsys):
    """A kernel compiled during tick 0 prints the notice when its compile starts (once per
    process), and the tick's end says how long it took; a cached kernel says nothing."""
    from numba import njit

    from ag_uav.engine import compiling

    monkeypatch.setattr(compiling, "_announced", "")
    with compiling.compile_notice():
        @njit
        def fresh(x):
            return x + 1

        assert fresh(1) == 2
    err = capsys.readouterr().err
    assert err == compiling.COMPILE_NOTICE + "\n"
    with compiling.compile_notice():
        assert fresh(2) == 3            # compiled: no event, nothing said
        @njit
        def another(x):
            return x * 2

        another(1)                       # a second compile: said once per process
    assert capsys.readouterr().err == ""
    t0 = compiling.time.perf_counter() - 2 * compiling.COMPILE_THRESHOLD_S
    took, _ = compiling.first_tick(t0)
    assert took > compiling.COMPILE_THRESHOLD_S
    assert capsys.readouterr().err.startswith("compiled the kernels in ")
    assert compiling._announced == "done"


def test_the_progress_bar_counts_the_kernels_as_they_compile(monkeypatch, capsys):
    """With a progress bar, each kernel's compile shows in its postfix (counted and named),
    and the postfix is cleared when tick 0 is done."""
    from numba import njit

    from ag_uav.engine import compiling

    class Bar:
        mininterval = 0.0

        def __init__(self) -> None:
            self.shown: list[str] = []
            self.refreshed = 0

        def set_postfix_str(self, s: str, refresh: bool = True) -> None:
            self.shown.append(s)

        def refresh(self) -> None:
            self.refreshed += 1

    bar = Bar()
    monkeypatch.setattr(compiling, "_announced", "done")
    with compiling.compile_notice(bar):
        @njit
        def first_law(x):
            return x + 1

        @njit
        def second_law(x):
            return first_law(x) * 2

        assert second_law(1) == 4
    assert bar.shown[0].startswith("compiling kernel 1: ")
    assert any(s.endswith("second_law") for s in bar.shown)
    assert any(s.startswith("compiling kernel 2: ") for s in bar.shown)
    assert bar.shown[-1] == "" and bar.refreshed == len(bar.shown) - 1
    assert capsys.readouterr().err == ""     # the notice was said before (once per process)


def test_a_compile_before_tick_0_is_said_with_it(monkeypatch, capsys):
    """Kernels compiled before tick 0 under the notice (the INS, while the helper compiles the
    rest) count in what tick 0 says, also when tick 0 itself compiles nothing."""
    from numba import njit

    from ag_uav.engine import compiling

    monkeypatch.setattr(compiling, "_announced", "")
    monkeypatch.setattr(compiling, "_before_s", 0.0)
    with compiling.compile_notice(ahead=True):
        @njit
        def early(x):
            return x - 1

        assert early(1) == 0
    assert compiling._before_s > 0.0
    assert capsys.readouterr().err == compiling.COMPILE_NOTICE + "\n"
    took, _ = compiling.first_tick(compiling.time.perf_counter())  # tick 0 compiled nothing
    assert took == 0.0
    assert capsys.readouterr().err.startswith("compiled the kernels in ")
    assert compiling._before_s == 0.0 and compiling._announced == "done"
