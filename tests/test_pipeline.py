"""Replay: magnetometer on the IMU clock, restarts after gaps, scoring rows (the declination: test_declination)."""
from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from mavattitude import quaternion as quat
from mavattitude.errors import InputError, UsageError
from mavattitude.flight import ImuSeries, MagSeries
from mavattitude.pipeline import run_replay
from mavattitude.readers import read_log
from mavattitude.runner import held_magnetometer


def test_mag_is_held_until_stale():
    mag = MagSeries("m", np.array([1.0, 1.1, 1.2, 5.0]), np.arange(12.0).reshape(4, 3))
    imu_t = np.array([0.9, 1.0, 1.05, 1.25, 1.6, 1.8, 5.01])
    out = held_magnetometer(imu_t, mag)
    assert np.isnan(out[0]).all()  # before the first sample
    np.testing.assert_array_equal(out[1], [0, 1, 2])
    np.testing.assert_array_equal(out[2], [0, 1, 2])
    np.testing.assert_array_equal(out[3], [6, 7, 8])
    np.testing.assert_array_equal(out[4], [6, 7, 8])  # 0.4 s old: still within 0.5 s
    assert np.isnan(out[5]).all()  # 0.6 s old: stale
    np.testing.assert_array_equal(out[6], [9, 10, 11])
    assert held_magnetometer(imu_t, None) is None


def test_gap_restarts_the_estimators_from_a_fresh_alignment(sim_logs):
    sim, path = sim_logs["figure8.bin"]
    flight = read_log(str(path))
    imu = flight.imu["IMU[0]"]
    # Cut 5 s out of the IMU while the vehicle turns: what it did meanwhile is unknown, so
    # the estimators start again from the accelerometer and magnetometer after the gap.
    cut = (imu.t > 50.0) & (imu.t < 55.0)
    keep = ~cut
    flight.imu = {"IMU[0]": ImuSeries("IMU[0]", imu.t[keep], imu.gyro[keep], imu.accel[keep])}
    result = run_replay(flight, ["mahony"], reference="truth", warmup_s=0.0)
    assert any("IMU gap of 5.0 s" in e.text for e in result.events)
    q = result.estimates["mahony"].q
    assert np.isfinite(q).all()
    i = np.searchsorted(imu.t[keep], 55.0)
    np.testing.assert_allclose(np.linalg.norm(q, axis=1), 1.0, atol=1e-9)
    # After the gap the filter starts from the accelerometer, close to the truth again.
    truth = quat.interpolate(sim.t, sim.truth.q, imu.t[keep][i:i + 50])
    err = np.degrees(quat.to_euler(q[i:i + 50])[:, :2] - quat.to_euler(truth)[:, :2])
    assert np.abs(err).max() < 10.0


def test_reference_truth_adds_the_autopilot_row(sim_logs):
    flight = read_log(str(sim_logs["figure8.tlog"][1]))
    result = run_replay(flight, ["mahony"], reference="truth")
    assert set(result.comparisons) == {"mahony", "autopilot"}
    assert result.reference.source == "SIMSTATE"
    assert result.comparisons["autopilot"].axes["roll"].mae < 0.5
    with pytest.raises(UsageError, match="unknown reference"):
        run_replay(flight, ["mahony"], reference="nope")
    no_truth = replace(flight, truth=None)
    with pytest.raises(InputError, match="no ground truth"):
        run_replay(no_truth, ["mahony"], reference="truth")


def test_low_imu_rate_warns(sim_logs):
    flight = read_log(str(sim_logs["figure8.tlog"][1]))
    imu = flight.imu["RAW_IMU"]
    every = slice(None, None, 10)  # 50 Hz -> 5 Hz
    flight.imu = {"RAW_IMU": ImuSeries("RAW_IMU", imu.t[every], imu.gyro[every], imu.accel[every])}
    result = run_replay(flight, ["mahony"])
    assert any("low IMU rate: 5.0 Hz" in e.text for e in result.events)


def test_estimating_in_steps_changes_nothing_and_reports_progress(sim_logs, monkeypatch):
    """An hour is estimated in steps of ``STEP_ROWS`` (bounded scratch memory): every
    estimate and diagnostic is bit-identical to one step, and the progress climbs to 1."""
    from mavattitude import runner
    from mavattitude.estimators import ESTIMATORS

    flight = read_log(str(sim_logs["figure8.bin"][1]))
    whole = run_replay(flight, list(ESTIMATORS))
    monkeypatch.setattr(runner, "STEP_ROWS", 700)
    seen = []
    steps = run_replay(flight, list(ESTIMATORS), progress=seen.append)
    assert len(seen) > 10 and seen == sorted(seen) and seen[-1] == 1.0
    for name in ESTIMATORS:
        np.testing.assert_array_equal(steps.estimates[name].q, whole.estimates[name].q)
        assert steps.diagnostics[name].keys() == whole.diagnostics[name].keys()
        for key, values in whole.diagnostics[name].items():
            np.testing.assert_array_equal(steps.diagnostics[name][key], values)
        assert steps.comparisons[name].axes == whole.comparisons[name].axes
