"""``mavattitude replay``: one log through the estimators, scored, its recording written."""
from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

from .. import memory, signals
from ..errors import InputError
from ..outputs import Outputs
from ..trim import describe as describe_trim
from .args import estimation_args, force_arg, segment_arg, trim_arg, viewer_args
from .common import compile_kernels, estimator_names, plan_sink_of, read_log_file, run_options, warn


def add_parser(sub) -> None:
    p = sub.add_parser("replay", help="run estimators over a log, score them, write a Rerun recording",
                       description="Run attitude estimators over a log's IMU, compare each with the "
                                   "reference attitude (per axis: MAE, RMSE, max, R², degrees), and "
                                   "write a Rerun recording. Without a sink option the recording goes "
                                   "to <log name>.rrd in the current folder.",
                       formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("log", help="a .bin (DataFlash), .tlog (telemetry) or .ulg (PX4 ULog) file")
    estimation_args(p, "log")
    trim_arg(p)
    segment_arg(p)
    out = p.add_argument_group("outputs")
    out.add_argument("--json", metavar="FILE", help="write the metrics as JSON")
    out.add_argument("--export", metavar="DIR",
                     help="write DIR/reference.csv and DIR/<estimator>.csv (time_s,roll_deg,pitch_deg,yaw_deg)")
    view = out.add_mutually_exclusive_group()
    viewer_args(view)
    view.add_argument("--no-view", action="store_true", help="no Rerun recording at all")
    force_arg(out)
    p.set_defaults(func=run)


def run(args) -> int:
    from ..events import grouped_lines
    from ..commands.replay import choose_imu, replay_flight
    from ..progress import ProgressBar
    from ..commands.report import (csv_file_name, estimator_extras, format_events, format_table, nothing_scored,
                         write_csv, write_json)
    from ..view.sink import open_sink

    names = estimator_names(args.estimators)
    options = run_options(args, names)
    with Outputs(inputs=[args.log, args.params], force=args.force) as outputs:
        json_out = outputs.file(args.json, "--json", "json")
        export = outputs.folder(args.export, "--export", only="csv")
        csv_outs = {n: outputs.file(export / csv_file_name(n), "--export", "csv")
                    for n in ("reference", *names)} if export else {}
        sink = None if args.no_view else plan_sink_of(args, outputs, default_rrd=Path(args.log).stem + ".rrd")
        # a viewer is opened now, so that one that is not there fails before the read, not after;
        # a file was checked and made by plan_sink, and Rerun (its import: 57 MB, held through the
        # read and the estimation) is opened for it when there is something to write
        rec = open_sink(sink, "mavattitude", Path(args.log).name) if sink and sink.kind != "rrd" else None
        compiling = compile_kernels(names, args.quiet, args.log)  # in other processes, while the log is read
        flight = read_log_file(args.log, args.segment, args.quiet)
        memory.give_back_freed_arrays()  # the estimation's peak: what it holds, not what it once held
        compiling.done("log reader")
        compiling.wait()
        with ProgressBar(f"estimating with {len(names)} estimator{'s' if len(names) > 1 else ''}",
                         len(flight.imu[choose_imu(flight, options.imu, options.imu_family)].t),
                         "samples", args.quiet) as progress:
            # the whole estimates only for the view, unless --export writes them
            result, notes = replay_flight(flight, options, progress, compact=not export)
        for note in notes:
            print(f"note: {note}")
        # one line per kind, before the table: they say how to read it, and on stderr they stay
        # on the screen when the table goes to a file
        for line in grouped_lines(result.events):
            warn(line)
        if result.reference is not None:
            trim = "" if result.trim is None else (
                f"; estimates turned by the board trim ({describe_trim(result.trim)}) as the autopilot's are")
            ref = result.reference_info
            print(f"{flight.path}: {len(result.flight.imu[result.imu_source].t)} samples of "
                  f"{result.imu_source}, scored against {ref.stream} ({ref.algorithm}; --reference {ref.choice}) "
                  f"after a {args.warmup:g} s warm-up{trim}")
            print(format_table(result.comparisons, ref.label, result.declination, streams=result.stream_comparisons,
                               reference_algorithm=ref.algorithm))
            broad = {name: c.broad for name, c in result.comparisons.items() if c.broad is not None}
            if broad:
                from ..scoring.broadscore import format_broad_table
                print(format_broad_table(broad))
            why = nothing_scored(result.comparisons, args.warmup)
            if why:
                warn(why)
        print(format_events(result), end="")
        if json_out:
            with json_out.writing() as path:
                write_json(path, flight.path, result.reference_object, result.comparisons, estimator_extras(result),
                           scoring=result.scoring, events=result.events, declination=result.declination,
                           streams=result.stream_comparisons)
            print(f"metrics written to {json_out.path}")
        if export:
            if result.reference is None:
                raise InputError(args.log, "--export needs a reference attitude (ATT / ATTITUDE), "
                                           "and the log has none")
            for name in set(csv_outs) - {"reference", *result.estimates}:  # no estimate: no file
                csv_outs.pop(name).discard()
            write_csv(export, result.reference, {n: s for n, s in result.estimates.items() if n in csv_outs},
                      paths={name: out.write_path for name, out in csv_outs.items()})
            print(f"CSV written to {export}/ ({', '.join(out.path.name for out in csv_outs.values())})")
        if sink is not None:
            memory.give_back_free_pages()  # what scoring freed, before the view's imports and arrays
            _view(result, rec or open_sink(sink, "mavattitude", Path(args.log).name), sink)
    return 0


def _view(result, rec, sink) -> None:
    from .. import view
    from ..view.sink import close_sink

    view.log_replay(result, rec)
    if sink.kind == "web":
        print("serving the recording to the web viewer; press Ctrl-C to stop", file=sys.stderr)
        try:
            while True:
                time.sleep(1)
        except KeyboardInterrupt:
            signals.rearm()  # that one only ended the serving; the next stops the command
    close_sink(rec, sink)
    if sink.kind == "rrd":  # put in place with the other outputs, when the command ends
        print(f"Rerun recording written to {sink.file.path}; open it with: rerun {sink.file.path}")
