"""What the commands of the command line share: reading a log with its progress, compiling the
kernels first, the estimators named on the command line, the Rerun sink, a run's options."""
from __future__ import annotations

import os
import sys

from ..errors import InputError, UsageError


def read_log_file(path: str, segment: int | None, quiet: bool = False):
    from ..progress import ProgressBar
    from ..readers import read_log

    with ProgressBar(f"reading {os.path.basename(path)}", os.path.getsize(path) if os.path.isfile(path) else None,
                     "B", quiet) as progress:
        return read_log(path, segment=segment, progress=progress)


def compile_kernels(names: list[str], quiet: bool = False, log: str | None = None):
    """Start compiling what these estimators need and is not cached yet (said on stderr, and
    then, but for ``quiet``, each as it is done and the time so far). ``log``: the log to be
    read here, whose reader compiles as it reads (the caller says ``done("log reader")``)."""
    from ..estimators import needs_compile
    from ..progress import StepsLine
    from ..readers import reader_needs_compile
    from ..core.warmup import precompile

    pending = needs_compile(names)
    also = ["log reader"] if log is not None and reader_needs_compile(log) else []
    if not pending and not also:
        return precompile(pending)
    print(f"compiling {', '.join(also + pending)} (first run on this machine only; cached afterwards) ...",
          file=sys.stderr, flush=True)
    return precompile(pending, StepsLine("compiling (first run only)", quiet=quiet), also)


def warn(text: str) -> None:
    print(f"warning: {text}", file=sys.stderr)


def estimator_names(text: str) -> list[str]:
    from ..estimators import ESTIMATORS, all_names, available

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


def plan_sink_of(args, outputs, default_rrd: str | None = None):
    """The checked Rerun sink of --rrd/--spawn/--connect/--web (mutually exclusive in the
    parser), ``default_rrd`` when none is given; None for no view."""
    from ..view.sink import plan_sink

    for kind in ("rrd", "spawn", "connect", "web"):
        value = getattr(args, kind)
        if value:
            return plan_sink(kind, value, outputs)
    return plan_sink("rrd", default_rrd, outputs) if default_rrd else None


def run_options(args, names: list[str]):
    """The checked ``RunOptions`` of the options replay, evaluate, tune and live share."""
    from ..core.params import load_file
    from ..core.policy import RunOptions

    options = RunOptions(
        names=tuple(names), reference=args.reference, imu=args.imu, imu_family=getattr(args, "imu_family", None),
        warmup_s=args.warmup, declination_deg=args.declination_deg, home=args.home, use_mag=not args.no_mag,
        trim=not args.no_trim, segment=getattr(args, "segment", None),  # live has neither
        file_values=load_file(args.params) if args.params else None,
        assignments=tuple(args.set or ()), params_source=args.params or "--params")
    options.check()  # bad values fail before any log is read
    return options


def logs_to_run(args) -> list[str]:
    """The logs PATH... names (evaluate, tune), once the --scheduler, if any, answers."""
    from ..commands.evaluate import check_scheduler, find_logs

    if args.scheduler:
        check_scheduler(args.scheduler)
    passed: list[str] = []
    logs = find_logs(args.paths, passed)
    for path in passed:
        print(f"note: passed by {path}: not a regular file", file=sys.stderr)
    if not logs:
        raise InputError(", ".join(args.paths), "holds no .bin, .tlog, .ulg log or BROAD trial (.hdf5)")
    return logs
