"""Inputs that cannot carry an attitude (imucheck): an IMU too slow to follow the vehicle is
scored but marked not meaningful and left out of evaluate's rankings; an accelerometer that
reads g far off is a warning naming what it does to each estimator; yaw without a heading
reference is marked drift."""
from __future__ import annotations

import csv
import json
import re
from dataclasses import replace

import pytest

from conftest import SAMPLE_LOGS
from mavattitude import estimators as est
from mavattitude.scoring import imucheck
from mavattitude.cli import main
from mavattitude.flight import GRAVITY
from mavattitude.commands.info import summarize
from mavattitude.readers import read_log
from mavattitude.commands.report import NOT_MEANINGFUL, YAW_ALIGNED_NOTE, YAW_DRIFT
from mavattitude.sim import simulate, write_log


@pytest.fixture(scope="module")
def rate_logs(tmp_path_factory):
    """The same 30 s hover at 2 Hz and at 50 Hz, in a folder of their own."""
    folder = tmp_path_factory.mktemp("rates")
    return {rate: write_log(simulate("hover", 30.0, seed=4, imu_rate=rate), folder / f"hover-{rate:g}hz.bin")
            for rate in (2.0, 50.0)}


def scaled_log(folder, scale: float):
    """A 30 s flight that starts still, its accelerometers reading ``scale`` g."""
    sim = simulate("hover", 30.0, seed=5, imu_rate=50.0)
    sim = replace(sim, imu=[replace(imu, accel=imu.accel * scale) for imu in sim.imu])
    return write_log(sim, folder / f"scaled-{scale:g}.bin")


def test_the_rate_threshold():
    assert imucheck.rate_not_meaningful(9.4) is not None
    assert imucheck.rate_not_meaningful(imucheck.MEANINGFUL_RATE_HZ) is None
    assert imucheck.rate_not_meaningful(9.6) is None  # a nominal 10 Hz stream with clock jitter
    assert "not meaningful" in imucheck.rate_warning(4.0)
    assert "coarse" in imucheck.rate_warning(10.0)
    assert imucheck.rate_warning(imucheck.COARSE_RATE_HZ) is None


def test_a_slow_imu_is_scored_but_marked_not_meaningful(rate_logs, tmp_path, capsys):
    out = tmp_path / "slow.json"
    assert main(["replay", str(rate_logs[2.0]), "--estimators", "mahony", "--no-view", "--json", str(out)]) == 0
    text = capsys.readouterr()
    assert "low IMU rate: 2.0 Hz, below 9.5 Hz: gyro integration cannot follow the vehicle" in text.err
    table = text.out.splitlines()
    marked = next(i for i, line in enumerate(table) if line.startswith(NOT_MEANINGFUL))
    assert table[marked + 1].split()[:2] == ["estimator", "axis"]  # above the table
    roll = next(line for line in table if line.startswith("mahony"))
    assert len(roll.split()[3].split(".")[1]) == 1  # MAE with one decimal
    metrics = json.loads(out.read_text())
    assert metrics["estimators"]["mahony"]["meaningful"] is False
    assert "2.0 Hz" in metrics["estimators"]["mahony"]["why"]
    assert metrics["estimators"]["mahony"]["roll"]["mae"] > 0  # shown all the same
    assert metrics["scoring"]["meaningful"] is False and metrics["scoring"]["imu_rate_hz"] == 2.0

    assert main(["replay", str(rate_logs[50.0]), "--estimators", "mahony", "--no-view", "--json", str(out)]) == 0
    text = capsys.readouterr()
    assert NOT_MEANINGFUL not in text.out and "low IMU rate" not in text.err
    metrics = json.loads(out.read_text())
    assert metrics["estimators"]["mahony"]["meaningful"] is True and metrics["estimators"]["mahony"]["why"] is None


def test_the_view_summary_says_so_too(rate_logs):
    from mavattitude import replay, view

    slow, fast = (view.summary_markdown(replay(rate_logs[rate], ["mahony", "eskf"])) for rate in (2.0, 50.0))
    assert "**Not meaningful**: IMU at 2.0 Hz, below 9.5 Hz" in slow and "Not meaningful" not in fast
    assert "| eskf \\* |" in fast and "\\* yaw drift (no heading reference)" in fast


def test_evaluate_leaves_a_slow_imu_out_of_its_rankings(rate_logs, tmp_path, capsys):
    out = tmp_path / "eval"
    assert main(["evaluate", str(rate_logs[2.0].parent), "--estimators", "mahony", "--out", str(out), "-j", "1"]) == 0
    assert "1 not meaningful" in capsys.readouterr().out
    summary = json.loads((out / "summary.json").read_text())
    assert summary["scored"] == 1 and summary["estimators"]["mahony"]["logs"] == 1
    assert [n["log"].endswith("hover-2hz.bin") for n in summary["not_meaningful"]] == [True]
    assert "below 9.5 Hz" in summary["not_meaningful"][0]["why"]
    assert all(not w["log"].endswith("hover-2hz.bin") for w in summary["estimators"]["mahony"]["worst_logs"])
    report = (out / "report.md").read_text()
    assert "## Not meaningful (left out of the ranking)" in report and "hover-2hz.bin" in report
    rows = list(csv.DictReader((out / "results.csv").open()))
    marks = {r["log"].rsplit("/", 1)[-1]: r["not_meaningful"] for r in rows}
    assert "below 9.5 Hz" in marks["hover-2hz.bin"] and marks["hover-50hz.bin"] == ""
    assert all(r["mae"] for r in rows if r["log"].endswith("hover-2hz.bin"))  # its scores kept in the table


def test_accel_at_rest_reads_the_scale():
    sim = simulate("static", 20.0, seed=2, imu_rate=50.0)
    imu = sim.imu[0]
    norm, at_rest = imucheck.accel_at_rest(imu.t, imu.gyro, imu.accel * 0.82)
    assert at_rest and norm == pytest.approx(0.82 * GRAVITY, rel=0.005)
    turning = imu.gyro + [0.0, 0.0, 0.3]  # 17 °/s all along: no span at rest, the whole series' median
    norm, at_rest = imucheck.accel_at_rest(imu.t, turning, imu.accel * 1.1)
    assert not at_rest and norm == pytest.approx(1.1 * GRAVITY, rel=0.005)
    assert imucheck.accel_at_rest(imu.t[:0], imu.gyro[:0], imu.accel[:0]) == (None, False)


def test_an_accelerometer_far_from_g_is_a_warning_that_names_the_estimators(tmp_path, capsys):
    bad, good = scaled_log(tmp_path, 0.82), scaled_log(tmp_path, 1.0)
    info = summarize(read_log(str(bad)))
    warning = next(w for w in info["warnings"] if w.startswith("accelerometer reads"))
    assert re.search(r"reads 8\.0\d m/s² at rest, -18\.\d % from g", warning)  # 0.82 g, and the sim's bias
    still_start = "none when the log starts still (g is then the accelerometer's reading there); without a still start "
    for effect in (f"mahony-ekf: {still_start}its accelerometer noise",
                   f"ncs-eskf: {still_start}the scale error reads as a horizontal manoeuvre",
                   f"eq-kf: {still_start}its trust in the accelerometer falls",
                   "mahony, ekf, eskf, cpf-ekf: little or no effect"):
        assert effect in warning, effect
    assert "the start is not recognised as still" not in warning  # within 25 % of g: it is
    assert info["imu_sources"][info["best_imu"]]["accel_g_reading"]["scale_error"] == pytest.approx(-0.18, abs=0.005)
    assert not any(w.startswith("accelerometer reads") for w in summarize(read_log(str(good)))["warnings"])

    out = tmp_path / "m.json"
    assert main(["replay", str(bad), "--estimators", "mahony,ncs-eskf", "--no-view", "--json", str(out)]) == 0
    err = capsys.readouterr().err
    line = next(x for x in err.splitlines() if "accelerometer reads" in x)
    assert "ncs-eskf:" in line and "mahony: little or no effect" in line and "eq-kf" not in line  # those run only
    reading = json.loads(out.read_text())["scoring"]["accel_g_reading"]
    assert reading["at_rest"] and reading["ms2"] == pytest.approx(0.82 * GRAVITY, rel=0.01)
    assert main(["replay", str(good), "--estimators", "mahony", "--no-view"]) == 0
    assert "accelerometer reads" not in capsys.readouterr().err


def test_each_estimator_says_what_a_scale_error_does():
    effects = {name: est.create(name).accel_scale_effect(-0.18) for name in est.ESTIMATORS}
    assert {n for n, e in effects.items() if e} == {"mahony-ekf", "ncs-eskf", "eq-kf"}
    assert "never used" in est.create("ncs-eskf").accel_scale_effect(-0.25)  # beyond its 0.2 g total gate
    # strict keeps standard gravity: no still start to say "none" for; beyond 25 % no start is still
    assert est.create("ncs-eskf", strict=True).accel_scale_effect(-0.18).startswith("the scale error reads")
    assert est.create("eq-kf").accel_scale_effect(-0.18).startswith("none when the log starts still")
    assert est.create("eq-kf").accel_scale_effect(-0.3).startswith("its trust in the accelerometer falls")
    assert "the start is not recognised as still" in imucheck.accel_scale_warning(0.7 * GRAVITY, True, [])
    assert all(est.create(n).accel_scale_effect(0.004) is None for n in est.ESTIMATORS if n != "mahony-ekf")


def test_yaw_without_a_heading_reference_is_marked_drift(capsys):
    assert main(["replay", str(SAMPLE_LOGS / "figure8.tlog"), "--estimators", "mahony,eskf", "--no-view"]) == 0
    lines = capsys.readouterr().out.splitlines()
    yaw = [line for line in lines if line.split()[:1] in (["yaw"], ["yaw*"])]
    assert yaw[0].split()[0] == "yaw" and not yaw[0].endswith(YAW_DRIFT)  # mahony: compass heading
    assert yaw[1].split()[0] == "yaw*" and yaw[1].endswith(YAW_DRIFT)  # eskf: the gyro's alone
    assert YAW_ALIGNED_NOTE in lines[lines.index(yaw[1]) + 1:]  # right under the table


def test_live_marks_a_slow_imu_too(tmp_path):
    """A session's final scores, as replay's: marked when the IMU arrived too slowly."""
    from pymavlink import mavutil

    from mavattitude.live.estimation import LiveEstimation

    for rate, marked in ((4.0, True), (12.0, False)):  # either side of 9.5 Hz
        path = write_log(simulate("hover", 20.0, seed=6, imu_rate=rate), tmp_path / f"hover-{rate:g}.tlog")
        session = LiveEstimation(["mahony"])
        log = mavutil.mavlink_connection(str(path))
        while (msg := log.recv_msg()) is not None:
            if msg.get_type() != "BAD_DATA":
                session.add(msg)
        session.step(final=True)
        comparisons, _ = session.final_comparisons()
        assert (comparisons["mahony"].not_meaningful is not None) == marked, rate
        assert comparisons["mahony"].axes["roll"] is not None  # scored all the same
