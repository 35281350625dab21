"""The estimation core: estimators run over one clock segment's samples, as they arrive.

Replay, live, evaluate, tune and the Python API run the estimators through a ``Runner``;
plain ``bench`` times each estimator's own ``update()`` instead, on purpose. Replay
hands it a whole log at once, live a few packets at a time; either way every IMU sample is
given exactly what had *arrived* before it (``arrival``: a log's file order, a link's packet
order), so the two give the same estimates to the last bit:

- the magnetometer: the latest sample to arrive, held until stale (older than
  ``MAG_STALE_PERIODS`` of its own last interval, and at least ``MAG_STALE_MIN_S``);
- the ground/air phase (``phase.PhaseTracker``): from baro height, or GPS height (3D fix)
  when no baro sample had arrived by the first IMU sample;
- GPS and baro (estimators with ``uses_aiding``): each measurement once, at the first IMU
  sample to arrive after it whose time is not earlier than its own, unless that sample is
  more than ``aiding.MAX_LATENCY_S`` (or two IMU intervals) later (stale). The GPS origin is
  the first good fix, the baro zero the first good sample.

Runs: the estimators start at the first IMU sample and again after a gap longer than
``REINIT_GAP_S``, from the alignment of the run's first samples (``estimators.align``). A
run waits until its alignment is decided (``alignment_decided``: the still period at its start
has ended, or reached ``alignment.MAX_STILL_S``, 10 s), so live and replay align on the same
samples. A run without a still period keeps the first run's gyro bias, and an estimator with
no heading reference carries its yaw across the gap.

Against the time-ordered replay of before (each measurement used from its timestamp, even
where it arrived later), this changes nothing on a DataFlash log, whose records are written
in time order, and on telemetry logs what a live link would have seen: a GPS_RAW_INT that
arrives a second after its fix is fused then, not a second in the past.
"""
from __future__ import annotations

import inspect
from dataclasses import dataclass

import numpy as np

from .. import aiding as aid
from .. import estimators as est
from .. import quaternion as quat
from ..diagcolumns import Column, Series
from ..events import Event
from ..flight import AttitudeSeries
from ..growing import Growing
from .imurows import ImuRows
from ..scoring.imucheck import rate_warning
from ..phase import STALE_S, PhaseTracker, pressure_height
from .scoredrows import ScoredRows

# An IMU gap longer than this restarts the estimators from a fresh alignment: after it the
# vehicle may be anywhere (logging paused while disarmed, a crash and a pick-up).
REINIT_GAP_S = 2.0
GAP_KIND = f"IMU gap over {REINIT_GAP_S:g} s, estimators re-initialised"  # the gap events' Event.kind
# Rows estimated per kernel call at most (82 s at 400 Hz): an hour-long log's per-sample
# scratch and diagnostics (cpf-ekf: 29 float64 a row) stay some 15 MB, not gigabytes (65,536
# rows: 30 MB, at the top of a replay's memory; the same estimates to the bit either way).
STEP_ROWS = 1 << 15
# A magnetometer sample older than this many of its own intervals (or MAG_STALE_MIN_S) is stale.
MAG_STALE_PERIODS = 3.0
MAG_STALE_MIN_S = 0.5

IMU, MAG, GPS, BARO = "imu", "mag", "gps", "baro"
AIDING_WIDTHS = tuple(3 if f in ("gps_pos", "gps_vel") else 1 for f in aid.Aiding.COLUMNS)
AIDING_WIDTH = sum(AIDING_WIDTHS)
WIDTH = {IMU: 8, MAG: 5, GPS: len(aid.GPS_COLUMNS), BARO: len(aid.BARO_COLUMNS)}  # arrival last


@dataclass
class Chunk:
    """What one ``step`` produced: estimates at the IMU times ``t``."""
    t: np.ndarray
    q: dict[str, np.ndarray]  # estimator -> (N, 4)
    diagnostics: dict[str, dict[str, np.ndarray]]  # estimator -> key -> (N,)
    in_air: np.ndarray

    @staticmethod
    def join(chunks: list[Chunk]) -> Chunk | None:
        if not chunks:
            return None
        if len(chunks) == 1:
            return chunks[0]
        first = chunks[0]
        return Chunk(np.concatenate([c.t for c in chunks]),
                     {n: np.vstack([c.q[n] for c in chunks]) for n in first.q},
                     {n: {k: np.concatenate([c.diagnostics[n][k] for c in chunks]) for k in first.diagnostics[n]}
                      for n in first.diagnostics},
                     np.concatenate([c.in_air for c in chunks]))


@dataclass
class Run:
    """One stretch of IMU data without a gap: [start, end) rows, and how it began."""
    start: int
    alignment: est.Alignment
    end: int
    t_start: float  # s, its first IMU sample
    gap: float  # s, from the IMU sample before it (0 for the first run)
    has_heading: dict[str, bool]  # estimator -> whether it had a heading reference in this run


class Runner:
    """Estimators ``names`` (``params``: name -> parameter dataclass) on one clock segment.

    Feed it with ``add_imu``, ``add_mag``, ``add_gps``, ``add_baro`` in any order, as long as
    every sample that arrived before an IMU sample is added before the ``step`` that runs it
    (a log: everything, then ``step(final=True)``; a link: each packet as it comes, ``step``
    now and then). ``declination``: rad, east positive. ``keep_history``: keep every row's
    diagnostics and aiding for ``diagnostic_series`` and ``aiding`` (replay); a live session
    takes them from each step's ``Chunk`` instead, and keeps only the attitudes.
    ``scored_rows``, ``shown_rows``: a replay's estimates kept for scoring and the view only,
    see ``estimates`` below.
    """

    def __init__(self, names: list[str], params: dict | None = None, declination: float = 0.0,
                 use_mag: bool = True, imu_source: str = "IMU", mag_source: str | None = None,
                 keep_history: bool = True, scored_rows: np.ndarray | None = None,
                 shown_rows: np.ndarray | None = None):
        self.names = list(names)
        self.estimators = [est.create(n, (params or {}).get(n), declination) for n in self.names]
        self.uses_aiding = any(e.uses_aiding for e in self.estimators)
        self.keep_history = keep_history
        self.declination = declination
        self.use_mag = use_mag
        self.imu_source, self.mag_source = imu_source, mag_source
        self.rate_over_step = False  # the IMU's samples are means over their steps (add_flight; a link's are not)
        self.store = {kind: Growing(width) for kind, width in WIDTH.items()}
        # kinds whose rows, in time order, also arrived in that order (a log's and a link's do)
        self._in_arrival_order = set(WIDTH)
        self.done = 0  # IMU rows estimated
        self.runs: list[Run] = []
        self.running = False
        self.events: list[Event] = []
        # (N, 4) at the IMU rows estimated; with ``scored_rows`` (a replay's ``scoredrows.bracket_rows``)
        # in float32, for the view, and in float64 only where scoring reads them (``scoring_estimate``);
        # with ``shown_rows`` (sorted: the rows the view draws) only at those (an hour at 400 Hz: 23 MB
        # an estimator otherwise)
        self.estimates = {n: Growing(4, dtype=np.float64 if scored_rows is None else np.float32)
                          for n in self.names}
        self.scored = None if scored_rows is None else {n: ScoredRows(scored_rows) for n in self.names}
        self.shown = None if shown_rows is None else np.asarray(shown_rows, dtype=np.int64)
        self.nonfinite = {n: 0 for n in self.names}  # rows estimated with a non-finite attitude
        self._last_q: dict[str, np.ndarray] = {}  # each estimator's last attitude, as estimated
        self.diagnostics: dict[str, dict[str, Column]] = {n: {} for n in self.names}  # key -> every row's
        self.has_heading = {e.name: e.has_heading_reference(False) for e in self.estimators}
        self._phase: PhaseTracker | None = None
        self._heights_seen = 0  # height samples given to the phase tracker
        self._phase_rows = Growing(1)  # the tracker's row count after each height sample
        self._phase_reported = 0
        self._placer = aid.Placer()
        # the aiding handed over, only at the IMU rows that had any: (row, the Aiding's columns);
        # at every row it was 104 MB for an hour at 400 Hz, nearly all NaN
        self._aiding_given = Growing(1 + AIDING_WIDTH)
        self._imu_t: np.ndarray | None = None  # the IMU's times, once ``release_inputs`` dropped the rest
        self._rows_expected = 0  # a whole log's IMU rows, once known: room made for them at once

    # ------------------------------------------------------------ input

    def add_imu(self, t, gyro, accel, arrival) -> None:
        """IMU samples in time order (rad/s, m/s²); ``arrival``: their place in the arrival order."""
        self._add(IMU, np.column_stack([t, gyro, accel, arrival]))

    def add_mag(self, t, field_t, arrival) -> None:
        """Magnetometer samples in time order (tesla)."""
        self._add(MAG, np.column_stack([t, field_t, arrival]))

    def add_gps(self, rows: np.ndarray) -> None:
        """GPS samples in time order, rows of ``aiding.GPS_COLUMNS``."""
        self._add(GPS, rows)

    def add_baro(self, rows: np.ndarray) -> None:
        """Baro samples in time order, rows of ``aiding.BARO_COLUMNS``."""
        self._add(BARO, rows)

    def _add(self, kind: str, rows: np.ndarray | ImuRows) -> None:
        if len(rows):
            last = self.store[kind].last
            arrival = rows[:, -1]
            if kind in self._in_arrival_order and not (
                    (last is None or arrival[0] >= last[-1]) and np.all(arrival[1:] >= arrival[:-1])):
                self._in_arrival_order.discard(kind)
            if isinstance(rows, ImuRows):  # (the first rows given: see add_flight)
                self.store[kind] = rows
            else:
                self.store[kind].extend(rows)

    def add_flight(self, flight) -> None:
        """A whole log (``flight.Flight``): its IMU and compass of the runner's sources, GPS and
        baro, in the order the log holds them (``arrival``; by time where a series lacks it)."""
        imu = flight.imu[self.imu_source]
        self.rate_over_step = imu.rate_over_step
        mag = flight.mag.get(self.mag_source) if self.mag_source and self.use_mag else None
        series = [s for s in (imu, mag, flight.gps, flight.baro) if s is not None]
        by_time = any(s.arrival is None for s in series)

        def arrival(s):
            return s.t if by_time else s.arrival
        if self.store[IMU].n or self.store[IMU].forgotten:
            self.add_imu(imu.t, imu.gyro, imu.accel, arrival(imu))
        else:  # read where the flight holds them, a step's rows at a time: not a second copy (``imurows``)
            self._add(IMU, ImuRows(imu.t, imu.gyro, imu.accel, arrival(imu)))
        self._rows_expected = len(imu.t)
        for series in self.estimates.values():  # filled to exactly this size, never doubled
            series.reserve(len(imu.t) if self.shown is None else int(np.searchsorted(self.shown, len(imu.t))))
        if mag is not None:
            self.add_mag(mag.t, mag.field, arrival(mag))
        if flight.gps is not None:
            self.add_gps(aid.gps_rows(flight.gps, arrival(flight.gps)))
        if flight.baro is not None:
            self.add_baro(aid.baro_rows(flight.baro, arrival(flight.baro)))

    # ------------------------------------------------------------ stepping

    def step(self, final: bool = False, chunk: bool = True, progress=None) -> Chunk | None:
        """Estimate every IMU row added since the last step that can be: all of them, but for
        the rows of a run whose alignment is not decided yet (unless ``final``: no more data).
        Returns what it estimated as a ``Chunk`` (``chunk=False``: None; a whole log's results
        are read from the runner, not copied into a chunk). ``progress(fraction of the rows
        added)`` is called after each kernel call."""
        imu = self.store[IMU].view()
        t = imu[:, 0]
        chunks = []
        while self.done < len(t):
            a = self.done
            if self.running and a > 0 and t[a] - t[a - 1] > REINIT_GAP_S:
                self.running = False
                self.events.append(Event(float(t[a]), "warn", f"IMU gap of {t[a] - t[a - 1]:.1f} s: "
                                                              "estimators re-initialised", kind=GAP_KIND))
            gaps = np.flatnonzero(np.diff(t[a:]) > REINIT_GAP_S)
            b = a + int(gaps[0]) + 1 if len(gaps) else len(t)
            if not self.running and not self._start_run(a, b, complete=final or b < len(t)):
                break
            b = min(b, a + STEP_ROWS)
            done = self._run(a, b)
            if chunk:
                chunks.append(done)
            self.done = self.runs[-1].end = b
            if progress is not None:
                progress(b / len(t))
        return Chunk.join(chunks)

    def _start_run(self, a: int, b: int, complete: bool) -> bool:
        imu = self.store[IMU].view()[a:b]
        t, gyro, accel = imu[:, 0], imu[:, 1:4], imu[:, 4:7]
        if not est.alignment.alignment_decided(t, gyro, accel, complete):
            return False
        mag = self._mag_held(a, b)
        alignment = est.align(t, gyro, accel, mag, self.declination)
        if not self.runs:
            self._report_start(t, mag is not None, alignment)
        elif alignment.still_span is None:  # no new still period: keep the first's bias and reading of g
            alignment.gyro_bias = self.runs[0].alignment.gyro_bias
            alignment.accel_g = self.runs[0].alignment.accel_g
        for e in self.estimators:
            q0 = alignment.q0
            if self.runs and not alignment.heading_from_mag and e.name in self._last_q:
                # no heading reference: carry the yaw over the gap rather than restart it at 0
                roll, pitch, _ = quat.to_euler(q0)
                q0 = quat.from_euler(roll, pitch, quat.to_euler(self._last_q[e.name])[2])
            e.rate_over_step = self.rate_over_step
            if _takes_accel_g(e):
                e.initialize(q0, alignment.gyro_bias, alignment.accel_g)
            else:  # an estimator of a user's, written to the two-argument interface
                e.initialize(q0, alignment.gyro_bias)
            self.has_heading[e.name] = e.has_heading_reference(mag is not None)
        gap = float(t[0] - self.store[IMU].view()[a - 1, 0]) if a > 0 else 0.0
        self.runs.append(Run(a, alignment, a, float(t[0]), gap, dict(self.has_heading)))
        self.running = True
        return True

    def _report_start(self, t: np.ndarray, has_mag: bool, alignment: est.Alignment) -> None:
        t0 = float(t[0])
        rate = float(1.0 / np.median(np.diff(t))) if len(t) > 1 else 0.0
        self.events.append(Event(t0, "info", f"IMU source {self.imu_source} at {rate:.1f} Hz, "
                                             f"magnetometer {self.mag_source if has_mag else 'none'}"))
        if (low_rate := rate_warning(rate)) is not None:
            self.events.append(Event(t0, "warn", low_rate))
        if alignment.still_span:
            a, b = alignment.still_span
            bias = np.degrees(alignment.gyro_bias)
            self.events.append(Event(b, "info", f"still {a:.1f}-{b:.1f} s: gyro bias "
                                                f"[{bias[0]:.3f}, {bias[1]:.3f}, {bias[2]:.3f}] °/s, "
                                                f"accelerometer reads g as {alignment.accel_g:.3f} m/s²"))
        else:
            self.events.append(Event(t0, "warn", "no initial still period: gyro bias starts at 0"))

    def _run(self, a: int, b: int) -> Chunk:
        imu = self.store[IMU].view()[a:b]
        t = np.ascontiguousarray(imu[:, 0])
        gyro, accel = imu[:, 1:4], imu[:, 4:7]
        mag = self._mag_held(a, b)
        in_air = self._in_air(a, b)
        aiding = self._aiding(a, b) if self.uses_aiding else None
        if aiding is not None and self.keep_history:
            rows = np.column_stack([np.arange(a, b), *(getattr(aiding, f) for f in aid.Aiding.COLUMNS)])
            self._aiding_given.extend(rows[np.isfinite(rows[:, 1:]).any(axis=1)])
        out, diagnostics = {}, {}
        for e in self.estimators:
            q = e.update(t, gyro, accel, mag, in_air, aiding=aiding)
            self.nonfinite[e.name] += int(np.count_nonzero(~np.isfinite(q).all(axis=1)))
            if self.shown is None:
                self.estimates[e.name].extend(q)
                out[e.name] = self.estimates[e.name].view()[-len(t):]  # one copy of the result, not two
            else:
                lo, hi = np.searchsorted(self.shown, [a, b])
                self.estimates[e.name].extend(q[self.shown[lo:hi] - a])
                out[e.name] = q
            if len(q):
                self._last_q[e.name] = np.array(q[-1], dtype=np.float64)
            if self.scored is not None:
                self.scored[e.name].add(a, q)
            # Diagnostics are kept in float32 (for plots and events; half the memory of an hour at 400 Hz)
            new = {key: _compact(value) for key, value in e.diagnostics.items()}
            e.diagnostics = new  # the estimator's float64 arrays go now, not at its next update
            diagnostics[e.name] = new
            kept = self.diagnostics[e.name]
            # in the order first given (a set's order is the string hash's, new each process)
            for key in [*kept, *(k for k in new if k not in kept)] if self.keep_history else ():
                if key not in kept:  # rows before the key first appeared: nothing
                    kept[key] = Column(new[key].dtype, self._rows_expected)
                    kept[key].extend(_nothing(a, new[key].dtype))
                kept[key].extend(new[key] if key in new else _nothing(len(t), kept[key].dtype))
            for key, mark in e.MARKS.items():  # a warning at each event the estimator marks (cpf-ekf's resets)
                if key in new:
                    self.events += [Event(float(tm), "warn", f"{e.name}: {mark.text}", kind=f"{e.name}: {mark.kind}")
                                    for tm in t[new[key] == 1.0]]
        return Chunk(t, out, diagnostics, in_air)

    # ------------------------------------------------------------ forgetting (a live session)

    def forget(self, before: float) -> None:
        """Drop the IMU rows estimated before ``before`` (s) with their estimates, and the
        compass, GPS and baro samples that no later IMU row can be given: a session of hours
        keeps a window, not everything. What is estimated after it is what a runner that kept
        everything estimates, to the bit (tested). Nothing is dropped with ``keep_history``
        (replay), or once a kind's rows have not arrived in time order (never on a link:
        samples are delivered in arrival order), where the latest to arrive is no longer
        among the latest rows."""
        if self.keep_history or self._in_arrival_order != set(WIDTH):
            return
        imu = self.store[IMU]
        # two estimated rows stay: the gap check reads the one before, the aiding's IMU interval two
        k = min(int(np.searchsorted(imu.column(0), before)), self.done - 2)
        if k <= 0:
            return
        key = imu.view()[k, -1]  # IMU rows arrive in order: every later one arrived after this
        tracked = (BARO if self._phase.source == "baro height" else GPS) if self._phase is not None else None
        for kind in (MAG, GPS, BARO):
            rows = self.store[kind]
            first = int(np.searchsorted(rows.column(rows.width - 1), key, side="right")) - 1  # held at row k
            if kind == MAG:
                first -= 1  # its staleness reads the interval before it
            if kind != MAG and self.uses_aiding:
                first = min(first, self._placer.done[kind])
            if kind == tracked:
                first = min(first, self._heights_seen)
            first = max(first, 0)
            rows.forget(first)
            if kind != MAG and self.uses_aiding:
                self._placer.done[kind] -= first
            if kind == tracked:
                self._heights_seen -= first
                self._phase_rows.forget(first)
        if tracked is not None and self._phase_rows.n:
            # the phase rows still looked up (the latest at each kept height sample), and the
            # one before the first not yet reported (its change is an event)
            r = max(min(int(self._phase_rows.view()[0, 0]) - 1, self._phase_reported - 1), 0)
            self._phase.forget(r)
            self._phase_rows.view()[:] -= r
            self._phase_reported -= r
        imu.forget(k)
        for kept in self.estimates.values():
            kept.forget(k)
        self.done -= k
        for run in self.runs:
            run.start, run.end = run.start - k, run.end - k
        self._placer.forget(k, self.done)

    @property
    def estimated(self) -> int:
        """IMU rows estimated since the start, forgotten ones included."""
        return self.done + self.store[IMU].forgotten

    # ------------------------------------------------------------ what each IMU sample is given

    def _latest_arrived(self, kind: str, a: int, b: int, usable: np.ndarray | None = None) -> np.ndarray:
        """For IMU rows [a, b): the index of the latest sample of ``kind`` to have arrived
        before each, among the ``usable`` ones; -1 where none had."""
        rows = self.store[kind].view()
        if usable is None and kind in self._in_arrival_order:
            # a search, not a sort of every row so far: a session of hours steps a few times a second
            return np.searchsorted(rows[:, -1], self.store[IMU].view()[a:b, -1], side="right") - 1
        index = np.arange(len(rows)) if usable is None else np.flatnonzero(usable)
        k = latest_arrived(rows[index, -1], self.store[IMU].view()[a:b, -1])
        return np.where(k >= 0, index[np.maximum(k, 0)], -1) if len(index) else k

    def _mag_held(self, a: int, b: int) -> np.ndarray | None:
        """The latest compass sample to have arrived before each IMU row, NaN where stale."""
        if not self.use_mag or not self.store[MAG].n:
            return None
        m = self.store[MAG].view()
        return held_field(self.store[IMU].view()[a:b, 0], m[:, 0], m[:, 1:4], self._latest_arrived(MAG, a, b))

    def _height_usable(self, kind: str) -> np.ndarray:
        rows = self.store[kind].view()
        return rows[:, 1] > aid.MIN_PRESSURE_PA if kind == BARO else rows[:, 7] >= 3

    def _in_air(self, a: int, b: int) -> np.ndarray:
        """The ground/air phase at each IMU row, from the heights that arrived before it. The
        source: baro, if a baro sample had arrived by the first IMU row to have any height
        before it, else GPS height (3D fix)."""
        if self._phase is None:
            baro = self._latest_arrived(BARO, 0, b, self._height_usable(BARO))
            gps = self._latest_arrived(GPS, 0, b, self._height_usable(GPS))
            first = np.flatnonzero((baro >= 0) | (gps >= 0))
            if not len(first):
                return np.full(b - a, np.nan)  # no height has arrived yet
            source = "baro height" if baro[first[0]] >= 0 else "GPS height"
            self._phase = PhaseTracker(source)
            t_first = float(self.store[IMU].view()[first[0], 0])
            self.events.append(Event(t_first, "info", f"ground/air phase from {source}"))
        kind = BARO if self._phase.source == "baro height" else GPS
        rows = self.store[kind].view()
        usable = self._height_usable(kind)
        new, use = rows[self._heights_seen:], usable[self._heights_seen:]
        taken = np.zeros(len(new), dtype=bool)
        rows_before = self._phase.n
        if use.any():
            taken[use] = self._phase.add(new[use, 0], self._raw_height(kind, new[use]))
        self._phase_rows.extend(rows_before + np.cumsum(taken))  # the tracker's rows after each sample
        self._heights_seen = len(rows)
        phase = self._phase.series()
        self._phase_events(phase)
        k = self._latest_arrived(kind, a, b)
        n_rows = np.where(k >= 0, self._phase_rows.view()[np.maximum(k, 0), 0], 0).astype(np.int64)
        out = np.full(b - a, np.nan)
        have = n_rows > 0
        j = n_rows[have] - 1
        age = self.store[IMU].view()[a:b, 0][have] - phase.t[j]
        out[have] = np.where(age <= STALE_S, phase.in_air[j], np.nan)
        return out

    @staticmethod
    def _raw_height(kind: str, rows: np.ndarray) -> np.ndarray:
        return pressure_height(rows[:, 1]) if kind == BARO else rows[:, 3]

    def _phase_events(self, phase) -> None:
        for i in range(max(self._phase_reported, 1), len(phase.t)):
            if phase.in_air[i] != phase.in_air[i - 1]:
                self.events.append(Event(float(phase.t[i]), "info", ("in the air" if phase.in_air[i] else "on the ground")
                                         + f" ({phase.source} {phase.height_m[i]:.1f} m above the start)"))
        self._phase_reported = len(phase.t)

    def _aiding(self, a: int, b: int) -> aid.Aiding:
        """GPS and baro on IMU rows [a, b), each sample once (``aiding.Placer``)."""
        imu = self.store[IMU].view()
        for kind in (GPS, BARO):
            self._placer.place(kind, self.store[kind].view(), imu[:, 0], imu[:, -1])
        return self._placer.take(a, b)

    # ------------------------------------------------------------ results

    def times(self) -> np.ndarray:
        """The times of every IMU row estimated so far."""
        return self.store[IMU].column(0)[:self.done] if self._imu_t is None else self._imu_t

    def estimate(self, name: str) -> AttitudeSeries:
        """An estimator's attitude at every IMU row estimated so far (with ``shown_rows``: at
        those rows among them)."""
        q = self.estimates[name].view()
        t = self.times() if self.shown is None else self.times()[self.shown[:len(q)]]
        return AttitudeSeries(name, t, q)

    def scoring_estimate(self, name: str, release: bool = False) -> AttitudeSeries:
        """What scoring reads of an estimator's attitude, as estimated: the whole estimate, or
        with ``scored_rows`` the rows kept for it (``scoredrows``; ``release``: let go by the runner)."""
        if self.scored is None:
            return self.estimate(name)
        return self.scored[name].series(name, self.times(), release)

    def release_inputs(self) -> None:
        """Drop the samples added (IMU, compass, GPS, baro) but the IMU's times, once a whole
        log is estimated (``step(final=True)``): a replay keeps its results, not a second copy
        of its inputs (92 MB of IMU rows for an hour at 400 Hz). No more stepping after it."""
        times = self.store[IMU].column(0)[:self.done]  # (a log's own times are not copied: ``imurows``)
        self._imu_t = times if isinstance(self.store[IMU], ImuRows) else times.copy()
        self.store = {kind: Growing(width) for kind, width in WIDTH.items()}

    @property
    def restarts(self) -> list[tuple[float, float]]:
        """(time, gap before it) of every run after the first."""
        return [(r.t_start, r.gap) for r in self.runs[1:]]

    @property
    def alignment(self) -> est.Alignment | None:
        return self.runs[0].alignment if self.runs else None

    def diagnostic_series(self, name: str) -> Series:
        """An estimator's diagnostics at every IMU row estimated so far: key -> (N,), each
        array made when asked (``diagcolumns``)."""
        return Series(self.diagnostics[name])

    def aiding(self, given_only: bool = False) -> aid.Aiding | None:
        """The GPS and baro measurements handed to the estimators, at every IMU row estimated
        so far, NaN where none was (None when no estimator takes them). ``given_only``: only the
        rows that had one, in order (``aiding_rows`` numbers them)."""
        if not self.uses_aiding:
            return None
        given = self._aiding_given.view()
        if given_only:
            values = given[:, 1:]
        else:
            values = np.full((self.done, AIDING_WIDTH), np.nan)
            values[given[:, 0].astype(np.int64)] = given[:, 1:]
        out = aid.Aiding(*(values[:, k].copy() if w == 1 else values[:, k:k + w].copy()
                           for k, w in zip(np.cumsum([0, *AIDING_WIDTHS[:-1]]), AIDING_WIDTHS)))
        out.origin, out.baro_zero = self._placer.origin, self._placer.baro_zero
        return out

    @property
    def aiding_rows(self) -> np.ndarray:
        """The IMU rows that were handed a GPS or baro measurement (``aiding(given_only=True)``)."""
        return self._aiding_given.column(0).astype(np.int64)

    def phase_series(self):
        return self._phase.series() if self._phase is not None and self._phase.n else None


def latest_arrived(arrival: np.ndarray, at: np.ndarray) -> np.ndarray:
    """For each of ``at`` (arrival keys): the index of the latest sample (they are in time
    order) among those whose ``arrival`` is not later; -1 where there is none. Keys that tie
    (time standing in for arrival) count as arrived."""
    if not len(arrival):
        return np.full(len(at), -1)
    order = np.argsort(arrival, kind="stable")
    latest = np.maximum.accumulate(order)
    count = np.searchsorted(arrival[order], at, side="right")
    return np.where(count > 0, latest[np.maximum(count - 1, 0)], -1)


def held_field(imu_t: np.ndarray, mag_t: np.ndarray, field: np.ndarray, held: np.ndarray) -> np.ndarray:
    """The compass sample ``held`` (index, -1 none) at each IMU time, NaN where there is none or
    it is stale: older than MAG_STALE_PERIODS of the interval before it (at least MAG_STALE_MIN_S)."""
    k = np.maximum(held, 0)
    interval = np.diff(mag_t, prepend=-np.inf)[k]
    max_age = np.maximum(MAG_STALE_MIN_S, MAG_STALE_PERIODS * interval)
    out = field[k].copy()
    out[(held < 0) | (imu_t - mag_t[k] > max_age)] = np.nan
    return out


def held_magnetometer(imu_t: np.ndarray, mag) -> np.ndarray | None:
    """A compass series (``flight.MagSeries``) on the IMU clock, as the runner holds it when
    time stands in for arrival (simulated data, the bench): None without one."""
    if mag is None or not len(mag.t):
        return None
    return held_field(imu_t, mag.t, mag.field, latest_arrived(mag.t, imu_t))


def _compact(values) -> np.ndarray:
    """A diagnostic series as kept: float32 for measures (7 digits, for plots), codes as they are."""
    values = np.asarray(values)
    return values.astype(np.float32) if values.dtype == np.float64 else values


def _nothing(n: int, dtype) -> np.ndarray:
    """Diagnostic values where an estimator gave none: 0 for codes, NaN for measures."""
    return np.zeros(n, dtype) if np.dtype(dtype).kind in "iub" else np.full(n, np.nan, dtype)


def _takes_accel_g(estimator) -> bool:
    """Whether ``estimator.initialize`` takes the accelerometer's reading of g (ours do; an
    estimator written before it was added takes the attitude and the gyro bias only)."""
    return "accel_g" in inspect.signature(estimator.initialize).parameters
