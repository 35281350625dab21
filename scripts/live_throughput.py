"""How many packets a second a live session holds: the simulated autopilot streams RAW_IMU at
1 kHz and ATTITUDE at 50 Hz (plus GPS, baro, heartbeats) at N times real time over loopback
UDP to a live session (no recording, no viewer), for a given wall time; prints packets sent,
received and dropped by the system at each speed.

    python scripts/live_throughput.py --estimators mahony --speeds 10,20,30 --seconds 60

A speed is held when every packet sent is received (none lost, none dropped by the system's
receive buffer) for the whole stream. The session's receive buffer (16 MB granted here) absorbs
a few seconds of overload: judge rates on streams of a minute or more.
"""
from __future__ import annotations

import argparse
import io
import json
import multiprocessing
import socket
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
IMU_HZ = 1000.0


def _sender(port: int, speed: float, sim_seconds: float, out: str) -> None:
    from mavattitude.live.link import open_link
    from mavattitude.sim import simulate
    from mavattitude.sim.autopilot import SimAutopilot

    sim = simulate("figure8", sim_seconds, seed=0, imu_rate=IMU_HZ)
    conn = open_link(f"udpout:127.0.0.1:{port}")
    stats = SimAutopilot(sim, conn, rates={"RAW_IMU": IMU_HZ, "ATTITUDE": 50.0}).serve(speed=speed)
    Path(out).write_text(json.dumps(sum(stats.sent.values())))


def run(names: list[str], speed: float, seconds: float) -> dict:
    from mavattitude.live import LiveOptions, run_live
    from mavattitude.live.display import StatusLine

    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    with tempfile.TemporaryDirectory() as tmp:
        out = str(Path(tmp) / "sent.json")
        child = multiprocessing.get_context("spawn").Process(target=_sender, args=(port, speed, seconds * speed, out),
                                                             daemon=True)
        started = []

        def on_line(line: str) -> None:  # the first line comes once the port is bound
            if not started:
                child.start()
                started.append(True)
        cpu = time.process_time()
        result = run_live(LiveOptions(url=f"udpin:127.0.0.1:{port}", names=names, imu_rate=IMU_HZ, record=None,
                                      request=False, duration=seconds + 120.0),
                          stop=lambda: bool(started) and child.exitcode is not None,
                          status=StatusLine(io.StringIO()), say=on_line)
        cpu = time.process_time() - cpu
        child.join()
        sent = json.loads(Path(out).read_text())
    return {"speed": speed, "packets_per_s": sent / seconds, "sent": sent, "received": result.monitor.packets,
            "kernel_drops": result.kernel_drops, "cpu_share": cpu / result.seconds}


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--estimators", default="mahony", help="comma-separated, or 'all'")
    ap.add_argument("--speeds", default="10,20,30", help="times real time, comma-separated")
    ap.add_argument("--seconds", type=float, default=60.0, help="wall seconds of each stream")
    args = ap.parse_args()
    from mavattitude.estimators import ESTIMATORS, warm_up

    names = list(ESTIMATORS) if args.estimators == "all" else args.estimators.split(",")
    warm_up(names)
    print(f"estimators: {', '.join(names)}; {args.seconds:g} s of wall time per speed")
    print(f"{'speed':>6s} {'packets/s':>10s} {'sent':>10s} {'received':>10s} {'dropped':>8s} {'CPU':>5s}  held")
    for speed in (float(x) for x in args.speeds.split(",")):
        r = run(names, speed, args.seconds)
        held = r["received"] == r["sent"] and not r["kernel_drops"]
        print(f"{speed:6g} {r['packets_per_s']:10,.0f} {r['sent']:10,} {r['received']:10,} "
              f"{r['kernel_drops'] if r['kernel_drops'] is not None else '-':>8} {100 * r['cpu_share']:4.0f}%  "
              f"{'yes' if held else 'NO'}", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
