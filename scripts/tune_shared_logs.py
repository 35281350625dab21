#!/usr/bin/env python3
"""Tune every estimator on the shared logs with 5-fold cross-validation by log, and tabulate the
default vs tuned tilt error on the held-out logs: the figures of the README's "Tuning" section.

    python scripts/tune_shared_logs.py [--logs ../shared/logs] [--trials 50] [--out tuning/]

Runs ``mavattitude tune LOGS --estimator NAME --folds 5 --trials N --study OUT/study.db
--json OUT/NAME.json -o OUT/NAME.toml`` for each estimator (a stopped run resumes from the study),
then prints, per estimator, the held-out median and mean with the defaults and tuned, the logs
made better and worse, and the fit on all logs.
"""
from __future__ import annotations

import argparse
import json
import subprocess
import sys
from pathlib import Path

from mavattitude.estimators import ESTIMATORS
from mavattitude.commands.tune import OBJECTIVES, aggregate

ROOT = Path(__file__).resolve().parents[1]


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--logs", default=str(ROOT.parent / "shared" / "logs"))
    parser.add_argument("--trials", type=int, default=50)
    parser.add_argument("--folds", type=int, default=5)
    parser.add_argument("--objective", default="median", choices=OBJECTIVES)
    parser.add_argument("--estimators", default=",".join(ESTIMATORS))
    parser.add_argument("--out", default="tuning")
    parser.add_argument("--table-only", action="store_true", help="only tabulate the JSON a run left in --out")
    args = parser.parse_args()
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    names = args.estimators.split(",")
    for name in [] if args.table_only else names:
        command = ["mavattitude", "tune", args.logs, "--estimator", name, "--folds", str(args.folds),
                   "--trials", str(args.trials), "--objective", args.objective, "--study", str(out / "study.db"), "--json", str(out / f"{name}.json"),
                   "-o", str(out / f"{name}.toml"), "-q"]
        print("$ " + " ".join(command), file=sys.stderr, flush=True)
        if subprocess.run(command, stdout=subprocess.DEVNULL).returncode:
            return 1
    first = json.loads((out / f"{names[0]}.json").read_text())
    print(f"tilt error (mean of roll and pitch MAE, deg) against the autopilot, {len(first['folds'])}-fold by log, "
          f"{first['final']['trials']} trials per fit, objective {first['objective']}; default -> tuned")
    print(f"{'estimator':<11} {'logs':>4}  {'held-out median':>22}  {'held-out mean':>22}  "
          f"{'held-out geomean':>22}  {'better':>6} {'worse':>5}  {'fit on all logs':>22}  {'run s':>6}")
    for name in names:
        r = json.loads((out / f"{name}.json").read_text())
        start = {log: v for fold in r["folds"] for log, v in fold["held_out_start"].items()}
        tuned = {log: v for fold in r["folds"] for log, v in fold["held_out_tuned"].items()}
        better = sum(tuned[log] < start[log] for log in start)
        worse = sum(tuned[log] > start[log] for log in start)
        print(f"{name:<11} {len(r['logs']):>4}  " + "  ".join(
            cell(aggregate(start.values(), o), aggregate(tuned.values(), o)) for o in OBJECTIVES)
            + f"  {better:>6} {worse:>5}  {cell(r['final']['start_value'], r['final']['best_value'])}"
            + f"  {r.get('seconds', float('nan')):6.0f}")
    return 0


def cell(before: float, after: float) -> str:
    return f"{before:6.3f} -> {after:6.3f} ({100 * (after - before) / before:+4.0f} %)"


if __name__ == "__main__":
    sys.exit(main())
