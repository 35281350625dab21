"""mavattitude: replay MAVLink flight logs through attitude estimators and compare them
with the autopilot's own attitude and simulator ground truth.

From Python::

    import mavattitude
    flight = mavattitude.load("flight.bin")          # SI arrays on the autopilot clock
    result = mavattitude.replay(flight, estimators=["mahony", "ekf"])
    result.metrics["estimators"]["ekf"]["roll"]["mae"]   # what --json writes
    result.write_rrd("flight.rrd")

Estimators on your own arrays: ``mavattitude.estimators.create``; your own estimator class,
listed and run by the command too: ``mavattitude.estimators.register`` (or the entry point
group ``mavattitude.estimators``).
"""
from __future__ import annotations

from ._version import __version__  # noqa: F401 - mavattitude.__version__


def load(path, segment: int | None = None):
    """A log (.bin, .tlog or .ulg) as a ``flight.Flight``: SI arrays on the autopilot clock, with
    what the reader fixed (``notes``) or had to leave out (``warnings``). ``segment``: the clock
    segment to keep when the autopilot rebooted during the log (default the longest)."""
    from .readers import read_log

    return read_log(str(path), segment=segment)


def replay(log, estimators=("mahony",), reference: str = "autopilot", params: dict | None = None,
           imu: str | None = None, warmup: float = 10.0, declination: float | None = None,
           use_mag: bool = True, trim: bool = True, imu_source: str | None = None,
           home: tuple[float, float] | None = None):
    """Run ``estimators`` over a log (a path, or a flight from ``load``) and score them, as
    ``mavattitude replay`` does: a ``commands.replay.ReplayResult`` with ``metrics`` (the --json
    dict), ``estimates`` (name -> series with ``t``, ``q``, ``euler``), ``reference``,
    ``reference_info`` (its stream and algorithm), ``stream_comparisons`` (the autopilot's other
    streams scored against it), ``events``, and ``write_json``, ``write_csv``, ``write_rrd``.

    ``reference``: "autopilot" (the attitude in use), "truth", "ekf" or a stream ``info``
    lists, e.g. "EKF1" (``commands.replay.choose_reference``).

    ``params``: {estimator: {parameter: value}} (or a parameter dataclass), checked against
    each parameter's valid range; ``declination`` in degrees (default: as the autopilot had it,
    ``declination.choose``); ``home``: (lat, lon) degrees where the log has no GPS fix;
    ``trim``: turn the estimates by the log's board trim before scoring against the autopilot.
    ``imu`` names one IMU series (e.g. "IMU[1]"); ``imu_source`` a family: "imu", "raw" or
    "delta" (default: the best the log has).
    """
    from .declination import Fix
    from .core.policy import RunOptions
    from .commands.replay import replay_flight

    flight = log if hasattr(log, "imu") else load(log)
    options = RunOptions.of(list(estimators), params, reference=reference, imu=imu, imu_family=imu_source,
                            warmup_s=warmup, declination_deg=declination, use_mag=use_mag, trim=trim,
                            home=Fix(*home) if home is not None else None)
    return replay_flight(flight, options)[0]
