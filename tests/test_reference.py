"""Which reference the scores are against (issue 24, parts 2-4): its name in the table, the JSON,
evaluate's records and the view; the autopilot's other streams scored as rows against it, and
the reference's own spread; --reference choosing any stream, "ekf", "truth"."""
from __future__ import annotations

import csv
import json

import numpy as np
import pytest

from conftest import SAMPLE_LOGS, shared_log
from mavattitude import quaternion as quat
from mavattitude.cli import main
from mavattitude.flight import AttitudeSeries, Flight
from mavattitude.commands.replay import NoReference, choose_reference, run_replay
from mavattitude.readers import read_log
from mavattitude.sim import SensorParams, simulate, write_log
from mavattitude.view import _series, summary_markdown

BIAS_DEG = np.array([2.0, -1.0, 3.0])  # DCM - truth, roll, pitch, yaw
NOISE_DEG = 0.3  # DCM's white noise (RMS) on top, the simulator's default
ESTIMATORS = ["mahony", "eskf"]
EKF_ROW = "autopilot:EKF1 (EKF1)"


@pytest.fixture(scope="module")
def dcm_log(tmp_path_factory):
    """A .bin whose ATT is DCM (truth + BIAS_DEG + noise), with the EKF beside it as EKF1 and AHR2."""
    sim = simulate("figure8", 40.0, seed=3, imu_rate=50.0, params=SensorParams(dcm_bias=tuple(np.radians(BIAS_DEG))))
    return write_log(sim, tmp_path_factory.mktemp("dcm") / "dcm.bin")


@pytest.fixture(scope="module")
def dcm_flight(dcm_log):
    return read_log(dcm_log)


def mean_error(comparison) -> np.ndarray:
    return comparison.error_deg[comparison.scored].mean(axis=0)


def run(capsys, *args) -> tuple[int, str, str]:
    code = main([str(a) for a in args])
    out, err = capsys.readouterr()
    return code, out, err


def test_against_dcm_the_ekf_row_is_the_known_bias(dcm_flight):
    result = run_replay(dcm_flight, ESTIMATORS)
    assert result.reference_info.as_dict() == {"stream": "ATT", "algorithm": "DCM", "choice": "autopilot"}
    # AHR2 repeats EKF1 to the bit: one row for the EKF, named by its own message
    assert list(result.stream_comparisons) == [EKF_ROW]
    ekf = result.stream_comparisons[EKF_ROW]
    assert mean_error(ekf)[:2] == pytest.approx(-BIAS_DEG[:2], abs=0.15)  # EKF - DCM: minus the bias
    assert ekf.axes["roll"].mae == pytest.approx(abs(BIAS_DEG[0]), abs=0.2)
    spread = result.metrics["reference_spread_deg"]
    assert spread["roll"] == pytest.approx(ekf.axes["roll"].mae)
    assert spread["pitch"] == pytest.approx(ekf.axes["pitch"].mae)
    assert spread["tilt"] == pytest.approx(0.5 * (ekf.axes["roll"].mae + ekf.axes["pitch"].mae))


def test_table_and_json_name_the_reference_and_say_the_spread(dcm_log, tmp_path, capsys):
    code, out, err = run(capsys, "replay", dcm_log, "--estimators", ",".join(ESTIMATORS), "--no-view", "-q",
                         "--json", tmp_path / "m.json")
    assert code == 0, err
    assert "Attitude error against ATT (DCM, ArduPilot's complementary filter; ATT.AEKF)" in out
    assert EKF_ROW in out
    spread_said = [line for line in out.splitlines() if line.startswith("roll: the estimators' MAEs span")]
    assert len(spread_said) == 1
    assert "the autopilot's own spread" in spread_said[0] and "(DCM vs EKF1)" in spread_said[0]
    data = json.loads((tmp_path / "m.json").read_text())
    assert data["reference"] == {"stream": "ATT", "algorithm": "DCM", "choice": "autopilot"}
    assert list(data["autopilot_streams"]) == [EKF_ROW] and EKF_ROW not in data["estimators"]
    assert data["autopilot_streams"][EKF_ROW]["roll"]["mae"] == pytest.approx(abs(BIAS_DEG[0]), abs=0.2)
    assert set(data["reference_spread_deg"]) == {"roll", "pitch", "tilt"}


def test_reference_ekf1_scores_against_the_ekf(dcm_flight):
    result = run_replay(dcm_flight, ESTIMATORS, reference="ekf1")  # any case
    assert result.reference_info.as_dict() == {"stream": "EKF1", "algorithm": "EKF1", "choice": "ekf1"}
    assert result.reference is dcm_flight.attitudes["EKF1"] and result.trim is None
    assert list(result.stream_comparisons) == ["autopilot:DCM (ATT)"]  # AHR2: a copy of the reference
    assert mean_error(result.stream_comparisons["autopilot:DCM (ATT)"])[:2] == pytest.approx(BIAS_DEG[:2], abs=0.15)
    against_dcm = run_replay(dcm_flight, ESTIMATORS)
    for name in ESTIMATORS:  # each estimator's error moves by DCM's bias between the two references
        moved = mean_error(against_dcm.comparisons[name]) - mean_error(result.comparisons[name])
        assert moved[:2] == pytest.approx(-BIAS_DEG[:2], abs=0.15)


def test_reference_truth_gives_a_row_per_stream(dcm_flight):
    result = run_replay(dcm_flight, ["mahony"], reference="truth")
    assert result.reference_info.algorithm == "truth"
    assert list(result.comparisons) == ["mahony", "autopilot"]  # the primary (DCM) keeps its row name
    assert mean_error(result.comparisons["autopilot"])[:2] == pytest.approx(BIAS_DEG[:2], abs=0.15)
    assert list(result.stream_comparisons) == [EKF_ROW]
    assert result.stream_comparisons[EKF_ROW].axes["roll"].mae < 0.5  # the EKF is close to the truth
    assert result.metrics["reference_spread_deg"] is None  # a spread of the autopilot, not of the truth


def test_the_view_draws_the_streams_and_names_the_reference(dcm_flight, tmp_path):
    result = run_replay(dcm_flight, ["mahony"], reference="EKF1")
    keys = [key for key, _, _ in _series(result)]
    assert keys == ["reference", "truth", "autopilot:DCM (ATT)", "mahony"]  # ATT drawn once, as its row
    assert "**reference**: EKF1 (EKF1)" in summary_markdown(result)
    assert "| autopilot:DCM (ATT) |" in summary_markdown(result)
    result.write_rrd(tmp_path / "r.rrd")  # the streams' lines and errors drawn
    assert (tmp_path / "r.rrd").stat().st_size > 0


def test_unknown_stream_is_one_line_listing_the_log_s(dcm_log, capsys):
    code, _, err = run(capsys, "replay", dcm_log, "--reference", "XKF1[3]", "--no-view", "-q")
    assert code == 1 and len(err.strip().splitlines()) == 1
    assert str(dcm_log) in err and "'XKF1[3]'" in err and "ATT (DCM), AHR2 (EKF1), EKF1 (EKF1)" in err


def test_reference_ekf_without_an_ekf():
    t = np.arange(0.0, 10.0, 0.1)
    att = AttitudeSeries("ATT", t, quat.from_euler(0.1 * np.sin(t), 0.0 * t, 0.0 * t))
    flight = Flight("old.bin", "bin", attitude=att, attitudes={"ATT": att}, params={"AHRS_EKF_USE": 0.0})
    with pytest.raises(NoReference, match="old.bin: --reference ekf, but the log has no EKF attitude .ATT .DCM.."):
        choose_reference(flight, "ekf")
    assert choose_reference(flight, "autopilot").algorithm == "DCM"


def two_logs(dcm_log, tmp_path):
    """A folder with the DCM log (EKF1 beside ATT) and a sample log whose only attitude is EKF3."""
    logs = tmp_path / "logs"
    logs.mkdir()
    (logs / "dcm.bin").symlink_to(dcm_log)
    (logs / "figure8.bin").symlink_to(SAMPLE_LOGS / "figure8.bin")
    return logs


def evaluated(out) -> dict:
    """evaluate's records, by log file name."""
    return {r["log"].split("/")[-1]: r for r in (json.loads(p.read_text()) for p in (out / "logs").glob("*.json"))}


def test_evaluate_reference_ekf_picks_per_log_and_says_so(dcm_log, tmp_path, capsys):
    logs, out = two_logs(dcm_log, tmp_path), tmp_path / "eval"
    assert main(["evaluate", str(logs), "--estimators", "mahony", "--reference", "ekf", "--out", str(out),
                 "-j", "1", "-q"]) == 0
    printed = capsys.readouterr().out
    records = evaluated(out)
    dcm, ekf3 = records["dcm.bin"], records["figure8.bin"]
    assert (dcm["reference_stream"], dcm["reference_algorithm"]) == ("EKF1", "EKF1")  # not ATT: that is DCM
    assert dcm["reference"] == {"stream": "EKF1", "algorithm": "EKF1", "choice": "ekf"}
    assert dcm["reference_spread_deg"] == pytest.approx(0.5 * sum(abs(BIAS_DEG[:2])), abs=0.2)
    assert (ekf3["reference_stream"], ekf3["reference_algorithm"]) == ("ATT", "EKF3")
    assert ekf3["reference_spread_deg"] is None  # no other stream
    assert "reference per log: EKF1 (EKF1) 1 log, EKF3 (ATT) 1 log" in printed
    report = (out / "report.md").read_text()
    assert "## Reference per log" in report and "| `dcm.bin` | EKF1 | EKF1 |" in report
    rows = list(csv.DictReader((out / "results.csv").open()))
    assert {(r["log"].split("/")[-1], r["reference_stream"], r["reference_algorithm"]) for r in rows} == \
        {("dcm.bin", "EKF1", "EKF1"), ("figure8.bin", "ATT", "EKF3")}


def test_evaluate_skips_a_log_without_the_stream(dcm_log, tmp_path, capsys):
    logs, out = two_logs(dcm_log, tmp_path), tmp_path / "eval"
    assert main(["evaluate", str(logs), "--estimators", "mahony", "--reference", "AHR2", "--out", str(out),
                 "-j", "1", "-q"]) == 0
    records = evaluated(out)
    assert records["dcm.bin"]["status"] == "ok" and records["dcm.bin"]["reference_algorithm"] == "EKF1"
    assert records["figure8.bin"]["status"] == "skipped"
    assert "has no attitude stream 'AHR2'" in records["figure8.bin"]["error"]


def test_shared_dcm_log_names_its_reference_and_scores_ekf1(tmp_path, capsys):
    """Issue 24's "done when", with one estimator (all seven: the same rows, 30 s)."""
    path = shared_log("copter-3.3-loiter-rtl.bin")
    code, out, err = run(capsys, "replay", path, "--no-view", "-q", "--json", tmp_path / "m.json")
    assert code == 0, err
    data = json.loads((tmp_path / "m.json").read_text())
    assert data["reference"] == {"stream": "ATT", "algorithm": "DCM", "choice": "autopilot"}
    ekf1 = data["autopilot_streams"]["autopilot:EKF1 (EKF1)"]
    assert 0.5 < ekf1["roll"]["mae"] < 3.0 and data["reference_spread_deg"]["roll"] == ekf1["roll"]["mae"]
    assert "against ATT (DCM, ArduPilot's complementary filter; AHRS_EKF_USE=0)" in out
    code, out, err = run(capsys, "replay", path, "--no-view", "-q", "--reference", "EKF1",
                         "--json", tmp_path / "e.json")
    assert code == 0, err
    data = json.loads((tmp_path / "e.json").read_text())
    assert data["reference"] == {"stream": "EKF1", "algorithm": "EKF1", "choice": "EKF1"}
    assert "autopilot:DCM (ATT)" in data["autopilot_streams"]
