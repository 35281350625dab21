"""replay's checks of the reference (``refcheck``) on data that arrives a part at a time: a live session.

``refcheck`` judges a whole log at once. ``RunningReferenceCheck`` is fed the same series as
they grow (the IMU rows the runner estimates, the reference, GPS, the runner's ground/air phase,
the autopilot's other attitude streams) and, on each ``advance``, judges what has become
certain, with the same thresholds, the same arithmetic and the same words (the functions of
``refcheck`` that make the spans and their texts):

- **tilt jump**: a step between two reference samples is judged once the IMU covers its end;
  the gyro's turned angle is the same running sum as the whole log's (``np.cumsum`` carried on
  from its last value: the same additions, in the same order). A span is final once a step
  starting after its end is judged.
- **tilt at rest**: a 1 s bin (counted from the first IMU sample, as the whole log counts them)
  is judged once it is complete and the phase, GPS and reference have a sample after its
  middle; a run of bad bins is final once a bin after it is judged good.
- **autopilot disagrees**: a reference sample is compared with a stream once that stream has
  a sample after it (``refcheck.tilt_apart_deg`` on the samples around it: the same numbers);
  ``disagreeing_spans``' bridging and counting is followed sample by sample (``_Chain``).
  Which streams give a second opinion, and what algorithm made each, the front end says
  (``compared``: ``refcheck.compared_streams`` on what it has seen).
- an input that has not come ``WAIT_S`` of IMU time later is taken as not coming (a vehicle
  without GPS, a stream that stopped): the whole log would have judged it the same, but for a
  GPS that starts after a long silence (its first speed is held back to the start there).

The spans of a check can begin in the past (a disagreement counts as one after
``DISAGREE_MIN_S`` above the limit; a rest span after ``MIN_REST_SPAN_S``), so a reference
sample is not to be scored before ``settled`` has passed it: no later span can then cover it.
``excluded`` gives the spans known so far, the open ones up to where they are certain; that is
all a scorer needs for the samples before ``settled``. Behind the latest data, ``settled`` lags
by an open span's length: usually under ``DISAGREE_MIN_S`` + ``DISAGREE_BRIDGE_S``.
``finish`` judges the rest as the whole log's end does. Memory: what is still to be judged,
and the spans found.
"""
from __future__ import annotations

import math

import numpy as np

from .. import quaternion as quat
from ..flight import AttitudeSeries
from ..growing import Growing
from ..phase import STALE_S
from . import refcheck as rc
from .refcheck import Suspect

WAIT_S = 5.0  # s of IMU time: an input that has not come by then is taken as not coming
_KIND_ORDER = {"tilt at rest": 0, "tilt jump": 1, "autopilot disagrees": 2}  # refcheck's order at equal starts


class RunningReferenceCheck:
    """``refcheck.check_reference`` and ``autopilot_disagreement`` of a reference ``source``
    (``trim``: (roll, pitch) rad or None, as replay gives it), fed by ``add_*`` in time order.

    ``compared``: the streams that give a second opinion, {key: algorithm}, in refcheck's order;
    ``algorithm``: the reference's (both for the disagreement's words; the front end keeps them
    up to date). ``suspects``: the final spans so far, in refcheck's order."""

    def __init__(self, source: str, trim=None):
        self.source, self.trim = source, trim
        self.algorithm = "unknown"
        self.compared: dict[str, str] = {}
        self.imu = Growing(6)  # t, turned (rad since the first sample), |gyro|, accel (3)
        self.ref = Growing(5)  # t, q
        self.gps = Growing(2)  # t, ground speed (where known)
        self.phase = Growing(2)  # t, in_air
        self.streams: dict[str, Growing] = {}  # key -> t, q
        self.t0: float | None = None  # the first IMU sample: the bins count from it
        self.ref_t0: float | None = None
        self._turned = 0.0
        self._jump_i = 0  # the first reference step not judged (an index of every reference row)
        self._jump: list | None = None  # the open jump span [start, end, largest step]
        self._bin = 0  # the first bin not judged
        self._rest: list | None = None  # the open run of bad bins [first bin, last bin, largest off]
        self._chains: dict[str, _Chain] = {}
        self._found: list[tuple] = []  # (sort key, Suspect)
        self.final = False

    # ------------------------------------------------------------ input

    def add_imu(self, t, gyro, accel) -> None:
        t, gyro = np.asarray(t, float), np.asarray(gyro, float)
        if not len(t):
            return
        rate = np.linalg.norm(gyro, axis=1)
        if self.t0 is None:
            self.t0, steps = float(t[0]), rate[1:] * np.diff(t)
        else:
            steps = rate * np.diff(np.concatenate([[self.imu.last[0]], t]))
        turned = np.cumsum(np.concatenate([[self._turned], steps]))
        turned = turned if len(turned) == len(t) else turned[1:]
        self._turned = float(turned[-1])
        self.imu.extend(np.column_stack([t, turned, rate, accel]))

    def add_reference(self, t, q) -> None:
        if len(t):
            self.ref_t0 = float(t[0]) if self.ref_t0 is None else self.ref_t0
            self.ref.extend(np.column_stack([t, q]))

    def add_gps(self, t, vel_ne) -> None:
        speed = np.linalg.norm(np.asarray(vel_ne, float).reshape(-1, 2), axis=1)
        ok = np.isfinite(speed)
        self.gps.extend(np.column_stack([np.asarray(t, float)[ok], speed[ok]]))

    def add_phase(self, t, in_air) -> None:
        self.phase.extend(np.column_stack([t, in_air]))

    def add_stream(self, key: str, t, q) -> None:
        store = self.streams.get(key)
        if store is None:
            store = self.streams[key] = Growing(5)
            self._chains[key] = _Chain()
        store.extend(np.column_stack([t, q]))

    # ------------------------------------------------------------ judging

    def advance(self) -> list[Suspect]:
        """Judge what the data now settles; returns the spans that became final."""
        before = len(self._found)
        if self.t0 is not None and self.ref.n:
            self._jumps()
            self._rest_bins()
            for key in self.streams:
                self._disagreement(key)
            self._forget()
        return [s for _, s in self._found[before:]]

    def finish(self) -> list[Suspect]:
        """The data is complete: judge the rest, as the whole log's end does."""
        self.final = True
        found = self.advance()
        before = len(self._found)
        if self._jump is not None:
            self._found.append(self._key(rc.jump_suspect(self.source, *self._jump)))
        if self._rest is not None:
            self._close_rest()
        for key, chain in self._chains.items():
            self._close_chain(key, chain)
        self._jump = self._rest = None
        return found + [s for _, s in self._found[before:]]

    @property
    def suspects(self) -> list[Suspect]:
        return [s for _, s in sorted(self._found, key=lambda f: f[0])]

    @property
    def settled(self) -> float:
        """Reference samples earlier than this are judged for good (``excluded`` covers them)."""
        if self.final:
            return math.inf
        if self.t0 is None or not self.ref.n:
            return -math.inf
        ref_t = self.ref.column(0)
        first = self._jump_i - self.ref.forgotten
        times = [ref_t[first] if first < self.ref.n else ref_t[-1]]
        times.append(self._bin_start(self._rest[0] if self._rest and self._rest[1] - self._rest[0] + 1 < rc.MIN_REST_SPAN_S
                                     else self._bin))
        for key, chain in self._chains.items():
            if key in self.compared:
                times.append(chain.settled(ref_t, self.ref.forgotten))
        return min(times)

    def excluded(self) -> list[tuple[float, float]]:
        """The spans known not to be scored: the final ones, and the open ones as far as they are certain."""
        spans = [(s.start, s.end) for _, s in self._found]
        if self._jump is not None:
            spans.append((self._jump[0], self._jump[1]))
        if self._rest is not None and self._rest[1] - self._rest[0] + 1 >= rc.MIN_REST_SPAN_S:
            first, last = self._centres(self._rest[0], self._rest[1] + 1)[[0, -1]]
            spans.append((float(first - 0.5), float(last + 0.5)))
        spans += [(c.start, c.last_above) for k, c in self._chains.items()
                  if k in self.compared and c.open and c.declared()]
        return spans

    def _key(self, s: Suspect, stream: str | None = None) -> tuple:
        order = list(self.compared).index(stream) if stream in self.compared else 0
        return (s.start, _KIND_ORDER[s.kind], order), s

    # ------------------------------------------------------------ tilt jumps

    def _jumps(self) -> None:
        ref, imu = self.ref.view(), self.imu.view()
        a = self._jump_i - self.ref.forgotten
        end = len(ref) if self.final else int(np.searchsorted(ref[:, 0], imu[-1, 0], side="right"))
        if end - a < 2:
            return
        rows = ref[a:end]
        rt, down = rows[:, 0], quat.rotate(quat.conjugate(np.ascontiguousarray(rows[:, 1:5])), np.array([0.0, 0.0, 1.0]))
        with np.errstate(invalid="ignore"):
            step = np.degrees(np.arccos(np.clip((down[:-1] * down[1:]).sum(axis=1), -1.0, 1.0)))
        allowed = np.degrees(np.interp(rt[1:], imu[:, 0], imu[:, 1]) - np.interp(rt[:-1], imu[:, 0], imu[:, 1]))
        inside = (rt[:-1] >= self.t0) & (rt[1:] <= imu[-1, 0]) & (np.diff(rt) < rc.MAX_JUMP_STEP_S)
        for i in np.flatnonzero(inside & (step > 2.0 * allowed + rc.JUMP_MARGIN_DEG)):
            start, stop = float(rt[i]), float(rt[i + 1]) + rc.JUMP_HOLD_S
            if self._jump is not None and start <= self._jump[1]:
                self._jump[1], self._jump[2] = max(self._jump[1], stop), max(self._jump[2], step[i])
            else:
                if self._jump is not None:
                    self._found.append(self._key(rc.jump_suspect(self.source, *self._jump)))
                self._jump = [start, stop, step[i]]
        self._jump_i += end - a - 1
        if self._jump is not None and rt[-1] > self._jump[1]:  # no later step can reach back into it
            self._found.append(self._key(rc.jump_suspect(self.source, *self._jump)))
            self._jump = None

    # ------------------------------------------------------------ tilt at rest

    def _centres(self, a: int, b: int) -> np.ndarray:
        return self.t0 + np.arange(a, b) + 0.5

    def _bin_start(self, k: int) -> float:
        return float(self._centres(k, k + 1)[0] - 0.5) - 1e-6  # below the span's start, whatever its rounding

    def _rest_bins(self) -> None:
        imu = self.imu.view()
        last_bin = int(np.floor(imu[-1, 0] - self.t0))
        end = last_bin + 1 if self.final else last_bin  # the last bin is complete only at the end
        if end > self._bin and not self.final:  # each input has a sample after the middle, or is not coming
            centre = self._centres(self._bin, end)
            timeout = centre < imu[-1, 0] - WAIT_S
            ready = timeout | ((centre < _last(self.phase)) & (centre <= _last(self.gps)) & (centre < _last(self.ref)))
            end = self._bin + (int(np.argmin(ready)) if not ready.all() else len(ready))
        if end <= self._bin:
            return
        first = int(np.searchsorted(imu[:, 0], self._bin_start(self._bin) + 1e-6, side="left"))
        first = max(first - 1, 0)
        rows = imu[first:]
        bins = np.floor(rows[:, 0] - self.t0).astype(np.int64)
        take = (bins >= self._bin) & (bins < end)
        count, rate, acc = rc.bin_means(bins[take] - self._bin, end - self._bin, rows[take, 2],
                                        np.ascontiguousarray(rows[take, 3:6]))
        centre = self._centres(self._bin, end)
        ref = self.ref.view()
        rest = rc.resting(count, rate, acc, self._in_air(centre), self._moving(centre)) & (
            centre > self.ref_t0) & (centre < ref[-1, 0])
        off = np.zeros(len(centre))
        if rest.any():
            off = rc.tilt_off_deg(acc, quat.interpolate(ref[:, 0], ref[:, 1:5], centre), self.trim)
        for k, bad in enumerate(rest & (off > rc.TILT_AT_REST_DEG)):
            if bad:
                self._rest = [self._bin + k, self._bin + k, off[k]] if self._rest is None else \
                    [self._rest[0], self._bin + k, max(self._rest[2], off[k])]
            elif self._rest is not None:
                self._close_rest()
        self._bin = end

    def _close_rest(self) -> None:
        a, b, largest = self._rest
        self._rest = None
        if b + 1 - a >= rc.MIN_REST_SPAN_S:
            first, last = self._centres(a, b + 1)[[0, -1]]
            self._found.append(self._key(rc.rest_suspect(self.source, first, last, np.array([largest]))))

    def _in_air(self, centre: np.ndarray) -> np.ndarray:
        """``phase.PhaseSeries.on_clock`` over the rows kept."""
        rows = self.phase.view()
        if not len(rows):
            return np.full(len(centre), np.nan)
        idx = np.searchsorted(rows[:, 0], centre, side="right") - 1
        out = rows[np.clip(idx, 0, None), 1].astype(float)
        out[(idx < 0) | (centre - rows[np.clip(idx, 0, None), 0] > STALE_S)] = np.nan
        return out

    def _moving(self, centre: np.ndarray) -> np.ndarray:
        rows = self.gps.view()
        if not len(rows):
            return np.zeros(len(centre), dtype=bool)
        return np.interp(centre, rows[:, 0], rows[:, 1]) > rc.REST_SPEED

    # ------------------------------------------------------------ the autopilot disagrees

    def _disagreement(self, key: str) -> None:
        chain, store, ref = self._chains[key], self.streams[key], self.ref.view()
        a = chain.next_ref - self.ref.forgotten
        if not store.n or a >= len(ref):
            return
        other = store.view()
        if self.final:
            end = len(ref)
        else:  # the stream has a sample after it, or is not coming
            end = int(np.searchsorted(ref[:, 0], other[-1, 0], side="left"))
            end = max(end, int(np.searchsorted(ref[:, 0], self.imu.last[0] - WAIT_S, side="left")))
        if end <= a:
            return
        lo = max(int(np.searchsorted(other[:, 0], ref[a, 0], side="left")) - 1, 0)
        t, apart = rc.tilt_apart_deg(AttitudeSeries(self.source, ref[a:end, 0], np.ascontiguousarray(ref[a:end, 1:5])),
                                     AttitudeSeries(key, np.ascontiguousarray(other[lo:, 0]),
                                                    np.ascontiguousarray(other[lo:, 1:5])))
        for ti, v in zip(t.tolist(), apart.tolist()):
            if v == v and chain.add(ti, v):  # closed: a span, if it lasted
                self._close_chain(key, chain)
        chain.next_ref += end - a

    def _close_chain(self, key: str, chain: _Chain) -> None:
        if chain.open and chain.declared() and key in self.compared:
            self._found.append(self._key(rc.disagreement(self.source, self.algorithm, key, self.compared[key],
                                                         chain.start, chain.last_above, chain.seconds(),
                                                         np.array(chain.values)), key))
        chain.reset()

    # ------------------------------------------------------------ memory

    def _forget(self) -> None:
        """Drop the rows every check has judged (keeping the one before, for interpolation)."""
        ref_t = self.ref.column(0)
        keep = [self._jump_i - self.ref.forgotten - 1]
        keep.append(int(np.searchsorted(ref_t, self._bin_start(self._bin), side="left")) - 2)
        keep += [c.next_ref - self.ref.forgotten - 1 for c in self._chains.values()]
        self.ref.forget(min(keep))
        since = min(self.ref.column(0)[0] if self.ref.n else math.inf, self._bin_start(self._bin))
        for store in (self.imu, self.gps, self.phase, *self.streams.values()):
            if store.n:
                store.forget(int(np.searchsorted(store.column(0), since, side="left")) - 2)


class _Chain:
    """``refcheck.disagreeing_spans`` followed one known sample at a time: the runs above the
    limit joined across dips shorter than DISAGREE_BRIDGE_S, the time above counted as there."""

    def __init__(self):
        self.next_ref = 0  # the first reference row (of every row) not yet compared
        self.reset()

    def reset(self) -> None:
        self.open = False
        self.start = self.last_above = math.nan
        self.steps: list[float] = []  # refcheck's ``above``: steps from an above sample, in order
        self.counted = 0  # of them, those before the last above sample
        self.values: list[float] = []  # the known angles from the start to the last above sample
        self.dip: list[float] = []  # the angles since the last above sample
        self.dip_first = math.nan  # the first time below, after the last above sample
        self.prev = None  # (t, above) of the previous known sample

    def add(self, t: float, v: float) -> bool:
        """One known sample; True when it closes the chain (this sample then starts afresh)."""
        above = v > rc.DISAGREE_DEG
        if not self.open:
            if above:
                self.open, self.start, self.last_above, self.values = True, t, t, [v]
            self.prev = (t, above)
            return False
        prev_t, prev_above = self.prev
        if prev_above and t - prev_t <= rc.DISAGREE_MAX_GAP_S:
            self.steps.append(t - prev_t)
        self.prev = (t, above)
        if above:  # a dip shorter than DISAGREE_BRIDGE_S (a longer one closed the chain): bridged
            self.values += self.dip + [v]
            self.dip, self.dip_first, self.last_above = [], math.nan, t
            self.counted = len(self.steps)
            return False
        if not self.dip:
            self.dip_first = t
        self.dip.append(v)
        return t - self.dip_first >= rc.DISAGREE_BRIDGE_S  # no later run can be joined to this one

    def seconds(self) -> float:
        return float(np.array(self.steps[:self.counted]).sum())

    def declared(self) -> bool:
        return self.seconds() >= rc.DISAGREE_MIN_S

    def settled(self, ref_t: np.ndarray, forgotten: int) -> float:
        """Reference samples before this are judged for good against this stream."""
        i = self.next_ref - forgotten
        pending = ref_t[i] if i < len(ref_t) else (ref_t[-1] if len(ref_t) else -math.inf)
        if not self.open:
            return pending
        return min(pending, float(np.nextafter(self.last_above, math.inf)) if self.declared() else self.start)


def _last(store: Growing) -> float:
    return float(store.last[0]) if store.n else -math.inf
