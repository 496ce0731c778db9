"""The engine's heap trim (ag_uav.engine.heap) binds glibc's malloc_trim where there is one."""

import platform

from ag_uav.engine import heap


def test_trim_heap_binds_malloc_trim_on_glibc():
    done = heap.trim_heap()
    if platform.system() == "Linux" and platform.libc_ver()[0] == "glibc":
        assert done is True
    else:  # pragma: no cover - other C libraries
        assert done is False
