"""``mavattitude live``: a vehicle watched over MAVLink, estimated as samples arrive, recorded."""
from __future__ import annotations

import argparse
import math
import textwrap

from ..errors import UsageError
from ..outputs import Outputs
from .args import COUNT, POSITIVE, estimation_args, force_arg, number, trim_arg, viewer_args
from .common import compile_kernels, estimator_names, plan_sink_of, run_options, warn


def add_parser(sub) -> None:
    p = sub.add_parser(
        "live", help="watch a vehicle over MAVLink: estimate in real time, stream to Rerun, record",
        description=textwrap.fill(
            "Connect to a vehicle (or SITL, or 'mavattitude simulate --live'), ask it for its IMU, "
            "ATTITUDE, GPS and baro messages, run the estimators as samples arrive, and show a "
            "status line (rates, packets lost, rolling MAE against the autopilot). Every packet "
            "received is recorded to a .tlog that 'mavattitude replay' reads. Ctrl-C ends the "
            "session cleanly and prints the final metrics.", 79),
        epilog="examples:\n"
               "  mavattitude live                                  # listen on udpin:0.0.0.0:14550\n"
               "  mavattitude live tcp:127.0.0.1:5760 --spawn       # ArduPilot SITL's TCP port, Rerun viewer\n"
               "  mavattitude live /dev/ttyUSB0 --baud 57600 --estimators all --web\n"
               "  mavattitude live udpin:0.0.0.0:14550 --no-request --no-record   # listen only\n",
        formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("url", nargs="?", default="udpin:0.0.0.0:14550",
                   help="a pymavlink connection string: udpin:HOST:PORT, udpout:HOST:PORT, tcp:HOST:PORT, "
                        "or a serial device (default udpin:0.0.0.0:14550)")
    p.add_argument("--baud", type=COUNT, default=115200, help="serial baud rate (default 115200)")
    p.add_argument("--sysid", type=number(1, 255, whole=True), default=None, metavar="ID",
                   help="the vehicle's MAVLink system id (default: the first autopilot heard)")
    estimation_args(p, "vehicle")
    trim_arg(p)
    p.add_argument("--imu-rate", type=POSITIVE, default=50.0, metavar="HZ",
                   help="IMU rate to ask the vehicle for (default 50; ATTITUDE up to 50 Hz, GPS 5 Hz, "
                        "baro up to 10 Hz)")
    p.add_argument("--no-request", action="store_true",
                   help="do not ask for rates: leave the vehicle's streams as they are (listen-only links)")
    p.add_argument("--window", type=POSITIVE, default=10.0, metavar="S",
                   help="seconds of the rolling metrics (default 10)")
    p.add_argument("--timeout", type=POSITIVE, default=5.0, metavar="S",
                   help="seconds without packets before the link counts as lost (default 5)")
    p.add_argument("--duration", type=POSITIVE, default=None, metavar="S",
                   help="stop after this many seconds (default: run until Ctrl-C)")
    rec = p.add_argument_group("recording")
    rec.add_argument("--record", metavar="FILE",
                     help="the .tlog every received packet goes to (default live-<UTC time>.tlog)")
    rec.add_argument("--no-record", action="store_true", help="do not record")
    rec.add_argument("--json", metavar="FILE", help="write the final metrics as JSON")
    force_arg(rec)
    viewer_args(p.add_argument_group("viewer (one of)").add_mutually_exclusive_group())
    p.set_defaults(func=run)


def run(args) -> int:
    from ..live import LiveOptions, default_record_path, run_live
    from ..core.warmup import warm_up
    from ..live.session import check_ended_with_vehicle, loss_text
    from ..commands.report import format_table, nothing_scored, write_json
    from ..events import grouped_lines
    from ..scoring.refcheck import suspect_event

    names = estimator_names(args.estimators)
    options = run_options(args, names)  # the parameters checked now; the vehicle's defaults join them later
    from ..live.link import MAX_REQUEST_HZ, MIN_REQUEST_HZ
    if not MIN_REQUEST_HZ <= args.imu_rate <= MAX_REQUEST_HZ:
        raise UsageError(f"--imu-rate {args.imu_rate:g}: MAVLink asks for rates from {MIN_REQUEST_HZ:.3g} Hz "
                         f"(an interval of 2^31-1 µs) to {MAX_REQUEST_HZ:g} Hz")
    if args.record and args.no_record:
        raise UsageError("choose --record FILE or --no-record, not both")
    with Outputs(inputs=[args.params], force=args.force) as outputs:
        record = None if args.no_record else outputs.new_file(args.record or default_record_path(), "--record")
        json_out = outputs.file(args.json, "--json", "json")
        sink = plan_sink_of(args, outputs)
        compile_kernels(names).wait()
        warm_up(names, options.user_params())
        result = run_live(LiveOptions(
            url=args.url, baud=args.baud, sysid=args.sysid, run=options, imu_rate=args.imu_rate,
            request=not args.no_request, window=args.window, timeout=args.timeout,
            record=str(record) if record else None, duration=args.duration, sink=sink))
        print(f"session: {result.seconds:.1f} s, {result.monitor.packets} packets ("
              + loss_text(result.monitor, result.estimation.samples_lost, result.kernel_drops)
              + f"), {result.estimation.samples} IMU samples estimated"
              + (f"; {result.recorded} packets recorded to {record}" if record else ""))
        check_ended_with_vehicle(result, args.url)
        suspects = result.estimation.suspects
        if result.comparisons:
            n_segments = len(result.estimation.segments)
            where = (f" (clock segment {result.segment} of {n_segments}: the vehicle rebooted)"
                     if n_segments > 1 else "")
            print(f"final metrics against {result.reference} after a {args.warmup:g} s warm-up{where}:")
            for line in grouped_lines([suspect_event(s) for s in suspects]):  # as replay says them
                warn(line)
            for note in result.estimation.reference_notes:
                warn(note.detail)
            print(format_table(result.comparisons, result.reference, result.estimation.declination_choice))
            why = nothing_scored(result.comparisons, args.warmup)
            if why:
                warn(why)
        else:
            print("nothing scored: " + ("no IMU samples were estimated" if not result.estimation.samples
                                        else "no reference attitude (ATTITUDE / SIMSTATE) arrived"))
        if json_out:
            with json_out.writing() as path:
                write_json(path, args.url, {"stream": result.reference, "algorithm": None, "choice": args.reference},
                           result.comparisons, link=result.link(),
                           declination=result.estimation.declination_choice, scoring=live_scoring(result.estimation))
            print(f"metrics written to {json_out.path}")
        if sink is not None and sink.kind == "rrd":
            print(f"Rerun recording written to {sink.file.path}; open it with: rerun {sink.file.path}")
    return 0


def live_scoring(est) -> dict:
    """The JSON's "scoring" of a session, as replay's (``ReplayResult.scoring``) has it: the board
    trim applied and the spans of reference not scored (``refcheck``)."""
    trim = None if est.trim is None else {"roll_deg": round(math.degrees(est.trim[0]), 4),
                                          "pitch_deg": round(math.degrees(est.trim[1]), 4)}
    return {"board_trim": trim, "reference_suspect": [s.as_dict() for s in est.suspects],
            "reference_notes": [n.as_dict() for n in est.reference_notes]}
