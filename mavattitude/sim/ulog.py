"""PX4 ULog (.ulg) writer: a simulated flight as the topics PX4 logs, so tests have ULog with
known truth.

A ULog file (https://docs.px4.io/main/en/dev_log/ulog_file_format.html) is a 16-byte header
('ULog', magic, version, start time in µs) and messages, each a 3-byte header (payload size,
type) and its payload: flag bits ('B'), a format per topic ('F': "name:type field;..."),
information ('I': firmware, board), parameters ('P'), then a subscription per topic ('A':
instance, id, name) and the data ('D': id and the fields packed as the format says), in time
order. pyulog reads what this writes (tested). What is written:

- sensor_combined (IMU 0, at the IMU rate): gyro_rad (rad/s), accelerometer_m_s2 (m/s²);
- vehicle_magnetometer (the compass, calibrated: magnetometer_ga, gauss);
- vehicle_gps_position (latitude_deg, longitude_deg, altitude_msl_m, vel_n/e/d_m_s, eph, epv);
- vehicle_air_data (baro_pressure_pa, baro_alt_meter);
- vehicle_attitude (the autopilot's estimate) and vehicle_attitude_groundtruth (truth), q
  [w, x, y, z] body FRD -> NED, at the .bin's ATT rate;
- vehicle_status (nav_state, arming_state) at 1 Hz and at each change of the flight's ``script``,
  and its text lines as logged messages ('L', level '6' info);
- parameters EKF2_MAG_DECL (degrees) and MAV_TYPE (2, quadrotor); the firmware text as
  information ``ver_sw_branch``;
- with a second attitude (``SimFlight.ekf_q``): vehicle_attitude is the Q complementary filter's
  (PX4's DCM), EKF2's goes to estimator_attitude (instance 0), and ATT_EN and EKF2_EN are 1.
"""
from __future__ import annotations

import math
import struct
from pathlib import Path

import numpy as np

HEADER = b"ULog\x01\x12\x35" + bytes([1])  # magic, then file format version 1
US_PER_S = 1e6
TESLA_TO_GAUSS = 1e4

# topic -> its fields: (ULog type, numpy type, count, name); timestamp first, as PX4 has it
TOPICS = {
    "sensor_combined": [("uint64_t", "<u8", 1, "timestamp"), ("float", "<f4", 3, "gyro_rad"),
                        ("uint32_t", "<u4", 1, "gyro_integral_dt"),
                        ("int32_t", "<i4", 1, "accelerometer_timestamp_relative"),
                        ("float", "<f4", 3, "accelerometer_m_s2"), ("uint32_t", "<u4", 1, "accelerometer_integral_dt")],
    "vehicle_magnetometer": [("uint64_t", "<u8", 1, "timestamp"), ("uint64_t", "<u8", 1, "timestamp_sample"),
                             ("float", "<f4", 3, "magnetometer_ga")],
    "vehicle_gps_position": [("uint64_t", "<u8", 1, "timestamp"), ("uint64_t", "<u8", 1, "timestamp_sample"),
                             ("double", "<f8", 1, "latitude_deg"), ("double", "<f8", 1, "longitude_deg"),
                             ("double", "<f8", 1, "altitude_msl_m"), ("float", "<f4", 1, "vel_n_m_s"),
                             ("float", "<f4", 1, "vel_e_m_s"), ("float", "<f4", 1, "vel_d_m_s"),
                             ("float", "<f4", 1, "eph"), ("float", "<f4", 1, "epv"), ("uint8_t", "u1", 1, "fix_type"),
                             ("bool", "u1", 1, "vel_ned_valid"), ("uint8_t", "u1", 1, "satellites_used")],
    "vehicle_air_data": [("uint64_t", "<u8", 1, "timestamp"), ("uint64_t", "<u8", 1, "timestamp_sample"),
                         ("float", "<f4", 1, "baro_alt_meter"), ("float", "<f4", 1, "baro_pressure_pa")],
    "vehicle_attitude": [("uint64_t", "<u8", 1, "timestamp"), ("uint64_t", "<u8", 1, "timestamp_sample"),
                         ("float", "<f4", 4, "q")],
}
TOPICS["vehicle_attitude_groundtruth"] = TOPICS["estimator_attitude"] = TOPICS["vehicle_attitude"]
TOPICS["vehicle_status"] = [("uint64_t", "<u8", 1, "timestamp"), ("uint8_t", "u1", 1, "nav_state"),
                            ("uint8_t", "u1", 1, "arming_state")]
PX4_STANDBY, PX4_ARMED = 1, 2  # vehicle_status.arming_state


def write_ulog(sim, path) -> None:
    """Write ``sim`` (a SimFlight) as a PX4 ULog at ``path``."""
    columns = _topic_columns(sim)
    definitions = [_message(b"B", bytes(16) + bytes(24))]  # no flags; no appended data
    for name in columns:
        fields = TOPICS[name]
        text = name + ":" + "".join(f"{u}{f'[{n}]' if n > 1 else ''} {field};" for u, _, n, field in fields)
        definitions.append(_message(b"F", text.encode()))
    definitions.append(_info("ver_sw_branch", sim.firmware))
    definitions.append(_info("sys_name", "PX4"))
    definitions.append(_info("ver_hw", "MAVATTITUDE_SIM"))
    definitions.append(_message(b"P", _key("float EKF2_MAG_DECL") + struct.pack("<f", math.degrees(sim.declination_rad))))
    definitions.append(_message(b"P", _key("int32_t MAV_TYPE") + struct.pack("<i", 2)))
    if sim.ekf_q is not None:  # the Q estimator and EKF2 both on: Q published vehicle_attitude first
        definitions += [_message(b"P", _key(f"int32_t {name}") + struct.pack("<i", 1))
                        for name in ("ATT_EN", "EKF2_EN")]
    topics = []
    for msg_id, (name, values) in enumerate(columns.items()):
        definitions.append(_message(b"A", struct.pack("<BH", 0, msg_id) + name.encode()))
        topics.append(_packed(msg_id, TOPICS[name], values))
    topics += [_logged(text, us) for us, text in zip(np.rint(np.array([t for t, _ in sim.script.messages])
                                                             * US_PER_S).astype(np.uint64).tolist(),
                                                     [text for _, text in sim.script.messages])]
    stamps = np.concatenate([rows["timestamp"] for rows in topics])
    with open(Path(path), "wb") as f:
        f.write(HEADER + struct.pack("<Q", int(stamps.min())))
        f.write(b"".join(definitions))
        f.write(_in_time_order(topics, stamps).tobytes())


def _topic_columns(sim) -> dict[str, dict[str, np.ndarray]]:
    """Each topic's fields as arrays, in PX4's units."""
    def us(t):
        return np.rint(np.asarray(t) * US_PER_S).astype(np.uint64)

    imu = sim.imu[0]
    every = sim.rates.att_every
    gps, baro, mag = sim.gps, sim.baro, sim.mag
    dt_us = np.full(len(imu.t), int(round(US_PER_S / sim.rates.imu)), np.uint32)
    attitude_t = us(sim.truth.t[::every])
    topics = {
        "sensor_combined": {"timestamp": us(imu.t), "gyro_rad": imu.gyro, "gyro_integral_dt": dt_us,
                            "accelerometer_timestamp_relative": np.zeros(len(imu.t), np.int32),
                            "accelerometer_m_s2": imu.accel, "accelerometer_integral_dt": dt_us},
        "vehicle_magnetometer": {"timestamp": us(mag.t), "timestamp_sample": us(mag.t),
                                 "magnetometer_ga": mag.field * TESLA_TO_GAUSS},
        "vehicle_gps_position": {"timestamp": us(gps.t), "timestamp_sample": us(gps.t), "latitude_deg": gps.lat_deg,
                                 "longitude_deg": gps.lon_deg, "altitude_msl_m": gps.alt_m,
                                 "vel_n_m_s": gps.vel_ned[:, 0], "vel_e_m_s": gps.vel_ned[:, 1],
                                 "vel_d_m_s": gps.vel_ned[:, 2], "eph": np.full(len(gps.t), gps.h_acc_m),
                                 "epv": np.full(len(gps.t), gps.v_acc_m), "fix_type": np.full(len(gps.t), gps.fix_type),
                                 "vel_ned_valid": np.ones(len(gps.t)), "satellites_used": np.full(len(gps.t), gps.num_sats)},
        "vehicle_air_data": {"timestamp": us(baro.t), "timestamp_sample": us(baro.t), "baro_alt_meter": baro.alt_m,
                             "baro_pressure_pa": baro.pressure_pa},
        "vehicle_attitude": {"timestamp": attitude_t, "timestamp_sample": attitude_t, "q": sim.autopilot_q[::every]},
        "vehicle_attitude_groundtruth": {"timestamp": attitude_t, "timestamp_sample": attitude_t,
                                         "q": sim.truth.q[::every]},
    }
    topics["vehicle_status"] = _status(sim, us)
    if sim.ekf_q is not None:
        topics["estimator_attitude"] = {"timestamp": attitude_t, "timestamp_sample": attitude_t,
                                        "q": sim.ekf_q[::every]}
    return topics


def _status(sim, us) -> dict[str, np.ndarray]:
    """vehicle_status at 1 Hz and at each change of the script: its nav_state and arming_state."""
    script = sim.script
    changes = [m[0] for m in script.modes] + ([script.armed_at] if script.armed_at is not None else [])
    t = np.unique(np.concatenate([np.arange(sim.t[0], sim.t[-1], 1.0), changes]))
    starts = np.array([m[0] for m in script.modes])
    nav = np.array([m[2] for m in script.modes])[np.maximum(np.searchsorted(starts, t, side="right") - 1, 0)]
    armed = t >= (np.inf if script.armed_at is None else script.armed_at)
    return {"timestamp": us(t), "nav_state": nav, "arming_state": np.where(armed, PX4_ARMED, PX4_STANDBY)}


def _logged(text: str, t_us: int) -> np.ndarray:
    """A logged message ('L': level '6' info, timestamp, the text) as a one-row array."""
    data = text.encode()
    dtype = np.dtype([("size", "<u2"), ("type", "u1"), ("log_level", "u1"), ("timestamp", "<u8"),
                      ("message", f"S{len(data)}")])
    row = np.zeros(1, dtype)
    row["size"], row["type"], row["log_level"], row["timestamp"], row["message"] = \
        dtype.itemsize - 3, ord("L"), ord("6"), t_us, data
    return row


def _packed(msg_id: int, fields, values: dict) -> np.ndarray:
    """The topic's 'D' messages as one structured array (header, id, fields; packed)."""
    dtype = np.dtype([("size", "<u2"), ("type", "u1"), ("msg_id", "<u2")]
                     + [(field, np_type, (n,)) if n > 1 else (field, np_type) for _, np_type, n, field in fields])
    rows = np.zeros(len(values["timestamp"]), dtype)
    rows["size"], rows["type"], rows["msg_id"] = dtype.itemsize - 3, ord("D"), msg_id
    for _, _, _, field in fields:
        rows[field] = values[field]
    return rows


def _in_time_order(topics: list[np.ndarray], stamps: np.ndarray) -> np.ndarray:
    """Every topic's 'D' messages as one byte array, in time order (a topic's own order kept
    among equal times): each message's bytes placed at its offset in that order."""
    sizes = np.concatenate([np.full(len(rows), rows.dtype.itemsize) for rows in topics])
    order = np.argsort(stamps, kind="stable")
    offsets = np.empty(len(order), np.int64)
    offsets[order] = np.concatenate([[0], np.cumsum(sizes[order])[:-1]])
    out = np.empty(int(sizes.sum()), np.uint8)
    first = 0
    for rows in topics:
        mine = offsets[first:first + len(rows)]
        out[mine[:, None] + np.arange(rows.dtype.itemsize)] = rows.view(np.uint8).reshape(len(rows), -1)
        first += len(rows)
    return out


def _message(kind: bytes, payload: bytes) -> bytes:
    return struct.pack("<HB", len(payload), kind[0]) + payload


def _key(text: str) -> bytes:
    return bytes([len(text)]) + text.encode()


def _info(name: str, value: str) -> bytes:
    data = value.encode()
    return _message(b"I", _key(f"char[{len(data)}] {name}") + data)
