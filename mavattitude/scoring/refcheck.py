"""Where the autopilot's own attitude cannot be right, judged by the log's own IMU and by the
autopilot's other estimators.

A real log's reference is the autopilot's estimate, and it has faults of its own. Four checks:

- **tilt at rest**: on the ground and still (rotating slower than ``REST_RATE``, the
  accelerometer's 1 s mean within ``REST_ACCEL`` of g, and slower than ``REST_SPEED`` where
  GPS says: a plane braking on its runway turns nothing yet its accelerometer is not level),
  the accelerometer measures gravity alone: a reference tilt more than ``TILT_AT_REST_DEG`` from it, for ``MIN_REST_SPAN_S`` or
  longer, is the reference's fault (the board trim is applied to the accelerometer first, as
  the autopilot applies it to its attitude). Only where the ground/air phase is known: a
  hovering copter's accelerometer does not measure its tilt.
- **tilt jump**: between two reference samples the direction of gravity in the body turns by
  more than the gyros allow (twice the integrated rate plus ``JUMP_MARGIN_DEG``): the reference
  jumped (a crash that saturated its estimate, a lane switch, a reset). Yaw is not judged: an
  EKF's yaw resets to its compass or GPS are its own business, and yaw is not ranked.
  The span flagged runs from the jump to ``JUMP_HOLD_S`` after it.
- **autopilot disagrees**: the autopilot's own estimators (the reference and each other stream
  of ``Flight.attitudes`` that is not a copy of it, ``readers.attitudes.name_attitudes``) differ
  in tilt by more than ``DISAGREE_DEG`` for ``DISAGREE_MIN_S`` or longer: at most one of them is
  right, and nothing in the log says which. Measured (``scripts/reference_spread.py --flags``)
  on the shared logs' 60 pairs, the tilt angle between the two: modern DCM/EKF2/EKF3 pairs differ
  by a median 0.1-2.3°, their 99th percentile under 6.1° but for a crash, and stay above 10° for
  at most 4.6 s (SITL vibration; the 4.x real copters: never); the known bad logs stay above 10°
  for minutes (the 88° log 862 s, nearly all of it; gps-flight-20141009-31 202 s; the plane
  roverfolder log 60 s, above 20° nearly throughout). 10° is ten times the modern spread and
  10 s twice the longest modern transient. Also flagged at that setting: plane-3.1-flight-329
  (14 s), a plane's crash (17 s) and the SITL quadplane's AHRS3 (EKF2, 93 s). The time counted
  is the time above ``DISAGREE_DEG``; a dip below it shorter than ``DISAGREE_BRIDGE_S``, or a
  gap (nothing there says the two agree), does not end a span (``disagreeing_spans``).
- **repeated times**: reference samples that repeat the time of the one before (the reader
  keeps the first of each time and drops the rest): not a span but a note on the whole log
  (``LogNote``), saying what was done; what is left is in order and scored.

Reference samples inside a flagged span are not scored (``metrics.compare(exclude=...)``); the
spans and the notes are listed on the terminal, in the JSON and in evaluate's report.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .. import quaternion as quat
from ..events import Event
from ..flight import GRAVITY, AttitudeSeries, Flight, GpsSeries, ImuSeries
from ..readers.attitudes import MOST as SAME_SHARE, name_attitudes

TILT_AT_REST_DEG = 5.0
REST_RATE = 0.05  # rad/s, mean over 1 s
REST_ACCEL = 0.03  # share of g, the 1 s mean's distance from g
REST_SPEED = 0.5  # m/s, GPS ground speed
MIN_REST_SPAN_S = 2.0
JUMP_MARGIN_DEG = 20.0
JUMP_HOLD_S = 5.0
MAX_JUMP_STEP_S = 2.0  # reference samples further apart are a gap, not a jump
DISAGREE_DEG = 10.0
DISAGREE_MIN_S = 10.0
DISAGREE_BRIDGE_S = 2.0
DISAGREE_MAX_GAP_S = 1.0  # no comparison across a stream's samples further apart than this
REPEATED_SHARE = 0.005  # flag the log when more reference samples than this repeat a time


@dataclass
class Suspect:
    """A stretch of reference that is not to be trusted, and not scored: [start, end] s."""
    kind: str  # "tilt at rest", "tilt jump", "autopilot disagrees"
    start: float
    end: float
    detail: str

    def as_dict(self) -> dict:
        return {"kind": self.kind, "start_s": round(self.start, 3), "end_s": round(self.end, 3), "detail": self.detail}


@dataclass
class LogNote:
    """Something wrong with the reference over the whole log, and what was done about it
    (nothing is left out of the scoring for it)."""
    kind: str  # "repeated times"
    detail: str

    def as_dict(self) -> dict:
        return {"kind": self.kind, "detail": self.detail}


def check_reference(ref: AttitudeSeries, imu: ImuSeries, trim, in_air_at=None,
                    gps: GpsSeries | None = None) -> list[Suspect]:
    """Every suspect stretch of ``ref``, in time order. ``trim``: (roll, pitch) rad or None;
    ``in_air_at``: t -> 1 (air) / 0 (ground) / NaN (unknown), or None when unknown."""
    suspects = []
    if in_air_at is not None:
        suspects += _tilt_at_rest(ref, imu, trim, in_air_at, gps)
    suspects += _tilt_jumps(ref, imu)
    return sorted(suspects, key=lambda s: s.start)


def autopilot_disagreement(ref: AttitudeSeries, flight: Flight, named=None) -> list[Suspect]:
    """Where ``ref`` and another of the autopilot's estimators (``flight.attitudes``, copies of
    ``ref`` or of a stream already compared left out) differ in tilt by more than DISAGREE_DEG for
    DISAGREE_MIN_S or longer, one Suspect per span and stream, in time order."""
    if ref.source not in flight.attitudes or len(flight.attitudes) < 2:
        return []
    named = name_attitudes(flight) if named is None else named
    algorithm = next(n.algorithm for n in named if n.key == ref.source)
    out = []
    for other in compared_streams(ref, named):
        key = other.key
        for start, end, seconds, values in disagreeing_spans(*tilt_apart_deg(ref, flight.attitudes[key])):
            if seconds >= DISAGREE_MIN_S:
                out.append(disagreement(ref.source, algorithm, key, other.algorithm, start, end, seconds, values))
    return sorted(out, key=lambda s: s.start)


def disagreement(source: str, algorithm: str, key: str, other_algorithm: str, start: float, end: float,
                 seconds: float, values: np.ndarray) -> Suspect:
    """The Suspect of one span where ``source`` and the stream ``key`` disagree (``disagreeing_spans``)."""
    return Suspect("autopilot disagrees", start, end,
                   f"{source} ({algorithm}) and {key} ({other_algorithm}) differ in tilt by more than "
                   f"{DISAGREE_DEG:g}° for {seconds:.0f} s (median {np.median(values):.0f}°, up to "
                   f"{np.max(values):.0f}°)")


def suspect_event(s: Suspect) -> Event:
    """What replay and live say of a span they do not score."""
    return Event(s.start, "warn", f"reference not trusted {s.start:.1f}-{s.end:.1f} s: {s.detail} (not scored there)",
                 kind=f"reference not trusted ({s.kind}), not scored there")


def compared_streams(ref: AttitudeSeries, named: list) -> list:
    """The streams of ``named`` (``name_attitudes``) that give a second opinion on ``ref``: not
    ``ref`` itself, nor a copy of it or of one already taken (ATT = XKF1[0], AHR2 = EKF1)."""
    by_key = {n.key: n for n in named}
    taken, out = [ref.source], []
    for other in named:
        if any(max(other.equals.get(k, 0.0), by_key[k].equals.get(other.key, 0.0)) > SAME_SHARE
               for k in taken if k in by_key) or other.key == ref.source:
            continue
        taken.append(other.key)
        out.append(other)
    return out


def tilt_apart_deg(ref: AttitudeSeries, other: AttitudeSeries) -> tuple[np.ndarray, np.ndarray]:
    """(t, angle) on ``ref``'s clock: the angle between the two streams' down directions in the body
    (their tilt difference, yaw aside), NaN where either stream has a gap over DISAGREE_MAX_GAP_S."""
    t = ref.t
    q_other = quat.interpolate(other.t, other.q, t)
    after = np.clip(np.searchsorted(other.t, t), 1, max(len(other.t) - 1, 1))
    if len(other.t) >= 2:
        q_other[other.t[after] - other.t[after - 1] > DISAGREE_MAX_GAP_S] = np.nan
    down = np.array([0.0, 0.0, 1.0])
    with np.errstate(invalid="ignore"):
        cosine = (quat.rotate(quat.conjugate(ref.q), down) * quat.rotate(quat.conjugate(q_other), down)).sum(axis=1)
        return t, np.degrees(np.arccos(np.clip(cosine, -1.0, 1.0)))


def disagreeing_spans(t: np.ndarray, apart: np.ndarray, limit: float = DISAGREE_DEG) -> list[tuple]:
    """(start, end, seconds, angles) of each span where ``apart`` (°, NaN where not known) is above
    ``limit``: a stretch below it shorter than DISAGREE_BRIDGE_S does not end a span, nor does a
    stretch where it is not known (a gap: nothing there says the two agree). ``seconds`` counts
    the time above ``limit`` alone, not the gaps; ``angles`` the known ones inside the span."""
    known = np.isfinite(apart)
    t, apart = t[known], apart[known]
    runs: list[tuple[int, int]] = []
    for a, b in _runs(apart > limit):
        if runs and t[a - 1] - t[runs[-1][1]] < DISAGREE_BRIDGE_S:  # the samples below: t[prev end .. a - 1]
            runs[-1] = (runs[-1][0], b)
        else:
            runs.append((a, b))
    out = []
    for a, b in runs:
        steps = np.diff(t[a:b])
        above = steps[(apart[a:b - 1] > limit) & (steps <= DISAGREE_MAX_GAP_S)]
        out.append((float(t[a]), float(t[b - 1]), float(above.sum()), apart[a:b]))
    return out


def whole_log_notes(ref: AttitudeSeries, repeated: int = 0) -> list[LogNote]:
    """The notes on ``ref`` as a whole. ``repeated``: reference samples the reader dropped for
    repeating the time of the one before."""
    return repeat_notes(ref.source, len(ref.t), repeated)


def repeat_notes(source: str, kept: int, repeated: int) -> list[LogNote]:
    """``whole_log_notes`` of a reference ``source`` of which ``kept`` samples were kept and
    ``repeated`` dropped (a live session keeps count, not the samples)."""
    total = kept + repeated
    if not repeated or repeated <= REPEATED_SHARE * total:
        return []
    return [LogNote("repeated times", f"{source} timestamps repeat {repeated:,} times "
                                      f"({100.0 * repeated / total:.1f} % of its samples); the repeats were "
                                      "dropped, the first of each time kept; the rest is scored")]


def excluded_spans(suspects: list[Suspect]) -> list[tuple[float, float]]:
    return [(s.start, s.end) for s in suspects]


def _moving(gps: GpsSeries | None, t: np.ndarray) -> np.ndarray:
    """Where GPS says the vehicle moves faster than REST_SPEED (False where it says nothing)."""
    if gps is None:
        return np.zeros(len(t), dtype=bool)
    speed = np.linalg.norm(gps.vel_ned[:, :2], axis=1)
    ok = np.isfinite(speed)
    if not ok.any():
        return np.zeros(len(t), dtype=bool)
    return np.interp(t, gps.t[ok], speed[ok]) > REST_SPEED


def _tilt_at_rest(ref: AttitudeSeries, imu: ImuSeries, trim, in_air_at, gps) -> list[Suspect]:
    if len(imu.t) < 2 or len(ref.t) < 2:
        return []
    t0 = imu.t[0]
    bins = np.floor(imu.t - t0).astype(np.int64)
    n = int(bins[-1]) + 1
    count, rate, acc = bin_means(bins, n, quat.row_norms(imu.gyro), imu.accel)
    centre = t0 + np.arange(n) + 0.5
    rest = resting(count, rate, acc, in_air_at(centre), _moving(gps, centre)) & (centre > ref.t[0]) & (centre < ref.t[-1])
    if not rest.any():
        return []
    off = tilt_off_deg(acc, quat.interpolate(ref.t, ref.q, centre), trim)
    bad = rest & (off > TILT_AT_REST_DEG)
    return [rest_suspect(ref.source, centre[a], centre[b - 1], off[a:b]) for a, b in _runs(bad)
            if b - a >= MIN_REST_SPAN_S]


def bin_means(bins: np.ndarray, n: int, rate: np.ndarray, accel: np.ndarray) -> tuple:
    """Per 1 s bin (``bins``: each IMU sample's, 0 to n - 1): samples, mean |gyro|, mean accelerometer."""
    count = np.bincount(bins, minlength=n)
    mean_rate = np.bincount(bins, rate, n) / np.maximum(count, 1)
    acc = np.stack([np.bincount(bins, accel[:, k], n) for k in range(3)], axis=1) / np.maximum(count, 1)[:, None]
    return count, mean_rate, acc


def resting(count, rate, acc, in_air, moving) -> np.ndarray:
    """The bins (``bin_means``) where the vehicle is still on the ground: the accelerometer measures gravity alone."""
    with np.errstate(invalid="ignore"):
        return ((count > 0) & (rate < REST_RATE) & (np.abs(np.linalg.norm(acc, axis=1) - GRAVITY) < REST_ACCEL * GRAVITY)
                & (in_air == 0.0) & ~moving)


def tilt_off_deg(acc: np.ndarray, q_ref: np.ndarray, trim) -> np.ndarray:
    """The angle (°) between the accelerometer's gravity direction in the body (turned by the
    board trim) and the reference's (``q_ref`` at the same times)."""
    roll = np.arctan2(-acc[:, 1], -acc[:, 2])
    pitch = np.arctan2(acc[:, 0], np.hypot(acc[:, 1], acc[:, 2]))
    q_acc = quat.from_euler(roll, pitch, np.zeros(len(acc)))
    if trim is not None:
        q_acc = quat.trimmed(q_acc, *trim)
    # the angle between the two gravity directions in the body
    down_acc = quat.rotate(quat.conjugate(q_acc), np.array([0.0, 0.0, 1.0]))
    down_ref = quat.rotate(quat.conjugate(q_ref), np.array([0.0, 0.0, 1.0]))
    with np.errstate(invalid="ignore"):
        return np.degrees(np.arccos(np.clip((down_acc * down_ref).sum(axis=1), -1.0, 1.0)))


def rest_suspect(source: str, first_centre: float, last_centre: float, off: np.ndarray) -> Suspect:
    """A run of bins at rest (centres ``first_centre`` to ``last_centre``) whose reference tilt is off by ``off``."""
    return Suspect("tilt at rest", float(first_centre - 0.5), float(last_centre + 0.5),
                   f"still on the ground, {source}'s tilt is up to {off.max():.1f}° from the accelerometer's")


def _tilt_jumps(ref: AttitudeSeries, imu: ImuSeries) -> list[Suspect]:
    if len(imu.t) < 2 or len(ref.t) < 2:
        return []
    turned = np.concatenate([[0.0], np.cumsum(quat.row_norms(imu.gyro[1:]) * np.diff(imu.t))])
    down = quat.rotate(quat.conjugate(ref.q), np.array([0.0, 0.0, 1.0]))
    with np.errstate(invalid="ignore"):
        step = np.degrees(np.arccos(np.clip((down[:-1] * down[1:]).sum(axis=1), -1.0, 1.0)))
    allowed = np.degrees(np.interp(ref.t[1:], imu.t, turned) - np.interp(ref.t[:-1], imu.t, turned))
    inside = (ref.t[:-1] >= imu.t[0]) & (ref.t[1:] <= imu.t[-1]) & (np.diff(ref.t) < MAX_JUMP_STEP_S)
    jumps = np.flatnonzero(inside & (step > 2.0 * allowed + JUMP_MARGIN_DEG))
    spans: list[list[float]] = []
    for i in jumps:
        a, b = float(ref.t[i]), float(ref.t[i + 1]) + JUMP_HOLD_S
        if spans and a <= spans[-1][1]:
            spans[-1][1] = max(spans[-1][1], b)
            spans[-1][2] = max(spans[-1][2], step[i])
        else:
            spans.append([a, b, step[i]])
    return [jump_suspect(ref.source, a, b, big) for a, b, big in spans]


def jump_suspect(source: str, start: float, end: float, big: float) -> Suspect:
    return Suspect("tilt jump", start, end, f"{source}'s tilt jumped {big:.0f}° where the gyros turned at most "
                   "a few degrees")


def _runs(mask: np.ndarray) -> list[tuple[int, int]]:
    """[start, end) of each run of True."""
    edges = np.diff(np.concatenate([[0], mask.astype(np.int8), [0]]))
    return list(zip(np.flatnonzero(edges == 1), np.flatnonzero(edges == -1)))
