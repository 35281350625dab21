"""Replay: a flight in, estimates and their scores out. The estimation itself is the
``runner``'s (the same as a live session's); this chooses the sources, scores the estimates
against the reference and gathers what the report and the view show."""
from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, field

import numpy as np

from .. import aiding as aid
from .. import declination as decl
from .. import quaternion as quat
from .. import estimators as est
from ..scoring.broadscore import broad_measures
from ..errors import InputError
from ..memory import give_back_free_pages
from ..events import Event
from ..flight import GRAVITY, AttitudeSeries, Flight
from ..scoring.imucheck import accel_at_rest, accel_scale_warning, rate_not_meaningful
from ..scoring.metrics import Comparison, compare, non_finite_warning
from ..core.policy import FlightFacts, RunOptions, RunPolicy, decide
from ..phase import PhaseSeries
from ..scoring.refcheck import (autopilot_disagreement, check_reference, excluded_spans, suspect_event,
                                whole_log_notes)
from ..readers import best_imu_source, imu_rate, mag_for_imu
from ..readers.attitudes import SECONDARY_KEYS, NamedAttitude, name_attitudes
from ..core.runner import REINIT_GAP_S, STEP_ROWS, Runner
from ..core.scoredrows import bracket_rows
from ..trim import describe
from ..trim import trimmed  # noqa: F401  (replay's callers and tests take it from here)


REFERENCE_WORDS = ("autopilot", "truth", "ekf")  # --reference besides a stream's name
COPY_SHARE = 0.9  # a stream equal to another on more than this share of samples is a copy of it
ALGORITHM_KINDS = {"DCM": "ArduPilot's complementary filter", "PX4 Q": "PX4's complementary filter",
                   "SITL": "the simulator's attitude"}  # said beside the name in the table's title


class NoReference(InputError):
    """The log has not the reference asked for (``evaluate`` skips such a log)."""


@dataclass(frozen=True)
class Reference:
    """What the estimates are scored against: a stream of ``Flight.attitudes`` (or the truth),
    the algorithm that made it (``readers.attitudes``) and the --reference that chose it."""
    stream: str  # "ATT", "EKF1", "XKF1[1]", ... or the truth's source ("SIM", "SIMSTATE", ...)
    algorithm: str  # "DCM", "EKF1", "EKF3 core 0", "PX4 EKF2", "truth", "unknown", ...
    choice: str  # "autopilot", "truth", "ekf" or the stream's name as given
    evidence: str = ""  # how the primary's algorithm was named (a stream's own message names the others)

    def as_dict(self) -> dict:
        return {"stream": self.stream, "algorithm": self.algorithm, "choice": self.choice}

    @property
    def label(self) -> str:
        """For the table's title: "ATT (DCM, ArduPilot's complementary filter; AHRS_EKF_USE=0)"."""
        if self.algorithm == "truth":
            return f"{self.stream} (the simulator's ground truth)"
        kind = f", {ALGORITHM_KINDS[self.algorithm]}" if self.algorithm in ALGORITHM_KINDS else ""
        return f"{self.stream} ({self.algorithm}{kind}" + (f"; {self.evidence})" if self.evidence else ")")


@dataclass
class ReplayResult:
    flight: Flight
    imu_source: str  # key into flight.imu of the IMU the estimators ran on
    reference: AttitudeSeries  # what the comparisons score against (a stream of flight.attitudes, or flight.truth)
    estimates: dict[str, AttitudeSeries]  # estimator name -> its attitude at the IMU timestamps
    comparisons: dict[str, Comparison]  # estimator name (and "autopilot" when scoring against truth)
    reference_info: Reference | None = None  # which stream the reference is, and its algorithm
    # The autopilot's other streams scored as the estimators are ("autopilot:EKF1 (EKF1)" -> its
    # comparison, and its series), see score_autopilot_streams
    stream_comparisons: dict[str, Comparison] = field(default_factory=dict)
    stream_series: dict[str, AttitudeSeries] = field(default_factory=dict)
    events: list[Event] = field(default_factory=list)
    declination: decl.Declination = decl.Declination(0.0, "none (0)")  # as used, and its source
    mag_source: str | None = None
    alignment: est.Alignment | None = None
    phase: PhaseSeries | None = None  # ground/air, when the log has a height source
    # estimator name -> diagnostic name -> (N,) series at the IMU timestamps (a runner's
    # ``diagcolumns.Series``: each array made when asked; hold one at a time)
    diagnostics: dict[str, Mapping[str, np.ndarray]] = field(default_factory=dict)
    # estimator name -> what happened to its accelerometer updates, see accel_state_events
    estimator_events: dict[str, dict] = field(default_factory=dict)
    params: dict = field(default_factory=dict)  # estimator name -> its parameter dataclass
    # GPS / baro handed to the estimators, when one used them: only the IMU rows that had one, in order
    aiding: aid.Aiding | None = None
    trim: tuple[float, float] | None = None  # (roll, pitch) rad the estimates were turned by, see RunPolicy.trim_for
    suspects: list = field(default_factory=list)  # refcheck.Suspect: where the reference is not trusted
    reference_notes: list = field(default_factory=list)  # refcheck.LogNote: about the reference as a whole
    restarts: list[float] = field(default_factory=list)  # s: where the estimators started again after a gap
    imu_rate_hz: float = 0.0  # the IMU's median rate
    not_meaningful: str | None = None  # why the estimators' scores are not meaningful (imucheck); None: they are
    accel_g_reading: tuple[float | None, bool] = (None, False)  # m/s², whether at rest (imucheck.accel_at_rest)
    # the IMU rows ``estimates`` hold, when only those the view draws are kept (``compact``); None: every row
    shown_rows: np.ndarray | None = None
    nonfinite: dict[str, int] = field(default_factory=dict)  # estimator -> rows estimated not finite

    @property
    def scoring(self) -> dict:
        """How the estimates were scored, beyond the reference: the board trim applied, the
        spans of reference not scored and the notes on the reference as a whole, whether
        the scores mean anything (the IMU's rate) and the accelerometer's reading of g."""
        trim = None if self.trim is None else {"roll_deg": round(math.degrees(self.trim[0]), 4),
                                               "pitch_deg": round(math.degrees(self.trim[1]), 4)}
        g, at_rest = self.accel_g_reading
        return {"board_trim": trim, "reference_suspect": [s.as_dict() for s in self.suspects],
                "reference_notes": [n.as_dict() for n in self.reference_notes],
                "meaningful": self.not_meaningful is None, "why": self.not_meaningful,
                "imu_rate_hz": round(self.imu_rate_hz, 3),
                "accel_g_reading": {"ms2": None if g is None else round(g, 4), "at_rest": at_rest,
                                    "scale_error": None if g is None else round(g / GRAVITY - 1.0, 4)}}

    @property
    def metrics(self) -> dict:
        """What ``replay --json`` writes: per estimator and axis the statistics, its events,
        diagnostics and parameters; ``scoring``."""
        from .report import estimator_extras, to_json_dict
        return to_json_dict(self.flight.path, self.reference_object, self.comparisons, estimator_extras(self),
                            scoring=self.scoring, events=self.events, declination=self.declination,
                            streams=self.stream_comparisons)

    @property
    def reference_object(self) -> dict:
        """The JSON's ``reference``: {"stream", "algorithm", "choice"} (nulls without a reference)."""
        if self.reference_info is None:
            return {"stream": None, "algorithm": None, "choice": None}
        return self.reference_info.as_dict()

    def write_json(self, path) -> None:
        """The metrics as JSON (``replay --json``)."""
        from ..outputs import Outputs
        from .report import estimator_extras, write_json
        with Outputs(inputs=[self.flight.path]) as outputs, outputs.file(path, "write_json", "json").writing() as to:
            write_json(to, self.flight.path, self.reference_object, self.comparisons, estimator_extras(self),
                       scoring=self.scoring, events=self.events, declination=self.declination,
                       streams=self.stream_comparisons)

    def write_csv(self, folder) -> None:
        """reference.csv and <estimator>.csv in ``folder`` (``replay --export``)."""
        from .report import write_csv
        if self.reference is None:
            raise InputError(self.flight.path, "no reference attitude to write")
        write_csv(folder, self.reference, self.estimates)

    def write_rrd(self, path) -> None:
        """The Rerun recording (``replay --rrd``)."""
        from .. import view
        from ..outputs import Outputs
        from ..view.sink import close_sink, open_sink, plan_sink
        with Outputs(inputs=[self.flight.path]) as outputs:
            sink = plan_sink("rrd", path, outputs)
            rec = open_sink(sink, "mavattitude", str(self.flight.path))
            view.log_replay(self, rec)
            close_sink(rec, sink)


def is_ekf(algorithm: str) -> bool:
    """An EKF's attitude: ArduPilot's EKF1/2/3 (any core) or PX4's EKF2."""
    return algorithm.startswith(("EKF", "PX4 EKF2"))


def choose_reference(flight: Flight, choice: str, named: list[NamedAttitude] | None = None) -> Reference | None:
    """The stream --reference names (``REFERENCE_WORDS`` or a key of ``flight.attitudes``, any case):

    - "autopilot": the primary (``flight.attitude``; None when the log has none);
    - "truth": the simulator's ground truth;
    - "ekf": the EKF where the log has one: the primary if it is an EKF, else the first EKF
      stream of the algorithm's own message (EKF1, NKF1[0], XKF1[0]), else a secondary named EKF (AHR2, AHRS2);
    - a stream's name: that stream.
    NoReference (naming the log, and the streams it has) when the log has no such stream.
    ``named``: ``name_attitudes(flight)``, when already made."""
    choice = choice.lower() if choice.lower() in REFERENCE_WORDS else choice
    if choice == "truth":
        if flight.truth is None:
            raise NoReference(flight.path, "--reference truth, but the log has no ground truth "
                                           "(SIM in .bin, SIMSTATE in .tlog, vehicle_attitude_groundtruth in .ulg)")
        return Reference(flight.truth.source, "truth", "truth")
    named = name_attitudes(flight) if named is None else named
    if choice == "autopilot":
        first = next((n for n in named if n.primary), None)
        return None if first is None else Reference(first.key, first.algorithm, choice, first.evidence)
    if choice == "ekf":
        ekfs = sorted((n for n in named if is_ekf(n.algorithm)),
                      key=lambda n: (not n.primary, n.key in SECONDARY_KEYS))  # stable: the log's order otherwise
        if not ekfs:
            raise NoReference(flight.path, f"--reference ekf, but the log has no EKF attitude ({_streams_said(named)})")
        return Reference(ekfs[0].key, ekfs[0].algorithm, "ekf", ekfs[0].evidence if ekfs[0].primary else "")
    found = next((n for n in named if n.key.lower() == choice.lower()), None)
    if found is None:
        raise NoReference(flight.path, f"has no attitude stream {choice!r} (--reference); it has: "
                                       f"{_streams_said(named)}; or use {', '.join(REFERENCE_WORDS)}")
    return Reference(found.key, found.algorithm, choice, found.evidence if found.primary else "")


def _streams_said(named: list[NamedAttitude]) -> str:
    return ", ".join(f"{n.key} ({n.algorithm})" for n in named) or "no autopilot attitude"


def is_copy(a: NamedAttitude, b: NamedAttitude) -> bool:
    """Whether two streams are one estimate (equal on more than COPY_SHARE of their samples)."""
    return max(a.equals.get(b.key, 0.0), b.equals.get(a.key, 0.0)) > COPY_SHARE


def autopilot_streams(named: list[NamedAttitude], reference_key: str) -> list[NamedAttitude]:
    """The autopilot's streams scored beside the estimators: all but the reference and its
    copies (AHR2 equal to EKF1, ATT to XKF1[0], ...), one of each estimate: the stream of the
    algorithm's own message before the secondary (AHR2, AHRS2) that repeats it."""
    ref = next((n for n in named if n.key == reference_key), None)
    kept: list[NamedAttitude] = []
    for n in sorted(named, key=lambda n: n.key in SECONDARY_KEYS):  # stable: the log's order otherwise
        if n.key == reference_key or (ref is not None and is_copy(n, ref)) or any(is_copy(n, k) for k in kept):
            continue
        kept.append(n)
    return kept


def stream_row(n: NamedAttitude) -> str:
    """A stream's row name: "autopilot:DCM (AHR2)"."""
    return f"autopilot:{n.algorithm} ({n.key})"


def score_autopilot_streams(flight: Flight, streams: list[NamedAttitude], ref: AttitudeSeries, warmup_s: float,
                            exclude=()) -> tuple[dict[str, Comparison], dict[str, AttitudeSeries]]:
    """Each stream scored against ``ref`` as the estimators are (its gaps, its warm-up, the
    untrusted spans ``exclude``), by row name (``stream_row``), with its series. No board trim:
    the autopilot's streams come as the autopilot logged them (AHRS_TRIM_X/Y does not explain
    EKF1's offsets from ATT on the shared logs)."""
    comparisons, series = {}, {}
    for n in streams:
        row = stream_row(n)
        series[row] = flight.attitudes[n.key]
        comparisons[row] = compare(ref, series[row], warmup_s=warmup_s, name=row, max_gap_s=REINIT_GAP_S,
                                   exclude=exclude)
    return comparisons, series


def choose_imu(flight: Flight, imu_source: str | None = None, imu_family: str | None = None) -> str:
    """The IMU series to estimate from: ``imu_source`` (--imu) if given, else the best of
    ``imu_family`` (--imu-source; default: the best present). InputError if there is none."""
    if imu_source is None:
        try:
            return best_imu_source(flight, imu_family)
        except KeyError as exc:
            raise InputError(flight.path, f"{exc.args[0]} (--imu-source)") from None
    if imu_source not in flight.imu:
        raise InputError(flight.path, f"has no IMU source {imu_source!r} (--imu); it has: {', '.join(flight.imu)}")
    return imu_source


def run_estimators(flight: Flight, policy: RunPolicy, progress=None,
                   scored_against: AttitudeSeries | None = None, shown_rows: np.ndarray | None = None) -> Runner:
    """Run the policy's estimators over the chosen IMU of a whole flight (``choose_imu``): the
    runner, which holds estimates, diagnostics and events. ``progress(fraction)`` is called as
    it goes. ``scored_against``: the reference the estimates will be scored against, when the
    whole estimates are wanted only for the view: kept in float32, and in float64 only at the
    rows scoring reads (``Runner.scoring_estimate``; an hour at 400 Hz: 46 -> 29 MB an estimator).
    ``shown_rows``: and only at these rows in float32 (``view.drawn_rows``: 1 MB, not 23)."""
    imu_source = choose_imu(flight, policy.options.imu, policy.options.imu_family)
    mag_source = mag_for_imu(flight, imu_source) if policy.use_mag else None
    rows = None if scored_against is None else bracket_rows(flight.imu[imu_source].t, scored_against.t)
    runner = Runner(policy.names, policy.params, policy.declination.rad, policy.use_mag, imu_source, mag_source,
                    scored_rows=rows, shown_rows=shown_rows)
    runner.add_flight(flight)
    runner.step(final=True, chunk=False, progress=progress)
    runner.release_inputs()  # the flight holds them; the runner's copy would double the IMU
    give_back_free_pages()  # what the steps freed between the arrays kept (an hour's: 70 MB)
    return runner


def accel_state_events(t: np.ndarray, codes: np.ndarray, states: tuple) -> dict[str, dict]:
    """For each accel state other than 0 ("used"): samples, spans (runs of consecutive
    samples) and seconds spent in it."""
    out = {}
    dt = np.diff(t, append=t[-1]) if len(t) else t
    for code, state in enumerate(states):
        if code == 0:
            continue
        hit = codes == code
        starts = np.count_nonzero(hit[1:] & ~hit[:-1]) + int(bool(len(hit)) and hit[0])
        out[state] = {"samples": int(np.count_nonzero(hit)), "spans": int(starts),
                      "seconds": round(float(dt[hit].sum()), 3)}
    return out


def marked_events(t: np.ndarray, marks: np.ndarray) -> dict:
    """Events an estimator marks in a diagnostic (``Estimator.MARKS``, 1.0 at each; cpf-ekf's
    watchdog resets): count and times (s)."""
    hit = np.asarray(marks) == 1.0
    return {"count": int(np.count_nonzero(hit)), "times": [round(float(x), 3) for x in t[hit]]}


def run_replay(flight: Flight, names: list[str], progress=None, **options) -> ReplayResult:
    """``replay_flight`` in short, for scripts and tests: ``options`` are ``RunOptions``' fields
    (``params`` as the API takes it, ``RunOptions.of``)."""
    return replay_flight(flight, RunOptions.of(names, **options), progress)[0]


def replay_policy(flight: Flight, policy: RunPolicy, progress=None, compact: bool = False) -> ReplayResult:
    """Estimate with every estimator of the policy and score each against the reference.

    The reference (``policy.reference``): see ``choose_reference`` ("autopilot", "truth", "ekf"
    or a stream such as "EKF1"). The autopilot's other streams are scored against it too
    (``score_autopilot_streams``); with truth the primary's row is "autopilot" among the
    estimators' and the other streams' rows are "autopilot:EKF1 (EKF1)", .... Against the
    autopilot's primary the estimates are turned by the board trim first, as the autopilot turns
    its own (``RunPolicy.trim_for``); not against another stream, which the autopilot logs untrimmed.
    ``compact``: the estimates are kept whole for the view only (``ReplayResult.estimates`` in
    float32; scored from the float64 rows scoring reads, the same numbers to the bit: ``scoredrows``),
    and ``flight`` keeps only the IMU series the estimators run on (``drop_other_imus``), and of
    it, once the reference is checked, its times (``keep_imu_times_only``).
    """
    names, warmup_s = policy.names, policy.warmup_s
    if compact:
        drop_other_imus(flight, choose_imu(flight, policy.options.imu, policy.options.imu_family))
    named = name_attitudes(flight)
    chosen = choose_reference(flight, policy.reference, named)
    ref = None if chosen is None else flight.truth if chosen.algorithm == "truth" else flight.attitudes[chosen.stream]
    against_truth = chosen is not None and chosen.algorithm == "truth"

    declination = policy.declination
    shown_rows = _drawn_rows(flight, policy, named, chosen, ref) if compact else None
    runner = run_estimators(flight, policy, progress, scored_against=ref if compact else None,
                            shown_rows=shown_rows)
    estimates = {name: runner.estimate(name) for name in names}
    # what scoring reads: the same series, or (compact) the float64 rows it reads
    scored = {name: runner.scoring_estimate(name, release=True) for name in names} if compact else estimates
    give_back_free_pages()  # the rows kept a step at a time, now joined (an hour's: 40 MB)
    events = _events(flight, runner, declination)
    imu = flight.imu[runner.imu_source]
    rate = imu_rate(imu)
    not_meaningful = rate_not_meaningful(rate)
    g_reading = accel_at_rest(imu.t, imu.gyro, imu.accel)
    if (scale := accel_scale_warning(*g_reading, runner.estimators)) is not None:
        events.append(Event(float(imu.t[0]), "warn", scale))
    applied_trim = policy.trim_for(ref is not None and ref is flight.attitude)
    if applied_trim:
        turned = list(estimates.values()) + ([] if scored is estimates else list(scored.values()))
        for series in turned:  # in place, a step at a time: an hour's estimates are not copied
            for a in range(0, len(series.q), STEP_ROWS):
                series.q[a:a + STEP_ROWS] = quat.trimmed(series.q[a:a + STEP_ROWS], *applied_trim)
        events.append(Event(flight.time_span[0], "info", "estimates turned by the board trim AHRS_TRIM_X/Y "
                            f"({describe(applied_trim)}) "
                            "before scoring and drawing, as the autopilot turns its own (--no-trim: raw); "
                            "the autopilot's other streams are scored as logged"))
    for name, series in estimates.items():
        bad = runner.nonfinite[name]  # (as estimated: the board trim keeps a row finite or not)
        if bad:
            events.append(Event(float(series.t[0]), "warn", non_finite_warning(name, bad)))
    restarts = [t for t, _ in runner.restarts]
    comparisons, streams, stream_series = {}, {}, {}
    suspects, notes = [], []
    if ref is not None and not against_truth:
        phase = runner.phase_series()
        suspects = check_reference(ref, flight.imu[runner.imu_source], applied_trim,
                                   phase.on_clock if phase is not None else None, flight.gps)
        suspects = sorted(suspects + autopilot_disagreement(ref, flight, named), key=lambda s: s.start)
        notes = whole_log_notes(ref, flight.repeated.get(ref.source, 0))
        events += [suspect_event(s) for s in suspects]
        events += [Event(float(ref.t[0]), "warn", note.detail) for note in notes]
    if compact:  # nothing reads the IMU's samples from here on
        keep_imu_times_only(flight, runner.imu_source)
    if ref is not None:
        for name, series in scored.items():
            comparisons[name] = compare(ref, series, warmup_s=warmup_s, align_yaw=not runner.has_heading[name],
                                        name=name, restarts=restarts, max_gap_s=REINIT_GAP_S,
                                        exclude=excluded_spans(suspects) + flight.unscored_spans)
            comparisons[name].not_meaningful = not_meaningful
        if against_truth and flight.attitude is not None:
            comparisons["autopilot"] = compare(ref, flight.attitude, warmup_s=warmup_s, name="autopilot")
        primary = flight.attitude.source if against_truth and flight.attitude is not None else None
        streams, stream_series = score_autopilot_streams(
            flight, autopilot_streams(named, primary or chosen.stream), ref, warmup_s,
            excluded_spans(suspects) + flight.unscored_spans)
        if against_truth:  # BROAD's error-quaternion measures, beside the Euler axes
            headings = {**runner.has_heading, "autopilot": True}
            for name, comp in comparisons.items():
                series = scored.get(name, flight.attitude)
                comp.broad = broad_measures(ref, series, comp, heading=headings[name])
    else:
        events.append(Event(flight.time_span[0], "warn",
                            "the log has no attitude reference (ATT / ATTITUDE / vehicle_attitude): nothing to score against"))
    imu_t = runner.times()
    diagnostics = {name: runner.diagnostic_series(name) for name in names}
    estimator_events = {e.name: accel_state_events(imu_t, diagnostics[e.name]["accel_state"], e.ACCEL_STATES)
                        for e in runner.estimators if "accel_state" in diagnostics[e.name]}
    for e in runner.estimators:
        marked = {mark.counted_as: marked_events(imu_t, diagnostics[e.name][key])
                  for key, mark in e.MARKS.items() if key in diagnostics[e.name]}
        if marked:
            estimator_events.setdefault(e.name, {}).update(marked)
    return ReplayResult(flight=flight, imu_source=runner.imu_source, reference=ref,
                        estimates=estimates, comparisons=comparisons, events=events, reference_info=chosen,
                        stream_comparisons=streams, stream_series=stream_series,
                        declination=declination,
                        mag_source=runner.mag_source, alignment=runner.alignment, phase=runner.phase_series(),
                        diagnostics=diagnostics, estimator_events=estimator_events,
                        params={e.name: e.params for e in runner.estimators}, aiding=runner.aiding(given_only=True),
                        trim=applied_trim, suspects=suspects, reference_notes=notes, restarts=restarts, imu_rate_hz=rate,
                        not_meaningful=not_meaningful, accel_g_reading=g_reading, shown_rows=shown_rows,
                        nonfinite=dict(runner.nonfinite))


def _drawn_rows(flight: Flight, policy: RunPolicy, named: list[NamedAttitude], chosen: Reference | None,
                ref: AttitudeSeries | None) -> np.ndarray:
    """The IMU rows the view draws of an estimate (``view.drawn_rows``), for the length the
    view's rates are chosen for: the flight's span, or a stream drawn beside it that is longer."""
    from ..view.decimation import drawn_duration, drawn_rows  # (no Rerun)

    imu = flight.imu[choose_imu(flight, policy.options.imu, policy.options.imu_family)]
    against_truth = chosen is not None and chosen.algorithm == "truth"
    primary = flight.attitude.source if against_truth and flight.attitude is not None else None
    streams = [] if ref is None else [flight.attitudes[n.key] for n in autopilot_streams(named, primary or chosen.stream)]
    drawn = [s for s in (ref, flight.attitude, flight.truth, *streams) if s is not None]
    return drawn_rows(imu.t, drawn_duration(flight, [imu.t, *(s.t for s in drawn)]))  # an estimate is on imu.t


def keep_imu_times_only(flight: Flight, source: str) -> None:
    """Let go of the gyro and accelerometer samples of IMU ``source`` (left with no rows, so that
    a reader of them fails rather than reads nothing) and of their order in the log (None, as
    where a log has none): what a replay reads of it after checking the reference, and all the
    view draws of it, is its times (81 MB of an hour at 400 Hz)."""
    imu = flight.imu[source]  # (the series itself: whoever holds it)
    imu.gyro, imu.accel, imu.arrival = imu.gyro[:0].copy(), imu.accel[:0].copy(), None


def drop_other_imus(flight: Flight, source: str) -> None:
    """Let go of the IMU series but ``source`` (a second IMU of an hour at 400 Hz: 92 MB through
    estimating, scoring and the view), but for one that begins or ends the flight's time span,
    which the events and the view read (it stays the same to the bit)."""
    span, every = flight.time_span, flight.imu
    flight.imu = {source: every[source]}
    for key, series in every.items():
        a, b = flight.time_span
        if key != source and len(series.t) and (series.t[0] < a or series.t[-1] > b):
            flight.imu[key] = series  # it begins or ends the span: kept
    flight.imu = {key: s for key, s in every.items() if key in flight.imu}  # in the log's order
    assert flight.time_span == span


def replay_flight(flight: Flight, options: RunOptions, progress=None,
                  compact: bool = False) -> tuple[ReplayResult, list[str]]:
    """Replay a log as the command does: the policy decided on the log's own parameters
    (``policy.decide``: the defaults a log supplies where the user gave none, its declination
    and board trim), then ``replay_policy``: the result, and a note per parameter the log
    supplied (also in its events). ``compact``: see ``replay_policy``."""
    policy = decide(options, FlightFacts.of(flight))
    result = replay_policy(flight, policy, progress, compact)
    result.events += [Event(flight.time_span[0], "info", note) for note in policy.notes]
    return result, list(policy.notes)


def _events(flight: Flight, runner: Runner, declination: decl.Declination) -> list[Event]:
    """The runner's events, what the reader noticed, and the replay's own."""
    t0 = float(flight.imu[runner.imu_source].t[0])
    events = list(runner.events)
    events.append(Event(t0, "info", f"declination {declination.text()}"))
    if runner.mag_source and not declination.known:
        events.append(Event(t0, "warn", decl.NO_DECLINATION))
    if runner.phase_series() is None:
        events.append(Event(t0, "info", "no baro or GPS height: ground/air phase unknown"))
    events += [Event(t0, "info", note) for note in flight.notes]
    events += [Event(t0, "warn", warning) for warning in flight.warnings]
    return sorted(events, key=lambda e: e.t)
