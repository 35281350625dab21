"""``mavattitude bench``: estimator speed against imufusion, the live figure, the reading figures."""
from __future__ import annotations

import sys
from pathlib import Path

from ..errors import UsageError
from ..outputs import Outputs, json_text
from .args import COUNT, POSITIVE, SEED, force_arg
from .common import estimator_names
from .simulate import check_sim_length


def add_parser(sub) -> None:
    p = sub.add_parser("bench", help="time every estimator on a simulated flight, against imufusion",
                       description="Simulate a flight (default: 1 h at 400 Hz), time each estimator's "
                                   "update() over all of it (best of --repeat; compiled first), and "
                                   "imufusion's Ahrs called per sample from Python on part of it, with "
                                   "and without the magnetometer. Prints samples/s, the ratio to "
                                   "imufusion and whether the targets are met (every estimator >= 5x "
                                   "imufusion, cpf-ekf >= 1x, mahony >= 1 M samples/s). imufusion "
                                   "is optional: "
                                   'pip install "mavattitude[bench]". The filters of other projects '
                                   "(vqf, imufusion) can be timed too, by name: their rows have no target.")
    p.add_argument("--estimators", default="all", metavar="LIST",
                   help="comma-separated estimator names, 'all' (ours) among them (default: all)")
    p.add_argument("--scenario", default="figure8", help="simulated scenario (default figure8)")
    p.add_argument("--duration", type=POSITIVE, default=3600.0, metavar="S",
                   help="simulated seconds (default 3600)")
    p.add_argument("--imu-rate", type=POSITIVE, default=400.0, metavar="HZ", help="IMU rate (default 400)")
    p.add_argument("--seed", type=SEED, default=0, help="sensor-noise seed (default 0)")
    p.add_argument("--repeat", type=COUNT, default=3, metavar="N",
                   help="time each run N times and keep the best (default 3)")
    p.add_argument("--imufusion-samples", type=COUNT, default=200_000, metavar="N",
                   help="samples imufusion's Python loop is timed on (default 200000)")
    p.add_argument("--json", metavar="FILE", help="write the results as JSON")
    force_arg(p)
    p.add_argument("--live", action="store_true",
                   help="also the live figure: a simulated autopilot streams RAW_IMU at 1 kHz and ATTITUDE "
                        "at 50 Hz over loopback UDP to a live session running the estimators; reports "
                        "packets dropped and packet-to-estimate latency (targets: 0, p99 <= 10 ms)")
    p.add_argument("--live-seconds", type=POSITIVE, default=60.0, metavar="S",
                   help="how long the live figure streams (default 60)")
    p.add_argument("--read", action="store_true",
                   help="instead, the reading figures: .bin and .tlog read speed against pymavlink's "
                        "type-filtered read, .ulg against pyulog's read of the same topics (on a simulated "
                        ".bin and .ulg of --duration at --imu-rate, by default 1 h at 400 Hz, and on each "
                        "--log), and the wall time and peak memory of 'replay --estimators all --rrd' on the "
                        "simulated log (targets: .bin >= 15x pymavlink, .ulg >= 10x pyulog, 1 h at 400 Hz "
                        "<= 30 s)")
    p.add_argument("--log", action="append", metavar="FILE",
                   help="with --read: a real log to read too (repeatable)")
    p.set_defaults(func=run)


def run(args) -> int:
    from ..commands.bench import run

    names = estimator_names(args.estimators)
    if args.log and not args.read:
        raise UsageError("--log is for --read (the reading figures)")
    check_sim_length(args.duration, args.imu_rate)
    if args.live:
        from ..commands.bench_live import LIVE_IMU_HZ, SETTLE_S
        check_sim_length(args.live_seconds + SETTLE_S, LIVE_IMU_HZ, f"--live-seconds plus {SETTLE_S:g} s of settling")
    with Outputs(force=args.force) as outputs:
        json_out = outputs.file(args.json, "--json", "json")
        if args.read:
            return _bench_read(args, json_out)
        code = run(names, args.scenario, args.duration, args.imu_rate, args.seed, args.repeat,
                   args.imufusion_samples, json_out, live_seconds=args.live_seconds if args.live else None)
        if json_out:
            print(f"results written to {json_out.path}")
    return code


def _bench_read(args, json_out) -> int:
    from ..commands.bench_read import format_read, run_read_bench
    from ..readers import sniff_format

    for path in args.log or ():
        sniff_format(path)  # a missing or foreign file: one line, before minutes of work
    result = run_read_bench(args.log or [], args.scenario, args.duration, args.imu_rate, repeat=args.repeat,
                            say=lambda text: print(text, file=sys.stderr))
    print(format_read(result), end="")
    if json_out:
        with json_out.writing() as path:
            Path(path).write_text(json_text(result))
        print(f"results written to {json_out.path}")
    return 0  # a missed target is the benchmark's finding (its "targets:" line, "met" in the JSON), not a failure
