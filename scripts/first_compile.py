#!/usr/bin/env python3
"""A first run's compile, measured: `replay` of a small sample log with every estimator, numba's
cache empty (NUMBA_CACHE_DIR pointed at a new temporary folder, so the cache of the checkout is
neither read nor touched), in a child process.

    python scripts/first_compile.py [--estimators all] [--log sample_logs/static.bin]

Prints the steps as the command said them (each estimator, the log reader and the estimation
core, with the time it was done), the wall time, the CPU time of the command and its compiling
processes, and the load average before and after: a loaded machine takes several times an idle
one's wall time for the same CPU.
"""
from __future__ import annotations

import argparse
import os
import resource
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--estimators", default="all")
    parser.add_argument("--log", default=str(ROOT / "sample_logs" / "static.bin"))
    args = parser.parse_args()
    load_before = os.getloadavg()
    with tempfile.TemporaryDirectory(prefix="mavattitude-numba-") as cache:
        env = {**os.environ, "NUMBA_CACHE_DIR": cache}
        start = time.perf_counter()
        done = subprocess.run([sys.executable, "-m", "mavattitude", "replay", args.log, "--estimators",
                               args.estimators, "--no-view"], env=env, capture_output=True, text=True)
        wall = time.perf_counter() - start
    if done.returncode != 0:
        print(done.stderr.strip(), file=sys.stderr)
        return 1
    cpu = resource.getrusage(resource.RUSAGE_CHILDREN)
    for line in done.stderr.splitlines():
        if line.startswith("compiling"):
            print(line)
    print(f"wall {wall:.1f} s; CPU {cpu.ru_utime + cpu.ru_stime:.1f} s (the command and its compiling processes); "
          f"load average (1 min) {load_before[0]:.1f} before, {os.getloadavg()[0]:.1f} after, "
          f"on {os.cpu_count()} cores")
    return 0


if __name__ == "__main__":
    sys.exit(main())
