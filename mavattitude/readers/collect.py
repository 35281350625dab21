"""Samples in file order -> clean time-stamped columns, shared by both log readers.

A reader hands over samples in SI units with their time in seconds on the autopilot clock:
one at a time (``add``, the .tlog reader) or a whole message type at once (``add_columns``,
the .bin reader, with each record's file offset as its order). ``finish`` then follows the
clock through all samples in file order (``track_clock``):

- a jump of the clock by more than ``JUMP_S``, back (a reboot) or ahead (logging paused, a
  link back after an outage), counts only once ``CONFIRM_SAMPLES`` samples in a row agree
  with the new clock; until then the samples that jumped are held, and dropped as corrupt
  records (a flipped bit in a time field) if the old clock resumes. A jump back starts a new
  clock segment;
- a sample with a negative or non-finite time is dropped as corrupt.

Then, per series, ``columns`` keeps one segment, sorts by time and drops repeated
timestamps: smaller backward steps are reordering (a GPS sample logged after a later IMU
sample), fixed by the sort.
"""
from __future__ import annotations

from array import array
from dataclasses import dataclass, field

import numpy as np
from numba import njit

# Between two samples in file order the clock moves by less than this: ArduPilot writes a
# sample at most a few hundred ms after it was taken. A larger step is a jump of the clock.
JUMP_S = 2.0
# Samples in a row that must agree with a jumped clock before it counts. A corrupt record
# is one sample; every stream of a rebooted autopilot agrees.
CONFIRM_SAMPLES = 5
# For a live link (live.estimation): back this far is a reboot; ahead this far, a sample is
# held until the next confirms it.
REBOOT_JUMP_S = JUMP_S
FORWARD_JUMP_S = 60.0


@njit(cache=True)
def track_clock(t, jump, confirm):
    """The clock segment of each sample, in file order; -1 for a corrupt one (see module doc)."""
    n = len(t)
    seg = np.full(n, -1, np.int64)
    held = np.empty(confirm, np.int64)
    n_held = 0
    held_max = 0.0
    current = 0
    clock_max = -np.inf
    segment_start = 0  # index of the first sample of the current segment
    segment_count = 0
    for i in range(n):
        x = t[i]
        if not (x >= 0.0 and x < np.inf):
            continue
        if clock_max == -np.inf:
            clock_max = x
            seg[i] = current
            segment_count = 1
            continue
        fits_old = clock_max - jump <= x <= clock_max + jump
        if n_held:
            fits_new = held_max - jump <= x <= held_max + jump
            if fits_old and not fits_new:  # the old clock resumed: what jumped was corrupt
                n_held = 0
            elif fits_new:
                held[n_held] = i
                n_held += 1
                held_max = max(held_max, x)
                if n_held == confirm:  # the jump is real
                    if t[held[0]] < clock_max - jump:  # back: a reboot
                        if segment_count < confirm:  # what came before is too short for a clock
                            for j in range(segment_start, i):
                                if seg[j] == current:
                                    seg[j] = -1
                        else:
                            current += 1
                        segment_start = held[0]
                        segment_count = 0
                    for k in range(n_held):
                        seg[held[k]] = current
                    segment_count += n_held
                    clock_max = held_max
                    n_held = 0
                continue
            else:
                continue  # agrees with neither clock: corrupt
        if fits_old:
            seg[i] = current
            segment_count += 1
            if x > clock_max:
                clock_max = x
        else:
            held[0] = i
            n_held = 1
            held_max = x
    return seg


class Collector:
    """The samples of one log (see the module docstring)."""

    def __init__(self):
        # (kind, key) -> chunks of (order, t, values (N, M)); samples added one at a time go
        # to a flat float64 buffer first (8 bytes a value, not a Python tuple per sample).
        self._chunks: dict[tuple[str, str], list] = {}
        self._rows: dict[tuple[str, str], array] = {}
        self._width: dict[tuple[str, str], int] = {}
        self._order = 0
        self._series: dict[tuple[str, str], tuple[np.ndarray, np.ndarray, np.ndarray]] = {}
        self._segment_spans: list[tuple[float, float]] = []
        self.outliers = 0  # samples dropped as corrupt (their time fits no clock)

    def add(self, kind: str, key: str, t: float, row: tuple) -> None:
        """One sample, in file order."""
        buffer = self._rows.get((kind, key))
        if buffer is None:
            buffer = self._rows[(kind, key)] = array("d")
            self._width[(kind, key)] = 2 + len(row)
        buffer.append(self._order)
        buffer.append(t)
        buffer.extend(row)
        self._order += 1

    def add_columns(self, kind: str, key: str, order: np.ndarray, t: np.ndarray, values: np.ndarray) -> None:
        """Many samples of one series: ``order`` places them in the file (e.g. record offsets)."""
        self._chunks.setdefault((kind, key), []).append(
            (np.asarray(order, np.int64), np.asarray(t, np.float64), np.asarray(values, np.float64)))

    def finish(self) -> None:
        """Call after the last sample: follows the clock and assigns segments."""
        series = dict(self._chunks)
        for k, buffer in self._rows.items():
            data = np.frombuffer(buffer, dtype=np.float64).reshape(-1, self._width[k])
            series.setdefault(k, []).append((data[:, 0].astype(np.int64), data[:, 1], data[:, 2:]))
        merged = {k: (np.concatenate([c[0] for c in chunks]), np.concatenate([c[1] for c in chunks]),
                      np.concatenate([c[2] for c in chunks])) for k, chunks in series.items()}
        if not merged:
            return
        order = np.concatenate([m[0] for m in merged.values()])
        t = np.concatenate([m[1] for m in merged.values()])
        sort = np.argsort(order, kind="stable")
        seg_sorted = track_clock(t[sort], JUMP_S, CONFIRM_SAMPLES)
        seg = np.empty_like(seg_sorted)
        seg[sort] = seg_sorted
        self.outliers = int(np.count_nonzero(seg < 0))
        n_segments = int(seg.max()) + 1 if len(seg) else 0
        spans = []
        for s in range(n_segments):
            times = t[seg == s]
            spans.append((float(times.min()), float(times.max())) if len(times) else (np.inf, -np.inf))
        self._segment_spans = spans
        start = 0
        for k, (o, times, values) in merged.items():
            self._series[k] = (times, values, seg[start:start + len(times)])
            start += len(times)

    @property
    def segments(self) -> list[tuple[float, float]]:
        return [(a, b) for a, b in self._segment_spans if a <= b]

    def longest_segment(self) -> int:
        return int(np.argmax([b - a if a <= b else -1.0 for a, b in self._segment_spans]))

    def keys(self, kind: str) -> list[str]:
        return [k for (kd, k) in self._series if kd == kind]

    def columns(self, kind: str, key: str, segment: int) -> tuple[np.ndarray, np.ndarray, dict]:
        """(t, values (N, M), stats) for one series in one segment: sorted, unique times."""
        if (kind, key) not in self._series:
            return np.empty(0), np.empty((0, 0)), {"reordered": 0, "duplicates": 0}
        t, values, seg = self._series[(kind, key)]
        mine = seg == segment
        t, values = t[mine], values[mine]
        order = np.argsort(t, kind="stable")
        reordered = int(np.count_nonzero(np.diff(t) < 0))
        t, values = t[order], values[order]
        keep = np.concatenate([[True], np.diff(t) > 0]) if len(t) else np.zeros(0, bool)
        return t[keep], values[keep], {"reordered": reordered,
                                       "duplicates": int(len(t) - np.count_nonzero(keep))}


@dataclass
class Decoded:
    """What a reader got out of a file, before it becomes a ``Flight``."""
    collector: Collector
    params: dict[str, float]
    texts: list[str]  # firmware strings, status texts: who wrote the log
    counts: dict[str, int]  # message name -> how many
    notes: list[str] = field(default_factory=list)  # what was fixed or noticed
    warnings: list[str] = field(default_factory=list)  # data lost to damage: the user must hear of it
