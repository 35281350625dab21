"""Fair scoring on constructed logs: the board trim, gaps, a questionable reference."""
from __future__ import annotations

import json
import math
from dataclasses import replace

import numpy as np
import pytest

from mavattitude import quaternion as quat
from mavattitude.cli import main
from mavattitude.commands.replay import board_trim, trimmed
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


# ---------------------------------------------------------------- gaps


def test_no_estimate_is_interpolated_across_a_gap_or_a_restart():
    from mavattitude.flight import AttitudeSeries
    from mavattitude.scoring.metrics import compare

    def yaw_series(t, yaw_deg):
        return AttitudeSeries("x", t, np.array([quat.from_euler(0.0, 0.0, math.radians(y)) for y in yaw_deg]))

    t_est = np.concatenate([np.arange(0.0, 20.0, 0.1), np.arange(25.0, 40.0, 0.1)])  # a 5 s hole
    est = yaw_series(t_est, np.where(t_est < 22, 0.0, 90.0))
    t_ref = np.arange(0.0, 40.0, 0.25)
    ref = yaw_series(t_ref, np.where(t_ref < 22, 0.0, 90.0))
    bridged = compare(ref, est, warmup_s=0.0)
    held = compare(ref, est, warmup_s=0.0, max_gap_s=2.0)
    assert bridged.axes["yaw"].max > 20.0  # the interpolation across the hole invents an attitude
    in_hole = (t_ref > 19.9) & (t_ref < 25.0)
    assert held.n_in_gaps == np.count_nonzero(in_hole) and held.axes["yaw"].max < 1e-6
    assert not held.scored[np.isin(held.t, t_ref[in_hole])].any()
    # a restart is a hole too, however short the step across it
    restarted = compare(ref, yaw_series(t_ref[::2], np.where(t_ref[::2] < 22, 0.0, 90.0)), warmup_s=0.0,
                        restarts=[22.0])
    assert restarted.n_in_gaps == 1 and restarted.axes["yaw"].max < 1e-6


def test_a_logged_imu_gap_is_neither_scored_nor_bridged(tmp_path):
    """The static sample log with 6 s of IMU cut out (the attitude log goes on): the runner
    restarts, the reference samples in the hole are counted, not scored."""
    from conftest import SAMPLE_LOGS
    from mavattitude.commands.replay import run_replay

    flight = read_log(str(SAMPLE_LOGS / "static.bin"))
    for source, imu in flight.imu.items():
        keep = (imu.t < 20.0) | (imu.t > 26.0)
        flight.imu[source] = replace(imu, t=imu.t[keep], gyro=imu.gyro[keep], accel=imu.accel[keep],
                                     arrival=None if imu.arrival is None else imu.arrival[keep])
    result = run_replay(flight, ["mahony"], warmup_s=0.0)
    comp = result.comparisons["mahony"]
    t = flight.imu[result.imu_source].t
    last, first = t[t < 20.0][-1], t[t > 26.0][0]
    expected = np.count_nonzero((flight.attitude.t > last) & (flight.attitude.t < first))
    assert comp.n_in_gaps == expected > 0
    assert result.metrics["estimators"]["mahony"]["unscored_in_gaps"] == expected
    assert any("IMU gap" in e.text for e in result.events)


# ---------------------------------------------------------------- a questionable reference


@pytest.fixture(scope="module")
def broken_reference_log(tmp_path_factory):
    """A vehicle still on the ground for 60 s whose autopilot reports 10° of roll from 20 to
    30 s (its accelerometer says level) and a 60° roll for 3 s from 40 s (no gyro moved)."""
    sim = simulate("static", 60.0, seed=6, imu_rate=100.0)
    t = sim.t
    roll = np.where((t >= 20.0) & (t < 30.0), math.radians(10.0), 0.0)
    roll = np.where((t >= 40.0) & (t < 43.0), math.radians(60.0), roll)
    bad = quat.from_euler(roll, np.zeros_like(t), np.zeros_like(t))
    sim = replace(sim, autopilot_q=quat.multiply(sim.autopilot_q, bad))
    return write_log(sim, tmp_path_factory.mktemp("ref") / "broken.bin")


def test_a_reference_the_imu_contradicts_is_flagged_and_not_scored(broken_reference_log, tmp_path):
    got = scores(broken_reference_log, tmp_path)
    spans = got["scoring"]["reference_suspect"]
    rest = [s for s in spans if s["kind"] == "tilt at rest"]
    jump = [s for s in spans if s["kind"] == "tilt jump"]
    assert 19.0 <= rest[0]["start_s"] <= 21.5 and 28.5 <= rest[0]["end_s"] <= 31.0
    assert len(jump) == 1 and 39.5 <= jump[0]["start_s"] <= 40.5 and jump[0]["end_s"] >= 43.0  # out and back
    m = got["estimators"]["mahony"]
    assert m["unscored_suspect_reference"] > 0
    # the rest of the log is scored as if the reference had been right
    assert m["roll"]["max"] < 1.0


def test_repeated_reference_times_are_a_note_on_the_whole_log_not_a_span():
    """What happened and what was done, said plainly: on the terminal, and in the JSON as a
    note of its own, not a span with no end; everything left is scored."""
    from mavattitude.commands.replay import run_replay
    from mavattitude.scoring.refcheck import whole_log_notes

    flight = read_log(str(__import__("conftest").SAMPLE_LOGS / "static.bin"))
    assert whole_log_notes(flight.attitude, 0) == [] and whole_log_notes(flight.attitude, 1) == []
    flight.repeated[flight.attitude.source] = 2442  # as the reader counts the samples it dropped
    result = run_replay(flight, ["mahony"])
    share = 100.0 * 2442 / (len(flight.attitude.t) + 2442)
    said = (f"ATT timestamps repeat 2,442 times ({share:.1f} % of its samples); the repeats were dropped, "
            "the first of each time kept; the rest is scored")
    assert [e.text for e in result.events if e.level == "warn" and "repeat" in e.text] == [said]
    scoring = result.metrics["scoring"]
    assert scoring["reference_notes"] == [{"kind": "repeated times", "detail": said}]
    assert scoring["reference_suspect"] == []
    assert result.comparisons["mahony"].n_excluded == 0


def test_a_real_log_whose_att_times_repeat_says_what_was_done(tmp_path, capsys):
    log = __import__("conftest").shared_log("corpus/real-copter-3.3dev-erlepxf-dcm-althold-error-erle-20140318.bin")
    got = scores(log, tmp_path)
    err = capsys.readouterr().err
    notes = got["scoring"]["reference_notes"]
    assert [n["kind"] for n in notes] == ["repeated times"]
    assert notes[0]["detail"].startswith("ATT timestamps repeat 566 times (")
    assert f"warning: {notes[0]['detail']}" in err.splitlines()
    assert "not trusted from" not in err
    assert all(s["end_s"] is not None for s in got["scoring"]["reference_suspect"])
