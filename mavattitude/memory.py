"""Freed arrays given back to the system at once (glibc), so a long replay's peak memory is what
it holds, not what it once held.

glibc serves an allocation of 128 kB or more from its own mapping, returned to the system when
freed; but each time such a block is freed it raises that threshold (up to 32 MB), so that from
then on arrays of an hour's series (10-30 MB) come from the heap, where what is freed stays in
the process. Fixing the threshold at 4 MB turns the raising off: a series' arrays are mapped
and given back, a step's (0.5-2 MB, made and freed a few hundred times a replay) reused from the
heap. Hour at 400 Hz, all seven estimators, --rrd (scripts/replay_memory.py): peak 881 -> 845 MB
at no cost in CPU time; at 256 kB, 799 MB, but the page faults of mapping every step's arrays
afresh cost 3 s of CPU time (12.3 + 2.9 s -> 13.4 + 6.2 s).
"""
from __future__ import annotations

import ctypes
import ctypes.util
import sys

M_TRIM_THRESHOLD, M_MMAP_THRESHOLD = -1, -3  # mallopt's parameter numbers (malloc.h)
MMAP_THRESHOLD_BYTES = 4 << 20
TRIM_THRESHOLD_BYTES = 2 * MMAP_THRESHOLD_BYTES  # what glibc's own raising sets beside it


def give_back_freed_arrays() -> bool:
    """Fix glibc's mmap threshold (see the module docstring); whether it was set (False off
    glibc: macOS and Windows give large blocks back on their own)."""
    if not sys.platform.startswith("linux"):
        return False
    name = ctypes.util.find_library("c")
    try:
        libc = ctypes.CDLL(name or "libc.so.6")
        return bool(libc.mallopt(M_MMAP_THRESHOLD, MMAP_THRESHOLD_BYTES)) and \
            bool(libc.mallopt(M_TRIM_THRESHOLD, TRIM_THRESHOLD_BYTES))
    except (OSError, AttributeError):  # not glibc (musl has no mallopt)
        return False
