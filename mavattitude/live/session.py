"""A live session: link in, estimates out, everything recorded. ``mavattitude live`` runs this.

One loop on one thread: drain the link (every packet is recorded, counted, and, when it comes
from the vehicle, decoded), step the estimators over what arrived, and a few times a second
flush the recording, stream to Rerun, tick the rate requests, watch for a lost link; once a
second redraw the status line. The loop ends on Ctrl-C, SIGTERM or SIGHUP (handled: the loop
finishes its turn, so the recording is complete up to the last packet), after ``duration``
seconds, or when ``stop()`` says so; then the final metrics are printed.
"""
from __future__ import annotations

import gc
import math
import os
import signal
import sys
import threading
import time
from collections import deque
from dataclasses import dataclass, field
from datetime import datetime, timezone

from ..core.policy import RunOptions, wanted_params
from ..errors import InputError
from ..events import Event
from ..scoring.imucheck import COARSE_RATE_HZ
from ..view.sink import Sink
from .estimation import HISTORY_S, LiveEstimation
from ..readers import enum_name, identify_vehicle
from ..readers.tlog import IMU_MESSAGES, is_vehicle
from .link import (UDP_RECEIVE_BUFFER, LinkMonitor, RateRequester, close_link, drop_cut_frame, is_corrupt,
                   is_datagram_link, kernel_drops, mavlink2, open_link, receive_buffer, request_identity,
                   wait_readable)
from .recorder import TlogRecorder

TICK_S = 0.2  # s of wall time between the periodic jobs
RATES_REPORT_AFTER_S = 4.0  # s after the requests: report the rates that actually arrive
WAIT_NOTE_EVERY_S = 10.0
MAX_BATCH = 500  # packets decoded before the estimators step, at most
# A turn of the loop takes at least this long unless packets are waiting beyond MAX_BATCH: a step
# of the estimators costs ~100 µs whatever its size, so at 5,000 packets/s stepping on every
# packet or two kept a core busy. Latency grows by at most this.
CYCLE_S = 0.002
DRAIN_S = 2.0  # s at most spent, after a stop, on the packets still in the socket
GCS_HEARTBEAT_S = 1.0  # a ground station says it is there once a second
FIRMWARE_WAIT_S = 1.0  # s after the vehicle is found: its version and texts have come, say the firmware
BEFORE_VEHICLE_PACKETS = 20_000  # kept until the vehicle's first HEARTBEAT says which system it is
# Heartbeats from these are not the vehicle, whatever autopilot field they carry.
NOT_VEHICLES = {getattr(mavlink2, f"MAV_TYPE_{n}") for n in (
    "GCS", "ANTENNA_TRACKER", "ONBOARD_CONTROLLER", "GIMBAL", "ADSB", "CAMERA", "CHARGING_STATION",
    "FLARM", "SERVO", "ODID", "BATTERY", "PARACHUTE", "LOG", "OSD", "IMU", "GPS", "WINCH")
    if hasattr(mavlink2, f"MAV_TYPE_{n}")}


def default_record_path() -> str:
    """live-<UTC time>.tlog in the current folder (-2, -3, ... if that exists)."""
    stem = f"live-{datetime.now(timezone.utc).strftime('%Y%m%d-%H%M%S')}"
    path, n = f"{stem}.tlog", 1
    while os.path.exists(path):
        n += 1
        path = f"{stem}-{n}.tlog"
    return path


@dataclass
class LiveOptions:
    """A session's link and what it estimates (``run``: the options a replay takes too; the
    session decides the run's policy on the vehicle's parameters, ``policy.decide``)."""
    url: str = "udpin:0.0.0.0:14550"
    baud: int = 115200
    sysid: int | None = None  # the vehicle: default the first autopilot heard
    run: RunOptions = field(default_factory=lambda: RunOptions(("mahony",)))
    imu_rate: float = 50.0  # Hz asked of the vehicle for its IMU message (ATTITUDE: up to 50 Hz)
    request: bool = True  # ask for rates and the policy's parameters (False: listen only)
    window: float = 10.0  # s of the rolling metrics
    timeout: float = 5.0  # s without packets: link lost
    record: str | None = None  # .tlog path (None: no recording)
    duration: float | None = None  # s of wall time, then stop
    sink: Sink | None = None  # where the Rerun view goes (sink.plan_sink), if anywhere
    record_latency: bool = False


@dataclass
class LiveResult:
    estimation: LiveEstimation
    monitor: LinkMonitor
    comparisons: dict
    reference: str | None  # the reference's source name, if any
    vehicle: tuple[int, int] | None
    firmware: str | None
    recorded: int  # packets written to the .tlog
    seconds: float
    ended_by: str  # "signal", "duration", "stop"
    segment: int | None = None  # the clock segment the comparisons score (reboots start new ones)
    kernel_drops: int | None = None  # datagrams the system dropped (receive buffer full); None: unknown

    def link(self) -> dict:
        """The link's figures, as ``live --json`` writes them ("link")."""
        m, loss = self.monitor, self.estimation.samples_lost
        return {"packets_received": m.packets, "packets_lost_by_sequence": m.lost,
                "imu_samples_received": loss.received if loss else 0,
                "imu_samples_lost_by_clock": loss.lost if loss else 0,
                "corrupt": m.bad, "cut_frames": m.cut_frames, "kernel_drops": self.kernel_drops, "duration_s": round(self.seconds, 3),
                "peak_rss_mb": _peak_rss_mb()}


def _peak_rss_mb() -> float | None:
    """This process's peak resident memory, MB (None where the system does not say: Windows)."""
    try:
        import resource
    except ImportError:
        return None
    peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    return round(peak / (1 << 20 if sys.platform == "darwin" else 1 << 10), 1)  # macOS: bytes; Linux: kB


def _wanted_rates(opts: LiveOptions) -> dict[str, float]:
    imu = opts.run.imu if opts.run.imu in IMU_MESSAGES else "RAW_IMU"
    return {imu: opts.imu_rate, "ATTITUDE": min(opts.imu_rate, 50.0), "GPS_RAW_INT": 5.0,
            "SCALED_PRESSURE": min(opts.imu_rate, 10.0)}


def run_live(opts: LiveOptions, stop=lambda: False, status=None, say=None) -> LiveResult:
    """Run a session until a signal, ``opts.duration`` or ``stop()``. ``status``: a
    ``display.StatusLine`` (default one on stderr); ``say``: where lines go (default status)."""
    from ..view.live import StatusLine

    status = status or StatusLine()
    session = _Session(opts, status, say or status.message)
    # What is loaded by now (modules, compiled kernels) lives as long as the session: out of the
    # garbage collector's full passes, which otherwise walk it all now and then, long enough
    # for a fast link to overflow the receive buffer
    gc.collect()
    gc.freeze()
    signalled = []
    previous = {}
    if threading.current_thread() is threading.main_thread():
        for sig in (signal.SIGINT, signal.SIGTERM, signal.SIGHUP):
            previous[sig] = signal.signal(sig, lambda signum, frame: signalled.append(signum))
    ended_by = "stop"
    try:
        session.say(f"listening on {opts.url}" + (f", recording to {opts.record}" if opts.record else "")
                    + "; waiting for a vehicle's HEARTBEAT (Ctrl-C to stop)")
        granted = receive_buffer(session.conn)
        if granted is not None and granted < UDP_RECEIVE_BUFFER:
            session.say(f"receive buffer {granted / 1024:.0f} KB ({UDP_RECEIVE_BUFFER >> 20} MB asked; the system "
                        "allows no more: sysctl net.core.rmem_max): a stall of the session may drop packets")
        if not opts.sink:
            session.say("no Rerun viewer: add --spawn, --connect URL or --web to watch, or --rrd FILE")
        while True:
            if signalled:
                ended_by = "signal"
                break
            if opts.duration is not None and time.monotonic() - session.start >= opts.duration:
                ended_by = "duration"
                break
            if stop():
                break
            cycle_start = time.monotonic()
            got = session.receive(MAX_BATCH)
            session.periodic(time.monotonic())
            if got == 0:
                wait_readable(session.conn, 0.005)
            elif got < MAX_BATCH:  # drained: let packets gather a moment, for fewer and larger steps
                rest = CYCLE_S - (time.monotonic() - cycle_start)
                if rest > 0:
                    time.sleep(rest)
        drain_until = time.monotonic() + DRAIN_S
        while session.receive(MAX_BATCH) == MAX_BATCH and time.monotonic() < drain_until:
            pass  # what is still in the socket: record it too
    finally:
        for sig, handler in previous.items():
            signal.signal(sig, handler)
        session.close()
        gc.unfreeze()
    return session.finish(ended_by)


class _Session:
    """The state of one ``run_live``: the link, the recording, the estimation, the view."""

    def __init__(self, opts: LiveOptions, status, say):
        self.opts = opts
        self.status = status
        self.say = say
        self.conn = open_link(opts.url, opts.baud)
        self.datagrams = is_datagram_link(self.conn)  # each read a whole datagram (UDP)
        self.recorder = TlogRecorder(opts.record) if opts.record else None
        self.monitor = LinkMonitor(timeout_s=opts.timeout)
        self.est = LiveEstimation(opts.run, record_latency=opts.record_latency, params_asked=opts.request,
                                  history_s=max(HISTORY_S, 2 * opts.window), errors_for_view=bool(opts.sink))
        self.rec = self.live_view = None
        if opts.sink:
            from ..view.sink import open_sink
            from ..view.live import LiveView
            self.rec = open_sink(opts.sink, "mavattitude", f"live {opts.url}")
            self.live_view = LiveView(self.rec, self.est, opts.window, to_file=opts.sink.kind == "rrd")
        self.start = time.monotonic()
        # a listen-only session stays silent, but an outgoing UDP link must speak to be heard
        self.talk = opts.request or opts.url.startswith("udpout:")
        self.heartbeat_at = -math.inf
        self.vehicle: tuple[int, int] | None = None
        self.firmware: str | None = None
        self.requester: RateRequester | None = None
        self.requested_at: float | None = None
        self.rates_reported = False
        self.next_tick = self.start
        self.last_wait_note = self.start
        self.events_shown = 0
        self.before_vehicle: deque = deque(maxlen=BEFORE_VEHICLE_PACKETS)  # (message, arrival)
        self.kernel_drops: int | None = None  # read as the link closes
        self.others: set = set()  # (sysid, compid) of other senders, said once each
        self._parsed: deque = deque()  # decoded, not yet handled (a datagram can hold several)
        self.found_at: float | None = None
        self.firmware_said = False

    def receive(self, limit: int) -> int:
        """Handle up to ``limit`` packets waiting on the link, then step the estimators.
        Returns how many packets there were."""
        got = 0
        fresh = False
        opts, est = self.opts, self.est
        while got < limit:
            msg = self._next_message()
            if msg is None:
                break
            got += 1
            now = time.monotonic()
            self.monitor.count(msg, now)
            if is_corrupt(msg):
                continue
            name = msg.get_type()
            if self.recorder is not None:
                self.recorder.write(msg.get_msgbuf())
            src = (msg.get_srcSystem(), msg.get_srcComponent())
            if self.vehicle is None:
                if not (name == "HEARTBEAT" and msg.autopilot != mavlink2.MAV_AUTOPILOT_INVALID
                        and msg.type not in NOT_VEHICLES and (opts.sysid is None or src[0] == opts.sysid)):
                    self.before_vehicle.append((msg, now))
                    continue
                self._found_vehicle(msg, now)
                self._catch_up()
            if src != self.vehicle:
                if src not in self.others:
                    self.others.add(src)
                    self.say(f"also on the link: system {src[0]} component {src[1]} ({name}); ignored"
                             + ("" if self.opts.sysid is not None else ", --sysid to choose another vehicle"))
                continue
            self.monitor.heard(msg, now)
            if self.requester is not None:
                self.requester.on_message(msg, now)
            segments = len(est.segments)
            est.add(msg, now)
            if len(est.segments) != segments:  # a reboot: sequence numbers and stream rates start again
                self.monitor.forget_sequences(since=now - 0.5)
                self._ask(now)
            fresh = True
            if name in ("STATUSTEXT", "AUTOPILOT_VERSION"):
                self.firmware = identify_vehicle(est.decoder.texts)[1] or self.firmware
        if fresh:
            chunk = est.step()
            if chunk is not None and self.live_view is not None:
                self.live_view.push(chunk)
        return got

    def _next_message(self):
        """The next packet of the link, decoded, or None when none is waiting. pymavlink parses
        and decodes, but its bookkeeping of every message (a copy of each, per type) is left
        out: a quarter of the time a packet took."""
        while not self._parsed:
            try:
                data = self.conn.recv(self.conn.mav.bytes_needed())
            except (ConnectionError, OSError):
                data = b""  # a TCP peer went away: TcpReconnect takes over; keep listening
            parsed = self.conn.mav.parse_buffer(data)  # every packet the bytes complete
            if self.datagrams and data and drop_cut_frame(self.conn.mav):
                self.monitor.cut_frame()
            if not parsed:
                return None
            self._parsed.extend(parsed)
        return self._parsed.popleft()

    def _catch_up(self) -> None:
        """Estimate what the vehicle sent before its first HEARTBEAT, as a log reader does:
        from its first message that says it is the vehicle (``readers.tlog.is_vehicle``)."""
        started = False
        for msg, at in self.before_vehicle:
            if (msg.get_srcSystem(), msg.get_srcComponent()) != self.vehicle:
                continue
            started = started or is_vehicle(msg)
            if started:
                self.est.add(msg, at)
        self.before_vehicle.clear()

    def _found_vehicle(self, heartbeat, now: float) -> None:
        src = heartbeat.get_srcSystem()
        self.vehicle = (src, heartbeat.get_srcComponent())
        self.found_at = now
        self.say(f"vehicle: system {src} component {self.vehicle[1]}, "
                 f"{enum_name('MAV_TYPE', heartbeat.type)} on {enum_name('MAV_AUTOPILOT', heartbeat.autopilot)}")
        self._ask(now)

    def _ask(self, now: float) -> None:
        """Ask for the firmware, the parameters a run's policy reads and the stream rates (at the start, and again
        after a reboot: rates set by SET_MESSAGE_INTERVAL do not survive one)."""
        if not self.opts.request:
            return
        request_identity(self.conn, self.vehicle, wanted_params(self.opts.run.names))
        self.requester = RateRequester(self.conn, self.vehicle, _wanted_rates(self.opts))
        self.requester.start(now)
        self.requested_at = now
        self.rates_reported = False

    def periodic(self, now: float) -> None:
        """The jobs of every TICK_S: flush, requests, link watch, messages, view, status."""
        if now < self.next_tick:
            return
        self.next_tick = now + TICK_S
        opts, est, monitor = self.opts, self.est, self.monitor
        if self.recorder is not None:
            self.recorder.tick(now)
        if self.talk and now - self.heartbeat_at >= GCS_HEARTBEAT_S:
            self.heartbeat_at = now
            try:
                self.conn.mav.heartbeat_send(mavlink2.MAV_TYPE_GCS, mavlink2.MAV_AUTOPILOT_INVALID, 0, 0,
                                             mavlink2.MAV_STATE_ACTIVE)
            except OSError:
                pass  # nobody to send to yet (a UDP listener that has not heard anyone)
        keeper = getattr(self.conn, "reconnector", None)
        if keeper is not None and keeper.tick(now):
            _session_event(est, "info", f"reconnected to {opts.url}")
        if self.requester is not None:
            self.requester.tick(now)
            while self.requester.notes:
                self.say(self.requester.notes.pop(0))
        change = monitor.check_lost(now)
        if change == "lost":
            _session_event(est, "warn", f"link lost: no packets for {opts.timeout:g} s; still listening")
        elif change == "back":
            monitor.forget_sequences()
            _session_event(est, "info", "link back: packets arriving again")
        if self.vehicle is None and now - self.last_wait_note >= WAIT_NOTE_EVERY_S:
            self.last_wait_note = now
            heard = (f"{monitor.packets} packets, none a HEARTBEAT from an autopilot"
                     + (f" with system id {opts.sysid}" if opts.sysid is not None else "")
                     if monitor.packets else "nothing received yet")
            self.say(f"still waiting for a vehicle on {opts.url} ({heard})")
        if not self.rates_reported:
            since = self.requested_at if opts.request else (monitor.first_at if est.started else None)
            if since is not None and now - since >= RATES_REPORT_AFTER_S and (
                    self.requester is None or self.requester.done):
                self.rates_reported = True
                _report_rates(est, monitor, self.requester.wanted if self.requester else {}, now)
        if self.firmware and not self.firmware_said and now - self.found_at >= FIRMWARE_WAIT_S:
            self.firmware_said = True  # once: the version and the status texts answer one after another
            self.say(f"firmware: {self.firmware}")
        self._show_events()
        if self.live_view is not None:
            self.live_view.flush(now)
        show = self.vehicle is not None and self.status.due(now)
        to_view = (self.live_view is not None and math.isfinite(est.seg.clock_max)
                   and self.live_view.status_due(now))
        if show or to_view:
            rolling = est.rolling_mae(opts.window)
            if show:
                self.status.show(_status_text(est, monitor, rolling, now, self.vehicle, opts,
                                              kernel_drops(self.conn)), now)
            if to_view:
                self.live_view.status(est.seg.clock_max, _shown_rates(est, monitor, now),
                                      monitor.lost, monitor.bad, rolling)

    def _show_events(self) -> None:
        for event in sorted(self.est.events[self.events_shown:], key=lambda e: e.t):  # in time order
            self.say(f"[{event.t:8.1f} s] " + ("warning: " if event.level == "warn" else "") + event.text)
        self.events_shown = len(self.est.events)

    def close(self) -> None:
        """Close the recording and the link (whatever happened)."""
        if self.recorder is not None:
            self.recorder.close()
        self.kernel_drops = kernel_drops(self.conn)
        close_link(self.conn)
        self.status.end()

    def finish(self, ended_by: str) -> LiveResult:
        est = self.est
        chunk = est.step(final=True)
        if chunk is not None and self.live_view is not None:
            self.live_view.push(chunk)
        self._show_events()
        if self.live_view is not None:
            from ..view.sink import close_sink
            self.live_view.flush()
            try:
                close_sink(self.rec, self.opts.sink)
            except InputError as exc:  # the metrics still count: say it and go on
                self.say(f"warning: {exc}")
        comparisons, seg = est.final_comparisons()
        ref = est.reference_series(seg) if seg is not None else None
        return LiveResult(est, self.monitor, comparisons, ref.source if ref is not None else None,
                          self.vehicle, self.firmware, self.recorder.packets if self.recorder else 0,
                          time.monotonic() - self.start, ended_by, seg.index if seg is not None else None,
                          self.kernel_drops)


def _session_event(est: LiveEstimation, level: str, text: str) -> None:
    t = est.seg.clock_max
    est.events.append(Event(t if math.isfinite(t) else 0.0, level, text))


def _shown_rates(est: LiveEstimation, monitor: LinkMonitor, now: float) -> dict[str, float]:
    rates = monitor.rates(now)
    imu = est.seg.imu_key or next((n for n in IMU_MESSAGES if n in rates), None)
    out = {}
    if imu is not None:
        out[imu.split("[")[0]] = rates.get(imu.split("[")[0], 0.0)
    for name in ("ATTITUDE", "GPS_RAW_INT", "SCALED_PRESSURE"):
        if name in rates:
            out[name] = rates[name]
    return out


def _report_rates(est: LiveEstimation, monitor: LinkMonitor, wanted: dict[str, float], now: float) -> None:
    rates = monitor.rates(now)
    parts = []
    for name in dict.fromkeys(list(wanted) + [n for n in IMU_MESSAGES if n in rates]
                              + ["ATTITUDE", "GPS_RAW_INT", "SCALED_PRESSURE"]):
        if name in rates or name in wanted:
            asked = f" (asked {wanted[name]:g})" if name in wanted else ""
            parts.append(f"{name} {rates.get(name, 0.0):.1f} Hz{asked}")
    _session_event(est, "info", "arriving: " + ", ".join(parts))
    imu = next((n for n in list(wanted) + list(IMU_MESSAGES) if n in IMU_MESSAGES and rates.get(n)), None)
    if imu is None:
        _session_event(est, "warn", "no IMU message is arriving (RAW_IMU, SCALED_IMU*, HIGHRES_IMU): "
                                    "nothing to estimate from")
        return
    rate = rates[imu]
    if imu in wanted and rate < 0.8 * wanted[imu]:
        _session_event(est, "warn", f"the vehicle sends {imu} at {rate:.1f} Hz, not the {wanted[imu]:g} Hz asked")
    if rate < COARSE_RATE_HZ:
        _session_event(est, "warn", f"IMU rate {rate:.1f} Hz is too low for good estimates (want ≥ "
                                    f"{COARSE_RATE_HZ:.0f} Hz; raise the stream rate, or use --imu-rate)")


def loss_text(monitor: LinkMonitor, samples, drops: int | None) -> str:
    """'lost 3 packets by sequence number, 250 IMU samples by clock (1.2 %), 0 dropped by the
    system, bad 0': the sequence number misses bursts of 128 and more, the clock does not.
    Frames cut short at a datagram's end are bad data, said apart: '(2 frames cut short)'."""
    parts = [f"lost {monitor.lost} packets by sequence number"]
    if samples is not None:
        parts.append(f"{samples.lost} IMU samples by clock ({samples.percent:.1f} %)")
    if drops is not None:
        parts.append(f"{drops} dropped by the system")
    cut = f" ({monitor.cut_frames} frame{'s' if monitor.cut_frames != 1 else ''} cut short)" if monitor.cut_frames else ""
    return ", ".join(parts) + f", bad {monitor.bad}{cut}"


def _status_text(est: LiveEstimation, monitor: LinkMonitor, rolling: dict, now: float, vehicle, opts,
                 drops: int | None = None) -> str:
    if vehicle is None:
        return f"waiting for a vehicle on {opts.url} ({monitor.packets} packets)"
    link = "LINK LOST" if monitor.lost_since is not None else "link ok"
    t = est.seg.clock_max
    rates = _shown_rates(est, monitor, now)
    rate_text = ", ".join(f"{n} {r:.0f} Hz" for n, r in rates.items())
    parts = [f"t {t:7.1f} s" if math.isfinite(t) else "t -", link, rate_text,
             loss_text(monitor, est.samples_lost, drops)]
    if rolling:
        parts.append(f"MAE {opts.window:g} s r/p/y: " + "; ".join(
            f"{n} {r:.2f}/{p:.2f}/{y:.2f}" for n, (r, p, y) in rolling.items()))
    elif not est.started:
        parts.append("estimators starting" if est.seg.imu else "no IMU data yet")
    return " | ".join(parts)


def check_ended_with_vehicle(result: LiveResult, url: str) -> None:
    """A session that never heard the vehicle ends as a bad input (exit 1), not a success."""
    if result.vehicle is None:
        raise InputError(url, f"no vehicle heard in {result.seconds:.0f} s "
                              f"({result.monitor.packets} packets, none a HEARTBEAT from an autopilot)")

