"""Log readers: a file in, a :class:`~mavattitude.flight.Flight` out (SI units, autopilot clock).

``read_log(path)`` picks the format from the file's first bytes, decodes it with pymavlink
(``dataflash`` or ``tlog``), and turns the collected rows into clean series: one clock
segment (the longest, unless asked), sorted, without repeated timestamps or empty samples.
"""
from __future__ import annotations

import contextlib
import io
import os
import re
import sys
import tempfile

import numpy as np

from .. import quaternion as quat
from ..errors import InputError
from ..flight import (AttitudeSeries, BaroSeries, Flight, GpsSeries, ImuSeries, MagSeries)
from .collect import Collector
from .dataflash import read_dataflash
from .tlog import read_tlog

DATAFLASH_MAGIC = b"\xa3\x95"
MAVLINK_MAGIC = (0xFE, 0xFD)  # MAVLink 1, MAVLink 2 start bytes

# IMU sources, best first, among those with the same sample rate: float SI data beats
# integer mG/mrad/s, and the primary instance beats the others.
IMU_PREFERENCE = ["HIGHRES_IMU", "IMU[0]", "RAW_IMU", "SCALED_IMU", "SCALED_IMU2", "IMU[1]",
                  "SCALED_IMU3", "IMU[2]"]


# Beyond what any autopilot IMU measures (ArduPilot: ±16 g, ±2000 °/s) or any magnetometer
# reads on Earth: such samples are corrupt records.
IMU_LIMITS = [(slice(0, 3), 50.0), (slice(3, 6), 50 * 9.81)]  # rad/s, m/s²
MAG_LIMITS = [(slice(0, 3), 1e-3)]  # tesla (10 gauss)


def sniff_format(path: str) -> str:
    """'bin' or 'tlog' from the file's content; InputError if it is neither."""
    if not os.path.exists(path):
        raise InputError(path, "no such file")
    if os.path.isdir(path):
        raise InputError(path, "is a folder, not a log file")
    with open(path, "rb") as f:
        head = f.read(64)
    if not head:
        raise InputError(path, "empty file")
    if head[:2] == DATAFLASH_MAGIC:
        return "bin"
    if len(head) > 8 and head[8] in MAVLINK_MAGIC:
        return "tlog"
    ext = os.path.splitext(path)[1].lower()
    kind = {".bin": "DataFlash .bin", ".tlog": "telemetry .tlog"}.get(ext, "MAVLink log")
    raise InputError(path, f"not a {kind} file (it starts with bytes {head[:10].hex(' ')}; "
                           "expected a DataFlash header a3 95 or a tlog record)")


@contextlib.contextmanager
def _captured_output():
    """Capture what pymavlink prints while it decodes, Python and C alike (its Cython
    indexer writes to the process's stdout and stderr directly); yields a function that
    returns the captured lines. The progress display is let through: it writes after."""
    sys.stdout.flush()
    sys.stderr.flush()
    with tempfile.TemporaryFile(mode="w+b") as sink:
        saved = [os.dup(1), os.dup(2)]
        lines: list[str] = []
        try:
            os.dup2(sink.fileno(), 1)
            os.dup2(sink.fileno(), 2)
            with contextlib.redirect_stdout(io.StringIO()) as out, \
                    contextlib.redirect_stderr(io.StringIO()) as err:
                yield lambda: lines
        finally:
            sys.stdout.flush()
            sys.stderr.flush()
            os.dup2(saved[0], 1)
            os.dup2(saved[1], 2)
            for fd in saved:
                os.close(fd)
            sink.seek(0)
            lines += sink.read().decode(errors="replace").splitlines()
            lines += out.getvalue().splitlines() + err.getvalue().splitlines()


def read_log(path: str, segment: int | None = None, progress=None) -> Flight:
    """Read a .bin or .tlog. ``segment``: which clock segment to keep when the autopilot
    rebooted during the log (0-based); default the longest."""
    path = str(path)
    fmt = sniff_format(path)
    with _captured_output() as chatter:  # pymavlink's complaints about corrupt data
        decoded = read_dataflash(path, progress) if fmt == "bin" else read_tlog(path, progress)
    col, notes, warnings = decoded.collector, decoded.notes, decoded.warnings
    col.finish()
    complaints = [line for line in chatter() if line.strip()]
    if col.outliers:
        warnings.append(f"dropped {col.outliers} samples whose time fits neither the clock before them nor "
                        "after (corrupt records)")
    if complaints:
        warnings.append(f"pymavlink skipped corrupt data ({len(complaints)} reports; first: {complaints[0]})")
    if progress is not None:
        progress(1.0)
    segments = col.segments
    if not segments:
        why = f" (pymavlink: {complaints[0]})" if complaints else ""
        raise InputError(path, f"no time-stamped sensor or attitude messages found{why}")
    if segment is None:
        segment = col.longest_segment()
    elif not 0 <= segment < len(segments):
        raise InputError(path, f"has {len(segments)} clock segment(s); segment {segment} does not exist")
    if len(segments) > 1:
        spans = ", ".join(f"#{i}: {a:.1f}-{b:.1f} s" for i, (a, b) in enumerate(segments))
        warnings.append(f"the autopilot clock went back (reboot): {len(segments)} segments ({spans}); "
                        f"using segment {segment} (--segment N for another)")
    flight = Flight(path=path, format=fmt, params=decoded.params, message_counts=decoded.counts,
                    segments=segments, segment_index=segment, notes=notes, warnings=warnings)
    unusable = _fill_series(flight, col, segment)
    flight.vehicle, flight.firmware = identify_vehicle(decoded.texts)
    if not flight.imu and unusable:
        raise InputError(path, "IMU data present but none usable: " + "; ".join(unusable))
    if not flight.imu:
        raise InputError(path, "no IMU data (looked for IMU/IMU2/IMU3 in .bin; RAW_IMU, SCALED_IMU/2/3 "
                               "and HIGHRES_IMU in .tlog)")
    return flight


def _fill_series(flight: Flight, col: Collector, segment: int) -> list[str]:
    """Fill the flight's series from one clock segment; returns why each IMU series that
    holds data was not usable (none when every one was)."""
    def columns(kind, key):
        c = col.columns(kind, key, segment)
        # a message that feeds two series (RAW_IMU: IMU and compass) has the same fixes in both
        for text in ((f"{key}: dropped {c.duplicates} samples with repeated timestamps" if c.duplicates else None),
                     (f"{key}: dropped {c.reordered} samples older than one before them (out of order)"
                      if c.reordered else None)):
            if text and text not in flight.notes:
                flight.notes.append(text)
        return c.t, c.values, c.arrival

    def plausible(key, v, limits):
        """Rows that are finite and within physical ranges; corrupt records decode as anything."""
        ok = np.isfinite(v).all(axis=1)
        finite = np.where(ok[:, None], v, 0.0)
        for cols, limit in limits:
            ok &= np.linalg.norm(finite[:, cols], axis=1) < limit
        if np.count_nonzero(~ok):
            flight.warnings.append(f"{key}: dropped {np.count_nonzero(~ok)} samples with impossible values")
        return ok

    unusable = []
    for key in col.keys("imu"):
        t, v, arrival = columns("imu", key)
        fitted = np.any(v != 0, axis=1)  # an unfitted sensor sends all zeros
        live = fitted & plausible(key, v, IMU_LIMITS)
        if np.count_nonzero(live) >= 2:
            flight.imu[key] = ImuSeries(key, t[live], v[live, :3], v[live, 3:6], arrival=arrival[live])
        elif len(t):
            why = ("all zeros (no sensor fitted?)" if not fitted.any() else
                   "none within ±50 rad/s and ±50 g (saturated or corrupt)" if not live.any() else
                   "fewer than two usable")
            unusable.append(f"{key}: {len(t)} samples, {why}")
    for key in col.keys("mag"):
        t, v, arrival = columns("mag", key)
        live = np.any(v != 0, axis=1) & np.isfinite(v).all(axis=1)
        if np.count_nonzero(live) < 2:
            continue
        # Repair the unit before judging plausibility: a whole series off by 1e6 is a unit
        # bug, not a series of corrupt records.
        t, v, arrival = t[live], _earth_field_scale(flight, key, v[live]), arrival[live]
        live = plausible(key, v, MAG_LIMITS)
        if np.count_nonzero(live) >= 2:
            flight.mag[key] = MagSeries(key, t[live], v[live], arrival=arrival[live])
    for key in col.keys("gps"):
        t, v, arrival = columns("gps", key)
        if len(t):
            flight.gps = GpsSeries(key, t, v[:, 0], v[:, 1], v[:, 2], v[:, 3:6], v[:, 6].astype(int),
                                   v[:, 7].astype(int), v[:, 8], arrival=arrival)
    for key in col.keys("baro"):
        t, v, arrival = columns("baro", key)
        if len(t):
            flight.baro = BaroSeries(key, t, v[:, 0], v[:, 1], arrival=arrival)
    flight.attitude = _attitude(col, "att", segment, columns)
    flight.truth = _attitude(col, "truth", segment, columns)
    return unusable


def _earth_field_scale(flight: Flight, key: str, field: np.ndarray) -> np.ndarray:
    """Fix a magnetometer whose unit is off by powers of 1000.

    Earth's field is 0.25-0.65 gauss (25-65 µT) everywhere. ArduPilot 4.7 sends HIGHRES_IMU
    xmag..zmag at 1e6 times the gauss the message defines (seen: 580000 for 0.58 G), so a
    median strength far outside any plausible field is rescaled by the power of 1000 that
    brings it back, and the note says so. Heading only needs the direction, but a field in
    the wrong unit must not leave the reader.
    """
    power, strength = earth_field_power(field)
    if power == 0:
        return field
    flight.notes.append(f"{key}: magnetometer strength {strength * 1e4:.4g} G is implausible; "
                        f"rescaled by 1e{-3 * power} to {strength * 1e4 * 10.0 ** (-3 * power):.3g} G")
    return field * 10.0 ** (-3 * power)


def earth_field_power(field: np.ndarray) -> tuple[int, float]:
    """(k, median strength in tesla): the field reads 1000^k times what the Earth's can be
    (``_earth_field_scale``); k = 0 for a plausible one."""
    strength = float(np.median(np.linalg.norm(field, axis=1)))
    if not strength > 0:
        return 0, strength
    return int(round(np.log10(strength / 50e-6) / 3)), strength


def _attitude(col: Collector, prefix: str, segment: int, columns) -> AttitudeSeries | None:
    """The attitude series with most samples among the Euler and quaternion messages."""
    best = None
    for kind in (f"{prefix}_euler", f"{prefix}_quat"):
        for key in col.keys(kind):
            t, v, _ = columns(kind, key)
            if not len(t):
                continue
            ok = np.isfinite(v).all(axis=1) & (np.abs(v).max(axis=1) < 10.0)  # rad or unit quaternion
            t, v = t[ok], v[ok]
            if kind.endswith("quat"):
                ok = np.linalg.norm(v, axis=1) > 0.5
                t, v = t[ok], v[ok]
            if not len(t):
                continue
            q = quat.from_euler(v[:, 0], v[:, 1], v[:, 2]) if kind.endswith("euler") else quat.normalize(v)
            if best is None or len(t) > len(best.t):
                best = AttitudeSeries(key, t, q)
    return best


def identify_vehicle(texts: list[str]) -> tuple[str | None, str | None]:
    """(vehicle, firmware) from the version strings the autopilot wrote."""
    for text in texts:
        m = re.search(r"(Ardu(?:Copter|Plane|Rover|Sub)|APM:(?:Copter|Plane|Rover)|PX4)[^\n]*", text)
        if m:
            firmware = m.group(0).strip()
            vehicle = m.group(1).replace("APM:", "Ardu")
            return vehicle, firmware
    version = next((t[len("version "):] for t in texts if t.startswith("version ")), None)
    for text in texts:
        if text.startswith("heartbeat "):
            _, _, mav_type, _, autopilot = text.split()
            vehicle = enum_name("MAV_TYPE", int(mav_type))
            autopilot_name = enum_name("MAV_AUTOPILOT", int(autopilot))
            return vehicle, " ".join(x for x in (autopilot_name, version) if x)
    return None, version


def enum_name(enum: str, value: int) -> str:
    """'QUADROTOR' for MAV_TYPE 2: MAVLink's own name, without its prefix."""
    from pymavlink.dialects.v20 import ardupilotmega as mavlink
    entry = mavlink.enums.get(enum, {}).get(value)
    return entry.name.replace(enum + "_", "") if entry else f"{enum} {value}"


def imu_rate(series: ImuSeries) -> float:
    """Median sample rate, Hz."""
    if len(series.t) < 2:
        return 0.0
    return float(1.0 / np.median(np.diff(series.t)))


def best_imu_source(flight: Flight) -> str:
    """The IMU to estimate from: the highest sample count (within 2 %), then IMU_PREFERENCE."""
    return pick_imu({k: len(s.t) for k, s in flight.imu.items()})


def pick_imu(counts: dict[str, int]) -> str:
    """``best_imu_source`` on {source: sample count} (a log's, or what a live link has sent)."""
    top = max(counts.values())
    candidates = [k for k, n in counts.items() if n >= 0.98 * top]

    def rank(key):
        return IMU_PREFERENCE.index(key) if key in IMU_PREFERENCE else len(IMU_PREFERENCE)
    return sorted(candidates, key=lambda k: (rank(k), k))[0]


def mag_for_imu(flight: Flight, imu_source: str) -> str | None:
    """The magnetometer to pair with an IMU: the one in the same message (tlog), else the first."""
    return pick_mag(list(flight.mag), imu_source)


def pick_mag(mag_sources: list[str], imu_source: str) -> str | None:
    """``mag_for_imu`` on a list of magnetometer sources."""
    if imu_source in mag_sources:
        return imu_source
    for key in ("MAG[0]", "HIGHRES_IMU", "RAW_IMU", "SCALED_IMU", "SCALED_IMU2"):
        if key in mag_sources:
            return key
    return mag_sources[0] if mag_sources else None
