#!/usr/bin/env python3
"""Per reference family (all, DCM, EKF, other): each estimator's median tilt error, its worst log,
and its ratio to mahony and to VQF on the same log (median and worst), from an evaluation's
records. The figures an estimator change is judged by on the shared corpus.

    mavattitude evaluate ../shared/logs --estimators all,vqf,imufusion --out DIR
    python scripts/rank_by_family.py DIR

Logs marked not meaningful, and logs where any estimator scored nothing, are left out, so every
estimator is compared on the same logs.
"""
from __future__ import annotations

import argparse
import json
import statistics
from pathlib import Path

from mavattitude.commands.evalreport import tilt_score
from mavattitude.scoring.rankstats import reference_family


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("evaluation", type=Path, help="an evaluate --out folder")
    args = parser.parse_args()
    records = [json.loads(p.read_text()) for p in sorted((args.evaluation / "logs").glob("*.json"))]
    names = list(dict.fromkeys(n for r in records if r["status"] == "ok" for n in r["metrics"]))
    families: dict[str, list] = {}
    for r in records:
        if r["status"] != "ok" or r["facts"].get("not_meaningful"):
            continue
        scores = {n: tilt_score(r["metrics"][n]) for n in names if n in r["metrics"]}
        if len(scores) < len(names) or None in scores.values():
            continue
        for family in ("all", reference_family(r.get("reference_algorithm"))):
            families.setdefault(family, []).append((Path(r["log"]).name, scores))
    for family, rows in families.items():
        print(f"\n{family} ({len(rows)} logs)\n")
        print("| estimator | median ° | worst log ° | × mahony: median, worst (log) | × vqf: median, worst |")
        print("|---|---|---|---|---|")
        for n in names:
            worst = max(rows, key=lambda row: row[1][n])
            to_mahony = {log: s[n] / s["mahony"] for log, s in rows} if "mahony" in names else {}
            to_vqf = [s[n] / s["vqf"] for _, s in rows] if "vqf" in names else []
            mahony = "-" if not to_mahony else (f"{statistics.median(to_mahony.values()):.2f}, "
                                                f"{max(to_mahony.values()):.2f} ({max(to_mahony, key=to_mahony.get)})")
            vqf = "-" if not to_vqf else f"{statistics.median(to_vqf):.2f}, {max(to_vqf):.2f}"
            print(f"| {n} | {statistics.median(s[n] for _, s in rows):.2f} | {worst[1][n]:.2f} ({worst[0]}) "
                  f"| {mahony} | {vqf} |")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
