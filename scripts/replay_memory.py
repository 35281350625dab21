#!/usr/bin/env python3
"""Where a replay's memory peaks: the command run in this process, its RSS sampled every 3 ms,
the peak of each phase (reading, estimating, scoring, the view, the export) printed at the end.

    python scripts/replay_memory.py replay HOUR.bin --estimators all --rrd /tmp/hour.rrd -q

Any ``mavattitude`` command line works; the phases are the calls below, entered and left (a
phase's "after" row is the RSS between it and the next). The last line is the process's peak
RSS as the kernel counts it (``ru_maxrss``, what ``/usr/bin/time`` and ``bench --read`` report).
Linux only (/proc/self/statm).
"""
from __future__ import annotations

import importlib
import resource
import sys
import threading
import time

PHASES = [("mavattitude.readers", "read_log", "read"),
          ("mavattitude.commands.replay", "run_estimators", "estimate"),
          ("mavattitude.commands.replay", "check_reference", "check the reference"),
          ("mavattitude.commands.replay", "compare", "score"),
          ("mavattitude.cli.replay", "_view", "view"),  # (not mavattitude.view: that imports Rerun now)
          ("mavattitude.commands.report", "write_csv", "export")]
phase = ["imports"]
order: list[str] = []
peaks: dict[str, float] = {}


def rss_mb() -> float:
    with open("/proc/self/statm") as f:
        return int(f.read().split()[1]) * resource.getpagesize() / 1e6


def note(name: str) -> None:
    rss = rss_mb()
    if name not in peaks:
        order.append(name)
        peaks[name] = rss
    peaks[name] = max(peaks[name], rss)


def sample() -> None:
    while True:
        note(phase[0])
        time.sleep(0.003)


def wrap(module_name: str, function: str, label: str) -> None:
    module = importlib.import_module(module_name)
    inner = getattr(module, function)

    def timed(*args, **kwargs):
        note(phase[0])
        phase[0] = label
        note(label)
        try:
            return inner(*args, **kwargs)
        finally:
            note(label)
            phase[0] = f"after {label}"
            note(phase[0])
    setattr(module, function, timed)


def main(argv: list[str]) -> int:
    threading.Thread(target=sample, daemon=True).start()
    from mavattitude.cli import main as mavattitude
    for module_name, function, label in PHASES:
        wrap(module_name, function, label)
    code = mavattitude(argv)
    note(phase[0])
    for name in order:
        print(f"{name:28s} {peaks[name]:7.0f} MB", file=sys.stderr)
    print(f"{'peak RSS (ru_maxrss)':28s} {resource.getrusage(resource.RUSAGE_SELF).ru_maxrss * 1024 / 1e6:7.0f} MB",
          file=sys.stderr)
    return code


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
