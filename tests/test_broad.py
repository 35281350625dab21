"""BROAD's HDF5 trials as a source (readers.broad) and BROAD's error measures (broadscore).

The synthetic trials are written here with h5py; the shared ones (../shared/broad: 8 trials of
Laidig et al. 2021, doi:10.3390/data6070072, CC BY 4.0) are skipped where absent."""
from __future__ import annotations

import json
import math
import sys

import numpy as np
import pytest

from conftest import ROOT
from mavattitude.scoring.broadscore import broad_measures, broad_text, error_angles
from mavattitude.errors import InputError
from mavattitude.flight import GRAVITY, AttitudeSeries
from mavattitude.scoring.metrics import compare
from mavattitude.quaternion import conjugate, from_euler, multiply, rotate, to_euler
from mavattitude.readers import read_log, sniff_format
from mavattitude.readers.broad import NEEDS_H5PY

h5py = pytest.importorskip("h5py", reason="h5py (mavattitude[broad]) is not installed")

SHARED_BROAD = ROOT.parent / "shared" / "broad"
RATE = 100.0


def axis_quat(axis, angle_rad: float) -> np.ndarray:
    axis = np.asarray(axis, float) / np.linalg.norm(axis)
    return np.concatenate([[math.cos(angle_rad / 2)], math.sin(angle_rad / 2) * axis])


def write_trial(path, q_enu_imu, n: int = 2000, movement=None, nan_rows=(), extra: dict | None = None):
    """A still IMU at the attitude ``q_enu_imu`` (IMU frame -> ENU): its accelerometer reads +g up
    in its own frame, its gyro a small known rate, its magnetometer a known field (µT)."""
    up_in_imu = rotate(conjugate(q_enu_imu), np.array([0.0, 0.0, GRAVITY]))
    quats = np.tile(q_enu_imu, (n, 1))
    quats[list(nan_rows)] = np.nan
    with h5py.File(path, "w") as f:
        f["imu_acc"] = np.tile(up_in_imu, (n, 1))
        f["imu_gyr"] = np.tile([0.01, 0.02, 0.03], (n, 1))
        f["imu_mag"] = np.tile([20.0, 5.0, -40.0], (n, 1))
        f["opt_quat"] = quats
        f["opt_pos"] = np.zeros((n, 3))
        f["movement"] = np.ones(n, bool) if movement is None else movement
        for name, value in (extra or {}).items():
            f[name] = value
        f.attrs["sampling_rate"] = RATE
    return str(path)


# ---------------------------------------------------------------- the reader


def test_reader_turns_the_imu_frame_to_frd(tmp_path):
    q = axis_quat([0.3, -0.5, 0.8], 0.7)
    flight = read_log(write_trial(tmp_path / "01_trial.hdf5", q))
    imu = flight.imu["imu"]
    assert flight.format == "broad" and sniff_format(flight.path) == "broad"
    with h5py.File(flight.path) as f:  # body = the IMU frame turned 180° about x: (x, -y, -z)
        np.testing.assert_array_equal(imu.accel, f["imu_acc"][:] * [1, -1, -1])
        np.testing.assert_array_equal(imu.gyro, f["imu_gyr"][:] * [1, -1, -1])
        np.testing.assert_allclose(flight.mag["imu"].field, f["imu_mag"][:] * [1e-6, -1e-6, -1e-6], rtol=1e-15)
    np.testing.assert_allclose(imu.t, np.arange(2000) / RATE)
    assert imu.rate_over_step  # integrated sample by sample, as the dataset's own filters do
    # the truth (body -> NED) puts gravity where the accelerometer reads it: specific force (0, 0, -g) in NED
    np.testing.assert_allclose(rotate(conjugate(flight.truth.q), np.array([0, 0, -GRAVITY])), imu.accel, atol=1e-12)


def test_reader_truth_of_an_imu_aligned_with_enu(tmp_path):
    # IMU x east, y north, z up: the body's x (forward) east, y (right) south, z down: yaw 90°, level
    flight = read_log(write_trial(tmp_path / "t.hdf5", np.array([1.0, 0, 0, 0])))
    np.testing.assert_allclose(np.degrees(to_euler(flight.truth.q[0])), [0, 0, 90], atol=1e-12)
    np.testing.assert_allclose(flight.imu["imu"].accel[0], [0, 0, -GRAVITY], atol=1e-12)


def test_reader_skips_nan_truth_and_keeps_the_movement_spans(tmp_path):
    movement = np.zeros(2000, bool)
    movement[500:1200] = True
    movement[1500:1800] = True
    flight = read_log(write_trial(tmp_path / "t.h5", np.array([1.0, 0, 0, 0]), movement=movement,
                                  nan_rows=range(600, 650)))
    assert len(flight.truth.t) == 1950 and np.isfinite(flight.truth.q).all()
    assert not np.isin(np.arange(600, 650) / RATE, flight.truth.t).any()
    assert flight.unscored_spans == [(0.0, 4.99), (12.0, 14.99), (18.0, 19.99)]
    assert any("50 truth samples" in note for note in flight.notes)
    from mavattitude.declination import for_flight
    assert for_flight(flight).known and for_flight(flight).rad == 0.0  # its north is magnetic: no warning
    assert for_flight(flight, 5.0).source == "--declination"


def test_replay_scores_only_the_movement_samples(tmp_path):
    from mavattitude.commands.replay import run_replay

    movement = np.zeros(3000, bool)
    movement[1500:2500] = True
    flight = read_log(write_trial(tmp_path / "t.hdf5", axis_quat([1, 1, 0], 0.2), n=3000, movement=movement))
    result = run_replay(flight, ["mahony"], reference="truth", warmup_s=1.0)
    comp = result.comparisons["mahony"]
    scored_t = comp.t[comp.scored]
    assert len(scored_t) == 1000 and scored_t[0] == 15.0 and scored_t[-1] == 24.99
    assert comp.broad["inclination_rmse_deg"] < 0.5  # still, level-ish: the tilt from gravity


def test_identity_from_trials_json(tmp_path):
    (tmp_path / "trials.json").write_text(json.dumps(
        {"groups": [], "trials": {"07_fast": {"groups": ["all_trials", "undisturbed", "fast"]}}}))
    flight = read_log(write_trial(tmp_path / "07_fast.hdf5", np.array([1.0, 0, 0, 0])))
    assert flight.firmware == "BROAD trial 07 (undisturbed, fast)"
    assert read_log(write_trial(tmp_path / "08_other.hdf5", np.array([1.0, 0, 0, 0]))).firmware == "BROAD trial 08"


def test_hdf5_that_is_no_trial_and_missing_h5py(tmp_path, monkeypatch):
    other = tmp_path / "other.hdf5"
    with h5py.File(other, "w") as f:
        f["x"] = np.zeros(3)
    with pytest.raises(InputError, match="HDF5 file, but not a BROAD trial"):
        read_log(str(other))
    (tmp_path / "text.hdf5").write_text("hello")
    with pytest.raises(InputError, match="not a BROAD HDF5 file .* or an HDF5 signature"):
        read_log(str(tmp_path / "text.hdf5"))
    trial = write_trial(tmp_path / "t.hdf5", np.array([1.0, 0, 0, 0]))
    monkeypatch.setitem(sys.modules, "h5py", None)  # import h5py now raises ImportError
    with pytest.raises(InputError) as exc:
        read_log(trial)
    assert str(exc.value) == f"{trial}: {NEEDS_H5PY}"


def test_a_trial_with_a_bad_rate_or_shape(tmp_path):
    path = write_trial(tmp_path / "t.hdf5", np.array([1.0, 0, 0, 0]))
    with h5py.File(path, "r+") as f:
        f.attrs["sampling_rate"] = 0.0
    with pytest.raises(InputError, match="sampling_rate is 0.0"):
        read_log(path)
    path = write_trial(tmp_path / "u.hdf5", np.array([1.0, 0, 0, 0]))
    with h5py.File(path, "r+") as f:
        del f["movement"]
        f["movement"] = np.ones(5, bool)
    with pytest.raises(InputError, match="movement has shape"):
        read_log(path)


def test_evaluate_finds_hdf5_trials(tmp_path):
    from mavattitude.commands.evaluate import find_logs

    write_trial(tmp_path / "a.hdf5", np.array([1.0, 0, 0, 0]))
    write_trial(tmp_path / "b.H5", np.array([1.0, 0, 0, 0]))
    (tmp_path / "c.hdf5").write_bytes(b"not hdf5")
    assert [p.rsplit("/", 1)[-1] for p in find_logs([str(tmp_path)])] == ["a.hdf5", "b.H5"]


# ---------------------------------------------------------------- the measures


def series(q, n=200):
    return AttitudeSeries("x", np.arange(n) / RATE, np.tile(q, (n, 1)))


def measures(q_ref, q_est, heading=True):
    ref, est = series(q_ref), series(q_est)
    return broad_measures(ref, est, compare(ref, est, warmup_s=0.0), heading=heading)


def test_pure_heading_error():
    q_ref = from_euler(0.3, -0.2, 1.0)
    q_est = multiply(axis_quat([0, 0, 1], math.radians(5)), q_ref)  # 5° about the world's vertical
    m = measures(q_ref, q_est)
    assert m["heading_rmse_deg"] == pytest.approx(5, abs=1e-9)
    assert m["total_rmse_deg"] == pytest.approx(5, abs=1e-9)
    assert m["inclination_rmse_deg"] == pytest.approx(0, abs=1e-6)


def test_pure_inclination_error_and_6d():
    q_ref = from_euler(0.3, -0.2, 1.0)
    tilt = multiply(axis_quat([1, 1, 0], math.radians(3)), q_ref)  # 3° about a horizontal world axis
    m = measures(q_ref, tilt)
    assert m["inclination_rmse_deg"] == pytest.approx(3, abs=1e-9)
    assert m["total_rmse_deg"] == pytest.approx(3, abs=1e-9)
    assert m["heading_rmse_deg"] == pytest.approx(0, abs=1e-6)
    # no heading reference: any yaw offset, the inclination alone, heading and total n/a
    drifted = multiply(axis_quat([0, 0, 1], 2.0), tilt)
    assert measures(q_ref, drifted, heading=False) == {
        "total_rmse_deg": None, "heading_rmse_deg": None, "inclination_rmse_deg": pytest.approx(3, abs=1e-9)}


def test_error_angles_match_the_datasets_definition():
    # BROAD's broad_utils: q_err = q_est ⊗ q_ref⁻¹; heading 2·atan(|z/w|), inclination 2·acos(√(w²+z²))
    rng = np.random.default_rng(0)
    q_ref, q_est = (q / np.linalg.norm(q, axis=1)[:, None] for q in rng.normal(size=(2, 50, 4)))
    e = multiply(q_est, conjugate(q_ref))
    angles = error_angles(q_ref, q_est)
    np.testing.assert_allclose(angles["total"], 2 * np.arccos(np.abs(e[:, 0])), atol=1e-12)
    np.testing.assert_allclose(angles["heading"], 2 * np.arctan(np.abs(e[:, 3] / e[:, 0])), atol=1e-12)
    np.testing.assert_allclose(angles["inclination"], 2 * np.arccos(np.sqrt(e[:, 0] ** 2 + e[:, 3] ** 2)), atol=1e-12)


def test_evaluate_tables_beside_the_published_figures(tmp_path):
    published = {"trials": {"02_a": {"tagp_parameters": {"inclination_rmse_deg": 0.66}}},
                 "groups": {"rotation": {"tagp_parameters": {"inclination_rmse_deg": 1.41}}}}
    (tmp_path / "published_mahony_average_rmse.json").write_text(json.dumps(published))
    (tmp_path / "trials.json").write_text(json.dumps({"groups": [], "trials": {
        "02_a": {"groups": ["all_trials", "rotation"]}, "07_b": {"groups": ["all_trials", "rotation"]}}}))
    records = [{"status": "ok", "log": str(tmp_path / f"{stem}.hdf5"), "facts": {"format": "broad"},
                "metrics": {"mahony": {"broad": {"total_rmse_deg": None, "heading_rmse_deg": None,
                                                 "inclination_rmse_deg": value}}}}
               for stem, value in (("02_a", 1.0), ("07_b", 2.0))]
    text = broad_text(records, ["mahony"])
    assert "heading" not in text.split("BROAD inclination")[0]  # 6D: no heading or total table
    def row(section: str, name: str) -> list[str]:
        return next(line for line in section.splitlines() if line.startswith(name))[len(name):].split()

    per_trial, per_group = text.split("per group")
    assert row(per_trial, "mahony") == ["1.00", "2.00"] and row(per_trial, "Mahony (published)") == ["0.66", "n/a"]
    assert row(per_group, "estimator") == ["all_trials", "rotation"]
    assert row(per_group, "mahony") == ["1.50", "1.50"] and row(per_group, "Mahony (published)") == ["n/a", "1.41"]
    assert "doi:10.3390/data6070072" in text


# ---------------------------------------------------------------- the shared trials


def shared_trials():
    trials = sorted(SHARED_BROAD.glob("*.hdf5")) if SHARED_BROAD.is_dir() else []
    if not trials:
        pytest.skip(f"BROAD's trials not found in {SHARED_BROAD}")
    return trials


def test_shared_trials_at_rest_read_gravity_down_and_the_truths_tilt():
    for path in shared_trials():
        flight = read_log(str(path))
        imu, truth = flight.imu["imu"], flight.truth
        rest = (imu.t >= truth.t[0]) & (imu.t < truth.t[0] + 3)  # each trial starts still
        accel = imu.accel[rest].mean(axis=0)
        assert accel[2] < -9.7 and np.hypot(accel[0], accel[1]) < 0.5, path.name
        down = rotate(conjugate(truth.q[np.searchsorted(truth.t, imu.t[rest])]), np.array([0, 0, -1.0])).mean(0)
        angle = np.degrees(np.arccos(np.dot(accel, down) / np.linalg.norm(accel) / np.linalg.norm(down)))
        assert angle < 0.5, (path.name, angle)


@pytest.mark.slow
def test_evaluate_on_the_shared_trials(tmp_path, capsys):
    from mavattitude.cli import main

    shared_trials()
    assert main(["evaluate", str(SHARED_BROAD), "--estimators", "mahony", "--reference", "truth", "-j", "1",
                 "--out", str(tmp_path / "out"), "--quiet"]) == 0
    out = capsys.readouterr().out
    assert "BROAD inclination RMSE per trial" in out and "BROAD heading RMSE per group" in out
    rotation = next(line for line in out.split("BROAD total RMSE per group")[1].splitlines()
                    if line.startswith("Mahony (published)"))
    assert "7.49" in rotation  # all_trials, TAGP: the published total over the 39 trials
    assert "## BROAD's measures" in (tmp_path / "out" / "report.md").read_text()


def test_replay_prints_and_writes_the_measures(tmp_path, capsys):
    from mavattitude.cli import main

    trial = write_trial(tmp_path / "t.hdf5", axis_quat([0, 1, 0], 0.1), n=2000)
    assert main(["replay", trial, "--estimators", "mahony,eskf", "--reference", "truth", "--no-mag", "--no-view",
                 "--warmup", "1", "--json", str(tmp_path / "m.json")]) == 0
    out = capsys.readouterr().out
    table = out.split("BROAD's measures")[1]
    assert next(line for line in table.splitlines() if line.startswith("eskf")).split()[1:] == ["n/a", "n/a"] + \
        [f"{json.loads((tmp_path / 'm.json').read_text())['estimators']['eskf']['broad']['inclination_rmse_deg']:.2f}"]
    written = json.loads((tmp_path / "m.json").read_text())["estimators"]
    assert set(written["mahony"]["broad"]) == {"total_rmse_deg", "heading_rmse_deg", "inclination_rmse_deg"}


def test_a_folder_of_trials_without_h5py_says_so(tmp_path, monkeypatch, capsys):
    from mavattitude.cli import main

    write_trial(tmp_path / "a.hdf5", np.array([1.0, 0, 0, 0]))
    monkeypatch.setitem(sys.modules, "h5py", None)
    assert main(["evaluate", str(tmp_path), "--estimators", "mahony", "--reference", "truth", "-j", "1",
                 "--out", str(tmp_path / "out"), "--quiet"]) == 1
    assert NEEDS_H5PY in capsys.readouterr().err
