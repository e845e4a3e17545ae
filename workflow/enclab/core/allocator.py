"""Let a job process keep the memory it frees, so numpy's large temporaries are reused.

glibc hands every freed block above its mmap threshold back to the operating system and trims
the top of the heap once enough of it is free. The LRDE likelihood allocates and frees arrays of
about half a megabyte thousands of times a second; with the default settings each one comes
back as fresh pages, faulted in and zeroed one by one (about 7 million page faults and 40 % of
the wall time of the embedded closed-loop log's LRDE stage). Raising both thresholds keeps
those blocks in the process. Results do not change: only where the memory comes from.
"""
from __future__ import annotations

import ctypes
import ctypes.util

__all__ = ["keep_freed_memory"]

_M_TRIM_THRESHOLD = -1
_M_MMAP_THRESHOLD = -3
_MMAP_THRESHOLD = 64 << 20
_TRIM_THRESHOLD = 256 << 20
_done = False


def keep_freed_memory() -> bool:
    """Raise glibc's mmap and trim thresholds for this process (once); ``False`` elsewhere.

    Both are needed: a fixed mmap threshold alone still trims the heap, and a trim threshold
    alone still maps the large blocks. The process keeps at most ``_TRIM_THRESHOLD`` bytes
    of freed heap.
    """
    global _done
    if _done:
        return True
    name = ctypes.util.find_library("c")
    try:
        libc = ctypes.CDLL(name)
        mallopt = libc.mallopt
    except (OSError, AttributeError, TypeError):
        return False  # not glibc (macOS, musl without mallopt): the defaults stay
    mallopt.argtypes = (ctypes.c_int, ctypes.c_int)
    _done = bool(mallopt(_M_MMAP_THRESHOLD, _MMAP_THRESHOLD)) and bool(
        mallopt(_M_TRIM_THRESHOLD, _TRIM_THRESHOLD))
    return _done
