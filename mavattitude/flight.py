"""The in-memory flight record every layer shares.

Readers fill it; estimators, metrics and the view only read it. Everything is SI and
time-stamped on the autopilot's clock, in seconds since it booted:

- body frame FRD, navigation frame NED;
- angular rate rad/s, specific force m/s² (level and still: [0, 0, -g]);
- magnetic field tesla, pressure pascal, heights metres;
- latitude/longitude in degrees (named ``*_deg``: the one non-SI quantity, kept as GPS gives it);
- attitudes as unit quaternions [w, x, y, z] rotating body to NED.

Each sensor series may carry ``arrival``: every sample's place in the order the log holds
them (a .bin's record offsets, a .tlog's packet count). The estimation core gives each IMU
sample what had arrived before it, as a live link would have (``runner``); without it, the
order of time stands in.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

GRAVITY = 9.80665  # m/s², standard gravity


# The IMU families a log can hold (``--imu-source``), told apart by their series' names.
# Names: an "IMU source" (``imu_source``, ``--imu``) is one series, a key of ``Flight.imu``
# ("IMU[0]", "RAW_IMU"); a family is ``imu_family``. Two user-facing names keep the older
# meaning for compatibility: the ``--imu-source`` option and ``mavattitude.replay(imu_source=)``
# take a family. Likewise ``declination`` is radians east inside (estimators, ``Runner``),
# ``declination_deg`` the user's degrees, except ``mavattitude.replay(declination=)`` (degrees);
# a result's or a report's ``declination`` is a ``declination.Declination``: value and source.
IMU_FAMILIES = {
    "imu": "the main loop's samples (IMU, RAW_IMU, SCALED_IMU*, HIGHRES_IMU; PX4's sensor_combined)",
    "raw": "the sensor-rate samples (GYR with ACC, 1-8 kHz)",
    "delta": "delta angles and velocities (IMT; PX4's vehicle_imu)",
}
# The default: the first a log has. The main loop's samples first: on simulated truth neither the
# deltas nor the sensor-rate samples did better (scripts/imu_source_gain.py), and the sensor-rate
# ones cost 3x the work.
DEFAULT_FAMILIES = ("imu", "delta", "raw")


def imu_family(key: str) -> str:
    return "raw" if key.startswith("GYR[") else "delta" if key.startswith(("IMT[", "vehicle_imu[")) else "imu"


def median_step(t: np.ndarray) -> float:
    """The median interval of sample times ``t`` (increasing), as ``np.median(np.diff(t))`` gives
    it, without its copy of the intervals (an hour at 400 Hz: 11.5 MB)."""
    return float(np.median(np.diff(t), overwrite_input=True))


def means_over_steps(key: str) -> bool:
    """Whether a series' samples are means over the step ending at each (``ImuSeries.rate_over_step``):
    the deltas, integrated over each logged interval. ArduPilot's IMU and MAVLink's *_IMU hold
    samples of the filtered rate; PX4's sensor_combined holds means over the sensor's own period
    (gyro_integral_dt, a few ms), which is the logged step only when logged at the sensor's rate:
    taken as samples of the rate (its 10 Hz log, px4-real-fmuv3-1.9-escstatus: ncs-eskf 15.9° ->
    17.8°, cpf-ekf 11.2° -> 13.4° against the autopilot when taken as means over the step)."""
    return imu_family(key) == "delta"


@dataclass
class ImuSeries:
    source: str  # e.g. "IMU[0]", "RAW_IMU", "HIGHRES_IMU"
    t: np.ndarray  # (N,) s
    gyro: np.ndarray  # (N, 3) rad/s, FRD
    accel: np.ndarray  # (N, 3) m/s², specific force, FRD
    arrival: np.ndarray | None = None  # (N,) order in the log (see the module docstring)
    # True: each sample is the mean over the step that ends at its time (delta angles and
    # velocities over their intervals; see means_over_steps), integrated over that step alone;
    # False: a sample of the rate at its time, integrated as the mean of the step's two ends
    rate_over_step: bool = False


@dataclass
class MagSeries:
    source: str
    t: np.ndarray
    field: np.ndarray  # (N, 3) tesla, FRD
    arrival: np.ndarray | None = None  # (N,) order in the log (see the module docstring)


@dataclass
class GpsSeries:
    source: str
    t: np.ndarray
    lat_deg: np.ndarray
    lon_deg: np.ndarray
    alt_m: np.ndarray  # above mean sea level
    vel_ned: np.ndarray  # (N, 3) m/s; NaN where the message has no velocity
    fix_type: np.ndarray  # int: 0-1 no fix, 2 2D, 3 3D, 4+ DGPS/RTK
    num_sats: np.ndarray  # int
    h_acc_m: np.ndarray  # horizontal accuracy; NaN where unknown
    v_acc_m: np.ndarray | None = None  # vertical accuracy; NaN or None where unknown
    arrival: np.ndarray | None = None  # (N,) order in the log (see the module docstring)


@dataclass
class BaroSeries:
    source: str
    t: np.ndarray
    pressure_pa: np.ndarray
    alt_m: np.ndarray  # relative altitude the autopilot reports; NaN where absent
    arrival: np.ndarray | None = None  # (N,) order in the log (see the module docstring)


@dataclass
class AttitudeSeries:
    source: str  # "ATT", "ATTITUDE", "SIMSTATE", "SIM", "vehicle_attitude", or an estimator's name
    t: np.ndarray
    q: np.ndarray  # (N, 4) unit quaternions [w, x, y, z], body -> NED
    # ATT only (ArduPilot 4.1+, its AEKF): per sample, the estimator the autopilot was using
    # (0 DCM, 2 EKF2, 3 EKF3, 10 SITL, 11 external); None where the log does not say
    active: np.ndarray | None = None

    @property
    def euler(self) -> np.ndarray:
        """(N, 3) roll, pitch, yaw in radians (ZYX), yaw in [-pi, pi)."""
        from .quaternion import to_euler
        return to_euler(self.q)


@dataclass
class LabelSeries:
    """What the log says happened, one row per change, on the autopilot clock: flight modes
    (``value`` the autopilot's mode number, ``label`` its name), arming (``value`` 1 armed, 0
    disarmed) or the autopilot's own text lines (``value`` the MAVLink severity, 0 emergency to 7
    debug; ``label`` the text: MSG, ERR, STATUSTEXT, a ULog's logged messages). Readers:
    ``readers.logevents``."""
    source: str  # "MODE", "HEARTBEAT", "vehicle_status", "EV", "MSG+ERR", ...
    t: np.ndarray  # (N,) s, in the order the log holds them (not always increasing: a text's time is its writer's)
    value: np.ndarray  # (N,) int
    label: list[str]

    def spans(self, end: float) -> list[tuple[float, float, int, str]]:
        """(start, end, value, label) of each row until the next (the last until ``end``)."""
        ends = list(self.t[1:]) + [max(end, float(self.t[-1]))] if len(self.t) else []
        return [(float(a), float(b), int(v), name) for a, b, v, name in zip(self.t, ends, self.value, self.label)]


@dataclass
class Flight:
    path: str
    format: str  # "bin", "tlog", "ulg" or "broad" (a BROAD trial: readers.broad)
    imu: dict[str, ImuSeries] = field(default_factory=dict)  # every IMU source found
    mag: dict[str, MagSeries] = field(default_factory=dict)
    gps: GpsSeries | None = None
    baro: BaroSeries | None = None
    attitude: AttitudeSeries | None = None  # the autopilot's own estimate
    # Every attitude the autopilot logged, by message (and instance): "ATT", "AHR2", "EKF1",
    # "XKF1[1]", "AHRS2", "estimator_attitude[1]", ...; ``attitude`` is one of them, the primary.
    # Which algorithm made each: ``readers.attitudes.name_attitudes``.
    attitudes: dict[str, AttitudeSeries] = field(default_factory=dict)
    truth: AttitudeSeries | None = None  # simulator ground truth (or a benchmark's measured truth)
    # (first, last) time, s, of each span the source says not to score (BROAD's rest phases)
    unscored_spans: list[tuple[float, float]] = field(default_factory=list)
    params: dict[str, float] = field(default_factory=dict)
    vehicle: str | None = None  # e.g. "ArduCopter"
    firmware: str | None = None  # e.g. "ArduCopter V4.4.4 (865cffa5)"
    # UNIX time (s, UTC) of the log's first valid GPS or system time: when it was flown (the
    # declination's date); None when the log has none. The readers convert it (``readers.collect.first_utc``).
    utc_s: float | None = None
    message_counts: dict[str, int] = field(default_factory=dict)
    # Clock segments: (start, end) in seconds. More than one means the autopilot rebooted
    # (its clock went back); the record holds the segment ``segment_index`` only.
    segments: list[tuple[float, float]] = field(default_factory=list)
    segment_index: int = 0
    # What the log says happened (``LabelSeries``): its flight modes, arming and text lines
    modes: LabelSeries | None = None
    arming: LabelSeries | None = None
    messages: LabelSeries | None = None
    notes: list[str] = field(default_factory=list)  # things the reader fixed or noticed
    warnings: list[str] = field(default_factory=list)  # data the reader had to leave out (damage)
    repeated: dict[str, int] = field(default_factory=dict)  # series -> samples dropped for repeating a time

    def all_series(self):
        """(kind, series) for every time series in the record."""
        for name, s in self.imu.items():
            yield "imu", s
        for name, s in self.mag.items():
            yield "mag", s
        for kind in ("gps", "baro", "attitude", "truth"):
            s = getattr(self, kind)
            if s is not None:
                yield kind, s

    @property
    def time_span(self) -> tuple[float, float]:
        starts = [s.t[0] for _, s in self.all_series() if len(s.t)]
        ends = [s.t[-1] for _, s in self.all_series() if len(s.t)]
        if not starts:
            return (0.0, 0.0)
        return (float(min(starts)), float(max(ends)))

    @property
    def duration(self) -> float:
        a, b = self.time_span
        return b - a
