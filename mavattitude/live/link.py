"""The MAVLink link of a live session: opening it, counting what crosses it, asking for rates.

pymavlink opens the connection (any of its connection strings) and decodes; this module adds
what a monitoring tool needs around it:

- ``open_link``: one clear error for a port in use, a missing serial device, a bad string;
- ``LinkMonitor``: packets and bytes, corrupt data, packets lost by sequence number (per
  sender), per-message arrival rates on the wall clock, and whether the link is lost;
- ``RateRequester``: asks the vehicle for its IMU, ATTITUDE, GPS and baro messages with
  MAV_CMD_SET_MESSAGE_INTERVAL, one message at a time, and falls back to the older
  REQUEST_DATA_STREAM groups when the vehicle does not acknowledge or refuses.
"""
from __future__ import annotations

import errno
import os
import socket
import time
from collections import deque
from dataclasses import dataclass, field

os.environ.setdefault("MAVLINK20", "1")  # MAVLink 2 (the v2 parser reads v1 packets too)
from pymavlink import mavutil  # noqa: E402
from pymavlink.dialects.v20 import ardupilotmega as mavlink2  # noqa: E402

from ..errors import InputError, UsageError  # noqa: E402

GCS_SYSID, GCS_COMPID = 255, mavlink2.MAV_COMP_ID_MISSIONPLANNER  # who we are on the link
RATE_WINDOW_S = 3.0  # s: arrival rates are counted over this trailing window
# Receive buffer asked of the OS for a UDP link: a second of 1 kHz IMU and more, so a pause of
# the session (a viewer that stalls, a slow disk) does not overflow it. Linux caps the request
# at net.core.rmem_max unless the process may force it.
UDP_RECEIVE_BUFFER = 8 << 20
ACK_TIMEOUT_S = 1.0  # s: a command without an answer is sent once more, then given up
REQUEST_STREAMS = {  # REQUEST_DATA_STREAM group of each message (ArduPilot's grouping)
    "RAW_IMU": mavlink2.MAV_DATA_STREAM_RAW_SENSORS,
    "SCALED_IMU": mavlink2.MAV_DATA_STREAM_RAW_SENSORS,
    "SCALED_IMU2": mavlink2.MAV_DATA_STREAM_RAW_SENSORS,
    "SCALED_IMU3": mavlink2.MAV_DATA_STREAM_RAW_SENSORS,
    "HIGHRES_IMU": mavlink2.MAV_DATA_STREAM_RAW_SENSORS,
    "SCALED_PRESSURE": mavlink2.MAV_DATA_STREAM_RAW_SENSORS,
    "ATTITUDE": mavlink2.MAV_DATA_STREAM_EXTRA1,
    "GPS_RAW_INT": mavlink2.MAV_DATA_STREAM_EXTENDED_STATUS,
}


def open_link(url: str, baud: int = 115200):
    """A pymavlink connection for ``url`` (udpin:, udpout:, udp:, tcp:, tcpin:, a serial device).

    Raises InputError (one line, naming the link) for a port in use, a missing device or a
    refused TCP connection; UsageError for a string pymavlink does not understand."""
    _check_udp_port_free(url)
    try:
        conn = mavutil.mavlink_connection(url, baud=baud, source_system=GCS_SYSID,
                                          source_component=GCS_COMPID, robust_parsing=True,
                                          autoreconnect=True)
    except OSError as exc:
        if exc.errno == errno.EADDRINUSE:
            raise InputError(url, "port already in use (another program is listening there)") from None
        if exc.errno in (errno.ENOENT, errno.ENODEV, errno.ENXIO):
            raise InputError(url, "no such serial device") from None
        if exc.errno == errno.ECONNREFUSED:
            raise InputError(url, "connection refused (nothing listening there)") from None
        raise InputError(url, exc.strerror or str(exc)) from None
    except ValueError as exc:
        raise UsageError(f"{url}: not a MAVLink connection string ({exc}); e.g. udpin:0.0.0.0:14550, "
                         "udpout:192.168.1.10:14550, tcp:127.0.0.1:5760, /dev/ttyUSB0") from None
    except Exception as exc:  # pyserial's SerialException and the like
        raise InputError(url, str(exc).splitlines()[0] if str(exc) else type(exc).__name__) from None
    _enlarge_receive_buffer(conn)
    return conn


def _enlarge_receive_buffer(conn) -> None:
    port = getattr(conn, "port", None)
    if not isinstance(port, socket.socket) or port.type != socket.SOCK_DGRAM:
        return
    for option in (getattr(socket, "SO_RCVBUFFORCE", None), socket.SO_RCVBUF):
        if option is None:
            continue
        try:
            port.setsockopt(socket.SOL_SOCKET, option, UDP_RECEIVE_BUFFER)
            return
        except OSError:
            continue


def _check_udp_port_free(url: str) -> None:
    """pymavlink binds a UDP listening port with SO_REUSEADDR, so a second listener on the same
    port succeeds and then receives nothing. Bind it once without that option first: that
    fails, as it should, when someone is already there."""
    kind, _, address = url.partition(":")
    if kind not in ("udpin", "udp"):
        return
    host, _, port = address.rpartition(":")
    if not port.isdigit():
        return
    probe = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    try:
        probe.bind((host or "0.0.0.0", int(port)))
    except OSError as exc:
        if exc.errno == errno.EADDRINUSE:
            raise InputError(url, "port already in use (another program is listening there)") from None
        if exc.errno == errno.EADDRNOTAVAIL:
            raise InputError(url, f"{host} is not an address of this machine") from None
        raise InputError(url, exc.strerror or str(exc)) from None
    except (socket.gaierror, OverflowError) as exc:
        raise UsageError(f"{url}: not a usable address ({exc})") from None
    finally:
        probe.close()


@dataclass
class LinkMonitor:
    """Counts of what arrived, and whether the link is alive. Times are wall-clock monotonic s."""
    timeout_s: float = 5.0
    packets: int = 0  # valid MAVLink packets
    bad: int = 0  # corrupt data: garbage bytes, bad CRC, unknown messages (pymavlink's BAD_DATA)
    lost: int = 0  # packets missing by sequence number
    first_at: float | None = None
    last_at: float | None = None
    lost_since: float | None = None  # when the link was declared lost (None: alive)
    _seq: dict = field(default_factory=dict)  # (sysid, compid) -> last sequence number
    _gaps: deque = field(default_factory=deque)  # (time, packets missing) of the last second
    _arrivals: dict = field(default_factory=dict)  # message name -> deque of arrival times

    def count(self, msg, now: float) -> None:
        if msg.get_type() == "BAD_DATA":
            self.bad += 1
            return
        self.packets += 1
        if self.first_at is None:
            self.first_at = now
        self.last_at = now
        key = (msg.get_srcSystem(), msg.get_srcComponent())
        seq = msg.get_seq()
        last = self._seq.get(key)
        if last is not None:
            # packets missing since the last one (modulo 256: a burst of 300 counts as 44;
            # the session forgets the count after a silence or a reboot, where the sender may
            # have restarted its sequence)
            gap = (seq - last - 1) & 0xFF
            if gap:
                self.lost += gap
                self._gaps.append((now, gap))
                while self._gaps and self._gaps[0][0] < now - 1.0:
                    self._gaps.popleft()
        self._seq[key] = seq
        arrivals = self._arrivals.get(msg.get_type())
        if arrivals is None:
            arrivals = self._arrivals[msg.get_type()] = deque()
        arrivals.append(now)

    def forget_sequences(self, since: float | None = None) -> None:
        """After a silence or a reboot: the next sequence number starts a new count. ``since``
        (monotonic s): the gaps counted from then on were the sender restarting its sequence,
        not losses (a reboot is noticed a packet or two after it happened)."""
        self._seq.clear()
        if since is not None:
            self.lost -= sum(gap for t, gap in self._gaps if t >= since)
            self._gaps.clear()

    def rate(self, name: str, now: float) -> float:
        """Arrivals per second of message ``name`` over the last RATE_WINDOW_S."""
        arrivals = self._arrivals.get(name)
        if not arrivals:
            return 0.0
        while arrivals and arrivals[0] < now - RATE_WINDOW_S:
            arrivals.popleft()
        span = min(RATE_WINDOW_S, now - self.first_at) if self.first_at is not None else 0.0
        return len(arrivals) / span if span > 0.5 else 0.0

    def rates(self, now: float) -> dict[str, float]:
        return {name: self.rate(name, now) for name in list(self._arrivals)}

    def check_lost(self, now: float) -> str | None:
        """'lost' when the link just went silent for timeout_s, 'back' when packets just
        returned after that, else None."""
        if self.last_at is None:
            return None
        if self.lost_since is None and now - self.last_at > self.timeout_s:
            self.lost_since = now
            return "lost"
        if self.lost_since is not None and self.last_at > self.lost_since:
            self.lost_since = None
            return "back"
        return None

    @property
    def loss_percent(self) -> float:
        total = self.packets + self.lost
        return 100.0 * self.lost / total if total else 0.0


@dataclass
class RateRequester:
    """Asks the vehicle (``target``: sysid, compid) for ``wanted`` {message name: Hz}.

    Call ``tick(now)`` often and ``on_message(msg)`` with every message from the vehicle.
    One SET_MESSAGE_INTERVAL at a time: the next goes after the vehicle's COMMAND_ACK (or
    after a second unanswered try). Messages the vehicle refused or never acknowledged are
    then asked for with REQUEST_DATA_STREAM. ``notes`` says what happened, a line each."""
    conn: object
    target: tuple[int, int]
    wanted: dict[str, float]
    notes: list[str] = field(default_factory=list)
    done: bool = False
    _queue: list = field(default_factory=list)
    _current: str | None = None
    _sent_at: float = 0.0
    _tries: int = 0
    _failed: list = field(default_factory=list)
    _accepted: list = field(default_factory=list)

    def start(self, now: float) -> None:
        self._queue = list(self.wanted)
        self._next(now)

    def _next(self, now: float) -> None:
        if not self._queue:
            self._current = None
            self._finish()
            return
        self._current = self._queue.pop(0)
        self._tries = 0
        self._send(now)

    def _send(self, now: float) -> None:
        name = self._current
        msg_id = getattr(mavlink2, f"MAVLINK_MSG_ID_{name}")
        interval_us = 1e6 / self.wanted[name]
        self.conn.mav.command_long_send(*self.target, mavlink2.MAV_CMD_SET_MESSAGE_INTERVAL, 0,
                                        msg_id, interval_us, 0, 0, 0, 0, 0)
        self._sent_at = now
        self._tries += 1

    def on_message(self, msg, now: float) -> None:
        if (self._current is None or msg.get_type() != "COMMAND_ACK"
                or msg.command != mavlink2.MAV_CMD_SET_MESSAGE_INTERVAL):
            return
        if msg.result == mavlink2.MAV_RESULT_ACCEPTED:
            self._accepted.append(self._current)
        else:
            self._failed.append((self._current, _enum("MAV_RESULT", msg.result)))
        self._next(now)

    def tick(self, now: float) -> None:
        if self._current is None or now - self._sent_at < ACK_TIMEOUT_S:
            return
        if self._tries < 2:
            self._send(now)
        else:
            self._failed.append((self._current, "no answer"))
            self._next(now)

    def _finish(self) -> None:
        if self.done:
            return
        self.done = True
        if self._accepted:
            self.notes.append("asked for " + ", ".join(f"{n} at {self.wanted[n]:g} Hz" for n in self._accepted)
                              + " (SET_MESSAGE_INTERVAL, acknowledged)")
        if not self._failed:
            return
        self.notes.append("SET_MESSAGE_INTERVAL not honoured for "
                          + ", ".join(f"{n} ({why})" for n, why in self._failed)
                          + "; falling back to REQUEST_DATA_STREAM")
        streams: dict[int, float] = {}
        for name, _ in self._failed:
            stream = REQUEST_STREAMS.get(name)
            if stream is not None:
                streams[stream] = max(streams.get(stream, 0.0), self.wanted[name])
        for stream, hz in streams.items():
            self.conn.mav.request_data_stream_send(*self.target, stream, max(1, int(round(hz))), 1)
            self.notes.append(f"asked for stream {_enum('MAV_DATA_STREAM', stream)} at "
                              f"{max(1, int(round(hz)))} Hz (REQUEST_DATA_STREAM)")


def _enum(enum: str, value: int) -> str:
    entry = mavlink2.enums.get(enum, {}).get(value)
    return entry.name.replace(enum + "_", "") if entry else str(value)


def request_identity(conn, target: tuple[int, int]) -> None:
    """Ask for AUTOPILOT_VERSION (firmware) and COMPASS_DEC (the declination)."""
    conn.mav.command_long_send(*target, mavlink2.MAV_CMD_REQUEST_MESSAGE, 0,
                               mavlink2.MAVLINK_MSG_ID_AUTOPILOT_VERSION, 0, 0, 0, 0, 0, 0)
    conn.mav.param_request_read_send(*target, b"COMPASS_DEC", -1)


def wait_readable(conn, timeout: float) -> None:
    """Sleep until the link has data or ``timeout`` s pass (select on its descriptor)."""
    fd = getattr(conn, "fd", None)
    if fd is None:
        time.sleep(timeout)
        return
    import select
    try:
        select.select([fd], [], [], timeout)
    except (OSError, ValueError):
        time.sleep(timeout)
