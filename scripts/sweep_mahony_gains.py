#!/usr/bin/env python3
"""Sweep mahony's Kp and Ki over the shared logs: the worse of roll and pitch MAE (degrees) against
the autopilot's attitude, one row per gain pair, one column per log. How the defaults were chosen.

    python scripts/sweep_mahony_gains.py [--kp 0.1,0.2,0.5,1] [--ki 0,0.0005,0.01,0.05] [LOGS_DIR]
"""
from __future__ import annotations

import argparse
import sys
from pathlib import Path

from mavattitude.estimators.mahony import MahonyParams
from mavattitude.commands.replay import run_replay
from mavattitude.readers import read_log

ROOT = Path(__file__).resolve().parents[1]


def floats(text: str) -> list[float]:
    return [float(x) for x in text.split(",")]


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("logs", nargs="?", default=str(ROOT.parent / "shared" / "logs"))
    parser.add_argument("--kp", type=floats, default=floats("0.1,0.15,0.2,0.3,0.5,1"))
    parser.add_argument("--ki", type=floats, default=floats("0,0.0005,0.002,0.01,0.05"))
    args = parser.parse_args()
    paths = sorted(p for p in Path(args.logs).glob("*") if p.suffix in (".bin", ".tlog"))
    if not paths:
        print(f"no .bin or .tlog files in {args.logs}", file=sys.stderr)
        return 1
    flights = {}
    for p in paths:
        print(f"reading {p.name}", file=sys.stderr)
        flights[p.name] = read_log(str(p))
    names = list(flights)
    print("   kp      ki  " + " ".join(f"{i:>6d}" for i in range(len(names))) + "   worst")
    for kp in args.kp:
        for ki in args.ki:
            cells = []
            for flight in flights.values():
                c = run_replay(flight, ["mahony"], params={"mahony": MahonyParams(kp=kp, ki=ki)})
                cells.append(max(c.comparisons["mahony"].axes["roll"].mae,
                                 c.comparisons["mahony"].axes["pitch"].mae))
            print(f"{kp:5.2f} {ki:7.4f}  " + " ".join(f"{x:6.2f}" for x in cells) + f"  {max(cells):6.2f}",
                  flush=True)
    print("\ncolumns (worse of roll and pitch MAE, degrees):")
    for i, n in enumerate(names):
        print(f"  {i:2d} {n}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
