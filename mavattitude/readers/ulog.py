"""PX4 ULog flight logs (.ulg), decoded into columns by our bulk decoder (``ulogdata``: the
values pyulog gives, tested against it), or by pyulog (the PX4 project's reader) for what that
one does not follow (appended data, an unknown flag, a damaged format; said in a note).

Every topic is a series on PX4's clock (µs since boot; SITL may count from the Unix epoch),
taken at ``timestamp_sample`` where the topic has it set (when the sensor sampled), else at
``timestamp`` (when it was published). A sample's place among the others (``arrival``) is its
``timestamp``: the logger writes in publication order. Units as logged:

| topic | fields used | unit in the log |
|---|---|---|
| sensor_combined | gyro_rad[3], accelerometer_m_s2[3] (+ accelerometer_timestamp_relative) | rad/s, m/s², FRD |
| sensor_combined (logs before ~2018) | magnetometer_ga[3], baro_alt_meter (+ their *_timestamp_relative) | gauss; m |
| vehicle_imu (instances) | delta_angle[3], delta_velocity[3], delta_angle_dt, delta_velocity_dt | rad, m/s, µs |
| vehicle_magnetometer (instances) | magnetometer_ga[3] (calibrated, body frame) | gauss |
| vehicle_gps_position, sensor_gps | latitude_deg/longitude_deg/altitude_msl_m, or lat/lon (1e-7 °) and alt (mm); vel_n/e/d_m_s, fix_type, satellites_used, eph, epv; time_utc_usec | °, m, m/s, m; µs UNIX time (the log's date) |
| vehicle_air_data | baro_pressure_pa, baro_alt_meter | Pa, m |
| vehicle_attitude | q[4] (the estimator in use: EKF2, or the Q filter; ``readers.attitudes``) | [w, x, y, z], body FRD -> NED |
| estimator_attitude (instances: each EKF2 of a multi-EKF PX4) | q[4] | as vehicle_attitude |
| vehicle_attitude_groundtruth (SITL) | q[4] | as vehicle_attitude |
| vehicle_status (``logevents``) | nav_state, arming_state | PX4's enums: the flight mode, armed (2) |
| logged messages ('L', 'C') | log_level, timestamp, message | '0'-'7' (emergency .. debug), µs, text |

The IMU is ``sensor_combined``: PX4's selected IMU (``sensor_selection``), the one its EKF uses.
``vehicle_imu[i]`` (every IMU, as delta angles and velocities) is the ``delta`` family where the
logger kept it at a useful rate (its default profile keeps it at ~2 Hz: too slow to estimate
from). The compass is ``vehicle_magnetometer[0]``, the one PX4's sensors module selects,
calibrated and in the body frame; ``sensor_mag`` (uncalibrated, in the sensor's frame) is not
read. Parameters are kept as PX4 names them (the declination is ``EKF2_MAG_DECL``, degrees).
"""
from __future__ import annotations

import io
import mmap

import numpy as np

from ..earth import height_pressure
from ..errors import InputError
from .collect import Collector, Decoded, first_utc
from .logevents import PX4_ARMED, PX4_ARMING_STATES, PX4_NAV_STATES
from .ulogdata import Unsupported, read_topics
from .ulogrecords import frame

GAUSS_TO_TESLA = 1e-4
S_PER_US = 1e-6
RELATIVE_TIMESTAMP_INVALID = 0x7FFFFFFF  # PX4: the *_timestamp_relative of a sensor not in this sample
TOPICS = ["sensor_combined", "vehicle_imu", "vehicle_magnetometer", "vehicle_gps_position", "sensor_gps",
          "vehicle_air_data", "vehicle_attitude", "vehicle_attitude_groundtruth", "sensor_selection",
          "estimator_attitude", "vehicle_status"]


def read_ulog(path: str, progress=None) -> Decoded:
    """Decode a .ulg (the topics of ``TOPICS``); InputError for a file that cannot be read.
    Damage is cut out first (``ulogrecords``), and said in the warnings. Our bulk decoder
    (``ulogdata``) reads it; pyulog where that one cannot (said in a note)."""
    data = _mapped(path)
    framing = frame(data)
    warnings = framing.notes()
    fallback = None
    try:
        ulog = read_topics(data, framing, TOPICS)
    except Unsupported as exc:
        fallback = f"read by pyulog ({exc})"
        ulog = _read_pyulog(path, data, framing)
    if progress is not None:
        progress(0.5)
    col = Collector()
    counts: dict[str, int] = {}
    notes: list[str] = [fallback] if fallback else []
    if ulog.file_corruption and not framing.damage:
        warnings.append("the file is damaged (pyulog found corrupt data and skipped to the next valid message)")
    if ulog.dropouts:
        lost_ms = sum(d.duration for d in ulog.dropouts)
        warnings.append(f"the logger dropped data {len(ulog.dropouts)} times ({lost_ms} ms in all)")
    for d in ulog.data_list:
        if d.name == "sensor_selection":
            continue
        key = d.name if d.name in ("sensor_combined", "vehicle_attitude", "vehicle_attitude_groundtruth") \
            else f"{d.name}[{d.multi_id}]"
        if "timestamp" not in d.data:  # a damaged format definition: its samples cannot be placed in time
            warnings.append(f"{key}: not read, its format has no timestamp field (damaged)")
            continue
        counts[key] = len(d.data["timestamp"])
        if not counts[key]:
            continue
        try:
            _add_topic(col, d.name, key, d.data, notes)
        except KeyError as exc:  # a PX4 version that names a field otherwise
            warnings.append(f"{key}: not read, it has no field {exc.args[0]!r} (a PX4 version not known here)")
    # (pyulog keeps the tagged lines apart; our decoder lists them with the others)
    tagged = getattr(ulog, "logged_messages_tagged", {})
    _add_logged_messages(col, ulog.logged_messages + [m for lines in tagged.values() for m in lines])
    selected = _selected_imu(ulog.data_list)
    if selected:
        notes.append(f"{selected} is the IMU PX4 selected (sensor_selection); sensor_combined carries its samples")
    params = {k: float(v) for k, v in ulog.initial_parameters.items() if isinstance(v, (int, float))}
    if not isinstance(ulog.msg_info_dict.get("ver_sw_release", 0), int):
        warnings.append("the ULog header is damaged: the firmware version (ver_sw_release) is not a number; "
                        "left out")
    utc = [first_utc(d.data["time_utc_usec"] * 1e-6) for d in ulog.data_list
           if d.name in ("vehicle_gps_position", "sensor_gps") and "time_utc_usec" in d.data]
    return Decoded(col, params, [], counts, notes=notes, warnings=warnings, identity=_identify(ulog, params),
                   utc_s=min((u for u in utc if u is not None), default=None))


def _mapped(path: str) -> bytes | mmap.mmap:
    """The file's bytes, memory-mapped (a read would copy them first: a third of the decode's time)."""
    with open(path, "rb") as f:
        try:
            return mmap.mmap(f.fileno(), 0, access=mmap.ACCESS_READ)
        except ValueError:  # an empty file cannot be mapped
            return b""


def _read_pyulog(path: str, data: bytes, framing):
    """pyulog's read of the file (its damage cut out)."""
    from pyulog import ULog

    source = io.BytesIO(framing.repaired(data)) if framing.damage or framing.header else path
    try:
        ulog = ULog(source, message_name_filter_list=TOPICS, disable_str_exceptions=True)
    except Exception as exc:  # noqa: BLE001 - pyulog raises what it meets (struct.error, ValueError, ...)
        raise InputError(path, f"not a readable ULog (header damaged: {type(exc).__name__}: {exc})") from None
    return ulog


def _add_topic(col: Collector, name: str, key: str, data: dict, notes: list[str]) -> None:
    # Damaged data decodes as anything: a flipped bit can make a signalling NaN (numpy warns as
    # it converts one) or a height above the standard atmosphere; such rows are NaN, then dropped
    # as not finite (series.fill_series).
    with np.errstate(invalid="ignore"):
        order = data["timestamp"].astype(np.int64)
        sampled = data.get("timestamp_sample")  # 0 where a driver left it unset (GPS)
        t = (order if sampled is None else np.where(sampled > 0, sampled, order).astype(np.float64)) * S_PER_US

        def vector(*fields, n=3):
            """The fields' elements side by side, as float64 (one array filled: an hour at 400 Hz
            is 1.4 M rows); an array field at a time where its elements lie side by side."""
            rows = np.empty((len(order), n * len(fields)))
            for i, field in enumerate(fields):
                rows[:, i * n:(i + 1) * n] = _side_by_side([data[f"{field}[{k}]"] for k in range(n)])
            return rows

        if name == "sensor_combined":
            accel_ok = data.get("accelerometer_timestamp_relative", order * 0) != RELATIVE_TIMESTAMP_INVALID
            rows = vector("gyro_rad", "accelerometer_m_s2")
            if accel_ok.all():  # nearly always: no copies
                col.add_columns("imu", key, order, t, rows)
            else:
                col.add_columns("imu", key, order[accel_ok], t[accel_ok], rows[accel_ok])
            if "magnetometer_ga[0]" in data:  # old logs: the compass in the same topic, repeated
                _add_relative(col, "mag", key, data, "magnetometer", order, vector("magnetometer_ga") * GAUSS_TO_TESLA)
            if "baro_alt_meter" in data:
                # old logs give only the height PX4 computed from pressure in the standard atmosphere
                # (QNH 1013.25 hPa): that pressure back, for the phase that differences it
                height = data["baro_alt_meter"].astype(np.float64)
                pressure = height_pressure(height)  # NaN above the model's top (a corrupt height)
                if _add_relative(col, "baro", key, data, "baro", order, np.column_stack([pressure, height])):
                    notes.append("baro pressure from sensor_combined.baro_alt_meter (standard atmosphere)")
        elif name == "vehicle_imu":
            angle_dt = data["delta_angle_dt"].astype(np.float64) * S_PER_US
            velocity_dt = data["delta_velocity_dt"].astype(np.float64) * S_PER_US
            ok = (angle_dt > 0) & (velocity_dt > 0)
            with np.errstate(divide="ignore"):  # as rates over their intervals, as IMT
                rows = np.hstack([vector("delta_angle") / angle_dt[:, None],
                                  vector("delta_velocity") / velocity_dt[:, None]])
            col.add_columns("imu", key, order[ok], t[ok], rows[ok])
        elif name == "vehicle_magnetometer":
            col.add_columns("mag", key, order, t, vector("magnetometer_ga") * GAUSS_TO_TESLA)
        elif name in ("vehicle_gps_position", "sensor_gps"):
            col.add_columns("gps", key, order, t, _gps_rows(data))
        elif name == "vehicle_air_data":
            col.add_columns("baro", key, order, t, np.column_stack([data["baro_pressure_pa"], data["baro_alt_meter"]]))
        elif name == "vehicle_status":
            nav_state = data["nav_state"].astype(np.int64)
            col.add_events("mode", name, order, t, nav_state,
                           [PX4_NAV_STATES.get(v, f"nav_state {v}") for v in nav_state.tolist()])
            state = data["arming_state"].astype(np.int64)
            known = np.isin(state, PX4_ARMING_STATES)  # not init, reboot, in-air restore
            col.add_events("armed", name, order[known], t[known], np.isin(state[known], PX4_ARMED))
        elif name in ("vehicle_attitude", "vehicle_attitude_groundtruth", "estimator_attitude"):
            kind = {"vehicle_attitude": "att_quat", "vehicle_attitude_groundtruth": "truth_quat"}.get(name, "stream_quat")
            col.add_columns(kind, key, order, t, vector("q", n=4))


def _add_logged_messages(col: Collector, messages) -> None:
    """The logged text lines as event rows: level '0'-'7' is the MAVLink severity."""
    messages = [m for m in messages if 0 <= m.timestamp < 1 << 62]  # a damaged time: dropped (as by the clock)
    if not messages:
        return
    at = np.array([m.timestamp for m in messages], np.int64)
    level = np.array([m.log_level - ord("0") if ord("0") <= m.log_level <= ord("7") else 6 for m in messages])
    col.add_events("text", "logged_messages", at, at * S_PER_US, level, [m.message for m in messages])


def _side_by_side(columns: list[np.ndarray]) -> np.ndarray:
    """The columns as one (rows, k) array: a view where they lie side by side in one buffer
    (an array field of our decoder's rows: copied at once, 2.5x faster than column by column),
    else stacked."""
    first = columns[0]
    step = first.itemsize
    if all(c.dtype == first.dtype and c.shape == first.shape and c.strides == first.strides
           and c.__array_interface__["data"][0] == first.__array_interface__["data"][0] + k * step
           for k, c in enumerate(columns)):
        return np.lib.stride_tricks.as_strided(first, (len(first), len(columns)), (first.strides[0], step),
                                               writeable=False)
    return np.column_stack(columns)


def _add_relative(col: Collector, kind: str, key: str, data: dict, sensor: str, order, rows) -> int:
    """A sensor carried in sensor_combined at its own time (``<sensor>_timestamp_relative`` after
    the row's), each sample once: the rows repeat it until the next. Returns how many."""
    relative = data.get(f"{sensor}_timestamp_relative")
    if relative is None:
        return 0
    valid = relative != RELATIVE_TIMESTAMP_INVALID
    t = (data["timestamp"].astype(np.int64) + relative.astype(np.int64)) * S_PER_US
    new = valid & np.concatenate([[True], t[1:] != t[:-1]])
    if new.any():
        col.add_columns(kind, key, order[new], t[new], rows[new])
    return int(np.count_nonzero(new))


def _selected_imu(data_list) -> str | None:
    """The ``vehicle_imu[i]`` whose gyro PX4's ``sensor_selection`` names, when there are several."""
    selection = next((d.data for d in data_list if d.name == "sensor_selection"), None)
    imus = [d for d in data_list if d.name == "vehicle_imu" and len(d.data.get("timestamp", ()))]
    if selection is None or len(imus) < 2 or "gyro_device_id" not in selection:
        return None
    wanted = selection["gyro_device_id"][-1]
    return next((f"vehicle_imu[{d.multi_id}]" for d in imus if d.data.get("gyro_device_id", [None])[0] == wanted), None)


def _gps_rows(data: dict) -> np.ndarray:
    """lat, lon (°), alt (m AMSL), vel N/E/D (m/s), fix type, satellites, horizontal accuracy (m)."""
    if "latitude_deg" in data:
        lat, lon, alt = data["latitude_deg"], data["longitude_deg"], data["altitude_msl_m"]
    else:  # before PX4 1.14: integers
        lat, lon, alt = data["lat"] * 1e-7, data["lon"] * 1e-7, data["alt"] * 1e-3  # 1e-7 °, mm
    velocity = np.column_stack([data["vel_n_m_s"], data["vel_e_m_s"], data["vel_d_m_s"]]).astype(np.float64)
    if "vel_ned_valid" in data:
        velocity[data["vel_ned_valid"] == 0] = np.nan
    return np.column_stack([lat, lon, alt, velocity, data["fix_type"], data["satellites_used"], data["eph"]])


def _identify(ulog, params: dict) -> tuple[str, str]:
    """(vehicle, firmware): MAVLink's name of the vehicle type (MAV_TYPE) and PX4's version."""
    from .sources import enum_name

    info = ulog.msg_info_dict
    vehicle = enum_name("MAV_TYPE", int(params["MAV_TYPE"])) if "MAV_TYPE" in params else "PX4"
    release = info.get("ver_sw_release")
    if not isinstance(release, int):  # a damaged header can give it another type
        release = None
    version = f"v{release >> 24}.{(release >> 16) & 0xFF}.{(release >> 8) & 0xFF}" if release else None
    git = str(info.get("ver_sw", ""))[:8] or None
    parts = ["PX4", version, f"({git})" if git else None, info.get("ver_hw")]
    return vehicle, " ".join(str(p) for p in parts if p)
