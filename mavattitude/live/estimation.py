"""Estimation on a live link: the replay's core (``runner``), fed packet by packet.

``LiveEstimation`` takes the vehicle's decoded MAVLink messages (``add``) and, on each
``step``, has the runner estimate the IMU samples that arrived since the last step. Every
sample gets its place in the arrival order as it is decoded, and the runner gives each IMU
sample what had arrived before it, so a session's estimates equal those of ``mavattitude
replay`` of its own recording, to the bit, once both chose the same sources. Knows nothing
of sockets; the session feeds it.

On the autopilot's clock, per clock segment:
- the clock is followed by ``readers.collect.ClockTracker``, as a log's is: a jump back (a
  reboot) or ahead counts once 5 samples agree, and starts a new segment if it went back;
  a sample that agrees with neither clock is dropped as corrupt (a GPS without a fix repeats
  the time of its last one: those samples go too);
- samples of a series not newer than its last one are dropped (a log sorts them in), as are
  implausible ones (the reader's limits);
- a compass whose unit is off by a power of 1000 (ArduPilot 4.7's HIGHRES_IMU) is rescaled,
  judged on its first ``MAG_SCALE_SAMPLES`` (a log: on the median of all);
- the IMU and compass sources are chosen once ``ALIGN_S`` of IMU data is in (every source has
  shown up by then; ``imu`` chooses), and, when the session asked the vehicle for the
  parameters a run's policy reads (``policy.wanted_params``), once a declination parameter
  (with the one that says whether the autopilot computes it) and the board trim have arrived,
  or ``PARAMS_WAIT_S`` more have passed (a line says what did not come). A log chooses on all
  of its data: pass the same ``imu`` to compare the two;
- the run's policy is decided then, as replay decides it on a log (``policy.decide``: the
  parameters with the vehicle's own defaults, the declination and the board trim), on the
  vehicle's parameters, identity, first good GPS fix so far and date, else today's. It stays for
  the session: when the vehicle has no fix yet, the first good one later gets an event with the
  model's declination there. Scored against the autopilot's attitude, the estimates are turned
  by the board trim first, as replay turns them, and shown turned;
- non-finite estimates (a filter fault) are left out of the scores and said at the end, as replay says them;
- against the autopilot, replay's checks of the reference run as the data comes
  (``scoring.running_refcheck``: tilt at rest, tilt jump, the autopilot's estimators apart), on
  what replay's run on: the estimated IMU, the reference, GPS, the runner's phase and the
  autopilot's other streams (AHRS2/AHRS3, decoded as the tlog reader decodes them, on the clock
  the others found), named as replay names them on what the session keeps. Each span is said
  when it becomes certain, in replay's words; reference times that repeat are counted as the
  reader counts them and noted at the end. A span can begin in the past, so the scores take a
  reference sample only once the checks have settled it (``RunningComparison.update``'s
  ``settled``): the samples after wait, with the estimates around them.

Memory stays flat however long a session runs: each estimate is scored as it comes
(``running_metrics``: the final metrics are replay's of the same data, the quantiles within
0.1 %), and only the last ``history_s`` of samples, estimates and references is kept (the
rolling metrics and the view read them); the runner forgets the rest (``Runner.forget``).
"""
from __future__ import annotations

import datetime
import math
import time

import numpy as np

from .. import declination as decl
from .. import quaternion as quat
from ..events import Event
from ..flight import AttitudeSeries, Flight
from ..growing import Growing
from ..scoring.metrics import AXES, Comparison, compare, non_finite_warning
from ..readers import IMU_LIMITS, MAG_LIMITS, earth_field_power, pick_imu, pick_mag
from ..readers.collect import CORRUPT, FOLLOWER_KINDS, HELD, JUMP_S, ClockTracker
from ..readers.tlog import MessageDecoder
from ..scoring.imucheck import rate_not_meaningful
from ..core.runner import IMU, Chunk, Runner
from ..scoring.running_metrics import RunningComparison, joined
from ..scoring.refcheck import compared_streams, repeat_notes, suspect_event
from ..scoring.running_refcheck import RunningReferenceCheck
from ..readers.attitudes import name_attitudes
from ..trim import TRIM_PARAMS, describe, trimmed
from ..core.policy import FlightFacts, RunOptions, RunPolicy, decide
from ..readers import identify_vehicle
from .loss import SampleLoss

ALIGN_S = 3.0  # s of IMU data before the sources are chosen
PARAMS_WAIT_S = 2.0  # s more of IMU data to wait for the parameters asked for (policy.wanted_params)
MAG_SCALE_SAMPLES = 5  # compass samples that decide its unit
HISTORY_S = 60.0  # s of samples, estimates and references kept (at least the rolling window)
SCORE_EVERY_S = 0.5  # s of estimates between scorings (each one computes errors for every estimator)
FORGET_EVERY_S = 10.0  # s of estimates between forgetting what is older than the history
REFERENCE_KINDS = {"att_euler": "autopilot", "att_quat": "autopilot_q", "truth_euler": "truth"}
REFERENCE_SOURCES = {"autopilot": "ATTITUDE", "autopilot_q": "ATTITUDE_QUATERNION", "truth": "SIMSTATE"}


class _Segment:
    """Everything of one clock segment (between reboots)."""

    def __init__(self, index: int):
        self.index = index
        self.clock_max = -math.inf
        self.mag_scale: dict[str, float] = {}  # source -> factor its samples are multiplied by
        self.mag_pending: dict[str, list] = {}  # source -> first samples, until the unit is judged
        self.imu: dict[str, Growing] = {}  # source -> rows t, gyro (3), accel (3), arrival
        self.mag: dict[str, Growing] = {}  # source -> rows t, field (3) T, arrival
        self.gps = Growing(12)  # t, lat, lon, alt, vn, ve, vd, fix, sats, h_acc, v_acc, arrival
        self.baro = Growing(4)  # t, pressure Pa, alt, arrival
        self.att: dict[str, Growing] = {}  # "autopilot", "autopilot_q", "truth", "AHRS2", ... -> rows t, q (4)
        self.wall: dict[str, list[float]] = {}  # IMU source -> arrival wall time of each row (record_latency)
        self.imu_key: str | None = None
        self.mag_key: str | None = None
        self.runner: Runner | None = None
        self.fed: dict[str, int] = {}  # rows of each store handed to the runner
        self.events_taken = 0  # of the runner's events
        self.scores: dict[str, RunningComparison] = {}  # estimator (or "autopilot" against truth) -> its score
        self.check: RunningReferenceCheck | None = None  # replay's checks of the reference (against the autopilot)
        self.checked: dict[str, int] = {}  # rows of each store handed to the check (``Growing.appended``)
        self.phase_checked = -math.inf  # s, the latest phase row handed to the check
        self.att_latest: dict[str, float] = {}  # attitude store -> its latest time received (plausible or not)
        self.repeated: dict[str, int] = {}  # attitude store -> samples repeating the latest time (the reader's count)
        self.notes: list = []  # refcheck.LogNote on the reference as a whole, at the segment's end
        self.scored_at = -math.inf  # s, the latest estimate when last scored
        self.forgot_at = -math.inf  # s, the latest estimate when last forgotten


class LiveEstimation:
    """The estimators of ``options`` (a ``policy.RunOptions``; live uses its ``names``,
    ``reference``: "autopilot" or "truth" (SIMSTATE), ``imu``, ``warmup_s``, the parameters,
    ``declination_deg``, ``home``, ``use_mag`` and ``trim``) on a live vehicle's data. The run's
    policy is decided once, as the estimators first start, on what the vehicle sent so far
    (``policy.decide``, as replay decides it on a log).

    ``params_asked``: the session asked the vehicle for the parameters a policy reads
    (``policy.wanted_params``): wait a little for them. ``record_latency``: keep (time_usec,
    monotonic s when estimated) per IMU sample (a bench: it grows). ``history_s``: s of data
    kept. ``errors_for_view``: keep each estimator's errors as they are scored, for ``take_errors``."""

    def __init__(self, options: RunOptions, record_latency: bool = False, params_asked: bool = False,
                 history_s: float = HISTORY_S, errors_for_view: bool = False):
        self.options = options
        self.names = list(options.names)
        self.policy: RunPolicy | None = None  # decided when the estimators first start
        self.declination: float | None = None  # rad, the policy's
        self.declination_choice: decl.Declination | None = None  # the same, with its source
        self.awaiting_fix = False  # chosen without the position a GPS fix would give
        self.use_mag = options.use_mag
        self.imu_choice = options.imu
        self.reference = options.reference
        self.warmup_s = options.warmup_s
        self.decoder = MessageDecoder()
        self.clock = ClockTracker()
        self._held: dict[int, tuple] = {}  # arrival -> sample, until the clock says where it goes
        self.events: list[Event] = []
        self.segments: list[_Segment] = [_Segment(0)]
        self.dropped = 0  # samples corrupt, implausible, or not newer than their series' last
        self.samples = 0  # IMU samples estimated
        self.record_latency = record_latency
        self.latency: list[tuple[float, float, float]] = []  # (t autopilot s, arrival, estimated) monotonic s
        self.params_asked = params_asked
        self.apply_trim = options.trim and options.reference == "autopilot"  # as replay: only against the autopilot
        self.trim: tuple[float, float] | None = None  # rad (roll, pitch): the policy's, when it applies
        self._now = 0.0
        self._warned_imu = False
        self.imu_loss: dict[str, SampleLoss] = {}  # IMU samples lost by the autopilot clock, per stream
        self.history_s = history_s
        self._errors: dict[str, list] | None = {n: [] for n in self.names} if errors_for_view else None
        self.non_finite: dict[str, int] = {}  # estimator -> attitude samples not finite (a filter fault), until said
        self._first_t: float | None = None  # s, the first estimated sample

    @property
    def samples_lost(self) -> SampleLoss | None:
        """The estimated IMU stream's samples lost on the link, by the autopilot's clock (the
        stream with most samples until one is chosen)."""
        key = self.seg.imu_key or max(self.imu_loss, key=lambda k: self.imu_loss[k].received, default=None)
        return self.imu_loss.get(key) if key else None

    @property
    def seg(self) -> _Segment:
        return self.segments[-1]

    @property
    def has_heading(self) -> dict[str, bool]:
        runner = self.seg.runner or next((s.runner for s in reversed(self.segments) if s.runner), None)
        return runner.has_heading if runner else {}

    # ------------------------------------------------------------ input

    def add(self, msg, now: float | None = None) -> None:
        """A message from the vehicle (``now``: its arrival, monotonic s)."""
        self._now = time.monotonic() if now is None else now
        self.decoder.decode(msg, self._sample)

    def _sample(self, kind: str, key: str, t: float, row: tuple) -> None:
        """One decoded sample: its place in the arrival order, then its clock."""
        if kind == "imu":
            loss = self.imu_loss.get(key)
            if loss is None:
                loss = self.imu_loss[key] = SampleLoss()
            loss.add(t)
        if kind in FOLLOWER_KINDS:  # no time of its own (AHRS2, AHRS3): on the clock the others found, as a log's
            if abs(t - self.seg.clock_max) <= JUMP_S:
                self._deliver((kind, key, t, row, None, self._now), self.seg.index)
            return
        arrival = self.clock.seen
        labels, decided = self.clock.push([t])
        for g, label in decided:
            self._deliver(self._held.pop(g), label)
        sample = (kind, key, t, row, arrival, self._now)
        if labels[0] == HELD:
            self._held[arrival] = sample
        else:
            self._deliver(sample, int(labels[0]))

    def _deliver(self, sample: tuple, label: int) -> None:
        kind, key, t, row, arrival, wall = sample
        if label == CORRUPT:
            self.dropped += 1
            return
        while label > self.seg.index:  # the clock went back: a reboot
            self.segments.append(_Segment(self.seg.index + 1))
            self.events.append(Event(t, "warn", f"the autopilot clock went back from "
                                                f"{self.segments[-2].clock_max:.1f} s to {t:.1f} s "
                                                "(a reboot): estimators re-initialised"))
        seg = self.seg
        seg.clock_max = max(seg.clock_max, t)
        if kind == "imu":
            if seg.imu_key is not None and key != seg.imu_key:
                return  # the sources are chosen: the other IMUs are not kept (a session runs for hours)
            if not any(row) or not _within(row, IMU_LIMITS):
                self.dropped += 1
                return
            if self._append(seg.imu, key, 8, t, (*row, arrival)) and self.record_latency:
                seg.wall.setdefault(key, []).append(wall)
        elif kind == "mag":
            if seg.runner is None or key == seg.mag_key:
                self._add_mag(seg, key, t, row, arrival)
        elif kind == "gps":
            gps = (*row[:8], row[8], math.nan)  # GPS_RAW_INT has no vertical accuracy
            self._append_one(seg.gps, t, (*gps, arrival))
            if self.awaiting_fix and decl.is_good_fix(row[0], row[1], row[6], row[7], row[8]):
                self._fix_came(t, decl.Fix(row[0], row[1], row[2]))
        elif kind == "baro":
            self._append_one(seg.baro, t, (*row, arrival))
        elif kind in REFERENCE_KINDS or kind == "stream_euler":  # a stream: its message's name (AHRS2, AHRS3)
            store = REFERENCE_KINDS.get(kind, key)
            if t == seg.att_latest.get(store):
                seg.repeated[store] = seg.repeated.get(store, 0) + 1
            seg.att_latest[store] = max(t, seg.att_latest.get(store, -math.inf))
            q = _attitude(kind, row)
            if q is not None:
                self._append(seg.att, REFERENCE_KINDS.get(kind, key), 5, t, tuple(q))

    def _add_mag(self, seg: _Segment, key: str, t: float, row: tuple, arrival: int) -> None:
        if not any(row) or not all(math.isfinite(v) for v in row):
            return
        scale = seg.mag_scale.get(key)
        if scale is None:  # judge the unit on the first few samples, then let them in
            pending = seg.mag_pending.setdefault(key, [])
            pending.append((t, row, arrival))
            if len(pending) < MAG_SCALE_SAMPLES:
                return
            power, strength = earth_field_power(np.array([r for _, r, _ in pending]))
            scale = seg.mag_scale[key] = 10.0 ** (-3 * power)
            if power:
                self.events.append(Event(t, "info", f"{key}: magnetometer strength {strength * 1e4:.4g} G is "
                                                    f"implausible; rescaled by 1e{-3 * power}"))
            del seg.mag_pending[key]
            for tp, rp, ap in pending:
                self._add_mag(seg, key, tp, rp, ap)
            return
        scaled = tuple(v * scale for v in row)
        if _within(scaled, MAG_LIMITS):
            self._append(seg.mag, key, 5, t, (*scaled, arrival))

    def _append(self, stores: dict, key: str, width: int, t: float, row) -> bool:
        store = stores.get(key)
        if store is None:
            store = stores[key] = Growing(width)
        return self._append_one(store, t, row)

    def _append_one(self, store: Growing, t: float, row) -> bool:
        last = store.last
        if last is not None and t <= last[0]:
            self.dropped += 1
            return False
        store.append((t, *row))
        return True

    # ------------------------------------------------------------ stepping

    def step(self, final: bool = False) -> Chunk | None:
        """Estimate the IMU samples that arrived since the last step (``final``: the session is
        over, estimate what waits for its alignment too)."""
        if final:
            for g, label in self.clock.finish():
                self._deliver(self._held.pop(g), label)
        seg = self.seg
        if seg.runner is None and not self._start(seg):
            return None
        self._feed(seg)
        done = seg.runner.estimated
        chunk = seg.runner.step(final=final)
        self.events += seg.runner.events[seg.events_taken:]
        seg.events_taken = len(seg.runner.events)
        for old in self.segments[:-1]:  # a reboot: score what the last segment estimated
            if old.scored_at != math.inf:
                self._score(old, final=True)
                old.scored_at = math.inf
        if chunk is not None:
            self.samples += len(chunk.t)
            self._first_t = float(chunk.t[0]) if self._first_t is None else self._first_t
            for name, q in chunk.q.items():
                bad = int(np.count_nonzero(~np.isfinite(q).all(axis=1)))
                if bad:
                    self.non_finite[name] = self.non_finite.get(name, 0) + bad
            if self.record_latency:
                estimated = time.monotonic()
                wall = seg.wall[seg.imu_key][done:done + len(chunk.t)]
                self.latency.extend((t, w, estimated) for t, w in zip(chunk.t.tolist(), wall))
            latest = float(chunk.t[-1])
            if latest - seg.scored_at >= SCORE_EVERY_S:
                seg.scored_at = latest
                self._score(seg)
            if latest - seg.forgot_at >= FORGET_EVERY_S:
                seg.forgot_at = latest
                self._forget(seg, latest)
        if final:
            self._score(seg, final=True)
            self.events += [Event(self._first_t, "warn", non_finite_warning(name, bad))
                            for name, bad in self.non_finite.items()]  # as replay says it, once
            self.non_finite = {}
        if chunk is not None and self.trim is not None:  # shown as scored: the vehicle's attitude
            chunk = Chunk(chunk.t, {n: quat.trimmed(q, *self.trim) for n, q in chunk.q.items()}, chunk.diagnostics,
                          chunk.in_air)
        return chunk

    def _start(self, seg: _Segment) -> bool:
        """Choose the sources and start the runner, once enough has arrived to choose."""
        if not seg.imu:
            return False
        first = min(s.column(0)[0] for s in seg.imu.values())
        span = max(s.column(0)[-1] for s in seg.imu.values()) - first
        if span < ALIGN_S:
            return False  # let every source (and the compass, and COMPASS_DEC) show up first
        if span < ALIGN_S + PARAMS_WAIT_S and self._params_missing(seg):
            return False
        if self.imu_choice is not None:
            if self.imu_choice not in seg.imu:
                if not self._warned_imu:
                    self._warned_imu = True
                    self.events.append(Event(first + span, "warn", f"no {self.imu_choice} samples arrive; the "
                                                                   f"link carries {', '.join(sorted(seg.imu))} (--imu)"))
                return False
            seg.imu_key = self.imu_choice
        else:
            seg.imu_key = pick_imu({k: s.n for k, s in seg.imu.items()})
        seg.mag_key = pick_mag(list(seg.mag), seg.imu_key) if self.use_mag else None
        if self.policy is None:
            self._decide(first + span, bool(seg.mag_key))
        seg.runner = Runner(self.names, self.policy.params, self.declination, self.use_mag, seg.imu_key, seg.mag_key,
                            keep_history=False)  # the view takes diagnostics from each step
        return True

    def _params_missing(self, seg: _Segment) -> list[str]:
        """What the policy still waits for from the vehicle, when the session asked for it: a
        declination parameter with the one that says whether the autopilot computes it (any of
        ``DECLINATION_PARAMS``; unless --declination, or no compass), and the board trim."""
        if not self.params_asked:
            return []
        have = self.decoder.params
        missing = []
        if (self.options.declination_deg is None and seg.mag and self.use_mag
                and not any(name in have and auto in have for name, _, auto, _ in decl.DECLINATION_PARAMS)):
            half = [auto if name in have else name for name, _, auto, _ in decl.DECLINATION_PARAMS
                    if name in have or auto in have]  # the other of a pair that came in part
            missing.append(half[0] if half else "a declination parameter ("
                           + ", ".join(name for name, _, _, _ in decl.DECLINATION_PARAMS) + ")")
        if self.apply_trim and not all(name in have for name in TRIM_PARAMS):
            missing.append("/".join(TRIM_PARAMS))
        return missing

    def _decide(self, t: float, has_mag: bool) -> None:
        """The session's policy (``policy.decide``) on what the vehicle sent so far: its
        parameters, its identity, its first good GPS fix and its date (else today's)."""
        missing = self._params_missing(self.seg)
        if missing:
            self.events.append(Event(t, "info", f"no answer from the vehicle within {PARAMS_WAIT_S:g} s for "
                                                f"{'; '.join(missing)}: going on as a log without them"))
        gps = self.seg.gps.view()  # t, lat, lon, alt, vn, ve, vd, fix, sats, h_acc, v_acc, arrival
        good = np.flatnonzero(decl.is_good_fix(gps[:, 1], gps[:, 2], gps[:, 7], gps[:, 8], gps[:, 9]))
        fix = decl.Fix(*map(float, gps[good[0], 1:4])) if len(good) else None
        facts = FlightFacts(dict(self.decoder.params), identify_vehicle(self.decoder.texts)[0], fix, self._date(),
                            where="vehicle")
        policy = self.policy = decide(self.options, facts)
        chosen = policy.declination
        self.declination, self.declination_choice = chosen.rad, chosen
        self.awaiting_fix = chosen.kind in ("held", "none")
        self.events.append(Event(t, "info", f"declination {chosen.text()}"))
        if has_mag and not chosen.known:
            self.events.append(Event(t, "warn", decl.NO_DECLINATION))
        self.events += [Event(t, "info", note) for note in policy.notes]
        self.trim = policy.trim_for(self.apply_trim)
        if self.trim is not None:
            self.events.append(Event(t, "info", f"board trim {describe(self.trim)} (AHRS_TRIM_X/Y): the estimates are "
                                                "turned by it, as the autopilot turns its own attitude"))

    def _trimmed(self, series: AttitudeSeries) -> AttitudeSeries:
        return series if self.trim is None else trimmed(series, self.trim)

    def _date(self) -> datetime.datetime:
        """The vehicle's date (SYSTEM_TIME, as the replay of the recording takes it), else today's."""
        if self.decoder.utc_s is not None:
            return datetime.datetime.fromtimestamp(self.decoder.utc_s, datetime.timezone.utc)
        return datetime.datetime.now(datetime.timezone.utc)

    def _fix_came(self, t: float, fix: decl.Fix) -> None:
        """The first good fix after the start: what the declination is there (the session keeps its own)."""
        self.awaiting_fix = False
        there = decl.choose(self.decoder.params, fix, self._date(), where="vehicle")
        self.events.append(Event(t, "info", f"GPS fix: the declination there is {there.text()}; this session "
                                            f"keeps its {math.degrees(self.declination):.2f}° (--home or "
                                            "--declination give it from the start)"))

    def _score(self, seg: _Segment, final: bool = False) -> None:
        """Score the estimates (against truth, the autopilot too) at the reference samples they
        now cover (``running_metrics``), and that replay's reference checks have settled
        (``_check``; ``final``: the segment's data is complete)."""
        runner, ref = seg.runner, self.reference_series(seg)
        if runner is None or not runner.done or ref is None:
            return
        exclude, settled = self._check(seg, ref, final)
        restarts = [t for t, _ in runner.restarts]
        pairs = [(name, self._trimmed(runner.estimate(name)), restarts, [not r.has_heading[name] for r in runner.runs])
                 for name in self.names]
        autopilot = self.autopilot_series(seg) if self.reference == "truth" else None
        if autopilot is not None:
            pairs.append(("autopilot", autopilot, (), (False,)))
        for name, estimate, restarts, align in pairs:
            score = seg.scores.get(name)
            if score is None:
                score = seg.scores[name] = RunningComparison(name, ref.source, self.warmup_s)
            got = score.update(ref, estimate, restarts, align, exclude, settled)
            if got is not None and self._errors is not None and name in self._errors:
                self._errors[name].append(got)

    def _check(self, seg: _Segment, ref: AttitudeSeries, final: bool) -> tuple[list, float]:
        """Hand replay's reference checks (``running_refcheck``) what arrived since the last
        call, as replay hands its checks the log: the estimated IMU's rows, the reference (raw:
        the check turns the accelerometer by the trim), GPS, the runner's phase and the
        autopilot's other streams, named as replay names them (``name_attitudes`` and
        ``compared_streams`` on what the session keeps). Returns the spans not to score and the
        time before which they are final. Against truth there is nothing to check, as in replay."""
        if self.reference != "autopilot":
            return [], math.inf
        check = seg.check
        if check is None:
            check = seg.check = RunningReferenceCheck(ref.source, self.trim)
        if not check.final:
            def new(name: str, store: Growing) -> np.ndarray:
                start, seg.checked[name] = seg.checked.get(name, 0), store.appended
                return store.view()[max(store.n - (store.appended - start), 0):]

            rows = new("imu", seg.runner.store[IMU])
            check.add_imu(rows[:, 0], rows[:, 1:4], rows[:, 4:7])
            for key, store in seg.att.items():
                if key == "truth":
                    continue
                rows, name = new(key, store), REFERENCE_SOURCES.get(key, key)
                if name == ref.source:
                    check.add_reference(rows[:, 0], rows[:, 1:5])
                else:
                    check.add_stream(name, rows[:, 0], rows[:, 1:5])
            rows = new("gps", seg.gps)
            check.add_gps(rows[:, 0], rows[:, 4:6])
            phase = seg.runner.phase_series()
            if phase is not None:
                taken = phase.t > seg.phase_checked
                check.add_phase(phase.t[taken], phase.in_air[taken])
                seg.phase_checked = float(phase.t[-1])
            self._name_streams(seg, ref, check)
            found = check.finish() if final else check.advance()
            self.events += [suspect_event(s) for s in found]
            if final:  # as replay notes it on the whole log
                key = next(k for k in seg.att if REFERENCE_SOURCES.get(k, k) == ref.source)
                seg.notes = repeat_notes(ref.source, seg.att[key].appended, seg.repeated.get(key, 0))
                self.events += [Event(check.ref_t0, "warn", note.detail) for note in seg.notes]
        return check.excluded(), check.settled

    def _name_streams(self, seg: _Segment, ref: AttitudeSeries, check: RunningReferenceCheck) -> None:
        """The reference's algorithm and the streams that give a second opinion, as replay names
        them on a log (``readers.attitudes``), on the samples the session keeps."""
        streams = {REFERENCE_SOURCES.get(k, k): self._attitude_series(seg, (k,)) for k in seg.att if k != "truth"}
        streams = {k: v for k, v in streams.items() if v is not None}
        if ref.source not in streams:
            return
        vehicle, firmware = identify_vehicle(self.decoder.texts)
        flight = Flight("live", "tlog", attitude=streams[ref.source], attitudes=streams,
                        truth=self._attitude_series(seg, ("truth",)), params=dict(self.decoder.params),
                        vehicle=vehicle, firmware=firmware)
        named = name_attitudes(flight)
        check.algorithm = next(n.algorithm for n in named if n.key == ref.source)
        check.compared = {n.key: n.algorithm for n in compared_streams(ref, named)} if len(streams) > 1 else {}

    @property
    def suspects(self) -> list:
        """The spans of the scored segment's reference not scored (``refcheck.Suspect``), as replay lists them."""
        seg = self._scored_segment()
        return seg.check.suspects if seg is not None and seg.check is not None else []

    @property
    def reference_notes(self) -> list:
        """The notes on the scored segment's reference as a whole (``refcheck.LogNote``), once it ended."""
        seg = self._scored_segment()
        return seg.notes if seg is not None else []

    def yaw_offset_deg(self, name: str) -> float | None:
        """The yaw offset the final metrics remove from the estimator's current span (no
        heading reference), once its first scored second is in; None otherwise. The view
        shows its yaw with it removed, as its yaw error."""
        score = self.seg.scores.get(name)
        return score.yaw_offset if score is not None else None

    def take_errors(self, name: str) -> tuple[np.ndarray, np.ndarray, np.ndarray] | None:
        """An estimator's errors scored since the last call (``errors_for_view``): (t, (N, 3)
        estimate - reference in degrees, scored), yaw without a heading reference with its
        offset removed (as the final metrics), NaN until that offset is known."""
        parts, self._errors[name] = self._errors[name], []
        return joined(parts)

    def _forget(self, seg: _Segment, latest: float) -> None:
        """Drop what is older than the history and no longer needed: what was handed to the
        runner, and what was scored."""
        before = latest - self.history_s
        if seg.scores:  # the estimate sample before the next reference sample to score stays
            before = min(before, min(s.until for s in seg.scores.values()) - 1.0)
        seg.runner.forget(before)
        for store in seg.att.values():
            store.forget(min(int(np.searchsorted(store.column(0), before)), store.n - 1))
        seg.imu = {seg.imu_key: seg.imu[seg.imu_key]}  # the others stopped at the choice
        seg.mag = {k: m for k, m in seg.mag.items() if k == seg.mag_key}
        for name, store in (("imu", seg.imu[seg.imu_key]), ("mag", seg.mag.get(seg.mag_key)),
                            ("gps", seg.gps), ("baro", seg.baro)):
            if store is None:
                continue
            # fed rows go but the last (the next must be newer); the view reads recent GPS
            k = min(seg.fed.get(name, 0), store.n - 1)
            if name == "gps":
                k = min(k, int(np.searchsorted(store.column(0), before)))
            store.forget(k)
            seg.fed[name] = seg.fed.get(name, 0) - max(k, 0)

    def _feed(self, seg: _Segment) -> None:
        """Hand the runner what arrived since the last step."""
        def new(name: str, store: Growing) -> np.ndarray:
            start, seg.fed[name] = seg.fed.get(name, 0), store.n
            return store.view()[start:]

        runner = seg.runner
        rows = new("imu", seg.imu[seg.imu_key])
        runner.add_imu(rows[:, 0], rows[:, 1:4], rows[:, 4:7], rows[:, 7])
        if seg.mag_key in seg.mag:
            rows = new("mag", seg.mag[seg.mag_key])
            runner.add_mag(rows[:, 0], rows[:, 1:4], rows[:, 4])
        runner.add_gps(new("gps", seg.gps))  # the columns of aiding.GPS_COLUMNS
        runner.add_baro(new("baro", seg.baro)[:, [0, 1, 3]])  # t, pressure, arrival

    # ------------------------------------------------------------ results

    @property
    def started(self) -> bool:
        return any(s.runner is not None and s.runner.done for s in self.segments)

    def reference_series(self, seg: _Segment | None = None) -> AttitudeSeries | None:
        """The reference of a segment (default the current one): ATTITUDE (or
        ATTITUDE_QUATERNION) for "autopilot", SIMSTATE for "truth"."""
        keys = ("truth",) if self.reference == "truth" else ("autopilot", "autopilot_q")
        return self._attitude_series(seg or self.seg, keys)

    def autopilot_series(self, seg: _Segment | None = None) -> AttitudeSeries | None:
        return self._attitude_series(seg or self.seg, ("autopilot", "autopilot_q"))

    @staticmethod
    def _attitude_series(seg: _Segment, keys) -> AttitudeSeries | None:
        for key in keys:
            store = seg.att.get(key)
            if store is not None and store.n:
                rows = store.view()
                return AttitudeSeries(REFERENCE_SOURCES.get(key, key), rows[:, 0], rows[:, 1:5])
        return None

    def estimate_series(self, name: str, seg: _Segment | None = None) -> AttitudeSeries | None:
        seg = seg or self.seg
        if seg.runner is None or not seg.runner.done:
            return None
        return self._trimmed(seg.runner.estimate(name))

    def rolling_mae(self, window_s: float) -> dict[str, tuple[float, float, float]]:
        """Per estimator, MAE (degrees) of roll, pitch, yaw over the last ``window_s`` of the
        reference (no warm-up; yaw without a heading reference aligned over the window)."""
        ref = self.reference_series()
        out = {}
        if ref is None or not len(ref.t):
            return out
        for name in self.names:
            e = self.estimate_series(name)
            if e is None:
                continue
            t_end = min(float(ref.t[-1]), float(e.t[-1]))
            r0, r1 = np.searchsorted(ref.t, [t_end - window_s, t_end], side="right")
            e0 = max(int(np.searchsorted(e.t, t_end - window_s - 1.0)) - 1, 0)
            if r1 <= r0:
                continue
            c = compare(AttitudeSeries(ref.source, ref.t[r0:r1], ref.q[r0:r1]),
                        AttitudeSeries(name, e.t[e0:], e.q[e0:]), warmup_s=0.0,
                        align_yaw=not self.has_heading.get(name, True), name=name)
            out[name] = tuple(c.axes[a].mae if c.axes[a] is not None else math.nan for a in AXES)
        return out

    def _scored_segment(self) -> _Segment | None:
        candidates = [s for s in self.segments if s.runner is not None and s.runner.done]
        return max(candidates, key=lambda s: s.runner.estimated) if candidates else None

    def final_comparisons(self) -> tuple[dict[str, Comparison], _Segment | None]:
        """Each estimator (and, against truth, the autopilot) scored over the clock segment
        with most estimates, as replay scores a log: (comparisons, that segment)."""
        seg = self._scored_segment()
        if seg is None:
            return {}, None
        self._score(seg)
        comparisons = {name: score.result() for name, score in seg.scores.items()}
        t = seg.runner.store[IMU].column(0)  # the rows kept: the rate of the last seconds
        why = rate_not_meaningful(float(1.0 / np.median(np.diff(t)))) if len(t) > 1 else None
        for name in self.names:
            if name in comparisons:
                comparisons[name].not_meaningful = why
        return comparisons, seg


def _attitude(kind: str, row: tuple) -> np.ndarray | None:
    """A reference attitude sample as a unit quaternion, None if implausible (as the reader)."""
    if kind.endswith("euler"):
        if not all(math.isfinite(v) and abs(v) < 10.0 for v in row):
            return None
        return np.ravel(quat.from_euler(row[0], row[1], row[2]))
    q = np.asarray(row, dtype=float)
    if not np.isfinite(q).all() or np.linalg.norm(q) < 0.5:
        return None
    return q / np.linalg.norm(q)


def _within(row, limits) -> bool:
    for cols, limit in limits:
        if math.sqrt(sum(v * v for v in row[cols])) >= limit or any(v != v for v in row[cols]):
            return False
    return True
