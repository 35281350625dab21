#!/usr/bin/env python3
"""What replay gives on every shared log, to compare two versions of the code to the bit.

    python scripts/replay_fingerprint.py OUT.json [LOGS ...]       # write the fingerprint
    python scripts/replay_fingerprint.py --compare A.json B.json    # exit 1 where they differ
    python scripts/replay_fingerprint.py --no-export OUT.json        # replay's compact path (no CSV)

Per log: ``replay --estimators all --json --export`` (in this process, no view) and the JSON
metrics as written, with a SHA-1 of each CSV ``--export`` writes. Default logs: every log in
../shared/logs, its corpus and ulog folders, ../shared/broad and sample_logs/. A log replay refuses (no
reference, damaged) is fingerprinted by its error line: that must not change either.
``--no-export``: without ``--export``, as a replay that keeps its estimates whole for the
view only (``scoredrows``): its JSON must equal the one with ``--export`` (``--compare``
leaves the CSV out where one side has none).
"""
from __future__ import annotations

import contextlib
import hashlib
import io
import json
import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
SUFFIXES = (".bin", ".tlog", ".ulg", ".hdf5")


def default_logs() -> list[str]:
    shared = ROOT.parent / "shared" / "logs"
    folders = [shared, shared / "corpus", shared / "ulog", ROOT.parent / "shared" / "broad", ROOT / "sample_logs"]
    return [str(p) for f in folders if f.is_dir() for p in sorted(f.iterdir()) if p.suffix in SUFFIXES]


def fingerprint(log: str, export: bool = True) -> dict:
    from mavattitude.cli import main as mavattitude

    with tempfile.TemporaryDirectory() as tmp:
        out, err = io.StringIO(), io.StringIO()
        with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
            truth = ["--reference", "truth"] if log.endswith(".hdf5") else []  # BROAD: no autopilot
            code = mavattitude(["replay", log, "--estimators", "all", "--no-view", "--json", f"{tmp}/m.json",
                                *(["--export", f"{tmp}/csv"] if export else []), *truth])
        if code != 0:
            return {"exit": code, "error": [line.replace(log, Path(log).name)
                                            for line in err.getvalue().strip().splitlines()[-1:]]}
        csv = {p.name: hashlib.sha1(p.read_bytes()).hexdigest() for p in sorted(Path(tmp, "csv").glob("*.csv"))}
        metrics = json.loads(Path(tmp, "m.json").read_text())
        metrics["log"] = Path(log).name  # where the checkout is does not count
        return {"exit": 0, "metrics": metrics, **({"csv": csv} if export else {})}


def compare(a_path: str, b_path: str) -> int:
    a, b = json.loads(Path(a_path).read_text()), json.loads(Path(b_path).read_text())
    for log, print_ in [*a.items(), *b.items()]:
        if "metrics" in print_:
            print_["metrics"]["log"] = log
    for log in set(a) & set(b):  # a --no-export side has no CSV to compare
        if ("csv" in a[log]) != ("csv" in b[log]):
            a[log].pop("csv", None)
            b[log].pop("csv", None)
    bad = 0
    for log in sorted(set(a) | set(b)):
        if a.get(log) != b.get(log):
            bad += 1
            fa, fb = a.get(log, {}), b.get(log, {})
            parts = [k for k in sorted(set(fa) | set(fb)) if fa.get(k) != fb.get(k)]
            print(f"DIFFERS {log}: {', '.join(parts)}")
    print(f"{len(set(a) | set(b)) - bad} of {len(set(a) | set(b))} logs identical")
    return 1 if bad else 0


def main(argv: list[str]) -> int:
    if not argv or argv[0] in ("-h", "--help") or (argv[0].startswith("-") and argv[0] not in ("--compare", "--no-export")):
        print(__doc__)
        return 0 if argv[:1] in (["-h"], ["--help"]) else 2
    if argv[:1] == ["--compare"]:
        return compare(argv[1], argv[2])
    export = argv[:1] != ["--no-export"]
    argv = argv if export else argv[1:]
    out, logs = argv[0], argv[1:] or default_logs()
    result = {}
    for log in logs:
        result[Path(log).name] = fingerprint(log, export)
        print(Path(log).name, result[Path(log).name]["exit"], flush=True)
    Path(out).write_text(json.dumps(result, indent=1, sort_keys=True))
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
