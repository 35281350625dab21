"""Compare two `mavattitude evaluate --out` folders record by record, exactly.

A refactor that claims "bit-identical" runs evaluate before and after into two folders and then:

    python scripts/compare_records.py BEFORE_DIR AFTER_DIR

Every value of every per-log record (logs/*.json) must be equal to the letter, floats included
(JSON keeps a float's shortest round-trip form, so equal text is equal bits). Left out: the
record's wall time (`seconds`) and `settings`, the key that says which options and which source
made it (evaluate.settings_key hashes the package's source, so any change to the code changes it; records
are paired by log name, the key in their file names left out). Prints the count of records and values compared and every difference;
exit status 1 when there is one.
"""

from __future__ import annotations

import json
import sys
from pathlib import Path

IGNORED = {("seconds",), ("settings",)}  # wall time; the options-and-source key: differ by design


def _leaves(value, path=()):
    if path in IGNORED:
        return
    if isinstance(value, dict):
        for key, item in value.items():
            yield from _leaves(item, path + (key,))
    elif isinstance(value, list):
        yield path + ("#len",), len(value)
        for index, item in enumerate(value):
            yield from _leaves(item, path + (index,))
    else:
        yield path, value


def main(argv: list[str]) -> int:
    if len(argv) != 2:
        print("usage: compare_records.py BEFORE_DIR AFTER_DIR", file=sys.stderr)
        return 2
    before, after = (Path(a) / "logs" for a in argv)
    # a record is named LOG-KEY.json, KEY the settings key (which hashes the source): paired by LOG
    files_b = {p.name.rsplit("-", 1)[0]: p for p in before.glob("*.json")}
    files_a = {p.name.rsplit("-", 1)[0]: p for p in after.glob("*.json")}
    names_b, names_a = set(files_b), set(files_a)
    differences = [f"only in {argv[0]}: {n}" for n in sorted(names_b - names_a)]
    differences += [f"only in {argv[1]}: {n}" for n in sorted(names_a - names_b)]
    values = 0
    for name in sorted(names_b & names_a):
        old = dict(_leaves(json.loads(files_b[name].read_text())))
        new = dict(_leaves(json.loads(files_a[name].read_text())))
        values += len(old)
        for key in sorted(set(old) | set(new), key=str):
            # repr: a float's shortest round-trip text, so equal text is equal bits (NaN included)
            if repr(old.get(key, "<absent>")) != repr(new.get(key, "<absent>")):
                where = "/".join(map(str, key))
                differences.append(f"{name}: {where}: {old.get(key, '<absent>')!r} -> "
                                   f"{new.get(key, '<absent>')!r}")
    for line in differences:
        print(line)
    print(f"{len(names_b & names_a)} records, {values} values compared: "
          f"{len(differences)} differences")
    return 1 if differences else 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
