"""The live figure of ``mavattitude bench --live``: can a live session keep up with a fast link?

A simulated autopilot (``sim.autopilot``) runs in a child process and streams a flight over
loopback UDP in real time; a live session (``live.run_live``, the code ``mavattitude live``
runs, recording included) listens in this process and asks it for RAW_IMU at ``LIVE_IMU_HZ``
and ATTITUDE at 50 Hz. Measured:

- packets dropped: sent by the child minus received here (and, separately, the losses the
  session counts from sequence numbers);
- loss you can trust: the child loses ``FADE_BURST``-packet bursts on purpose (a radio fade, every
  ``FADE_EVERY`` packets once the rates are set) and counts the IMU samples in them; the session
  should count as many from the autopilot's clock (the 8-bit sequence number cannot see a burst
  of 128 or more). Those samples are left out of the latency figures;
- rate held: ``rate_probe`` streams the same flight at ``RATE_PROBE_SPEED`` times real time
  (22,440 packets/s) for ``RATE_PROBE_S`` s to a session with no recording: held when every
  packet sent was received and the system dropped none (target: ``TARGET_RATE`` packets/s);
- memory: the session's RSS through that probe (20 minutes of 1 kHz data in 60 s; the
  latency run records per-sample timings, which would count too): at the start of the stream,
  half-way and at the end, and its growth per hour of 1 kHz data from the slope over the
  second half (a session fills its ``history_s`` of data in the first minute; after that it
  should not grow). A least-squares slope, since RSS wanders a few MB as large arrays come and
  go (target: ``TARGET_MB_PER_HOUR``);
- packet-to-estimate latency per IMU sample: from the moment the child handed the packet to
  the socket to the moment every estimator had produced its attitude for that sample. Both
  are ``time.monotonic()`` (CLOCK_MONOTONIC, one clock for all processes of the machine), so
  the difference includes the network stack, the wait in the socket buffer, decoding and
  estimation. Only samples sent after the requested rates took effect count.

Targets: no packet dropped, 99th percentile latency at most ``TARGET_P99_MS``; the clock's
count of the faded samples within ``TARGET_LOSS_AGREEMENT`` of the truth.
"""
from __future__ import annotations

import io
import json
import multiprocessing
import tempfile
import threading
import time
from pathlib import Path

import numpy as np

LIVE_IMU_HZ = 1000.0
LIVE_ATT_HZ = 50.0
TARGET_P99_MS = 10.0
TARGET_DROPPED = 0
SETTLE_S = 3.0  # s of the stream before the measured span: the rate requests take effect
FADE_BURST, FADE_EVERY = 200, 10_000  # packets lost on purpose: bursts of 200 every 10,000 (~10 s)
TARGET_LOSS_AGREEMENT = 0.01  # the clock's count of the faded IMU samples: within 1 %
# 20 minutes of 1 kHz data in 60 s: RSS wanders some 10 MB as large arrays come and go, so
# its slope over the second half (10 minutes of data) is good to a few tens of MB an hour
RATE_PROBE_SPEED, RATE_PROBE_S = 20.0, 60.0
TARGET_RATE = 20_000  # packets/s a session holds
TARGET_MB_PER_HOUR = 50.0  # RSS growth per hour of 1 kHz data, all estimators
RSS_EVERY_S = 0.25  # s between RSS samples during the probe


class _Fade:
    """The child's link, losing ``FADE_BURST`` packets every ``FADE_EVERY`` once the stream runs
    at full rate. Counts the packets and the IMU samples (by time) it lost; a burst at the very
    end, which nothing after it can reveal, does not count."""

    def __init__(self, conn, after: int):
        self.conn, self.after = conn, after
        self.seen = self.dropped = 0
        self.lost_imu_us: list[int] = []
        self._pending: list[int] = []
        self._after_burst = 0

    def write(self, packet: bytes) -> None:
        self.seen += 1
        k = self.seen - self.after
        imu = packet[0] == 0xFD and packet[7] == 27 and packet[8] == 0 and packet[9] == 0  # RAW_IMU, MAVLink 2
        if k >= 0 and k % FADE_EVERY < FADE_BURST:
            self.dropped += 1
            if imu:
                self._pending.append(int.from_bytes(packet[10:18], "little"))  # time_usec: the first field
            self._after_burst = 0
            return
        self._after_burst += imu
        if self._pending and self._after_burst > 3:
            self.lost_imu_us += self._pending
            self._pending = []
        self.conn.write(packet)

    def __getattr__(self, name):
        return getattr(self.conn, name)


def _sender(port: int, seconds: float, out_dir: str) -> None:
    """The child process: simulate, stream, write what was sent when."""
    from ..live.link import open_link
    from ..sim import simulate
    from ..sim.autopilot import SimAutopilot

    sim = simulate("figure8", seconds + SETTLE_S, seed=0, imu_rate=LIVE_IMU_HZ)
    conn = open_link(f"udpout:127.0.0.1:{port}")
    link = _Fade(conn, after=int(SETTLE_S * (LIVE_IMU_HZ + LIVE_ATT_HZ)) + 2000)
    autopilot = SimAutopilot(sim, link, record_imu_times=True)
    stats = autopilot.serve(speed=1.0)
    conn.close()
    np.save(Path(out_dir) / "imu_sent_at.npy", np.array(stats.imu_sent_at, dtype=float).reshape(-1, 2))
    (Path(out_dir) / "sent.json").write_text(json.dumps({
        "sent": stats.sent, "requests": stats.requests, "faded_packets": link.dropped,
        "faded_imu_us": link.lost_imu_us + link._pending, "faded_imu_seen_after": len(link.lost_imu_us)}))


def _probe_sender(port: int, speed: float, sim_seconds: float, out: str) -> None:
    from ..live.link import open_link
    from ..sim import simulate
    from ..sim.autopilot import SimAutopilot

    sim = simulate("figure8", sim_seconds, seed=0, imu_rate=LIVE_IMU_HZ)
    conn = open_link(f"udpout:127.0.0.1:{port}")
    started_at = time.monotonic()  # one clock for every process of the machine
    stats = SimAutopilot(sim, conn, rates={"RAW_IMU": LIVE_IMU_HZ, "ATTITUDE": LIVE_ATT_HZ}).serve(speed=speed)
    Path(out).write_text(json.dumps({"sent": sum(stats.sent.values()), "started_at": started_at,
                                     "ended_at": time.monotonic()}))


def _session_against(sender, args: tuple, names: list[str], **options):
    """A live session running ``names`` (more ``LiveOptions`` in ``options``) while a child
    process runs ``sender(port, *args)``: started once the session listens, the session ends
    when it is done. Returns the session's result."""
    from ..live import LiveOptions, run_live
    from ..view.live import StatusLine

    port = _free_port()
    child = multiprocessing.get_context("spawn").Process(target=sender, args=(port, *args), daemon=True)

    def on_line(line: str) -> None:  # the first line comes once the port is bound
        if child.pid is None:
            child.start()
    result = run_live(LiveOptions(url=f"udpin:127.0.0.1:{port}", names=names, imu_rate=LIVE_IMU_HZ, **options),
                      stop=lambda: child.pid is not None and child.exitcode is not None,
                      status=StatusLine(io.StringIO()), say=on_line)
    child.join(10)
    if child.exitcode != 0:
        raise RuntimeError(f"the simulated autopilot failed (exit {child.exitcode})")
    return result


def rate_probe(names: list[str], speed: float = RATE_PROBE_SPEED, seconds: float = RATE_PROBE_S) -> dict:
    """The flight streamed at ``speed`` times real time for ``seconds`` of wall time to a live
    session running ``names`` (no recording, no rate requests): what was sent and received, and
    the memory it took. The session runs in a fresh process, so its RSS is its own, not the
    high-water mark of what ran before it in this one."""
    from concurrent.futures import ProcessPoolExecutor

    with ProcessPoolExecutor(1, mp_context=multiprocessing.get_context("spawn")) as pool:
        return pool.submit(_rate_probe, names, speed, seconds).result()


def _rate_probe(names: list[str], speed: float, seconds: float) -> dict:
    from ..core.warmup import warm_up

    warm_up(names)
    rss: list[tuple[float, float]] = []  # (monotonic s, MB)
    done = threading.Event()

    def sample_rss():
        while not done.wait(RSS_EVERY_S):
            rss.append((time.monotonic(), _rss_mb()))
    sampler = threading.Thread(target=sample_rss, daemon=True)
    sampler.start()
    with tempfile.TemporaryDirectory() as tmp:
        out = str(Path(tmp) / "sent.json")
        try:
            result = _session_against(_probe_sender, (speed, seconds * speed, out), names,
                                      record=None, request=False, duration=seconds + 120.0)
        finally:
            done.set()
        sent = json.loads(Path(out).read_text())
    received, drops = result.monitor.packets, result.kernel_drops
    samples = result.estimation.samples
    return {"speed": speed, "seconds": seconds, "packets_per_s": round(sent["sent"] / seconds), "sent": sent["sent"],
            "received": received, "kernel_drops": drops, "held": received == sent["sent"] and not drops,
            "imu_samples": samples, **_rss_figures(rss, sent["started_at"], sent["ended_at"], samples)}


def _rss_figures(rss: list[tuple[float, float]], start: float, end: float, samples: int) -> dict:
    """RSS at the start of the stream, half-way and at the end (MB; the median of the samples
    within 5 % of the stream's span there, or one sampling interval), and the growth per hour
    of 1 kHz data from the least-squares slope over the second half."""
    t, mb = (np.array(c) for c in zip(*rss)) if rss else (np.zeros(0), np.zeros(0))
    span = end - start

    def at(when: float) -> float | None:
        near = np.abs(t - when) <= max(0.05 * span, RSS_EVERY_S)
        return round(float(np.median(mb[near])), 1) if near.any() else None
    second_half = (t >= start + span / 2) & (t <= end)
    per_hour = None
    if np.count_nonzero(second_half) >= 3 and samples:
        slope = np.polyfit(t[second_half], mb[second_half], 1)[0]  # MB per s of wall time
        per_hour = round(float(slope * span / samples * 3.6e6), 1)  # MB a sample, times an hour of 1 kHz
    return {"rss_mb": {"start": at(start), "half": at(start + span / 2), "end": at(end)},
            "mb_per_hour_at_1khz": per_hour}


def run_live_bench(names: list[str], seconds: float = 60.0, say=print, probe_seconds: float = RATE_PROBE_S) -> dict:
    """Stream ``seconds`` of 1 kHz IMU to a live session running ``names``, then probe the rate
    it holds for ``probe_seconds``; the figures as a dict."""
    from ..core.warmup import warm_up

    warm_up(names)
    say(f"live: streaming {seconds:g} s of RAW_IMU at {LIVE_IMU_HZ:g} Hz and ATTITUDE at "
        f"{LIVE_ATT_HZ:g} Hz over loopback UDP to a live session ({', '.join(names)}) ...")
    with tempfile.TemporaryDirectory() as tmp:
        result = _session_against(_sender, (seconds, tmp), names, record=str(Path(tmp) / "bench.tlog"),
                                     record_latency=True, duration=seconds + SETTLE_S + 60.0)
        sent_at = np.load(Path(tmp) / "imu_sent_at.npy")
        sent = json.loads((Path(tmp) / "sent.json").read_text())
    figures = _figures(names, seconds, result, sent_at, sent)
    say(f"live: streaming at {RATE_PROBE_SPEED:g}x real time for {probe_seconds:g} s ...")
    figures["rate_probe"] = probe = rate_probe(names, seconds=probe_seconds)
    figures["target_met"] = (figures["target_met"] and probe["packets_per_s"] >= TARGET_RATE and probe["held"]
                             and probe["mb_per_hour_at_1khz"] is not None
                             and probe["mb_per_hour_at_1khz"] <= TARGET_MB_PER_HOUR)
    return figures


def _rss_mb() -> float:
    """This process's resident memory now, MB (Linux; NaN elsewhere)."""
    try:
        with open("/proc/self/status") as f:
            return int(f.read().split("VmRSS:")[1].split()[0]) / 1024
    except (OSError, IndexError, ValueError):
        return float("nan")


def _figures(names, seconds, result, sent_at: np.ndarray, sent: dict) -> dict:
    est = result.estimation
    done = {int(round(t * 1e6)): (arrival, estimated) for t, arrival, estimated in est.latency}
    faded = np.isin(sent_at[:, 0].astype(np.int64), np.array(sent["faded_imu_us"], np.int64))
    sent_at = sent_at[~faded]  # lost on purpose: no latency to measure
    usec = sent_at[:, 0].astype(np.int64)
    # the measured span: after the rates took effect (the IMU at full rate), and after the
    # estimators started: until its alignment is decided (the vehicle moved, or 10 s still) a
    # session holds its samples back, as replay does, and estimates them all at once then
    fast = np.flatnonzero(np.diff(usec) <= 1.5e6 / LIVE_IMU_HZ)
    first = usec[fast[0]] + SETTLE_S * 1e6 if len(fast) else usec[-1] + 1
    began = min((estimated for _, estimated in done.values()), default=np.inf)
    measured = (usec >= first) & (sent_at[:, 1] >= began)
    waited = float(began - sent_at[0, 1]) if np.isfinite(began) else float("nan")
    latency, in_process = [], []
    missing = 0
    for u, t_send in zip(usec[measured].tolist(), sent_at[measured, 1].tolist()):
        got = done.get(u)
        if got is None:
            missing += 1
            continue
        latency.append(got[1] - t_send)
        in_process.append(got[1] - got[0])
    latency_ms = np.array(latency) * 1e3
    total_sent = int(sum(sent["sent"].values())) - sent["faded_packets"]
    dropped = total_sent - result.monitor.packets
    loss = est.samples_lost
    faded_imu = sent["faded_imu_seen_after"]
    counted = loss.lost if loss else 0
    agrees = abs(counted - faded_imu) <= TARGET_LOSS_AGREEMENT * faded_imu
    p99 = float(np.percentile(latency_ms, 99)) if len(latency_ms) else float("nan")
    return {
        "imu_rate_hz": LIVE_IMU_HZ, "attitude_rate_hz": LIVE_ATT_HZ, "seconds": seconds,
        "estimators": names,
        "packets_sent": total_sent, "packets_received": result.monitor.packets,
        "packets_dropped": dropped, "lost_by_sequence": result.monitor.lost,
        "kernel_drops": result.kernel_drops,
        "faded_packets": sent["faded_packets"], "faded_imu_samples": faded_imu,
        "imu_samples_lost_by_clock": counted,
        "imu_samples_measured": int(np.count_nonzero(measured)), "imu_samples_not_estimated": missing,
        "alignment_wait_s": waited,
        "requests": sent["requests"],
        "latency_ms": _stats(latency_ms),
        "in_process_ms": _stats(np.array(in_process) * 1e3),
        "targets": {"packets_dropped": TARGET_DROPPED, "p99_latency_ms": TARGET_P99_MS,
                    "loss_agreement": TARGET_LOSS_AGREEMENT},
        "target_met": dropped <= TARGET_DROPPED and missing == 0 and p99 <= TARGET_P99_MS and agrees,
    }


def _stats(ms: np.ndarray) -> dict:
    if not len(ms):
        return {"p50": None, "p99": None, "max": None}
    return {"p50": float(np.percentile(ms, 50)), "p99": float(np.percentile(ms, 99)), "max": float(ms.max())}


def format_live(figures: dict) -> str:
    lat, inproc = figures["latency_ms"], figures["in_process_ms"]
    met = "yes" if figures["target_met"] else "NO"
    lines = [
        f"live: {figures['seconds']:g} s of RAW_IMU at {figures['imu_rate_hz']:g} Hz + ATTITUDE at "
        f"{figures['attitude_rate_hz']:g} Hz over loopback UDP; estimators {', '.join(figures['estimators'])}",
        f"  packets sent {figures['packets_sent']:,}, received {figures['packets_received']:,}, "
        f"dropped {figures['packets_dropped']:,} (lost by sequence number {figures['lost_by_sequence']:,})",
        f"  estimates began {figures['alignment_wait_s']:.1f} s after the first packet (the alignment "
        "waits for the vehicle to move, or 10 s still)",
        f"  packet-to-estimate latency over {figures['imu_samples_measured']:,} IMU samples from then: "
        f"p50 {_ms(lat['p50'])}, p99 {_ms(lat['p99'])}, max {_ms(lat['max'])} "
        f"(of which in this process: p50 {_ms(inproc['p50'])}, p99 {_ms(inproc['p99'])})",
        f"  loss: {figures['faded_packets']:,} packets lost on purpose in {FADE_BURST}-packet bursts, "
        f"{figures['faded_imu_samples']:,} of them IMU samples: counted {figures['imu_samples_lost_by_clock']:,} by "
        f"the autopilot's clock, {figures['lost_by_sequence']:,} packets by sequence number"
        + (f"; {figures['kernel_drops']:,} dropped by the system" if figures["kernel_drops"] is not None else ""),
        *_probe_lines(figures.get("rate_probe")),
        f"  targets: 0 dropped, p99 ≤ {TARGET_P99_MS:g} ms, loss counted within "
        f"{100 * TARGET_LOSS_AGREEMENT:g} %, {TARGET_RATE:,} packets/s held, ≤ {TARGET_MB_PER_HOUR:g} MB "
        f"per hour: {met}"
        + (f" ({figures['imu_samples_not_estimated']} samples never estimated)"
           if figures["imu_samples_not_estimated"] else ""),
    ]
    return "\n".join(lines) + "\n"


def _probe_lines(probe: dict | None) -> list[str]:
    if probe is None:
        return ["  rate: not probed"]
    drops = "" if probe["kernel_drops"] is None else f", {probe['kernel_drops']:,} dropped by the system"
    per_hour, rss = probe["mb_per_hour_at_1khz"], probe["rss_mb"]
    minutes = probe["imu_samples"] / LIVE_IMU_HZ / 60

    def mb(x):
        return "–" if x is None else f"{x:.0f} MB"
    return [f"  rate: {probe['packets_per_s']:,} packets/s for {probe['seconds']:g} s: {probe['sent']:,} sent, "
            f"{probe['received']:,} received{drops}: {'held' if probe['held'] else 'NOT held'}",
            f"  memory over those {probe['imu_samples']:,} IMU samples ({minutes:.0f} min at {LIVE_IMU_HZ:g} Hz, "
            f"no recording): RSS {mb(rss['start'])} at the start, {mb(rss['half'])} after {minutes / 2:.0f} min, "
            f"{mb(rss['end'])} at the end; growth over the second half: "
            + (f"{per_hour:.0f} MB per hour at {LIVE_IMU_HZ:g} Hz" if per_hour is not None else "–")]


def _ms(x) -> str:
    return "–" if x is None else f"{x:.2f} ms"


def _free_port() -> int:
    import socket
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]
