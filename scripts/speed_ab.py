#!/usr/bin/env python3
"""Estimator speed of this checkout against another revision, in one process (robust to load).

    python scripts/speed_ab.py REV [--estimators mahony,eq-kf,cpf-ekf] [--runs 15] [--duration 300]

For a kernel refactor that must not cost speed ("bit-identical and not slower"). The package at
git revision REV is exported to a temporary folder as ``mavattitude_base`` (its imports inside are
relative, so it runs beside this one) with a numba cache of its own; then, on a simulated
figure-eight at 400 Hz (``commands.bench.make_data``), each estimator's ``update()`` of the base
and of this checkout run interleaved, ``--runs`` times each, with and without the compass. Prints
samples/s of both by CPU time (``time.process_time``, min of the runs) and the ratio (this / base):
under 1 this checkout is slower. Checks the two give the same attitudes to the bit, else says so.
Both compile first (cold caches: a minute or two).

The one compiled first runs faster here (measured on this 2-core EPYC: identical code read 0.80-0.89 when
compiled second, 1.14-1.22 when first), so one order says little about a few per cent: run it with
``--first base`` and ``--first this`` and take the geometric mean of the two ratios (identical code:
1.01-1.02).
"""
from __future__ import annotations

import argparse
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]


def export_base(rev: str, into: Path) -> None:
    """The package at ``rev`` as ``into/mavattitude_base``."""
    archive = subprocess.run(["git", "-C", str(ROOT), "archive", rev, "mavattitude"], check=True,
                             capture_output=True).stdout
    subprocess.run(["tar", "-x", "-C", str(into)], input=archive, check=True)
    (into / "mavattitude").rename(into / "mavattitude_base")


def timed(package, name: str, data, use_mag: bool) -> tuple[float, np.ndarray]:
    e = package.create(name, declination=data.declination)
    e.initialize(data.q0.copy(), data.gyro_bias.copy())
    extra = {"aiding": data.aiding} if e.uses_aiding else {}
    start = time.process_time()
    q = e.update(data.t, data.gyro, data.accel, data.mag if use_mag else None, in_air=data.in_air, **extra)
    return time.process_time() - start, q


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("rev", help="the git revision to compare with, e.g. main or a commit")
    ap.add_argument("--estimators", default="mahony,mahony-ekf,ekf,eskf,ncs-eskf,eq-kf,cpf-ekf")
    ap.add_argument("--runs", type=int, default=15)
    ap.add_argument("--duration", type=float, default=300.0, help="simulated seconds at 400 Hz (default 300)")
    ap.add_argument("--first", choices=("base", "this"), default="base",
                    help="which one compiles (and runs) first (default base; see the docstring: run both)")
    args = ap.parse_args()

    with tempfile.TemporaryDirectory(prefix="speed-ab-") as tmp:
        export_base(args.rev, Path(tmp))
        os.environ.setdefault("NUMBA_CACHE_DIR", str(Path(tmp) / "numba-cache"))  # the two caches apart
        sys.path[:0] = [tmp, str(ROOT)]
        import mavattitude.estimators as ours
        import mavattitude_base.estimators as base
        from mavattitude.commands.bench import make_data

        data = make_data("figure8", args.duration, 400.0, 0)
        n = len(data.t)
        print(f"{n} samples; CPU time, min of {args.runs} interleaved runs; ratio = this checkout / {args.rev}; "
              f"{args.first} compiled first")
        for name in args.estimators.split(","):
            for use_mag in (True, False):
                if name not in base.ESTIMATORS:
                    print(f"{name}: not in {args.rev}")
                    break
                if args.first == "base":  # compiles both first
                    _, qb = timed(base, name, data, use_mag)
                    _, qo = timed(ours, name, data, use_mag)
                else:
                    _, qo = timed(ours, name, data, use_mag)
                    _, qb = timed(base, name, data, use_mag)
                same = "same attitudes" if np.array_equal(qb, qo) else "ATTITUDES DIFFER"
                tb, to = [], []
                for _ in range(args.runs):
                    tb.append(timed(base, name, data, use_mag)[0])
                    to.append(timed(ours, name, data, use_mag)[0])
                print(f"{name:10} {'mag' if use_mag else 'no mag':7} {args.rev} {n / min(tb) / 1e6:5.2f} M/s  "
                      f"this {n / min(to) / 1e6:5.2f} M/s  ratio {min(tb) / min(to):.3f}  ({same})", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
