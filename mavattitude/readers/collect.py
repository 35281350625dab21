"""Samples in file order -> clean time-stamped columns, shared by both log readers.

A reader hands over samples in SI units with their time in seconds on the autopilot clock:
one at a time (``add``, the .tlog reader) or a whole message type at once (``add_columns``,
the .bin reader, with each record's file offset as its order). ``finish`` then follows the
clock through all samples in file order (``ClockTracker``, which a live link uses too):

- the clock counts once ``CONFIRM_SAMPLES`` samples in a row agree on it (so a corrupt first
  sample does not set it);
- a jump of the clock by more than ``JUMP_S``, back (a reboot) or ahead (logging paused, a
  link back after an outage), counts only once ``CONFIRM_SAMPLES`` samples in a row agree
  with the new clock; until then the samples that jumped are held, and dropped as corrupt
  records (a flipped bit in a time field) if the old clock resumes. A jump back starts a new
  clock segment;
- a sample with a negative or non-finite time is dropped as corrupt, and so is one that
  agrees with neither the clock nor the samples held.

Then, per series, ``columns`` keeps one segment and, of its samples in file order, those newer
than every one before them: a sample out of order within its series (a telemetry link that
reordered two packets) or repeating a time is dropped, as a live link must drop it. Across
series, order does not matter (a GPS sample logged after a later IMU sample).

The autopilot's other attitude streams (``FOLLOWER_KINDS``: AHR2, EKF1, XKF1[1], AHRS2, ...) do
not take part in following the clock: each of their samples takes the segment of the last sample
before it in the file that did, or is dropped as corrupt when its time is more than ``JUMP_S``
from that sample's. So reading more streams leaves every other series, the segments and the
counts of corrupt samples as they were.

What the log says happened (``add_events``: flight modes, arming, text lines) follows the same
way, with two differences: a message without a time of its own (an old .bin's MODE, EV, ERR and
MSG; a .tlog's HEARTBEAT and STATUSTEXT) takes the time of the last clocked sample before it in
the file (the first after it when none is before), and ``events`` keeps every row of a segment in
file order, repeats included (two lines written in the same microsecond are two lines).
"""
from __future__ import annotations

from array import array
from dataclasses import dataclass, field
from typing import NamedTuple

import numpy as np

from ..kernel_cache import kernel

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


# Series that follow the clock the others found (see the module docstring).
FOLLOWER_KINDS = ("stream_euler", "stream_quat")

HELD = -2  # a label: waiting for the samples after it to say which clock it is on
CORRUPT = -1


@kernel
def _decide(held, n_held, label, res_index, res_label, n_res):
    """The n_held held samples decided: ``label`` each, appended to ``res_index``/``res_label``
    at n_res; returns the new count."""
    for k in range(n_held):
        res_index[n_res] = held[k]
        res_label[n_res] = label
        n_res += 1
    return n_res


@kernel
def _track(t, first_index, jump, confirm, state, held, out, res_index, res_label):
    """The clock-following of ``ClockTracker.push`` over ``t`` (see the module docstring).
    ``state``: [segment, clock_max, n_held, held_max, confirmed]; ``held``: global indices
    of the held samples. Writes a label per sample to ``out`` (HELD for one held) and the
    labels of held samples decided here to ``res_index``/``res_label``; returns how many."""
    current, clock_max, n_held, held_max, confirmed = int(state[0]), state[1], int(state[2]), state[3], state[4]
    n_res = np.int64(0)  # (not the literal 0, nor CORRUPT's -1 below: _decide compiled once, not four times)
    for i in range(len(t)):
        x = t[i]
        g = first_index + i
        if not (x >= 0.0 and x < np.inf):
            out[i] = CORRUPT
            continue
        if n_held and held_max - jump <= x <= held_max + jump:  # agrees with the held samples
            out[i] = HELD
            held[n_held] = g
            n_held += 1
            held_max = max(held_max, x)
            if n_held == confirm:  # a clock: the first, or one that jumped
                if confirmed and held_max < clock_max - jump:
                    current += 1  # it went back: a reboot
                n_res = _decide(held, n_held, current, res_index, res_label, n_res)
                clock_max = held_max
                confirmed = 1.0
                n_held = 0
            continue
        if confirmed and clock_max - jump <= x <= clock_max + jump:  # the clock goes on
            n_res = _decide(held, n_held, np.int64(CORRUPT), res_index, res_label, n_res)  # what jumped was corrupt
            n_held = 0
            out[i] = current
            clock_max = max(clock_max, x)
            continue
        if n_held and confirmed:
            out[i] = CORRUPT  # agrees with nothing: a corrupt time
            continue
        if n_held > 1:  # no clock yet: the samples that agree so far are the clock, this a jump
            n_res = _decide(held, n_held, current, res_index, res_label, n_res)
            clock_max = held_max
            confirmed = 1.0
        elif n_held == 1:  # no clock yet, and two lone samples disagree: keep the newer
            res_index[n_res] = held[0]
            res_label[n_res] = CORRUPT
            n_res += 1
        out[i] = HELD
        held[0] = g
        n_held = 1
        held_max = x
    state[0], state[1], state[2], state[3], state[4] = current, clock_max, n_held, held_max, confirmed
    return n_res


class ClockTracker:
    """The autopilot clock followed through samples in arrival order: a log's (``Collector``)
    or a live link's. ``push`` labels each sample with its clock segment, ``CORRUPT``, or
    ``HELD`` when it jumped and the samples after it must decide; those decisions come later
    (``decided``). ``finish`` decides what is still held: corrupt."""

    def __init__(self, jump: float = JUMP_S, confirm: int = CONFIRM_SAMPLES):
        self.jump, self.confirm = jump, confirm
        self._state = np.array([0.0, -np.inf, 0.0, 0.0, 0.0])
        self._held = np.zeros(confirm, np.int64)
        self.seen = 0  # samples pushed so far

    def push(self, t) -> tuple[np.ndarray, list[tuple[int, int]]]:
        """Labels for ``t`` (their indices run on from the samples pushed before), and the
        (index, label) decided now for samples held before this call."""
        t = np.ascontiguousarray(t, dtype=np.float64)
        out = np.empty(len(t), np.int64)
        res_index = np.empty(len(t) + self.confirm, np.int64)
        res_label = np.empty(len(t) + self.confirm, np.int64)
        n = _track(t, self.seen, self.jump, self.confirm, self._state, self._held, out, res_index, res_label)
        earlier = []
        for g, label in zip(res_index[:n].tolist(), res_label[:n].tolist()):
            if g >= self.seen:
                out[g - self.seen] = label
            else:
                earlier.append((g, label))
        self.seen += len(t)
        return out, earlier

    def finish(self) -> list[tuple[int, int]]:
        """The end of the samples: whatever is held is decided corrupt (a jump that nothing
        after it confirmed)."""
        n = int(self._state[2])
        self._state[2] = 0
        return [(int(g), CORRUPT) for g in self._held[:n]]

    @property
    def segment(self) -> int:
        return int(self._state[0])


class Collector:
    """The samples of one log (see the module docstring)."""

    def __init__(self):
        # (kind, key) -> chunks of (order, t, values (N, M)); samples added one at a time go
        # to a flat float64 buffer first (8 bytes a value, not a Python tuple per sample).
        self._chunks: dict[tuple[str, str], list] = {}
        # (kind, key) -> [order, t, values, rows filled]: a series given a capacity (``add_columns``),
        # filled in place; its key stays in ``_chunks`` (with no chunks) for the series' order
        self._filled: dict[tuple[str, str], list] = {}
        self._rows: dict[tuple[str, str], array] = {}
        self._width: dict[tuple[str, str], int] = {}
        self._order = 0
        self._series: dict[tuple[str, str], tuple[np.ndarray, np.ndarray, np.ndarray]] = {}
        self._segment_spans: list[tuple[float, float]] = []
        self._events: dict[tuple[str, str], list] = {}  # (kind, key) -> chunks of (order, t, values, labels)
        self._event_rows: dict[tuple[str, str], tuple] = {}  # (kind, key) -> (t, values, labels, segment)
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

    def add_columns(self, kind: str, key: str, order: np.ndarray, t: np.ndarray, values: np.ndarray,
                    capacity: int = 0) -> None:
        """Many samples of one series: ``order`` places them in the file (e.g. record offsets).
        ``capacity``: at least the rows the series will have, said with its first samples (a
        type read in parts: its record count): the series is then filled in place, rather than
        kept in chunks and joined at the end (for an hour at 400 Hz the chunks and their join
        were 200 MB each). The rows past those filled are never written, so never in memory."""
        k = (kind, key)
        if capacity and k not in self._chunks:
            values = np.asarray(values)
            self._chunks[k] = []
            self._filled[k] = [np.empty(capacity, np.int64), np.empty(capacity, np.float64),
                               np.empty((capacity, *values.shape[1:]), np.float64), 0]
        if k in self._filled:
            filling = self._filled[k]
            a, b = filling[3], filling[3] + len(t)
            filling[0][a:b], filling[1][a:b], filling[2][a:b] = order, t, values
            filling[3] = b
            return
        self._chunks.setdefault(k, []).append(
            (np.asarray(order, np.int64), np.asarray(t, np.float64), np.asarray(values, np.float64)))

    def add_events(self, kind: str, key: str, order, t, values, labels=None) -> None:
        """Rows of what the log says happened (see the module docstring): ``t`` in seconds,
        NaN where the message has no time of its own; ``values`` a number per row, ``labels``
        a text per row (or None)."""
        order = np.asarray(order, np.int64)
        labels = [""] * len(order) if labels is None else [str(x) for x in labels]
        self._events.setdefault((kind, key), []).append(
            (order, np.asarray(t, np.float64), np.asarray(values, np.float64), labels))

    @property
    def series_count(self) -> int:
        """How many series were given columns so far."""
        return len(self._chunks)

    def sort_new_series(self, known: int) -> None:
        """Put the series added after the first ``known`` in the order of their keys (a type
        collected in parts adds its instances in the order its parts meet them; whole, in
        the order of their numbers)."""
        new = sorted(list(self._chunks)[known:])
        for k in new:
            self._chunks[k] = self._chunks.pop(k)

    def finish(self) -> None:
        """Call after the last sample: follows the clock and assigns segments."""
        series, self._chunks = self._chunks, {}  # the chunks go as they are merged
        for k, buffer in self._rows.items():
            data = np.frombuffer(buffer, dtype=np.float64).reshape(-1, self._width[k])
            series.setdefault(k, []).append((data[:, 0].astype(np.int64), data[:, 1], data[:, 2:]))
        self._rows = {}
        merged = {}
        for k in list(series):
            chunks = series.pop(k)
            if k in self._filled:
                *columns, n = self._filled.pop(k)
                merged[k] = tuple(c[:n] for c in columns)
            else:
                merged[k] = tuple(chunks[0][i] if len(chunks) == 1 else np.concatenate([c[i] for c in chunks])
                                  for i in range(3))
            del chunks  # (joined: its parts go now, not with the next series')
        followers = {k: merged.pop(k) for k in list(merged) if k[0] in FOLLOWER_KINDS}
        if not merged:
            return
        # every sample in file order; each array let go once used (an hour at 400 Hz: 24 MB each)
        order_sorted = np.concatenate([m[0] for m in merged.values()])
        sort = np.argsort(order_sorted, kind="stable")
        order_sorted = order_sorted[sort] if followers or self._events else None
        t_sorted = np.concatenate([m[1] for m in merged.values()])[sort]
        tracker = ClockTracker()
        seg_sorted, _ = tracker.push(t_sorted)
        for g, label in tracker.finish():
            seg_sorted[g] = label
        self.outliers = int(np.count_nonzero(seg_sorted < 0))
        n_segments = int(seg_sorted.max()) + 1 if len(seg_sorted) else 0
        spans = []
        for s in range(n_segments):  # (in file order: the same samples, the same least and greatest)
            mine = seg_sorted == s
            spans.append((float(t_sorted.min(where=mine, initial=np.inf)),
                          float(t_sorted.max(where=mine, initial=-np.inf))))
        if order_sorted is not None:
            if followers:
                self._follow(followers, order_sorted, t_sorted, seg_sorted)
            if self._events:
                self._place_events(order_sorted, t_sorted, seg_sorted)
            del order_sorted
        del t_sorted
        seg = np.empty_like(seg_sorted)  # each sample's segment, in the series' order
        seg[sort] = seg_sorted
        del sort, seg_sorted
        self._segment_spans = spans
        start = 0
        for k, (order, times, values) in merged.items():
            self._series[k] = (order, times, values, seg[start:start + len(times)])
            start += len(times)

    def _follow(self, followers: dict, order: np.ndarray, t: np.ndarray, seg: np.ndarray) -> None:
        """Each follower sample takes the segment of the last clocked sample before it in the
        file (``order``, ``t``, ``seg``: the other samples in file order, CORRUPT ones among
        them), or CORRUPT when its time is more than JUMP_S from that sample's."""
        clocked = np.flatnonzero(seg >= 0)  # (indices only: the samples themselves are not copied)
        for k, (at, times, values) in followers.items():
            before = np.searchsorted(order, at, side="right") - 1  # the last sample before, clocked or not
            last = np.searchsorted(clocked, before, side="right") - 1  # the last clocked one up to it
            before = clocked[np.maximum(last, 0)] if len(clocked) else np.zeros_like(last)
            near = (last >= 0) & (np.abs(times - t[before]) <= JUMP_S)
            self._series[k] = (at, times, values, np.where(near, seg[before], CORRUPT))

    def _place_events(self, order: np.ndarray, t: np.ndarray, seg: np.ndarray) -> None:
        """Each event row takes the segment of the last clocked sample before it in the file
        (the first after it when none is before), and its time where it has none; CORRUPT when
        its own time is more than JUMP_S from that sample's."""
        clocked = np.flatnonzero(seg >= 0)
        events, self._events = self._events, {}
        for k, chunks in events.items():
            at = np.concatenate([c[0] for c in chunks])
            times = np.concatenate([c[1] for c in chunks])
            values = np.concatenate([c[2] for c in chunks])
            labels = [x for c in chunks for x in c[3]]
            if not len(clocked):
                continue
            before = np.searchsorted(order, at, side="right") - 1
            last = np.searchsorted(clocked, before, side="right") - 1
            near_sample = clocked[np.maximum(last, 0)]  # (last -1: none before, the first after)
            times = np.where(np.isfinite(times), times, t[near_sample])
            label = np.where(np.abs(times - t[near_sample]) <= JUMP_S, seg[near_sample], CORRUPT)
            by_place = np.argsort(at, kind="stable")
            self._event_rows[k] = (times[by_place], values[by_place], [labels[i] for i in by_place],
                                   label[by_place])

    def events(self, kind: str, key: str, segment: int) -> tuple[np.ndarray, np.ndarray, list[str]]:
        """(t, values, labels) of one event series' rows in one segment, in file order."""
        if (kind, key) not in self._event_rows:
            return np.empty(0), np.empty(0), []
        t, values, labels, seg = self._event_rows[(kind, key)]
        mine = np.flatnonzero(seg == segment)
        return t[mine], values[mine], [labels[i] for i in mine]

    def event_keys(self, kind: str) -> list[str]:
        return [k for (kd, k) in self._event_rows if kd == kind]

    @property
    def segments(self) -> list[tuple[float, float]]:
        return [(a, b) for a, b in self._segment_spans if a <= b]

    def longest_segment(self) -> int:
        return int(np.argmax([b - a if a <= b else -1.0 for a, b in self._segment_spans]))

    def keys(self, kind: str) -> list[str]:
        return [k for (kd, k) in self._series if kd == kind]

    def columns(self, kind: str, key: str, segment: int, take: bool = False) -> Columns:
        """One series in one segment, each sample newer than every one before it in the file
        (as a live link keeps them: a sample cannot be estimated after a later one was).
        ``take``: the collector lets go of the series (what is not handed over is freed; its
        key stays, with no rows)."""
        if (kind, key) not in self._series:
            return Columns(np.empty(0), np.empty((0, 0)), np.empty(0, np.int64), 0, 0)
        arrival, t, values, seg = self._series[(kind, key)]
        if take:
            self._series[(kind, key)] = (arrival[:0].copy(), t[:0].copy(), values[:0].copy(), seg[:0].copy())

        def select(rows):  # (an hour of IMU is copied only where something is left out or moved)
            return (arrival, t, values) if rows is None else (arrival[rows], t[rows], values[rows])
        mine = seg == segment
        arrival, t, values = select(None if mine.all() else mine)
        if not np.all(arrival[1:] >= arrival[:-1]):  # (in file order, as a .bin's are, no sort)
            arrival, t, values = select(np.argsort(arrival, kind="stable"))
        before = np.maximum.accumulate(np.concatenate([[-np.inf], t]))[:-1]
        keep = t > before
        repeated = int(np.count_nonzero(t == before))
        dropped = int(len(t) - np.count_nonzero(keep))
        arrival, t, values = select(keep if dropped else None)
        return Columns(t, values, arrival, dropped - repeated, repeated)


class Columns(NamedTuple):
    t: np.ndarray  # (N,) s
    values: np.ndarray  # (N, M)
    arrival: np.ndarray  # (N,) each sample's place in the file
    reordered: int  # samples dropped for being older than one before them
    duplicates: int  # samples dropped for repeating the time of the one before


# The date a log was flown, from the vehicle's GPS or system time (UNIX seconds, UTC).
GPS_EPOCH_UNIX = 315_964_800  # s, 1980-01-06 00:00:00 UTC
GPS_LEAP_SECONDS = 18  # GPS time runs ahead of UTC by this much (since 2017; 16-17 before: nothing to a date)
UTC_RANGE_S = (946_684_800, 4_102_444_800)  # 2000 to 2100: outside, a time not yet set (0, GPS week 0)


def gps_to_unix(week, week_ms):
    """UNIX time (s, UTC) of GPS week and milliseconds of the week (arrays or numbers)."""
    return GPS_EPOCH_UNIX + np.asarray(week, np.float64) * 604_800 + np.asarray(week_ms, np.float64) * 1e-3 \
        - GPS_LEAP_SECONDS


def first_utc(unix_s) -> float | None:
    """The first of these UNIX times (s) that is a set clock (``UTC_RANGE_S``); None if none is."""
    unix_s = np.atleast_1d(np.asarray(unix_s, np.float64))
    hits = np.flatnonzero((unix_s >= UTC_RANGE_S[0]) & (unix_s <= UTC_RANGE_S[1]))
    return float(unix_s[hits[0]]) if len(hits) else None


@dataclass
class Decoded:
    """What a reader got out of a file, before it becomes a ``Flight``."""
    collector: Collector
    params: dict[str, float]
    texts: list[str]  # firmware strings, status texts: who wrote the log
    counts: dict[str, int]  # message name -> how many
    notes: list[str] = field(default_factory=list)  # what was fixed or noticed
    warnings: list[str] = field(default_factory=list)  # data lost to damage: the user must hear of it
    identity: tuple[str, str] | None = None  # (vehicle, firmware) when the format says them (ULog)
    utc_s: float | None = None  # UNIX time (s, UTC) of the first valid GPS or system time (``flight.Flight``)
    build: str | None = None  # a .bin's vehicle by its VER record's build type, where no text names it
