"""Our ULog decoder (readers.ulogdata) against pyulog, its oracle: every wanted topic field by
field (names, dtypes, values bit-equal), parameters, info, multi ids and dropouts, on every shared
.ulg and on simulated ones; the whole Flight read both ways; what it does not follow goes to
pyulog with a note."""
from __future__ import annotations

import struct

import numpy as np
import pytest
from pyulog import ULog

from conftest import SHARED_LOGS
from mavattitude.readers import read_log
from mavattitude.readers import ulog as ulog_reader
from mavattitude.readers.ulog import TOPICS
from mavattitude.readers.ulogdata import Unsupported, read_topics
from mavattitude.readers.ulogrecords import frame
from mavattitude.sim import simulate, write_log

SHARED_ULOGS = SHARED_LOGS / "ulog"


def _shared_ulogs():
    paths = sorted(SHARED_ULOGS.glob("*.ulg")) if SHARED_ULOGS.is_dir() else []
    if not paths:
        return [pytest.param(None, marks=pytest.mark.skip(reason=f"real ULogs not found at {SHARED_ULOGS}"))]
    return [pytest.param(p, id=p.name) for p in paths]


@pytest.fixture(scope="module", params=[(20.0, 100.0, 1), (90.0, 400.0, 2)], ids=["20s-100Hz", "90s-400Hz"])
def simulated(request, tmp_path_factory):
    duration, rate, seed = request.param
    path = tmp_path_factory.mktemp("ulogsim") / "sim.ulg"
    write_log(simulate("figure8", duration, seed=seed, imu_rate=rate), path)
    return path


def assert_same_as_pyulog(path) -> None:
    data = path.read_bytes()
    ours = read_topics(data, frame(data), TOPICS)
    theirs = ULog(str(path), message_name_filter_list=TOPICS, disable_str_exceptions=True)
    assert [(d.name, d.multi_id) for d in ours.data_list] == [(d.name, d.multi_id) for d in theirs.data_list]
    for mine, other in zip(ours.data_list, theirs.data_list):
        assert list(mine.data) == list(other.data), mine.name  # names, in pyulog's order
        for name, values in other.data.items():
            assert mine.data[name].dtype == values.dtype, (mine.name, name)
            # bit-equal, NaNs and all
            assert mine.data[name].tobytes() == values.tobytes(), (mine.name, name)
    assert ours.initial_parameters == theirs.initial_parameters
    assert ours.msg_info_dict == theirs.msg_info_dict
    assert [d.duration for d in ours.dropouts] == [d.duration for d in theirs.dropouts]
    assert ours.file_corruption == theirs.file_corruption


@pytest.mark.parametrize("path", _shared_ulogs())
def test_every_shared_ulog_decodes_as_pyulog_does(path):
    assert_same_as_pyulog(path)


def test_simulated_ulogs_decode_as_pyulog_does(simulated):
    assert_same_as_pyulog(simulated)


def _flights_both_ways(path, monkeypatch):
    ours = read_log(str(path))
    monkeypatch.setattr(ulog_reader, "read_topics", lambda *a: (_ for _ in ()).throw(Unsupported("asked")))
    theirs = read_log(str(path))
    return ours, theirs


def _assert_same_series(a, b, where):
    if a is None or b is None:
        assert a is b, where
        return
    for name, value in vars(a).items():
        if isinstance(value, np.ndarray):
            np.testing.assert_array_equal(value, getattr(b, name), err_msg=f"{where}.{name}")


@pytest.mark.parametrize("path", _shared_ulogs())
def test_a_shared_ulog_reads_into_the_same_flight_both_ways(path, monkeypatch):
    ours, theirs = _flights_both_ways(path, monkeypatch)
    assert "read by pyulog (asked)" in theirs.notes and not any("pyulog" in n for n in ours.notes)
    assert sorted(ours.imu) == sorted(theirs.imu) and sorted(ours.mag) == sorted(theirs.mag)
    for key in ours.imu:
        _assert_same_series(ours.imu[key], theirs.imu[key], key)
    for key in ours.mag:
        _assert_same_series(ours.mag[key], theirs.mag[key], key)
    for name in ("gps", "baro", "attitude", "truth"):
        _assert_same_series(getattr(ours, name), getattr(theirs, name), name)
    assert ours.params == theirs.params and ours.vehicle == theirs.vehicle and ours.firmware == theirs.firmware
    assert ours.warnings == theirs.warnings


def test_a_simulated_ulog_reads_into_the_same_flight_both_ways(simulated, monkeypatch):
    ours, theirs = _flights_both_ways(simulated, monkeypatch)
    assert ours.truth is not None and ours.attitude is not None and ours.gps is not None
    _assert_same_series(ours.imu["sensor_combined"], theirs.imu["sensor_combined"], "imu")
    _assert_same_series(ours.truth, theirs.truth, "truth")
    _assert_same_series(ours.gps, theirs.gps, "gps")


def test_appended_data_is_read_by_pyulog_with_a_note(simulated, tmp_path):
    data = bytearray(simulated.read_bytes())
    assert data[16 + 2] == ord("B")
    data[16 + 3 + 8] |= 1  # appended data, at the file's end (nothing there yet)
    struct.pack_into("<Q", data, 16 + 3 + 16, len(data))
    path = tmp_path / "appended.ulg"
    path.write_bytes(bytes(data))
    with pytest.raises(Unsupported, match="appended"):
        read_topics(bytes(data), frame(bytes(data)), TOPICS)
    flight = read_log(str(path))
    assert "read by pyulog (data appended at given offsets)" in flight.notes
    assert len(flight.imu["sensor_combined"].t) == len(read_log(str(simulated)).imu["sensor_combined"].t)


def test_a_nested_format_flattens_as_pyulog_names_it():
    formats = {"outer": [("uint64_t", 0, "timestamp"), ("inner", 2, "part"), ("bool", 0, "ok"),
                         ("uint8_t", 3, "_padding0")],
               "inner": [("float", 2, "v"), ("char", 0, "c")]}
    dtype = ulog_reader_dtype(formats)
    assert dtype.names == ("timestamp", "part[0].v[0]", "part[0].v[1]", "part[0].c", "part[1].v[0]",
                           "part[1].v[1]", "part[1].c", "ok")
    assert dtype["ok"] == np.int8 and dtype["part[1].c"] == np.int8 and dtype.itemsize == 8 + 2 * 9 + 1
    formats["inner"] = [("float", -1, "v")]  # a damaged array size
    with pytest.raises(Unsupported):
        ulog_reader_dtype(formats)


def ulog_reader_dtype(formats):
    from mavattitude.readers.ulogdata import topic_dtype

    return topic_dtype(formats, "outer")


def _nested_ulog(n: int) -> bytes:
    """A ULog with a nested format (arrays of formats, bool, char, trailing padding) and many
    small data messages of two topics, an info string and two parameters."""
    from mavattitude.sim.ulog import HEADER, _message

    def param(kind, key, raw):
        text = f"{kind} {key}".encode()
        return bytes([len(text)]) + text + raw

    body = [_message(b"B", bytes(40)),
            _message(b"I", param("char[5]", "sys_name", b"PX4\x00\x00")),
            _message(b"P", param("int32_t", "MAV_TYPE", struct.pack("<i", 2))),
            _message(b"P", param("float", "EKF2_MAG_DECL", struct.pack("<f", 5.5))),
            _message(b"F", b"inner:float[2] v;char c;"),
            _message(b"F", b"outer:uint64_t timestamp;inner[2] part;bool ok;uint8_t[3] _padding0;"),
            _message(b"F", b"small:uint64_t timestamp;"),
            _message(b"A", struct.pack("<BH", 1, 7) + b"outer"),
            _message(b"A", struct.pack("<BH", 0, 9) + b"small")]
    rng = np.random.default_rng(5)
    for i in range(n):
        parts = rng.standard_normal(4).astype("<f4").tobytes()
        row = struct.pack("<Q", i) + parts[:8] + b"a" + parts[8:] + b"b" + bytes([i % 2])
        body.append(_message(b"D", struct.pack("<H", 7) + row))
        body += [_message(b"D", struct.pack("<HQ", 9, 10 * i + k)) for k in range(4)]
        if i == n // 2:
            body.append(_message(b"O", struct.pack("<H", 12)))
    return HEADER + struct.pack("<Q", 0) + b"".join(body)


def test_a_nested_format_with_many_small_messages_decodes_as_pyulog_does(tmp_path):
    path = tmp_path / "nested.ulg"
    path.write_bytes(_nested_ulog(3000))  # data messages average < 32 bytes: the offsets' array grows
    data = path.read_bytes()
    framing = frame(data)
    assert not framing.damage and len(framing.data_at) == 5 * 3000
    ours = read_topics(data, framing, ["outer", "small"])
    theirs = ULog(str(path), message_name_filter_list=["outer", "small"], disable_str_exceptions=True)
    assert [(d.name, d.multi_id) for d in ours.data_list] == [("outer", 1), ("small", 0)]
    for mine, other in zip(ours.data_list, theirs.data_list):
        assert list(mine.data) == list(other.data)
        for name, values in other.data.items():
            assert mine.data[name].dtype == values.dtype and mine.data[name].tobytes() == values.tobytes()
    assert ours.initial_parameters == theirs.initial_parameters == {"MAV_TYPE": 2, "EKF2_MAG_DECL": 5.5}
    assert ours.msg_info_dict == theirs.msg_info_dict == {"sys_name": "PX4\x00\x00"}  # pyulog keeps the NULs
    assert [d.duration for d in ours.dropouts] == [d.duration for d in theirs.dropouts] == [12]


def test_a_damaged_ulog_reads_into_the_same_flight_both_ways(simulated, tmp_path, monkeypatch):
    """Damage is cut out before either decoder: ours reads the valid messages where they lie,
    pyulog the repaired copy, and the flights agree."""
    data = bytearray(simulated.read_bytes())
    starts = frame(bytes(data)).data_at  # a message's header: damage the framing itself
    for at in (len(data) // 3, len(data) // 2):
        at = int(starts[np.searchsorted(starts, at)])
        data[at:at + 16] = bytes(16)  # where pyulog alone would stop reading (issue 23)
    path = tmp_path / "damaged.ulg"
    path.write_bytes(bytes(data))
    ours, theirs = _flights_both_ways(path, monkeypatch)
    assert any("skipped" in w for w in ours.warnings) and ours.warnings == theirs.warnings
    _assert_same_series(ours.imu["sensor_combined"], theirs.imu["sensor_combined"], "imu")
    _assert_same_series(ours.attitude, theirs.attitude, "attitude")
    _assert_same_series(ours.gps, theirs.gps, "gps")


def test_a_damaged_header_is_read_by_our_decoder(simulated, tmp_path):
    data = bytearray(simulated.read_bytes())
    data[0], data[7] = ord("X"), 0  # one magic byte; version 0 (an older PX4's)
    path = tmp_path / "header.ulg"
    path.write_bytes(bytes(data))
    damaged, sound = read_log(str(path)), read_log(str(simulated))
    assert not any("pyulog" in n for n in damaged.notes) and any("magic byte 0" in w for w in damaged.warnings)
    _assert_same_series(damaged.imu["sensor_combined"], sound.imu["sensor_combined"], "imu")
