"""PX4 ULog (.ulg): the simulator's ULog read back through pyulog and our reader (units,
frames, clock against the simulated truth), the same flight scored alike from .ulg and .bin,
the real samples in ../shared/logs/ulog against pyulog's raw values, detection by content, and
damaged files as one-line errors."""
from __future__ import annotations

import re

import shutil

import numpy as np
import pytest
from pyulog import ULog

from conftest import shared_log
from mavattitude.cli import main
from mavattitude.declination import for_flight
from mavattitude.commands.replay import replay_flight
from mavattitude.core.policy import RunOptions
from mavattitude.estimators import all_names
from mavattitude.readers import read_log
from mavattitude.sim import simulate, write_log

F32 = dict(rtol=1e-6, atol=1e-6)  # ULog stores float32


@pytest.fixture(scope="module")
def sim_logs(tmp_path_factory):
    """One simulated figure-eight written as .ulg and as .bin."""
    folder = tmp_path_factory.mktemp("ulg")
    sim = simulate("figure8", 60.0, seed=3, imu_rate=200.0)
    return sim, write_log(sim, folder / "figure8.ulg"), write_log(sim, folder / "figure8.bin")


def test_the_simulators_ulog_reads_back_in_si_on_its_clock(sim_logs):
    sim, ulg, _ = sim_logs
    flight = read_log(str(ulg))
    assert flight.format == "ulg" and flight.vehicle == "QUADROTOR"
    imu = flight.imu["sensor_combined"]
    np.testing.assert_allclose(imu.t, sim.imu[0].t, atol=1e-6)  # µs on the autopilot clock
    np.testing.assert_allclose(imu.gyro, sim.imu[0].gyro, **F32)
    np.testing.assert_allclose(imu.accel, sim.imu[0].accel, rtol=1e-6, atol=1e-5)
    mag = flight.mag["vehicle_magnetometer[0]"]
    np.testing.assert_allclose(mag.field, sim.mag.field, rtol=1e-6, atol=1e-11)  # gauss in the file, tesla here
    np.testing.assert_allclose(flight.gps.lat_deg, sim.gps.lat_deg, atol=1e-9)
    np.testing.assert_allclose(flight.gps.vel_ned, sim.gps.vel_ned, **F32)
    np.testing.assert_allclose(flight.baro.pressure_pa, sim.baro.pressure_pa, rtol=1e-6)
    every = sim.rates.att_every
    np.testing.assert_allclose(flight.truth.q, sim.truth.q[::every], **F32)
    np.testing.assert_allclose(flight.attitude.q, sim.autopilot_q[::every], **F32)
    declination = for_flight(flight)  # no EKF2_DECL_TYPE: set by hand
    assert declination.source.startswith("log parameter EKF2_MAG_DECL")
    assert declination.rad == pytest.approx(sim.declination_rad, abs=1e-6)


def test_pyulog_reads_what_the_simulator_writes(sim_logs):
    sim, ulg, _ = sim_logs
    ulog = ULog(str(ulg))
    assert not ulog.file_corruption and not ulog.dropouts
    data = {d.name: d.data for d in ulog.data_list}
    assert set(data) == {"sensor_combined", "vehicle_magnetometer", "vehicle_gps_position", "vehicle_air_data",
                         "vehicle_attitude", "vehicle_attitude_groundtruth", "vehicle_status"}
    np.testing.assert_allclose(data["sensor_combined"]["gyro_rad[2]"], sim.imu[0].gyro[:, 2], **F32)
    assert ulog.initial_parameters["MAV_TYPE"] == 2
    assert "mavattitude-sim" in ulog.msg_info_dict["ver_sw_branch"]


def test_the_same_flight_scores_alike_from_ulog_and_dataflash(sim_logs):
    _, ulg, binary = sim_logs
    settings = RunOptions(names=("mahony", "cpf-ekf"), reference="truth")
    scores = []
    for path in (ulg, binary):
        result, _ = replay_flight(read_log(str(path)), settings)
        scores.append({(n, axis): c.axes[axis].mae for n, c in result.comparisons.items() for axis in ("roll", "pitch")})
    for key, mae in scores[0].items():
        assert mae == pytest.approx(scores[1][key], rel=0.05, abs=0.01), key
    assert scores[0][("cpf-ekf", "roll")] < 0.2


# ---------------------------------------------------------------- real PX4 logs


def raw(path, topic, multi_id=0) -> dict:
    return next(d.data for d in ULog(str(path), message_name_filter_list=[topic]).data_list if d.multi_id == multi_id)


def test_a_real_flights_imu_compass_and_attitude_are_pyulogs_values():
    path = shared_log("ulog/px4-real-auav-x21-flight.ulg")
    flight = read_log(str(path))
    sc = raw(path, "sensor_combined")
    imu = flight.imu["sensor_combined"]
    np.testing.assert_array_equal(imu.t, sc["timestamp"] * 1e-6)
    np.testing.assert_array_equal(imu.gyro[:, 1], sc["gyro_rad[1]"].astype(float))
    np.testing.assert_array_equal(imu.accel[:, 2], sc["accelerometer_m_s2[2]"].astype(float))
    # the compass rides in sensor_combined in logs this old, each sample repeated until the next
    mag = flight.mag["sensor_combined"]
    t_mag = (sc["timestamp"].astype(np.int64) + sc["magnetometer_timestamp_relative"]) * 1e-6
    assert len(mag.t) == len(np.unique(t_mag)) and np.all(np.diff(mag.t) > 0)
    first = np.searchsorted(t_mag, mag.t[0])
    assert mag.field[0, 0] == pytest.approx(float(sc["magnetometer_ga[0]"][first]) * 1e-4)
    att = raw(path, "vehicle_attitude")
    q = np.column_stack([att[f"q[{k}]"] for k in range(4)]).astype(float)
    np.testing.assert_allclose(flight.attitude.q, q / np.linalg.norm(q, axis=1)[:, None], atol=1e-12)
    assert flight.baro is None  # its baro fields are all marked invalid
    assert any("dropped data 4 times" in w for w in flight.warnings)


def test_gps_baro_compass_and_delta_imus_of_a_newer_log():
    path = shared_log("ulog/px4-real-cubeorange-ground-6s.ulg")
    flight = read_log(str(path))
    gps = raw(path, "vehicle_gps_position")
    np.testing.assert_allclose(flight.gps.lat_deg, gps["lat"] * 1e-7)  # 1e-7 ° integers before PX4 1.14
    np.testing.assert_allclose(flight.gps.alt_m, gps["alt"] * 1e-3)  # mm
    air = raw(path, "vehicle_air_data")
    np.testing.assert_allclose(flight.baro.pressure_pa, air["baro_pressure_pa"].astype(float))
    np.testing.assert_allclose(flight.baro.t, air["timestamp_sample"] * 1e-6)
    mag = raw(path, "vehicle_magnetometer")
    np.testing.assert_allclose(flight.mag["vehicle_magnetometer[0]"].field[:, 0], mag["magnetometer_ga[0]"] * 1e-4)
    assert sorted(k for k in flight.imu if k.startswith("vehicle_imu")) == [f"vehicle_imu[{i}]" for i in range(3)]
    imu = raw(path, "vehicle_imu", 1)
    rate = imu["delta_angle[0]"] / (imu["delta_angle_dt"] * 1e-6)
    np.testing.assert_allclose(flight.imu["vehicle_imu[1]"].gyro[:, 0], rate, rtol=1e-6)
    assert flight.params["EKF2_MAG_DECL"] == pytest.approx(3.9908, abs=1e-3)  # saved by the last flight
    # EKF2_DECL_TYPE 7: PX4 looks the declination up at its fix, Trondheim in April 2021
    assert for_flight(flight).source.startswith("WMM-2020 at the first GPS fix 63.4171,10.4082 on 2021-04-21")
    assert "v1.11.2" in flight.firmware and "CUBEORANGE" in flight.firmware
    assert "vehicle_imu[0] is the IMU PX4 selected (sensor_selection); sensor_combined carries its samples" in flight.notes


def test_a_gps_without_its_sample_time_takes_its_publication_time():
    path = shared_log("ulog/px4-sitl-events-31s.ulg")
    flight = read_log(str(path))
    gps = raw(path, "vehicle_gps_position")
    assert not gps["timestamp_sample"].any()  # the driver leaves it 0
    np.testing.assert_allclose(flight.gps.t, gps["timestamp"] * 1e-6)
    np.testing.assert_allclose(flight.gps.lat_deg, gps["latitude_deg"])
    assert not flight.warnings


@pytest.mark.slow
def test_every_estimator_follows_px4s_ekf2_on_a_real_flight(capsys):
    path = shared_log("ulog/px4-real-auav-x21-flight.ulg")
    # its ±22° of roll come 5 s in: a 2 s warm-up keeps them scored
    result, _ = replay_flight(read_log(str(path)), RunOptions(names=tuple(all_names()), warmup_s=2.0))
    for name, c in result.comparisons.items():
        for axis in ("roll", "pitch"):
            assert c.axes[axis].mae < 0.15 and c.axes[axis].r2 > 0.99, (name, axis)


# ---------------------------------------------------------------- content, not name; damage


def test_a_ulog_is_known_by_its_content_and_a_non_ulog_is_named(sim_logs, tmp_path, capsys):
    _, ulg, _ = sim_logs
    renamed = tmp_path / "flight.bin"
    shutil.copy(ulg, renamed)
    assert read_log(str(renamed)).format == "ulg"
    fake = tmp_path / "fake.ulg"
    fake.write_bytes(b"not a log at all" * 10)
    assert main(["info", str(fake)]) == 1
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "not a PX4 ULog file" in err and str(fake) in err


def damaged_copies(source, folder):
    data = source.read_bytes()
    rng = np.random.default_rng(7)
    for n in (8, 16, 40, 200, 700, len(data) // 3, len(data) // 2, len(data) - 5):
        (folder / f"cut-{n}.ulg").write_bytes(data[:n])
        yield folder / f"cut-{n}.ulg"
    for k in range(12):
        damaged = bytearray(data)
        for at in rng.integers(16, len(data), 20):
            damaged[at] ^= 1 << int(rng.integers(8))
        (folder / f"flips-{k}.ulg").write_bytes(bytes(damaged))
        yield folder / f"flips-{k}.ulg"


def test_a_damaged_ulog_reads_or_fails_in_one_line(sim_logs, tmp_path, capsys):
    _, ulg, _ = sim_logs
    outcomes = set()
    for path in damaged_copies(ulg, tmp_path):
        code = main(["info", str(path)])
        err = capsys.readouterr().err
        assert code in (0, 1) and "Traceback" not in err, (path.name, err)
        if code == 1:
            errors = [line for line in err.splitlines() if line.startswith("mavattitude: error:")]
            assert len(errors) == 1 and str(path) in errors[0], err
        outcomes.add(code)
    assert outcomes == {0, 1}  # some damage is survivable, some is not


def test_evaluate_finds_and_scores_ulog(sim_logs, tmp_path):
    _, ulg, _ = sim_logs
    folder = tmp_path / "logs"
    folder.mkdir()
    shutil.copy(ulg, folder / "flight.ulg")
    out = tmp_path / "eval"
    assert main(["evaluate", str(folder), "--estimators", "mahony", "--reference", "truth", "--out", str(out),
                 "-j", "1", "-q"]) == 0
    assert "flight.ulg" in (out / "results.csv").read_text()


def test_a_topic_without_a_field_we_read_is_a_warning(tmp_path, monkeypatch):
    from mavattitude.sim import ulog as writer

    fields = [f for f in writer.TOPICS["vehicle_gps_position"] if f[3] != "eph"]
    monkeypatch.setitem(writer.TOPICS, "vehicle_gps_position", fields)
    columns = writer._topic_columns
    monkeypatch.setattr(writer, "_topic_columns", lambda sim: {
        name: {k: v for k, v in topic.items() if k != "eph"} for name, topic in columns(sim).items()})
    path = write_log(simulate("hover", 20.0), tmp_path / "other-px4.ulg")
    flight = read_log(str(path))
    assert flight.gps is None and flight.imu
    assert flight.warnings == ["vehicle_gps_position[0]: not read, it has no field 'eph' (a PX4 version not known here)"]


# ---------------------------------------------------------------- damage cut out and said (issue 23)

EVENTS_LOG = "ulog/px4-sitl-events-31s.ulg"


def zeroed(source, folder, at, n, name="damaged.ulg"):
    data = bytearray(source.read_bytes())
    data[at:at + n] = bytes(len(data[at:at + n]))
    (folder / name).write_bytes(bytes(data))
    return folder / name


def test_every_shared_ulog_frames_without_damage():
    from conftest import SHARED_LOGS
    from mavattitude.readers.ulogrecords import frame

    paths = sorted((SHARED_LOGS / "ulog").glob("*.ulg")) if (SHARED_LOGS / "ulog").is_dir() else []
    if not paths:
        pytest.skip(f"PX4 logs not found in {SHARED_LOGS / 'ulog'}")
    for path in paths:
        framing = frame(path.read_bytes())
        assert framing.damage == [] and framing.header == [] and framing.notes() == [], path.name


def test_zeroed_bytes_in_a_real_ulog_cost_one_message_not_its_tail(tmp_path):
    source = shared_log(EVENTS_LOG)
    whole = read_log(str(source))
    flight = read_log(str(zeroed(source, tmp_path, 862_488, 16)))  # pyulog alone stopped here, at 16.4 s
    imu = flight.imu["sensor_combined"]
    assert len(imu.t) >= len(whole.imu["sensor_combined"].t) - 1
    assert imu.t[-1] == whole.imu["sensor_combined"].t[-1]
    assert flight.warnings == ["skipped 54 bytes of corrupt data (0.0035 % of the file) in 1 stretch, the first "
                               "at byte 862,502: messages resumed after each (less than 0.01 s of data lost)"]


def test_zeroed_bytes_in_a_simulated_ulog_are_skipped_and_said(sim_logs, tmp_path):
    sim, ulg, _ = sim_logs
    size = ulg.stat().st_size
    flight = read_log(str(zeroed(ulg, tmp_path, size // 2, 64)))  # longer than a message: a header is hit
    assert abs(flight.imu["sensor_combined"].t[-1] - sim.t[-1]) < 0.01  # the tail is read
    assert len(flight.warnings) == 1 and "skipped" in flight.warnings[0]
    # a few samples at 200 Hz: under 0.01 s or a few hundredths, by where the bytes fall
    assert re.search(r"messages resumed after each \((less than 0\.01|0\.0\d+) s of data lost\)$", flight.warnings[0])
    cut = read_log(str(zeroed(ulg, tmp_path, size // 2, size, "tail.ulg")))
    assert cut.imu["sensor_combined"].t[-1] < sim.t[-1] * 0.6
    assert f"(the data ends at {cut.imu['sensor_combined'].t[-1]:.1f} s on the log's clock)" in cut.warnings[0]
    assert "the first at byte" in cut.warnings[0] and "% of the file is lost" in cut.warnings[0]


def test_a_damaged_ulog_header_is_read_and_said_or_one_line(tmp_path, capsys):
    source = shared_log(EVENTS_LOG)
    data = source.read_bytes()
    for at, value, said in [(127, data[127] ^ 0xFF, "the firmware version (ver_sw_release) is not a number"),
                            (0, ord("X"), "the ULog header is damaged (magic byte 0 is 0x58, not 0x55)"),
                            (7, 9, "the ULog header is damaged (version byte is 9, not 1)")]:
        damaged = bytearray(data)
        damaged[at] = value
        path = tmp_path / f"byte-{at}.ulg"
        path.write_bytes(bytes(damaged))
        assert main(["info", str(path)]) == 0
        out, err = capsys.readouterr()
        assert "Traceback" not in err and said in out and "pyulog" not in out, out
    damaged = bytearray(data)
    damaged[19 + 8] = 0xFF  # an incompatible flag pyulog does not know
    path = tmp_path / "flags.ulg"
    path.write_bytes(bytes(damaged))
    assert main(["info", str(path)]) == 1
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "not a readable ULog (header damaged" in err and str(path) in err
    damaged[0:2] = b"XX"  # two magic bytes: no ULog
    path.write_bytes(bytes(damaged))
    assert main(["info", str(path)]) == 1
    assert "not a PX4 ULog file" in capsys.readouterr().err


def test_cutting_damage_out_keeps_the_offsets_of_appended_data(sim_logs):
    """A ULog's flag bits may point at data appended later (file offsets): after the damage
    before it is cut out, the offset points at the same bytes."""
    import struct

    from mavattitude.readers.ulogrecords import frame

    _, ulg, _ = sim_logs
    data = bytearray(ulg.read_bytes())
    assert data[16 + 2] == ord("B")  # the flag-bits message comes first
    target = frame(bytes(data)).runs[0][1] * 3 // 4  # a place in the data, said to start appended data
    data[16 + 3 + 8] |= 1
    struct.pack_into("<Q", data, 16 + 3 + 16, target)
    data[target // 2:target // 2 + 64] = bytes(64)
    framing = frame(bytes(data))
    assert framing.damage and framing.damage[-1][1] < target
    repaired = framing.repaired(bytes(data))
    moved, = struct.unpack_from("<Q", repaired, 16 + 3 + 16)
    assert moved == target - framing.skipped and repaired[moved:moved + 100] == data[target:target + 100]


def test_a_damaged_array_size_in_a_format_is_damage_not_a_traceback(sim_logs, tmp_path, capsys):
    _, ulg, _ = sim_logs
    data = ulg.read_bytes()
    at = data.index(b"gyro_rad") - 3  # "float[3] gyro_rad": the 3
    assert data[at:at + 1] == b"3"
    path = tmp_path / "format.ulg"
    path.write_bytes(data[:at] + b"\xb3" + data[at + 1:])  # '³' in latin-1, a digit to str.isdigit
    assert main(["info", str(path)]) == 1  # the simulator's only IMU topic has lost its format
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "no IMU data" in err and "the file is damaged" in err


def test_a_corrupt_height_in_an_old_ulog_is_no_numpy_warning():
    """Old logs give the baro as a height; one above the standard atmosphere's top (a flipped
    bit, found by fuzzing the real flight) has no pressure: NaN, without numpy's warning."""
    import warnings

    from mavattitude.readers.collect import Collector
    from mavattitude.readers.ulog import _add_topic

    n = 3
    data = {"timestamp": np.array([1000, 2000, 3000], np.uint64), "baro_alt_meter": np.array([10.0, 9e4, 12.0]),
            "baro_timestamp_relative": np.zeros(n, np.int32), "accelerometer_timestamp_relative": np.zeros(n, np.int32),
            **{f"{field}[{k}]": np.zeros(n, np.float32)
               for field in ("gyro_rad", "accelerometer_m_s2") for k in range(3)}}
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        _add_topic(Collector(), "sensor_combined", "sensor_combined", data, [])


def test_a_signalling_nan_in_a_ulog_is_no_numpy_warning(tmp_path):
    """A flipped bit can make a float a signalling NaN, whose conversion numpy warns of (found
    fuzzing the shared ULogs): the sample is dropped, silently as any non-finite one."""
    import warnings

    from mavattitude.readers.collect import Collector
    from mavattitude.readers.ulog import _add_topic

    n = 3
    signalling = np.array([0x7FA00000], np.uint32).view(np.float32)[0]
    data = {"timestamp": np.array([1000, 2000, 3000], np.uint64),
            "accelerometer_timestamp_relative": np.zeros(n, np.int32),
            **{f"{field}[{k}]": np.ones(n, np.float32)
               for field in ("gyro_rad", "accelerometer_m_s2") for k in range(3)}}
    data["gyro_rad[0]"][1] = signalling
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        _add_topic(Collector(), "sensor_combined", "sensor_combined", data, [])
