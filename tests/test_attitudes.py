"""Every attitude the autopilot logged: read (flight.attitudes), named (readers.attitudes), listed by info."""
from __future__ import annotations

import numpy as np
import pytest

from conftest import SHARED_LOGS, read_shared
from mavattitude.commands import info
from mavattitude import quaternion as quat
from mavattitude.flight import AttitudeSeries, Flight
from mavattitude.readers import read_log
from mavattitude.readers.attitudes import name_attitudes
from mavattitude.readers.collect import Collector
from mavattitude.sim import SensorParams, simulate, write_log

# What each shared log's streams are, as ArduPilot's logging code and the "ATT equals which
# stream" comparison say (the primary first). The twelve erle 2014-15 logs are DCM-reference
# logs with EKF1 beside ATT, but for one (20150331-83: ATT equals EKF1 on 80 % of samples); the
# 3.6-dev pixracer log has AHRS_EKF_TYPE=0, which ArduCopter reads as EKF2 (ATT equals NKF1).
EXPECTED = {
    "copter-3.3-loiter-rtl.bin": {"ATT": "DCM", "AHR2": "EKF1", "EKF1": "EKF1"},
    "copter-3.4-erlebrain-22.bin": {"ATT": "EKF2", "AHR2": "DCM", "NKF1[0]": "EKF2 core 0"},
    "copter-4.1-flight.tlog": {"ATTITUDE": "EKF", "AHRS2": "DCM"},
    "plane-3.1-flight-329.bin": {"ATT": "DCM", "AHR2": "EKF1", "EKF1": "EKF1"},
    "sitl-copter-4.4.bin": {"ATT": "EKF3", "XKF1[0]": "EKF3 core 0", "XKF1[1]": "EKF3 core 1", "AHR2": "DCM"},
    "sitl-copter-4.7-400hz.bin": {"ATT": "EKF3", "XKF1[0]": "EKF3 core 0", "XKF1[1]": "EKF3 core 1", "AHR2": "DCM",
                                  "DCM": "DCM"},
    "sitl-copter-4.7-50hz.tlog": {"ATTITUDE": "EKF3", "ATTITUDE_QUATERNION": "EKF3", "AHRS2": "DCM"},
    "sitl-copter-4.7-vibration.tlog": {"ATTITUDE": "EKF3", "ATTITUDE_QUATERNION": "EKF3", "AHRS2": "DCM"},
    "sitl-copter-4.7-wind.tlog": {"ATTITUDE": "EKF3", "ATTITUDE_QUATERNION": "EKF3", "AHRS2": "DCM"},
    "sitl-plane-4.7-circuit.tlog": {"ATTITUDE": "unknown", "ATTITUDE_QUATERNION": "unknown", "AHRS2": "unknown"},
    "sitl-quadplane-vtol.tlog": {"ATTITUDE": "SITL", "AHRS2": "DCM", "AHRS3": "EKF2"},
    "corpus/real-copter-3.1.3-pixhawk1-joeydouglas-flight-a.bin": {"ATT": "DCM"},
    "corpus/real-copter-3.1.3-pixhawk1-joeydouglas-flight-b.bin": {"ATT": "DCM"},
    "corpus/real-copter-3.2.1-pixhawk1-upset-at-end-peterbarker3.bin": {"ATT": "EKF1", "AHR2": "DCM", "EKF1": "EKF1"},
    "corpus/real-copter-3.2.1rc1-pixhawk1-aggressive-loggaps-peterbarker1.bin": {"ATT": "DCM", "AHR2": "EKF1",
                                                                                "EKF1": "EKF1"},
    "corpus/real-copter-3.3dev-erlepxf-dcm-alt-issue-erle-aux.bin": {"ATT": "DCM", "EKF1": "EKF1"},
    "corpus/real-copter-3.3dev-erlepxf-dcm-althold-error-erle-20140318.bin": {"ATT": "DCM", "AHR2": "EKF1",
                                                                              "EKF1": "EKF1"},
    "corpus/real-copter-3.3dev-erlepxf-dcm-flight-erle-20140929-4.bin": {"ATT": "DCM", "EKF1": "EKF1"},
    "corpus/real-copter-3.3dev-erlepxf-dcm-flight-erle-20141222-41.bin": {"ATT": "DCM", "EKF1": "EKF1"},
    "corpus/real-copter-3.3dev-erlepxf-dcm-gps-flight-erle-20141009-31.bin": {"ATT": "DCM", "AHR2": "EKF1",
                                                                              "EKF1": "EKF1"},
    "corpus/real-copter-3.3dev-erlepxf-dcm-gps-flight-erle-20141110-103.bin": {"ATT": "DCM", "AHR2": "EKF1",
                                                                               "EKF1": "EKF1"},
    "corpus/real-copter-3.3dev-erlepxf-dcm-gps-issues-erle-20141106.bin": {"ATT": "DCM", "AHR2": "EKF1", "EKF1": "EKF1"},
    "corpus/real-copter-3.3dev-erlepxf-dcm-gps-mag-erle-20150331-83.bin": {"ATT": "EKF1", "AHR2": "DCM", "EKF1": "EKF1"},
    "corpus/real-copter-3.3dev-erlepxf-dcm-long-erle-20140923-51.bin": {"ATT": "DCM", "EKF1": "EKF1"},
    "corpus/real-copter-3.4.6-pixhawk1-mag-anomaly-forumlog0039.bin": {"ATT": "EKF2", "AHR2": "DCM",
                                                                       "NKF1[0]": "EKF2 core 0", "NKF1[1]": "EKF2 core 1"},
    "corpus/real-copter-3.4rc2-erlebrain-ekf2-flight-erle-apm7.bin": {"ATT": "EKF2", "AHR2": "DCM",
                                                                      "NKF1[0]": "EKF2 core 0"},
    "corpus/real-copter-3.6.8-pixhawk1-nogps-hover-yladzislay.bin": {"ATT": "EKF3", "XKF1[0]": "EKF3 core 0",
                                                                     "XKF1[1]": "EKF3 core 1", "AHR2": "DCM"},
    "corpus/real-copter-3.6dev-pixracer-dcm-lowbatt-suweipeng.bin": {"ATT": "EKF2", "AHR2": "DCM",
                                                                     "NKF1[0]": "EKF2 core 0"},
    "corpus/real-copter-4.1.3-cubeblack-crash-flip-fyp-test4.bin": {"ATT": "EKF3", "XKF1[0]": "EKF3 core 0",
                                                                    "XKF1[1]": "EKF3 core 1", "AHR2": "DCM"},
    "corpus/real-copter-4.1.3-cubeblack-loggap-fyp-test1.bin": {"ATT": "EKF3", "XKF1[0]": "EKF3 core 0",
                                                                "XKF1[1]": "EKF3 core 1", "AHR2": "DCM"},
    "corpus/real-copter-4.1.3-cubeblack-mission-fyp-test3.bin": {"ATT": "EKF3", "XKF1[0]": "EKF3 core 0",
                                                                 "XKF1[1]": "EKF3 core 1", "AHR2": "DCM"},
    "corpus/real-copter-4.5.7-pixhawk6x-ekf-lane-switch-quiver083.bin": {"ATT": "EKF3", "XKF1[0]": "EKF3 core 0",
                                                                         "XKF1[1]": "EKF3 core 1", "AHR2": "DCM",
                                                                         "DCM": "DCM"},
    "corpus/real-copter-4.5.7-pixhawk6x-mag-anomaly-quiver090.bin": {"ATT": "EKF3", "XKF1[0]": "EKF3 core 0",
                                                                     "XKF1[1]": "EKF3 core 1", "AHR2": "DCM",
                                                                     "DCM": "DCM"},
    "corpus/real-copter-4.5.7-pixhawk6x-tipover-quiver088.bin": {"ATT": "EKF3", "XKF1[0]": "EKF3 core 0",
                                                                 "XKF1[1]": "EKF3 core 1", "AHR2": "DCM", "DCM": "DCM"},
    "corpus/real-plane-3.0.4b3-erlepxf-dcm-erle-roverfolder-20140802-10.bin": {"ATT": "DCM", "EKF1": "EKF1"},
    "corpus/real-plane-3.1.2b1-erlepxf-dcm-flight-erle-20141205.bin": {"ATT": "DCM", "AHR2": "EKF1", "EKF1": "EKF1"},
    "corpus/real-plane-4.3.1-kakutef7-crash-bixler-scottyob.bin": {"ATT": "EKF3", "XKF1[0]": "EKF3 core 0",
                                                                   "AHR2": "DCM"},
    "corpus/real-sub-4.1.0-bluerov-dive-thruster-setup-orca-mohai009.bin": {"ATT": "EKF3", "XKF1[0]": "EKF3 core 0",
                                                                            "AHR2": "DCM"},
    "corpus/real-sub-4.2.0dev-bluerov-dive-handling-orca-mohai016.bin": {"ATT": "EKF3", "XKF1[0]": "EKF3 core 0",
                                                                         "AHR2": "DCM"},
    "corpus/real-sub-4.2.0dev-bluerov-dive-orca-signalqual027.bin": {"ATT": "EKF3", "XKF1[0]": "EKF3 core 0",
                                                                     "AHR2": "DCM"},
    "corpus/real-sub-4.5.0b1-bluerov-compasscal-handrotated-orca-0925.tlog": {"ATTITUDE": "EKF3", "AHRS2": "DCM"},
    "corpus/real-sub-4.5.0b1-bluerov-compasscal-handrotated-orca126.bin": {"ATT": "EKF3", "XKF1[0]": "EKF3 core 0",
                                                                           "AHR2": "DCM", "DCM": "DCM"},
    "corpus/sitl-copter-4.1.0dev-simtruth-mission-delorean017.bin": {"ATT": "EKF3", "XKF1[0]": "EKF3 core 0",
                                                                     "XKF1[1]": "EKF3 core 1", "AHR2": "DCM"},
    "ulog/px4-real-auav-x21-flight.ulg": {"vehicle_attitude": "PX4 Q"},
    "ulog/px4-real-cubeorange-ground-6s.ulg": {"vehicle_attitude": "PX4 EKF2"},
    "ulog/px4-real-fmuv3-1.9-escstatus-40s.ulg": {"vehicle_attitude": "PX4 EKF2"},
    "ulog/px4-sitl-1.8-groundtruth-26s.ulg": {"vehicle_attitude": "PX4 EKF2"},
    "ulog/px4-sitl-events-31s.ulg": {"vehicle_attitude": "PX4 EKF2"},
}
SLOW = ("sitl-copter-4.7-400hz.bin",)  # 78 MB


@pytest.mark.parametrize("name", [pytest.param(n, marks=[pytest.mark.slow] if n in SLOW else []) for n in EXPECTED])
def test_every_shared_log_streams_read_and_named(name):
    flight = read_shared(name)
    named = name_attitudes(flight)
    assert {n.key: n.algorithm for n in named} == EXPECTED[name]
    assert named[0].primary and named[0].key == flight.attitude.source
    assert flight.attitudes[flight.attitude.source] is flight.attitude  # the primary is one of them, unchanged
    assert not any(n.primary for n in named[1:])
    for key, s in flight.attitudes.items():
        assert len(s.t) > 100 and np.all(np.diff(s.t) > 0), key
        assert np.allclose(np.linalg.norm(s.q, axis=1), 1.0), key


def test_every_shared_log_is_in_the_table():
    if not SHARED_LOGS.is_dir():
        pytest.skip(f"real logs not found at {SHARED_LOGS}")
    found = {str(p.relative_to(SHARED_LOGS)) for sub in ("", "corpus", "ulog")
             for p in (SHARED_LOGS / sub).iterdir() if p.suffix in (".bin", ".tlog", ".ulg")}
    assert found == set(EXPECTED)


def test_a_primary_that_equals_an_ekf_core_says_so():
    """ATT of a modern log equals XKF1 core 0 to the bit; where the EKF switched lanes, each core in turn."""
    lane_switch = read_shared("corpus/real-copter-4.5.7-pixhawk6x-ekf-lane-switch-quiver083.bin")
    named = {n.key: n for n in name_attitudes(lane_switch)}
    assert named["ATT"].equals["XKF1[0]"] == pytest.approx(0.90, abs=0.02)
    assert named["ATT"].equals["XKF1[1]"] == pytest.approx(0.10, abs=0.02)
    mixed = name_attitudes(read_shared("corpus/real-plane-4.3.1-kakutef7-crash-bixler-scottyob.bin"))[0]
    assert mixed.algorithm == "EKF3" and "DCM 37 %" in mixed.evidence  # a plane falls back to DCM


@pytest.mark.parametrize("suffix, names", [
    (".bin", {"ATT": "DCM", "AHR2": "EKF1", "EKF1": "EKF1"}),
    (".tlog", {"ATTITUDE": "DCM", "AHRS2": "EKF1"}),
    (".ulg", {"vehicle_attitude": "PX4 Q", "estimator_attitude[0]": "PX4 EKF2 instance 0"}),  # PX4's DCM: Q
])
def test_simulated_dcm_primary_read_back_with_its_names_and_bias(tmp_path, suffix, names):
    bias = np.radians([2.0, -1.0, 3.0])
    sim = simulate("figure8", 40.0, seed=3, imu_rate=50.0, params=SensorParams(dcm_bias=tuple(bias)))
    flight = read_log(write_log(sim, tmp_path / f"dcm{suffix}"))
    assert {n.key: n.algorithm for n in name_attitudes(flight)} == names
    primary, ekf_key = list(names)[0], list(names)[-1]
    assert flight.attitude.source == primary
    dcm, ekf = flight.attitude, flight.attitudes[ekf_key]
    apart = np.degrees(quat.wrap_pi(dcm.euler - quat.to_euler(quat.interpolate(ekf.t, ekf.q, dcm.t))))
    # DCM - EKF: the bias, within the EKF's own wander (0.15° RMS tilt, 0.3° yaw) and the noise's (0.3° RMS)
    assert apart.mean(axis=0) == pytest.approx(np.degrees(bias), abs=0.2)
    assert apart.std(axis=0) == pytest.approx([0.34, 0.34, 0.42], abs=0.1)


@pytest.mark.parametrize("name, algorithm", [("figure8.bin", "EKF3"), ("figure8.tlog", "EKF")])
def test_default_simulation_has_one_autopilot_attitude(sim_logs, name, algorithm):
    sim, path = sim_logs[name]
    flight = read_log(path)
    assert sim.ekf_q is None and list(flight.attitudes) == [flight.attitude.source]
    # the .bin's ATT.AEKF says EKF3; the .tlog's quadrotor uses an EKF, the log does not say which
    assert name_attitudes(flight)[0].algorithm == algorithm


def test_streams_beside_the_primary_follow_the_clock_and_change_nothing_else():
    """A follower sample takes the segment of the sample before it in the file, or is dropped when
    its time is off; the segments and the other series are those found without it."""
    def collector(with_followers):
        col = Collector()
        t = np.r_[np.arange(10.0, 20.0, 0.1), np.arange(1.0, 5.0, 0.1)]  # a reboot at the 100th sample
        col.add_columns("imu", "IMU[0]", np.arange(len(t)) * 10, t, np.zeros((len(t), 6)))
        if with_followers:
            order = np.arange(len(t))[::5] * 10 + 5
            times = t[::5].copy()
            times[3] = 500.0  # a corrupt time
            col.add_columns("stream_euler", "AHR2", order, times, np.zeros((len(times), 3)))
        col.finish()
        return col
    plain, both = collector(False), collector(True)
    assert both.segments == plain.segments and both.outliers == plain.outliers
    for segment in (0, 1):
        a, b = plain.columns("imu", "IMU[0]", segment), both.columns("imu", "IMU[0]", segment)
        assert np.array_equal(a.t, b.t) and np.array_equal(a.arrival, b.arrival)
    first, second = both.columns("stream_euler", "AHR2", 0), both.columns("stream_euler", "AHR2", 1)
    assert len(first.t) == 19 and 500.0 not in first.t  # 20 in the first segment, one corrupt
    assert len(second.t) == 8 and second.t.min() >= 1.0


def test_info_lists_the_streams(tmp_path):
    sim = simulate("hover", 20.0, seed=1, imu_rate=50.0, params=SensorParams(dcm_bias=(0.02, 0.0, 0.0)))
    flight = read_log(write_log(sim, tmp_path / "dcm.bin"))
    summary = info.summarize(flight)
    streams = {s["stream"]: s for s in summary["attitude_streams"]}
    assert list(streams) == ["ATT", "AHR2", "EKF1"]
    assert streams["ATT"]["primary"] and streams["ATT"]["algorithm"] == "DCM"
    assert streams["ATT"]["named_by"] == "ATT.AEKF"
    assert streams["EKF1"]["rate_hz"] == pytest.approx(25.0, rel=0.01) and streams["EKF1"]["equals"]["AHR2"] == 1.0
    text = info.render(summary)
    assert "* ATT" in text and "EKF1" in text and "autopilot attitudes" in text


@pytest.mark.parametrize("use_ekf, att_is_ekf, expected", [
    (0, True, "EKF1"),  # the comparison beats the parameter
    (1, False, "DCM"),  # an EKF chosen but never in use: ATT equals none of the EKF's samples
    (1, True, "EKF1"),
    (0, False, "DCM"),
])
def test_primary_named_by_comparison_before_parameters(use_ekf, att_is_ekf, expected):
    t = np.arange(0.0, 20.0, 0.1)
    ekf_q = quat.from_euler(0.1 * np.sin(t), 0.05 * np.cos(t), 0.3 * t)
    att_q = ekf_q if att_is_ekf else quat.from_euler(0.1 * np.sin(t) + 0.01, 0.05 * np.cos(t), 0.3 * t)
    att = AttitudeSeries("ATT", t, att_q)
    flight = Flight("x.bin", "bin", attitude=att, params={"AHRS_EKF_USE": float(use_ekf), "AHRS_TRIM_X": 0.0},
                    attitudes={"ATT": att, "EKF1": AttitudeSeries("EKF1", t + 0.001, ekf_q)})
    named = name_attitudes(flight)
    assert [n.key for n in named] == ["ATT", "EKF1"] and named[0].algorithm == expected
    assert named[0].equals["EKF1"] == (1.0 if att_is_ekf else 0.0)
