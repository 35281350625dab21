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
            wide[log.name] = metrics
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
    """A row per log: its reference (stream, algorithm) and the autopilot's own spread (the
    smallest tilt error of its other streams against the reference), then each estimator's
    roll / pitch / yaw MAE; a log whose IMU is too slow to mean anything is marked so, not bolded."""
    names = list(dict.fromkeys(n for metrics in table.values() for n in metrics["estimators"]))
    print("| log | reference | spread | " + " | ".join(names) + " |")
    print("|---|---|---|" + "---|" * len(names))
    for log, metrics in table.items():
        per_log = metrics["estimators"]
        ref = metrics["reference"]
        spread = (metrics.get("reference_spread_deg") or {}).get("tilt")
        meaningful = all(m.get("meaningful", True) for m in per_log.values())
        tilt = {n: (m["roll"]["mae"] + m["pitch"]["mae"]) / 2 for n, m in per_log.items()
                if m["roll"] and m["pitch"]}
        best = min(tilt, key=tilt.get) if tilt and meaningful else None
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
        said = f"{ref['stream']} ({ref['algorithm']})" + ("" if meaningful else "; not meaningful (IMU too slow)")
        print(f"| `{log}` | {said} | {'-' if spread is None else f'{spread:.2f}'} | " + " | ".join(cells) + " |")
    print("\nroll / pitch / yaw MAE in degrees; bold: the lowest mean of roll and pitch MAE on the log. Spread: the "
          "smallest tilt error (mean of roll and pitch MAE) of the autopilot's other attitude streams against the "
          "reference: a lead smaller than it is not meaningful.\n\\* yaw drift: no heading reference, its initial "
          "offset removed.")


if __name__ == "__main__":
    sys.exit(main())
