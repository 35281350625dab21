#!/usr/bin/env python3
"""A first run's compile, measured: `replay` of a small sample log with every estimator, numba's
cache empty (NUMBA_CACHE_DIR pointed at a new temporary folder, so the cache of the checkout is
neither read nor touched), in a child process.

    python scripts/first_compile.py [--estimators all] [--log sample_logs/static.bin]

Prints the steps as the command said them (each estimator, the log reader and the estimation
core, with the time it was done), the wall time, the CPU time of the command and its compiling
processes, in all and each (read from /proc every 0.1 s, so each process's last tenth of a
second may be missing: on a shared machine the longest of them decides the wall time an idle
one would take), and the load average before and after: a loaded machine takes several times
an idle one's wall time for the same CPU.
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
        with tempfile.TemporaryFile("w+") as err:
            proc = subprocess.Popen([sys.executable, "-m", "mavattitude", "replay", args.log, "--estimators",
                                     args.estimators, "--no-view"], env=env, stdout=subprocess.DEVNULL, stderr=err,
                                    text=True)
            each = {}  # pid: CPU seconds, the last seen
            while proc.poll() is None:
                each.update(_cpu_of_tree(proc.pid))
                time.sleep(0.1)
            wall = time.perf_counter() - start
            err.seek(0)
            done = subprocess.CompletedProcess(proc.args, proc.returncode, "", err.read())
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
    main_cpu, *others = each.values()
    print(f"CPU per process: the command {main_cpu:.1f} s" + "".join(f", compiling process {k} {c:.1f} s"
                                                               for k, c in enumerate(others, 1)))
    return 0


def _cpu_of_tree(pid: int) -> dict[int, float]:
    """CPU seconds (user + system) of process ``pid`` and its descendants, now, by pid; those
    that have just ended are left out."""
    tick = os.sysconf("SC_CLK_TCK")
    out, todo = {}, [pid]
    while todo:
        p = todo.pop(0)
        try:
            fields = Path(f"/proc/{p}/stat").read_text().rsplit(")", 1)[1].split()
            children = Path(f"/proc/{p}/task/{p}/children").read_text().split()
        except OSError:
            continue
        out[p] = (int(fields[11]) + int(fields[12])) / tick  # utime, stime (fields 14, 15 of stat)
        todo += [int(c) for c in children]
    return out


if __name__ == "__main__":
    sys.exit(main())
