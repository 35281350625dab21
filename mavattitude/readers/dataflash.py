"""ArduPilot DataFlash logs (.bin): pymavlink decodes, we keep columns.

Units as logged (pymavlink applies the format-character scaling, e.g. 'c' centidegrees ->
degrees, 'L' 1e-7 degrees -> degrees, but not the FMTU multipliers):

| message | fields used | unit in the log |
|---|---|---|
| IMU, IMU2, IMU3 (old) / IMU with I (new) | GyrX..Z, AccX..Z | rad/s, m/s² |
| MAG, MAG2, MAG3 / MAG with I | MagX..Z | milligauss (FMTU says 1e-3 G; not applied) |
| GPS / GPS with I | Lat, Lng, Alt, Spd, GCrs, VZ, Status, NSats | deg, deg, m AMSL, m/s, deg, m/s down |
| BARO | Press, Alt | Pa, m |
| ATT | Roll, Pitch, Yaw | degrees, yaw 0-360 |
| SIM | Roll, Pitch, Yaw (+ Q1..Q4 when present) | degrees; quaternion |
| PARM | Name, Value | as the parameter |

Time: ``TimeUS`` (µs since boot) or, in old logs, ``TimeMS`` (ms). Old GPS messages carry
GPS time-of-week in ``TimeMS`` and the boot time in ``T`` (ms): we use ``T``.
"""
from __future__ import annotations

import math
import os

from pymavlink import DFReader

from ..errors import InputError
from .collect import Collector

MILLIGAUSS_TO_TESLA = 1e-7  # 1 mG = 1e-3 G = 1e-7 T
DEG = math.pi / 180.0

WANTED = ["IMU", "IMU2", "IMU3", "MAG", "MAG2", "MAG3", "GPS", "BARO", "ATT", "SIM",
          "PARM", "MSG", "VER"]


def _instance(msg, name: str) -> int:
    """Sensor instance: the I field of new logs, or the digit of IMU2/MAG2 in old ones."""
    inst = getattr(msg, "I", None) if "I" in msg._fieldnames else None
    if inst is not None:
        return int(inst)
    return int(name[-1]) - 1 if name[-1].isdigit() else 0


def _time_s(msg, fields) -> float | None:
    if "TimeUS" in fields:
        return msg.TimeUS * 1e-6
    if "TimeMS" in fields:
        return msg.TimeMS * 1e-3
    return None


def read_dataflash(path: str, progress=None):
    """Decode a .bin into a Collector plus metadata. ``progress(fraction)`` is called as it goes."""
    try:
        log = DFReader.DFReader_binary(path, zero_time_base=True)
    except Exception as exc:  # pymavlink raises bare exceptions on garbage
        raise InputError(path, f"not a readable DataFlash log ({exc.__class__.__name__}: {exc})")
    col = Collector()
    params: dict[str, float] = {}
    texts: list[str] = []
    size = max(os.path.getsize(path), 1)
    n = 0
    while True:
        try:
            msg = log.recv_match(type=WANTED)
        except Exception as exc:
            raise InputError(path, f"corrupt DataFlash data near byte {log.offset} ({exc})")
        if msg is None:
            break
        n += 1
        if progress is not None and n % 20000 == 0:
            progress(log.offset / size)
        name = msg.get_type()
        fields = msg._fieldnames
        if name == "PARM":
            params[msg.Name] = float(msg.Value)
            continue
        if name == "MSG":
            texts.append(msg.Message)
            continue
        if name == "VER":
            texts.append(getattr(msg, "FWS", ""))
            continue
        if name == "GPS" and "T" in fields and "TimeUS" not in fields:
            t = msg.T * 1e-3  # old GPS: TimeMS is GPS time of week, T is the boot clock
        else:
            t = _time_s(msg, fields)
        if t is None:
            continue
        if name.startswith("IMU"):
            col.add("imu", f"IMU[{_instance(msg, name)}]", t,
                    (msg.GyrX, msg.GyrY, msg.GyrZ, msg.AccX, msg.AccY, msg.AccZ))
        elif name.startswith("MAG"):
            col.add("mag", f"MAG[{_instance(msg, name)}]", t,
                    (msg.MagX * MILLIGAUSS_TO_TESLA, msg.MagY * MILLIGAUSS_TO_TESLA,
                     msg.MagZ * MILLIGAUSS_TO_TESLA))
        elif name == "GPS":
            if _instance(msg, name) != 0:
                continue
            course = msg.GCrs * DEG
            col.add("gps", "GPS", t,
                    (msg.Lat, msg.Lng, msg.Alt, msg.Spd * math.cos(course), msg.Spd * math.sin(course),
                     msg.VZ, msg.Status, msg.NSats, math.nan))
        elif name == "BARO":
            if _instance(msg, name) != 0:
                continue
            col.add("baro", "BARO", t, (msg.Press, msg.Alt))
        elif name == "ATT":
            col.add("att_euler", "ATT", t, (msg.Roll * DEG, msg.Pitch * DEG, msg.Yaw * DEG))
        elif name == "SIM":
            if "Q1" in fields:
                col.add("truth_quat", "SIM", t, (msg.Q1, msg.Q2, msg.Q3, msg.Q4))
            else:
                col.add("truth_euler", "SIM", t, (msg.Roll * DEG, msg.Pitch * DEG, msg.Yaw * DEG))
    counts = {log.formats[i].name: c for i, c in enumerate(log.counts)
              if c and i in log.formats and log.formats[i].name != "FMT"}
    return col, params, texts, counts
