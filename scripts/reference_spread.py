#!/usr/bin/env python3
"""How far the autopilot's own estimators are apart: for every shared log, the primary attitude
(the "autopilot" reference) against each other stream the log holds (issue 24, part 5's data).

    python scripts/reference_spread.py [LOGS_DIR ...] [--warmup S] [--flags]

Per pair: the roll and pitch MAE and mean offset (other - primary, degrees), and for sustained
disagreement the longest span (s) where roll or pitch differ by more than 3°, 5° and 10°. The
other stream is scored on the primary's clock as an estimator is (``metrics.compare``: no
extrapolation, nothing across a gap over ``MAX_GAP_S``), after ``--warmup`` seconds (default 0:
the whole log, the EKF's start included). Then the board trim (AHRS_TRIM_X/Y) beside the mean
offset of the EKF1 logs, and the median MAE per kind of pair. "equal to primary": the share of
the primary's samples the other stream equals to the log's resolution (0.02°): 100 % is a copy.

``--flags``: instead, refcheck's "autopilot disagrees" check on every log: per pair it compares
(copies left out), the tilt angle between the two (median, 99th percentile) and the longest span
above 5°, 10° and 20° (refcheck.disagreeing_spans: the seconds above the limit, dips shorter than
refcheck.DISAGREE_BRIDGE_S and gaps bridged), then the spans it flags.
"""
from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

from mavattitude import load
from mavattitude.errors import InputError
from mavattitude.scoring.metrics import compare
from mavattitude.scoring import refcheck
from mavattitude.readers.attitudes import name_attitudes

ROOT = Path(__file__).resolve().parents[1]
LOGS = ROOT.parent / "shared" / "logs"
THRESHOLDS_DEG = (3.0, 5.0, 10.0)
MAX_GAP_S = 1.0  # a stream's samples further apart than this: a gap, not scored
SUFFIXES = (".bin", ".tlog", ".ulg")


def longest_span(t: np.ndarray, apart: np.ndarray) -> float:
    """Seconds of the longest run of samples where ``apart`` holds, a gap over MAX_GAP_S ending a run."""
    best, start = 0.0, None
    for i in range(len(t)):
        if apart[i] and start is not None and t[i] - t[i - 1] <= MAX_GAP_S:
            best = max(best, t[i] - t[start])
        elif apart[i]:
            start = i
        else:
            start = None
    return best


def spread(flight, warmup_s: float) -> list[dict]:
    """The primary against every other stream: one row each."""
    named = name_attitudes(flight)
    primary, rows = named[0], []
    for other in named[1:]:
        c = compare(flight.attitude, flight.attitudes[other.key], warmup_s=warmup_s, max_gap_s=MAX_GAP_S)
        t, error = c.t[c.scored], c.error_deg[c.scored]
        if not len(t):
            continue
        tilt = np.max(np.abs(error[:, :2]), axis=1)
        rows.append({"primary": f"{primary.key} ({primary.algorithm})", "other": f"{other.key} ({other.algorithm})",
                     "kind": f"{primary.algorithm} vs {other.algorithm.split(' core')[0]}",
                     "roll_mae": c.axes["roll"].mae, "pitch_mae": c.axes["pitch"].mae,
                     "roll_mean": float(np.mean(error[:, 0])), "pitch_mean": float(np.mean(error[:, 1])),
                     "spans": [longest_span(t, tilt > limit) for limit in THRESHOLDS_DEG],
                     "equal": primary.equals.get(other.key, 0.0),
                     "seconds": float(t[-1] - t[0])})
    return rows


def readable(paths: list[Path]):
    """(path, flight) for each log that reads; a table row with the reason for one that does not."""
    for path in paths:
        try:
            yield path, load(path)
        except InputError as exc:
            print(f"| {path.name} | {exc} |")


def print_flags(paths: list[Path]) -> None:
    """The disagreement check's measurements and flags on each log (--flags)."""
    limits = (5.0, refcheck.DISAGREE_DEG, 20.0)
    print("| log | reference | other | median ° | 99th percentile ° | "
          + " | ".join(f"longest > {limit:g}° (s)" for limit in limits) + " |")
    print("|---|---|---|---|---|" + "---|" * len(limits))
    flags = []
    for path, flight in readable(paths):
        ref = flight.attitude
        if ref is None:
            continue
        named = name_attitudes(flight)
        for other in refcheck.compared_streams(ref, named):
            t, apart = refcheck.tilt_apart_deg(ref, flight.attitudes[other.key])
            if not np.isfinite(apart).any():
                continue
            longest = [max((span[2] for span in refcheck.disagreeing_spans(t, apart, limit)), default=0.0)
                       for limit in limits]
            print(f"| {path.name} | {ref.source} ({named[0].algorithm}) | {other.key} ({other.algorithm}) | "
                  f"{np.nanmedian(apart):.2f} | {np.nanpercentile(apart, 99):.1f} | "
                  + " | ".join(f"{s:.1f}" for s in longest) + " |")
        flags += [(path.name, s) for s in refcheck.autopilot_disagreement(ref, flight)]
    print(f"\nFlagged (> {refcheck.DISAGREE_DEG:g}° for {refcheck.DISAGREE_MIN_S:g} s or longer): "
          f"{len(flags)} spans on {len({name for name, _ in flags})} logs\n")
    print("| log | start s | end s | detail |")
    print("|---|---|---|---|")
    for name, s in flags:
        print(f"| {name} | {s.start:.1f} | {s.end:.1f} | {s.detail} |")


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("folders", nargs="*", default=[str(LOGS), str(LOGS / "corpus"), str(LOGS / "ulog")])
    parser.add_argument("--warmup", type=float, default=0.0, help="seconds left out at the start (default 0)")
    parser.add_argument("--flags", action="store_true", help="what refcheck's 'autopilot disagrees' check flags")
    args = parser.parse_args()
    paths = [p for folder in args.folders for p in sorted(Path(folder).iterdir()) if p.suffix.lower() in SUFFIXES]
    if not paths:
        print(f"no logs in {', '.join(args.folders)}", file=sys.stderr)
        return 1
    if args.flags:
        print_flags(paths)
        return 0
    spans = " | ".join(f"> {limit:g}° (s)" for limit in THRESHOLDS_DEG)
    print(f"| log | primary | other | equal to primary | roll / pitch MAE ° | mean offset roll / pitch ° | "
          f"longest {spans} |")
    print("|---|---|---|---|---|---|" + "---|" * len(THRESHOLDS_DEG))
    by_kind: dict[str, list[float]] = {}
    trims = []
    for path, flight in readable(paths):
        rows = spread(flight, args.warmup)
        if not rows:
            print(f"| {path.name} | {flight.attitude.source if flight.attitude else '-'} | (no other stream) |")
        kinds = set()
        for r in rows:
            print(f"| {path.name} | {r['primary']} | {r['other']} | {100 * r['equal']:.0f} % | "
                  f"{r['roll_mae']:.2f} / {r['pitch_mae']:.2f} | {r['roll_mean']:+.2f} / {r['pitch_mean']:+.2f} | "
                  + " | ".join(f"{s:.1f}" for s in r["spans"]) + " |")
            # the spread between estimators: a copy of the primary (ATT = XKF1[0]) is none, and a
            # log counts once per kind (AHR2 and EKF1 are one EKF where DCM is the primary)
            if r["equal"] <= 0.5 and r["kind"] not in kinds:
                kinds.add(r["kind"])
                by_kind.setdefault(r["kind"], []).append((r["roll_mae"] + r["pitch_mae"]) / 2)
            if r["other"].startswith("EKF1 ") and "AHRS_TRIM_X" in flight.params:
                trims.append((path.name, r, np.degrees(flight.params["AHRS_TRIM_X"]),
                               np.degrees(flight.params.get("AHRS_TRIM_Y", 0.0))))
    print("\nEKF1 against ATT: mean offset (EKF1 - ATT) beside the board trim (AHRS_TRIM_X/Y, °)\n")
    print("| log | ATT is | mean roll offset | AHRS_TRIM_X | mean pitch offset | AHRS_TRIM_Y |")
    print("|---|---|---|---|---|---|")
    for name, r, trim_x, trim_y in trims:
        print(f"| {name} | {r['primary'].split('(')[1][:-1]} | {r['roll_mean']:+.2f} | {trim_x:+.2f} | "
              f"{r['pitch_mean']:+.2f} | {trim_y:+.2f} |")
    print("\nMedian (roll + pitch) / 2 MAE per kind of pair: one per log, copies of the primary left out\n")
    print("| pair | logs | median ° | min ° | max ° |")
    print("|---|---|---|---|---|")
    for kind, values in sorted(by_kind.items()):
        print(f"| {kind} | {len(values)} | {np.median(values):.2f} | {min(values):.2f} | {max(values):.2f} |")
    return 0


if __name__ == "__main__":
    sys.exit(main())
