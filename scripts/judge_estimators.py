#!/usr/bin/env python3
"""One line per estimator that says whether an estimator change is a gain, on all the evidence at
once: BROAD (real IMU, optical truth), the shared corpus (against the autopilot), and the SITL
logs within it (against a reference close to the truth). Each run is an ``evaluate`` under
--out with the given --set options, so a setting can be compared with the defaults:

    python scripts/judge_estimators.py --out /tmp/judge/base
    python scripts/judge_estimators.py --out /tmp/judge/tau3 --set mahony.accel_tau=3 ...

Columns: BROAD 6D median inclination RMSE and the worst trial's ratio to VQF (target ≤ 2);
corpus median tilt error (mean of roll and pitch MAE) over every scored log, over the SITL logs,
and the worst log's ratio to mahony as the defaults run it (target ≤ 1.5; mahony's own column is
its ratio to its defaults). BROAD: Laidig, Caruso, Cereatti, Seel 2021, doi:10.3390/data6070072,
CC BY 4.0.
"""
from __future__ import annotations

import argparse
import json
import statistics
import subprocess
import sys
from pathlib import Path

from mavattitude.commands.evalreport import tilt_score

SHARED = Path(__file__).resolve().parent.parent.parent / "shared"


def evaluate(folder: Path, out: Path, extra: list[str]) -> list[dict]:
    """The records of an evaluate run (made unless already there)."""
    if not (out / "summary.json").exists():
        subprocess.run([sys.executable, "-m", "mavattitude", "evaluate", str(folder), "--out", str(out),
                        "--estimators", "all,vqf", "-j", "2", *extra], check=True, stdout=subprocess.DEVNULL)
    return [json.loads(p.read_text()) for p in sorted((out / "logs").glob("*.json"))]


def scored(records: list[dict], score) -> dict[str, dict[str, float]]:
    """log name -> estimator -> score, for the logs every estimator was scored on."""
    out = {}
    for r in records:
        if r["status"] != "ok" or r["facts"].get("not_meaningful"):
            continue
        scores = {n: score(m) for n, m in r["metrics"].items()}
        if None not in scores.values():
            out[Path(r["log"]).name] = scores
    return out


def inclination(metrics: dict) -> float | None:
    broad = metrics.get("broad") or {}
    return broad.get("inclination_rmse_deg")


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", type=Path, required=True, help="a folder for this setting's evaluations")
    parser.add_argument("--set", action="append", default=[], metavar="NAME.PARAM=VALUE")
    parser.add_argument("--baseline", type=Path, help="a --out of the defaults (for the × mahony column; "
                                                     "default: this run's own mahony)")
    parser.add_argument("--shared", type=Path, default=SHARED)
    args = parser.parse_args()
    sets = [x for s in args.set for x in ("--set", s)]
    broad = scored(evaluate(args.shared / "broad", args.out / "broad", ["--reference", "truth", "--no-mag", *sets]),
                   inclination)
    corpus = scored(evaluate(args.shared / "logs", args.out / "corpus", sets), tilt_score)
    base = corpus if args.baseline is None else scored(
        [json.loads(p.read_text()) for p in sorted((args.baseline / "corpus" / "logs").glob("*.json"))], tilt_score)
    names = [n for n in next(iter(broad.values()))]
    print(f"{'estimator':12s} {'BROAD med':>9s} {'worst×VQF':>9s} {'corpus med':>10s} {'SITL med':>8s} "
          f"{'worst×mahony (log)':>20s}")
    for n in names:
        b = [s[n] for s in broad.values()]
        to_vqf = max(s[n] / s["vqf"] for s in broad.values())
        logs = [log for log in corpus if log in base]
        sitl = [corpus[log][n] for log in logs if log.startswith("sitl")]
        ratios = {log: corpus[log][n] / base[log]["mahony"] for log in logs}
        worst = max(ratios, key=ratios.get)
        print(f"{n:12s} {statistics.median(b):9.2f} {to_vqf:9.2f} {statistics.median(corpus[log][n] for log in logs):10.2f} "
              f"{statistics.median(sitl):8.2f} {ratios[worst]:6.2f} ({worst[:40]})")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
