"""Freed arrays given back to the system at once (glibc), so a long replay's peak memory is what
it holds, not what it once held.

glibc serves an allocation of 128 kB or more from its own mapping, returned to the system when
freed; but each time such a block is freed it raises that threshold (up to 32 MB), so that from
then on a replay's arrays (a step's 0.5-2 MB, an hour's series 10-30 MB) come from the heap,
where what is freed stays in the process. Fixing the threshold turns the raising off.

The threshold is a trade (hour at 400 Hz, all seven estimators, --rrd; ``ru_maxrss`` and CPU
time of the replay, scripts/replay_memory.py or bench --read): glibc's own raising 881 MB, 12.3 +
2.9 s of CPU; 4 MB 845-860 MB at the same CPU time; 1 MB 830-860 MB, 11.9 + 4.0 s; 256 kB 775 MB,
12-13 + 6.4 s (every step's arrays mapped afresh: their page faults). 256 kB also slowed the
readers (every decoded column mapped afresh: `bench --read`, the 4 MB .ulg read at 9.6x pyulog
instead of 14.5-25x, the 78 MB .bin at 22x pymavlink instead of 25-34x). So: 4 MB, set once
replay has read its log (a 4 MB .ulg still read 50 % slower with it), most of the memory for
none of the time: the hour's peak 847 MB (826-828 MiB), 4.3x its decoded arrays.

What a phase freed inside the heap (arrays under the threshold, and everything freed while
glibc's own raising was on) stays there, to be reused or not: ``give_back_free_pages`` gives
its free pages back (``malloc_trim``, a few ms): after the read (14 MB for the hour), the
estimation (70 MB: the steps' arrays), the joining of the scoring rows (40 MB), and each batch
the view hands Rerun (its threads free what they sent into their own heaps: 20 MB).
"""
from __future__ import annotations

import ctypes
import sys

M_MMAP_THRESHOLD = -3  # mallopt's parameter number (malloc.h)
MMAP_THRESHOLD_BYTES = 4 << 20


def give_back_freed_arrays() -> bool:
    """Give back the heap's free pages and fix glibc's mmap threshold (see the module
    docstring); whether the threshold was set (False off glibc: macOS and Windows give large
    blocks back on their own)."""
    if not sys.platform.startswith("linux"):
        return False
    give_back_free_pages()
    try:  # the process's own symbols, libc's among them (find_library would run ldconfig)
        return bool(ctypes.CDLL(None).mallopt(M_MMAP_THRESHOLD, MMAP_THRESHOLD_BYTES))
    except (OSError, AttributeError):  # not glibc (musl has no mallopt)
        return False


def give_back_free_pages() -> None:
    """The heap's free pages given back to the system, wherever they lie in it (glibc's
    ``malloc_trim``; not at its top alone, as every ``free`` does): what a phase of a replay
    freed between the arrays it keeps (see the module docstring)."""
    if not sys.platform.startswith("linux"):
        return
    try:
        ctypes.CDLL(None).malloc_trim(0)  # (0: keep no free space at the heap's top)
    except (OSError, AttributeError):  # not glibc
        pass
