"""``mavattitude live`` on loopback UDP, against two independent sources: the project's simulated
autopilot (``sim.autopilot``, which honours rate requests) and pymavlink's own mavplayback.py
replaying a real SITL .tlog. Also: the recording holds exactly the packets sent (also after
SIGINT mid-stream), corrupt data between packets, a sender that stops and comes back, a
vehicle reboot, and the link's bookkeeping on its own."""
from __future__ import annotations

import math
import os
import random
import signal
import socket
import subprocess
import sys
import threading
import time
from dataclasses import fields, replace
from pathlib import Path

import numpy as np
import pytest
from pymavlink import mavutil

from mavattitude.cli import main
from mavattitude.growing import Growing
from mavattitude.core.policy import RunOptions
from mavattitude.live import LiveOptions, run_live
from mavattitude.live.link import LinkMonitor, RateRequester, mavlink2, open_link
from mavattitude.live.recorder import TlogRecorder
from mavattitude import quaternion as quat
from conftest import installed_estimators
from mavattitude.phase import PhaseTracker
from mavattitude.commands.replay import run_replay
from mavattitude.readers import read_log
from mavattitude.sim import simulate
from mavattitude.sim.autopilot import SimAutopilot

ROOT = Path(__file__).resolve().parents[1]
SHARED = ROOT.parent / "shared" / "logs"


def free_udp_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


class Tap:
    """A pymavlink connection that remembers every packet written, and can slip corrupt data
    in between (``garbage_every``: a random-byte datagram and a packet with a broken CRC)."""

    def __init__(self, conn, garbage_every: int = 0, seed: int = 0):
        self.conn = conn
        self.sent: list[bytes] = []
        self.garbage_every = garbage_every
        self.garbage_sent = 0
        self.rng = random.Random(seed)

    def write(self, packet: bytes) -> None:
        self.conn.write(packet)
        self.sent.append(bytes(packet))
        if self.garbage_every and len(self.sent) % self.garbage_every == 0:
            noise = bytes(self.rng.choice([b for b in range(256) if b not in (0xFD, 0xFE)])
                          for _ in range(self.rng.randint(1, 40)))
            broken = bytearray(packet)
            broken[10] ^= 0x5A  # a payload byte: the CRC no longer matches
            for data in (noise, bytes(broken)):
                self.conn.port.sendto(data, self.conn.destination_addr)
                self.garbage_sent += 1

    def recv_msg(self):
        return self.conn.recv_msg()

    def close(self):
        self.conn.close()


def sender(port: int, plan, sim, garbage_every: int = 0, tap_class=None):
    """A thread running ``plan(autopilot, tap)`` against udpout:127.0.0.1:port; returns
    (thread, tap, holder) where holder["done"] is set at the end."""
    tap = (tap_class or Tap)(open_link(f"udpout:127.0.0.1:{port}"), garbage_every)
    holder = {"done": False, "error": None}

    def run():
        try:
            time.sleep(0.3)  # the listener is bound before this starts; let it settle
            plan(SimAutopilot(sim, tap), tap)
        except Exception as exc:  # reported by the test
            holder["error"] = exc
        finally:
            holder["done_at"] = time.monotonic()  # before "done": the stop test reads both
            holder["done"] = True

    thread = threading.Thread(target=run, daemon=True)
    return thread, tap, holder


RUN_FIELDS = {f.name for f in fields(RunOptions)}
# times real time the simulated autopilot streams at: what is checked is on its clock (rates,
# gaps, reboots), or packet for packet; wall time only for the link-lost watch (its own sleeps)
SPEED = 8.0


def listen(port: int, thread, holder, tmp_path, **options):
    """Run a live session until the sender is done (and a moment more); returns the result."""
    run = {k: options.pop(k) for k in list(options) if k in RUN_FIELDS}  # what to estimate, as replay takes it
    opts = LiveOptions(**{"url": f"udpin:127.0.0.1:{port}", "record": str(tmp_path / "live.tlog"),
                          "timeout": 1.0, "run": RunOptions(**{"names": ["mahony"], **run}), **options})
    lines = []

    def say(line):  # the first line comes once the port is bound: start sending then
        if not lines:
            thread.start()
        lines.append(line)
    result = run_live(opts, stop=lambda: time.monotonic() - holder.get("done_at", math.inf) > 0.5,
                      say=say)
    thread.join(5)
    assert holder["error"] is None, holder["error"]
    result.lines = lines
    return result


ALL = installed_estimators()  # the filters from other projects too: live equals replay for them as well


def assert_live_equals_replay(est, segment, comparisons, recording, names, reference="autopilot"):
    """A live session's estimates (the last of them it keeps) equal those of ``replay`` of its
    own recording (the same IMU source: live chooses it from its first seconds, replay from the
    whole log), and so do its final metrics (the quantiles within the running sketch's 0.1 %)."""
    seg = est.segments[segment]
    flight = read_log(str(recording))
    # the recording's other attitude streams too (mavplayback forwards AHRS2/AHRS3): live
    # decodes them and runs replay's reference checks with them
    replay = run_replay(flight, names, reference=reference, imu=seg.imu_key)
    if seg.check is not None or replay.suspects:
        assert seg.check.suspects == replay.suspects
    for name in names:
        live, again = est.estimate_series(name, seg), replay.estimates[name]
        start = int(np.searchsorted(again.t, live.t[0]))
        again_t, again_q = again.t[start:start + len(live.t)], again.q[start:start + len(live.t)]
        assert len(live.t) > 100 and np.array_equal(live.t, again_t), name
        angle = 2 * np.arcsin(np.clip(np.linalg.norm(quat.multiply(quat.conjugate(again_q), live.q)[:, 1:], axis=1),
                                      0, 1))
        assert angle.max() <= 1e-9, (name, angle.max())
    assert list(comparisons) == list(replay.comparisons)
    for name, c in comparisons.items():
        for axis in ("roll", "pitch", "yaw"):
            a, b = c.axes[axis], replay.comparisons[name].axes[axis]
            # (the reference checks may leave most of a short recording out: sitl-quadplane-vtol's AHRS3)
            assert a.n == b.n > 0 and a.n + c.n_excluded > 100, (name, axis)
            assert a.mae == pytest.approx(b.mae, abs=1e-9), (name, axis)
            assert a.max == pytest.approx(b.max, abs=1e-9) and a.sigma3 == pytest.approx(b.sigma3, rel=1e-3)
        assert c.n_excluded == replay.comparisons[name].n_excluded, name
    return replay


def recorded_packets(path) -> list[bytes]:
    """The raw packets of a .tlog, as pymavlink reads them back."""
    log = mavutil.mavlink_connection(str(path), robust_parsing=True)
    out = []
    while True:
        msg = log.recv_msg()
        if msg is None:
            return out
        if msg.get_type() != "BAD_DATA":
            out.append(bytes(msg.get_msgbuf()))


@pytest.fixture(scope="module")
def flight():
    return simulate("figure8", 40.0, seed=7, imu_rate=100.0)


# ---------------------------------------------------------------- against the simulator


@pytest.mark.slow
def test_live_against_the_simulator_matches_replay_of_the_same_data(tmp_path, flight):
    port = free_udp_port()
    thread, tap, holder = sender(port, lambda ap, tap: ap.serve(speed=SPEED), flight)
    result = listen(port, thread, holder, tmp_path, names=ALL, reference="truth")
    est = result.estimation
    assert result.vehicle == (1, 1) and result.ended_by == "stop"
    assert est.samples > 1800 and result.comparisons["mahony"].axes["roll"].n > 1000
    # the requests were honoured: 50 Hz IMU and ATTITUDE (SIMSTATE with it), 5 Hz GPS, on the
    # autopilot's clock, from a 10 Hz default
    seg = est.seg
    late = seg.imu["RAW_IMU"].column(0) > 10.0
    assert np.median(np.diff(seg.imu["RAW_IMU"].column(0)[late])) == pytest.approx(0.02, abs=1e-6)
    assert np.median(np.diff(seg.att["autopilot"].column(0)[-100:])) == pytest.approx(0.02, abs=1e-6)
    assert np.median(np.diff(seg.gps.column(0)[-20:])) == pytest.approx(0.2, abs=1e-6)
    assert any("acknowledged" in line for line in result.lines)
    # every packet sent is in the recording, byte for byte, in order
    assert recorded_packets(tmp_path / "live.tlog") == tap.sent
    # replaying that recording gives the same estimates, to the bit
    assert_live_equals_replay(result.estimation, result.segment, result.comparisons, tmp_path / "live.tlog", ALL,
                              reference="truth")
    assert result.comparisons["cpf-ekf"].axes["roll"].mae < 0.3


@pytest.mark.slow
def test_corrupt_data_between_packets_is_counted_and_never_recorded(tmp_path, flight):
    port = free_udp_port()
    thread, tap, holder = sender(port, lambda ap, tap: ap.serve(speed=SPEED, t_to=20.0), flight, garbage_every=25)
    result = listen(port, thread, holder, tmp_path)
    assert tap.garbage_sent > 100
    assert result.monitor.bad >= tap.garbage_sent // 2  # every broken packet, the noise in runs
    assert recorded_packets(tmp_path / "live.tlog") == tap.sent
    assert result.monitor.lost == 0
    assert result.comparisons["mahony"].axes["roll"].mae < 2.0


class CuttingTap(Tap):
    """A tap that sends, every ``EVERY`` packets, a frame cut short at the end of a datagram:
    alone, or after the packet in the same datagram. No later datagram can complete it."""
    EVERY = 40

    def __init__(self, conn, garbage_every: int = 0):
        super().__init__(conn, garbage_every)
        self.cut_sent = 0

    def write(self, packet: bytes) -> None:
        if len(self.sent) % self.EVERY or len(packet) < 12:
            return super().write(packet)
        cut = packet[:self.rng.randint(1, len(packet) - 1)]  # from the magic byte on: a frame begun
        together = self.cut_sent % 2 == 0
        self.conn.port.sendto(packet + cut if together else cut, self.conn.destination_addr)
        if not together:
            self.conn.write(packet)
        self.sent.append(bytes(packet))
        self.cut_sent += 1


@pytest.mark.slow
def test_a_frame_cut_short_in_a_datagram_costs_no_valid_packet(tmp_path, flight):
    """UDP delivers whole datagrams: a frame cut short at the end of one is dropped there and
    counted, and every valid packet after it is decoded and recorded, none counted as lost."""
    port = free_udp_port()
    thread, tap, holder = sender(port, lambda ap, tap: ap.serve(speed=SPEED, t_to=20.0), flight,
                                 tap_class=CuttingTap)
    result = listen(port, thread, holder, tmp_path)
    assert tap.cut_sent > 50
    assert recorded_packets(tmp_path / "live.tlog") == tap.sent
    assert result.monitor.packets == len(tap.sent) and result.monitor.lost == 0
    assert result.monitor.cut_frames == result.monitor.bad == tap.cut_sent
    assert result.link()["cut_frames"] == tap.cut_sent
    assert result.comparisons["mahony"].axes["roll"].n > 300


def test_a_datagram_boundary_drops_the_frame_cut_short_before_it():
    """pymavlink's parser alone would complete a cut frame with the next datagram's bytes."""
    from mavattitude.live.link import drop_cut_frame

    mav = mavlink2.MAVLink(None, 1, 1)
    packets = [bytes(mavlink2.MAVLink_heartbeat_message(2, 3, 0, 0, 4, 3).pack(mav)) for _ in range(3)]
    datagrams = [packets[0] + packets[1][:9], packets[1], packets[2][:5], packets[2]]
    parser = mavlink2.MAVLink(None)
    parser.robust_parsing = True
    got, cut = [], 0
    for datagram in datagrams:
        got += [bytes(m.get_msgbuf()) for m in parser.parse_buffer(datagram) or [] if m.get_type() != "BAD_DATA"]
        cut += drop_cut_frame(parser)
    assert got == [packets[0], packets[1], packets[2]] and cut == 2
    assert not drop_cut_frame(parser)


@pytest.mark.slow
def test_a_sender_that_stops_and_comes_back(tmp_path, flight):
    """The vehicle goes silent for 2 s of wall time, and 3 s of its clock pass meanwhile: the
    link is reported lost and back, and the estimators start again after the gap."""
    def plan(ap, tap):
        ap.serve(speed=SPEED, t_to=15.0)
        time.sleep(2.0)
        ap.serve(speed=SPEED, t_from=18.0, t_to=30.0)
    port = free_udp_port()
    thread, tap, holder = sender(port, plan, flight)
    result = listen(port, thread, holder, tmp_path)
    texts = [e.text for e in result.estimation.events]
    assert any(t.startswith("link lost") for t in texts) and any(t.startswith("link back") for t in texts)
    assert any(t.startswith("IMU gap of 3.0 s") for t in texts)
    seg = result.estimation.seg
    assert seg.runner.restarts and 17.9 < seg.runner.restarts[0][0] < 18.1
    q = result.estimation.estimate_series("mahony").q
    assert np.isfinite(q).all() and result.estimation.estimate_series("mahony").t[-1] > 29.0
    assert recorded_packets(tmp_path / "live.tlog") == tap.sent


@pytest.mark.slow
def test_a_vehicle_reboot_starts_a_new_clock_segment(tmp_path, flight):
    """The autopilot reboots: its clock starts again near zero and its sequence numbers too."""
    def plan(ap, tap):
        ap.serve(speed=SPEED, t_to=16.0)
        SimAutopilot(flight, tap).serve(speed=SPEED, t_to=12.0)  # the same vehicle, booted again
    port = free_udp_port()
    thread, tap, holder = sender(port, plan, flight)
    result = listen(port, thread, holder, tmp_path)
    est = result.estimation
    assert any("clock went back" in e.text for e in est.events)
    assert len(est.segments) == 2 and all(s.runner is not None and s.runner.done for s in est.segments)
    assert result.segment == 0  # the longer one is scored
    assert est.estimate_series("mahony", est.segments[1]).t[-1] < 12.5
    assert result.monitor.lost == 0  # a restarted sequence is not a loss
    assert recorded_packets(tmp_path / "live.tlog") == tap.sent


@pytest.mark.slow
@pytest.mark.parametrize("signum", [signal.SIGINT, signal.SIGTERM])
def test_a_signal_mid_stream_ends_cleanly_with_a_complete_recording(tmp_path, flight, signum):
    """``mavattitude live`` in its own process, interrupted (Ctrl-C, or a service manager's
    SIGTERM) while packets flow: exit 0, final metrics printed, and the .tlog holds every
    packet it received, in order, up to the last."""
    port = free_udp_port()
    record = tmp_path / "sigint.tlog"
    proc = subprocess.Popen([sys.executable, "-m", "mavattitude", "live", f"udpin:127.0.0.1:{port}",
                             "--record", str(record), "--timeout", "1"],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, cwd=tmp_path)
    try:
        deadline = time.monotonic() + 120
        while not record.exists():  # bound and recording (after the first-run compile)
            assert proc.poll() is None and time.monotonic() < deadline, proc.communicate()
            time.sleep(0.1)
        sent_at_signal = {}

        def plan(ap, tap):
            def stop():
                if len(tap.sent) > 1500 and not sent_at_signal:
                    sent_at_signal["n"] = len(tap.sent)
                    proc.send_signal(signum)
                return proc.poll() is not None
            ap.serve(speed=SPEED, stop=stop)
        thread, tap, holder = sender(port, plan, flight)
        thread.start()
        out, err = proc.communicate(timeout=60)
        thread.join(10)
    finally:
        if proc.poll() is None:
            proc.kill()
    assert proc.returncode == 0, err
    assert "final metrics" in out and "mahony" in out and "Traceback" not in err
    packets = recorded_packets(record)
    assert len(packets) >= sent_at_signal["n"]  # nothing sent before the signal is missing
    assert packets == tap.sent[:len(packets)]
    assert f"{len(packets)} packets recorded" in out


# ---------------------------------------------------------------- against pymavlink's mavplayback.py


@pytest.mark.slow
def test_live_against_mavplayback_of_a_shared_sitl_log(tmp_path, monkeypatch):
    """9 s at 8x (some 70 s of the log); mavplayback answers no request: each rate request given up
    after two tries of 0.3 s (1 s in use), then the fallback. The log's 4.2 Hz IMU arrives at some
    34 Hz at 8x: the low-rate warning's limit is raised to 8x its 20 Hz to match."""
    from mavattitude.live import link, session

    log = SHARED / "sitl-quadplane-vtol.tlog"
    if not log.exists():
        pytest.skip(f"real log {log.name} not found in {SHARED} (it lives beside the project, not in it)")
    monkeypatch.setattr(link, "ACK_TIMEOUT_S", 0.3)
    monkeypatch.setattr(session, "COARSE_RATE_HZ", 8 * session.COARSE_RATE_HZ)
    port = free_udp_port()
    script = Path(mavutil.__file__).parent / "tools" / "mavplayback.py"
    env = {**os.environ, "PYTHONPATH": str(ROOT / "tests" / "tkstub"), "MAVPLAYBACK_SPEED": "8",
           "MAVPLAYBACK_SECONDS": "9"}
    holder = {"done": False}

    def play():
        # mavplayback is a Tk program: tests/tkstub stands in for tkinter (headless)
        subprocess.run([sys.executable, str(script), "--out", f"127.0.0.1:{port}", str(log)], env=env,
                       cwd=tmp_path, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, timeout=60)
        holder["done_at"] = time.monotonic()
        holder["done"] = True
        holder["error"] = None
    result = listen(port, threading.Thread(target=play, daemon=True), holder, tmp_path, names=ALL)
    est = result.estimation
    assert result.vehicle == (1, 1) and result.firmware
    assert_live_equals_replay(result.estimation, result.segment, result.comparisons, tmp_path / "live.tlog", ALL)
    assert est.samples > 100 and "RAW_IMU" in est.seg.imu
    assert any("falling back to REQUEST_DATA_STREAM" in line for line in result.lines)  # it cannot answer
    assert any("IMU rate" in e.text and "too low" in e.text for e in est.events)
    c = result.comparisons["mahony"]
    # (how many are scored before the span depends on how soon the estimators start: the machine's load)
    assert c.axes["roll"].n + c.n_excluded > 50 and c.axes["roll"].mae < 10.0
    # the log's ATTITUDE (SITL) and AHRS3 (EKF2) disagree from 608.6 s, and again later (how many
    # of its five spans the play reaches depends on the machine's load): flagged live as by replay
    assert est.suspects and all(s.kind == "autopilot disagrees" and "AHRS3 (EKF2)" in s.detail for s in est.suspects)
    assert len(recorded_packets(tmp_path / "live.tlog")) == result.recorded > 1000


# ---------------------------------------------------------------- the command's errors


def test_port_in_use_is_a_one_line_error(capsys):
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
        rc = main(["live", f"udpin:127.0.0.1:{port}", "--no-record", "--duration", "1"])
    err = capsys.readouterr().err.strip().splitlines()
    assert rc == 1 and err[-1] == f"mavattitude: error: udpin:127.0.0.1:{port}: port already in use " \
                                  "(another program is listening there)"


def test_no_vehicle_heard_is_an_error(capsys, tmp_path):
    rc = main(["live", f"udpin:127.0.0.1:{free_udp_port()}", "--no-record", "--duration", "0.5"])
    assert rc == 1 and "no vehicle heard" in capsys.readouterr().err


@pytest.mark.parametrize("args, text", [
    (["--imu-rate", "0"], "argument --imu-rate: expected a number above 0"),
    (["--estimators", "nope"], "unknown estimator"),
    (["notaurl:x:y:z"], "not a MAVLink connection string"),
])
def test_usage_errors(capsys, args, text):
    rc = main(["live", "--no-record", "--duration", "0.2"] + args)
    err = capsys.readouterr().err
    assert rc == 2 and text in err and len(err.strip().splitlines()) == 1


def test_simulate_live_needs_a_url_or_a_file(capsys):
    assert main(["simulate", "--duration", "1"]) == 2
    assert "--live URL" in capsys.readouterr().err


# ---------------------------------------------------------------- the pieces


class _Msg:
    def __init__(self, name, seq, src=(1, 1)):
        self.name, self.seq, self.src = name, seq, src

    def get_type(self):
        return self.name

    def get_seq(self):
        return self.seq

    def get_srcSystem(self):
        return self.src[0]

    def get_srcComponent(self):
        return self.src[1]


def test_link_monitor_counts_losses_per_sender_and_link_loss():
    m = LinkMonitor(timeout_s=1.0)
    for i, seq in enumerate([250, 251, 253, 254, 0, 1]):  # 252 and 255 missing, wrapping
        m.count(_Msg("RAW_IMU", seq), 10.0 + 0.01 * i)
    m.count(_Msg("HEARTBEAT", 7, src=(255, 190)), 10.1)  # another sender: its own count
    m.count(_Msg("BAD_DATA", 0), 10.1)
    assert (m.lost, m.packets, m.bad) == (2, 7, 1)
    m.count(_Msg("RAW_IMU", 90), 10.2)  # a jump of 88: that many lost
    assert m.lost == 90
    m.count(_Msg("RAW_IMU", 90), 10.21)  # repeated: a jump back, not 255 lost
    m.count(_Msg("RAW_IMU", 89), 10.22)  # reordered: likewise
    m.count(_Msg("RAW_IMU", 91), 10.23)
    assert m.lost == 90
    m.count(_Msg("RAW_IMU", 3), 10.3)  # a sender that restarted: confirmed by the next packet
    m.count(_Msg("RAW_IMU", 4), 10.31)
    m.count(_Msg("RAW_IMU", 6), 10.32)
    assert m.lost == 91
    m.count(_Msg("RAW_IMU", 200), 12.0)  # heard again after a silence: a new count
    assert m.lost == 91
    m.count(_Msg("RAW_IMU", 205), 12.1)  # 4 lost, then a reboot noticed a moment later
    m.forget_sequences(since=12.05)
    assert m.lost == 91
    # rates and the link-lost watch follow the vehicle only
    for k in range(30):
        m.heard(_Msg("RAW_IMU", k), 20.0 + 0.1 * k)
    assert m.rate("RAW_IMU", 23.0) == pytest.approx(10.0, abs=0.5) and m.rate("ATTITUDE", 23.0) == 0.0
    assert m.check_lost(23.5) is None and m.check_lost(24.0) == "lost" and m.check_lost(24.1) is None
    m.heard(_Msg("RAW_IMU", 31), 25.0)
    assert m.check_lost(25.0) == "back"


class _FakeMav:
    def __init__(self):
        self.calls = []

    def command_long_send(self, *args):
        self.calls.append(("command_long", args))

    def request_data_stream_send(self, *args):
        self.calls.append(("request_data_stream", args))


class _Ack:
    def __init__(self, result):
        self.command, self.result = mavlink2.MAV_CMD_SET_MESSAGE_INTERVAL, result

    def get_type(self):
        return "COMMAND_ACK"


def test_rate_requester_asks_one_at_a_time_and_falls_back():
    conn = type("Conn", (), {"mav": _FakeMav()})()
    r = RateRequester(conn, (1, 1), {"RAW_IMU": 50.0, "ATTITUDE": 50.0, "GPS_RAW_INT": 5.0})
    r.start(0.0)
    assert len(conn.mav.calls) == 1 and conn.mav.calls[0][1][4] == mavlink2.MAVLINK_MSG_ID_RAW_IMU
    assert conn.mav.calls[0][1][5] == pytest.approx(20000.0)  # µs
    r.on_message(_Ack(mavlink2.MAV_RESULT_ACCEPTED), 0.1)
    r.on_message(_Ack(mavlink2.MAV_RESULT_DENIED), 0.2)  # ATTITUDE refused
    r.tick(1.0)  # GPS_RAW_INT unanswered for 0.8 s: not yet
    r.tick(1.3)  # resent
    r.tick(2.4)  # given up
    assert r.done
    fallback = [c[1] for c in conn.mav.calls if c[0] == "request_data_stream"]
    assert sorted(f[2] for f in fallback) == sorted([mavlink2.MAV_DATA_STREAM_EXTRA1,
                                                     mavlink2.MAV_DATA_STREAM_EXTENDED_STATUS])
    assert any("DENIED" in n for n in r.notes) and any("no answer" in n for n in r.notes)


def test_recorder_flushes_within_a_second(tmp_path):
    rec = TlogRecorder(tmp_path / "r.tlog")
    rec.write(b"\xfd" + bytes(20), unix_time=1.5)
    rec.tick(time.monotonic() + 1.0)
    assert (tmp_path / "r.tlog").stat().st_size == 29
    assert (tmp_path / "r.tlog").read_bytes()[:8] == (1_500_000).to_bytes(8, "big")
    rec.close()


def test_phase_tracker_follows_a_take_off_and_landing_causally():
    t = np.arange(0.0, 60.0, 0.1)
    h = np.interp(t, [0, 10, 15, 40, 45, 60], [0, 0, 10, 10, 0, 0])
    h = h + np.random.default_rng(0).normal(0, 0.3, len(t)) + 480.0
    p = PhaseTracker("baro height")
    for chunk in np.array_split(np.arange(len(t)), 37):
        p.add(t[chunk], h[chunk])
    air = p.on_clock(np.array([5.0, 11.0, 14.0, 30.0, 44.0, 50.0, 80.0]))
    np.testing.assert_array_equal(air[:-1], [0.0, 0.0, 1.0, 1.0, 1.0, 0.0])
    assert np.isnan(air[-1])  # stale


def test_growing_views_survive_growth():
    g = Growing(2, capacity=2)
    g.append((1.0, 2.0))
    first = g.view()
    for i in range(10):
        g.append((float(i), 0.0))
    g.extend(np.ones((5, 2)))
    assert len(g) == 16 and first.tolist() == [[1.0, 2.0]] and g.last.tolist() == [1.0, 1.0]


def test_growing_forgets_its_oldest_rows_in_bounded_storage():
    """A window kept for hours: forgetting keeps the newest rows, the views taken before stay
    as they were, and the storage stays within a few times the window."""
    g = Growing(1)
    taken = []
    for i in range(200):
        g.extend(np.arange(i * 100, (i + 1) * 100, dtype=float))
        taken.append((g.view(), g.view().copy()))
        g.forget(g.n - 500)  # keep the last 500 rows
        assert g.column(0).tolist() == list(range((i + 1) * 100 - min(500, (i + 1) * 100), (i + 1) * 100))
    assert g.forgotten == 19_500 and g.appended == 20_000 and g.last[0] == 19_999
    assert all(np.array_equal(view, copy) for view, copy in taken)
    assert len(g._data) <= 2_000


# ---------------------------------------------------------------- what a real link does


def _feed(est, path, edit=lambda msg: msg, every=7):
    """Feed a .tlog's vehicle messages to a LiveEstimation (``edit`` may change or drop them)."""
    log = mavutil.mavlink_connection(str(path), robust_parsing=True)
    n = 0
    while (msg := log.recv_msg()) is not None:
        if msg.get_type() == "BAD_DATA" or msg.get_srcSystem() != 1:
            continue
        msg = edit(msg)
        if msg is not None:
            est.add(msg)
            n += 1
            if n % every == 0:
                est.step()
    est.step()
    return est


@pytest.mark.slow  # 5 s each: a session stepped packet by packet
@pytest.mark.parametrize("reference", ["autopilot", "truth"])
def test_a_session_keeps_only_its_last_seconds_and_scores_as_replay(monkeypatch, reference):
    """Constant memory: a session keeping 2 s of history, forgetting and scoring often,
    estimates what replay of the same packets does, to the bit, and its final metrics
    (scored as it went) are replay's."""
    from mavattitude.live import estimation
    from mavattitude.core.runner import IMU

    monkeypatch.setattr(estimation, "FORGET_EVERY_S", 0.7)
    monkeypatch.setattr(estimation, "SCORE_EVERY_S", 0.3)
    path = ROOT / "sample_logs" / "figure8.tlog"
    # a step every 21 messages (0.1 s of flight): some 1,000 steps, each forgetting or scoring
    # every few (every 7: 3,000 steps, three times the time)
    est = _feed(estimation.LiveEstimation(RunOptions(ALL, reference=reference), history_s=2.0), path, every=21)
    est.step(final=True)
    comparisons, seg = est.final_comparisons()
    runner = seg.runner
    assert runner.store[IMU].forgotten > 4500 and runner.store[IMU].n < 200  # 50 Hz: 2 s and a little
    assert all(s.forgotten > 0 for s in runner.store.values()) and seg.imu[seg.imu_key].n < 500
    assert runner._phase._rows.forgotten > 0  # the ground/air phase too
    assert list(comparisons) == ALL + (["autopilot"] if reference == "truth" else [])
    assert_live_equals_replay(est, seg.index, comparisons, path, ALL, reference=reference)


@pytest.mark.slow
def test_a_gps_that_loses_its_fix_does_not_look_like_a_reboot():
    """ArduPilot's GPS_RAW_INT carries the time of the last fix: without a fix it stops moving.
    Those samples are stale, not a clock that went back; one corrupt IMU time is no reboot
    either, and one far in the future is held, then dropped."""
    from mavattitude.live.estimation import LiveEstimation

    state = {"corrupted": 0}

    def edit(msg):
        if msg.get_type() == "GPS_RAW_INT" and msg.time_usec > 30e6:
            msg.time_usec, msg.fix_type = 30_000_000, 1  # the fix is lost at 30 s
        if msg.get_type() == "RAW_IMU" and 50e6 < msg.time_usec and state["corrupted"] < 2:
            msg.time_usec = 5_000_000 if state["corrupted"] == 0 else 900_000_000  # back, then ahead
            state["corrupted"] += 1
        return msg
    est = _feed(LiveEstimation(RunOptions(["mahony", "cpf-ekf"])), ROOT / "sample_logs" / "figure8.tlog", edit)
    assert len(est.segments) == 1 and not any("went back" in e.text for e in est.events)
    assert est.samples == est.seg.imu["RAW_IMU"].appended >= 4990  # all but the two corrupt ones
    assert est.seg.gps.column(0)[-1] <= 30.0 + 1e-9


@pytest.mark.slow
def test_imu_choice_still_waits_for_the_compass_declination():
    from mavattitude.live.estimation import LiveEstimation

    est = _feed(LiveEstimation(RunOptions(["mahony"], imu="RAW_IMU"), params_asked=True),
                ROOT / "sample_logs" / "figure8.tlog")
    start = next(e.text for e in est.events if e.text.startswith("IMU source"))
    assert "RAW_IMU at 50.0 Hz" in start
    assert any(e.text.startswith("declination 5.00° (vehicle parameter COMPASS_DEC, no COMPASS_AUTODEC") for e in est.events)
    assert not any("low IMU rate" in e.text for e in est.events)
    # the recording has neither COMPASS_AUTODEC nor a board trim: one line says so
    assert [e.text for e in est.events if "no answer" in e.text] == [
        "no answer from the vehicle within 2 s for COMPASS_AUTODEC; AHRS_TRIM_X/AHRS_TRIM_Y: going on as a log "
        "without them"]
    missing = _feed(LiveEstimation(RunOptions(["mahony"], imu="SCALED_IMU3")), ROOT / "sample_logs" / "figure8.tlog")
    assert missing.samples == 0
    assert sum("no SCALED_IMU3 samples arrive" in e.text for e in missing.events) == 1


@pytest.mark.slow
def test_a_compass_in_the_wrong_unit_is_rescaled_live(tmp_path):
    """ArduPilot 4.7 sends HIGHRES_IMU's field 1e6 times too large; replay rescales it, and so
    does live, rather than dropping every sample as implausible. (The log's first 2 MB, cut
    where a packet begins: some 60 s of flight, the estimator well under way.)"""
    log = SHARED / "sitl-copter-4.7-50hz.tlog"
    if not log.exists():
        pytest.skip(f"real log {log.name} not found in {SHARED} (it lives beside the project, not in it)")
    from mavattitude.live.estimation import LiveEstimation
    from mavattitude.readers.tlogrecords import scan

    data = log.read_bytes()
    offsets = scan(np.frombuffer(data, np.uint8), 0, ["HIGHRES_IMU"]).offsets
    prefix = tmp_path / log.name
    prefix.write_bytes(data[:int(offsets[np.searchsorted(offsets, 2_000_000)])])
    est = _feed(LiveEstimation(RunOptions(["mahony"], imu="HIGHRES_IMU")), prefix, every=50)
    assert any("HIGHRES_IMU: magnetometer strength" in e.text and "rescaled by 1e-6" in e.text
               for e in est.events)
    field = est.segments[0].mag["HIGHRES_IMU"].view()[:, 1:4]
    assert 0.2e-4 < np.median(np.linalg.norm(field, axis=1)) < 0.7e-4
    assert est.seg.mag_key == "HIGHRES_IMU" and est.has_heading["mahony"]


@pytest.mark.slow
def test_udpout_speaks_first_so_a_listening_vehicle_hears_it(tmp_path, flight):
    """An outgoing UDP link: the vehicle listens and sends only once it hears a ground station."""
    port = free_udp_port()
    vehicle = open_link(f"udpin:127.0.0.1:{port}")
    tap = Tap(vehicle)
    holder = {"done": False, "error": None}

    def run():
        try:
            SimAutopilot(flight, tap).serve(speed=SPEED, t_to=16.0)
        except Exception as exc:
            holder["error"] = exc
        finally:
            holder["done_at"], holder["done"] = time.monotonic(), True
    result = listen(port, threading.Thread(target=run, daemon=True), holder, tmp_path,
                    url=f"udpout:127.0.0.1:{port}", request=False)
    vehicle.close()
    assert result.vehicle == (1, 1) and result.estimation.samples > 100


@pytest.mark.slow
def test_a_tcp_peer_that_goes_away_and_comes_back(tmp_path, flight):
    """SITL restarted under a TCP link: the session reports the link lost, reconnects by itself,
    estimates again, and ends without a traceback."""
    port = free_udp_port()  # a free number; TCP's port space is separate but as free here
    holder = {"done": False, "error": None}

    def run():
        try:
            for t_from, t_to in ((None, 12.0), (16.0, 28.0)):
                server = mavutil.mavlink_connection(f"tcpin:127.0.0.1:{port}", source_system=1)
                deadline = time.monotonic() + 10
                while server.port is None and time.monotonic() < deadline:
                    server.recv_msg()  # accept the session's (re)connection
                    time.sleep(0.05)
                SimAutopilot(flight, server).serve(speed=SPEED, t_from=t_from, t_to=t_to)
                server.close()
                time.sleep(1.5)
        except Exception as exc:
            holder["error"] = exc
        finally:
            holder["done_at"], holder["done"] = time.monotonic(), True
    thread = threading.Thread(target=run, daemon=True)
    thread.start()
    time.sleep(0.3)  # the server listens before the session connects
    result = listen(port, threading.Thread(target=lambda: None), holder, tmp_path,
                    url=f"tcp:127.0.0.1:{port}")
    texts = [e.text for e in result.estimation.events]
    assert any(t.startswith("link lost") for t in texts) and any(t.startswith("reconnected") for t in texts)
    assert result.estimation.estimate_series("mahony").t[-1] > 27.0


class BurstyTap(Tap):
    """A tap that loses bursts of ``BURST`` packets on the way (every ``EVERY`` packets, after
    the first ``AFTER``), as a radio fade does, and counts the IMU samples it lost."""
    BURST, EVERY, AFTER = 200, 1000, 3000

    def __init__(self, conn, garbage_every: int = 0):
        super().__init__(conn, garbage_every)
        self.seen = 0
        self.lost_imu = 0  # in bursts the stream came back after (one at its very end cannot be seen)
        self._pending = self._after = 0

    def write(self, packet: bytes) -> None:
        self.seen += 1
        k = self.seen - self.AFTER
        imu = packet[7] == mavlink2.MAVLINK_MSG_ID_RAW_IMU  # MAVLink 2: the id's low byte
        if k > 0 and k % self.EVERY < self.BURST:
            self._pending += imu
            self._after = 0
            return
        self._after += imu
        if self._pending and self._after > 3:
            self.lost_imu, self._pending = self.lost_imu + self._pending, 0
        super().write(packet)


@pytest.mark.slow
def test_bursts_of_loss_are_counted_by_the_autopilot_clock(tmp_path, flight):
    """200-packet bursts lost: the 8-bit sequence number cannot see them (a gap of 200 looks
    like a jump back); the IMU samples missing from the autopilot's clock are counted."""
    port = free_udp_port()
    thread, tap, holder = sender(port, lambda ap, tap: ap.serve(speed=SPEED), flight, tap_class=BurstyTap)
    result = listen(port, thread, holder, tmp_path)
    loss = result.estimation.samples_lost
    assert tap.lost_imu > 100
    assert loss.lost == pytest.approx(tap.lost_imu, rel=0.01)
    assert result.monitor.lost < 0.5 * tap.lost_imu  # what the sequence number saw
    link = result.link()
    assert link["imu_samples_lost_by_clock"] == loss.lost and link["kernel_drops"] == 0
    assert link["packets_received"] == result.monitor.packets and link["peak_rss_mb"] > 0


@pytest.mark.slow
def test_a_second_system_and_unknown_packets_on_the_port(tmp_path, flight):
    """Another vehicle on the port is named once and ignored; a datagram that looks like a
    packet of an unknown message id is corrupt data: counted, never recorded."""
    def plan(ap, tap):
        other = mavutil.mavlink_connection(f"udpout:127.0.0.1:{port}", source_system=42, source_component=1)
        unknown = bytes([0xFD, 3, 0, 0, 0, 7, 1, 0x39, 0x30, 0x00, 1, 2, 3, 0xAB, 0xCD])  # id 12345
        for k in range(5):
            ap.serve(speed=SPEED, t_from=4.0 * k, t_to=4.0 * (k + 1))
            other.mav.heartbeat_send(mavlink2.MAV_TYPE_QUADROTOR, mavlink2.MAV_AUTOPILOT_ARDUPILOTMEGA, 0, 0, 0)
            other.mav.raw_imu_send(int(4e6 * k) + 1, 0, 0, -1000, 0, 0, 0, 0, 0, 0)
            tap.conn.port.sendto(unknown, tap.conn.destination_addr)
        other.close()
    port = free_udp_port()
    thread, tap, holder = sender(port, plan, flight)
    result = listen(port, thread, holder, tmp_path)
    assert result.vehicle == (1, 1)
    said = [line for line in result.lines if line.startswith("also on the link")]
    assert said == ["also on the link: system 42 component 1 (HEARTBEAT); ignored, --sysid to choose another vehicle"]
    assert result.monitor.bad >= 5
    recorded = recorded_packets(tmp_path / "live.tlog")
    assert [p for p in recorded if p[5] == 1] == tap.sent  # the vehicle's, byte for byte
    assert {p[5] for p in recorded} == {1, 42}  # and the other system's: a recording keeps the link
    assert all(int.from_bytes(p[7:10], "little") in mavlink2.mavlink_map for p in recorded)  # no unknown


@pytest.mark.slow
@pytest.mark.parametrize("after_s", [1.0, 4.0])
def test_ctrl_c_while_the_first_run_compiles_ends_cleanly(tmp_path, after_s):
    """A first run compiles before it listens (nothing is lost unannounced); Ctrl-C then, from
    a terminal (the whole process group, compiling children too), is one line and exit 130."""
    env = dict(os.environ, NUMBA_CACHE_DIR=str(tmp_path / "cold-cache"))
    proc = subprocess.Popen([sys.executable, "-m", "mavattitude", "live", f"udpin:127.0.0.1:{free_udp_port()}",
                             "--estimators", "all", "--no-record"], env=env, cwd=tmp_path,
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, start_new_session=True,
                            preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL))
    time.sleep(after_s)
    os.killpg(proc.pid, signal.SIGINT)
    out, err = proc.communicate(timeout=60)
    # 130, or killed by SIGINT, which a shell reports as 130 too: CPython ends that way when a
    # KeyboardInterrupt once escaped code it ran from C (numba's compile), though ours was handled
    assert proc.returncode in (130, -signal.SIGINT), err
    assert "Traceback" not in err and "listening" not in err + out
    assert err.strip().splitlines()[-1] == "interrupted"


def test_an_interrupt_numba_could_only_report_is_raised_after_the_compile():
    """Ctrl-C landing in an LLVM callback reaches Python as an unraisable exception (a
    traceback on stderr, and the compile goes on): taken quietly, raised once it is over."""
    from types import SimpleNamespace

    from mavattitude.signals import holding_interrupts

    before = sys.unraisablehook
    with pytest.raises(KeyboardInterrupt):
        with holding_interrupts():
            sys.unraisablehook(SimpleNamespace(exc_value=KeyboardInterrupt(), exc_type=KeyboardInterrupt))
    assert sys.unraisablehook is before


@pytest.mark.slow  # a session stepped packet by packet
def test_a_vehicle_with_a_board_trim_and_a_declination_scores_as_replay_of_its_recording(tmp_path):
    """A simulated board mounted off level (AHRS_TRIM_X/Y), its autopilot reporting the vehicle's
    attitude, with COMPASS_DEC: live waits for the parameters it asked for, turns its estimates
    by the trim as replay does, and scores what replay of the recording scores."""
    from mavattitude import quaternion as quat
    from mavattitude.live.estimation import LiveEstimation
    from mavattitude.sim import simulate, write_log

    trim = (math.radians(2.5), math.radians(-1.5))
    sim = simulate("figure8", 60.0, seed=5, imu_rate=50.0)
    q_trim = np.broadcast_to(quat.conjugate(quat.from_euler(trim[0], trim[1], 0.0)), sim.autopilot_q.shape)
    sim = replace(sim, autopilot_q=quat.multiply(sim.autopilot_q, q_trim),
                  extra_params={"AHRS_TRIM_X": trim[0], "AHRS_TRIM_Y": trim[1]})
    path = write_log(sim, tmp_path / "trimmed.tlog")
    names = ["mahony", "ekf"]
    est = _feed(LiveEstimation(RunOptions(names), params_asked=True), path, every=21)
    est.step(final=True)
    comparisons, seg = est.final_comparisons()
    assert est.trim == pytest.approx(trim)
    assert any(e.text.startswith("board trim roll 2.50°, pitch -1.50°") for e in est.events)
    assert any(e.text.startswith("declination 5.00° (vehicle parameter COMPASS_DEC") for e in est.events)
    assert_live_equals_replay(est, seg.index, comparisons, path, names)
    untrimmed = _feed(LiveEstimation(RunOptions(names, trim=False), params_asked=True), path, every=21)
    untrimmed.step(final=True)
    # without the trim every estimate is off by about it (the figure-eight's own error besides)
    off = untrimmed.final_comparisons()[0]["mahony"].axes["roll"].mae
    assert off > comparisons["mahony"].axes["roll"].mae + 1.5


@pytest.mark.slow  # a session stepped packet by packet
def test_a_vehicle_whose_attitude_has_faults_scores_as_replay_of_its_recording(tmp_path):
    """replay's reference checks in live (``running_refcheck``): a simulated vehicle whose
    attitude is tilted while still on the ground, jumps 60° and disagrees with its EKF (AHRS2)
    for 15 s. Live decodes AHRS2, flags the spans replay flags on the recording, says them in
    replay's words, and scores what replay scores (the spans left out, found looking back)."""
    from mavattitude.live.estimation import LiveEstimation
    from mavattitude.scoring.refcheck import suspect_event
    from test_running_refcheck import faulty_log

    path = faulty_log(tmp_path / "faulty.tlog")
    names = ["mahony", "ekf"]
    est = _feed(LiveEstimation(RunOptions(names)), path)
    est.step(final=True)
    comparisons, seg = est.final_comparisons()
    replay = assert_live_equals_replay(est, seg.index, comparisons, path, names)
    assert {s.kind for s in replay.suspects} == {"tilt at rest", "tilt jump", "autopilot disagrees"}
    assert est.suspects == replay.suspects
    said = sorted((e.t, e.text) for e in est.events if e.kind and e.kind.startswith("reference not trusted"))
    assert said == [(s.start, suspect_event(s).text) for s in replay.suspects]
    assert comparisons["mahony"].n_excluded > 100
    from mavattitude.cli.live import live_scoring
    scoring = live_scoring(est)  # the JSON's, as replay's
    assert scoring["reference_suspect"] == replay.metrics["scoring"]["reference_suspect"]


@pytest.mark.slow  # a session stepped packet by packet
def test_repeated_reference_times_are_noted_as_replay_notes_them(tmp_path):
    """Every third ATTITUDE repeats the time of the one before: live drops them, as the reader
    does, and says so at the end in replay's words (a note on the whole reference, no span)."""
    from mavattitude.live.estimation import LiveEstimation

    mav = mavlink2.MAVLink(None, srcSystem=1, srcComponent=1)
    recorder, last, n = TlogRecorder(tmp_path / "repeats.tlog"), None, 0
    log = mavutil.mavlink_connection(str(ROOT / "sample_logs" / "figure8.tlog"), robust_parsing=True)
    while (msg := log.recv_msg()) is not None:
        if msg.get_type() == "BAD_DATA" or msg.get_srcSystem() != 1:
            continue
        if msg.get_type() == "ATTITUDE":
            n += 1
            if n % 3 == 0:
                msg.time_boot_ms = last
            last = msg.time_boot_ms
        mav.srcComponent = msg.get_srcComponent()
        recorder.write(msg.pack(mav), msg._timestamp)
    recorder.close()
    est = _feed(LiveEstimation(RunOptions(["mahony"])), tmp_path / "repeats.tlog")
    est.step(final=True)
    comparisons, seg = est.final_comparisons()
    replay = assert_live_equals_replay(est, seg.index, comparisons, tmp_path / "repeats.tlog", ["mahony"])
    assert replay.reference_notes and est.reference_notes == replay.reference_notes
    assert [e.text for e in est.events if "timestamps repeat" in e.text] == [replay.reference_notes[0].detail]


@pytest.mark.slow  # 40 s of a simulated plane streamed at 8x (5 s)
def test_live_asks_the_vehicle_for_the_policys_parameters_and_scores_as_replay_of_its_recording(tmp_path):
    """One policy for live and replay (``core.policy``): a simulated ArduPlane that sends no
    parameter unless asked, with a board trim (AHRS_TRIM_X/Y, its autopilot reporting the
    vehicle's attitude), a declination set by hand in PX4's EKF2_MAG_DECL (no COMPASS_DEC) and a
    cruise airspeed (TRIM_ARSPD_CM, eq-kf's default on a plane). Live asks for them by
    PARAM_REQUEST_READ, decides the policy replay decides on the recording, and scores the same."""
    from mavattitude.core.policy import FlightFacts, decide, wanted_params

    trim = (math.radians(2.5), math.radians(-1.5))
    sim = simulate("figure8", 40.0, seed=5, imu_rate=100.0)
    q_trim = np.broadcast_to(quat.conjugate(quat.from_euler(trim[0], trim[1], 0.0)), sim.autopilot_q.shape)
    sim = replace(sim, autopilot_q=quat.multiply(sim.autopilot_q, q_trim), firmware="ArduPlane V4.5.7 (sim)",
                  extra_params={"AHRS_TRIM_X": trim[0], "AHRS_TRIM_Y": trim[1], "COMPASS_DEC": None,
                                "EKF2_MAG_DECL": math.degrees(sim.declination_rad), "EKF2_DECL_TYPE": 0.0,
                                "TRIM_ARSPD_CM": 1500.0})
    served = {}

    def plan(autopilot, tap):
        autopilot.announce_params = False  # as a real ArduPilot: only what is asked for
        served["stats"] = autopilot.serve(speed=SPEED)
    port = free_udp_port()
    thread, tap, holder = sender(port, plan, sim)
    names = ["mahony", "eq-kf"]
    result = listen(port, thread, holder, tmp_path, names=names)
    est = result.estimation
    asked = {line.split()[1] for line in served["stats"].requests if line.startswith("PARAM_REQUEST_READ")}
    assert asked == set(wanted_params(names)) and "TRIM_ARSPD_CM" in asked  # eq-kf's on a plane
    policy = est.policy
    assert policy.params["eq-kf"].airspeed == 15.0 and policy.notes == (
        "eq-kf airspeed 15 m/s from TRIM_ARSPD_CM (the plane's cruise airspeed)",)
    assert policy.declination.source.startswith("vehicle parameter EKF2_MAG_DECL, EKF2_DECL_TYPE=0: set by hand")
    assert est.trim == pytest.approx(trim) and not any("no answer" in e.text for e in est.events)
    # replay of the recording decides the same policy on the log ...
    again = decide(policy.options, FlightFacts.of(read_log(str(tmp_path / "live.tlog"))))
    assert again.params == policy.params and again.notes == policy.notes and again.board_trim == policy.board_trim
    assert again.declination.rad == policy.declination.rad and again.declination.kind == "parameter"
    # ... and scores what live scored
    assert_live_equals_replay(est, result.segment, result.comparisons, tmp_path / "live.tlog", names)
