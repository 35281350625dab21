"""``mavattitude tune``: an estimator's parameters fitted to logs, cross-validated by log."""
from __future__ import annotations

import argparse
import sys
import textwrap
from pathlib import Path

from ..errors import UsageError
from ..outputs import Outputs, json_text
from .args import COUNT, SEED, estimation_args, force_arg, number, segment_arg, trim_arg, workers_args
from .common import compile_kernels, estimator_names, logs_to_run, replay_settings


def add_parser(sub) -> None:
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
    p.add_argument("--folds", type=number(0, whole=True), default=5, metavar="K",
                   help="folds of the cross-validation by log (default 5; 0 or 1: none, fit on all logs only)")
    p.add_argument("--objective", choices=("median", "mean", "geomean"), default="median",
                   help="what a trial minimises over its logs' tilt errors: median (default), mean, or "
                        "geomean, the geometric mean, which weighs each log's change by its ratio")
    p.add_argument("--seed", type=SEED, default=0, help="seed of the folds and the sampler (default 0)")
    estimation_args(p, "log", estimators=False)
    workers_args(p, keeping=True)
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
    p.set_defaults(func=run)


def run(args) -> int:
    from ..commands.evaluate import Workers
    from ..commands.tune import TrialProgress, TuneSettings, open_study, report_text, space_for, tune, tuned_toml

    try:
        import optuna  # noqa: F401 - only to say now that it is missing
    except ImportError:
        raise UsageError("tune needs Optuna: pip install 'mavattitude[tune]'") from None
    name = estimator_names(args.estimator)
    if len(name) != 1:
        raise UsageError("--estimator takes one estimator: tune fits one at a time")
    name = name[0]
    if args.ship_logs and not args.scheduler:
        raise UsageError("--ship-logs goes with --scheduler (local workers read the logs themselves)")
    settings = TuneSettings(name, replay_settings(args, [name]), trials=args.trials, folds=args.folds,
                            objective=args.objective, seed=args.seed)
    space_for(settings)  # nothing to search is a usage error, before any log is read
    logs = logs_to_run(args)
    with Outputs(inputs=[*logs, args.params], force=args.force) as outputs:
        toml_out = outputs.file(args.output or f"tuned-{name}.toml", "-o", "toml")
        json_out = outputs.file(args.json, "--json", "json")
        study = outputs.database(args.study, "--study")
        storage = open_study(study) if study else None
        if not args.scheduler:
            compile_kernels([name], args.quiet).wait()  # once here, not in every worker
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
