"""Every MAVLink packet a live session receives, written to a .tlog as it arrives.

The .tlog format (what Mission Planner, MAVProxy and pymavlink write and read): per packet the
UNIX time of reception in microseconds (uint64, big-endian), then the packet's bytes exactly
as received. The file is flushed to the operating system at least every ``FLUSH_PERIOD_S``
and when closed, so a session ended by Ctrl-C, SIGTERM or a crash of this program loses at
most that last fraction of a second (and nothing on a clean stop).
"""
from __future__ import annotations

import struct
import time
from pathlib import Path

_STAMP = struct.Struct(">Q")
FLUSH_PERIOD_S = 0.5


class TlogRecorder:
    def __init__(self, path):
        self.path = Path(path)
        self.path.parent.mkdir(parents=True, exist_ok=True)
        self._f = open(self.path, "xb")  # a recording never replaces a file
        self.packets = 0
        self.bytes = 0
        self._flushed_at = time.monotonic()

    def write(self, packet: bytes, unix_time: float | None = None) -> None:
        """One packet, stamped with ``unix_time`` (default now)."""
        stamp = int((time.time() if unix_time is None else unix_time) * 1e6)
        self._f.write(_STAMP.pack(stamp))
        self._f.write(packet)
        self.packets += 1
        self.bytes += 8 + len(packet)

    def tick(self, now: float) -> None:
        """Flush if the last flush is FLUSH_PERIOD_S old (``now``: monotonic s)."""
        if now - self._flushed_at >= FLUSH_PERIOD_S:
            self._f.flush()
            self._flushed_at = now

    def close(self) -> None:
        if not self._f.closed:
            self._f.flush()
            self._f.close()
