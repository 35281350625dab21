"""MAVLink telemetry log (.tlog) writer.

A tlog is a sequence of records: the UNIX time the ground station received the packet
(uint64 microseconds, big-endian), then the raw MAVLink packet. Packets are MAVLink 2, encoded by
pymavlink's generated ardupilotmega dialect, from system 1 component 1, with ArduPilot's field
scaling. Times inside messages are on the autopilot clock (time_usec / time_boot_ms since boot);
the record stamp is the fake boot epoch plus that time, so output is deterministic.

What is written, and when:

- once at the start: STATUSTEXT with the firmware string, PARAM_VALUE for COMPASS_DEC (rad) and
  COMPASS_OFS_X/Y/Z (mGauss);
- 1 Hz: HEARTBEAT (quadrotor, ArduPilot; the flight mode and arming of the flight's ``script``),
  SYSTEM_TIME; the script's text lines as STATUSTEXT, after the IMU tick at their time;
- every IMU sample: RAW_IMU (IMU 0) and SCALED_IMU2 (IMU 1): acceleration mG, rates mrad/s,
  field mGauss (the latest compass sample, as ArduPilot sends it); then ATTITUDE (the autopilot's
  estimate, rad) and SIMSTATE (truth; it has no timestamp, so it follows ATTITUDE in the same tick);
- GPS_RAW_INT at the GPS rate, SCALED_PRESSURE (hPa, cdegC) at the baro rate;
- with a DCM primary (``SimFlight.ekf_q``): ATTITUDE is DCM's, AHRS2 the EKF's (after SIMSTATE),
  and PARAM_VALUE AHRS_EKF_USE 0.
"""
from __future__ import annotations

import struct
from pathlib import Path

import numpy as np
from pymavlink.dialects.v20 import ardupilotmega as mavlink2

from .. import earth
from .. import quaternion as quat
from ..flight import GRAVITY

_STAMP = struct.Struct(">Q")
STATUSTEXT_MAX = 50  # characters in a STATUSTEXT

# Event kinds, in the order they are written when they share a timestamp.
HEARTBEAT, START, IMU_TICK, GPS, BARO, TEXT = range(6)


def _int_list(values) -> list:
    """Rounded Python ints (pymavlink packs Python numbers fastest)."""
    return np.rint(np.asarray(values, dtype=float)).astype(np.int64).tolist()


def write_tlog(sim, path) -> None:
    """Write ``sim`` (a SimFlight) as a MAVLink 2 telemetry log at ``path``."""
    mav = mavlink2.MAVLink(None, srcSystem=1, srcComponent=1)
    epoch_us = int(round(sim.epoch_unix_at_boot * 1e6))
    t_imu = sim.truth.t
    t_start, t_end = float(t_imu[0]), float(t_imu[-1])
    t_heartbeat = np.arange(t_start, t_end, 1.0)

    # Each event: (time s, kind, index into that kind's arrays); written in time order.
    streams = [(t_heartbeat, HEARTBEAT), (np.array([t_start]), START), (t_imu, IMU_TICK),
               (sim.gps.t, GPS), (sim.baro.t, BARO), (np.array([t for t, _ in sim.script.messages]), TEXT)]
    times = np.concatenate([t for t, _ in streams])
    kinds = np.concatenate([np.full(len(t), k) for t, k in streams])
    index = np.concatenate([np.arange(len(t)) for t, _ in streams])
    order = np.lexsort((kinds, times))
    stamps_us = (epoch_us + np.rint(times * 1e6).astype(np.int64))[order].tolist()

    emit = {
        HEARTBEAT: _heartbeat_packets(sim, t_heartbeat, mav, epoch_us),
        START: _start_packets(sim, mav),
        IMU_TICK: _imu_packets(sim, mav),
        GPS: _gps_packets(sim, mav),
        BARO: _baro_packets(sim, mav),
        TEXT: lambda i: [mavlink2.MAVLink_statustext_message(
            mavlink2.MAV_SEVERITY_INFO, sim.script.messages[i][1][:STATUSTEXT_MAX].encode()).pack(mav)],
    }
    with open(Path(path), "wb") as f:
        write = f.write
        for stamp, kind, i in zip(stamps_us, kinds[order].tolist(), index[order].tolist()):
            for packet in emit[kind](i):
                write(_STAMP.pack(stamp))
                write(packet)
                mav.seq = (mav.seq + 1) % 256  # pack() does not count; MAVLink.send() would


def _heartbeat_packets(sim, t_heartbeat, mav, epoch_us):
    per = heartbeat_packers(sim, t_heartbeat, mav, epoch_us)
    return lambda i: (pack(i) for pack in per.values())  # lazily: each packs with the next seq


def heartbeat_packers(sim, t_heartbeat, mav, epoch_us) -> dict:
    """{message name: packer(i) -> bytes} for the 1 Hz messages at ``t_heartbeat[i]``."""
    base = (mavlink2.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED | mavlink2.MAV_MODE_FLAG_STABILIZE_ENABLED
            | mavlink2.MAV_MODE_FLAG_MANUAL_INPUT_ENABLED)
    script = sim.script
    armed = (t_heartbeat >= (np.inf if script.armed_at is None else script.armed_at)).tolist()
    starts = np.array([m[0] for m in script.modes])
    custom = [script.modes[max(k, 0)][1] for k in (np.searchsorted(starts, t_heartbeat, side="right") - 1).tolist()]
    boot_ms = _int_list(t_heartbeat * 1e3)
    unix_us = (epoch_us + np.rint(t_heartbeat * 1e6).astype(np.int64)).tolist()

    def heartbeat(i):
        mode = base | (mavlink2.MAV_MODE_FLAG_SAFETY_ARMED if armed[i] else 0)
        state = mavlink2.MAV_STATE_ACTIVE if armed[i] else mavlink2.MAV_STATE_STANDBY
        return mavlink2.MAVLink_heartbeat_message(
            mavlink2.MAV_TYPE_QUADROTOR, mavlink2.MAV_AUTOPILOT_ARDUPILOTMEGA, mode, custom[i], state, 3).pack(mav)
    return {"HEARTBEAT": heartbeat,
            "SYSTEM_TIME": lambda i: mavlink2.MAVLink_system_time_message(unix_us[i], boot_ms[i]).pack(mav)}


def _start_packets(sim, mav):
    params = sim.log_params

    def packets(_):
        yield mavlink2.MAVLink_statustext_message(
            mavlink2.MAV_SEVERITY_INFO, sim.firmware[:STATUSTEXT_MAX].encode()).pack(mav)
        for i, (name, value) in enumerate(params.items()):
            yield mavlink2.MAVLink_param_value_message(
                name.encode(), value, mavlink2.MAV_PARAM_TYPE_REAL32, len(params), i).pack(mav)
    return packets


def _imu_packets(sim, mav):
    per = imu_packers(sim, mav)
    if sim.ekf_q is not None:  # a DCM primary: the EKF's estimate as AHRS2, after ATTITUDE and SIMSTATE
        ekf = quat.to_euler(sim.ekf_q).tolist()
        lat, lon, alt = earth.ned_to_geodetic(sim.home.origin, sim.truth.pos_ned)
        lat_e7, lon_e7, alt = _int_list(lat * 1e7), _int_list(lon * 1e7), alt.tolist()
        per["AHRS2"] = lambda i: mavlink2.MAVLink_ahrs2_message(*ekf[i], alt[i], lat_e7[i], lon_e7[i]).pack(mav)
    return lambda i: (pack(i) for pack in per.values())  # lazily: each packs with the next seq


def imu_packers(sim, mav) -> dict:
    """{message name: packer(i) -> bytes} for the messages of IMU sample ``i``, in the order
    ArduPilot sends them: RAW_IMU, SCALED_IMU2, ATTITUDE, SIMSTATE."""
    t = sim.truth.t
    time_usec = _int_list(t * 1e6)
    boot_ms = _int_list(t * 1e3)
    scaled = []  # per IMU: columns of acc mG, gyro mrad/s
    for imu in sim.imu:
        scaled.append(list(zip(*(_int_list(c) for c in np.hstack([imu.accel / GRAVITY * 1e3,
                                                                   imu.gyro * 1e3]).T))))
    temperature = [int(round(imu.temperature_c * 100)) for imu in sim.imu]
    # Compass: the latest sample at or before each IMU time (zero-order hold), mGauss.
    latest = np.clip(np.searchsorted(sim.mag.t, t + 1e-9, side="right") - 1, 0, None)
    mag = list(zip(*(_int_list(c) for c in (sim.mag.field[latest] * 1e7).T)))
    estimate = quat.to_euler(sim.autopilot_q).tolist()
    rates = sim.truth.omega_b.tolist()  # the autopilot reports bias-corrected body rates
    true = quat.to_euler(sim.truth.q).tolist()
    force = sim.truth.specific_force_b.tolist()
    lat, lon, _ = earth.ned_to_geodetic(sim.home.origin, sim.truth.pos_ned)
    lat_e7, lon_e7 = _int_list(lat * 1e7), _int_list(lon * 1e7)
    raw, second = scaled  # RAW_IMU carries IMU 0, SCALED_IMU2 IMU 1
    raw_t, second_t = temperature

    return {
        "RAW_IMU": lambda i: mavlink2.MAVLink_raw_imu_message(
            time_usec[i], *raw[i], *mag[i], 0, raw_t).pack(mav),
        "SCALED_IMU2": lambda i: mavlink2.MAVLink_scaled_imu2_message(
            boot_ms[i], *second[i], *mag[i], second_t).pack(mav),
        "ATTITUDE": lambda i: mavlink2.MAVLink_attitude_message(boot_ms[i], *estimate[i], *rates[i]).pack(mav),
        "SIMSTATE": lambda i: mavlink2.MAVLink_simstate_message(
            *true[i], *force[i], *rates[i], lat_e7[i], lon_e7[i]).pack(mav),
    }


def _gps_packets(sim, mav):
    gps = sim.gps
    v = gps.vel_ned
    time_usec = _int_list(gps.t * 1e6)
    lat, lon = _int_list(gps.lat_deg * 1e7), _int_list(gps.lon_deg * 1e7)
    alt = _int_list(gps.alt_m * 1e3)
    vel = _int_list(np.hypot(v[:, 0], v[:, 1]) * 100)
    cog = _int_list(np.rint(np.degrees(np.arctan2(v[:, 1], v[:, 0])) * 100) % 36000)
    eph, epv = int(round(gps.hdop * 100)), int(round(gps.vdop * 100))
    h_acc, v_acc = int(round(gps.h_acc_m * 1e3)), int(round(gps.v_acc_m * 1e3))
    vel_acc = int(round(gps.speed_acc_ms * 1e3))

    def packets(i):
        return (mavlink2.MAVLink_gps_raw_int_message(
            time_usec[i], gps.fix_type, lat[i], lon[i], alt[i], eph, epv, vel[i], cog[i], gps.num_sats,
            alt[i], h_acc, v_acc, vel_acc, 0, 0).pack(mav),)
    return packets


def _baro_packets(sim, mav):
    baro = sim.baro
    boot_ms = _int_list(baro.t * 1e3)
    hpa = (baro.pressure_pa / 100.0).tolist()
    temperature = int(round(baro.temperature_c * 100))

    def packets(i):
        return (mavlink2.MAVLink_scaled_pressure_message(boot_ms[i], hpa[i], 0.0, temperature, 0).pack(mav),)
    return packets
