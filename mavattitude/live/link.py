"""The MAVLink link of a live session: opening it, counting what crosses it, asking for rates.

pymavlink opens the connection (any of its connection strings) and decodes; this module adds
what a monitoring tool needs around it:

- ``open_link``: one clear error for a port in use, a missing serial device, a bad string;
- ``LinkMonitor``: packets and bytes, corrupt data, packets lost by sequence number (per
  sender), per-message arrival rates on the wall clock, and whether the link is lost;
- ``drop_cut_frame``: a UDP datagram holds whole frames; one cut short at its end is dropped
  there, not completed with the bytes of the next datagram's packets;
- ``RateRequester``: asks the vehicle for its IMU, ATTITUDE, GPS and baro messages with
  MAV_CMD_SET_MESSAGE_INTERVAL, one message at a time, and falls back to the older
  REQUEST_DATA_STREAM groups when the vehicle does not acknowledge or refuses.
"""
from __future__ import annotations

import errno
import os
import socket
import sys
import time
from collections import deque
from dataclasses import dataclass, field

os.environ.setdefault("MAVLINK20", "1")  # MAVLink 2 (the v2 parser reads v1 packets too)
from pymavlink import mavutil  # noqa: E402
from pymavlink.dialects.v20 import ardupilotmega as mavlink2  # noqa: E402

from ..errors import InputError, UsageError  # noqa: E402
from ..readers import enum_name  # noqa: E402

GCS_SYSID, GCS_COMPID = 255, mavlink2.MAV_COMP_ID_MISSIONPLANNER  # who we are on the link
RATE_WINDOW_S = 3.0  # s: arrival rates are counted over this trailing window
# Receive buffer asked of the OS for a UDP link: a second of 1 kHz IMU and more, so a pause of
# the session (a viewer that stalls, a slow disk) does not overflow it. Linux caps the request
# at net.core.rmem_max unless the process may force it.
UDP_RECEIVE_BUFFER = 8 << 20
ACK_TIMEOUT_S = 1.0  # s: a command without an answer is sent once more, then given up
# The rates a request can carry: the autopilot keeps SET_MESSAGE_INTERVAL's interval as an
# int32 of µs (MESSAGE_INTERVAL.interval_us), REQUEST_DATA_STREAM's rate is a uint16 of Hz.
MIN_REQUEST_HZ = 1e6 / (2**31 - 1)
MAX_REQUEST_HZ = 65535.0
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
    mavutil.set_dialect("ardupilotmega")  # MAVLink 2's, whatever imported pymavlink first
    try:
        # one connection attempt (retries=0): pymavlink's own retries sleep and print;
        # reconnecting a TCP link is the session's job (``TcpReconnect``)
        conn = mavutil.mavlink_connection(url, baud=baud, source_system=GCS_SYSID,
                                          source_component=GCS_COMPID, robust_parsing=True,
                                          autoreconnect=False, retries=0)
    except OSError as exc:
        if exc.errno == errno.EADDRINUSE:
            raise InputError(url, "port already in use (another program is listening there)") from None
        if exc.errno in (errno.ENOENT, errno.ENODEV, errno.ENXIO):
            raise InputError(url, "no such serial device (nor a MAVLink connection string: "
                                  "udpin:HOST:PORT, udpout:HOST:PORT, tcp:HOST:PORT)") from None
        if exc.errno == errno.ECONNREFUSED:
            raise InputError(url, "connection refused (nothing listening there)") from None
        raise InputError(url, exc.strerror or str(exc)) from None
    except ValueError as exc:
        raise UsageError(f"{url}: not a MAVLink connection string ({exc}); e.g. udpin:0.0.0.0:14550, "
                         "udpout:192.168.1.10:14550, tcp:127.0.0.1:5760, /dev/ttyUSB0") from None
    except ModuleNotFoundError as exc:
        raise InputError(url, f"not a network address, and serial links need the {exc.name} module "
                              "(pip install pyserial)") from None
    except Exception as exc:  # pyserial's SerialException and the like
        text = str(exc).splitlines()[0] if str(exc) else type(exc).__name__
        if "No such file" in text or "could not open port" in text:
            text = "no such serial device (or not a MAVLink connection string: udpin:HOST:PORT, tcp:HOST:PORT)"
        raise InputError(url, text) from None
    _enlarge_receive_buffer(conn)
    if isinstance(conn, mavutil.mavtcp):
        TcpReconnect.attach(conn)
    return conn


class TcpReconnect:
    """A TCP link whose peer went away (SITL restarted, a bridge closed): pymavlink would block
    for seconds retrying and print about it. Instead the link goes quiet (``gone``) and
    ``tick`` tries one quick connect a second; the session reports "link lost" meanwhile."""

    def __init__(self, conn):
        self.conn = conn
        self.gone = False
        self.tried_at = 0.0

    @classmethod
    def attach(cls, conn) -> None:
        keeper = cls(conn)
        conn.reconnector = keeper
        conn.handle_eof = keeper.lost
        conn.handle_disconnect = keeper.lost
        recv = conn.recv

        def quiet_recv(n=None):
            if keeper.gone or conn.port is None:
                return b""
            return recv(n)
        conn.recv = quiet_recv

    def lost(self) -> None:
        self.gone = True
        if self.conn.port is not None:
            self.conn.port.close()
            self.conn.port = None

    def tick(self, now: float) -> bool:
        """Try to reconnect (once a second); True when the link just came back."""
        if not self.gone or now - self.tried_at < 1.0:
            return False
        self.tried_at = now
        sock = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
        sock.settimeout(0.2)
        try:
            sock.connect(self.conn.destination_addr)
        except OSError:
            sock.close()
            return False
        sock.setblocking(False)
        sock.setsockopt(socket.SOL_TCP, socket.TCP_NODELAY, 1)
        self.conn.port = sock
        self.conn.fd = sock.fileno()
        self.gone = False
        return True


def close_link(conn) -> None:
    """Close a link whatever state it is in."""
    port = getattr(conn, "port", None)
    try:
        if port is not None or not hasattr(conn, "port"):
            conn.close()
    except (OSError, AttributeError):
        pass


SO_RCVBUFFORCE = getattr(socket, "SO_RCVBUFFORCE", 33 if sys.platform.startswith("linux") else None)


def _enlarge_receive_buffer(conn) -> None:
    """Ask for UDP_RECEIVE_BUFFER: forced past the system's limit where the process may (Linux,
    CAP_NET_ADMIN), else as much as the limit allows. ``receive_buffer`` says what was granted."""
    port = getattr(conn, "port", None)
    if not isinstance(port, socket.socket) or port.type != socket.SOCK_DGRAM:
        return
    for option in (SO_RCVBUFFORCE, socket.SO_RCVBUF):
        if option is None:
            continue
        try:
            port.setsockopt(socket.SOL_SOCKET, option, UDP_RECEIVE_BUFFER)
            return
        except OSError:
            continue


def _udp_socket(conn) -> socket.socket | None:
    """The socket of a UDP link; None for other links."""
    port = getattr(conn, "port", None)
    return port if isinstance(port, socket.socket) and port.type == socket.SOCK_DGRAM else None


def is_datagram_link(conn) -> bool:
    """Whether each read of the link is one UDP datagram (udpin, udpout, udpbcast, mcast), not
    a slice of a byte stream (TCP, serial)."""
    return _udp_socket(conn) is not None


def drop_cut_frame(mav) -> bool:
    """After a datagram is parsed: the bytes left in pymavlink's parser (``mav``) are a frame cut
    short, since a frame never spans datagrams. Left there, they would take the start of the
    next datagram's first packet to complete themselves and fail the CRC, and the parser would
    then resynchronise inside that packet's payload: valid packets lost. Dropped here; True if
    there were any. (A stream link must keep them: the rest of the frame is on its way.)"""
    if mav.buf_len() == 0:
        return False
    mav.buf = bytearray()
    mav.buf_index = 0
    mav.expected_length = mavlink2.HEADER_LEN_V1 + 2  # as a new parser starts
    return True


def receive_buffer(conn) -> int | None:
    """Bytes of receive buffer the system granted a UDP link (Linux counts its bookkeeping
    too: twice what was asked); None for other links."""
    port = _udp_socket(conn)
    return port.getsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF) if port is not None else None


def kernel_drops(conn) -> int | None:
    """Datagrams the system dropped for a UDP link because its receive buffer was full: the
    'drops' column of Linux's /proc/net/udp for this socket. None where it is not known."""
    port = _udp_socket(conn)
    if port is None:
        return None
    try:
        inode = str(os.fstat(port.fileno()).st_ino)
    except OSError:
        return None
    for table in ("/proc/net/udp", "/proc/net/udp6"):
        try:
            with open(table) as f:
                rows = f.read().splitlines()[1:]
        except OSError:
            continue
        for row in rows:
            fields = row.split()  # sl local rem st tx:rx tr:when retrnsmt uid timeout inode ref pointer drops
            if len(fields) > 12 and fields[9] == inode:
                return int(fields[12])
    return None


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


def is_corrupt(msg) -> bool:
    """pymavlink's BAD_DATA, or a packet of a message id the dialect does not know: its checksum
    cannot be checked (that needs the message's CRC_EXTRA), so it is as likely noise that
    happened to start with a MAVLink magic byte. Counted as corrupt, never recorded."""
    return msg.get_type() == "BAD_DATA" or msg.get_type().startswith("UNKNOWN_")


@dataclass
class LinkMonitor:
    """What arrived and whether the link is alive. Times are wall-clock monotonic s.

    ``count`` takes every packet: totals, corrupt data, and losses by sequence number per
    sender (a gap of 1-127 is that many lost; a jump back is a repeated or reordered packet,
    not 129+ losses, unless the next packet confirms a new sequence: a sender that
    restarted; a sender heard again after ``timeout_s`` of silence starts a new count).
    ``heard`` takes the vehicle's packets only: arrival rates and the link-lost watch are
    about the vehicle, not about whatever else shares the link (a second vehicle, a radio's
    RADIO_STATUS, another ground station)."""
    timeout_s: float = 5.0
    packets: int = 0  # valid MAVLink packets, every sender
    bad: int = 0  # corrupt data: garbage bytes, bad CRC, unknown message ids (``is_corrupt``), cut frames
    cut_frames: int = 0  # of ``bad``: frames cut short at the end of a datagram (``drop_cut_frame``)
    lost: int = 0  # packets missing by sequence number
    first_at: float | None = None  # the vehicle's first and last packet
    last_at: float | None = None
    lost_since: float | None = None  # when the link was declared lost (None: alive)
    _seq: dict = field(default_factory=dict)  # (sysid, compid) -> (last sequence number, time)
    _jump: dict = field(default_factory=dict)  # (sysid, compid) -> sequence number of a jump back
    _gaps: deque = field(default_factory=deque)  # (time, packets missing) of the last second
    _arrivals: dict = field(default_factory=dict)  # message name -> deque of arrival times

    def count(self, msg, now: float) -> None:
        if is_corrupt(msg):
            self.bad += 1
            return
        self.packets += 1
        key = (msg.get_srcSystem(), msg.get_srcComponent())
        seq = msg.get_seq()
        last = self._seq.get(key)
        if last is None or now - last[1] > self.timeout_s:
            self._seq[key] = (seq, now)
            return
        gap = (seq - last[0] - 1) & 0xFF
        if gap >= 128:  # a jump back: repeated or reordered, or a new sequence if confirmed
            confirmed = self._jump.get(key) == (seq - 1) & 0xFF
            self._jump[key] = seq
            if confirmed:
                self._seq[key] = (seq, now)
            return
        self._jump.pop(key, None)
        if gap:
            self.lost += gap
            self._gaps.append((now, gap))
            while self._gaps and self._gaps[0][0] < now - 1.0:
                self._gaps.popleft()
        self._seq[key] = (seq, now)

    def cut_frame(self) -> None:
        """A frame cut short at the end of a datagram, dropped (corrupt data)."""
        self.bad += 1
        self.cut_frames += 1

    def heard(self, msg, now: float) -> None:
        """A packet from the vehicle."""
        if self.first_at is None:
            self.first_at = now
        self.last_at = now
        arrivals = self._arrivals.get(msg.get_type())
        if arrivals is None:
            arrivals = self._arrivals[msg.get_type()] = deque()
        arrivals.append(now)
        while arrivals[0] < now - RATE_WINDOW_S:
            arrivals.popleft()

    def forget_sequences(self, since: float | None = None) -> None:
        """After a reboot: the next sequence number starts a new count. ``since`` (monotonic
        s): the gaps counted from then on were the sender restarting its sequence, not losses
        (a reboot is noticed a packet or two after it happened)."""
        self._seq.clear()
        self._jump.clear()
        if since is not None:
            self.lost -= sum(gap for t, gap in self._gaps if t >= since)
            self._gaps.clear()

    def rate(self, name: str, now: float) -> float:
        """The vehicle's arrivals per second of message ``name`` over the last RATE_WINDOW_S."""
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
        """'lost' when the vehicle just went silent for timeout_s, 'back' when its packets
        just returned after that, else None."""
        if self.last_at is None:
            return None
        if self.lost_since is None and now - self.last_at > self.timeout_s:
            self.lost_since = now
            return "lost"
        if self.lost_since is not None and self.last_at > self.lost_since:
            self.lost_since = None
            return "back"
        return None


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
            self._failed.append((self._current, enum_name("MAV_RESULT", msg.result)))
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
            self.notes.append(f"asked for stream {enum_name('MAV_DATA_STREAM', stream)} at "
                              f"{max(1, int(round(hz)))} Hz (REQUEST_DATA_STREAM)")


def request_identity(conn, target: tuple[int, int], params: tuple[str, ...] = ()) -> None:
    """Ask for AUTOPILOT_VERSION (firmware) and, by PARAM_REQUEST_READ, the parameters
    ``params`` (a run's policy reads them: ``core.policy.wanted_params``), in that order; a
    vehicle answers those it has."""
    conn.mav.command_long_send(*target, mavlink2.MAV_CMD_REQUEST_MESSAGE, 0,
                               mavlink2.MAVLINK_MSG_ID_AUTOPILOT_VERSION, 0, 0, 0, 0, 0, 0)
    for name in params:
        conn.mav.param_request_read_send(*target, name.encode(), -1)


def wait_readable(conn, timeout: float) -> None:
    """Sleep until the link has data or ``timeout`` s pass (select on its descriptor)."""
    fd = getattr(conn, "fd", None)
    keeper = getattr(conn, "reconnector", None)
    if fd is None or (keeper is not None and keeper.gone):
        time.sleep(timeout)
        return
    import select
    try:
        select.select([fd], [], [], timeout)
    except (OSError, ValueError):
        time.sleep(timeout)
