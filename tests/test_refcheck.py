"""refcheck's "autopilot disagrees" check: the autopilot's own estimators apart in tilt for long."""
from __future__ import annotations

import math
from dataclasses import replace

import numpy as np

from conftest import read_shared
from mavattitude import quaternion as quat
from mavattitude.flight import AttitudeSeries, Flight
from mavattitude.readers import read_log
from mavattitude.scoring.refcheck import DISAGREE_DEG, autopilot_disagreement
from mavattitude.sim import SensorParams, simulate, write_log


def two_estimators(extra_roll_deg):
    """ATT (DCM) 1° from EKF1 throughout, EKF1's roll moved by ``extra_roll_deg(t)``; AHR2 a copy of EKF1."""
    t = np.arange(0.0, 120.0, 0.1)
    roll, pitch, yaw = 0.2 * np.sin(0.3 * t), 0.1 * np.cos(0.2 * t), 0.05 * t
    att = AttitudeSeries("ATT", t, quat.from_euler(roll + math.radians(1.0), pitch, yaw))
    ekf = AttitudeSeries("EKF1", t + 0.002, quat.from_euler(roll + np.radians(extra_roll_deg(t)), pitch, yaw))
    copy = AttitudeSeries("AHR2", t + 0.001, ekf.q.copy())
    return Flight("x.bin", "bin", attitude=att, params={"AHRS_EKF_USE": 0.0},
                  attitudes={"ATT": att, "EKF1": ekf, "AHR2": copy})


def test_a_long_disagreement_is_flagged_naming_both_streams():
    # 25° for 20 s from 60 s (with a 1 s dip to 0 inside it), a 40° transient for 4 s at 20 s
    def extra(t):
        long = np.where((t >= 60.0) & (t < 80.0) & ~((t >= 70.0) & (t < 71.0)), 25.0, 0.0)
        return long + np.where((t >= 20.0) & (t < 24.0), 40.0, 0.0)
    flight = two_estimators(extra)
    suspects = autopilot_disagreement(flight.attitude, flight)
    assert len(suspects) == 1  # not the transient, not AHR2 again, the dip bridged
    s = suspects[0]
    assert s.kind == "autopilot disagrees" and 59.9 <= s.start <= 60.2 and 79.7 <= s.end <= 80.1
    # the time above 10°: 20 s less the dip
    assert s.detail.startswith("ATT (DCM) and EKF1 (EKF1) differ in tilt by more than 10° for 19 s")
    assert "median 24°" in s.detail  # 25° less ATT's 1° offset


def test_a_gap_in_the_other_stream_does_not_end_a_disagreement():
    """6 s apart, 8 s without EKF1 samples, 6 s apart: one span of 12 s above 10°, though neither half is 10 s."""
    flight = two_estimators(lambda t: np.where((t >= 60.0) & (t < 80.0), 25.0, 0.0))
    ekf = flight.attitudes["EKF1"]
    kept = (ekf.t < 66.0) | (ekf.t >= 74.0)
    flight.attitudes["EKF1"] = flight.attitudes["AHR2"] = AttitudeSeries("EKF1", ekf.t[kept], ekf.q[kept])
    suspects = autopilot_disagreement(flight.attitude, flight)
    assert len(suspects) == 1 and 59.9 <= suspects[0].start <= 60.2 and 79.7 <= suspects[0].end <= 80.1
    assert "for 12 s" in suspects[0].detail


def test_the_normal_degree_apart_and_short_transients_are_not_flagged():
    flight = two_estimators(lambda t: np.where((t >= 30.0) & (t < 39.0), DISAGREE_DEG + 20.0, 0.0))
    assert autopilot_disagreement(flight.attitude, flight) == []
    alone = Flight("x.bin", "bin", attitude=flight.attitude, attitudes={"ATT": flight.attitude})
    assert autopilot_disagreement(flight.attitude, alone) == []


def test_the_88_degree_log_is_flagged_and_modern_logs_are_not():
    flight = read_shared("corpus/real-copter-3.3dev-erlepxf-dcm-long-erle-20140923-51.bin")
    suspects = autopilot_disagreement(flight.attitude, flight)
    assert sum(s.end - s.start for s in suspects) > 1200.0  # of ATT's 1,306 s: across its gaps too
    assert all("ATT (DCM) and EKF1 (EKF1)" in s.detail for s in suspects)
    for name in ("corpus/real-copter-4.5.7-pixhawk6x-tipover-quiver088.bin",
                 "corpus/real-copter-4.1.3-cubeblack-mission-fyp-test3.bin", "sitl-copter-4.7-vibration.tlog"):
        modern = read_shared(name)
        assert autopilot_disagreement(modern.attitude, modern) == [], name


def test_replay_leaves_the_disagreement_unscored(tmp_path):
    from mavattitude.commands.replay import run_replay

    sim = simulate("figure8", 60.0, seed=3, imu_rate=50.0, params=SensorParams(dcm_bias=(0.01, 0.0, 0.0)))
    t = sim.t
    off = quat.from_euler(np.where((t >= 30.0) & (t < 45.0), math.radians(20.0), 0.0), 0 * t, 0 * t)
    sim = replace(sim, ekf_q=quat.multiply(sim.ekf_q, off))  # the EKF beside ATT (DCM) 20° off for 15 s
    result = run_replay(read_log(write_log(sim, tmp_path / "apart.bin")), ["mahony"])
    spans = [s for s in result.metrics["scoring"]["reference_suspect"] if s["kind"] == "autopilot disagrees"]
    assert len(spans) == 1 and 29.5 <= spans[0]["start_s"] <= 30.5 and 44.5 <= spans[0]["end_s"] <= 45.5
    assert "AHR2" in spans[0]["detail"] or "EKF1" in spans[0]["detail"]
    assert result.comparisons["mahony"].n_excluded > 0
    assert any("reference not trusted" in e.text and "differ in tilt" in e.text for e in result.events)


def test_a_reference_not_trusted_anywhere_says_so_when_nothing_is_scored(tmp_path):
    from mavattitude.commands.replay import run_replay
    from mavattitude.commands.report import nothing_scored

    sim = simulate("figure8", 40.0, seed=3, imu_rate=50.0, params=SensorParams(dcm_bias=(0.01, 0.0, 0.0)))
    off = quat.from_euler(np.full(len(sim.t), math.radians(20.0)), 0 * sim.t, 0 * sim.t)
    sim = replace(sim, ekf_q=quat.multiply(sim.ekf_q, off))  # the EKF 20° from ATT (DCM) all along
    result = run_replay(read_log(write_log(sim, tmp_path / "apart.bin")), ["mahony"])
    assert nothing_scored(result.comparisons, 10.0) == (
        "nothing scored: the reference is not trusted anywhere the estimates overlap it after the 10 s warm-up "
        "(the 'reference not trusted' warnings say where and why)")
