"""Rows in file order -> clean time-stamped columns, shared by both log readers.

A reader calls ``Collector.add(kind, key, t, row)`` for every sample it decodes (``t`` in
seconds on the autopilot clock, ``row`` a tuple already in SI units). The collector:

- tags each sample with a clock segment: when the autopilot clock jumps back by more than
  ``REBOOT_JUMP_S`` the vehicle rebooted, and a new segment starts;
- drops a lone sample far ahead of the clock that the next sample does not confirm: a
  corrupt record, whose garbage timestamp would otherwise look like a reboot after it;
- then, per series, keeps one segment, sorts by time and drops repeated timestamps.

Smaller backward steps are reordering (e.g. a GPS sample logged after a later IMU sample)
and are fixed by the sort.
"""
from __future__ import annotations

from array import array

import numpy as np

# A clock that goes back by more than this is a reboot, not reordering. ArduPilot writes
# samples at most a few hundred ms after they were taken, so 2 s leaves a wide margin.
REBOOT_JUMP_S = 2.0
# A sample this far ahead of the clock is held back until the next sample says whether the
# clock really jumped (a telemetry link that came back) or the sample was corrupt.
FORWARD_JUMP_S = 60.0


class Collector:
    def __init__(self):
        # (kind, key) -> flat float64 buffer of (segment, t, *row) records: 8 bytes a value,
        # not a Python tuple per sample, so an hour of 400 Hz IMU data stays small.
        self._rows: dict[tuple[str, str], array] = {}
        self._width: dict[tuple[str, str], int] = {}
        self._segment = 0
        self._clock_max = -np.inf
        self._segment_spans: list[list[float]] = [[np.inf, -np.inf]]
        self._ahead = None  # (kind, key, t, row) held back: far ahead of the clock
        self.outliers = 0

    def add(self, kind: str, key: str, t: float, row: tuple) -> None:
        if not np.isfinite(t) or t < 0:
            self.outliers += 1
            return
        if self._ahead is not None:
            held, self._ahead = self._ahead, None
            if abs(t - held[2]) < FORWARD_JUMP_S:
                self._append(*held)  # the clock really jumped forward
            else:
                self.outliers += 1
        if np.isfinite(self._clock_max) and t > self._clock_max + FORWARD_JUMP_S:
            self._ahead = (kind, key, t, row)
            return
        self._append(kind, key, t, row)

    def finish(self) -> None:
        """Call after the last ``add``: a sample still held back stands (the log ended there)."""
        if self._ahead is not None:
            self._append(*self._ahead)
            self._ahead = None

    def _append(self, kind: str, key: str, t: float, row: tuple) -> None:
        if t < self._clock_max - REBOOT_JUMP_S:
            self._segment += 1
            self._segment_spans.append([np.inf, -np.inf])
            self._clock_max = t
        self._clock_max = max(self._clock_max, t)
        span = self._segment_spans[self._segment]
        span[0] = min(span[0], t)
        span[1] = max(span[1], t)
        buffer = self._rows.get((kind, key))
        if buffer is None:
            buffer = self._rows[(kind, key)] = array("d")
            self._width[(kind, key)] = 2 + len(row)
        buffer.append(self._segment)
        buffer.append(t)
        buffer.extend(row)

    @property
    def segments(self) -> list[tuple[float, float]]:
        return [(float(a), float(b)) for a, b in self._segment_spans if a <= b]

    def longest_segment(self) -> int:
        spans = self._segment_spans
        return int(np.argmax([b - a if a <= b else -1.0 for a, b in spans]))

    def keys(self, kind: str) -> list[str]:
        return [k for (kd, k) in self._rows if kd == kind]

    def columns(self, kind: str, key: str, segment: int) -> tuple[np.ndarray, np.ndarray, dict]:
        """(t, values (N, M), stats) for one series in one segment: sorted, unique times."""
        rows = self._rows.get((kind, key))
        if not rows:
            return np.empty(0), np.empty((0, 0)), {"reordered": 0, "duplicates": 0}
        data = np.frombuffer(rows, dtype=np.float64).reshape(-1, self._width[(kind, key)])
        data = data[data[:, 0] == segment]
        t = data[:, 1]
        order = np.argsort(t, kind="stable")
        reordered = int(np.count_nonzero(np.diff(t) < 0))
        t, values = t[order], data[order, 2:]
        keep = np.concatenate([[True], np.diff(t) > 0]) if len(t) else np.zeros(0, bool)
        return t[keep], values[keep], {"reordered": reordered,
                                       "duplicates": int(len(t) - np.count_nonzero(keep))}
