"""Readers: real logs (units, clocks, sources) and simulated logs with exact truth."""
from __future__ import annotations

import numpy as np
import pytest

from conftest import read_shared, shared_log, shared_log_params
from mavattitude import quaternion as quat
from mavattitude.errors import InputError
from mavattitude.flight import GRAVITY
from mavattitude.readers import best_imu_source, imu_rate, read_log, sniff_format
from mavattitude.readers.collect import Collector


# ---------------------------------------------------------------- bad input


@pytest.mark.parametrize("content, problem", [
    (b"", "empty file"),
    (b"hello, this is not a log at all" * 4, "not a DataFlash .bin file"),
])
def test_bad_files_name_the_problem(tmp_path, content, problem):
    path = tmp_path / "broken.bin"
    path.write_bytes(content)
    with pytest.raises(InputError) as err:
        read_log(str(path))
    assert str(path) in str(err.value) and problem in str(err.value)
    assert "\n" not in str(err.value)


def test_missing_file_and_folder(tmp_path):
    with pytest.raises(InputError, match="no such file"):
        read_log(str(tmp_path / "nope.tlog"))
    with pytest.raises(InputError, match="is a folder"):
        read_log(str(tmp_path))


def test_truncated_dataflash_still_reads_what_is_there(sim_logs, tmp_path):
    _, path = sim_logs["figure8.bin"]
    data = path.read_bytes()
    cut = tmp_path / "cut.bin"
    cut.write_bytes(data[: len(data) // 2 + 7])  # mid-record
    flight = read_log(str(cut))
    full = read_log(str(path))
    n = len(flight.imu["IMU[0]"].t)
    assert 0.3 * len(full.imu["IMU[0]"].t) < n < 0.7 * len(full.imu["IMU[0]"].t)


def test_corrupt_records_are_dropped_not_decoded_as_data(sim_logs, tmp_path, capfd):
    _, path = sim_logs["figure8.bin"]
    data = bytearray(path.read_bytes())
    rng = np.random.default_rng(1)
    for start in (100_000, 300_000):  # overwrite two stretches with noise and fake headers
        noise = rng.integers(0, 256, 600, dtype=np.uint8)
        noise[::37] = 0xA3
        noise[1::37] = 0x95
        data[start:start + 600] = noise.tobytes()
    bad = tmp_path / "corrupt.bin"
    bad.write_bytes(bytes(data))
    flight = read_log(str(bad))
    out, err = capfd.readouterr()
    assert out == "" and err == ""  # what was skipped is a warning of the flight, not terminal noise
    assert any("skipped" in w and "corrupt" in w for w in flight.warnings)
    assert len(flight.segments) == 1
    for s in flight.imu.values():
        assert np.abs(s.gyro).max() < 5.0 and np.abs(s.accel).max() < 50.0
        assert np.all(np.diff(s.t) > 0) and s.t[-1] - s.t[0] < 120.0


def test_lone_timestamp_far_ahead_is_dropped_a_real_jump_kept():
    col = Collector()
    for t in [1.0, 1.1, 5000.0, 1.2, 1.3]:  # a corrupt record's garbage time
        col.add("imu", "A", t, (t,))
    for t in [900.0, 900.1, 900.2, 900.3, 900.4]:  # a telemetry link that came back 15 minutes later
        col.add("imu", "A", t, (t,))
    col.finish()
    t = col.columns("imu", "A", 0).t
    np.testing.assert_allclose(t, [1.0, 1.1, 1.2, 1.3, 900.0, 900.1, 900.2, 900.3, 900.4])
    assert col.outliers == 1 and len(col.segments) == 1


def test_a_time_a_few_seconds_off_is_corrupt_not_a_reboot():
    # A flipped bit moved one sample 4 s ahead: taken at face value, the next samples would
    # look like a reboot and the flight before it would be lost.
    col = Collector()
    times = [10.0 + 0.01 * i for i in range(300)]
    times[100] += 4.0
    times[200] -= 7.0  # and one 7 s back
    for t in times:
        col.add("imu", "A", t, (t,))
    col.finish()
    assert len(col.segments) == 1 and col.outliers == 2
    assert len(col.columns("imu", "A", 0)[0]) == 298


# ---------------------------------------------------------------- clocks


def test_the_clock_tracker_decides_the_same_fed_in_pieces():
    """A live link feeds the tracker a few samples at a time; a log, all at once."""
    from mavattitude.readers.collect import ClockTracker

    rng = np.random.default_rng(4)
    t = np.concatenate([5000.0 + np.zeros(1), 1.0 + 0.01 * np.arange(400), 50.0 + 0.01 * np.arange(300),
                        0.5 + 0.01 * np.arange(300), 30.0 + 0.01 * np.arange(3)])
    t[rng.choice(len(t), 12, replace=False)] = rng.uniform(-10, 1e4, 12)  # corrupt times
    whole = ClockTracker()
    labels, _ = whole.push(t)
    for g, label in whole.finish():
        labels[g] = label
    pieces = ClockTracker()
    streamed = np.full(len(t), 99)
    start = 0
    while start < len(t):
        size = int(rng.integers(1, 9))
        out, earlier = pieces.push(t[start:start + size])
        streamed[start:start + size] = out
        for g, label in earlier:
            streamed[g] = label
        start += size
    for g, label in pieces.finish():
        streamed[g] = label
    np.testing.assert_array_equal(streamed, labels)
    assert set(labels.tolist()) == {-1, 0, 1}  # one reboot, some corrupt, nothing left held
    assert labels[0] == -1 and np.all(labels[-3:] == -1)  # a lone first time; a jump nothing confirmed


def test_collector_splits_reboots_and_keeps_samples_newer_than_those_before():
    col = Collector()
    for t in [10.0, 10.1, 10.3, 10.2, 10.3, 10.4]:  # one reordered, one repeated
        col.add("imu", "A", t, (t,))
    for t in [0.5, 0.6, 0.7, 0.8, 0.9]:  # the clock went back, and stays back: a reboot
        col.add("imu", "A", t, (t,))
    col.finish()
    assert len(col.segments) == 2
    c = col.columns("imu", "A", 0)
    np.testing.assert_allclose(c.t, [10.0, 10.1, 10.3, 10.4])  # 10.2 came too late: as live drops it
    assert (c.reordered, c.duplicates) == (1, 1)
    np.testing.assert_array_equal(c.arrival, [0, 1, 2, 5])  # each sample's place in the file
    t = col.columns("imu", "A", 1).t
    np.testing.assert_allclose(t, [0.5, 0.6, 0.7, 0.8, 0.9])
    assert col.longest_segment() == 0


def test_a_reboot_is_confirmed_across_streams_and_a_short_tail_is_dropped():
    col = Collector()
    for i in range(20):  # two streams interleaved, as in a log
        col.add("imu", "A", 50.0 + 0.1 * i, (0.0,))
        col.add("att", "B", 50.0 + 0.1 * i, (0.0,))
    for i in range(3):
        col.add("imu", "A", 1.0 + 0.1 * i, (0.0,))
        col.add("att", "B", 1.0 + 0.1 * i, (0.0,))
    col.finish()
    assert len(col.segments) == 2 and col.outliers == 0
    assert len(col.columns("att", "B", 1)[0]) == 3
    col = Collector()
    for i in range(20):
        col.add("imu", "A", 50.0 + 0.1 * i, (0.0,))
    for i in range(3):  # the log ends before a jump could be confirmed: dropped
        col.add("imu", "A", 1.0 + 0.1 * i, (0.0,))
    col.finish()
    assert len(col.segments) == 1 and col.outliers == 3


def test_reboot_in_a_real_tlog_keeps_the_longest_segment():
    flight = read_shared("copter-4.1-flight.tlog")  # three power cycles in one file
    assert len(flight.segments) == 3
    assert flight.segment_index == 0
    assert any("reboot" in w for w in flight.warnings)
    other = read_log(str(shared_log("copter-4.1-flight.tlog")), segment=2)
    assert other.time_span[1] < flight.time_span[1]
    with pytest.raises(InputError, match="segment 7 does not exist"):
        read_log(str(shared_log("copter-4.1-flight.tlog")), segment=7)


# ---------------------------------------------------------------- real logs


@pytest.mark.parametrize("path", shared_log_params())
def test_every_shared_log_reads_in_si_units(path):
    flight = read_shared(path.name)
    assert flight.imu and flight.attitude is not None
    for s in flight.imu.values():
        assert np.all(np.diff(s.t) > 0)
        # Still or flying, the median specific force is about one g: m/s², not mG or g.
        assert abs(np.median(np.linalg.norm(s.accel, axis=1)) - GRAVITY) < 0.8
        assert np.abs(s.gyro).max() < 35.0  # rad/s, not mrad/s or deg/s
    for s in flight.mag.values():
        strength = np.median(np.linalg.norm(s.field, axis=1))
        assert 15e-6 < strength < 80e-6  # tesla: Earth's field
    np.testing.assert_allclose(np.linalg.norm(flight.attitude.q, axis=1), 1.0, atol=1e-9)


@pytest.mark.parametrize("name, truth_source", [("sitl-copter-4.7-400hz.bin", "SIM"),
                                                 ("sitl-copter-4.4.bin", "SIM"),
                                                 ("sitl-copter-4.7-50hz.tlog", "SIMSTATE"),
                                                 ("sitl-plane-4.7-circuit.tlog", "SIMSTATE")])
def test_autopilot_attitude_matches_truth_in_units_and_frame(name, truth_source):
    """ATT (degrees, yaw 0-360) and ATTITUDE (radians) land in the same frame as the truth."""
    flight = read_shared(name)
    assert flight.truth.source == truth_source
    truth = quat.interpolate(flight.truth.t, flight.truth.q, flight.attitude.t)
    ok = ~np.isnan(truth[:, 0])
    err = quat.wrap_deg(np.degrees(quat.to_euler(flight.attitude.q[ok]) - quat.to_euler(truth[ok])))
    assert np.median(np.abs(err[:, :2])) < 1.0  # EKF3 vs truth: tenths of a degree
    assert np.median(np.abs(err[:, 2])) < 3.0


def test_old_log_clocks_and_gps_boot_time():
    flight = read_shared("copter-3.3-loiter-rtl.bin")  # TimeMS clock; GPS boot time in T
    imu = flight.imu["IMU[0]"]
    assert imu_rate(imu) == pytest.approx(50.0, rel=0.05)
    assert imu.t[0] <= flight.gps.t[0] < imu.t[-1]
    assert flight.gps.t[-1] <= imu.t[-1] + 1.0
    assert flight.vehicle == "ArduCopter"


def test_best_imu_prefers_float_data_at_the_same_rate():
    assert best_imu_source(read_shared("sitl-copter-4.7-50hz.tlog")) == "HIGHRES_IMU"
    assert best_imu_source(read_shared("sitl-copter-4.7-400hz.bin")) == "IMU[0]"
    flight = read_shared("sitl-copter-4.7-400hz.bin")
    assert imu_rate(flight.imu["IMU[0]"]) == pytest.approx(400.0, rel=0.01)


def test_highres_imu_magnetometer_unit_is_repaired():
    flight = read_shared("sitl-copter-4.7-50hz.tlog")
    highres = np.median(np.linalg.norm(flight.mag["HIGHRES_IMU"].field, axis=1))
    raw = np.median(np.linalg.norm(flight.mag["RAW_IMU"].field, axis=1))
    assert highres == pytest.approx(raw, rel=0.01)
    assert any("HIGHRES_IMU: magnetometer strength" in n for n in flight.notes)


def test_declination_parameter_and_firmware():
    flight = read_shared("sitl-copter-4.7-400hz.bin")
    assert flight.params["COMPASS_DEC"] == pytest.approx(0.2234, abs=1e-3)
    assert flight.firmware.startswith("ArduCopter V4.7")


# ---------------------------------------------------------------- simulated logs, exact truth


@pytest.mark.parametrize("name", ["figure8.tlog", "figure8.bin"])
def test_simulated_log_round_trips_through_the_reader(sim_logs, name):
    sim, path = sim_logs[name]
    flight = read_log(str(path))
    source = best_imu_source(flight)
    imu = flight.imu[source]
    # Same samples, same clock (µs or ms resolution), same units.
    n = min(len(imu.t), len(sim.t))
    assert abs(len(imu.t) - len(sim.t)) <= 1
    np.testing.assert_allclose(imu.t[:n], sim.t[:n], atol=1e-3)
    tol_gyro, tol_acc = (1.1e-3, 0.011) if name.endswith(".tlog") else (1e-6, 1e-5)  # mrad/s, mG
    np.testing.assert_allclose(imu.gyro[:n], sim.imu[0].gyro[:n], atol=tol_gyro)
    np.testing.assert_allclose(imu.accel[:n], sim.imu[0].accel[:n], atol=tol_acc)
    # Truth in the log matches the simulator's truth.
    truth = quat.interpolate(sim.t, sim.truth.q, flight.truth.t)
    ok = ~np.isnan(truth[:, 0])
    err = quat.wrap_deg(np.degrees(quat.to_euler(flight.truth.q[ok]) - quat.to_euler(truth[ok])))
    assert np.abs(err).max() < 0.05
    assert flight.params["COMPASS_DEC"] == pytest.approx(sim.declination_rad, abs=1e-6)
    assert flight.gps is not None and flight.baro is not None and flight.mag


# ---------------------------------------------------------------- tolerance


def _tlog_metrics(path, tmp_path, name):
    import json

    from mavattitude.cli import main
    out = tmp_path / f"{name}.json"
    assert main(["replay", str(path), "--no-view", "--json", str(out)]) == 0
    return json.loads(out.read_text())["estimators"]


def test_a_tlog_behind_a_ground_station_header_reads_as_pymavlink_reads_it(tmp_path):
    """Some ground stations write a header before the first record (1,359 bytes in one real log)."""
    from conftest import SAMPLE_LOGS

    data = (SAMPLE_LOGS / "figure8.tlog").read_bytes()
    header = (b"\xfe\xfd" * 40 + bytes(range(256)) * 6)[:1359]  # with stray magic bytes
    (tmp_path / "headed.tlog").write_bytes(header + data)
    assert sniff_format(str(tmp_path / "headed.tlog")) == "tlog"
    assert _tlog_metrics(tmp_path / "headed.tlog", tmp_path, "h") == _tlog_metrics(SAMPLE_LOGS / "figure8.tlog", tmp_path, "p")


def test_a_tlog_is_known_by_its_content_whatever_its_name_and_folder(tmp_path):
    from conftest import SAMPLE_LOGS

    folder = tmp_path / "bin"  # pymavlink's mavlink_connection would *run* a file under a /bin/ folder
    folder.mkdir()
    (folder / "flight.bin").write_bytes((SAMPLE_LOGS / "figure8.tlog").read_bytes())
    flight = read_log(str(folder / "flight.bin"))
    assert flight.format == "tlog" and "RAW_IMU" in flight.imu


# ---------------------------------------------------------------- IMU families (--imu-source)


def test_delta_angles_read_as_rates_that_integrate_to_the_true_turn(tmp_path):
    """IMT (simulate --imt): delta angle / its interval, at the IMU's times, integrates to the
    true attitude change (exactly, but for the sensor's noise and bias)."""
    from mavattitude.sim import simulate, write_log

    sim = simulate("figure8", 60.0, seed=2, imu_rate=50.0)
    flight = read_log(str(write_log(sim, tmp_path / "f8.bin", imt=True)))
    imt, imu = flight.imu["IMT[0]"], flight.imu["IMU[0]"]
    np.testing.assert_allclose(imt.t, imu.t[1:], atol=1e-6)
    dt = np.diff(sim.t)[:, None]
    true_turn = quat.to_rotation_vector(quat.multiply(quat.conjugate(sim.truth.q[:-1]), sim.truth.q[1:]))
    sensor_error = (sim.imu[0].gyro - sim.truth.omega_b)[1:]
    np.testing.assert_allclose(imt.gyro * dt, true_turn + sensor_error * dt, atol=1e-7)
    assert best_imu_source(flight) == "IMU[0]" and best_imu_source(flight, "delta") == "IMT[0]"
    with pytest.raises(KeyError, match="no IMU of the 'raw' family"):
        best_imu_source(flight, "raw")


def test_sensor_rate_gyro_and_accel_join_on_the_gyro_clock():
    from mavattitude.readers.series import sensor_rate_imu

    t_gyro = np.arange(0.0, 1.0, 0.001)
    t_accel = np.concatenate([np.arange(0.0, 0.5, 0.002), np.arange(0.6, 1.0, 0.002)])  # a 100 ms hole
    accel = np.column_stack([t_accel, 2 * t_accel, np.full_like(t_accel, -9.8)])
    t, values, arrival = sensor_rate_imu((t_gyro, np.ones((len(t_gyro), 3)), np.arange(len(t_gyro))),
                                         (t_accel, accel, np.arange(len(t_accel))))
    assert not np.any((t > 0.5 + 0.02) & (t < 0.6 - 0.02))  # no accelerometer there
    np.testing.assert_allclose(values[:, 3], t, atol=1e-12)  # linear: interpolated exactly
    np.testing.assert_allclose(values[:, :3], 1.0)
    assert np.all(np.diff(arrival) > 0)


def test_sensor_rate_samples_of_a_real_log():
    """ArduPilot SITL 4.7 with raw IMU logging: GYR/ACC at 1.2 kHz beside IMU at 400 Hz, the
    same motion (the IMU message holds the filtered samples)."""
    flight = read_shared("sitl-copter-4.7-400hz.bin")
    raw, imu = flight.imu["GYR[0]"], flight.imu["IMU[0]"]
    assert imu_rate(raw) == pytest.approx(1200, rel=0.01) and imu_rate(imu) == pytest.approx(400, rel=0.01)
    assert best_imu_source(flight) == "IMU[0]" and best_imu_source(flight, "raw") == "GYR[0]"
    for a, b in ((raw.gyro, imu.gyro), (raw.accel, imu.accel)):
        np.testing.assert_allclose(a.mean(axis=0), b.mean(axis=0), atol=0.02)


def test_the_pymavlink_fallback_reads_what_the_bulk_reader_reads(sim_logs, monkeypatch):
    """A log the bulk reader cannot lay out goes to pymavlink, into the same columns."""
    from mavattitude.readers import dataflash

    _, path = sim_logs["figure8.bin"]
    bulk = read_log(str(path))
    monkeypatch.setattr(dataflash, "scan_log", lambda *a: (_ for _ in ()).throw(RuntimeError("test")))
    slow = read_log(str(path))
    assert slow.notes and "read with pymavlink" in slow.notes[0]
    assert list(slow.imu) == list(bulk.imu) and slow.params == bulk.params
    for key in bulk.imu:
        np.testing.assert_array_equal(slow.imu[key].gyro, bulk.imu[key].gyro)
    np.testing.assert_array_equal(slow.attitude.q, bulk.attitude.q)
    np.testing.assert_array_equal(slow.gps.lat_deg, bulk.gps.lat_deg)


def test_a_series_filled_in_place_is_the_series_joined_from_its_parts():
    """A sensor type read in parts, two instances interleaved: given its record count
    (``capacity``) each series is filled in place, and comes out as the parts joined would,
    to the bit, with the clock followed the same."""
    rng = np.random.default_rng(4)
    n = 1000
    order = np.arange(n) * 3
    t = np.repeat(np.arange(n // 2) * 0.01, 2)
    values = rng.normal(size=(n, 6))
    cols = []
    for capacity in (0, n):
        col = Collector()
        col.add_columns("baro", "BARO", order[::5] + 1, t[::5], values[::5, :2])
        for a in range(0, n, 300):  # parts of 300 records, each split by instance
            for i in (0, 1):
                mine = slice(a + i, a + 300, 2)
                col.add_columns("imu", f"IMU[{i}]", order[mine], t[mine], values[mine], capacity=capacity)
        col.finish()
        cols.append(col)
    assert cols[0].keys("imu") == cols[1].keys("imu") == ["IMU[0]", "IMU[1]"]
    assert cols[0].segments == cols[1].segments
    for key in ("IMU[0]", "IMU[1]"):
        a, b = (c.columns("imu", key, 0) for c in cols)
        assert len(a.t) == n // 2
        for x, y in zip(a, b):
            np.testing.assert_array_equal(x, y)


def test_row_norms_are_numpys_to_the_bit():
    x = np.random.default_rng(1).normal(size=(70_001, 3)) * 1e3
    np.testing.assert_array_equal(quat.row_norms(x, rows=4096), np.linalg.norm(x, axis=1))
    x32 = x.astype(np.float32)
    assert quat.row_norms(x32).dtype == np.float32
    np.testing.assert_array_equal(quat.row_norms(x32), np.linalg.norm(x32, axis=1))
