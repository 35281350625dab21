#!/usr/bin/env python3
"""Replay every log in ../shared/logs with `mavattitude replay` and print a Markdown table of
roll / pitch / yaw MAE per estimator (the README's accuracy table comes from this).

    python scripts/replay_shared_logs.py [--estimators mahony] [--reference NAME] [--wide] [LOGS_DIR]

``--wide``: one row per log, one column per estimator with "roll / pitch / yaw" MAE, and the
best mean roll+pitch MAE of the row in bold.
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
    parser.add_argument("--reference", default="autopilot", help="as replay's: autopilot, truth, ekf or a stream")
    parser.add_argument("--wide", action="store_true", help="one row per log, a column per estimator")
    args = parser.parse_args()
    logs = sorted(p for p in Path(args.logs).glob("*") if p.suffix in (".bin", ".tlog"))
    if not logs:
        print(f"no .bin or .tlog files in {args.logs}", file=sys.stderr)
        return 1
    rows = []
    wide = {}
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
            wide[log.name] = metrics["estimators"]
            for name, m in metrics["estimators"].items():
                yaw = m["yaw"]
                yaw_text = "n/a" if yaw is None else f"{yaw['mae']:.2f}" + ("*" if yaw.get("aligned") else "")
                rows.append(f"| `{log.name}` | {name} | {m['roll']['mae']:.2f} | {m['pitch']['mae']:.2f} "
                            f"| {yaw_text} |")
            print(rows[-1], file=sys.stderr)
    if args.wide:
        print_wide(wide)
        return 0
    print("| log | estimator | roll MAE ° | pitch MAE ° | yaw MAE ° |")
    print("|---|---|---|---|---|")
    print("\n".join(rows))
    print("\n\\* yaw compared after removing its initial offset: no magnetometer in the log.")
    return 0


def print_wide(table: dict) -> None:
    names = list(dict.fromkeys(n for per_log in table.values() for n in per_log))
    print("| log | " + " | ".join(names) + " |")
    print("|---|" + "---|" * len(names))
    for log, per_log in table.items():
        tilt = {n: (m["roll"]["mae"] + m["pitch"]["mae"]) / 2 for n, m in per_log.items()
                if m["roll"] and m["pitch"]}
        best = min(tilt, key=tilt.get) if tilt else None
        cells = []
        for n in names:
            m = per_log.get(n)
            if not m or not m["roll"]:
                cells.append("n/a")
                continue
            yaw = m["yaw"]
            yaw_text = "n/a" if yaw is None else f"{yaw['mae']:.2f}" + ("*" if yaw.get("aligned") else "")
            text = f"{m['roll']['mae']:.2f} / {m['pitch']['mae']:.2f} / {yaw_text}"
            cells.append(f"**{text}**" if n == best else text)
        print(f"| `{log}` | " + " | ".join(cells) + " |")
    print("\nroll / pitch / yaw MAE in degrees; bold: the lowest mean of roll and pitch MAE on the log."
          "\n\\* yaw compared after removing its initial offset: no heading reference.")


if __name__ == "__main__":
    sys.exit(main())
