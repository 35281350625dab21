"""ArduPilot DataFlash logs (.bin): decoded in bulk by type (``dfrecords``), kept as columns.

A record of a wanted type that cannot be decoded by ``dfrecords`` (a format it cannot lay
out) sends the whole log to pymavlink instead, with a note; damage (bytes that are no valid
record) is skipped and counted, and the notes say how much and where.

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

import numpy as np

from ..errors import InputError
from .collect import Collector, Decoded
from .dfrecords import decode, open_log, scan_log

MILLIGAUSS_TO_TESLA = 1e-7  # 1 mG = 1e-3 G = 1e-7 T
DEG = math.pi / 180.0
MAX_INSTANCE = 9  # sensor instances ArduPilot numbers (0-based); beyond: a corrupt record

WANTED = ["IMU", "IMU2", "IMU3", "MAG", "MAG2", "MAG3", "GPS", "BARO", "ATT", "SIM",
          "PARM", "MSG", "VER"]


def read_dataflash(path: str, progress=None) -> Decoded:
    """Decode a .bin. ``progress(fraction)`` is called as it goes."""
    try:
        data = open_log(path)
        scan = scan_log(data, WANTED)
    except Exception as exc:  # not expected: pymavlink may still make something of it
        return _read_with_pymavlink(path, progress, f"read with pymavlink ({type(exc).__name__}: {exc})")
    if progress is not None:
        progress(0.5)
    col = Collector()
    warnings = damage_notes(scan, len(data))
    records = {}
    for name in scan.offsets:
        try:
            records[name] = r = decode(data, scan, name)
            _collect(col, name, r, scan.offsets[name])
        except (ValueError, KeyError) as exc:  # a format the firmware or damage got wrong
            what = f"its format has no column {exc}" if isinstance(exc, KeyError) else str(exc)
            warnings.append(f"{name}: {what} (a corrupt FMT record?): {len(scan.offsets[name])} "
                            "records skipped")
    params = {name: float(value) for name, value in zip(records.get("PARM", {}).get("Name", []),
                                                          records.get("PARM", {}).get("Value", []))}
    texts = list(records.get("MSG", {}).get("Message", [])) + list(records.get("VER", {}).get("FWS", []))
    return Decoded(col, params, texts, dict(scan.counts), warnings=warnings)


def damage_notes(scan, size: int) -> list[str]:
    """What the scan could not use, said plainly (nothing for an undamaged log)."""
    notes = []
    if scan.skipped_bytes:
        notes.append(f"skipped {scan.skipped_bytes:,} bytes of corrupt data "
                     f"({100.0 * scan.skipped_bytes / max(size, 1):.2g} % of the file) in "
                     f"{scan.skipped_stretches} stretch{'es' if scan.skipped_stretches != 1 else ''}, "
                     f"the first at byte {scan.first_skip:,}: records resumed after each")
    if scan.bad_formats:
        notes.append(f"ignored {scan.bad_formats} corrupt message format definition(s) (FMT); "
                     "the messages they define were skipped")
    return notes


def _collect(col: Collector, name: str, r: dict, order: np.ndarray) -> None:
    """One message type's columns into the collector, in SI units (see the table above)."""
    if name in ("PARM", "MSG", "VER"):
        return
    if name == "GPS" and "T" in r and "TimeUS" not in r:
        t = r["T"] * 1e-3  # old GPS: TimeMS is GPS time of week, T is the boot clock
    elif "TimeUS" in r:
        t = r["TimeUS"] * 1e-6
    elif "TimeMS" in r:
        t = r["TimeMS"] * 1e-3
    else:
        return
    if "I" in r:
        instance = r["I"].astype(np.int64)
    else:
        instance = np.full(len(t), int(name[-1]) - 1 if name[-1].isdigit() else 0)
    plausible = (instance >= 0) & (instance <= MAX_INSTANCE)
    if name.startswith("IMU") or name.startswith("MAG"):
        kind, cols, scale = (("imu", ("GyrX", "GyrY", "GyrZ", "AccX", "AccY", "AccZ"), 1.0)
                             if name.startswith("IMU") else ("mag", ("MagX", "MagY", "MagZ"), MILLIGAUSS_TO_TESLA))
        values = np.column_stack([r[c] for c in cols]) * scale
        for i in np.unique(instance[plausible]):
            mine = instance == i
            col.add_columns(kind, f"{kind.upper() if kind == 'imu' else 'MAG'}[{i}]", order[mine], t[mine],
                            values[mine])
        return
    primary = instance == 0
    if name == "GPS":
        course = r["GCrs"] * DEG
        values = np.column_stack([r["Lat"], r["Lng"], r["Alt"], r["Spd"] * np.cos(course),
                                  r["Spd"] * np.sin(course), r["VZ"], r["Status"], r["NSats"],
                                  np.full(len(t), np.nan)])
        col.add_columns("gps", "GPS", order[primary], t[primary], values[primary])
    elif name == "BARO":
        values = np.column_stack([r["Press"], r["Alt"]])
        col.add_columns("baro", "BARO", order[primary], t[primary], values[primary])
    elif name == "ATT":
        values = np.column_stack([r["Roll"], r["Pitch"], r["Yaw"]]) * DEG
        col.add_columns("att_euler", "ATT", order, t, values)
    elif name == "SIM":
        if "Q1" in r:
            col.add_columns("truth_quat", "SIM", order, t, np.column_stack([r[c] for c in ("Q1", "Q2", "Q3", "Q4")]))
        else:
            col.add_columns("truth_euler", "SIM", order, t,
                            np.column_stack([r["Roll"], r["Pitch"], r["Yaw"]]) * DEG)


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


def _read_with_pymavlink(path: str, progress, why: str) -> Decoded:
    """The fallback: pymavlink, message by message (slower; stops at an unknown type)."""
    from pymavlink import DFReader

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
        try:
            _add_message(col, msg, params, texts)
        except (AttributeError, IndexError, TypeError, ValueError) as exc:  # a damaged format
            raise InputError(path, f"corrupt {msg.get_type()} record near byte {log.offset} ({exc})")
        n += 1
        if progress is not None and n % 20000 == 0:
            progress(log.offset / size)
    counts = {log.formats[i].name: c for i, c in enumerate(log.counts)
              if c and i in log.formats and log.formats[i].name != "FMT"}
    return Decoded(col, params, texts, counts, notes=[why])


def _add_message(col: Collector, msg, params: dict, texts: list) -> None:
    """One pymavlink message into the collector (the fallback's ``_collect``)."""
    name = msg.get_type()
    fields = msg._fieldnames
    if name == "PARM":
        params[msg.Name] = float(msg.Value)
        return
    if name in ("MSG", "VER"):
        texts.append(msg.Message if name == "MSG" else getattr(msg, "FWS", ""))
        return
    if name == "GPS" and "T" in fields and "TimeUS" not in fields:
        t = msg.T * 1e-3
    else:
        t = _time_s(msg, fields)
    if t is None:
        return
    if name.startswith("IMU"):
        col.add("imu", f"IMU[{_instance(msg, name)}]", t,
                (msg.GyrX, msg.GyrY, msg.GyrZ, msg.AccX, msg.AccY, msg.AccZ))
    elif name.startswith("MAG"):
        col.add("mag", f"MAG[{_instance(msg, name)}]", t,
                (msg.MagX * MILLIGAUSS_TO_TESLA, msg.MagY * MILLIGAUSS_TO_TESLA, msg.MagZ * MILLIGAUSS_TO_TESLA))
    elif name == "GPS" and _instance(msg, name) == 0:
        course = msg.GCrs * DEG
        col.add("gps", "GPS", t, (msg.Lat, msg.Lng, msg.Alt, msg.Spd * math.cos(course),
                                  msg.Spd * math.sin(course), msg.VZ, msg.Status, msg.NSats, math.nan))
    elif name == "BARO" and _instance(msg, name) == 0:
        col.add("baro", "BARO", t, (msg.Press, msg.Alt))
    elif name == "ATT":
        col.add("att_euler", "ATT", t, (msg.Roll * DEG, msg.Pitch * DEG, msg.Yaw * DEG))
    elif name == "SIM":
        if "Q1" in fields:
            col.add("truth_quat", "SIM", t, (msg.Q1, msg.Q2, msg.Q3, msg.Q4))
        else:
            col.add("truth_euler", "SIM", t, (msg.Roll * DEG, msg.Pitch * DEG, msg.Yaw * DEG))
