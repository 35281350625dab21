"""The bulk readers against pymavlink, the oracle: every record of every type we read, field by
field (NaN-aware), on every shared log (corpus included) and the sample logs."""
from __future__ import annotations

import numpy as np
import pytest
from pymavlink import DFReader, mavutil

from conftest import SAMPLE_LOGS, shared_log_params
from mavattitude.readers.collect import Collector
from mavattitude.readers.dataflash import WANTED
from mavattitude.readers.dfrecords import decode, open_log, scan_log
from mavattitude.readers.tlog import (OTHER_MESSAGES, STREAM_MESSAGES, MessageDecoder, is_vehicle, read_tlog,
                                      sample_values)

SAMPLE_BINS = [pytest.param(p, id=p.name) for p in sorted(SAMPLE_LOGS.glob("*.bin"))]
SAMPLE_TLOGS = [pytest.param(p, id=p.name) for p in sorted(SAMPLE_LOGS.glob("*.tlog"))]


def _same(ours, theirs) -> bool:
    ours, theirs = np.asarray(ours), np.asarray(theirs)
    if ours.dtype.kind == "f" or theirs.dtype.kind == "f":
        return ours.shape == theirs.shape and np.array_equal(ours.astype(np.float64), theirs.astype(np.float64),
                                                             equal_nan=True)
    return ours.tolist() == theirs.tolist()


DENSE = 30_000  # records of one type past which pymavlink's reading costs seconds (some 25 µs a record)


def _pymavlinks(path, types: list[str]):
    """pymavlink's reading of ``path``: the columns of every record of ``types``, and its own
    index's count of each message type in the whole file."""
    log = DFReader.DFReader_binary(str(path), zero_time_base=True)
    counts = {log.formats[t].name: n for t, n in enumerate(log.counts) if n and t in log.formats}
    theirs: dict[str, dict[str, list]] = {}
    while (msg := log.recv_match(type=types)) is not None:
        columns = theirs.setdefault(msg.get_type(), {})
        for field in msg._fieldnames:
            columns.setdefault(field, []).append(getattr(msg, field))
    return theirs, counts


def _assert_ours_equal(path, types: list[str]):
    """Every record of ``types`` in ``path`` that pymavlink reads is ours, field by field, and
    we have as many. Returns our scan, the types pymavlink read, and its counts."""
    data = open_log(str(path))
    scan = scan_log(data, WANTED)
    theirs, counts = _pymavlinks(path, types(scan) if callable(types) else types)
    assert set(theirs) <= set(scan.offsets)
    for name, columns in theirs.items():
        ours = decode(data, scan, name)
        n = len(next(iter(columns.values())))
        assert n == len(scan.offsets[name]), name
        for field, values in columns.items():
            assert _same(ours[field], values), (name, field)
    return scan, set(theirs), counts


def _dense(scan) -> list[str]:
    """The types of more than ``DENSE`` records, the densest first."""
    return sorted((name for name, offsets in scan.offsets.items() if len(offsets) > DENSE),
                  key=lambda name: -len(scan.offsets[name]))


@pytest.mark.parametrize("path", shared_log_params(corpus=True, suffix=".bin", slow_above_mb=0.5) + SAMPLE_BINS)
def test_dataflash_records_equal_pymavlinks(path, tmp_path):
    """pymavlink stops at the first record of a type no FMT defines; up to there (on these
    logs: everywhere) every record of a wanted type is ours, bit for bit. A type with more than
    ``DENSE`` records (the 400 Hz log's ACC, GYR, IMU: 850,000 records, 20 s of pymavlink) is
    compared on a prefix of the log cut where a record begins, ``DENSE`` records of the densest
    type in, and counted over the whole log by pymavlink's index; every other type is compared
    over the whole log."""
    scan, _, counts = _assert_ours_equal(path, lambda scan: [n for n in WANTED if n not in _dense(scan)])
    dense = _dense(scan)
    if not dense:
        return
    assert {name: counts.get(name) for name in dense} == {name: len(scan.offsets[name]) for name in dense}
    prefix = tmp_path / path.name
    prefix.write_bytes(path.read_bytes()[:int(scan.offsets[dense[0]][DENSE])])  # where a record begins
    head, read, _ = _assert_ours_equal(prefix, dense)
    assert read == set(dense) and head.tail_bytes == head.skipped_bytes == 0


def _pymavlink_tlog(path) -> Collector:
    """A .tlog read packet by packet by pymavlink, each message through the live link's decoder."""
    mavutil.set_dialect("ardupilotmega")
    log = mavutil.mavmmaplog(str(path))
    col, decoder, vehicle = Collector(), MessageDecoder(), None
    while (msg := log.recv_msg()) is not None:
        if msg.get_type() == "BAD_DATA":
            continue
        if vehicle is None and is_vehicle(msg):
            vehicle = msg.get_srcSystem()
        if vehicle is not None and msg.get_srcSystem() == vehicle:
            decoder.decode(msg, col.add)
            if msg.get_type() in STREAM_MESSAGES and decoder.last_t is not None:  # read from files only
                kind, values = sample_values(msg.get_type(), msg)
                col.add(kind, msg.get_type(), decoder.last_t, tuple(float(v) for v in values))
    col.finish()
    col.params, col.texts, col.vehicle = decoder.params, decoder.texts, vehicle
    return col


def _pymavlink_notes(path, vehicle: int):
    """The parameters and texts of a .tlog as the live link's decoder keeps them from pymavlink's
    messages of system ``vehicle``, from its first autopilot HEARTBEAT on: only those message
    types read (pymavlink's index skips the rest: a fraction of a second for 10 MB)."""
    mavutil.set_dialect("ardupilotmega")
    log = mavutil.mavmmaplog(str(path))
    decoder, heard = MessageDecoder(), False
    while (msg := log.recv_match(type=list(OTHER_MESSAGES))) is not None:
        heard = heard or (msg.get_srcSystem() == vehicle and is_vehicle(msg))
        if heard and msg.get_srcSystem() == vehicle:
            decoder.note(msg)
    return decoder.params, decoder.texts


TLOG_PREFIX_MB = 2.0  # pymavlink decodes these logs at some 1.5 MB/s, a packet at a time


@pytest.mark.parametrize("path", shared_log_params(corpus=True, suffix=".tlog", slow_above_mb=0.5) + SAMPLE_TLOGS)
def test_telemetry_samples_equal_pymavlinks(path, tmp_path):
    """Every sample, its time and its unit conversion as pymavlink's decoding gives them, one
    message at a time (as on a live link); parameters and texts too. A log of more than
    ``TLOG_PREFIX_MB``: its samples on a prefix cut where a packet begins (holding every
    series and clock segment of the whole log), its parameters and texts over the whole log."""
    decoded = read_tlog(str(path))
    sampled = path
    if path.stat().st_size > TLOG_PREFIX_MB * 1e6:
        data = path.read_bytes()
        sampled = tmp_path / path.name
        sampled.write_bytes(data[:_record_boundary(data, int(TLOG_PREFIX_MB * 1e6))])
    theirs = _pymavlink_tlog(sampled)
    ours = read_tlog(str(sampled)).collector
    ours.finish()
    assert sorted(ours._series) == sorted(theirs._series)
    assert ours.segments == theirs.segments
    for kind, key in theirs._series:
        for segment in range(len(theirs.segments)):
            a, b = ours.columns(kind, key, segment), theirs.columns(kind, key, segment)
            assert _same(a.t, b.t) and _same(a.values, b.values), (kind, key, segment)
    whole = decoded.collector
    whole.finish()
    assert sorted(whole._series) == sorted(ours._series) and len(whole.segments) == len(ours.segments)
    params, texts = (theirs.params, theirs.texts) if sampled == path else _pymavlink_notes(path, theirs.vehicle)
    assert decoded.params == params
    assert decoded.texts == texts


def _record(msg, sysid: int, t_us: int) -> bytes:
    """One .tlog record: the receive time, then ``msg`` packed by pymavlink as system ``sysid``."""
    from pymavlink.dialects.v20 import ardupilotmega as mav

    link = mav.MAVLink(None, srcSystem=sysid, srcComponent=1)
    return t_us.to_bytes(8, "big") + msg.pack(link)


def test_a_tlog_keeps_the_vehicle_and_counts_bad_packets(tmp_path):
    """Another system's packets are ignored (and said so); a packet whose checksum is wrong is
    skipped whole and counted; the rest reads as before."""
    from pymavlink.dialects.v20 import ardupilotmega as mav

    data = (SAMPLE_LOGS / "figure8.tlog").read_bytes()
    clean = read_tlog(str(SAMPLE_LOGS / "figure8.tlog"))
    clean.collector.finish()
    t0 = int.from_bytes(data[:8], "big")
    intruder = _record(mav.MAVLink_raw_imu_message(5_000_000, 1, 2, 3, 4, 5, 6, 7, 8, 9, 0, 0), 42, t0)
    damaged = bytearray(_record(mav.MAVLink_raw_imu_message(5_000_000, 1, 2, 3, 4, 5, 6, 7, 8, 9, 0, 0), 1, t0))
    damaged[20] ^= 0x10  # inside the payload: the checksum no longer fits
    path = tmp_path / "mixed.tlog"
    half = _record_boundary(data, len(data) // 2)
    path.write_bytes(data[:half] + intruder + bytes(damaged) + data[half:])
    decoded = read_tlog(str(path))
    decoded.collector.finish()
    assert any("other MAVLink systems [42]" in note for note in decoded.notes)
    assert any("1 with a wrong checksum" in w for w in decoded.warnings)
    for kind, key in clean.collector._series:
        a, b = decoded.collector.columns(kind, key, 0), clean.collector.columns(kind, key, 0)
        assert _same(a.t, b.t) and _same(a.values, b.values), (kind, key)


def _record_boundary(data: bytes, near: int) -> int:
    """The offset of the first .tlog record at or after ``near``."""
    from mavattitude.readers.tlogrecords import scan

    offsets = scan(np.frombuffer(data, np.uint8), 0, ["RAW_IMU"]).offsets
    return int(offsets[np.searchsorted(offsets, near)])
