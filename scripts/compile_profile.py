#!/usr/bin/env python3
"""Where a first compile's time goes, kernel by kernel: each step (the log reader, the
estimation core, each estimator) in a child process of its own with numba's cache empty, its
CPU time, and per kernel the time numba spent compiling it alone (its callees' own compiles
taken out), split into typing (type inference, inlining), LLVM (optimisation and machine code:
the time in llvmlite) and the rest (lowering to IR, caching), with how many signatures it
compiled.

    python scripts/compile_profile.py [STEP ...] [--log sample_logs/static.bin] [--top 8]

STEP: "reader", "core" or an estimator's name; default all of them. A kernel called by several
steps is compiled in each (each has its own cache), as it is in a first run's processes that
compile at the same time. CPU seconds are the main figure on a shared machine: wall time there
depends on the other processes.
"""
from __future__ import annotations

import argparse
import json
import os
import resource
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]

CHILD = r"""
import json, sys, time
from collections import defaultdict
from timeit import default_timer as timer
start = time.process_time()
from numba.core import event as ev

class Exclusive(ev.Listener):
    # each event's own time (nested events' taken out), to the innermost kernel being compiled
    def __init__(self):
        self.stack, self.kernels = [], defaultdict(lambda: defaultdict(float))
    def on_start(self, event):
        if event.kind == "numba:compile":
            d = event.data["dispatcher"]
            name = f"{d.py_func.__module__.replace('mavattitude.', '')}.{d.py_func.__qualname__}"
            self.kernels[name]["signatures"] += 1
        elif event.kind == "numba:run_pass":
            name = f"{event.data['module'].replace('mavattitude.', '')}.{event.data['qualname']}"
            kind = "other" if event.data["name"].split(" [")[0] in LOWERING else "typing"
        else:
            name, kind = None, "llvm"
        if event.kind == "numba:compile":
            kind = "other"
        if name is None:  # the LLVM lock: whose compile holds it
            name = next((frame[0] for frame in reversed(self.stack) if frame[0] is not None), "(numba)")
        self.stack.append([name, kind, timer(), 0.0])
    def on_end(self, event):
        name, kind, t0, nested = self.stack.pop()
        took = timer() - t0
        if self.stack:
            self.stack[-1][3] += took
        self.kernels[name][kind] += took - nested

LOWERING = {"native_lowering", "nopython_backend"}  # the rest of the pipeline: typing, inlining, rewrites
listener = Exclusive()
for kind in ("numba:compile", "numba:run_pass", "numba:llvm_lock"):
    ev.register(kind, listener)
step, log = sys.argv[1], sys.argv[2]
t0 = time.perf_counter()
if step == "reader":
    from mavattitude.readers import read_log
    read_log(log)
elif step == "core":
    from mavattitude.core.warmup import warm_up
    warm_up([])
else:
    from mavattitude.core.warmup import compile_kernels
    compile_kernels([step])
print(json.dumps({"wall": time.perf_counter() - t0, "cpu": time.process_time() - start,
                  "kernels": {k: dict(v) for k, v in listener.kernels.items()}}))
"""


def profile(step: str, log: str) -> dict:
    with tempfile.TemporaryDirectory(prefix="mavattitude-numba-") as cache:
        env = {**os.environ, "NUMBA_CACHE_DIR": cache}
        before = resource.getrusage(resource.RUSAGE_CHILDREN)
        start = time.perf_counter()
        done = subprocess.run([sys.executable, "-c", CHILD, step, log], env=env, capture_output=True, text=True)
        wall = time.perf_counter() - start
        after = resource.getrusage(resource.RUSAGE_CHILDREN)
    if done.returncode != 0:
        raise SystemExit(f"{step}: {done.stderr.strip().splitlines()[-1]}")
    out = json.loads(done.stdout.strip().splitlines()[-1])
    out["process_cpu"] = after.ru_utime + after.ru_stime - before.ru_utime - before.ru_stime
    out["process_wall"] = wall
    return out


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("steps", nargs="*")
    parser.add_argument("--log", default=str(ROOT / "sample_logs" / "static.bin"))
    parser.add_argument("--top", type=int, default=8, help="kernels shown per step (by their own time)")
    parser.add_argument("--json", help="also write every kernel's figures here")
    args = parser.parse_args()
    sys.path.insert(0, str(ROOT))
    from mavattitude.estimators import all_names

    steps = args.steps or ["reader", "core", *all_names()]
    load_before = os.getloadavg()[0]
    results = {}
    total_cpu = 0.0
    for step in steps:
        r = results[step] = profile(step, args.log)
        total_cpu += r["process_cpu"]
        kernels = r["kernels"]
        compiled = sum(sum(v for k, v in f.items() if k != "signatures") for f in kernels.values())
        print(f"{step}: CPU {r['process_cpu']:.1f} s (process, imports included), wall {r['process_wall']:.1f} s; "
              f"compiling {compiled:.1f} s in {len(kernels)} kernels")
        ranked = sorted(kernels.items(), key=lambda kv: -sum(v for k, v in kv[1].items() if k != "signatures"))
        for name, f in ranked[:args.top]:
            own = sum(v for k, v in f.items() if k != "signatures")
            print(f"    {own:5.2f} s  typing {f.get('typing', 0):5.2f}  llvm {f.get('llvm', 0):5.2f}  "
                  f"other {f.get('other', 0):5.2f}  x{int(f.get('signatures', 0))}  {name}")
    print(f"total CPU {total_cpu:.1f} s over {len(steps)} steps; load average (1 min) {load_before:.1f} before, "
          f"{os.getloadavg()[0]:.1f} after, on {os.cpu_count()} cores")
    if args.json:
        Path(args.json).write_text(json.dumps(results, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
