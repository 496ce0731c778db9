"""numba's cache is keyed on a kernel's own file: the packages sweep it when any source changes
(controllers._jit.sweep_stale_caches), so a kernel never keeps running an old law."""

from __future__ import annotations

import os
import subprocess
import sys
import textwrap
from pathlib import Path

import pytest

from controllers._jit import STAMP, sweep_stale_caches


def _fake_cache(pkg: Path) -> list[Path]:
    (pkg / "__pycache__").mkdir(parents=True, exist_ok=True)
    files = [pkg / "__pycache__" / "k.f-3.py311.nbi", pkg / "__pycache__" / "k.f-3.py311.1.nbc"]
    for f in files:
        f.write_bytes(b"x")
    return files


def test_sweep_deletes_the_cache_once_per_change_of_any_source(tmp_path: Path) -> None:
    pkg, dep = tmp_path / "pkg", tmp_path / "dep"
    pkg.mkdir()
    dep.mkdir()
    (pkg / "k.py").write_text("A = 1\n")
    (dep / "law.py").write_text("B = 1\n")
    files = _fake_cache(pkg)
    (pkg / "__pycache__" / "k.cpython-311.pyc").write_bytes(b"keep")
    assert sweep_stale_caches(pkg, [pkg, dep]) == 2   # no stamp yet: the cache's sources unknown
    assert not any(f.exists() for f in files)
    assert (pkg / "__pycache__" / "k.cpython-311.pyc").exists()   # Python's own cache stays
    assert (pkg / "__pycache__" / STAMP).is_file()
    files = _fake_cache(pkg)
    assert sweep_stale_caches(pkg, [pkg, dep]) == 0   # same sources: the cache is kept
    assert all(f.exists() for f in files)
    (dep / "law.py").write_text("B = 2\n")            # another package's law changed
    assert sweep_stale_caches(pkg, [pkg, dep]) == 2
    assert not any(f.exists() for f in files)


_LAW = "from controllers._jit import njit\n\n\n@njit\ndef law(x):\n    return x + {}\n"
_KERNEL = """
from pathlib import Path
from controllers._jit import njit, sweep_stale_caches
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
