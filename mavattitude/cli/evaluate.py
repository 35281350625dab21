"""``mavattitude evaluate``: many logs replayed, the estimators ranked across them."""
from __future__ import annotations

import argparse
import sys
from pathlib import Path

from ..errors import InputError, UsageError
from ..outputs import Outputs
from .args import estimation_args, force_arg, segment_arg, trim_arg, workers_args
from .common import compile_kernels, estimator_names, logs_to_run, run_options


def add_parser(sub) -> None:
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
    estimation_args(p, "log")
    p.add_argument("--baseline", default="mahony", metavar="NAME",
                   help="the estimator ratios are taken to (default mahony; run too if not listed)")
    workers_args(p)
    p.add_argument("--out", default="evaluation", metavar="DIR", help="where the results go (default evaluation/)")
    p.add_argument("--rrd", metavar="FILE", help="also a Rerun recording of the run: each log's tilt error per "
                                                 "estimator, a line per log with the replay command for its own")
    trim_arg(p)
    segment_arg(p)
    force_arg(p)
    p.set_defaults(func=run)


def run(args) -> int:
    from ..commands import evalreport as er
    from ..scoring.broadscore import broad_text
    from ..commands.evaluate import Progress, run_logs, write_recording

    names = estimator_names(args.estimators)
    if args.ship_logs and not args.scheduler:
        raise UsageError("--ship-logs goes with --scheduler (local workers read the logs themselves)")
    if args.baseline not in names:
        estimator_names(args.baseline)  # a known estimator, or a usage error
        names.append(args.baseline)
        print(f"note: the baseline {args.baseline} is run too", file=sys.stderr)
    settings = run_options(args, names)
    logs = logs_to_run(args)
    with Outputs(inputs=[*logs, args.params], force=args.force) as outputs:
        out = outputs.folder(args.out, "--out")  # its files are claimed one by one below
        files = {name: outputs.file(out / name, "--out", kind) for name, kind in (
            ("results.csv", "csv"), ("summary.json", "json"), ("report.md", "md"), ("tilt_error.svg", "svg"),
            ("results.parquet", "parquet"))}
        rrd = outputs.file(args.rrd, "--rrd", "rrd") if args.rrd else None
        records_dir = out / "logs"
        records_dir.mkdir(exist_ok=True)
        if not args.scheduler:
            compile_kernels(names, args.quiet).wait()  # once here, not in every worker
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
        if rrd is not None:
            with rrd.writing() as path:
                write_recording(path, records, names, args.reference, texts["report.md"])
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
          f"{', results.parquet' if parquet else ''}, tilt_error.svg)" + (f"; the recording {args.rrd}" if args.rrd else ""))
    if records and len(summary["failed"]) == len(records):  # some failing among others is a result; all is not
        raise InputError(", ".join(args.paths), f"every one of the {len(records)} logs failed; "
                                                f"the reasons are above and in {out / 'report.md'}")
    return 0
