"""Fair scoring on constructed logs: the board trim, gaps, a questionable reference."""
from __future__ import annotations

import json
import math
from dataclasses import replace

import numpy as np
import pytest

from mavattitude import quaternion as quat
from mavattitude.cli import main
from mavattitude.pipeline import board_trim, trimmed
from mavattitude.readers import read_log
from mavattitude.sim import simulate, write_log

TRIM = (math.radians(2.5), math.radians(-1.5))  # roll, pitch


@pytest.fixture(scope="module")
def trimmed_log(tmp_path_factory):
    """A simulated board mounted off level by TRIM: the IMU measures the board, the autopilot
    reports the vehicle (the board turned by the trim) and logs AHRS_TRIM_X/Y, as ArduPilot does."""
    sim = simulate("static", 60.0, seed=5, imu_rate=100.0)  # the filters are right to 0.1° here
    q_trim = np.broadcast_to(quat.conjugate(quat.from_euler(TRIM[0], TRIM[1], 0.0)), sim.autopilot_q.shape)
    sim = replace(sim, autopilot_q=quat.multiply(sim.autopilot_q, q_trim),
                  extra_params={"AHRS_TRIM_X": TRIM[0], "AHRS_TRIM_Y": TRIM[1], "AHRS_TRIM_Z": 0.0})
    return write_log(sim, tmp_path_factory.mktemp("trim") / "trimmed.bin")


def scores(log, tmp_path, *extra) -> dict:
    out = tmp_path / "m.json"
    assert main(["replay", str(log), "--estimators", "mahony", "--no-view", "--json", str(out), *extra]) == 0
    return json.loads(out.read_text())


def test_the_board_trim_is_read_and_turns_the_estimates_as_the_autopilot_does(trimmed_log, tmp_path):
    flight = read_log(str(trimmed_log))
    assert board_trim(flight) == pytest.approx(TRIM)
    with_trim = scores(trimmed_log, tmp_path)
    raw = scores(trimmed_log, tmp_path, "--no-trim")
    assert with_trim["scoring"]["board_trim"] == {"roll_deg": pytest.approx(2.5), "pitch_deg": pytest.approx(-1.5)}
    assert raw["scoring"]["board_trim"] is None
    m, r = with_trim["estimators"]["mahony"], raw["estimators"]["mahony"]
    # without the trim every estimate is off by it; with it the error is the filter's own
    assert r["roll"]["mae"] == pytest.approx(2.5, abs=0.2) and r["pitch"]["mae"] == pytest.approx(1.5, abs=0.2)
    assert m["roll"]["mae"] < 0.2 and m["pitch"]["mae"] < 0.2


def test_trimmed_is_the_autopilots_body_attitude():
    """Level board, trim (2.5°, -1.5°): the vehicle's roll and pitch are minus the trim (to
    first order: the trim turns about x, then y), its yaw the board's."""
    from mavattitude.flight import AttitudeSeries

    series = AttitudeSeries("x", np.array([0.0]), quat.from_euler(0.0, 0.0, 0.3)[None, :])
    euler = trimmed(series, TRIM).euler[0]
    assert euler == pytest.approx([-TRIM[0], -TRIM[1], 0.3], abs=2e-3)


def test_no_trim_in_the_log_means_none_applied(tmp_path):
    from conftest import SAMPLE_LOGS

    got = scores(SAMPLE_LOGS / "static.bin", tmp_path)
    assert got["scoring"]["board_trim"] is None
