"""Joins readers, estimators and metrics: a flight in, estimates and comparisons out."""
from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from . import aiding as aid
from . import estimators as est
from . import quaternion as quat
from .errors import InputError, UsageError
from .flight import AttitudeSeries, Flight, MagSeries
from .metrics import Comparison, compare
from .phase import PhaseSeries, detect_phase
from .readers import best_imu_source, imu_rate, mag_for_imu

# An IMU gap longer than this restarts the estimators from a fresh alignment: after it the
# vehicle may be anywhere (logging paused while disarmed, a crash and a pick-up).
REINIT_GAP_S = 2.0
# IMU rates below this leave the gyro integration too coarse for good estimates.
LOW_IMU_RATE_HZ = 20.0
# A magnetometer sample older than this many of its own periods (or 0.5 s) is stale.
MAG_STALE_PERIODS = 3.0


@dataclass
class Event:
    t: float  # s, autopilot clock
    level: str  # "info", "warn"
    text: str


@dataclass
class ReplayResult:
    flight: Flight
    imu_source: str  # key into flight.imu of the IMU the estimators ran on
    reference: AttitudeSeries  # what the comparisons score against (flight.attitude or flight.truth)
    estimates: dict[str, AttitudeSeries]  # estimator name -> its attitude at the IMU timestamps
    comparisons: dict[str, Comparison]  # estimator name (and "autopilot" when scoring against truth)
    events: list[Event] = field(default_factory=list)
    declination: float = 0.0  # rad, as used
    declination_source: str = ""  # "log parameter COMPASS_DEC", "--declination", "none (0)"
    mag_source: str | None = None
    alignment: est.Alignment | None = None
    phase: PhaseSeries | None = None  # ground/air, when the log has a height source
    # estimator name -> diagnostic name -> (N,) series at the IMU timestamps
    diagnostics: dict[str, dict[str, np.ndarray]] = field(default_factory=dict)
    # estimator name -> what happened to its accelerometer updates, see accel_state_events
    estimator_events: dict[str, dict] = field(default_factory=dict)
    params: dict = field(default_factory=dict)  # estimator name -> its parameter dataclass
    aiding: aid.Aiding | None = None  # GPS / baro on the IMU clock, when an estimator used them


def mag_on_imu_clock(imu_t: np.ndarray, mag: MagSeries | None) -> np.ndarray | None:
    """The latest magnetometer sample at each IMU time (zero-order hold), NaN where stale."""
    if mag is None or len(mag.t) == 0:
        return None
    idx = np.searchsorted(mag.t, imu_t, side="right") - 1
    period = float(np.median(np.diff(mag.t))) if len(mag.t) > 1 else 0.1
    max_age = max(0.5, MAG_STALE_PERIODS * period)
    out = mag.field[np.clip(idx, 0, None)].copy()
    age = imu_t - mag.t[np.clip(idx, 0, None)]
    out[(idx < 0) | (age > max_age)] = np.nan
    return out


def resolve_declination(flight: Flight, override_deg: float | None) -> tuple[float, str]:
    if override_deg is not None:
        return math.radians(override_deg), "--declination"
    if "COMPASS_DEC" in flight.params:
        return float(flight.params["COMPASS_DEC"]), "log parameter COMPASS_DEC"
    return 0.0, "none (0)"


def run_estimators(flight: Flight, names: list[str], imu_source: str | None = None,
                   declination_deg: float | None = None, params: dict | None = None,
                   use_mag: bool = True):
    """Run each named estimator over the chosen IMU. Returns (estimates, alignment, context)."""
    imu_source = imu_source or best_imu_source(flight)
    if imu_source not in flight.imu:
        raise InputError(flight.path, f"has no IMU source {imu_source!r} (--imu); it has: {', '.join(flight.imu)}")
    imu = flight.imu[imu_source]
    mag_source = mag_for_imu(flight, imu_source) if use_mag else None
    mag = mag_on_imu_clock(imu.t, flight.mag.get(mag_source)) if mag_source else None
    declination, dec_source = resolve_declination(flight, declination_deg)
    phase = detect_phase(flight)
    in_air = phase.on_clock(imu.t) if phase is not None else np.full(len(imu.t), np.nan)
    runs = contiguous_runs(imu.t)
    estimators = [est.create(name, (params or {}).get(name), declination) for name in names]
    aiding = aid.from_flight(flight, imu.t) if any(e.uses_aiding for e in estimators) else None
    outputs = {name: np.empty((len(imu.t), 4)) for name in names}
    diagnostics = {name: {} for name in names}
    alignments = []
    for start, end in runs:
        s = slice(start, end)
        alignment = est.align(imu.t[s], imu.gyro[s], imu.accel[s],
                              None if mag is None else mag[s], declination)
        if alignment.still_span is None and alignments:
            alignment.gyro_bias = alignments[0].gyro_bias  # no new still period: keep the first
        alignments.append(alignment)
        for estimator in estimators:
            q0 = alignment.q0
            if start > 0 and not alignment.heading_from_mag:
                # No heading reference: carry the yaw over the gap rather than restart it at 0.
                roll, pitch, _ = quat.to_euler(q0)
                q0 = quat.from_euler(roll, pitch, quat.to_euler(outputs[estimator.name][start - 1])[2])
            estimator.initialize(q0, alignment.gyro_bias)
            extra = {"aiding": aiding[s]} if estimator.uses_aiding else {}
            outputs[estimator.name][s] = estimator.update(
                imu.t[s], imu.gyro[s], imu.accel[s], None if mag is None else mag[s], in_air[s],
                **extra)
            for key, series in estimator.diagnostics.items():
                full = diagnostics[estimator.name].get(key)
                if full is None:
                    full = np.zeros(len(imu.t), series.dtype) if series.dtype.kind == "i" \
                        else np.full(len(imu.t), np.nan)
                    diagnostics[estimator.name][key] = full
                full[s] = series
    estimates = {name: AttitudeSeries(name, imu.t, q) for name, q in outputs.items()}
    has_heading = {e.name: e.has_heading_reference(mag is not None) for e in estimators}
    restarts = [(float(imu.t[start]), float(imu.t[start] - imu.t[start - 1])) for start, _ in runs[1:]]
    return estimates, alignments[0], dict(imu_source=imu_source, mag_source=mag_source,
                                          declination=declination, declination_source=dec_source,
                                          has_heading=has_heading, restarts=restarts, phase=phase,
                                          diagnostics=diagnostics,
                                          params={e.name: e.params for e in estimators},
                                          accel_states={e.name: e.ACCEL_STATES for e in estimators},
                                          aiding=aiding)


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


def reset_events(t: np.ndarray, reset: np.ndarray) -> dict:
    """A watchdog's resets (the ``reset`` diagnostic, 1.0 at a reset): count and times (s)."""
    hit = np.asarray(reset) == 1.0
    return {"count": int(np.count_nonzero(hit)), "times": [round(float(x), 3) for x in t[hit]]}


def contiguous_runs(t: np.ndarray) -> list[tuple[int, int]]:
    """[start, end) index ranges of the IMU between gaps longer than REINIT_GAP_S."""
    cuts = np.flatnonzero(np.diff(t) > REINIT_GAP_S) + 1
    bounds = np.concatenate([[0], cuts, [len(t)]])
    return [(int(a), int(b)) for a, b in zip(bounds[:-1], bounds[1:])]


def run_replay(flight: Flight, names: list[str], reference: str = "autopilot",
               imu_source: str | None = None, warmup_s: float = 10.0,
               declination_deg: float | None = None, params: dict | None = None,
               use_mag: bool = True) -> ReplayResult:
    """Estimate with every named estimator and score each against the reference.

    ``reference``: "autopilot" (ATT / ATTITUDE) or "truth" (SIM / SIMSTATE); with truth the
    autopilot's own attitude is scored as an extra row named "autopilot".
    """
    if reference == "truth":
        if flight.truth is None:
            raise InputError(flight.path, "--reference truth, but the log has no ground truth "
                                          "(SIM in .bin, SIMSTATE in .tlog)")
        ref = flight.truth
    elif reference == "autopilot":
        ref = flight.attitude
    else:
        raise UsageError(f"unknown reference {reference!r}: use 'autopilot' or 'truth'")

    estimates, alignment, ctx = run_estimators(flight, names, imu_source, declination_deg,
                                               params, use_mag)
    events = _events(flight, ctx, alignment)
    for name, series in estimates.items():
        bad = int(np.count_nonzero(~np.isfinite(series.q).all(axis=1)))
        if bad:
            events.append(Event(float(series.t[0]), "warn",
                                f"{name}: {bad} non-finite attitude samples (a filter fault; "
                                "they are left out of the metrics)"))
    comparisons = {}
    if ref is not None:
        for name, series in estimates.items():
            comparisons[name] = compare(ref, series, warmup_s=warmup_s,
                                        align_yaw=not ctx["has_heading"][name], name=name,
                                        restarts=[t for t, _ in ctx["restarts"]])
        if reference == "truth" and flight.attitude is not None:
            comparisons["autopilot"] = compare(ref, flight.attitude, warmup_s=warmup_s,
                                               name="autopilot")
    else:
        events.append(Event(flight.time_span[0], "warn",
                            "the log has no attitude reference (ATT / ATTITUDE): nothing to score against"))
    imu_t = flight.imu[ctx["imu_source"]].t
    estimator_events = {name: accel_state_events(imu_t, diag["accel_state"], ctx["accel_states"][name])
                        for name, diag in ctx["diagnostics"].items() if "accel_state" in diag}
    for name, diag in ctx["diagnostics"].items():
        if "reset" in diag:
            resets = reset_events(imu_t, diag["reset"])
            estimator_events.setdefault(name, {})["resets"] = resets
            events += [Event(t, "warn", f"{name}: watchdog reset (EKF attitude too far from its "
                                        "complementary filter): restarted from it")
                       for t in resets["times"]]
    return ReplayResult(flight=flight, imu_source=ctx["imu_source"], reference=ref,
                        estimates=estimates, comparisons=comparisons, events=events,
                        declination=ctx["declination"], declination_source=ctx["declination_source"],
                        mag_source=ctx["mag_source"], alignment=alignment, phase=ctx["phase"],
                        diagnostics=ctx["diagnostics"], estimator_events=estimator_events,
                        params=ctx["params"], aiding=ctx["aiding"])


def _events(flight: Flight, ctx: dict, alignment: est.Alignment) -> list[Event]:
    imu = flight.imu[ctx["imu_source"]]
    t0 = float(imu.t[0])
    events = [Event(t0, "info", f"IMU source {ctx['imu_source']} at {imu_rate(imu):.1f} Hz, "
                                f"magnetometer {ctx['mag_source'] or 'none'}")]
    rate = imu_rate(imu)
    if rate < LOW_IMU_RATE_HZ:
        events.append(Event(t0, "warn", f"low IMU rate: {rate:.1f} Hz (below {LOW_IMU_RATE_HZ:.0f} Hz): "
                                        "gyro integration is coarse and estimates will lag"))
    if ctx["mag_source"] and ctx["declination_source"] == "none (0)":
        events.append(Event(t0, "warn", "no COMPASS_DEC in the log and no --declination: using 0°; "
                                        "yaw compares magnetic with true heading"))
    if alignment.still_span:
        a, b = alignment.still_span
        bias = np.degrees(alignment.gyro_bias)
        events.append(Event(b, "info", f"still {a:.1f}-{b:.1f} s: gyro bias "
                                       f"[{bias[0]:.3f}, {bias[1]:.3f}, {bias[2]:.3f}] °/s"))
    else:
        events.append(Event(t0, "warn", "no initial still period: gyro bias starts at 0"))
    phase = ctx["phase"]
    if phase is not None:
        changes = np.flatnonzero(np.diff(phase.in_air)) + 1
        events.append(Event(t0, "info", f"ground/air phase from {phase.source}: "
                                        f"{len(changes)} change(s)"))
        for i in changes:
            where = "in the air" if phase.in_air[i] else "on the ground"
            events.append(Event(float(phase.t[i]), "info",
                                f"{where} ({phase.source} {phase.height_m[i]:.1f} m above the start)"))
    else:
        events.append(Event(t0, "info", "no baro or GPS height: ground/air phase unknown"))
    for t, gap in ctx["restarts"]:
        events.append(Event(t, "warn", f"IMU gap of {gap:.1f} s: estimators re-initialised"))
    for note in flight.notes:
        events.append(Event(t0, "info", note))
    for warning in flight.warnings:
        events.append(Event(t0, "warn", warning))
    return events
