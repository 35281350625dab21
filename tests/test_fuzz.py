"""Damaged FMT records (issue 11): a flipped bit in the format definition of a message the
reader wants is repaired when one repair explains it and the records that follow line up with
it; otherwise the reader warns, or fails in one line. Never a traceback, never other data.
(Random damage of every kind: tests/test_bad_input.py and scripts/fuzz_logs.py.)"""
from __future__ import annotations

import re

import numpy as np
import pytest

from conftest import SAMPLE_LOGS, SHARED_LOGS
from mavattitude.errors import InputError
from mavattitude.readers import read_log
from mavattitude.readers.dataflash import WANTED
from mavattitude.readers.dfrecords import decode, open_log, scan_log

LOG = SAMPLE_LOGS / "static.bin"  # simulated; IMU: QBffffffIIfBBHH, TimeUS,I,GyrX,...
FIELDS = {"header": (0, 3), "Type": (3, 4), "Length": (4, 5), "Name": (5, 9), "Format": (9, 25),
          "Columns": (25, 89)}  # where in an FMT record


def fmt_offset(raw: bytes, name: str) -> int:
    """Where the FMT record of message ``name`` starts."""
    return next(m.start() for m in re.finditer(rb"\xa3\x95\x80", raw)
                if raw[m.start() + 5:m.start() + 9].rstrip(b"\0") == name.encode())


def flipped(tmp_path, log, name: str, at: int, bit: int):
    """A copy of ``log`` with one bit flipped at byte ``at`` of ``name``'s FMT record."""
    raw = bytearray(log.read_bytes())
    raw[fmt_offset(raw, name) + at] ^= 1 << bit
    path = tmp_path / f"{name}-{at}-{bit}.bin"
    path.write_bytes(bytes(raw))
    return path


def same_imu(a, b) -> bool:
    return set(a.imu) == set(b.imu) and all(
        np.array_equal(a.imu[k].t, b.imu[k].t) and np.array_equal(a.imu[k].gyro, b.imu[k].gyro)
        and np.array_equal(a.imu[k].accel, b.imu[k].accel) for k in a.imu)


@pytest.fixture(scope="module")
def whole():
    return read_log(str(LOG))


@pytest.mark.parametrize("field, at, bit", [
    ("header", 0, 0), ("header", 2, 7),  # A2 95 80, A3 95 00: not seen as a record at all
    ("Type", 3, 0),  # the records are of a type no FMT defines
    ("Length", 4, 0), ("Length", 4, 5),  # the records do not line up at it
    ("Name", 5, 7), ("Name", 8, 0),  # 'I' | 0x80, "IMU\x01": not printable
    ("Format", 9, 2), ("Format", 11, 5),  # 'Q' -> 'U', 'f' -> 'F': no format characters
    ("Columns", 25, 7),  # 'T' | 0x80 in TimeUS: no column name
    ("Columns", 31, 0),  # ',' -> '-': TimeUS and I joined, every name after them one field off
])
def test_a_flipped_bit_in_the_imu_format_is_repaired(tmp_path, whole, field, at, bit):
    damaged = read_log(str(flipped(tmp_path, LOG, "IMU", at, bit)))
    assert same_imu(damaged, whole)
    what = "its header" if field == "header" else f"its {field}"
    assert any("repaired 1 damaged message format" in w and f"IMU ({what})" in w for w in damaged.warnings)
    assert not any("skipped" in w for w in damaged.warnings)


@pytest.mark.parametrize("at, bit, why", [
    (6, 0, "'M' -> 'L': a printable name, of a message not wanted (ILU)"),
    (11, 3, "'f' -> 'n': the same size; a float read as text is refused"),
    (11, 0, "'f' -> 'g': 'g' -> 'f' and 'H' -> 'I', 'H' -> 'L' make it add up again"),
    (25, 0, "'T' -> 'U': UimeUS is a sound column name"),
])
def test_an_imu_format_that_cannot_be_repaired_is_one_line(tmp_path, at, bit, why):
    path = flipped(tmp_path, LOG, "IMU", at, bit)
    assert scan_log(open_log(str(path)), WANTED).recovered_formats == [], why
    with pytest.raises(InputError, match="no IMU data"):
        read_log(str(path))


def test_a_sensor_format_that_cannot_be_repaired_is_a_warning(tmp_path, whole):
    damaged = read_log(str(flipped(tmp_path, LOG, "GPS", 9 + 10, 3)))  # Spd: 'f' -> 'n'
    assert same_imu(damaged, whole) and not damaged.gps
    assert any(w.startswith("GPS: its field Spd ('n', 4 characters) holds no text") for w in damaged.warnings)


def test_old_logs_do_not_guess_whose_records_they_are(tmp_path):
    """In Copter 3.3 IMU and IMU2 have one layout, and this log has no IMU2 records: a flipped
    Type bit in IMU's FMT leaves records IMU2's FMT fits just as well, one bit off its type.
    They stay skipped, not read as IMU2."""
    log = SHARED_LOGS / "copter-3.3-loiter-rtl.bin"
    if not log.exists():
        pytest.skip(f"{log} not found")
    scan = scan_log(open_log(str(flipped(tmp_path, log, "IMU", 3, 2))), WANTED)
    assert scan.recovered_formats == [] and "IMU" not in scan.offsets and "IMU2" not in scan.offsets
    assert scan.skipped_bytes > 0


def every_bit_logs():
    logs = [pytest.param(LOG, "IMU", id="static.bin-IMU"), pytest.param(LOG, "ATT", id="static.bin-ATT")]
    for name in ("copter-3.3-loiter-rtl.bin", "corpus/real-copter-4.5.7-pixhawk6x-tipover-quiver088.bin"):
        if (SHARED_LOGS / name).exists():
            logs.append(pytest.param(SHARED_LOGS / name, "IMU", id=f"{name.split('/')[-1]}-IMU"))
    return logs


PREFIX_RECORDS = 300


@pytest.mark.slow
@pytest.mark.parametrize("log, name", every_bit_logs())
def test_every_bit_of_a_format_record(log, name):
    """Each of the 712 bits of a wanted message's FMT record flipped in turn: a repair, when
    there is one, gives back every record as it was; decoding the rest fails with a
    ValueError or lacks a column (the reader warns), or the message is gone. Nothing else.
    On the log up to its 300th record of the message (cut where that record begins): a flip's
    repair is checked against those records, so the rest of the log only cost time; on these
    four logs the repairs, and bits repaired, are those of the whole log."""
    whole = scan_log(open_log(str(log)), WANTED)
    raw = log.read_bytes()[:int(whole.offsets[name][PREFIX_RECORDS])]
    at = fmt_offset(raw, name)
    data = np.frombuffer(raw, np.uint8)
    expected = decode(data, scan_log(data, WANTED), name)
    assert len(expected["TimeUS" if "TimeUS" in expected else "TimeMS"]) == PREFIX_RECORDS
    repaired = set()
    for i in range(at * 8, (at + 89) * 8):
        data = bytearray(raw)
        data[i // 8] ^= 1 << i % 8
        data = np.frombuffer(bytes(data), np.uint8)
        scan = scan_log(data, WANTED)
        if scan.recovered_formats:
            repaired.add(i - at * 8)
            got = decode(data, scan, name)
            assert scan.recovered_formats == [f"{name} ({_what(i // 8 - at)})"] and scan.skipped_bytes == 0
            assert all(np.array_equal(got[c], expected[c]) for c in expected), i
        elif name in scan.offsets:
            try:
                decode(data, scan, name)
            except ValueError:
                pass
    assert set(range(24)) | set(range(32, 40)) <= repaired  # header and Length: always (Type: see above)
    assert len(repaired) >= 150  # of 712 (static.bin IMU: 322); the rest: harmless, or no one repair


def _what(at: int) -> str:
    return next("its header" if field == "header" else f"its {field}" for field, (a, b) in FIELDS.items()
                if a <= at < b)
