#!/usr/bin/env python3
"""Replay every log in ../shared/logs with `mavattitude replay` and print a Markdown table of
roll / pitch / yaw MAE per estimator (the README's accuracy table comes from this).

    python scripts/replay_shared_logs.py [--estimators mahony] [--reference autopilot|truth] [LOGS_DIR]
"""
from __future__ import annotations

import argparse
import contextlib
import io
import json
import sys
import tempfile
from pathlib import Path

from mavattitude.cli import main as mavattitude

ROOT = Path(__file__).resolve().parents[1]


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("logs", nargs="?", default=str(ROOT.parent / "shared" / "logs"))
    parser.add_argument("--estimators", default="mahony")
    parser.add_argument("--reference", default="autopilot", choices=("autopilot", "truth"))
    args = parser.parse_args()
    logs = sorted(p for p in Path(args.logs).glob("*") if p.suffix in (".bin", ".tlog"))
    if not logs:
        print(f"no .bin or .tlog files in {args.logs}", file=sys.stderr)
        return 1
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        for log in logs:
            out = Path(tmp) / f"{log.stem}.json"
            cmd = ["replay", str(log), "--estimators", args.estimators, "--no-view",
                   "--reference", args.reference, "--json", str(out)]
            if args.reference == "truth" and log.name.startswith(("copter-", "plane-")):
                continue  # real flights have no ground truth
            with contextlib.redirect_stdout(io.StringIO()), contextlib.redirect_stderr(io.StringIO()):
                code = mavattitude(cmd)
            if code != 0:
                rows.append(f"| `{log.name}` | replay failed (exit {code}) | | | |")
                continue
            metrics = json.loads(out.read_text())
            for name, m in metrics["estimators"].items():
                yaw = m["yaw"]
                yaw_text = "n/a" if yaw is None else f"{yaw['mae']:.2f}" + ("*" if yaw.get("aligned") else "")
                rows.append(f"| `{log.name}` | {name} | {m['roll']['mae']:.2f} | {m['pitch']['mae']:.2f} "
                            f"| {yaw_text} |")
            print(rows[-1], file=sys.stderr)
    print(f"| log | estimator | roll MAE ° | pitch MAE ° | yaw MAE ° |")
    print("|---|---|---|---|---|")
    print("\n".join(rows))
    print("\n\\* yaw compared after removing its initial offset: no magnetometer in the log.")
    return 0


if __name__ == "__main__":
    sys.exit(main())
