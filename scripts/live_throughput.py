"""How many packets a second a live session holds: the simulated autopilot streams RAW_IMU at
1 kHz and ATTITUDE at 50 Hz (plus GPS, baro, heartbeats) at N times real time over loopback
UDP to a live session (no recording, no viewer), for a given wall time; prints packets sent,
received and dropped by the system at each speed, and the session's memory: RSS at the end
and its growth per hour of 1 kHz data (the slope over the stream's second half).

    python scripts/live_throughput.py --estimators mahony --speeds 10,20,30 --seconds 60

A speed is held when every packet sent is received (none lost, none dropped by the system's
receive buffer) for the whole stream. The session's receive buffer (16 MB granted here) absorbs
a few seconds of overload: judge rates on streams of a minute or more.
"""
from __future__ import annotations

import argparse
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--estimators", default="mahony", help="comma-separated, or 'all'")
    ap.add_argument("--speeds", default="10,20,30", help="times real time, comma-separated")
    ap.add_argument("--seconds", type=float, default=60.0, help="wall seconds of each stream")
    args = ap.parse_args()
    from mavattitude.commands.bench_live import rate_probe
    from mavattitude.estimators import ESTIMATORS
    from mavattitude.core.warmup import warm_up

    names = list(ESTIMATORS) if args.estimators == "all" else args.estimators.split(",")
    warm_up(names)
    print(f"estimators: {', '.join(names)}; {args.seconds:g} s of wall time per speed")
    print(f"{'speed':>6s} {'packets/s':>10s} {'sent':>10s} {'received':>10s} {'dropped':>8s}  held"
          f"  {'RSS MB':>7s} {'MB/h':>6s}")
    for speed in (float(x) for x in args.speeds.split(",")):
        r = rate_probe(names, speed, args.seconds)
        print(f"{speed:6g} {r['packets_per_s']:10,} {r['sent']:10,} {r['received']:10,} "
              f"{r['kernel_drops'] if r['kernel_drops'] is not None else '-':>8}  {'yes ' if r['held'] else 'NO  '}"
              f"  {r['rss_mb']['end'] or float('nan'):7.0f} {r['mb_per_hour_at_1khz'] or float('nan'):6.0f}", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
