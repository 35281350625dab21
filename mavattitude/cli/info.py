"""``mavattitude info``: what a log holds."""
from __future__ import annotations

import json

from .args import quiet_arg, segment_arg
from .common import read_log_file


def add_parser(sub) -> None:
    p = sub.add_parser("info", help="what a log holds: sensors, rates, vehicle, clock",
                       description="Summarise a log: duration, message counts and rates, IMU sources, "
                                   "vehicle and firmware, sensors, accelerometer-norm statistics.")
    p.add_argument("log", help="a .bin (DataFlash), .tlog (telemetry) or .ulg (PX4 ULog) file")
    p.add_argument("--json", action="store_true", help="print the summary as JSON on stdout")
    segment_arg(p)
    quiet_arg(p)
    p.set_defaults(func=run)


def run(args) -> int:
    from ..commands.info import render, summarize

    info = summarize(read_log_file(args.log, args.segment, args.quiet))
    if args.json:
        print(json.dumps(info, indent=2))
    else:
        print(render(info))
    return 0
