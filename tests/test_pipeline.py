"""Replay: magnetometer on the IMU clock, restarts after gaps, scoring rows (the declination: test_declination)."""
from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from mavattitude import quaternion as quat
from mavattitude.errors import InputError
from mavattitude.flight import ImuSeries, MagSeries
from mavattitude.commands.replay import run_replay
from mavattitude.readers import read_log
from mavattitude.core.runner import held_magnetometer


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
    with pytest.raises(InputError, match="has no attitude stream 'nope'"):
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
    assert "5.0 Hz" in result.comparisons["mahony"].not_meaningful  # scored, but marked


def test_estimating_in_steps_changes_nothing_and_reports_progress(sim_logs, monkeypatch):
    """An hour is estimated in steps of ``STEP_ROWS`` (bounded scratch memory): every
    estimate and diagnostic is bit-identical to one step, and the progress climbs to 1."""
    from mavattitude.core import runner
    from conftest import installed_estimators

    names = installed_estimators()
    flight = read_log(str(sim_logs["figure8.bin"][1]))
    whole = run_replay(flight, names)
    monkeypatch.setattr(runner, "STEP_ROWS", 700)
    seen = []
    steps = run_replay(flight, names, progress=seen.append)
    assert len(seen) > 10 and seen == sorted(seen) and seen[-1] == 1.0
    for name in names:
        np.testing.assert_array_equal(steps.estimates[name].q, whole.estimates[name].q)
        assert steps.diagnostics[name].keys() == whole.diagnostics[name].keys()
        for key, values in whole.diagnostics[name].items():
            np.testing.assert_array_equal(steps.diagnostics[name][key], values)
        assert steps.comparisons[name].axes == whole.comparisons[name].axes


# ---------------------------------------------------------------- warnings on the terminal


def test_warnings_are_one_line_per_kind_with_the_count_and_the_first_times():
    from mavattitude.events import Event, grouped_lines

    events = [Event(40.1, "warn", "IMU gap of 3.0 s: estimators re-initialised", kind="IMU gap"),
              Event(12.3, "warn", "IMU gap of 2.5 s: estimators re-initialised", kind="IMU gap"),
              Event(5.0, "warn", "no initial still period"),
              Event(88.0, "warn", "IMU gap of 9.0 s: estimators re-initialised", kind="IMU gap"),
              Event(90.0, "info", "in the air", kind="IMU gap"),  # another level: not counted
              Event(95.5, "warn", "IMU gap of 4.0 s: estimators re-initialised", kind="IMU gap"),
              Event(99.0, "warn", "the same words twice"), Event(99.5, "warn", "the same words twice"),
              Event(100.0, "warn", "IMU gap of 2.1 s: estimators re-initialised", kind="IMU gap")]
    assert grouped_lines(events[:2]) == ["IMU gap: 2 times, at 12.3, 40.1 s"]
    assert grouped_lines(events) == ["no initial still period",  # alone: its own text, in time order
                                     "IMU gap: 5 times, at 12.3, 40.1, 88.0, … s",
                                     "the same words twice: 2 times, at 99.0, 99.5 s"]
    assert grouped_lines(events[3:4]) == ["IMU gap of 9.0 s: estimators re-initialised"]
    assert grouped_lines(events, level="info") == ["in the air"]


def test_many_imu_gaps_are_one_warning_line_and_every_one_stays_in_the_json(capsys):
    from conftest import SAMPLE_LOGS
    from mavattitude.events import grouped_lines
    from mavattitude.core.runner import GAP_KIND

    flight = read_log(str(SAMPLE_LOGS / "static.bin"))
    holes = [(8.0, 11.0), (14.0, 17.5), (20.0, 23.0), (26.0, 30.0), (33.0, 36.0)]
    for source, imu in flight.imu.items():
        keep = np.ones(len(imu.t), dtype=bool)
        for a, b in holes:
            keep &= (imu.t < a) | (imu.t > b)
        flight.imu[source] = replace(imu, t=imu.t[keep], gyro=imu.gyro[keep], accel=imu.accel[keep],
                                     arrival=None if imu.arrival is None else imu.arrival[keep])
    result = run_replay(flight, ["mahony", "eskf"], warmup_s=0.0)
    gaps = [e for e in result.events if e.kind == GAP_KIND]
    assert len(gaps) == len(holes) and all(e.text.startswith("IMU gap of ") for e in gaps)
    lines = [line for line in grouped_lines(result.events) if line.startswith(GAP_KIND)]
    first = ", ".join(f"{e.t:.1f}" for e in gaps[:3])
    assert lines == [f"{GAP_KIND}: 5 times, at {first}, … s"]
    assert [e["text"] for e in result.metrics["events"] if e["kind"] == GAP_KIND] == [e.text for e in gaps]


def test_a_real_log_s_many_watchdog_resets_are_one_warning_line(tmp_path, capsys):
    from conftest import shared_log
    from mavattitude.cli import main

    log = shared_log("copter-4.1-flight.tlog")
    out = tmp_path / "m.json"
    assert main(["replay", str(log), "--estimators", "cpf-ekf", "--no-view", "--json", str(out)]) == 0
    err = capsys.readouterr().err
    warnings = [line for line in err.splitlines() if line.startswith("warning: ")]
    resets = [line for line in warnings if "watchdog reset" in line]
    got = __import__("json").loads(out.read_text())
    times = got["estimators"]["cpf-ekf"]["events"]["resets"]["times"]
    assert len(times) > 10  # 23 with the model's declination, 27 with 0
    assert resets == ["warning: cpf-ekf: watchdog reset (EKF attitude too far from its complementary filter, "
                      f"restarted from it): {len(times)} times, at {times[0]:.1f}, {times[1]:.1f}, {times[2]:.1f}, … s"]
    assert len(warnings) <= 6  # the log's own few, not one per reset
    assert sum("watchdog reset" in e["text"] for e in got["events"]) == len(times)  # each one kept in the JSON


@pytest.mark.slow  # cpf-ekf over a sample log: seconds, kept out of the quick loop
def test_the_aiding_kept_is_what_the_estimator_was_handed(sim_logs):
    """The runner keeps the aiding only at the IMU rows that had a measurement; given back
    at every row (NaN elsewhere) it is, to the bit, what cpf-ekf was handed, chunk by chunk."""
    from mavattitude import aiding as aid
    from mavattitude.core.runner import Runner

    flight = read_log(str(sim_logs["figure8.bin"][1]))
    runner = Runner(["cpf-ekf"], imu_source="IMU[0]")
    runner.add_flight(flight)
    handed = []
    update = runner.estimators[0].update

    def keeping(*args, aiding=None, **kwargs):
        handed.append(aiding)
        return update(*args, aiding=aiding, **kwargs)
    runner.estimators[0].update = keeping
    runner.step(final=True, chunk=False)
    runner.release_inputs()
    full, given, rows = runner.aiding(), runner.aiding(given_only=True), runner.aiding_rows
    assert len(full) == runner.done == len(runner.estimate("cpf-ekf").t)
    assert 0 < len(rows) < len(full) / 5  # baro at 10 Hz, the IMU at 100
    for f in aid.Aiding.COLUMNS:
        seen = np.concatenate([getattr(a, f) for a in handed])
        np.testing.assert_array_equal(getattr(full, f), seen)  # NaN where NaN
        np.testing.assert_array_equal(getattr(given, f), seen[rows])
    assert full.origin == given.origin is not None


def test_a_flight_estimated_in_place_equals_its_rows_given_a_few_at_a_time(sim_logs):
    """``add_flight`` reads the flight's own IMU arrays (``imurows``) where ``add_imu`` keeps
    rows: the estimates and diagnostics are the same to the bit, whether the rows come at
    once or in packets of 100 with a step after each, as on a live link."""
    from mavattitude import aiding as aid
    from mavattitude.core.imurows import ImuRows
    from mavattitude.core.runner import Runner

    flight = read_log(str(sim_logs["figure8.bin"][1]))
    imu, mag = flight.imu["IMU[0]"], flight.mag["MAG[0]"]
    whole = Runner(["mahony", "eq-kf"], imu_source="IMU[0]", mag_source="MAG[0]")
    whole.add_flight(flight)
    rows = whole.store["imu"]
    assert isinstance(rows, ImuRows)
    stacked = np.column_stack([imu.t, imu.gyro, imu.accel, imu.arrival])
    for index in (np.s_[3:40], np.s_[-5:], np.s_[:, 0], np.s_[7:9, -1], np.s_[12, 0], np.s_[:, 3], 17):
        np.testing.assert_array_equal(rows.view()[index], stacked[index])
    np.testing.assert_array_equal(rows.last, stacked[-1])
    whole.step(final=True, chunk=False)

    live = Runner(["mahony", "eq-kf"], imu_source="IMU[0]", mag_source="MAG[0]")
    live.add_mag(mag.t, mag.field, mag.arrival)
    live.add_gps(aid.gps_rows(flight.gps, flight.gps.arrival))
    live.add_baro(aid.baro_rows(flight.baro, flight.baro.arrival))
    for a in range(0, len(imu.t), 100):
        live.add_imu(imu.t[a:a + 100], imu.gyro[a:a + 100], imu.accel[a:a + 100], imu.arrival[a:a + 100])
        live.step()
    live.step(final=True)
    assert live.done == whole.done == len(imu.t)
    for name in whole.names:
        np.testing.assert_array_equal(live.estimate(name).q, whole.estimate(name).q)
        a, b = live.diagnostic_series(name), whole.diagnostic_series(name)
        assert list(a) == list(b)
        for key in a:
            np.testing.assert_array_equal(a[key], b[key])
