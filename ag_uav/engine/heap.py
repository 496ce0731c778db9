"""Give freed heap memory back to the system between a run's phases.

Planning a long job builds and drops arrays of tens of MB (a whole plan's reference, its
temporaries). glibc's allocator serves arrays below its mmap threshold (which it raises up to
32 MB as large blocks are freed) from the heap and keeps their pages when they are freed, so a
process that planned a 38 ha job carried ~50 MB of freed pages through its whole flight.
:func:`trim_heap` asks glibc to return them (``malloc_trim(0)``: free pages anywhere in the
heap, not only at its top); it changes no value and costs milliseconds. Where the C library
is not glibc it does nothing."""

from __future__ import annotations

import ctypes
import ctypes.util

__all__ = ["trim_heap"]


def _malloc_trim():
    try:
        libc = ctypes.CDLL(ctypes.util.find_library("c") or "libc.so.6")
        f = libc.malloc_trim
    except (OSError, AttributeError):  # not glibc (macOS, musl, Windows)
        return None
    f.argtypes, f.restype = [ctypes.c_size_t], ctypes.c_int
    return f


_TRIM = _malloc_trim()


def trim_heap() -> bool:
    """Return the heap's free pages to the system; False where there is no ``malloc_trim``."""
    if _TRIM is None:
        return False
    _TRIM(0)
    return True
