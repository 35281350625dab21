"""The ``mavattitude`` command: a thin layer over readers, pipeline, report and view.

Exit status (one rule for every command; the README lists it):

- 0 success;
- 1 a file, folder, device or endpoint named on the command line cannot be used: a log that
  cannot be read or lacks what was asked of it (an IMU source, a clock segment, ground
  truth), a parameter file with bad TOML or a bad value, an output that would write over an
  input or another kind of file or cannot be created, a viewer or link that fails. One line
  on stderr names it and says what is wrong;
- 2 the command line itself is wrong, whatever the files hold: an unknown option, estimator
  or parameter, a value out of its range, options that exclude each other, a malformed URL;
- 130 interrupted (Ctrl-C); 141 the reader of our output went away (``| head``).
"""
from __future__ import annotations

import argparse
import json
import math
import os
import re
import sys
import textwrap
import time
from pathlib import Path

from . import __version__, signals
from .errors import InputError, UsageError, is_interrupt
from .outputs import Outputs, json_text
from .trim import describe as describe_trim

DESCRIPTION = """\
Replay flight logs (ArduPilot .bin DataFlash, MAVLink .tlog telemetry, PX4 .ulg ULog) through
attitude estimators and compare each estimate with the autopilot's own attitude (ATT /
ATTITUDE / vehicle_attitude) or, where the log has it, simulator ground truth (SIM / SIMSTATE /
vehicle_attitude_groundtruth)."""

EPILOG = """\
examples:
  mavattitude info flight.bin
  mavattitude replay flight.bin --estimators mahony --rrd flight.rrd --json metrics.json
  mavattitude replay sitl.tlog --reference truth --export out/
  mavattitude replay flight.bin --estimators all --set ncs-eskf.h_threshold_air=0.02
  mavattitude evaluate ../logs --estimators all -j 4 --out evaluation/
  mavattitude tune ../logs --estimator mahony -o tuned.toml
  mavattitude estimators
  mavattitude simulate --scenario figure8 --duration 120 -o figure8.tlog
  mavattitude live udpin:0.0.0.0:14550 --estimators all --spawn
  mavattitude simulate --live udpout:127.0.0.1:14550   # a simulated vehicle for 'live'
  mavattitude bench --json bench.json
"""


def _read(path: str, segment: int | None, quiet: bool = False):
    from .progress import ProgressBar
    from .readers import read_log

    with ProgressBar(f"reading {os.path.basename(path)}", os.path.getsize(path) if os.path.isfile(path) else None,
                     "B", quiet) as progress:
        return read_log(path, segment=segment, progress=progress)


def _compile(names: list[str], quiet: bool = False, log: str | None = None):
    """Start compiling what these estimators need and is not cached yet (said on stderr, and
    then, but for ``quiet``, each as it is done and the time so far). ``log``: the log to be
    read here, whose reader compiles as it reads (the caller says ``done("log reader")``)."""
    from .estimators import needs_compile
    from .progress import StepsLine
    from .readers import reader_needs_compile
    from .warmup import precompile

    pending = needs_compile(names)
    also = ["log reader"] if log is not None and reader_needs_compile(log) else []
    if not pending and not also:
        return precompile(pending)
    print(f"compiling {', '.join(also + pending)} (first run on this machine only; cached afterwards) ...",
          file=sys.stderr, flush=True)
    return precompile(pending, StepsLine("compiling (first run only)", quiet=quiet), also)


def _warn(text: str) -> None:
    print(f"warning: {text}", file=sys.stderr)


# ---------------------------------------------------------------- info


def cmd_info(args) -> int:
    from .info import render, summarize

    info = summarize(_read(args.log, args.segment, args.quiet))
    if args.json:
        print(json.dumps(info, indent=2))
    else:
        print(render(info))
    return 0


# ---------------------------------------------------------------- replay


def _estimator_names(text: str) -> list[str]:
    from .estimators import ESTIMATORS, all_names, available

    names = []  # 'all' is ours, in a list too: all,vqf,imufusion
    for n in (n.strip() for n in text.split(",")):
        names += [m for m in (all_names() if n == "all" else [n] if n else []) if m not in names]
    unknown = [n for n in names if n not in ESTIMATORS]
    if unknown or not names:
        raise UsageError(f"unknown estimator(s) {', '.join(unknown) or '(none given)'}; "
                         f"choose from: {', '.join(ESTIMATORS)} (or 'all')")
    if "autopilot" in names:
        raise UsageError("'autopilot' is the name of the autopilot's own row; it is not an estimator")
    for n in names:
        if available(n):
            raise UsageError(available(n))
    return names


def _plan_sink(args, outputs, default_rrd: str | None = None):
    """The checked Rerun sink of --rrd/--spawn/--connect/--web (mutually exclusive in the
    parser), ``default_rrd`` when none is given; None for no view."""
    from .sink import plan_sink

    for kind in ("rrd", "spawn", "connect", "web"):
        value = getattr(args, kind)
        if value:
            return plan_sink(kind, value, outputs)
    return plan_sink("rrd", default_rrd, outputs) if default_rrd else None


def _replay_settings(args, names: list[str]):
    """The checked ReplaySettings of replay's and evaluate's shared options."""
    from .params import load_file
    from .pipeline import ReplaySettings

    settings = ReplaySettings(
        names=tuple(names), reference=args.reference, imu=args.imu, imu_family=args.imu_family, warmup_s=args.warmup,
        declination_deg=args.declination_deg, home=args.home, use_mag=not args.no_mag, trim=not args.no_trim,
        segment=args.segment,
        file_values=load_file(args.params) if args.params else None,
        assignments=tuple(args.set or ()), params_source=args.params or "--params")
    settings.check()  # bad values fail before any log is read
    return settings


def cmd_replay(args) -> int:
    from .events import grouped_lines
    from .pipeline import choose_imu, replay_flight
    from .progress import ProgressBar
    from .report import (csv_file_name, estimator_extras, format_events, format_table, nothing_scored,
                         write_csv, write_json)
    from .sink import open_sink

    names = _estimator_names(args.estimators)
    settings = _replay_settings(args, names)
    with Outputs(inputs=[args.log, args.params], force=args.force) as outputs:
        json_out = outputs.file(args.json, "--json", "json")
        export = outputs.folder(args.export, "--export", only="csv")
        csv_outs = {n: outputs.file(export / csv_file_name(n), "--export", "csv")
                    for n in ("reference", *names)} if export else {}
        sink = None if args.no_view else _plan_sink(args, outputs, default_rrd=Path(args.log).stem + ".rrd")
        rec = open_sink(sink, "mavattitude", Path(args.log).name) if sink else None  # fails now, not later
        compiling = _compile(names, args.quiet, args.log)  # in other processes, while the log is read
        flight = _read(args.log, args.segment, args.quiet)
        compiling.done("log reader")
        compiling.wait()
        with ProgressBar(f"estimating with {len(names)} estimator{'s' if len(names) > 1 else ''}",
                         len(flight.imu[choose_imu(flight, settings.imu, settings.imu_family)].t),
                         "samples", args.quiet) as progress:
            # the whole estimates only for the view, unless --export writes them
            result, notes = replay_flight(flight, settings, progress, compact=not export)
        for note in notes:
            print(f"note: {note}")
        # one line per kind, before the table: they say how to read it, and on stderr they stay
        # on the screen when the table goes to a file
        for line in grouped_lines(result.events):
            _warn(line)
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
                from .broadscore import format_broad_table
                print(format_broad_table(broad))
            why = nothing_scored(result.comparisons, args.warmup)
            if why:
                _warn(why)
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
        if rec is not None:
            _view(result, rec, sink)
    return 0


# ---------------------------------------------------------------- evaluate


def _logs_to_run(args) -> list[str]:
    """The logs PATH... names (evaluate, tune), once the --scheduler, if any, answers."""
    from .evaluate import check_scheduler, find_logs

    if args.scheduler:
        check_scheduler(args.scheduler)
    passed: list[str] = []
    logs = find_logs(args.paths, passed)
    for path in passed:
        print(f"note: passed by {path}: not a regular file", file=sys.stderr)
    if not logs:
        raise InputError(", ".join(args.paths), "holds no .bin, .tlog, .ulg log or BROAD trial (.hdf5)")
    return logs


def cmd_evaluate(args) -> int:
    from . import evalreport as er
    from .broadscore import broad_text
    from .evaluate import Progress, run_logs

    names = _estimator_names(args.estimators)
    if args.ship_logs and not args.scheduler:
        raise UsageError("--ship-logs goes with --scheduler (local workers read the logs themselves)")
    if args.baseline not in names:
        _estimator_names(args.baseline)  # a known estimator, or a usage error
        names.append(args.baseline)
        print(f"note: the baseline {args.baseline} is run too", file=sys.stderr)
    settings = _replay_settings(args, names)
    logs = _logs_to_run(args)
    with Outputs(inputs=[*logs, args.params], force=args.force) as outputs:
        out = outputs.folder(args.out, "--out")  # its files are claimed one by one below
        files = {name: outputs.file(out / name, "--out", kind) for name, kind in (
            ("results.csv", "csv"), ("summary.json", "json"), ("report.md", "md"), ("tilt_error.svg", "svg"),
            ("results.parquet", "parquet"))}
        records_dir = out / "logs"
        records_dir.mkdir(exist_ok=True)
        if not args.scheduler:
            _compile(names, args.quiet).wait()  # once here, not in every worker
        where = f"on the Dask cluster at {args.scheduler}" if args.scheduler else \
            f"in {min(args.jobs, len(logs))} process{'es' if min(args.jobs, len(logs)) > 1 else ''}"
        print(f"evaluating {', '.join(names)} on {len(logs)} logs {where}; records in {records_dir}/",
              file=sys.stderr)
        progress = Progress(len(logs), quiet=args.quiet)
        try:
            records = run_logs(logs, settings, records_dir, args.jobs, scheduler=args.scheduler,
                               ship_logs=args.ship_logs, force=args.force, progress=progress)
        finally:
            progress.close()
        rows = er.result_rows(records)
        summary = er.summarize(records, names, args.baseline, args.reference)
        command = "mavattitude evaluate " + " ".join(sys.argv[2:]) if sys.argv[1:2] == ["evaluate"] else \
            "mavattitude evaluate"
        broad = broad_text(records, names)  # BROAD trials: the dataset's measures, per trial and group
        texts = {"results.csv": er.results_csv(rows), "summary.json": er.summary_json(summary),
                 "report.md": er.report_markdown(summary, command, "tilt_error.svg")
                 + (f"\n## BROAD's measures\n\n```\n{broad}```\n" if broad else ""),
                 "tilt_error.svg": er.strip_plot_svg(records, names)}
        for name, text in texts.items():
            with files[name].writing() as path:
                Path(path).write_text(text)
        parquet = er.has_parquet()
        if parquet:
            with files["results.parquet"].writing() as path:
                er.write_parquet(rows, path)
    print(er.ranking_text(summary))
    if broad:
        print(broad)
    print(f"{len(records)} logs: {summary['scored']} scored, {len(summary['not_meaningful'])} not meaningful, "
          f"{len(summary['failed'])} failed, "
          f"{len(summary['skipped'])} skipped; written to {out}/ (report.md, summary.json, results.csv"
          f"{', results.parquet' if parquet else ''}, tilt_error.svg)")
    if records and len(summary["failed"]) == len(records):  # some failing among others is a result; all is not
        raise InputError(", ".join(args.paths), f"every one of the {len(records)} logs failed; "
                                                f"the reasons are above and in {out / 'report.md'}")
    return 0


# ---------------------------------------------------------------- tune


def cmd_tune(args) -> int:
    from .evaluate import Workers
    from .tune import TrialProgress, TuneSettings, open_study, report_text, space_for, tune, tuned_toml

    try:
        import optuna  # noqa: F401 - only to say now that it is missing
    except ImportError:
        raise UsageError("tune needs Optuna: pip install 'mavattitude[tune]'") from None
    name = _estimator_names(args.estimator)
    if len(name) != 1:
        raise UsageError("--estimator takes one estimator: tune fits one at a time")
    name = name[0]
    if args.ship_logs and not args.scheduler:
        raise UsageError("--ship-logs goes with --scheduler (local workers read the logs themselves)")
    settings = TuneSettings(name, _replay_settings(args, [name]), trials=args.trials, folds=args.folds,
                            objective=args.objective, seed=args.seed)
    space_for(settings)  # nothing to search is a usage error, before any log is read
    logs = _logs_to_run(args)
    with Outputs(inputs=[*logs, args.params], force=args.force) as outputs:
        toml_out = outputs.file(args.output or f"tuned-{name}.toml", "-o", "toml")
        json_out = outputs.file(args.json, "--json", "json")
        study = outputs.database(args.study, "--study")
        storage = open_study(study) if study else None
        if not args.scheduler:
            _compile([name], args.quiet).wait()  # once here, not in every worker
        jobs = min(args.jobs, len(logs))
        where = f"on the Dask cluster at {args.scheduler}" if args.scheduler else \
            f"in {jobs} process{'es' if jobs > 1 else ''}"
        folds = f"{args.folds}-fold cross-validation, then a fit on all logs" if args.folds >= 2 else \
            "no cross-validation, a fit on all logs"
        print(f"tuning {name} on {len(logs)} log{'s' if len(logs) != 1 else ''} {where}: {args.trials} trials per fit, {folds}; "
              + (f"study in {study} (a stopped run resumes)" if study else
                 "study in memory (--study FILE keeps it, so that a stopped run resumes)"), file=sys.stderr)
        progress = TrialProgress(name, quiet=args.quiet)
        try:
            with Workers(jobs, args.scheduler, args.ship_logs, keep=True) as workers:
                result = tune(logs, settings, workers, storage, progress)
        finally:
            progress.close()
        command = "mavattitude " + " ".join(sys.argv[1:]) if sys.argv[1:2] == ["tune"] else "mavattitude tune"
        with toml_out.writing() as path:
            Path(path).write_text(tuned_toml(result, settings, command))
        if json_out:
            with json_out.writing() as path:
                Path(path).write_text(json_text(result.as_dict(), indent=1))
    print(report_text(result))
    print(f"parameters written to {toml_out.path}: use them with --params {toml_out.path}"
          + (f"; the full results in {json_out.path}" if json_out else ""))
    return 0


def _view(result, rec, sink) -> None:
    from . import view
    from .sink import close_sink

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


# ---------------------------------------------------------------- estimators


def cmd_estimators(args) -> int:
    from .estimators import ESTIMATORS, available, summary
    from .estimators.rivals import INSTALL
    from .params import describe, search_space

    if args.json:
        print(json.dumps({name: {"summary": summary(cls), "uses_magnetometer": cls.uses_mag,
                                 "params": {f: {"default": d, "valid": str(v) if v else None, "help": h,
                                                "tune": str(search_space(cls.Params)[f])
                                                if f in search_space(cls.Params) else None}
                                            for f, d, v, h in describe(cls.Params)},
                                 "diagnostics": dict(cls.DIAGNOSTICS),
                                 "accel_states": list(cls.ACCEL_STATES)}
                          for name, cls in ESTIMATORS.items()}, indent=2))
        return 0
    for name, cls in ESTIMATORS.items():
        heading = "heading from the magnetometer" if cls.uses_mag else "no heading reference (yaw from the gyro)"
        optional = f" (optional: {INSTALL}; not installed)" if available(name) else ""
        print(f"{name}: {summary(cls)}{optional}")
        print(f"  {heading}")
        rows = describe(cls.Params)
        searched = search_space(cls.Params)
        width = max((len(f) for f, _, _, _ in rows), default=0)
        for field, default, valid, help_text in rows:
            tune = f"  [tune: {searched[field]}]" if field in searched else ""
            print(f"  --set {name}.{field:<{width}} = {default!s:<8} {str(valid or 'true/false'):<11} "
                  f"{help_text}{tune}".rstrip())
        for key, text in cls.DIAGNOSTICS.items():
            print(f"  diagnostic {key}: {text}")
        print()
    print("Override parameters with --set NAME.PARAM=VALUE or a TOML file (--params FILE) with a "
          "[NAME] table per estimator; each value must lie in the interval shown after its default. "
          "'mavattitude tune' searches the parameters marked [tune: scale [low, high]].")
    return 0


# ---------------------------------------------------------------- simulate


def cmd_simulate(args) -> int:
    from .sim import SCENARIOS, simulate, write_log

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
    _check_sim_length(args.duration, args.imu_rate)
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


def _check_sim_length(duration: float, imu_rate: float, options: str = "--duration/--imu-rate") -> None:
    """A usage error, before any work, when the simulator cannot make that flight."""
    from .sim import Rates
    from .sim.simflight import check_length

    try:
        check_length(duration, Rates(imu=imu_rate))
    except ValueError as exc:
        raise UsageError(f"{options}: {exc}") from None


def _simulate_live(args) -> int:
    import signal

    from .live.link import open_link
    from .sim import simulate
    from .sim.autopilot import SimAutopilot

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


# ---------------------------------------------------------------- live


def cmd_live(args) -> int:
    from .live import LiveOptions, default_record_path, run_live
    from .warmup import warm_up
    from .live.session import check_ended_with_vehicle, loss_text
    from .params import build, load_file
    from .report import format_table, nothing_scored, write_json

    names = _estimator_names(args.estimators)
    params = build(names, load_file(args.params) if args.params else None, args.set or (),
                   source=args.params or "--params")
    from .live.link import MAX_REQUEST_HZ, MIN_REQUEST_HZ
    if not MIN_REQUEST_HZ <= args.imu_rate <= MAX_REQUEST_HZ:
        raise UsageError(f"--imu-rate {args.imu_rate:g}: MAVLink asks for rates from {MIN_REQUEST_HZ:.3g} Hz "
                         f"(an interval of 2^31-1 µs) to {MAX_REQUEST_HZ:g} Hz")
    if args.record and args.no_record:
        raise UsageError("choose --record FILE or --no-record, not both")
    with Outputs(inputs=[args.params], force=args.force) as outputs:
        record = None if args.no_record else outputs.new_file(args.record or default_record_path(), "--record")
        json_out = outputs.file(args.json, "--json", "json")
        sink = _plan_sink(args, outputs)
        _compile(names).wait()
        warm_up(names, params)
        result = run_live(LiveOptions(
            url=args.url, baud=args.baud, sysid=args.sysid, names=names, params=params,
            imu_rate=args.imu_rate, request=not args.no_request, imu_source=args.imu, window=args.window,
            timeout=args.timeout, record=str(record) if record else None, warmup=args.warmup,
            declination_deg=args.declination_deg, home=args.home, reference=args.reference, use_mag=not args.no_mag,
            trim=not args.no_trim, duration=args.duration, sink=sink))
        print(f"session: {result.seconds:.1f} s, {result.monitor.packets} packets ("
              + loss_text(result.monitor, result.estimation.samples_lost, result.kernel_drops)
              + f"), {result.estimation.samples} IMU samples estimated"
              + (f"; {result.recorded} packets recorded to {record}" if record else ""))
        check_ended_with_vehicle(result, args.url)
        if result.comparisons:
            n_segments = len(result.estimation.segments)
            where = (f" (clock segment {result.segment} of {n_segments}: the vehicle rebooted)"
                     if n_segments > 1 else "")
            print(f"final metrics against {result.reference} after a {args.warmup:g} s warm-up{where}:")
            print(format_table(result.comparisons, result.reference, result.estimation.declination_choice))
            why = nothing_scored(result.comparisons, args.warmup)
            if why:
                _warn(why)
        else:
            print("nothing scored: " + ("no IMU samples were estimated" if not result.estimation.samples
                                        else "no reference attitude (ATTITUDE / SIMSTATE) arrived"))
        if json_out:
            with json_out.writing() as path:
                write_json(path, args.url, {"stream": result.reference, "algorithm": None, "choice": args.reference},
                           result.comparisons, link=result.link(),
                           declination=result.estimation.declination_choice)
            print(f"metrics written to {json_out.path}")
        if sink is not None and sink.kind == "rrd":
            print(f"Rerun recording written to {sink.file.path}; open it with: rerun {sink.file.path}")
    return 0


# ---------------------------------------------------------------- bench


def cmd_bench(args) -> int:
    from .bench import run

    names = _estimator_names(args.estimators)
    if args.log and not args.read:
        raise UsageError("--log is for --read (the reading figures)")
    _check_sim_length(args.duration, args.imu_rate)
    if args.live:
        from .bench_live import LIVE_IMU_HZ, SETTLE_S
        _check_sim_length(args.live_seconds + SETTLE_S, LIVE_IMU_HZ, f"--live-seconds plus {SETTLE_S:g} s of settling")
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
    from .bench_read import format_read, run_read_bench
    from .readers import sniff_format

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


# ---------------------------------------------------------------- parser


def _number(low: float, high: float = math.inf, *, above: bool = False, whole: bool = False):
    """An argparse type: a finite number from ``low`` (excluded with ``above``) to ``high``;
    ``whole`` for integers. Anything else is a usage error naming the option."""
    def parse(text: str):
        try:
            value = float(text)
        except ValueError:
            value = math.nan
        ok = math.isfinite(value) and (value > low if above else value >= low) and value <= high
        if ok and whole and value != int(value):
            ok = False
        if not ok:
            kind = "a whole number" if whole else "a number"
            shown = (lambda x: f"{x:.0f}") if whole else (lambda x: f"{x:g}")  # 4294967295, not 4.29497e+09
            bound = f"above {shown(low)}" if above else f"at least {shown(low)}"
            limit = f" and at most {shown(high)}" if math.isfinite(high) else ""
            raise argparse.ArgumentTypeError(f"expected {kind} {bound}{limit}, not {text!r}")
        return int(value) if whole else value
    parse.__name__ = "number"
    return parse


SECONDS = _number(0.0)  # zero or more
POSITIVE = _number(0.0, above=True)
COUNT = _number(1, whole=True)
DEGREES = _number(-180.0, 180.0)
SEED = _number(0, 2**32 - 1, whole=True)


def _home(text: str):
    """An argparse type: --home LAT,LON[,ALT] (``declination.parse_home``); a usage error otherwise."""
    from .declination import parse_home

    try:
        return parse_home(text)
    except ValueError as exc:
        raise argparse.ArgumentTypeError(str(exc)) from None


_home.__name__ = "LAT,LON"


class _Parser(argparse.ArgumentParser):
    """argparse with one-line usage errors, as every other error here is; a value that starts
    with a minus and a digit is a value, not an option (``--home -35.36,149.17``), as Python
    3.13's argparse has it (before, only a plain negative number was)."""

    def __init__(self, *args, **kwargs):
        super().__init__(*args, **kwargs)
        self._negative_number_matcher = re.compile(r"-\.?\d")

    def error(self, message):
        self.exit(2, f"{self.prog}: error: {message} (see '{self.prog} --help')\n")

    def _get_values(self, action, arg_strings):
        # argparse without CPython's fix gh-109475 (early 2024; 3.11.7 has it not) drops a value
        # of exactly '--' (--seed=--) as if it were the separator: the option gets [] and its
        # type and choices are never checked. Take the value as given, as the fix does.
        if action.option_strings and action.nargs is None and arg_strings == ["--"]:
            value = self._get_value(action, "--")
            self._check_value(action, value)
            return value
        return super()._get_values(action, arg_strings)


def quiet_arg(p) -> None:
    p.add_argument("-q", "--quiet", action="store_true",
                   help="no progress display (it shows on a terminal only, for work over 2 s)")


def _estimation_args(p, source: str, estimators: bool = True) -> None:
    """The options replay, evaluate, tune and live share: what to run, with what, against what.
    ``source``: "log" or "vehicle", for the help texts; ``estimators``: with --estimators."""
    if estimators:
        p.add_argument("--estimators", default="mahony", metavar="LIST",
                       help="comma-separated estimator names, 'all' (ours) among them, e.g. "
                            "all,vqf,imufusion (default: mahony)")
    if source == "log":
        p.add_argument("--reference", default="autopilot", metavar="NAME",
                       help="what to score against: 'autopilot' (its attitude in use: ATT/ATTITUDE/"
                            "vehicle_attitude, default), 'truth' (the simulator's: SIM/SIMSTATE/"
                            "vehicle_attitude_groundtruth), 'ekf' (the autopilot's EKF where the log has one; evaluate "
                            "skips a log without) or any attitude stream 'mavattitude info' lists (EKF1, AHR2, XKF1[1], "
                            "...; any case). The autopilot's other streams are scored against it too, as rows "
                            "'autopilot:ALGORITHM (STREAM)'; with truth the attitude in use is the row 'autopilot'")
    else:
        p.add_argument("--reference", choices=("autopilot", "truth"), default="autopilot",
                       help="score against the autopilot's attitude (ATTITUDE, default) or the simulator's ground "
                            "truth (SIMSTATE); with truth the autopilot is scored too, as the row 'autopilot'")
    p.add_argument("--imu", default=None, metavar="SOURCE",
                   help="IMU source to estimate from, e.g. IMU[1], RAW_IMU, SCALED_IMU2, HIGHRES_IMU "
                        "(default: the fastest, most precise" + ("; see 'mavattitude info')" if source == "log"
                                                                 else " that arrives; live asks for it)"))
    if source == "log":
        quiet_arg(p)
        from .flight import DEFAULT_FAMILIES, IMU_FAMILIES
        p.add_argument("--imu-source", choices=list(IMU_FAMILIES), default=None, dest="imu_family",
                       help="which kind of IMU data to estimate from: " + "; ".join(
                           f"{k}: {v}" for k, v in IMU_FAMILIES.items()) + " (default: the first of "
                           f"{', '.join(DEFAULT_FAMILIES)} the log has; --imu picks one series)")
    p.add_argument("--warmup", type=SECONDS, default=10.0, metavar="S",
                   help="seconds at the start not scored while estimators converge (default 10)")
    p.add_argument("--declination", type=DEGREES, default=None, metavar="DEG", dest="declination_deg",
                   help=f"magnetic declination in degrees, east positive, -180 to 180 (default: the "
                        f"{source}'s COMPASS_DEC where set by hand (COMPASS_AUTODEC=0; PX4: EKF2_MAG_DECL), "
                        "else the World Magnetic Model at --home or the first good GPS fix on the "
                        f"{source}'s date, as the autopilot computes it; else 0 with a warning)")
    p.add_argument("--home", type=_home, default=None, metavar="LAT,LON",
                   help="where the vehicle flew, degrees (LAT,LON,ALT: metres above sea level too): "
                        "the declination from the World Magnetic Model there, for a "
                        f"{source} without a GPS fix (it takes the place of the fix; a declination set by "
                        "hand on the autopilot still wins)")
    p.add_argument("--no-mag", action="store_true",
                   help="ignore the magnetometer: yaw from the gyro only, compared after removing "
                        "its initial offset")
    p.add_argument("--set", action="append", metavar="NAME.PARAM=VALUE",
                   help="override an estimator parameter, e.g. ncs-eskf.h_threshold_air=0.02 "
                        "(repeatable; see 'mavattitude estimators')")
    p.add_argument("--params", metavar="FILE",
                   help="a TOML file of parameters, a [NAME] table per estimator; --set wins over it")


def _workers_args(p, keeping: bool = False) -> None:
    """Where evaluate and tune replay their logs: local processes or a Dask cluster.
    ``keeping``: each worker keeps the logs it read (tune replays them once per trial)."""
    keeps = ", each keeping the logs it read" if keeping else ""
    p.add_argument("-j", "--jobs", type=COUNT, default=os.cpu_count() or 1, metavar="N",
                   help=f"logs replayed at once, one process each{keeps} (default: the CPUs, {os.cpu_count()})")
    p.add_argument("--scheduler", metavar="ADDRESS",
                   help="replay on a Dask distributed cluster, e.g. tcp://HOST:8786 (pip install "
                        "'mavattitude[cluster]'); its workers read the logs at the same paths")
    p.add_argument("--ship-logs", action="store_true",
                   help="with --scheduler: send each log's bytes to the worker (workers without the files)")


def _viewer_args(group) -> None:
    """Where the Rerun recording goes: one of these (a mutually exclusive group)."""
    group.add_argument("--rrd", metavar="FILE", help="write the Rerun recording to FILE")
    group.add_argument("--spawn", action="store_true", help="stream to a newly spawned Rerun viewer")
    group.add_argument("--connect", metavar="URL",
                       help="stream to a running Rerun viewer, e.g. rerun+http://127.0.0.1:9876/proxy")
    group.add_argument("--web", action="store_true",
                       help="serve Rerun's web viewer (ports 9090 and 9876, or the next free ones) until Ctrl-C")


def build_parser() -> argparse.ArgumentParser:
    parser = _Parser(prog="mavattitude", description=DESCRIPTION, epilog=EPILOG,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--version", action="version", version=f"mavattitude {__version__}")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")

    def force_arg(p):
        p.add_argument("--force", action="store_true",
                       help="write an output over an existing file of another kind (never over an "
                            "input log or parameter file)")

    def trim_arg(p):
        p.add_argument("--no-trim", action="store_true",
                       help="score the estimates as estimated: without turning them by the log's board "
                            "trim (AHRS_TRIM_X/Y) first, as the autopilot turns its own attitude")

    def segment_arg(p):
        p.add_argument("--segment", type=_number(0, whole=True), default=None, metavar="N",
                       help="when the autopilot rebooted during the log (its clock went back), "
                            "use clock segment N (0-based); default: the longest")

    p = sub.add_parser("info", help="what a log holds: sensors, rates, vehicle, clock",
                       description="Summarise a log: duration, message counts and rates, IMU sources, "
                                   "vehicle and firmware, sensors, accelerometer-norm statistics.")
    p.add_argument("log", help="a .bin (DataFlash), .tlog (telemetry) or .ulg (PX4 ULog) file")
    p.add_argument("--json", action="store_true", help="print the summary as JSON on stdout")
    segment_arg(p)
    quiet_arg(p)
    p.set_defaults(func=cmd_info)

    p = sub.add_parser("replay", help="run estimators over a log, score them, write a Rerun recording",
                       description="Run attitude estimators over a log's IMU, compare each with the "
                                   "reference attitude (per axis: MAE, RMSE, max, R², degrees), and "
                                   "write a Rerun recording. Without a sink option the recording goes "
                                   "to <log name>.rrd in the current folder.",
                       formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("log", help="a .bin (DataFlash), .tlog (telemetry) or .ulg (PX4 ULog) file")
    _estimation_args(p, "log")
    trim_arg(p)
    segment_arg(p)
    out = p.add_argument_group("outputs")
    out.add_argument("--json", metavar="FILE", help="write the metrics as JSON")
    out.add_argument("--export", metavar="DIR",
                     help="write DIR/reference.csv and DIR/<estimator>.csv (time_s,roll_deg,pitch_deg,yaw_deg)")
    view = out.add_mutually_exclusive_group()
    _viewer_args(view)
    view.add_argument("--no-view", action="store_true", help="no Rerun recording at all")
    force_arg(out)
    p.set_defaults(func=cmd_replay)

    p = sub.add_parser(
        "evaluate", help="replay many logs and rank the estimators across them",
        description="Replay every log (as 'replay' does, without a viewer) and rank the estimators "
                    "by their tilt error (mean of roll and pitch MAE) across the logs. Writes, in --out: "
                    "report.md (ranking, figure, paper checks, worst logs, failures), summary.json, "
                    "results.csv (a row per log, estimator and axis; Parquet too with pyarrow), "
                    "tilt_error.svg, and a record per log in logs/. A stopped run resumes: logs with a "
                    "record made with the same options are not replayed again (--force redoes them). "
                    "A log that fails is listed with its reason; the others go on (exit status 1 "
                    "only when every log failed).",
        epilog="examples:\n  mavattitude evaluate ../logs --estimators all\n"
               "  mavattitude evaluate 'flights/**/*.bin' --estimators mahony,ncs-eskf -j 8 --out eval/\n"
               "  mavattitude evaluate /shared/logs --estimators all --scheduler tcp://10.0.0.5:8786",
        formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("paths", nargs="+", metavar="PATH",
                   help="log files, folders (searched recursively for .bin/.tlog/.ulg logs and BROAD .hdf5 trials) or glob patterns")
    _estimation_args(p, "log")
    p.add_argument("--baseline", default="mahony", metavar="NAME",
                   help="the estimator ratios are taken to (default mahony; run too if not listed)")
    _workers_args(p)
    p.add_argument("--out", default="evaluation", metavar="DIR", help="where the results go (default evaluation/)")
    trim_arg(p)
    segment_arg(p)
    force_arg(p)
    p.set_defaults(func=cmd_evaluate)

    p = sub.add_parser(
        "tune", help="fit an estimator's parameters to your logs, cross-validated by log",
        description=textwrap.fill(
            "Search an estimator's parameters (those 'mavattitude estimators' shows with a search range) "
            "for the lowest tilt error (mean of roll and pitch MAE) over the logs, each replayed as "
            "'evaluate' replays it, with Optuna's TPE sampler (pip install 'mavattitude[tune]'). First "
            "K-fold cross-validation by log: each fold's logs are held out while the others are fitted, "
            "then scored with the defaults and with that fit, so the held-out figures say what tuning "
            "gains on flights it has not seen. Then a fit on all the logs, written as TOML for --params. "
            "The first trial of every fit is the starting point (the defaults, or --params); --set fixes "
            "a parameter. A log that makes a trial diverge counts as 90 degrees.", 79),
        epilog="examples:\n"
               "  mavattitude tune ../logs --estimator mahony\n"
               "  mavattitude tune flights/ --estimator ncs-eskf --trials 100 --study ncs.db -o ncs.toml\n"
               "  mavattitude tune sitl/ --estimator eq-kf --reference truth --set eq-kf.use_mag=false\n"
               "  mavattitude replay flight.bin --estimators mahony --params tuned-mahony.toml\n",
        formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("paths", nargs="+", metavar="PATH",
                   help="log files, folders (searched recursively for .bin/.tlog/.ulg logs and BROAD .hdf5 trials) or glob patterns")
    p.add_argument("--estimator", required=True, metavar="NAME", help="the estimator to tune")
    p.add_argument("--trials", type=COUNT, default=50, metavar="N",
                   help="trials per fit (default 50); the run makes (folds + 1) fits")
    p.add_argument("--folds", type=_number(0, whole=True), default=5, metavar="K",
                   help="folds of the cross-validation by log (default 5; 0 or 1: none, fit on all logs only)")
    p.add_argument("--objective", choices=("median", "mean", "geomean"), default="median",
                   help="what a trial minimises over its logs' tilt errors: median (default), mean, or "
                        "geomean, the geometric mean, which weighs each log's change by its ratio")
    p.add_argument("--seed", type=SEED, default=0, help="seed of the folds and the sampler (default 0)")
    _estimation_args(p, "log", estimators=False)
    _workers_args(p, keeping=True)
    p.add_argument("--study", metavar="FILE",
                   help="keep the trials in this SQLite file: run the same command again to resume a "
                        "stopped run (default: in memory)")
    p.add_argument("-o", "--output", metavar="FILE",
                   help="where the tuned parameters go, as TOML for --params (default tuned-NAME.toml)")
    p.add_argument("--json", metavar="FILE",
                   help="write every fit, fold and held-out log's tilt error as JSON")
    trim_arg(p)
    segment_arg(p)
    force_arg(p)
    p.set_defaults(func=cmd_tune)

    p = sub.add_parser("estimators", help="list the estimators with their parameters and defaults",
                       description="List every estimator: the paper it follows, whether it uses the "
                                   "magnetometer, its parameters with defaults and units, and the "
                                   "diagnostics it records.")
    p.add_argument("--json", action="store_true", help="print the list as JSON")
    p.set_defaults(func=cmd_estimators)

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
    p.set_defaults(func=cmd_simulate)

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
    p.add_argument("--sysid", type=_number(1, 255, whole=True), default=None, metavar="ID",
                   help="the vehicle's MAVLink system id (default: the first autopilot heard)")
    _estimation_args(p, "vehicle")
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
    _viewer_args(p.add_argument_group("viewer (one of)").add_mutually_exclusive_group())
    p.set_defaults(func=cmd_live)

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
    p.set_defaults(func=cmd_bench)
    return parser


def main(argv=None) -> int:
    program = argv is None  # the process's own command line, not a caller's (a test, a script)
    previous = signals.install()  # first: a stop signal during the imports below is one line too
    try:
        code = _main(argv)
    except KeyboardInterrupt:  # before the command started, or as it ended
        code = _interrupted()
    finally:
        if program:
            signals.ignore()  # done: the interpreter's exit is not cut short
        else:
            signals.restore(previous)  # a caller's own handlers back
    if program and code == signals.exit_code():
        # stopped wherever it was (an import, LLVM mid-compile, Rerun's start): the interpreter's
        # exit can crash on what was left half done (SIGSEGV seen); end here, everything closed
        _release_pool_semaphores()
        sys.stdout.flush()
        sys.stderr.flush()
        os._exit(code)
    return code


def _release_pool_semaphores() -> None:
    """Unlink the named semaphores of a process pool stopped mid-run, as the interpreter's exit
    would (their multiprocessing finalizers): os._exit skips that, and multiprocessing's
    resource tracker then printed a warning about leaked semaphores after 'interrupted'."""
    if "multiprocessing" in sys.modules:
        from multiprocessing import util

        util._run_finalizers(0)  # only those of priority >= 0: the semaphores, not joining processes


def _main(argv) -> int:
    # Rerun's own log lines would repeat, in Rust's format, what our one-line errors say.
    os.environ.setdefault("RUST_LOG", "off")
    parser = build_parser()
    try:
        args = parser.parse_args(argv)
    except SystemExit as exc:  # --help (0) or a usage error argparse has printed (2)
        return exc.code
    if not getattr(args, "func", None):
        parser.print_help()
        return 2
    from .estimators import load_plugins
    for problem in load_plugins():
        _warn(problem)
    code = _run(args)
    from .sink import shutdown
    try:
        closed = shutdown()
    except KeyboardInterrupt:
        closed = False
    if not closed:
        print("mavattitude: the Rerun viewer stopped answering; closed without it", file=sys.stderr)
        # Rerun's exit handler would wait for that viewer forever: end here, everything written and closed
        sys.stdout.flush()
        sys.stderr.flush()
        os._exit(code)
    return code


def _interrupted() -> int:
    """A stop signal's one line ('interrupted') and exit status (130; 143 for SIGTERM)."""
    print(signals.message(), file=sys.stderr)
    return signals.exit_code()


def _run(args) -> int:
    """Run the command; every error becomes one line on stderr and its exit status."""
    try:
        try:
            return args.func(args)
        except (SystemError, InputError, UsageError, OSError) as exc:
            # a Ctrl-C inside a compiled kernel comes back as a SystemError; and once told to
            # stop, whatever ends the command is the stop's doing
            if signals.received() is not None or is_interrupt(exc):
                raise KeyboardInterrupt from exc
            raise  # a SystemError that is no interrupt: a bug, whose traceback is the report
    except InputError as exc:
        print(f"mavattitude: error: {exc}", file=sys.stderr)
        return 1
    except UsageError as exc:
        print(f"mavattitude: error: {exc}", file=sys.stderr)
        return 2
    except BrokenPipeError:  # our reader went away (`| head`): stop quietly, as Unix tools do
        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
        return 141
    except OSError as exc:  # an output we cannot write, a port in use
        name = f"{exc.filename}: " if exc.filename else ""
        print(f"mavattitude: error: {name}{exc.strerror or exc}", file=sys.stderr)
        return 1
    except KeyboardInterrupt:
        return _interrupted()


if __name__ == "__main__":
    sys.exit(main())
