"""report: terminal table, JSON summary, CSV export."""
from __future__ import annotations

import json

import numpy as np
import pytest

import mavattitude
from mavattitude.flight import AttitudeSeries
from mavattitude.scoring.metrics import AXES, AxisMetrics, Comparison, compare
from mavattitude.quaternion import from_euler, to_euler
from mavattitude.commands.report import (BUCKET_KEYS, CSV_HEADER, NOT_MEANINGFUL, YAW_ALIGNED_NOTE, YAW_DRIFT,
                                _fixed_point_csv, format_table, to_json_dict, write_csv, write_json)

ATT_REF = {"stream": "ATT", "algorithm": "DCM", "choice": "autopilot"}


def series(t, roll_deg, pitch_deg, yaw_deg, source="test") -> AttitudeSeries:
    t = np.asarray(t, dtype=float)
    r, p, y = (np.broadcast_to(np.radians(np.asarray(a, dtype=float)), t.shape)
               for a in (roll_deg, pitch_deg, yaw_deg))
    return AttitudeSeries(source=source, t=t, q=from_euler(r, p, y))


def metrics(mae, n=100, r2=0.9) -> AxisMetrics:
    return AxisMetrics(n=n, mae=mae, rmse=mae * 1.25, mse=(mae * 1.25) ** 2, r2=r2, max=mae * 4,
                       sigma1=mae * 1.1, sigma3=mae * 3, buckets=(0.4, 0.3, 0.2, 0.1))


def comparison(name, axes, aligned=False) -> Comparison:
    return Comparison(estimator=name, reference="ATT", t=np.zeros(0), error_deg=np.zeros((0, 3)),
                      scored=np.zeros(0, bool), axes=axes, yaw_aligned=aligned)


@pytest.fixture
def comparisons():
    return {
        "mahony": comparison("mahony", {"roll": metrics(1.234), "pitch": metrics(0.5),
                                        "yaw": metrics(3.75)}),
        "ncs-eskf": comparison("ncs-eskf", {"roll": metrics(0.809, n=123456),
                                            "pitch": metrics(0.934, r2=float("nan")),
                                            "yaw": None}, aligned=True),
    }


# ---------------------------------------------------------------- table


def test_table_contains_the_numbers(comparisons):
    text = format_table(comparisons, "ATT")
    assert "ATT" in text
    assert "mahony" in text and "ncs-eskf" in text
    # mahony roll: MAE 1.234, RMSE 1.5425 (-> 1.542 or 1.543), max 4.936
    for value in ("1.234", f"{1.234 * 1.25:.3f}", "4.936", "0.9000", "0.809", "123456", "3.750"):
        assert value in text, value
    lines = text.splitlines()
    mahony_roll = next(line for line in lines if line.startswith("mahony"))
    assert mahony_roll.split() == ["mahony", "roll", "100", "1.234", f"{1.234 * 1.25:.3f}",
                                   "4.936", "0.9000"]
    pitch_line = next(line for line in lines if "0.934" in line)
    assert pitch_line.split()[-1] == "n/a"  # undefined R²


def test_table_marks_aligned_yaw_and_missing_axes(comparisons):
    text = format_table(comparisons, "SIM")
    lines = text.splitlines()
    yaw_lines = [line for line in lines if line.split()[:1] in (["yaw"], ["yaw*"])]
    assert [line.split()[0] for line in yaw_lines] == ["yaw", "yaw*"]
    assert yaw_lines[1].split()[1:6] == ["0", "n/a", "n/a", "n/a", "n/a"]
    assert lines[-1] == YAW_ALIGNED_NOTE
    assert yaw_lines[1].endswith(YAW_DRIFT)  # on the row itself, not only in the footnote
    # fixed width: every data row as wide as the header or narrower, columns right-aligned
    header = lines[1]
    assert all(len(line.removesuffix(f"  {YAW_DRIFT}")) == len(header) for line in lines[3:-1])


def test_table_marks_scores_that_are_not_meaningful(comparisons):
    why = "IMU at 1.0 Hz, below 9.5 Hz: gyro integration cannot follow the vehicle"
    comparisons["ncs-eskf"].not_meaningful = why
    lines = format_table(comparisons, "ATT").splitlines()
    assert lines[1] == f"{NOT_MEANINGFUL}: {why}. The scores below are shown, not to be relied on or ranked."
    assert lines[2].split()[:2] == ["estimator", "axis"]  # above the table, before its header
    ncs_roll = next(line for line in lines if line.startswith("ncs-eskf"))
    assert ncs_roll.split()[3:6] == ["0.8", "1.0", "3.2"]  # one decimal, not three
    assert "1.234" in "\n".join(lines)  # a meaningful row keeps its three
    d = to_json_dict("flight.bin", ATT_REF, comparisons)["estimators"]
    assert (d["ncs-eskf"]["meaningful"], d["ncs-eskf"]["why"]) == (False, why)
    assert (d["mahony"]["meaningful"], d["mahony"]["why"]) == (True, None)


def test_table_without_alignment_has_no_footnote(comparisons):
    del comparisons["ncs-eskf"]
    text = format_table(comparisons, "ATT")
    assert "yaw*" not in text and YAW_ALIGNED_NOTE not in text
    assert "(no estimates)" in format_table({}, "ATT")


# ---------------------------------------------------------------- JSON


def test_json_schema(comparisons):
    d = to_json_dict("flight.bin", ATT_REF, comparisons)
    assert set(d) == {"log", "reference", "estimators"}
    assert d["log"] == "flight.bin" and d["reference"] == ATT_REF
    assert list(d["estimators"]) == ["mahony", "ncs-eskf"]
    base = {"n", "mae", "rmse", "mse", "r2", "max", "sigma1", "sigma3", "buckets"}
    for name, axes in d["estimators"].items():
        assert list(axes) == [*AXES, "meaningful", "why", "unscored_in_gaps", "unscored_suspect_reference"]
        assert axes["unscored_in_gaps"] == 0
        assert axes["meaningful"] is True and axes["why"] is None
        for axis in AXES:
            m = axes[axis]
            if m is None:
                continue
            assert set(m) == (base | {"aligned"} if axis == "yaw" else base)
            assert list(m["buckets"]) == list(BUCKET_KEYS)
            assert isinstance(m["n"], int)
    mahony = d["estimators"]["mahony"]
    assert mahony["roll"]["mae"] == pytest.approx(1.234)
    assert mahony["roll"]["buckets"] == {"lt_0.5": 0.4, "0.5_1": 0.3, "1_2": 0.2, "gt_2": 0.1}
    assert mahony["yaw"]["aligned"] is False
    assert d["estimators"]["ncs-eskf"]["yaw"] is None
    assert d["estimators"]["ncs-eskf"]["pitch"]["r2"] is None  # NaN -> null


def test_json_is_valid_and_written(tmp_path, comparisons):
    path = write_json(tmp_path / "out" / "summary.json", "flight.bin", ATT_REF, comparisons)
    text = path.read_text(encoding="utf-8")
    assert "NaN" not in text
    loaded = json.loads(text)
    assert loaded.pop("written_by") == f"mavattitude {mavattitude.__version__}"  # first: outputs.is_kind knows ours
    assert loaded == to_json_dict("flight.bin", ATT_REF, comparisons)


def test_json_from_a_real_comparison(tmp_path):
    t = np.arange(0.0, 30.0, 0.1)
    ref = series(t, 10 * np.sin(t), 5 * np.cos(t), 20 * np.sin(0.1 * t), "ATT")
    est = series(t, 10 * np.sin(t) + 1.5, 5 * np.cos(t), 20 * np.sin(0.1 * t) + 40, "ncs-eskf")
    c = compare(ref, est, warmup_s=5.0, align_yaw=True)
    d = json.loads(json.dumps(to_json_dict("x.tlog", ATT_REF, {"ncs-eskf": c}), allow_nan=False))
    m = d["estimators"]["ncs-eskf"]
    assert m["roll"]["mae"] == pytest.approx(1.5)
    assert m["roll"]["buckets"]["1_2"] == pytest.approx(1.0)
    assert m["yaw"]["aligned"] is True and m["yaw"]["mae"] < 1e-9
    assert m["roll"]["n"] == np.count_nonzero(t >= 5.0)


# ---------------------------------------------------------------- CSV


def test_csv_round_trip(tmp_path):
    t = np.arange(1000.0, 1010.0, 0.0025)
    ref = series(t, 30 * np.sin(t), 20 * np.cos(t), 179.0 * np.sin(0.3 * t), "ATT")
    est = series(t, 30 * np.sin(t) + 1, 20 * np.cos(t), 200.0 * np.sin(0.3 * t), "mahony")
    out = tmp_path / "deep" / "csv"  # created
    paths = write_csv(out, ref, {"mahony": est})
    assert paths == {"reference": out / "reference.csv", "mahony": out / "mahony.csv"}
    for path, s in ((out / "reference.csv", ref), (out / "mahony.csv", est)):
        with open(path) as f:
            assert f.readline().strip() == CSV_HEADER
        data = np.loadtxt(path, delimiter=",", skiprows=1)
        assert data.shape == (len(t), 4)
        np.testing.assert_allclose(data[:, 0], s.t, atol=5e-7)
        expected = np.degrees(to_euler(s.q))
        diff = (data[:, 1:] - expected + 180.0) % 360.0 - 180.0
        assert np.abs(diff).max() <= 5.1e-7
        assert data[:, 3].min() >= -180.0 and data[:, 3].max() < 180.0


def test_csv_text_details(tmp_path):
    s = AttitudeSeries("ATT", np.array([12.5, 13.0, 13.25]),
                       from_euler(np.radians([-0.25, 0.0, 10.0]), np.radians([1.5, 0.0, 0.0]),
                                  np.radians([179.99999999, 0.0, -90.0])))
    s.q[1] = np.nan
    write_csv(tmp_path, s, {"my est/v2": s})
    lines = (tmp_path / "reference.csv").read_text().splitlines()
    assert lines == [CSV_HEADER,
                     "12.500000,-0.250000,1.500000,-180.000000",  # 179.99999999 rounds to -180
                     "13.000000,nan,nan,nan",
                     "13.250000,10.000000,0.000000,-90.000000"]
    assert (tmp_path / "my_est_v2.csv").read_text().splitlines() == lines
    with pytest.raises(ValueError):
        write_csv(tmp_path, s, {"reference": s})


def test_fixed_point_matches_printf():
    rng = np.random.default_rng(1)
    values = np.column_stack([rng.uniform(0, 5000, 2000), rng.uniform(-180, 180, (2000, 3))])
    values[0] = [0.0, 1.0, -1.0, 99.9999996]
    values[1] = [1e-7, -12345.0, 0.5, -0.5]
    text = _fixed_point_csv(values, 6).decode()
    expected = "".join("%.6f,%.6f,%.6f,%.6f\n" % tuple(r) for r in values.tolist())
    assert text == expected
    assert _fixed_point_csv(np.zeros((0, 4)), 6) == b""
