"""A simulated autopilot on a live MAVLink link: ``mavattitude simulate --live URL``.

It sends a ``SimFlight`` as ArduPilot would, paced on the wall clock (``speed`` times real
time), with the same packets as the .tlog writer (``sim.tlog``): HEARTBEAT and SYSTEM_TIME at
1 Hz, RAW_IMU, SCALED_IMU2, ATTITUDE and SIMSTATE (truth) on the IMU ticks, GPS_RAW_INT and
SCALED_PRESSURE on their own ticks. Each message has a send interval; a message is sent on a
tick once its interval has passed since it was last due, so it never exceeds the simulated
sensor's own rate. Defaults are modest, as a vehicle's stream-rate parameters usually are
(``DEFAULT_RATES_HZ``); the listener asks for more, and this autopilot honours:

- COMMAND_LONG MAV_CMD_SET_MESSAGE_INTERVAL (param1 message id, param2 interval µs; -1 stops
  the message, 0 restores its default), answered with COMMAND_ACK;
- REQUEST_DATA_STREAM (ArduPilot's stream groups, ``STREAMS``), no answer (as ArduPilot);
- MAV_CMD_REQUEST_MESSAGE for AUTOPILOT_VERSION, PARAM_REQUEST_READ and PARAM_REQUEST_LIST
  (``SimFlight.log_params``: COMPASS_DEC, COMPASS_OFS_*, and a test's own); a parameter the
  flight has not goes unanswered, as on a real vehicle.

SIMSTATE (truth) goes out with ATTITUDE, at its rate, as the .tlog writer pairs them. The
firmware banner (STATUSTEXT) and the parameters go out at the start and again when a ground
station first speaks, as ArduPilot greets a new GCS.

One MAVLink sequence counter runs over every packet sent, so a listener can count losses.
"""
from __future__ import annotations

import os
import time
from dataclasses import dataclass, field

import numpy as np

os.environ.setdefault("MAVLINK20", "1")  # parse MAVLink 2 requests (before pymavlink loads)
from pymavlink.dialects.v20 import ardupilotmega as mavlink2  # noqa: E402

from .tlog import STATUSTEXT_MAX, heartbeat_packers, imu_packers  # noqa: E402

SYSID, COMPID = 1, 1
# What the autopilot sends before anyone asks (Hz).
DEFAULT_RATES_HZ = {"RAW_IMU": 10.0, "SCALED_IMU2": 10.0, "ATTITUDE": 10.0, "SIMSTATE": 10.0,
                    "GPS_RAW_INT": 5.0, "SCALED_PRESSURE": 5.0}
# REQUEST_DATA_STREAM groups, as ArduPilot maps them.
STREAMS = {
    mavlink2.MAV_DATA_STREAM_RAW_SENSORS: ("RAW_IMU", "SCALED_IMU2", "SCALED_PRESSURE"),
    mavlink2.MAV_DATA_STREAM_EXTENDED_STATUS: ("GPS_RAW_INT",),
    mavlink2.MAV_DATA_STREAM_EXTRA1: ("ATTITUDE", "SIMSTATE"),
}
STREAMS[mavlink2.MAV_DATA_STREAM_ALL] = tuple(n for names in STREAMS.values() for n in names)
MSG_IDS = {name: getattr(mavlink2, f"MAVLINK_MSG_ID_{name}") for name in DEFAULT_RATES_HZ}
NAMES_BY_ID = {i: name for name, i in MSG_IDS.items()}
HEARTBEAT_PERIOD_S = 1.0


@dataclass
class ServeStats:
    """What ``SimAutopilot.serve`` did."""
    sent: dict[str, int] = field(default_factory=dict)  # packets per message name
    requests: list[str] = field(default_factory=list)  # one line per request honoured
    imu_sent_at: list[tuple[int, float]] = field(default_factory=list)  # (time_usec, monotonic s) per RAW_IMU
    seconds: float = 0.0  # wall time spent
    stopped: bool = False  # ended by ``stop`` rather than by the end of the flight


class SimAutopilot:
    """Sends ``sim`` over a pymavlink connection ``conn`` and answers its requests.

    ``rates`` overrides ``DEFAULT_RATES_HZ`` (0 = off). ``record_imu_times`` keeps the send time
    of every RAW_IMU (for latency measurements). ``sysid``: its MAVLink system id.
    ``announce_params``: send every parameter at the start and to a new ground station (False:
    only those asked for, as a real ArduPilot). The MAVLink packer (and its sequence
    counter) lives as long as the object, so consecutive ``serve`` calls continue the stream.
    """

    def __init__(self, sim, conn, rates: dict[str, float] | None = None, record_imu_times: bool = False,
                 sysid: int = SYSID, announce_params: bool = True):
        self.sim = sim
        self.announce_params = announce_params
        self.conn = conn
        self.sysid = sysid
        self.mav = mavlink2.MAVLink(None, srcSystem=sysid, srcComponent=COMPID)
        self.defaults = {**DEFAULT_RATES_HZ, **(rates or {})}
        self.interval = {name: (1.0 / hz if hz > 0 else None) for name, hz in self.defaults.items()}
        self.record_imu_times = record_imu_times
        epoch_us = int(round(sim.epoch_unix_at_boot * 1e6))
        self.t_heartbeat = np.arange(float(sim.t[0]), float(sim.t[-1]) + HEARTBEAT_PERIOD_S, HEARTBEAT_PERIOD_S)
        self._heartbeat = heartbeat_packers(sim, self.t_heartbeat, self.mav, epoch_us)
        self._imu = imu_packers(sim, self.mav)
        self._time_usec = np.rint(sim.t * 1e6).astype(np.int64).tolist()
        self._gps, self._baro = self._sensor_packers()
        self._next_due = {name: -np.inf for name in DEFAULT_RATES_HZ}
        self._greeted = False
        self.stats = ServeStats()

    # ------------------------------------------------------------ packets

    def _sensor_packers(self):
        from .tlog import _baro_packets, _gps_packets
        gps, baro = _gps_packets(self.sim, self.mav), _baro_packets(self.sim, self.mav)
        return (lambda i: gps(i)[0]), (lambda i: baro(i)[0])

    def _send(self, name: str, packet: bytes) -> None:
        self.conn.write(packet)
        self.mav.seq = (self.mav.seq + 1) % 256  # pack() does not count; MAVLink.send() would
        self.stats.sent[name] = self.stats.sent.get(name, 0) + 1

    def _due(self, name: str, t: float) -> bool:
        interval = self.interval.get("ATTITUDE" if name == "SIMSTATE" else name)
        if interval is None:
            return False
        due = self._next_due[name]
        if t + 1e-9 < due:
            return False
        # next due one interval on; if far behind (a new rate, a pause), from now
        self._next_due[name] = due + interval if t - due < interval else t + interval
        return True

    def send_identity(self) -> None:
        """The firmware STATUSTEXT and the parameters (``announce_params``), as at boot."""
        text = self.sim.firmware[:STATUSTEXT_MAX].encode()
        self._send("STATUSTEXT", mavlink2.MAVLink_statustext_message(mavlink2.MAV_SEVERITY_INFO, text).pack(self.mav))
        if self.announce_params:
            self.send_params()

    def send_params(self, only: str | None = None) -> None:
        params = self.sim.log_params
        for i, (name, value) in enumerate(params.items()):
            if only is None or name == only:
                self._send("PARAM_VALUE", mavlink2.MAVLink_param_value_message(
                    name.encode(), value, mavlink2.MAV_PARAM_TYPE_REAL32, len(params), i).pack(self.mav))

    # ------------------------------------------------------------ requests

    def poll_requests(self) -> None:
        """Answer whatever requests have arrived (non-blocking)."""
        while True:
            msg = self.conn.recv_msg()
            if msg is None:
                return
            name = msg.get_type()
            if name == "BAD_DATA" or getattr(msg, "target_system", self.sysid) not in (0, self.sysid):
                continue
            if not self._greeted:
                self._greeted = True
                self.send_identity()
            if name == "COMMAND_LONG":
                self._command(msg)
            elif name == "REQUEST_DATA_STREAM":
                names = STREAMS.get(msg.req_stream_id, ())
                for n in names:
                    rate = float(msg.req_message_rate)
                    self.interval[n] = 1.0 / rate if msg.start_stop and rate > 0 else None
                    self._next_due[n] = -np.inf
                if names:
                    self.stats.requests.append(f"REQUEST_DATA_STREAM {msg.req_stream_id} "
                                               f"{msg.req_message_rate} Hz start={msg.start_stop}")
            elif name == "PARAM_REQUEST_LIST":
                self.send_params()
            elif name == "PARAM_REQUEST_READ":
                self.send_params(only=msg.param_id)
                self.stats.requests.append(f"PARAM_REQUEST_READ {msg.param_id}")

    def _command(self, msg) -> None:
        result = mavlink2.MAV_RESULT_ACCEPTED
        if msg.command == mavlink2.MAV_CMD_SET_MESSAGE_INTERVAL:
            name = NAMES_BY_ID.get(_int(msg.param1))
            if name is None:
                result = mavlink2.MAV_RESULT_UNSUPPORTED
            else:
                us = msg.param2 if msg.param2 == msg.param2 else 0.0  # NaN: the default
                default = self.defaults[name]
                self.interval[name] = (None if us < 0 else (1.0 / default if default > 0 else None) if us == 0
                                       else us * 1e-6)
                self._next_due[name] = -np.inf
                self.stats.requests.append(f"SET_MESSAGE_INTERVAL {name} {us:g} us")
        elif (msg.command == mavlink2.MAV_CMD_REQUEST_MESSAGE
              and _int(msg.param1) == mavlink2.MAVLINK_MSG_ID_AUTOPILOT_VERSION):
            self._send("AUTOPILOT_VERSION", self._autopilot_version())
        else:
            result = mavlink2.MAV_RESULT_UNSUPPORTED
        self._send("COMMAND_ACK", mavlink2.MAVLink_command_ack_message(msg.command, result).pack(self.mav))

    def _autopilot_version(self) -> bytes:
        version = (4 << 24) | (7 << 16) | (0 << 8) | 255  # 4.7.0 official, as the firmware string says
        return mavlink2.MAVLink_autopilot_version_message(
            0, version, 0, 0, 0, b"\0" * 8, b"\0" * 8, b"\0" * 8, 0, 0, 0).pack(self.mav)

    # ------------------------------------------------------------ the stream

    def serve(self, speed: float = 1.0, t_from: float | None = None, t_to: float | None = None,
              stop=lambda: False) -> ServeStats:
        """Send the flight from ``t_from`` to ``t_to`` (s on the autopilot clock; default all of
        it) at ``speed`` times real time (0: as fast as possible), answering requests as they
        come. ``stop()`` is asked between ticks. Returns the (cumulative) stats."""
        sim = self.sim
        t = sim.t
        a = 0 if t_from is None else int(np.searchsorted(t, t_from))
        b = len(t) if t_to is None else int(np.searchsorted(t, t_to, side="right"))
        if a >= b:
            return self.stats
        t0 = float(t[a])
        # every event in [a, b): (time, kind, index), kind 0 heartbeat, 1 IMU tick, 2 GPS, 3 baro
        hb = np.flatnonzero((self.t_heartbeat >= t0) & (self.t_heartbeat <= t[b - 1]))
        gps = np.flatnonzero((sim.gps.t >= t0) & (sim.gps.t <= t[b - 1]))
        baro = np.flatnonzero((sim.baro.t >= t0) & (sim.baro.t <= t[b - 1]))
        imu = np.arange(a, b)
        times = np.concatenate([self.t_heartbeat[hb], t[imu], sim.gps.t[gps], sim.baro.t[baro]])
        kinds = np.concatenate([np.zeros(len(hb), int), np.ones(len(imu), int), np.full(len(gps), 2),
                                np.full(len(baro), 3)])
        index = np.concatenate([hb, imu, gps, baro])
        order = np.lexsort((kinds, times))
        start = time.monotonic()
        if a == 0:
            self.send_identity()
        for ti, kind, i in zip(times[order].tolist(), kinds[order].tolist(), index[order].tolist()):
            if speed > 0:
                wait = start + (ti - t0) / speed - time.monotonic()
                while wait > 0:  # sleep in slices so requests are answered while waiting
                    time.sleep(min(wait, 0.01))
                    self.poll_requests()
                    wait = start + (ti - t0) / speed - time.monotonic()
            self.poll_requests()
            if stop():
                self.stats.stopped = True
                break
            if kind == 0:
                for name, pack in self._heartbeat.items():
                    self._send(name, pack(i))
            elif kind == 1:
                for name, pack in self._imu.items():
                    if self._due(name, ti):
                        self._send(name, pack(i))
                        if name == "RAW_IMU" and self.record_imu_times:
                            self.stats.imu_sent_at.append((self._time_usec[i], time.monotonic()))
            elif kind == 2 and self._due("GPS_RAW_INT", ti):
                self._send("GPS_RAW_INT", self._gps(i))
            elif kind == 3 and self._due("SCALED_PRESSURE", ti):
                self._send("SCALED_PRESSURE", self._baro(i))
        self.stats.seconds += time.monotonic() - start
        return self.stats


def _int(x: float) -> int:
    """A command's float parameter as the integer it carries (-1 for NaN or inf)."""
    return int(x) if x == x and abs(x) < 2 ** 31 else -1
