"""The C allocator of a long scoring process: few arenas, large blocks returned to the system.

glibc's malloc gives every thread that allocates its own arena (up to eight per core) and keeps
freed memory inside them; a scorer whose threads (OpenCV's, the matcher's) allocate and free
frame-sized buffers hundreds of times then holds several times the memory it uses at any moment,
and grows with the clip's length. :func:`tune_allocator`, called once by the command line before
any work, caps the arenas and serves every block of :data:`MMAP_THRESHOLD` bytes or more straight
from the system (``mmap``), so a frame's buffers go back to it when freed. It sets the same values
in the environment, so the worker processes the command starts are tuned from their first
allocation. A value the user set in the environment (``MALLOC_ARENA_MAX``,
``MALLOC_MMAP_THRESHOLD_``, ``MALLOC_TRIM_THRESHOLD_``) is left as it is. Elsewhere than glibc it
does nothing.
"""

from __future__ import annotations

import ctypes
import ctypes.util
import os

__all__ = ["ARENAS", "MMAP_THRESHOLD", "tune_allocator"]

ARENAS = 2
"""Most malloc arenas of a tuned process."""
MMAP_THRESHOLD = 1 << 20
"""Bytes from which a block is mapped from the system (and unmapped when freed); also the trim threshold."""

_M_TRIM_THRESHOLD, _M_MMAP_THRESHOLD, _M_ARENA_MAX = -1, -3, -8  # <malloc.h>


def tune_allocator(arenas: int = ARENAS, mmap_threshold: int = MMAP_THRESHOLD) -> dict[str, int]:
    """Tune this process's allocator and its future children's (module docstring). Returns the
    settings applied here (name -> value), empty where the C library has no ``mallopt``."""
    wanted = {
        "MALLOC_ARENA_MAX": (_M_ARENA_MAX, arenas),
        "MALLOC_MMAP_THRESHOLD_": (_M_MMAP_THRESHOLD, mmap_threshold),
        "MALLOC_TRIM_THRESHOLD_": (_M_TRIM_THRESHOLD, mmap_threshold),
    }
    try:
        mallopt = ctypes.CDLL(ctypes.util.find_library("c") or "libc.so.6").mallopt
    except (OSError, AttributeError):
        return {}
    applied = {}
    for name, (param, value) in wanted.items():
        if name in os.environ:  # the user's choice (glibc read it at start)
            continue
        os.environ[name] = str(value)
        if mallopt(ctypes.c_int(param), ctypes.c_int(value)) == 1:
            applied[name] = value
    return applied
