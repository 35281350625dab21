"""Damage logs on purpose and check that mavattitude reads what is left or fails in one line.

    python scripts/fuzz_logs.py [LOG ...] [--cases 10000] [--seed 0] [--estimators mahony,eskf]

Each case is a seeded mutation of a log (``mutate``: truncation, flipped bits, overwritten
bytes, a duplicated or dropped block), read and replayed as ``mavattitude replay`` does.
Anything but success or an ``InputError`` (a one-line error) is a failure: the script prints
its seed and traceback and exits 1. numpy warnings count as failures too. Without LOG it
fuzzes the sample logs and, where present, the shared logs in ../shared/logs.

The test suite runs a few dozen cases (tests/test_bad_input.py); this runs as many as you like.
"""
from __future__ import annotations

import argparse
import random
import sys
import tempfile
import time
import traceback
import warnings
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))


def mutate(data: bytes, rng: random.Random) -> bytes:
    """One damaged copy of ``data``: what a flaky SD card, a cut-off download or a bad
    telemetry link does to a log."""
    b = bytearray(data)
    kind = rng.choice(["flips", "flips", "bytes", "truncate", "block", "mixed"])
    if kind in ("truncate", "mixed"):
        del b[rng.randrange(1, len(b)):]
    if kind in ("flips", "mixed"):
        for _ in range(rng.choice([1, 5, 20, 100])):
            i = rng.randrange(len(b))
            b[i] ^= 1 << rng.randrange(8)
    if kind == "bytes":
        start = rng.randrange(len(b))
        for i in range(start, min(len(b), start + rng.choice([1, 16, 512]))):
            b[i] = rng.randrange(256)
    if kind == "block":
        start = rng.randrange(len(b))
        size = rng.choice([64, 4096, 65536])
        block = b[start:start + size]
        if rng.random() < 0.5:
            del b[start:start + size]  # a lost block
        else:
            at = rng.randrange(len(b))
            b[at:at] = block  # a repeated block
    return bytes(b)


def replay_or_error(path: Path, estimators=("mahony",)) -> str:
    """'read' or 'error' (a clean InputError); anything else raises."""
    from mavattitude.errors import InputError
    from mavattitude.info import render, summarize
    from mavattitude.pipeline import run_replay
    from mavattitude.readers import read_log
    from mavattitude.report import estimator_extras, format_table, to_json_dict

    try:
        flight = read_log(str(path))
        render(summarize(flight))
        result = run_replay(flight, list(estimators), warmup_s=5.0)
    except InputError:
        return "error"
    if result.reference is not None:
        format_table(result.comparisons, result.reference.source)
    to_json_dict(str(path), "reference", result.comparisons, estimator_extras(result))
    for name, series in result.estimates.items():
        norms = abs((series.q ** 2).sum(axis=1) - 1.0)
        if not (norms[norms == norms] < 1e-6).all():
            raise AssertionError(f"{name}: not a unit quaternion")
    return "read"


def default_logs() -> list[Path]:
    logs = sorted((ROOT / "sample_logs").glob("*.bin")) + sorted((ROOT / "sample_logs").glob("*.tlog"))
    shared = ROOT.parent / "shared" / "logs"
    if shared.is_dir():
        logs += sorted(p for p in shared.rglob("*") if p.suffix in (".bin", ".tlog"))
    return logs


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("logs", nargs="*", type=Path)
    parser.add_argument("--cases", type=int, default=10000, help="mutations in all (default 10000)")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--estimators", default="mahony")
    args = parser.parse_args()
    logs = args.logs or default_logs()
    sources = {p: p.read_bytes() for p in logs}
    names = args.estimators.split(",")
    counts = {"read": 0, "error": 0}
    start = time.monotonic()
    with tempfile.TemporaryDirectory() as tmp, warnings.catch_warnings():
        warnings.simplefilter("error", RuntimeWarning)
        for case in range(args.cases):
            log = logs[case % len(logs)]
            seed = args.seed * 1_000_003 + case
            path = Path(tmp) / f"case{log.suffix}"
            path.write_bytes(mutate(sources[log], random.Random(seed)))
            try:
                counts[replay_or_error(path, names)] += 1
            except Exception:
                print(f"FAILED: {log.name}, case {case} (seed {seed})", file=sys.stderr)
                traceback.print_exc()
                return 1
            if (case + 1) % 100 == 0:
                print(f"\r{case + 1}/{args.cases} cases: {counts['read']} read, {counts['error']} "
                      f"one-line errors ({time.monotonic() - start:.0f} s)", end="", file=sys.stderr, flush=True)
    print(f"\n{args.cases} cases over {len(logs)} logs: {counts['read']} read, {counts['error']} one-line "
          f"errors, 0 tracebacks ({time.monotonic() - start:.0f} s)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
