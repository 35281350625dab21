"""mavattitude tune: the declared search spaces, the TOML it writes, the folds, the penalty for a
diverged trial, resuming a stopped study, the command's errors, and, on simulated flights with
a known best gain, that it finds it."""
from __future__ import annotations

import dataclasses
import math
import sqlite3

import numpy as np
import pytest

from conftest import SAMPLE_LOGS
from mavattitude.cli import main
from mavattitude.errors import UsageError
from mavattitude.estimators import ESTIMATORS
from mavattitude.commands.evaluate import evaluate_log
from mavattitude.core.params import build, load_file, search_space, to_toml
from mavattitude.core.policy import RunOptions
from mavattitude.commands.tune import DIVERGED_DEG, TuneSettings, deal_folds, log_score, space_for, tune

optuna = pytest.importorskip("optuna", reason="tune needs the optional extra: pip install 'mavattitude[tune]'")


# ---------------------------------------------------------------- search spaces


@pytest.mark.parametrize("name", list(ESTIMATORS))  # the Params alone: no package needed
def test_every_estimator_searches_a_space_around_its_defaults(name):
    cls = ESTIMATORS[name].Params
    space = search_space(cls)
    assert space, f"{name} declares nothing to tune"
    fields = {f.name: f for f in dataclasses.fields(cls)}
    defaults = cls()
    for field, search in space.items():
        valid = fields[field].metadata["valid"]
        assert search.lo in valid and search.hi in valid
        assert search.lo <= getattr(defaults, field) <= search.hi
        assert not search.log or search.lo > 0
    for lo, hi in getattr(cls, "ORDERED", ()):
        if lo in space and hi in space:  # any pair of sampled values keeps the ramp's order
            assert space[lo].hi < space[hi].lo


def test_a_search_range_is_checked_where_it_is_declared():
    from mavattitude.core.params import param

    with pytest.raises(ValueError, match="outside its own search range"):
        param(0.2, "[0, inf)", "log [1, 10]")
    with pytest.raises(ValueError, match="starts above 0"):
        param(0.2, "[0, inf)", "log [0, 10]")
    with pytest.raises(ValueError, match="leaves the valid interval"):
        param(0.5, "[0, 1]", "linear [0, 2]")
    with pytest.raises(ValueError, match="'log' or 'linear'"):
        param(0.5, "[0, 1]", "[0, 1]")


def test_set_fixes_a_field_and_strict_or_nothing_left_is_refused():
    replay = RunOptions(names=("mahony",), assignments=("mahony.ki=0", "mahony.accel_tau=0"))
    assert list(space_for(TuneSettings("mahony", replay))) == ["kp"]
    replay = RunOptions(names=("mahony",), assignments=("mahony.ki=0", "mahony.kp=1", "mahony.accel_tau=0"))
    with pytest.raises(UsageError, match="nothing to tune"):
        space_for(TuneSettings("mahony", replay))
    replay = RunOptions(names=("ncs-eskf",), assignments=("ncs-eskf.strict=true",))
    with pytest.raises(UsageError, match="strict"):
        space_for(TuneSettings("ncs-eskf", replay))


# ---------------------------------------------------------------- TOML, folds, scores


def test_toml_reads_back_to_the_same_values(tmp_path):
    values = {"mahony": {"kp": 0.1 + 0.2, "ki": 1.2345678901234567e-05, "use_mag": False},
              "cpf-ekf": {"reset_cycles": 4, "gyro_noise": 3.0e-4}}
    path = tmp_path / "tuned.toml"
    path.write_text(to_toml(values, {"mahony": "fitted on 3 logs\nsecond line"}))
    assert load_file(str(path)) == values
    params = build(["mahony", "cpf-ekf"], load_file(str(path)))
    assert params["mahony"].kp == 0.1 + 0.2 and params["mahony"].use_mag is False
    assert params["cpf-ekf"].reset_cycles == 4


def test_every_log_is_held_out_once():
    logs = [f"log{i}.bin" for i in range(11)]
    folds = deal_folds(logs, 5, seed=3)
    held = [log for fold in folds for log in fold]
    assert sorted(held) == sorted(logs) and len(held) == len(set(held))
    assert {len(f) for f in folds} == {2, 3}
    assert deal_folds(logs, 5, seed=3) == folds and deal_folds(logs, 5, seed=4) != folds


def test_a_log_scores_its_tilt_error_or_the_penalty():
    axes = {"roll": {"mae": 1.0}, "pitch": {"mae": 3.0}}
    ok = {"status": "ok", "metrics": {"mahony": {**axes, "nonfinite_samples": 0}}}
    assert log_score(ok, "mahony") == 2.0
    diverged = {"status": "ok", "metrics": {"mahony": {**axes, "nonfinite_samples": 7}}}
    assert log_score(diverged, "mahony") == DIVERGED_DEG
    assert log_score({"status": "failed", "metrics": {}}, "mahony") == DIVERGED_DEG
    assert math.isnan(log_score({"status": "skipped", "metrics": {}}, "mahony"))


# ---------------------------------------------------------------- the search, on a made-up objective


class FakeWorkers:
    """Replays nothing: each log's tilt error is |log(kp / best)| + its own offset, and kp > 5
    makes the estimate diverge (non-finite). ``stop_after`` runs raise KeyboardInterrupt."""

    def __init__(self, best: float = 0.7, stop_after: int | None = None):
        self.best, self.stop_after, self.runs = best, stop_after, 0

    def run(self, logs, settings, finished):
        self.runs += 1
        if self.stop_after is not None and self.runs > self.stop_after:
            raise KeyboardInterrupt
        kp = (settings.file_values or {}).get("mahony", {}).get("kp", 0.2)
        for log in logs:
            offset = int(log[3:-4]) / 100
            finished({"log": log, "status": "ok", "error": None, "metrics": {"mahony": {
                "roll": {"mae": abs(math.log(kp / self.best)) + offset}, "pitch": {"mae": abs(math.log(kp / self.best)) + offset},
                "nonfinite_samples": 100 if kp > 5 else 0}}})


LOGS = [f"log{i}.bin" for i in range(10)]


def settings(trials=30, folds=5, **kw):
    return TuneSettings("mahony", RunOptions(names=("mahony",), assignments=("mahony.ki=0.0005",)),
                        trials=trials, folds=folds, **kw)


def test_the_search_finds_the_best_and_holds_out_every_log():
    result = tune(LOGS, settings(), FakeWorkers(best=0.7))
    assert result.final.best["kp"] == pytest.approx(0.7, rel=0.1)
    assert result.final.best_value < result.final.start_value
    start, tuned = result.held_out()
    assert sorted(start) == sorted(LOGS)
    assert all(tuned[log] < start[log] for log in LOGS)  # the fake's best is the same on every log
    assert result.penalised > 0  # kp above 5 was tried: counted as diverged, not an error
    assert len(result.folds) == 5 and all(f.trials == 30 for f in [*result.folds, result.final])


def test_a_stopped_study_resumes_where_it_stopped(tmp_path):
    storage = f"sqlite:///{tmp_path / 'study.db'}"
    with pytest.raises(KeyboardInterrupt):
        tune(LOGS, settings(trials=8, folds=0), FakeWorkers(stop_after=5), storage)
    study = optuna.load_study(study_name=optuna.get_all_study_names(storage)[0], storage=storage)
    states = [t.state for t in study.trials]
    # the start (scored before the first trial, so free), then four trials replayed
    assert states.count(optuna.trial.TrialState.COMPLETE) == 5
    assert states[-1] == optuna.trial.TrialState.FAIL  # the trial the stop cut
    workers = FakeWorkers()
    result = tune(LOGS, settings(trials=8, folds=0), workers, storage)
    assert result.final.trials == 8
    assert workers.runs == 1 + 3  # the start's scores, then only the trials still missing
    again = tune(LOGS, settings(trials=8, folds=0), FakeWorkers(), storage)
    assert again.final.best == result.final.best


# ---------------------------------------------------------------- real replays


def test_a_kept_log_replays_as_a_freshly_read_one():
    log = str(SAMPLE_LOGS / "figure8.tlog")
    replay = RunOptions(names=("mahony", "cpf-ekf"))
    fresh = evaluate_log(log, replay)
    for _ in range(2):
        kept = evaluate_log(log, replay, keep=True)
        assert kept["metrics"] == fresh["metrics"]


@pytest.fixture(scope="module")
def still_flights(tmp_path_factory):
    """Two still, tilted 120 s flights whose gyro and accelerometer noise (and nothing else:
    no bias, no motion) set mahony's best Kp: the error's variance (σg² + Kp² σa²) / 2Kp is
    least at Kp = σg / σa, σa the accelerometer's noise density over g (rad/√Hz)."""
    from mavattitude.sim import SensorParams, simulate, write_log

    folder = tmp_path_factory.mktemp("still")
    noise = SensorParams(gyro_noise_density=0.02, gyro_bias_sigma=0.0, gyro_bias_walk=0.0,
                         accel_noise_density=0.05, accel_bias_sigma=0.0)
    for seed in (1, 2):
        write_log(simulate("static", 120.0, seed=seed, params=noise), folder / f"still{seed}.bin")
    return folder, 0.02 / (0.05 / 9.80665)


def test_tune_finds_mahonys_best_kp_from_the_noise(still_flights, tmp_path, capsys):
    folder, best_kp = still_flights
    out = tmp_path / "tuned.toml"
    assert main(["tune", str(folder), "--estimator", "mahony", "--reference", "truth", "--set", "mahony.ki=0",
                 "--set", "mahony.use_mag=false", "--set", "mahony.accel_tau=0", "--folds", "0", "--trials", "25", "-j", "1", "-q",
                 "-o", str(out)]) == 0
    tuned = load_file(str(out))["mahony"]
    assert tuned["ki"] == 0 and tuned["use_mag"] is False  # what --set fixed is written too
    # the error is flat near its least (+1 % at 0.75 and 1.25 times it): within 30 %
    assert tuned["kp"] == pytest.approx(best_kp, rel=0.3)
    assert "mahony: median tilt error" in capsys.readouterr().out


# ---------------------------------------------------------------- the command's errors


def run(*args) -> int:
    return main(["tune", *map(str, args)])


def test_bad_commands_fail_with_one_line(tmp_path, capsys):
    log = SAMPLE_LOGS / "static.bin"
    assert run(log, "--estimator", "nosuch") == 2
    assert run(log, "--estimator", "mahony,eskf") == 2
    assert run(log, "--estimator", "mahony", "--set", "mahony.kp=1", "--set", "mahony.ki=0",
               "--set", "mahony.accel_tau=0") == 2
    assert run(log, "--estimator", "mahony", "--ship-logs") == 2
    not_a_study = tmp_path / "notes.db"
    not_a_study.write_text("my notes")
    assert run(log, "--estimator", "mahony", "--study", not_a_study, "-o", tmp_path / "t.toml") == 1
    assert not_a_study.read_text() == "my notes"
    assert run(log, "--estimator", "mahony", "-o", log) == 1  # never over an input
    err = capsys.readouterr().err.splitlines()
    assert len(err) == 6 and all(line.startswith("mavattitude: error: ") for line in err)
    assert "not an SQLite database" in err[4] and "would write over the input" in err[5]


def test_without_optuna_the_command_says_how_to_get_it(monkeypatch, capsys):
    monkeypatch.setitem(__import__("sys").modules, "optuna", None)
    assert run(SAMPLE_LOGS / "static.bin", "--estimator", "mahony") == 2
    assert "pip install 'mavattitude[tune]'" in capsys.readouterr().err


def test_a_short_run_writes_toml_that_replay_reads(tmp_path, capsys):
    folder = tmp_path / "logs"
    folder.mkdir()
    for name in ("figure8.tlog", "static.bin", "hover.tlog"):
        (folder / name).write_bytes((SAMPLE_LOGS / name).read_bytes())
    out, report = tmp_path / "tuned.toml", tmp_path / "tune.json"
    study = tmp_path / "study.db"
    assert run(folder, "--estimator", "mahony", "--trials", "3", "--folds", "3", "-j", "1", "-q",
               "--study", study, "-o", out, "--json", report) == 0
    text = capsys.readouterr().out
    assert "3-fold cross-validation" in text and "held out, all 3 logs" in text
    with sqlite3.connect(study) as db:  # four studies (three folds, then all logs), three trials each
        assert db.execute("select count(*) from trials where state = 'COMPLETE'").fetchone()[0] == 12
    import json
    data = json.loads(report.read_text())
    assert sorted(np.ravel([f["held_out"] for f in data["folds"]])) == sorted(data["logs"])
    assert main(["replay", str(folder / "figure8.tlog"), "--params", str(out), "--no-view"]) == 0


@pytest.mark.slow
def test_a_pool_and_a_dask_cluster_tune_as_one_process_does(tmp_path):
    import json

    distributed = pytest.importorskip("distributed")
    folder = tmp_path / "logs"
    folder.mkdir()
    for name in ("figure8.tlog", "static.bin", "hover.tlog"):
        (folder / name).write_bytes((SAMPLE_LOGS / name).read_bytes())

    def tuned(where: str, *extra) -> dict:
        report = tmp_path / f"{where}.json"
        assert run(folder, "--estimator", "eskf", "--trials", "2", "--folds", "2", "-q", "-o", tmp_path / f"{where}.toml",
                   "--json", report, *extra) == 0
        data = json.loads(report.read_text())
        return {"folds": data["folds"], "final": data["final"]}

    here = tuned("here", "-j", "1")
    assert tuned("pool", "-j", "2") == here
    with distributed.LocalCluster(n_workers=1, threads_per_worker=1, processes=True,
                                  host="127.0.0.1", dashboard_address=":0") as cluster:
        assert tuned("dask", "--scheduler", cluster.scheduler_address) == here


class NothingScoredAbove(FakeWorkers):
    """As FakeWorkers, but kp above 2 leaves nothing scored (no roll or pitch)."""

    def run(self, logs, settings, finished):
        kp = (settings.file_values or {}).get("mahony", {}).get("kp", 0.2)
        super().run(logs, settings, lambda r: finished({**r, "metrics": {"mahony": {}}} if kp > 2 else r))


def test_values_that_leave_nothing_scored_count_as_diverged():
    result = tune(LOGS, settings(trials=20, folds=0), NothingScoredAbove(best=0.7))
    assert math.isfinite(result.final.best_value) and result.final.best["kp"] <= 2
    assert result.penalised > 0
