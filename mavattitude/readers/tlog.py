"""MAVLink telemetry logs (.tlog): decoded in bulk by message type (``tlogrecords``), kept as columns.

Units as sent (MAVLink common/ardupilotmega definitions):

| message | fields used | unit on the wire |
|---|---|---|
| RAW_IMU (ArduPilot) | x/y/zacc, x/y/zgyro, x/y/zmag | mG, mrad/s, mGauss: ArduPilot fills it like SCALED_IMU |
| SCALED_IMU, SCALED_IMU2, SCALED_IMU3 | same | mG, mrad/s, mGauss |
| HIGHRES_IMU (PX4, ArduPilot) | same | m/s², rad/s, gauss |
| GPS_RAW_INT | lat, lon, alt, vel, cog, fix_type, satellites_visible, h_acc | degE7, degE7, mm, cm/s, cdeg, -, -, mm |
| SCALED_PRESSURE | press_abs | hPa |
| ATTITUDE | roll, pitch, yaw | rad |
| ATTITUDE_QUATERNION | q1..q4 | - |
| AHRS2, AHRS3 (ArduPilot: its other estimators; no time of their own) | roll, pitch, yaw | rad |
| SIMSTATE (ArduPilot SITL truth) | roll, pitch, yaw | rad |
| SYSTEM_TIME | time_unix_usec (else GPS_RAW_INT time_usec when a UNIX time) | µs: the log's date |
| PARAM_VALUE | param_id, param_value | - |
| HEARTBEAT, STATUSTEXT (``logevents``; no time of their own) | custom_mode, base_mode; severity, text | mode number and armed bit; text |

Time: the autopilot's ``time_boot_ms`` / ``time_usec`` (µs since boot), never the ground
station's receive time. A message without a boot time (SIMSTATE, or a GPS_RAW_INT with a
zero or UNIX-epoch time) takes the latest boot time of its vehicle's other sample messages:
ArduPilot sends it in the same burst as the message that carried that time.

The vehicle is the first system that says it is one (``is_vehicle``); other systems' messages
are counted and ignored.
"""
from __future__ import annotations

from types import SimpleNamespace

import numpy as np

from ..errors import InputError
from .collect import Collector, Decoded, first_utc
from .dfrecords import open_log
from .tlogrecords import decode, dialect, msgid, packet_bytes, scan

G_STD = 9.80665
MILLI_G_TO_MS2 = G_STD / 1000.0
MRAD_TO_RAD = 1e-3
MILLIGAUSS_TO_TESLA = 1e-7
GAUSS_TO_TESLA = 1e-4
HPA_TO_PA = 100.0
# A time_usec larger than this (~31 years) is a UNIX time, not time since boot.
EPOCH_THRESHOLD_US = 1e15
MAV_AUTOPILOT_INVALID = 8

TLOG_SEARCH_BYTES = 1 << 16  # a ground station's header before the first record (1,359 bytes seen)
TLOG_TIME_RANGE_US = (946684800e6, 4102444800e6)  # a record's UNIX time: 2000 to 2100


def tlog_start(data: bytes) -> int | None:
    """Where the first of two consecutive telemetry records starts in ``data`` (a record: a
    big-endian UNIX time in µs, then a MAVLink 1 or 2 packet), or None. What comes before is
    a header pymavlink skips too."""
    def record_size(p: int) -> int | None:
        if p + 18 > len(data) or data[p + 8] not in (0xFE, 0xFD):
            return None
        if not TLOG_TIME_RANGE_US[0] <= int.from_bytes(data[p:p + 8], "big") <= TLOG_TIME_RANGE_US[1]:
            return None
        length = data[p + 9]
        if data[p + 8] == 0xFE:
            return 8 + 6 + length + 2
        return 8 + 10 + length + 2 + (13 if data[p + 10] & 0x01 else 0)  # v2, signed when flagged

    for start in range(0, max(len(data) - 18, 0)):
        if data[start + 8] not in (0xFE, 0xFD):
            continue
        size = record_size(start)
        if size is not None and (start + size >= len(data) or record_size(start + size) is not None):
            return start
    return None


# The messages whose samples we keep, by kind, and those read for their text or numbers only.
IMU_MESSAGES = ("RAW_IMU", "SCALED_IMU", "SCALED_IMU2", "SCALED_IMU3", "HIGHRES_IMU")
SAMPLE_MESSAGES = IMU_MESSAGES + ("GPS_RAW_INT", "SCALED_PRESSURE", "ATTITUDE", "ATTITUDE_QUATERNION", "SIMSTATE")
OTHER_MESSAGES = ("PARAM_VALUE", "STATUSTEXT", "AUTOPILOT_VERSION", "HEARTBEAT", "SYSTEM_TIME")
# The autopilot's attitude streams beside ATTITUDE (``readers.attitudes`` names them): read from a
# file for comparison; a live link does not ask for them, and decodes them when they come (its
# reference checks compare them with ATTITUDE, as replay's do).
STREAM_MESSAGES = ("AHRS2", "AHRS3")
VEHICLE_MESSAGES = IMU_MESSAGES + ("ATTITUDE",)  # what only a vehicle sends (``is_vehicle``)


# ---------------------------------------------------------------- units, shared by file and link
# Each takes one message or, from the bulk reader, a message type's columns (the same names
# holding arrays), and returns the sample's values in SI units.

def boot_time(m):
    """Seconds since boot from the message's own time field; NaN where it has none (zero, or
    a UNIX time in time_usec)."""
    if hasattr(m, "time_boot_ms"):
        ms = np.asarray(m.time_boot_ms, np.float64)
        return np.where(ms > 0, ms * 1e-3, np.nan)
    if hasattr(m, "time_usec"):
        us = np.asarray(m.time_usec, np.float64)
        return np.where((us > 0) & (us < EPOCH_THRESHOLD_US), us * 1e-6, np.nan)
    return np.full(np.shape(m.roll), np.nan)  # SIMSTATE: no time of its own


def boot_time_of(msg) -> float | None:
    """``boot_time`` of one message, without numpy (a live link decodes 20,000 a second)."""
    ms = getattr(msg, "time_boot_ms", None)
    if ms is not None:
        return ms * 1e-3 if ms > 0 else None
    us = getattr(msg, "time_usec", None)
    return us * 1e-6 if us is not None and 0 < us < EPOCH_THRESHOLD_US else None


def imu_values(name: str, m) -> tuple[tuple, tuple]:
    """(gyro rad/s + accel m/s², compass T) of an IMU message."""
    if name == "HIGHRES_IMU":
        return ((m.xgyro, m.ygyro, m.zgyro, m.xacc, m.yacc, m.zacc),
                (m.xmag * GAUSS_TO_TESLA, m.ymag * GAUSS_TO_TESLA, m.zmag * GAUSS_TO_TESLA))
    return ((m.xgyro * MRAD_TO_RAD, m.ygyro * MRAD_TO_RAD, m.zgyro * MRAD_TO_RAD,
             m.xacc * MILLI_G_TO_MS2, m.yacc * MILLI_G_TO_MS2, m.zacc * MILLI_G_TO_MS2),
            (m.xmag * MILLIGAUSS_TO_TESLA, m.ymag * MILLIGAUSS_TO_TESLA, m.zmag * MILLIGAUSS_TO_TESLA))


def imu_instance(name: str, m):
    """RAW_IMU and HIGHRES_IMU carry their sensor's instance in the field ``id`` (0 for the
    first). A pymavlink message of a dialect without that field still has an ``id`` attribute:
    its message id, not an instance."""
    if name not in ("RAW_IMU", "HIGHRES_IMU"):
        return 0
    fields = m.get_fieldnames() if hasattr(m, "get_fieldnames") else vars(m)
    return m.id if "id" in fields else 0


def imu_key(name: str, instance: int) -> str:
    return f"{name}[{instance}]" if instance else name


def gps_values(m) -> tuple:
    """lat, lon (deg), alt (m AMSL), north, east, down velocity (m/s; down not sent), fix type,
    satellites, horizontal accuracy (m; NaN when not sent)."""
    vel = np.asarray(m.vel, np.float64)
    cog = np.asarray(m.cog, np.float64)
    speed = np.where(vel != 65535, vel * 0.01, np.nan)
    course = np.where(cog != 65535, np.radians(cog * 0.01), np.nan)
    h_acc = np.asarray(getattr(m, "h_acc", 0), np.float64)
    return (m.lat * 1e-7, m.lon * 1e-7, m.alt * 1e-3, speed * np.cos(course), speed * np.sin(course),
            np.full(np.shape(vel), np.nan), m.fix_type, m.satellites_visible, np.where(h_acc > 0, h_acc * 1e-3, np.nan))


def sample_values(name: str, m) -> tuple | None:
    """(kind, values) of the non-IMU sample messages."""
    if name == "GPS_RAW_INT":
        return "gps", gps_values(m)
    if name == "SCALED_PRESSURE":
        return "baro", (m.press_abs * HPA_TO_PA, np.full(np.shape(m.press_abs), np.nan))
    if name == "ATTITUDE":
        return "att_euler", (m.roll, m.pitch, m.yaw)
    if name == "ATTITUDE_QUATERNION":
        return "att_quat", (m.q1, m.q2, m.q3, m.q4)
    if name == "SIMSTATE":
        return "truth_euler", (m.roll, m.pitch, m.yaw)
    if name in STREAM_MESSAGES:
        return "stream_euler", (m.roll, m.pitch, m.yaw)
    return None


def _vehicle_version(msg) -> str:
    v = msg.flight_sw_version
    return f"{(v >> 24) & 0xFF}.{(v >> 16) & 0xFF}.{(v >> 8) & 0xFF}"


class MessageDecoder:
    """One vehicle's MAVLink messages -> samples in SI units on its clock, one message at a time
    (the live link; a .tlog is read in bulk by ``read_tlog`` with the same unit functions).

    ``decode(msg, add)`` calls ``add(kind, key, t, row)`` for each sample a message carries
    (kinds: imu, mag, gps, baro, att_euler, att_quat, truth_euler, stream_euler; ``t`` seconds since boot),
    and keeps parameters (``params``), identity texts (``texts``: STATUSTEXT, version,
    heartbeat type) and the vehicle's first set UNIX time (``utc_s``, s: SYSTEM_TIME's). A
    message without a boot time (SIMSTATE, or a GPS_RAW_INT with a zero or UNIX-epoch time)
    takes the latest boot time of the vehicle's other sample messages: ArduPilot sends it in the
    same burst as the message that carried that time.
    """

    def __init__(self):
        self.params: dict[str, float] = {}
        self.texts: list[str] = []
        self.utc_s: float | None = None
        self.heard_heartbeat = False
        self.last_t = None  # the vehicle's latest boot time, for messages that carry none

    def note(self, msg) -> None:
        """A parameter, a text, the vehicle's identity or its UNIX time."""
        name = msg.get_type()
        if name == "SYSTEM_TIME":
            if self.utc_s is None:
                self.utc_s = first_utc(msg.time_unix_usec * 1e-6)
        elif name == "PARAM_VALUE":
            self.params[msg.param_id] = float(msg.param_value)
        elif name == "STATUSTEXT":
            self.texts.append(msg.text)
        elif name == "AUTOPILOT_VERSION":
            self.texts.append(f"version {_vehicle_version(msg)}")
        elif name == "HEARTBEAT" and not self.heard_heartbeat:  # the vehicle's type, once
            self.texts.append(f"heartbeat type {msg.type} autopilot {msg.autopilot}")
            self.heard_heartbeat = True

    def decode(self, msg, add) -> None:
        name = msg.get_type()
        if name in OTHER_MESSAGES:
            self.note(msg)
            return
        if name not in SAMPLE_MESSAGES and name not in STREAM_MESSAGES:
            return
        t = boot_time_of(msg)
        if t is None:
            t = self.last_t
        elif name != "GPS_RAW_INT":  # its time is the fix's, older than the send time
            self.last_t = t
        if t is None:
            return
        if name in IMU_MESSAGES:
            key = imu_key(name, imu_instance(name, msg))
            imu, mag = imu_values(name, msg)
            add("imu", key, t, imu)
            add("mag", key, t, mag)
        else:
            kind, values = sample_values(name, msg)
            add(kind, name, t, tuple(float(v) for v in values))


def is_vehicle(msg) -> bool:
    """Whether a message says its sender is the vehicle: an autopilot's HEARTBEAT, or IMU or
    attitude data (a ground station or a companion computer sends neither)."""
    name = msg.get_type()
    return ((name == "HEARTBEAT" and msg.autopilot != MAV_AUTOPILOT_INVALID)
            or name in VEHICLE_MESSAGES)


def read_tlog(path: str, progress=None) -> Decoded:
    """Decode a .tlog in bulk (``tlogrecords``). ``progress(fraction)`` is called as it goes."""
    data = open_log(path)
    with open(path, "rb") as f:
        start = tlog_start(f.read(TLOG_SEARCH_BYTES))
    if start is None:
        raise InputError(path, "not a readable telemetry log (no MAVLink records found)")
    samples = SAMPLE_MESSAGES + STREAM_MESSAGES
    packets = scan(data, start, list(samples + OTHER_MESSAGES))
    if progress is not None:
        progress(0.5)
    names = {msgid(name): name for name in samples + OTHER_MESSAGES}
    rows_of = {name: np.flatnonzero(packets.msgids == i) for i, name in names.items()}
    text_rows = np.sort(np.concatenate([rows_of[name] for name in OTHER_MESSAGES]))
    mav = dialect.MAVLink(None)  # the few text and identity messages: pymavlink decodes them
    notes = {i: mav.decode(packet_bytes(data, packets, i)) for i in text_rows.tolist()}

    # The vehicle: the first system that says it is an autopilot, or that sends IMU or attitude data.
    said_so = [rows_of[name] for name in VEHICLE_MESSAGES]
    said_so.append(np.array([i for i, m in notes.items() if is_vehicle(m)], np.int64))
    first = min((int(r[0]) for r in said_so if len(r)), default=None)
    if first is None:
        return Decoded(Collector(), {}, [], packets.counts, warnings=_damage(packets))
    vehicle = int(packets.sysids[first])
    after_first = np.arange(len(packets.msgids)) >= first
    mine = (packets.sysids == vehicle) & after_first

    decoder = MessageDecoder()
    for i, msg in notes.items():
        if mine[i]:
            decoder.note(msg)
    columns, order = {}, {}
    for name in samples:  # only the vehicle's packets are decoded
        rows = rows_of[name][mine[rows_of[name]]]
        if len(rows):
            columns[name] = SimpleNamespace(**decode(data, packets, name, rows))
            order[name] = packets.offsets[rows]
    col = Collector()
    _collect(col, columns, order)
    _collect_events(col, [(packets.offsets[i], m) for i, m in notes.items() if mine[i]])
    gps_utc = first_utc(np.asarray(columns["GPS_RAW_INT"].time_usec, np.float64) * 1e-6) \
        if "GPS_RAW_INT" in columns else None  # older ArduPilot sends the fix's UNIX time there
    out = Decoded(col, decoder.params, decoder.texts, packets.counts, warnings=_damage(packets),
                  utc_s=decoder.utc_s if decoder.utc_s is not None else gps_utc)
    others = sorted(set(packets.sysids[~mine & after_first].tolist()) - {vehicle})
    if others:
        out.notes.append(f"ignored messages from other MAVLink systems {others} (vehicle is system {vehicle})")
    return out


def _collect(col: Collector, columns: dict, order: dict) -> None:
    """The vehicle's sample messages (name -> columns; ``order``: each packet's offset in the
    file) into the collector, each sample on the boot clock (``MessageDecoder`` says how a
    message without a time gets one)."""
    times = {name: boot_time(m) for name, m in columns.items()}
    # the latest time of the vehicle's other sample messages, in file order
    timed = [(order[n][np.isfinite(t)], t[np.isfinite(t)]) for n, t in times.items() if n != "GPS_RAW_INT"]
    clock_at = np.concatenate([at for at, _ in timed] + [np.empty(0, np.int64)])
    clock_t = np.concatenate([t for _, t in timed] + [np.empty(0)])
    by_place = np.argsort(clock_at)
    clock_at, clock_t = clock_at[by_place], clock_t[by_place]
    for name, m in columns.items():
        t, at = times[name], order[name]
        missing = ~np.isfinite(t)
        if missing.any():
            before = np.searchsorted(clock_at, at[missing]) - 1
            t[missing] = np.where(before >= 0, clock_t[np.maximum(before, 0)], np.nan)
        has_time = np.isfinite(t)
        if name in IMU_MESSAGES:
            instance = np.broadcast_to(imu_instance(name, m), t.shape)
            imu, mag = (np.column_stack(v) for v in imu_values(name, m))
            for i in np.unique(instance):
                sel = (instance == i) & has_time
                col.add_columns("imu", imu_key(name, int(i)), at[sel], t[sel], imu[sel])
                # after the IMU sample of its packet, as a link decodes them (record offsets are
                # ≥ 16 bytes apart: one more is still before the next packet)
                col.add_columns("mag", imu_key(name, int(i)), at[sel] + 1, t[sel], mag[sel])
        else:
            kind, values = sample_values(name, m)
            values = np.column_stack([np.broadcast_to(np.asarray(v, np.float64), t.shape) for v in values])
            col.add_columns(kind, name, at[has_time], t[has_time], values[has_time])


def _collect_events(col: Collector, notes: list) -> None:
    """The vehicle's modes and arming (its autopilot's HEARTBEAT: not a gimbal's or a camera's)
    and its STATUSTEXT lines (``notes``: (offset, message) in file order) as event rows; they
    carry no time: each takes the last sample's before it (``Collector.add_events``)."""
    from pymavlink import mavutil

    beats = [(at, m) for at, m in notes if m.get_type() == "HEARTBEAT" and m.autopilot != MAV_AUTOPILOT_INVALID]
    texts = [(at, m) for at, m in notes if m.get_type() == "STATUSTEXT"]
    for kind, rows, value, label in (
            ("mode", beats, lambda m: m.custom_mode, mavutil.mode_string_v10),
            ("armed", beats, lambda m: bool(m.base_mode & mavutil.mavlink.MAV_MODE_FLAG_SAFETY_ARMED), None),
            ("text", texts, lambda m: m.severity, lambda m: m.text)):
        if rows:
            col.add_events(kind, "STATUSTEXT" if kind == "text" else "HEARTBEAT", [at for at, _ in rows],
                           np.full(len(rows), np.nan), [value(m) for _, m in rows],
                           None if label is None else [label(m) for _, m in rows])


def _damage(packets) -> list[str]:
    """What the scan could not use, said plainly (nothing for an undamaged log)."""
    notes = []
    if packets.corrupt or packets.unknown:
        notes.append(f"skipped {packets.corrupt + packets.unknown} corrupt or unknown packets "
                     f"({packets.corrupt} with a wrong checksum, {packets.unknown} of unknown message ids)")
    if packets.skipped_bytes:
        notes.append(f"skipped {packets.skipped_bytes:,} bytes that were no MAVLink record")
    return notes
