"""ArduPilot DataFlash logs (.bin): decoded in bulk by type (``dfrecords``), kept as columns.

A record of a wanted type that cannot be decoded by ``dfrecords`` (a format it cannot lay
out) sends the whole log to pymavlink instead, with a note; damage (bytes that are no valid
record) is skipped and counted, and the notes say how much and where.

Units as logged (pymavlink applies the format-character scaling, e.g. 'c' centidegrees ->
degrees, 'L' 1e-7 degrees -> degrees, but not the FMTU multipliers):

| message | fields used | unit in the log |
|---|---|---|
| IMU, IMU2, IMU3 (old) / IMU with I (new) | GyrX..Z, AccX..Z | rad/s, m/s² |
| GYR, ACC (sensor rate, INS_RAW_LOG_OPT / fast sampling) | SampleUS, GyrX..Z / AccX..Z | µs, rad/s / m/s² |
| IMT, IMT2, IMT3 / IMT with I (delta angles and velocities) | DelaT, DelvT, DelAX..Z, DelVX..Z | s, rad, m/s |
| MAG, MAG2, MAG3 / MAG with I | MagX..Z | milligauss (FMTU says 1e-3 G; not applied) |
| GPS / GPS with I | Lat, Lng, Alt, Spd, GCrs, VZ, Status, NSats; GWk, GMS (old: Week, TimeMS) | deg, deg, m AMSL, m/s, deg, m/s down; GPS week, ms of week (the log's date) |
| BARO | Press, Alt | Pa, m |
| ATT | Roll, Pitch, Yaw (+ AEKF, 4.1+: the estimator in use) | degrees, yaw 0-360 |
| AHR2, EKF1, NKF1/XKF1 (with C: per core), NKF6/XKF6 (old logs: core 1), DCM | Roll, Pitch, Yaw | degrees |
| SIM | Roll, Pitch, Yaw (+ Q1..Q4 when present) | degrees; quaternion |
| PARM | Name, Value | as the parameter |
| MODE, EV, ARM, ERR, MSG (``logevents``) | Mode (ModeNum); Id; ArmState; Subsys, ECode; Message | mode number, event id, text |

Time: ``TimeUS`` (µs since boot) or, in old logs, ``TimeMS`` (ms); old logs' MODE, EV, ERR and
MSG have no time: they take the last sample's before them (``Collector.add_events``). Old GPS messages carry
GPS time-of-week in ``TimeMS`` and the boot time in ``T`` (ms): we use ``T``. GYR and ACC carry
the sensor's own sample time in ``SampleUS``: we use it.

The three IMU families (``--imu-source``): ``IMU[i]``, the filtered samples of the main loop
(25-400 Hz); ``GYR[i]``, the sensor-rate samples (1-8 kHz, GYR with ACC interpolated onto its
times, ``series.sensor_rate_imu``); ``IMT[i]``, delta angles and velocities over each main-loop
step, as rates (delta / its interval), so an estimator integrating rate × dt integrates the
deltas. The batch sampler's ISBH/ISBD are not read: they are bursts of one sensor at a time,
with gaps between them, for vibration spectra, and cannot carry an attitude.
"""
from __future__ import annotations

import math
import os

import numpy as np

from ..errors import InputError, reraise_interrupt
from .collect import Collector, Decoded, first_utc, gps_to_unix
from .dfrecords import decode, open_log, release_pages, scan_log
from .logevents import ARMED_EVENTS, BUILD_TYPES, ERROR, INFO, err_text

MILLIGAUSS_TO_TESLA = 1e-7  # 1 mG = 1e-3 G = 1e-7 T
DEG = math.pi / 180.0
TEXT_TYPES = ("PARM", "MSG", "VER")  # parameters and who wrote the log, not samples
EVENT_TYPES = ("MODE", "EV", "ARM", "ERR", "MSG")  # what the log says happened (``logevents``)
MAX_INSTANCE = 9  # sensor instances ArduPilot numbers (0-based); beyond: a corrupt record
PART_ROWS = 1 << 18  # a sensor's records decoded this many at a time

# The sensor messages kept per instance: the collector's kind and the columns of their values
# (IMT: delta angles and velocities, made rates in ``_sensor_values``).
SENSORS = {
    "IMU": ("imu", ("GyrX", "GyrY", "GyrZ", "AccX", "AccY", "AccZ")),
    "IMT": ("imu", ("DelAX", "DelAY", "DelAZ", "DelVX", "DelVY", "DelVZ")),
    "GYR": ("gyr", ("GyrX", "GyrY", "GyrZ")),
    "ACC": ("acc", ("AccX", "AccY", "AccZ")),
    "MAG": ("mag", ("MagX", "MagY", "MagZ")),
}
# The autopilot's attitude streams beside ATT (``readers.attitudes`` names them): the secondary
# (AHR2), the old EKF (EKF1), EKF2 and EKF3 per core, and DCM (4.5+). Old EKF2/EKF3 logs write
# their second core as NKF6/XKF6; newer ones a core field C in NKF1/XKF1.
ATTITUDE_STREAMS = ("AHR2", "EKF1", "NKF1", "NKF6", "XKF1", "XKF6", "DCM")
SECOND_CORE = {"NKF6": "NKF1", "XKF6": "XKF1"}
WANTED = ["IMU", "IMU2", "IMU3", "GYR", "ACC", "IMT", "IMT2", "IMT3", "MAG", "MAG2", "MAG3", "GPS", "BARO",
          "ATT", "SIM", "PARM", "MSG", "VER", "MODE", "EV", "ARM", "ERR", *ATTITUDE_STREAMS]


def read_dataflash(path: str, progress=None) -> Decoded:
    """Decode a .bin. ``progress(fraction)`` is called as it goes."""
    try:
        data = open_log(path)
        scan = scan_log(data, WANTED)
        release_pages(data)  # the scan read every page; a type's records are gathered from a few
    except Exception as exc:  # not expected: pymavlink may still make something of it
        reraise_interrupt(exc)  # but a Ctrl-C in the compiled scan is no reason to read on
        return _read_with_pymavlink(path, progress, f"read with pymavlink ({type(exc).__name__}: {exc})")
    if progress is not None:
        progress(0.5)
    warnings = damage_notes(scan, len(data))

    def records():
        # one message type at a time, a sensor's in parts (its columns went up to 650 MB for an
        # hour of two IMUs at 400 Hz); each part let go once collected. The texts and events come
        # first (they make no series), and as a type read in parts goes, the mapped pages before
        # its next part are let go where no type left reads them (an hour's 166 MB were all held
        # until the end). Not every page after each part: a type's records lie on nearly every
        # page, and faulting them all in again for each part made the read 40 % slower. (All the
        # types read in parts last made a 78 MB log's read 9 % slower: not done.)
        in_parts = [name for name in scan.offsets if name.rstrip("23") in SENSORS and not scan.has_text(name)]
        names = sorted(scan.offsets, key=lambda name: name not in (*TEXT_TYPES, *EVENT_TYPES))  # (stable)
        for k, name in enumerate(names):
            offsets = scan.offsets[name]
            step = PART_ROWS if name in in_parts else len(offsets)
            later = min((int(scan.offsets[n][0]) for n in names[k + 1:] if len(scan.offsets[n])), default=len(data))
            for a in range(0, len(offsets), max(step, 1)):
                if name in in_parts:
                    release_pages(data, min(int(offsets[a]), later))
                try:
                    yield name, decode(data, scan, name, slice(a, a + step)), slice(a, a + step)
                except ValueError as exc:  # a format the firmware or damage got wrong (then in the first part)
                    warnings.append(f"{name}: {exc} (a corrupt FMT record?): {len(offsets)} records skipped")
                    break
        release_pages(data)
    return _decoded(records(), scan.offsets, dict(scan.counts), warnings=warnings)


def _decoded(records, order: dict, counts: dict, **notes) -> Decoded:
    """Each message type's columns into the collector, parameters and texts. ``records``:
    (name, columns, rows) triples, a type's parts one after the other (``rows``: the part's
    slice of ``order[name]``, the places of the type's records in the file)."""
    col = Collector()
    texts = {}
    utc_s = None
    failed = set()
    current, known = None, 0
    for name, r, rows in records:
        if name in failed:
            continue
        if name != current:  # a type's first part: the series it adds are new from here
            current, known = name, col.series_count
        if name in EVENT_TYPES:
            try:
                _collect_events(col, name, r, order[name][rows])
            except (KeyError, TypeError, ValueError) as exc:  # damage, as below: said, the rest read
                notes.setdefault("warnings", []).append(f"{name}: its columns do not fit ({exc}): "
                                                        f"{len(order[name])} records skipped")
        if name in TEXT_TYPES:
            texts[name] = r
            continue
        if name in EVENT_TYPES:
            continue
        if name == "GPS" and utc_s is None:
            utc_s = _gps_utc(r)
        try:
            # a type read in parts fills its series in place; read whole, each is a view of its columns
            whole = len(range(*rows.indices(len(order[name])))) == len(order[name])
            _collect(col, name, r, order[name][rows], 0 if whole else len(order[name]))
        except (KeyError, TypeError, ValueError) as exc:  # a column missing or of another type: damage
            what = f"its format has no column {exc}" if isinstance(exc, KeyError) else f"its columns do not fit ({exc})"
            notes.setdefault("warnings", []).append(f"{name}: {what} (a corrupt FMT record?): "
                                                    f"{len(order[name])} records skipped")
            failed.add(name)
        col.sort_new_series(known)  # a type's instances in their order, whichever part met them first
    parm, msg, ver = (texts.get(name, {}) for name in TEXT_TYPES)
    params = {name: float(value) for name, value in zip(parm.get("Name", []), parm.get("Value", []))}
    texts = list(msg.get("Message", [])) + list(ver.get("FWS", []))
    build = BUILD_TYPES.get(int(ver["BU"][0])) if "BU" in ver and len(ver["BU"]) else None
    return Decoded(col, params, texts, counts, utc_s=utc_s, build=build, **notes)


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
    if scan.recovered_formats:
        notes.append(f"repaired {len(scan.recovered_formats)} damaged message format definition(s) (FMT), "
                     f"a flipped bit in each: {', '.join(scan.recovered_formats)}; their records line up "
                     "with the repairs")
    return notes


def _collect(col: Collector, name: str, r: dict, order: np.ndarray, records: int = 0) -> None:
    """One message type's columns into the collector, in SI units (see the table above).
    ``records``: how many the type has in all, when ``r`` is a part of them: room for a
    sensor's series, filled in place (``Collector.add_columns``)."""
    if name == "GPS" and "T" in r and "TimeUS" not in r:
        t = r["T"] * 1e-3  # old GPS: TimeMS is GPS time of week, T is the boot clock
    elif "SampleUS" in r:
        t = r["SampleUS"] * 1e-6  # the sensor's sample time (TimeUS: when it was logged)
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
    prefix = name.rstrip("23")  # IMU2 and MAG3 of old logs: IMU and MAG
    if prefix in SENSORS:
        kind, _ = SENSORS[prefix]
        values = _sensor_values(prefix, r)
        # which instances there are, by counting: 0-9, and one slot past them for the implausible
        slot = np.where(plausible, instance, MAX_INSTANCE + 1).astype(np.uint8)
        per_instance = np.bincount(slot, minlength=MAX_INSTANCE + 2)[:MAX_INSTANCE + 1]
        if per_instance.max(initial=0) < len(t):  # several (or implausible): each instance's records together
            by_instance = np.argsort(slot, kind="stable")  # (a radix sort, on one byte)
            order, t, values = order[by_instance], t[by_instance], values[by_instance]
        end = np.cumsum(per_instance)
        for i in np.flatnonzero(per_instance):
            mine = slice(end[i] - per_instance[i], end[i])
            col.add_columns(kind, f"{prefix}[{i}]", order[mine], t[mine], values[mine], capacity=records)
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
        if "AEKF" in r:
            values = np.column_stack([values, r["AEKF"]])
        col.add_columns("att_euler", "ATT", order, t, values)
    elif name in ATTITUDE_STREAMS and "Roll" in r:  # (an EKF3 XKF6 of another layout has none)
        values = np.column_stack([r["Roll"], r["Pitch"], r["Yaw"]]) * DEG
        if "C" in r:  # one message for every core
            for core in np.unique(r["C"][r["C"] <= MAX_INSTANCE]):
                mine = r["C"] == core
                col.add_columns("stream_euler", f"{name}[{core}]", order[mine], t[mine], values[mine])
        elif name in SECOND_CORE:
            col.add_columns("stream_euler", f"{SECOND_CORE[name]}[1]", order, t, values)
        elif name in SECOND_CORE.values():
            col.add_columns("stream_euler", f"{name}[0]", order, t, values)
        else:
            col.add_columns("stream_euler", name, order, t, values)
    elif name == "SIM":
        if "Q1" in r:
            col.add_columns("truth_quat", "SIM", order, t, np.column_stack([r[c] for c in ("Q1", "Q2", "Q3", "Q4")]))
        else:
            col.add_columns("truth_euler", "SIM", order, t,
                            np.column_stack([r["Roll"], r["Pitch"], r["Yaw"]]) * DEG)


def _collect_events(col: Collector, name: str, r: dict, order: np.ndarray) -> None:
    """MODE, EV, ARM, ERR, MSG into the collector's event rows (``logevents``); NaN times where
    the records have none (old logs)."""
    t = r["TimeUS"] * 1e-6 if "TimeUS" in r else r["TimeMS"] * 1e-3 if "TimeMS" in r else np.full(len(order), np.nan)
    if name == "MODE":
        mode = r["ModeNum"] if "ModeNum" in r else r["Mode"]
        if mode.dtype.kind in "OSU":  # a name rather than a number
            col.add_events("mode", name, order, t, np.full(len(order), -1), [str(m) for m in mode])
        else:
            col.add_events("mode", name, order, t, mode)
    elif name == "EV":
        ids = np.asarray(r["Id"], np.int64)
        arm = np.isin(ids, list(ARMED_EVENTS))
        col.add_events("armed", name, order[arm], t[arm], [ARMED_EVENTS[i] for i in ids[arm].tolist()])
    elif name == "ARM":
        col.add_events("armed", name, order, t, np.asarray(r["ArmState"], np.int64) != 0)
    elif name == "ERR":
        col.add_events("text", name, order, t, np.full(len(order), ERROR),
                       [err_text(s, c) for s, c in zip(r["Subsys"].tolist(), r["ECode"].tolist())])
    elif name == "MSG":
        col.add_events("text", name, order, t, np.full(len(order), INFO), [str(m) for m in r["Message"]])


def _gps_utc(r: dict) -> float | None:
    """The first GPS time the records carry (GWk/GMS; Week/TimeMS in old logs), as UNIX s."""
    week, week_ms = ("GWk", "GMS") if "GWk" in r else ("Week", "TimeMS")
    if week not in r or week_ms not in r:
        return None
    return first_utc(gps_to_unix(r[week], r[week_ms]))


def _sensor_values(prefix: str, r: dict) -> np.ndarray:
    """The SI values of one sensor message type's records (see the table above)."""
    values = np.column_stack([r[c] for c in SENSORS[prefix][1]])
    if prefix == "MAG":
        return values * MILLIGAUSS_TO_TESLA
    if prefix == "IMT":  # delta angle and velocity over their intervals: rates
        with np.errstate(divide="ignore", invalid="ignore"):  # a zero interval: not finite, dropped later
            return values / np.column_stack([r["DelaT"]] * 3 + [r["DelvT"]] * 3)
    return values


def _read_with_pymavlink(path: str, progress, why: str) -> Decoded:
    """The fallback: pymavlink, message by message (slower; stops at an unknown type), into
    the same columns as the bulk decoder's."""
    from pymavlink import DFReader

    try:
        log = DFReader.DFReader_binary(path, zero_time_base=True)
    except Exception as exc:  # pymavlink raises bare exceptions on garbage
        raise InputError(path, f"not a readable DataFlash log ({exc.__class__.__name__}: {exc})")
    fields: dict[str, dict[str, list]] = {}
    order: dict[str, list[int]] = {}
    size = max(os.path.getsize(path), 1)
    n = 0
    while True:
        try:
            msg = log.recv_match(type=WANTED)
        except Exception as exc:
            raise InputError(path, f"corrupt DataFlash data near byte {log.offset} ({exc})")
        if msg is None:
            break
        name = msg.get_type()
        columns = fields.setdefault(name, {})
        for field in msg._fieldnames:
            columns.setdefault(field, []).append(getattr(msg, field))
        order.setdefault(name, []).append(n)
        n += 1
        if progress is not None and n % 20000 == 0:
            progress(log.offset / size)
    records = {}
    for name, columns in fields.items():
        if len({len(v) for v in columns.values()}) != 1:  # a format changed midway: damage
            raise InputError(path, f"corrupt {name} records (their fields change midway)")
        records[name] = {k: np.array(v, dtype=object if isinstance(v[0], str) else None) for k, v in columns.items()}
    counts = {log.formats[i].name: c for i, c in enumerate(log.counts)
              if c and i in log.formats and log.formats[i].name != "FMT"}
    return _decoded(((name, r, slice(None)) for name, r in records.items()),
                    {k: np.array(v) for k, v in order.items()}, counts, notes=[why])
