"""``mavattitude simulate``: a simulated flight with known truth, to a file or a live link."""
from __future__ import annotations

import sys
from pathlib import Path

from ..errors import UsageError
from ..outputs import Outputs
from .args import POSITIVE, SECONDS, SEED, force_arg


def add_parser(sub) -> None:
    p = sub.add_parser("simulate", help="write a simulated flight with known truth as .tlog, .bin or .ulg",
                       description="Simulate a flight (rigid-body trajectory and sensor models) and "
                                   "write it as a genuine ArduPilot .tlog (MAVLink 2) or DataFlash "
                                   ".bin, or a PX4 ULog .ulg, with ground truth (SIMSTATE / SIM / "
                                   "vehicle_attitude_groundtruth).")
    p.add_argument("--scenario", default="figure8", help="scenario name (see --list; default figure8)")
    p.add_argument("--duration", type=POSITIVE, default=120.0, metavar="S", help="seconds (default 120)")
    p.add_argument("--imu-rate", type=POSITIVE, default=100.0, metavar="HZ", help="IMU rate (default 100)")
    p.add_argument("--imt", action="store_true",
                   help="a .bin with delta angles and velocities too (IMT, as ArduPilot logs them)")
    p.add_argument("--seed", type=SEED, default=0, help="sensor-noise seed (default 0)")
    p.add_argument("-o", "--output", metavar="FILE", help="output file: .tlog, .bin or .ulg")
    p.add_argument("--live", metavar="URL",
                   help="instead of a file, act as an autopilot on this MAVLink connection (e.g. "
                        "udpout:127.0.0.1:14550): stream the flight in real time, honouring "
                        "SET_MESSAGE_INTERVAL and REQUEST_DATA_STREAM")
    p.add_argument("--speed", type=SECONDS, default=1.0, metavar="X",
                   help="with --live: times real time (default 1; 0 = as fast as possible)")
    p.add_argument("--list", action="store_true", help="list the scenarios and exit")
    force_arg(p)
    p.set_defaults(func=run)


def run(args) -> int:
    from ..sim import SCENARIOS, simulate, write_log

    if args.list:
        for name, description in SCENARIOS.items():
            print(f"{name:12s} {description}")
        return 0
    if not args.output and not args.live:
        raise UsageError("simulate needs -o FILE.tlog, FILE.bin or FILE.ulg, or --live URL (or --list)")
    if args.output and args.live:
        raise UsageError("choose -o FILE or --live URL, not both")
    if args.scenario not in SCENARIOS:
        raise UsageError(f"unknown scenario {args.scenario!r}; choose from: {', '.join(SCENARIOS)}")
    suffix = Path(args.output).suffix.lower() if args.output else None
    if args.output and suffix not in (".tlog", ".bin", ".ulg"):
        raise UsageError(f"{args.output}: the output must end in .tlog, .bin or .ulg")
    if args.imt and suffix != ".bin":
        raise UsageError("--imt writes DataFlash records: give -o FILE.bin")
    check_sim_length(args.duration, args.imu_rate)
    if args.live:
        return _simulate_live(args)
    with Outputs(force=args.force) as outputs:
        out = outputs.file(args.output, "-o", "sim")
        sim = simulate(args.scenario, args.duration, seed=args.seed, imu_rate=args.imu_rate)
        with out.writing() as path:
            write_log(sim, path, suffix, imt=args.imt)
    print(f"{out.path}: {args.scenario}, {args.duration:g} s, IMU {args.imu_rate:g} Hz, seed {args.seed} "
          f"({out.path.stat().st_size / 1e6:.2f} MB)")
    return 0


def check_sim_length(duration: float, imu_rate: float, options: str = "--duration/--imu-rate") -> None:
    """A usage error, before any work, when the simulator cannot make that flight."""
    from ..sim import Rates
    from ..sim.simflight import check_length

    try:
        check_length(duration, Rates(imu=imu_rate))
    except ValueError as exc:
        raise UsageError(f"{options}: {exc}") from None


def _simulate_live(args) -> int:
    import signal

    from ..live.link import open_link
    from ..sim import simulate
    from ..sim.autopilot import SimAutopilot

    print(f"simulating {args.scenario}, {args.duration:g} s at {args.imu_rate:g} Hz ...", file=sys.stderr)
    sim = simulate(args.scenario, args.duration, seed=args.seed, imu_rate=args.imu_rate)
    conn = open_link(args.live)
    stopped = []
    previous = {sig: signal.signal(sig, lambda s, f: stopped.append(s)) for sig in (signal.SIGINT, signal.SIGTERM)}
    autopilot = SimAutopilot(sim, conn)
    print(f"streaming to {args.live} as system 1 at {args.speed:g}x real time"
          + (" (as fast as possible)" if args.speed == 0 else "") + "; Ctrl-C to stop", file=sys.stderr)
    try:
        stats = autopilot.serve(speed=args.speed, stop=lambda: bool(stopped))
    finally:
        for sig, handler in previous.items():
            signal.signal(sig, handler)
        conn.close()
    for line in stats.requests:
        print(f"request honoured: {line}", file=sys.stderr)
    sent = ", ".join(f"{n} {c}" for n, c in sorted(stats.sent.items()))
    print(f"{'stopped' if stats.stopped else 'done'} after {stats.seconds:.1f} s; sent {sent}")
    return 0
