"""The settings of a run, decided once, for every front end: replay, evaluate, tune, the Python
API, live and ``bench --live``.

Two objects. ``RunOptions`` is what the user asked for, as given (the estimators, --params and
--set still unapplied, the reference, --declination, --home, --no-trim, ...), checked before any
log is read. ``RunPolicy`` is what a run does with a particular flight: each estimator's
parameters with the flight's own defaults below the user's (``params.log_defaults``: a plane's
cruise airspeed), the declination and where it came from (``declination.choose``), the board
trim (``trim.board_trim``). One function makes it, ``decide``, from the options and what a front
end gathered about the flight (``FlightFacts``: its autopilot parameters, vehicle, first good GPS
fix and date). Replay gathers those from a log (``FlightFacts.of``); a live session from the
vehicle's answers to PARAM_REQUEST_READ (``wanted_params``) and what it sent so far.
"""
from __future__ import annotations

import datetime
import math
from collections.abc import Mapping
from dataclasses import dataclass, field

from .. import declination as decl
from ..errors import UsageError
from ..trim import TRIM_PARAMS, board_trim
from .params import build, log_default_params, log_defaults

DECLINATION_PARAM_NAMES = tuple(n for name, _, auto, _ in decl.DECLINATION_PARAMS for n in (name, auto))


def wanted_params(names) -> tuple[str, ...]:
    """The autopilot parameters a policy for these estimators reads: what their log-derived
    defaults read, the declination and the parameters that say whether the autopilot computes
    it, the board trim. A live session asks the vehicle for these, in this order (a vehicle
    answers those it has, in order: the session waits for the last two kinds only,
    ``live.estimation.PARAMS_WAIT_S``)."""
    return (*log_default_params(list(names)), *DECLINATION_PARAM_NAMES, *TRIM_PARAMS)


@dataclass(frozen=True)
class RunOptions:
    """What the user asked for, as given (the command line's options, the API's keywords): the
    parameters still unapplied, so that each flight can add its own defaults below them."""
    names: tuple[str, ...]
    reference: str = "autopilot"
    imu: str | None = None  # --imu: one IMU series
    imu_family: str | None = None  # --imu-source: a kind of IMU data
    warmup_s: float = 10.0
    declination_deg: float | None = None  # --declination
    home: decl.Fix | None = None  # --home
    use_mag: bool = True
    trim: bool = True  # turn the estimates by the board trim, against the autopilot's primary attitude
    segment: int | None = None  # the log's clock segment (default the longest)
    file_values: dict | None = None  # --params, as read from the file
    assignments: tuple[str, ...] = ()  # --set
    params_source: str = "--params"  # what the file values are called in an error
    given: Mapping | None = None  # estimator -> its parameter dataclass, whole (the API, scripts)

    def __post_init__(self):
        object.__setattr__(self, "names", tuple(self.names))
        object.__setattr__(self, "assignments", tuple(self.assignments))

    @classmethod
    def of(cls, names, params: Mapping | None = None, **options) -> RunOptions:
        """Options with ``params`` as the Python API takes it: {estimator: {field: value}} (checked
        as --params is) or {estimator: parameter dataclass} (used whole)."""
        params = params or {}
        tables = {n: v for n, v in params.items() if isinstance(v, dict)}
        whole = {n: v for n, v in params.items() if not isinstance(v, dict)}
        return cls(names=tuple(names), file_values=tables or None, given=whole or None,
                   **({"params_source": "replay(params=...)"} if tables else {}), **options)

    def check(self) -> None:
        """Raise UsageError / InputError for a bad option now, before any log is read (evaluate
        would otherwise fail every log with the same "internal error")."""
        def number(value) -> bool:
            return isinstance(value, (int, float)) and not isinstance(value, bool) and math.isfinite(value)

        if not (number(self.warmup_s) and self.warmup_s >= 0):
            raise UsageError(f"--warmup {self.warmup_s!r}: expected a number of seconds, 0 or more")
        if self.declination_deg is not None and not (number(self.declination_deg)
                                                     and -180 <= self.declination_deg <= 180):
            raise UsageError(f"--declination {self.declination_deg!r}: expected degrees from -180 to 180")
        if self.segment is not None and not (isinstance(self.segment, int) and not isinstance(self.segment, bool)
                                             and self.segment >= 0):
            raise UsageError(f"--segment {self.segment!r}: expected a clock segment number, 0 or more")
        if not (isinstance(self.reference, str) and self.reference.strip()):  # a stream's name is checked per log
            raise UsageError(f"--reference {self.reference!r}: use autopilot, truth, ekf or a stream 'info' lists")
        self.user_params()

    def user_params(self, log_values: dict | None = None) -> dict[str, object]:
        """Each estimator's parameter dataclass: its declarations overridden by ``log_values``,
        then --params, then --set (``params.build``); a dataclass given whole replaces it."""
        params = build(list(self.names), self.file_values, self.assignments, source=self.params_source,
                       log_values=log_values)
        params.update(self.given or {})
        return params


@dataclass(frozen=True)
class FlightFacts:
    """What a front end gathers about a flight for its policy: a log's, or a live vehicle's."""
    params: Mapping[str, float]  # the autopilot's parameters (a log's dump, a vehicle's answers)
    vehicle: str | None = None  # "ArduPlane", "ArduCopter", "PX4", "QUADROTOR", ... (readers.identify_vehicle)
    fix: decl.Fix | None = None  # the first good GPS fix (declination.first_good_fix)
    when: datetime.datetime | None = None  # the flight's date, UTC
    where: str = "log"  # "log" or "vehicle": where the parameters came from, said with them
    magnetic_north: bool = False  # the data's own north is magnetic (a BROAD trial)

    @classmethod
    def of(cls, flight) -> FlightFacts:
        """A log's: its parameters, vehicle, first good fix and date."""
        return cls(flight.params, flight.vehicle, decl.first_good_fix(flight.gps), decl.flight_date(flight),
                   magnetic_north=flight.format == "broad")


@dataclass(frozen=True)
class RunPolicy:
    """The settings of one run on one flight (``decide``): the user's options and what the
    flight's own parameters added to them."""
    options: RunOptions
    params: dict  # estimator -> its parameter dataclass, the flight's defaults below the user's
    notes: tuple[str, ...]  # a line per parameter the flight supplied ("eq-kf airspeed 12 m/s from ...")
    declination: decl.Declination  # as used, and where it came from
    board_trim: tuple[float, float] | None  # rad (roll, pitch): AHRS_TRIM_X/Y, None without one or with --no-trim
    facts: FlightFacts | None = field(repr=False, default=None)  # what it was decided on

    @property
    def names(self) -> list[str]:
        return list(self.options.names)

    @property
    def reference(self) -> str:
        return self.options.reference

    @property
    def warmup_s(self) -> float:
        return self.options.warmup_s

    @property
    def use_mag(self) -> bool:
        return self.options.use_mag

    def trim_for(self, primary: bool) -> tuple[float, float] | None:
        """The trim the estimates are turned by before scoring: against the autopilot's primary
        attitude only (the vehicle's); its other streams are logged untrimmed, truth is the board's."""
        return self.board_trim if primary else None


def decide(options: RunOptions, facts: FlightFacts) -> RunPolicy:
    """The run's policy: the options applied to a flight (the module docstring)."""
    given = set(options.given or {})
    log_values, notes = log_defaults(facts, [n for n in options.names if n not in given], options.file_values,
                                     options.assignments)
    declination = decl.choose(facts.params, facts.fix, facts.when, options.declination_deg, options.home,
                              where=facts.where, magnetic_north=facts.magnetic_north)
    return RunPolicy(options, options.user_params(log_values), tuple(notes), declination,
                     board_trim(facts.params) if options.trim else None, facts)
