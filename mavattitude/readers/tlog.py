"""MAVLink telemetry logs (.tlog): pymavlink decodes, we keep columns.

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
| SIMSTATE (ArduPilot SITL truth) | roll, pitch, yaw | rad |
| PARAM_VALUE | param_id, param_value | - |

Time: the autopilot's ``time_boot_ms`` / ``time_usec`` (µs since boot), never the ground
station's receive time. A message without a boot time (SIMSTATE, or a GPS_RAW_INT with a
zero or UNIX-epoch time) takes the latest boot time its vehicle sent: ArduPilot sends it in
the same burst as the message that carried that time.
"""
from __future__ import annotations

import math
import os

from pymavlink import mavutil

from ..errors import InputError
from .collect import Collector, Decoded

G_STD = 9.80665
MILLI_G_TO_MS2 = G_STD / 1000.0
MRAD_TO_RAD = 1e-3
MILLIGAUSS_TO_TESLA = 1e-7
GAUSS_TO_TESLA = 1e-4
HPA_TO_PA = 100.0
# A time_usec larger than this (~31 years) is a UNIX time, not time since boot.
EPOCH_THRESHOLD_US = 1e15
MAV_AUTOPILOT_INVALID = 8

SCALED_IMUS = ("RAW_IMU", "SCALED_IMU", "SCALED_IMU2", "SCALED_IMU3")


def _boot_time(msg) -> float | None:
    """Seconds since boot from the message's own time field, or None."""
    ms = getattr(msg, "time_boot_ms", None)
    if ms is not None:
        return ms * 1e-3 if ms > 0 else None
    us = getattr(msg, "time_usec", None)
    if us is not None and 0 < us < EPOCH_THRESHOLD_US:
        return us * 1e-6
    return None


def _imu_key(name: str, msg) -> str:
    # RAW_IMU and HIGHRES_IMU carry an instance field "id" (not the message id attribute).
    inst = msg.id if name in ("RAW_IMU", "HIGHRES_IMU") and "id" in msg.get_fieldnames() else 0
    return f"{name}[{inst}]" if inst else name


def _vehicle_version(msg) -> str:
    v = msg.flight_sw_version
    return f"{(v >> 24) & 0xFF}.{(v >> 16) & 0xFF}.{(v >> 8) & 0xFF}"


class MessageDecoder:
    """One vehicle's MAVLink messages -> samples in SI units on its clock.

    ``decode(msg, add)`` calls ``add(kind, key, t, row)`` for each sample a message carries
    (kinds: imu, mag, gps, baro, att_euler, att_quat, truth_euler; ``t`` seconds since boot),
    and keeps parameters (``params``) and identity texts (``texts``: STATUSTEXT, version,
    heartbeat type). Shared by the .tlog reader and the live link, so a packet converts the same
    way whether it came from a file or a socket.
    """

    def __init__(self):
        self.params: dict[str, float] = {}
        self.texts: list[str] = []
        self.heard_heartbeat = False
        self.last_t = None  # the vehicle's latest boot time, for messages that carry none

    def decode(self, msg, add) -> None:
        name = msg.get_type()
        if name == "PARAM_VALUE":
            self.params[msg.param_id] = float(msg.param_value)
            return
        if name == "STATUSTEXT":
            self.texts.append(msg.text)
            return
        if name == "AUTOPILOT_VERSION":
            self.texts.append(f"version {_vehicle_version(msg)}")
            return
        if name == "HEARTBEAT":
            if not self.heard_heartbeat:  # the vehicle's type, once
                self.texts.append(f"heartbeat type {msg.type} autopilot {msg.autopilot}")
                self.heard_heartbeat = True
            return
        t = _boot_time(msg)
        if t is None:
            t = self.last_t
        elif name != "GPS_RAW_INT":  # its time is the fix's, older than the send time
            self.last_t = t
        if t is None:
            return
        if name in SCALED_IMUS:
            key = _imu_key(name, msg)
            add("imu", key, t,
                (msg.xgyro * MRAD_TO_RAD, msg.ygyro * MRAD_TO_RAD, msg.zgyro * MRAD_TO_RAD,
                 msg.xacc * MILLI_G_TO_MS2, msg.yacc * MILLI_G_TO_MS2, msg.zacc * MILLI_G_TO_MS2))
            add("mag", key, t,
                (msg.xmag * MILLIGAUSS_TO_TESLA, msg.ymag * MILLIGAUSS_TO_TESLA,
                 msg.zmag * MILLIGAUSS_TO_TESLA))
        elif name == "HIGHRES_IMU":
            key = _imu_key(name, msg)
            add("imu", key, t, (msg.xgyro, msg.ygyro, msg.zgyro, msg.xacc, msg.yacc, msg.zacc))
            add("mag", key, t,
                (msg.xmag * GAUSS_TO_TESLA, msg.ymag * GAUSS_TO_TESLA, msg.zmag * GAUSS_TO_TESLA))
        elif name == "GPS_RAW_INT":
            speed = msg.vel * 0.01 if msg.vel != 65535 else math.nan
            course = math.radians(msg.cog * 0.01) if msg.cog != 65535 else math.nan
            h_acc = msg.h_acc * 1e-3 if getattr(msg, "h_acc", 0) else math.nan
            add("gps", "GPS_RAW_INT", t,
                (msg.lat * 1e-7, msg.lon * 1e-7, msg.alt * 1e-3,
                 speed * math.cos(course), speed * math.sin(course), math.nan,
                 msg.fix_type, msg.satellites_visible, h_acc))
        elif name == "SCALED_PRESSURE":
            add("baro", "SCALED_PRESSURE", t, (msg.press_abs * HPA_TO_PA, math.nan))
        elif name == "ATTITUDE":
            add("att_euler", "ATTITUDE", t, (msg.roll, msg.pitch, msg.yaw))
        elif name == "ATTITUDE_QUATERNION":
            add("att_quat", "ATTITUDE_QUATERNION", t, (msg.q1, msg.q2, msg.q3, msg.q4))
        elif name == "SIMSTATE":
            add("truth_euler", "SIMSTATE", t, (msg.roll, msg.pitch, msg.yaw))


def is_vehicle(msg) -> bool:
    """Whether a message says its sender is the vehicle: an autopilot's HEARTBEAT, or IMU or
    attitude data (a ground station or a companion computer sends neither)."""
    name = msg.get_type()
    return ((name == "HEARTBEAT" and msg.autopilot != MAV_AUTOPILOT_INVALID)
            or name in SCALED_IMUS or name in ("HIGHRES_IMU", "ATTITUDE"))


def read_tlog(path: str, progress=None) -> Decoded:
    """Decode a .tlog. ``progress(fraction)`` is called as it goes."""
    try:
        # the telemetry reader itself: mavlink_connection would choose one by the file's name
        # (DataFlash for a .bin) and would run a file whose path holds "/bin/"
        mavutil.set_dialect("ardupilotmega")
        log = mavutil.mavmmaplog(path)
    except Exception as exc:
        raise InputError(path, f"not a readable telemetry log ({exc})")
    col = Collector()
    decoder = MessageDecoder()
    counts: dict[str, int] = {}
    size = max(os.path.getsize(path), 1)
    vehicle_sysid = None
    other_systems = set()
    n = 0
    while True:
        try:
            msg = log.recv_msg()
        except Exception as exc:
            raise InputError(path, f"corrupt telemetry data ({exc})")
        if msg is None:
            break
        n += 1
        if progress is not None and n % 20000 == 0:
            progress(log.f.tell() / size)
        name = msg.get_type()
        counts[name] = counts.get(name, 0) + 1
        if name == "BAD_DATA":
            continue
        sysid = msg.get_srcSystem()
        if vehicle_sysid is None:
            # The vehicle: the first system that says it is an autopilot, or that sends IMU data.
            if not is_vehicle(msg):
                continue
            vehicle_sysid = sysid
        if sysid != vehicle_sysid:
            other_systems.add(sysid)
            continue
        decoder.decode(msg, col.add)
    out = Decoded(col, decoder.params, decoder.texts, counts)
    if other_systems:
        out.notes.append(f"ignored messages from other MAVLink systems {sorted(other_systems)} "
                         f"(vehicle is system {vehicle_sysid})")
    if counts.get("BAD_DATA"):
        out.warnings.append(f"skipped {counts['BAD_DATA']} corrupt or unknown packets")
    return out
