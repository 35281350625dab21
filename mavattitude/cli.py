"""The ``mavattitude`` command: a thin layer over readers, pipeline, report and view.

Exit status: 0 success, 1 a bad input (one line on stderr naming the file and the
problem), 2 a usage error, 130 interrupted.
"""
from __future__ import annotations

import argparse
import json
import os
import sys
import time
from pathlib import Path

from . import __version__
from .errors import InputError, UsageError

DESCRIPTION = """\
Replay ArduPilot flight logs (.bin DataFlash, .tlog telemetry) through attitude estimators
and compare each estimate with the autopilot's own attitude (ATT / ATTITUDE) or, where the
log has it, simulator ground truth (SIM / SIMSTATE)."""

EPILOG = """\
examples:
  mavattitude info flight.bin
  mavattitude replay flight.bin --estimators mahony --rrd flight.rrd --json metrics.json
  mavattitude replay sitl.tlog --reference truth --export out/
  mavattitude replay flight.bin --estimators all --set ncs-eskf.h_threshold_air=0.02
  mavattitude estimators
  mavattitude simulate --scenario figure8 --duration 120 -o figure8.tlog
  mavattitude bench --json bench.json
"""


class _Progress:
    """A one-line progress display on stderr, only when stderr is a terminal."""

    def __init__(self, label: str):
        self.label = label
        self.last = 0.0
        # Our own handle on the terminal: the reader captures stderr while pymavlink decodes.
        self.stream = os.fdopen(os.dup(sys.stderr.fileno()), "w") if sys.stderr.isatty() else None

    def __call__(self, fraction: float) -> None:
        now = time.monotonic()
        if self.stream and (now - self.last > 0.2 or fraction >= 1.0):
            self.last = now
            print(f"\r{self.label}: {100 * fraction:5.1f} %", end="", file=self.stream, flush=True)

    def done(self) -> None:
        if self.stream:
            print("\r" + " " * (len(self.label) + 10) + "\r", end="", file=self.stream, flush=True)
            self.stream.close()


def _read(path: str, segment: int | None):
    from .readers import read_log

    progress = _Progress(f"reading {os.path.basename(path)}")
    try:
        return read_log(path, segment=segment, progress=progress)
    finally:
        progress.done()


def _warn(text: str) -> None:
    print(f"warning: {text}", file=sys.stderr)


# ---------------------------------------------------------------- info


def cmd_info(args) -> int:
    from .info import render, summarize

    info = summarize(_read(args.log, args.segment))
    if args.json:
        print(json.dumps(info, indent=2))
    else:
        print(render(info))
    return 0


# ---------------------------------------------------------------- replay


def _estimator_names(text: str) -> list[str]:
    from .estimators import ESTIMATORS

    names = list(ESTIMATORS) if text.strip() == "all" else [n.strip() for n in text.split(",") if n.strip()]
    unknown = [n for n in names if n not in ESTIMATORS]
    if unknown or not names:
        raise UsageError(f"unknown estimator(s) {', '.join(unknown) or '(none given)'}; "
                         f"choose from: {', '.join(ESTIMATORS)} (or 'all')")
    if "autopilot" in names:
        raise UsageError("'autopilot' is the name of the autopilot's own row; it is not an estimator")
    return names


def _sink_args(args, log_path: str) -> dict:
    chosen = [x for x in ("rrd", "spawn", "connect", "web") if getattr(args, x)]
    if len(chosen) > 1:
        raise UsageError(f"choose one Rerun sink, not {' and '.join('--' + c for c in chosen)}")
    if not chosen:
        return {"rrd": Path(log_path).stem + ".rrd"}
    return {chosen[0]: getattr(args, chosen[0])}


def cmd_replay(args) -> int:
    from .estimators import needs_compile
    from .pipeline import Event, run_replay
    from .report import estimator_extras, format_events, format_table, write_csv, write_json

    from .params import build, load_file, log_defaults

    names = _estimator_names(args.estimators)
    if args.warmup < 0:
        raise UsageError("--warmup must be zero or more seconds")
    file_values = load_file(args.params) if args.params else None
    source = args.params or "--params"
    params = build(names, file_values, args.set or (), source=source)  # bad values fail before reading
    sink = None if args.no_view else _sink_args(args, args.log)
    flight = _read(args.log, args.segment)
    log_values, notes = log_defaults(flight, names, file_values, args.set or ())
    if log_values:
        params = build(names, file_values, args.set or (), source=source, log_values=log_values)
    pending = needs_compile(names)
    if pending:
        print(f"compiling {', '.join(pending)} (first run on this machine only; cached afterwards) ...",
              file=sys.stderr, flush=True)
    result = run_replay(flight, names, reference=args.reference, imu_source=args.imu,
                        warmup_s=args.warmup, declination_deg=args.declination,
                        params=params, use_mag=not args.no_mag)
    result.events += [Event(flight.time_span[0], "info", note) for note in notes]
    for note in notes:
        print(f"note: {note}")
    for event in result.events:
        if event.level == "warn":
            _warn(event.text)
    if result.reference is not None:
        print(f"{flight.path}: {len(result.flight.imu[result.imu_source].t)} samples of "
              f"{result.imu_source}, scored against {result.reference.source} "
              f"({args.reference}) after a {args.warmup:g} s warm-up")
        print(format_table(result.comparisons, result.reference.source))
    print(format_events(result), end="")
    if args.json:
        write_json(args.json, flight.path, result.reference.source if result.reference else "none",
                   result.comparisons, estimator_extras(result))
        print(f"metrics written to {args.json}")
    if args.export:
        if result.reference is None:
            raise UsageError("--export needs a reference attitude, and the log has none")
        written = write_csv(args.export, result.reference, result.estimates)
        print(f"CSV written to {args.export}/ ({', '.join(p.name for p in written.values())})")
    if sink is not None:
        _view(result, sink, args.log)
    return 0


def _view(result, sink: dict, log_path: str) -> None:
    from . import view

    rec = view.open_sink("mavattitude", Path(log_path).name, **sink)
    view.log_replay(result, rec)
    if "web" in sink:
        print("serving the recording to the web viewer; press Ctrl-C to stop", file=sys.stderr)
        try:
            while True:
                time.sleep(1)
        except KeyboardInterrupt:
            pass
    view.close_sink(rec)
    if "rrd" in sink:
        print(f"Rerun recording written to {sink['rrd']}; open it with: rerun {sink['rrd']}")


# ---------------------------------------------------------------- estimators


def cmd_estimators(args) -> int:
    from .estimators import ESTIMATORS, summary
    from .params import describe

    if args.json:
        print(json.dumps({name: {"summary": summary(cls), "uses_magnetometer": cls.uses_mag,
                                 "params": {f: {"default": d, "help": h} for f, d, h in describe(cls.Params)},
                                 "diagnostics": dict(cls.DIAGNOSTICS),
                                 "accel_states": list(cls.ACCEL_STATES)}
                          for name, cls in ESTIMATORS.items()}, indent=2))
        return 0
    for name, cls in ESTIMATORS.items():
        heading = "heading from the magnetometer" if cls.uses_mag else "no heading reference (yaw from the gyro)"
        print(f"{name}: {summary(cls)}")
        print(f"  {heading}")
        rows = describe(cls.Params)
        width = max((len(f) for f, _, _ in rows), default=0)
        for field, default, help_text in rows:
            print(f"  --set {name}.{field:<{width}} = {default!s:<10} {help_text}".rstrip())
        for key, text in cls.DIAGNOSTICS.items():
            print(f"  diagnostic {key}: {text}")
        print()
    print("Override parameters with --set NAME.PARAM=VALUE or a TOML file (--params FILE) with a "
          "[NAME] table per estimator.")
    return 0


# ---------------------------------------------------------------- simulate


def cmd_simulate(args) -> int:
    from .sim import SCENARIOS, simulate, write_log

    if args.list:
        for name, description in SCENARIOS.items():
            print(f"{name:12s} {description}")
        return 0
    if not args.output:
        raise UsageError("simulate needs -o FILE.tlog or FILE.bin (or --list)")
    if args.scenario not in SCENARIOS:
        raise UsageError(f"unknown scenario {args.scenario!r}; choose from: {', '.join(SCENARIOS)}")
    if Path(args.output).suffix.lower() not in (".tlog", ".bin"):
        raise UsageError(f"{args.output}: the output must end in .tlog or .bin")
    if args.duration <= 0 or args.imu_rate <= 0:
        raise UsageError("--duration and --imu-rate must be positive")
    sim = simulate(args.scenario, args.duration, seed=args.seed, imu_rate=args.imu_rate)
    path = write_log(sim, args.output)
    print(f"{path}: {args.scenario}, {args.duration:g} s, IMU {args.imu_rate:g} Hz, seed {args.seed} "
          f"({path.stat().st_size / 1e6:.2f} MB)")
    return 0


# ---------------------------------------------------------------- bench


def cmd_bench(args) -> int:
    from .bench import run

    return run(_estimator_names(args.estimators), args.scenario, args.duration, args.imu_rate,
               args.seed, args.repeat, args.imufusion_samples, args.json)


# ---------------------------------------------------------------- parser


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="mavattitude", description=DESCRIPTION, epilog=EPILOG,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--version", action="version", version=f"mavattitude {__version__}")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")

    def segment_arg(p):
        p.add_argument("--segment", type=int, default=None, metavar="N",
                       help="when the autopilot rebooted during the log (its clock went back), "
                            "use clock segment N (0-based); default: the longest")

    p = sub.add_parser("info", help="what a log holds: sensors, rates, vehicle, clock",
                       description="Summarise a log: duration, message counts and rates, IMU sources, "
                                   "vehicle and firmware, sensors, accelerometer-norm statistics.")
    p.add_argument("log", help="a .bin (DataFlash) or .tlog (telemetry) file")
    p.add_argument("--json", action="store_true", help="print the summary as JSON on stdout")
    segment_arg(p)
    p.set_defaults(func=cmd_info)

    p = sub.add_parser("replay", help="run estimators over a log, score them, write a Rerun recording",
                       description="Run attitude estimators over a log's IMU, compare each with the "
                                   "reference attitude (per axis: MAE, RMSE, max, R², degrees), and "
                                   "write a Rerun recording. Without a sink option the recording goes "
                                   "to <log name>.rrd in the current folder.",
                       formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("log", help="a .bin (DataFlash) or .tlog (telemetry) file")
    p.add_argument("--estimators", default="mahony", metavar="LIST",
                   help="comma-separated estimator names, or 'all' (default: mahony)")
    p.add_argument("--reference", choices=("autopilot", "truth"), default="autopilot",
                   help="score against the autopilot's attitude (ATT/ATTITUDE, default) or the "
                        "simulator's ground truth (SIM/SIMSTATE); with truth the autopilot is "
                        "scored too, as the row 'autopilot'")
    p.add_argument("--imu", default=None, metavar="SOURCE",
                   help="IMU source to estimate from, e.g. IMU[1], RAW_IMU, SCALED_IMU2, HIGHRES_IMU "
                        "(default: the fastest, most precise; see 'mavattitude info')")
    p.add_argument("--warmup", type=float, default=10.0, metavar="S",
                   help="seconds at the start not scored while estimators converge (default 10)")
    p.add_argument("--declination", type=float, default=None, metavar="DEG",
                   help="magnetic declination in degrees, east positive (default: the log's "
                        "COMPASS_DEC, else 0 with a warning)")
    p.add_argument("--no-mag", action="store_true",
                   help="ignore the magnetometer: yaw from the gyro only, compared after removing "
                        "its initial offset")
    p.add_argument("--set", action="append", metavar="NAME.PARAM=VALUE",
                   help="override an estimator parameter, e.g. ncs-eskf.h_threshold_air=0.02 "
                        "(repeatable; see 'mavattitude estimators')")
    p.add_argument("--params", metavar="FILE",
                   help="a TOML file of parameters, a [NAME] table per estimator; --set wins over it")
    segment_arg(p)
    out = p.add_argument_group("outputs")
    out.add_argument("--json", metavar="FILE", help="write the metrics as JSON")
    out.add_argument("--export", metavar="DIR",
                     help="write DIR/reference.csv and DIR/<estimator>.csv (time_s,roll_deg,pitch_deg,yaw_deg)")
    view = out.add_mutually_exclusive_group()
    view.add_argument("--rrd", metavar="FILE", help="write the Rerun recording to FILE")
    view.add_argument("--spawn", action="store_true", help="stream to a newly spawned Rerun viewer")
    view.add_argument("--connect", metavar="URL",
                      help="stream to a running Rerun viewer, e.g. rerun+http://127.0.0.1:9876/proxy")
    view.add_argument("--web", action="store_true",
                      help="serve the recording to Rerun's web viewer until Ctrl-C")
    view.add_argument("--no-view", action="store_true", help="no Rerun recording at all")
    p.set_defaults(func=cmd_replay)

    p = sub.add_parser("estimators", help="list the estimators with their parameters and defaults",
                       description="List every estimator: the paper it follows, whether it uses the "
                                   "magnetometer, its parameters with defaults and units, and the "
                                   "diagnostics it records.")
    p.add_argument("--json", action="store_true", help="print the list as JSON")
    p.set_defaults(func=cmd_estimators)

    p = sub.add_parser("simulate", help="write a simulated flight with known truth as .tlog or .bin",
                       description="Simulate a flight (rigid-body trajectory and sensor models) and "
                                   "write it as a genuine ArduPilot .tlog (MAVLink 2) or DataFlash "
                                   ".bin with ground truth (SIMSTATE / SIM).")
    p.add_argument("--scenario", default="figure8", help="scenario name (see --list; default figure8)")
    p.add_argument("--duration", type=float, default=120.0, metavar="S", help="seconds (default 120)")
    p.add_argument("--imu-rate", type=float, default=100.0, metavar="HZ", help="IMU rate (default 100)")
    p.add_argument("--seed", type=int, default=0, help="sensor-noise seed (default 0)")
    p.add_argument("-o", "--output", metavar="FILE", help="output file: .tlog or .bin")
    p.add_argument("--list", action="store_true", help="list the scenarios and exit")
    p.set_defaults(func=cmd_simulate)

    p = sub.add_parser("bench", help="time every estimator on a simulated flight, against imufusion",
                       description="Simulate a flight (default: 1 h at 400 Hz), time each estimator's "
                                   "update() over all of it (best of --repeat; compiled first), and "
                                   "imufusion's Ahrs called per sample from Python on part of it, with "
                                   "and without the magnetometer. Prints samples/s, the ratio to "
                                   "imufusion and whether the targets are met (every estimator >= 5x "
                                   "imufusion, cpf-ekf >= 1x, mahony >= 1 M samples/s). imufusion "
                                   "is optional: "
                                   'pip install "mavattitude[bench]".')
    p.add_argument("--estimators", default="all", metavar="LIST",
                   help="comma-separated estimator names, or 'all' (default: all)")
    p.add_argument("--scenario", default="figure8", help="simulated scenario (default figure8)")
    p.add_argument("--duration", type=float, default=3600.0, metavar="S",
                   help="simulated seconds (default 3600)")
    p.add_argument("--imu-rate", type=float, default=400.0, metavar="HZ", help="IMU rate (default 400)")
    p.add_argument("--seed", type=int, default=0, help="sensor-noise seed (default 0)")
    p.add_argument("--repeat", type=int, default=3, metavar="N",
                   help="time each run N times and keep the best (default 3)")
    p.add_argument("--imufusion-samples", type=int, default=200_000, metavar="N",
                   help="samples imufusion's Python loop is timed on (default 200000)")
    p.add_argument("--json", metavar="FILE", help="write the results as JSON")
    p.set_defaults(func=cmd_bench)
    return parser


def main(argv=None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    if not getattr(args, "func", None):
        parser.print_help()
        return 2
    try:
        return args.func(args)
    except InputError as exc:
        print(f"mavattitude: error: {exc}", file=sys.stderr)
        return 1
    except UsageError as exc:
        print(f"mavattitude: error: {exc}", file=sys.stderr)
        return 2
    except OSError as exc:  # an output we cannot write, a port in use
        name = f"{exc.filename}: " if exc.filename else ""
        print(f"mavattitude: error: {name}{exc.strerror or exc}", file=sys.stderr)
        return 1
    except KeyboardInterrupt:
        print("interrupted", file=sys.stderr)
        return 130


if __name__ == "__main__":
    sys.exit(main())
