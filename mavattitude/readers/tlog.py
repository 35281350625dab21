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
from .collect import Collector

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


def read_tlog(path: str, progress=None):
    """Decode a .tlog into a Collector plus metadata. ``progress(fraction)`` is called as it goes."""
    try:
        log = mavutil.mavlink_connection(path, dialect="ardupilotmega", robust_parsing=True)
    except Exception as exc:
        raise InputError(path, f"not a readable telemetry log ({exc})")
    col = Collector()
    params: dict[str, float] = {}
    texts: list[str] = []
    counts: dict[str, int] = {}
    size = max(os.path.getsize(path), 1)
    vehicle_sysid = None
    other_systems = set()
    heard_heartbeat = False
    last_t = None  # the vehicle's latest boot time, for messages that carry none
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
            if (name == "HEARTBEAT" and msg.autopilot != MAV_AUTOPILOT_INVALID) or \
                    name in SCALED_IMUS or name in ("HIGHRES_IMU", "ATTITUDE"):
                vehicle_sysid = sysid
            else:
                continue
        if sysid != vehicle_sysid:
            other_systems.add(sysid)
            continue
        if name == "PARAM_VALUE":
            params[msg.param_id] = float(msg.param_value)
            continue
        if name == "STATUSTEXT":
            texts.append(msg.text)
            continue
        if name == "AUTOPILOT_VERSION":
            texts.append(f"version {_vehicle_version(msg)}")
            continue
        if name == "HEARTBEAT":
            if not heard_heartbeat:  # the vehicle's type, once
                texts.append(f"heartbeat type {msg.type} autopilot {msg.autopilot}")
                heard_heartbeat = True
            continue
        t = _boot_time(msg)
        if t is None:
            t = last_t
        elif name != "GPS_RAW_INT":  # its time is the fix's, older than the send time
            last_t = t
        if t is None:
            continue
        if name in SCALED_IMUS:
            col.add("imu", _imu_key(name, msg), t,
                    (msg.xgyro * MRAD_TO_RAD, msg.ygyro * MRAD_TO_RAD, msg.zgyro * MRAD_TO_RAD,
                     msg.xacc * MILLI_G_TO_MS2, msg.yacc * MILLI_G_TO_MS2, msg.zacc * MILLI_G_TO_MS2))
            col.add("mag", _imu_key(name, msg), t,
                    (msg.xmag * MILLIGAUSS_TO_TESLA, msg.ymag * MILLIGAUSS_TO_TESLA,
                     msg.zmag * MILLIGAUSS_TO_TESLA))
        elif name == "HIGHRES_IMU":
            col.add("imu", _imu_key(name, msg), t,
                    (msg.xgyro, msg.ygyro, msg.zgyro, msg.xacc, msg.yacc, msg.zacc))
            col.add("mag", _imu_key(name, msg), t,
                    (msg.xmag * GAUSS_TO_TESLA, msg.ymag * GAUSS_TO_TESLA, msg.zmag * GAUSS_TO_TESLA))
        elif name == "GPS_RAW_INT":
            speed = msg.vel * 0.01 if msg.vel != 65535 else math.nan
            course = math.radians(msg.cog * 0.01) if msg.cog != 65535 else math.nan
            h_acc = msg.h_acc * 1e-3 if getattr(msg, "h_acc", 0) else math.nan
            col.add("gps", "GPS_RAW_INT", t,
                    (msg.lat * 1e-7, msg.lon * 1e-7, msg.alt * 1e-3,
                     speed * math.cos(course), speed * math.sin(course), math.nan,
                     msg.fix_type, msg.satellites_visible, h_acc))
        elif name == "SCALED_PRESSURE":
            col.add("baro", "SCALED_PRESSURE", t, (msg.press_abs * HPA_TO_PA, math.nan))
        elif name == "ATTITUDE":
            col.add("att_euler", "ATTITUDE", t, (msg.roll, msg.pitch, msg.yaw))
        elif name == "ATTITUDE_QUATERNION":
            col.add("att_quat", "ATTITUDE_QUATERNION", t, (msg.q1, msg.q2, msg.q3, msg.q4))
        elif name == "SIMSTATE":
            col.add("truth_euler", "SIMSTATE", t, (msg.roll, msg.pitch, msg.yaw))
    notes = []
    if other_systems:
        notes.append(f"ignored messages from other MAVLink systems {sorted(other_systems)} "
                     f"(vehicle is system {vehicle_sysid})")
    if counts.get("BAD_DATA"):
        notes.append(f"{counts['BAD_DATA']} corrupt or unknown packets skipped")
    return col, params, texts, counts, notes
