"""Damage logs on purpose and check that mavattitude reads what is left or fails in one line.

    python scripts/fuzz_logs.py [LOG ...] [--cases 10000] [--seed 0] [--case N] [--estimators mahony,eskf]

Each case is a seeded mutation of a log (``mutate``: truncation, flipped bits, overwritten
bytes, a duplicated, dropped or swapped block, a damaged FMT record), read and replayed as
``mavattitude replay`` does. Anything but success or an ``InputError`` (a one-line error) is a
failure: the script prints its case number and traceback, goes on, and exits 1 at the end
(``--case N`` runs case N again). numpy warnings count as failures too, and so does a case slower
than ``--hang-s`` (a hang). Without LOG it fuzzes the sample logs and, where present, the shared
logs in ../shared/logs.

The test suite runs a few dozen cases (tests/test_bad_input.py); this runs as many as you like.
"""
from __future__ import annotations

import argparse
import faulthandler
import json
import random
import re
import sys
import tempfile
import time
import traceback
import warnings
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))


KINDS = ("flips", "bytes", "truncate", "block", "shuffle", "fmt", "mixed")
# A DataFlash FMT record's fields (offsets in the record): what defines every other record
FMT_FIELDS = {"header": (0, 3), "Type": (3, 4), "Length": (4, 5), "Name": (5, 9), "Format": (9, 25),
              "Columns": (25, 89)}


def mutate(data: bytes, rng: random.Random, kind: str | None = None) -> bytes:
    """One damaged copy of ``data``: what a flaky SD card, a cut-off download or a bad
    telemetry link does to a log. ``kind``: one of KINDS (default: drawn, flips and FMT damage
    twice as often as the others)."""
    b = bytearray(data)
    kind = kind or rng.choice(KINDS + ("flips", "fmt"))
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
    if kind == "shuffle":  # two blocks written in each other's place
        size = rng.choice([64, 4096, 65536])
        if len(b) >= 2 * size:
            i = rng.randrange(len(b) - 2 * size + 1)
            j = rng.randrange(i + size, len(b) - size + 1)
            b[i:i + size], b[j:j + size] = b[j:j + size], b[i:i + size]
    if kind == "fmt":
        _damage_fmt(b, rng)
    return bytes(b)


def _damage_fmt(b: bytearray, rng: random.Random) -> None:
    """A few flipped bits in, or random bytes over, one field of one FMT record (half the time
    one of a message the reader wants); a flipped bit anywhere in a file without FMT records."""
    from mavattitude.readers.dataflash import WANTED

    fmts = [m.start() for m in re.finditer(rb"\xa3\x95\x80", b) if m.start() + 89 <= len(b)]
    wanted = [at for at in fmts if bytes(b[at + 5:at + 9]).rstrip(b"\0").decode(errors="replace") in WANTED]
    if not fmts:
        b[rng.randrange(len(b))] ^= 1 << rng.randrange(8)
        return
    at = rng.choice(wanted if wanted and rng.random() < 0.5 else fmts)
    lo, hi = FMT_FIELDS[rng.choice(list(FMT_FIELDS))]
    if rng.random() < 0.75:
        for _ in range(rng.choice([1, 1, 1, 2, 3])):
            b[at + rng.randrange(lo, hi)] ^= 1 << rng.randrange(8)
    else:
        b[at + lo:at + hi] = bytes(rng.randrange(256) for _ in range(hi - lo))


def replay_or_error(path: Path, estimators=("mahony",)) -> str:
    """'read' or 'error' (a clean InputError); anything else raises."""
    from mavattitude.errors import InputError
    from mavattitude.commands.info import render, summarize
    from mavattitude.commands.replay import run_replay
    from mavattitude.readers import read_log
    from mavattitude.commands.report import format_table

    try:
        flight = read_log(str(path))
        render(summarize(flight))
        result = run_replay(flight, list(estimators), warmup_s=5.0)
    except InputError:
        return "error"
    if result.reference is not None:
        format_table(result.comparisons, result.reference_info.label, streams=result.stream_comparisons,
                     reference_algorithm=result.reference_info.algorithm)
    json.dumps(result.metrics, allow_nan=False)  # the JSON replay writes (the autopilot's streams too)
    for name, series in result.estimates.items():
        norms = abs((series.q ** 2).sum(axis=1) - 1.0)
        if not (norms[norms == norms] < 1e-6).all():
            raise AssertionError(f"{name}: not a unit quaternion")
    return "read"


def default_logs() -> list[Path]:
    logs = sorted((ROOT / "sample_logs").glob("*.bin")) + sorted((ROOT / "sample_logs").glob("*.tlog"))
    shared = ROOT.parent / "shared" / "logs"
    if shared.is_dir():
        logs += sorted(p for p in shared.rglob("*") if p.suffix in (".bin", ".tlog", ".ulg"))
    return logs


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("logs", nargs="*", type=Path)
    parser.add_argument("--cases", type=int, default=10000, help="mutations in all (default 10000)")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--case", type=int, help="run this case only (to reproduce a failure)")
    parser.add_argument("--estimators", default="mahony")
    parser.add_argument("--hang-s", type=float, default=60.0, help="a case slower than this is a hang (default 60)")
    args = parser.parse_args()
    logs = args.logs or default_logs()
    sources = {p: p.read_bytes() for p in logs}
    names = args.estimators.split(",")
    counts = {"read": 0, "error": 0, "traceback": 0, "hang": 0}
    cases = [args.case] if args.case is not None else range(args.cases)
    start = time.monotonic()
    with tempfile.TemporaryDirectory() as tmp, warnings.catch_warnings():
        warnings.simplefilter("error", RuntimeWarning)
        for n, case in enumerate(cases, 1):
            log = logs[case % len(logs)]
            seed = args.seed * 1_000_003 + case
            path = Path(tmp) / f"case{log.suffix}"
            path.write_bytes(mutate(sources[log], random.Random(seed)))
            # a case that never returns (a loop in compiled code) ends the run with every thread's stack
            faulthandler.dump_traceback_later(10 * args.hang_s, exit=True)
            began = time.monotonic()
            try:
                outcome = replay_or_error(path, names)
            except Exception:
                outcome = "traceback"
                print(f"\nFAILED: {log.name}, case {case} (--seed {args.seed} --case {case})", file=sys.stderr)
                traceback.print_exc()
            faulthandler.cancel_dump_traceback_later()
            if outcome != "traceback" and time.monotonic() - began > args.hang_s:
                outcome = "hang"
                print(f"\nHANG: {log.name}, case {case} took {time.monotonic() - began:.0f} s "
                      f"(--seed {args.seed} --case {case})", file=sys.stderr)
            counts[outcome] += 1
            if n % 100 == 0:
                print(f"\r{n}/{len(cases)} cases: {_summary(counts)} ({time.monotonic() - start:.0f} s)", end="",
                      file=sys.stderr, flush=True)
    print(f"\n{len(cases)} cases over {len(logs)} logs: {_summary(counts)} ({time.monotonic() - start:.0f} s)")
    return 1 if counts["traceback"] or counts["hang"] else 0


def _summary(counts: dict) -> str:
    return (f"{counts['read']} read, {counts['error']} one-line errors, {counts['traceback']} tracebacks, "
            f"{counts['hang']} hangs")


if __name__ == "__main__":
    sys.exit(main())
