"""Freed arrays given back to the system at once (glibc), so a long replay's peak memory is what
it holds, not what it once held.

glibc serves an allocation of 128 kB or more from its own mapping, returned to the system when
freed; but each time such a block is freed it raises that threshold (up to 32 MB), so that from
then on the arrays of a replay's steps (1-30 MB) come from the heap, where what is freed stays
in the process. An hour at 400 Hz peaked 140 MB higher for it (``bench --read``). Fixing the
threshold turns the raising off; a mapping per array costs nothing measurable beside the work
done on it.
"""
from __future__ import annotations

import ctypes
import ctypes.util
import sys

M_MMAP_THRESHOLD = -3  # mallopt's parameter numbers (malloc.h)
MMAP_THRESHOLD_BYTES = 256 * 1024


def give_back_freed_arrays() -> bool:
    """Fix glibc's mmap threshold (see the module docstring); whether it was set (False off
    glibc: macOS and Windows give large blocks back on their own)."""
    if not sys.platform.startswith("linux"):
        return False
    name = ctypes.util.find_library("c")
    try:
        libc = ctypes.CDLL(name or "libc.so.6")
        return bool(libc.mallopt(M_MMAP_THRESHOLD, MMAP_THRESHOLD_BYTES))
    except (OSError, AttributeError):  # not glibc (musl has no mallopt)
        return False
