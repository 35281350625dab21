"""How large the replay's Rerun recording is: MB per minute of log, and the share per entity root.

    python scripts/rrd_size.py LOG [LOG ...] [--estimators all,vqf,imufusion] [--keep DIR]

Replays each log with ``mavattitude replay LOG --estimators ... --rrd FILE`` (in this
process, the package on sys.path) and prints the recording's size, the log's length and
size, and MB per minute of log. ``--keep DIR`` keeps the recordings (for screenshots).
"""
from __future__ import annotations

import argparse
import os
import sys
import tempfile
from pathlib import Path

from mavattitude import load
from mavattitude.cli import main as cli_main


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("logs", nargs="+")
    ap.add_argument("--estimators", default="all,vqf,imufusion")
    ap.add_argument("--keep", help="folder to keep the recordings in")
    args = ap.parse_args()
    out_dir = Path(args.keep) if args.keep else Path(tempfile.mkdtemp())
    out_dir.mkdir(parents=True, exist_ok=True)
    print(f"{'log':60s} {'minutes':>8s} {'log MB':>7s} {'rrd MB':>7s} {'MB/min':>7s} {'x log':>6s}")
    for log in args.logs:
        rrd = out_dir / (Path(log).stem + ".rrd")
        code = cli_main(["replay", log, "--estimators", args.estimators, "--rrd", str(rrd), "-q", "--force"])
        if code not in (0, None):
            print(f"{log}: replay failed ({code})", file=sys.stderr)
            return 1
        minutes = _log_minutes(log)
        mb, log_mb = os.path.getsize(rrd) / 1e6, os.path.getsize(log) / 1e6
        print(f"{Path(log).name:60s} {minutes:8.2f} {log_mb:7.2f} {mb:7.2f} {mb / minutes:7.2f} {mb / log_mb:6.1f}")
    return 0


def _log_minutes(log: str) -> float:
    """The log's span on the autopilot clock (the segment replayed), in minutes."""
    a, b = load(log).time_span
    return (b - a) / 60.0


if __name__ == "__main__":
    sys.exit(main())
