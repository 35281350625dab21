"""The mavattitude command end to end: outputs, exit codes and one-line errors."""
from __future__ import annotations

import csv
import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from conftest import RERUN_CLI, SAMPLE_LOGS, kernel_interrupt, one_line, process_group, shared_log, shared_log_params
from mavattitude.cli import main

AXES = ("roll", "pitch", "yaw")
METRIC_KEYS = {"mae", "rmse", "mse", "r2", "max", "sigma1", "sigma3", "buckets"}


def run(capsys, *args) -> tuple[int, str, str]:
    code = main([str(a) for a in args])
    out, err = capsys.readouterr()
    return code, out, err


def rrd_verifies(path: Path) -> bool:
    cmd = [RERUN_CLI] if RERUN_CLI else [sys.executable, "-m", "rerun"]
    done = subprocess.run(cmd + ["rrd", "verify", str(path)], capture_output=True, text=True)
    return done.returncode == 0


def check_outputs(tmp_path: Path, estimators: list[str], reference: str) -> dict:
    metrics = json.loads((tmp_path / "m.json").read_text())
    assert set(metrics) == {"written_by", "log", "reference", "estimators", "scoring", "events", "declination_deg",
                            "declination_source", "autopilot_streams", "reference_spread_deg"}
    assert all(set(e) == {"t_s", "level", "kind", "text"} for e in metrics["events"]) and metrics["events"]
    assert metrics["reference"]["stream"] == reference
    assert set(metrics["estimators"]) >= set(estimators)
    for name, per_axis in metrics["estimators"].items():
        assert set(AXES) <= set(per_axis)
        if name in estimators:
            assert {"events", "diagnostics", "params"} <= set(per_axis)
            assert per_axis["nonfinite_samples"] == 0, f"{name} produced NaN"
        for axis in AXES:
            assert METRIC_KEYS <= set(per_axis[axis])
            assert set(per_axis[axis]["buckets"]) == {"lt_0.5", "0.5_1", "1_2", "gt_2"}
            assert sum(per_axis[axis]["buckets"].values()) == pytest.approx(1.0)
    for name in ["reference"] + estimators:
        with open(tmp_path / "csv" / f"{name}.csv") as f:
            rows = list(csv.reader(f))
        assert rows[0] == ["time_s", "roll_deg", "pitch_deg", "yaw_deg"]
        times = [float(r[0]) for r in rows[1:]]
        assert len(times) > 10 and times == sorted(times)
        assert all(-180.0 <= float(r[3]) < 180.0 for r in rows[1:])
    assert rrd_verifies(tmp_path / "r.rrd")
    return metrics


def test_replay_sample_log_writes_every_output(tmp_path, capsys):
    code, out, err = run(capsys, "replay", SAMPLE_LOGS / "figure8.tlog", "--rrd", tmp_path / "r.rrd",
                         "--json", tmp_path / "m.json", "--export", tmp_path / "csv")
    assert code == 0, err
    assert "mahony" in out and "MAE" in out and "RMSE" in out and "R²" in out
    metrics = check_outputs(tmp_path, ["mahony"], "ATTITUDE")
    assert metrics["estimators"]["mahony"]["roll"]["mae"] < 3.0
    assert metrics["declination_deg"] == pytest.approx(5.0)  # the simulator's COMPASS_DEC
    assert "declination 5.00° (log parameter COMPASS_DEC" in out  # under the table's title


def test_replay_against_truth_scores_the_autopilot_too(tmp_path, capsys):
    code, out, err = run(capsys, "replay", SAMPLE_LOGS / "figure8.bin", "--reference", "truth",
                         "--rrd", tmp_path / "r.rrd", "--json", tmp_path / "m.json",
                         "--export", tmp_path / "csv")
    assert code == 0, err
    metrics = check_outputs(tmp_path, ["mahony"], "SIM")
    autopilot = metrics["estimators"]["autopilot"]
    assert autopilot["roll"]["mae"] < 0.5  # the simulated autopilot's error is ~0.15° RMS
    assert "autopilot" in out


def test_default_sink_is_log_name_rrd_in_current_folder(tmp_path, capsys, monkeypatch):
    monkeypatch.chdir(tmp_path)
    code, out, _ = run(capsys, "replay", SAMPLE_LOGS / "static.bin")
    assert code == 0
    assert (tmp_path / "static.rrd").exists()
    assert "rerun static.rrd" in out


def test_info_text_and_json(capsys):
    code, out, _ = run(capsys, "info", SAMPLE_LOGS / "figure8.tlog")
    assert code == 0 and "RAW_IMU" in out and "SCALED_IMU2" in out
    code, out, _ = run(capsys, "info", SAMPLE_LOGS / "figure8.tlog", "--json")
    info = json.loads(out)
    assert info["best_imu"] == "RAW_IMU"
    assert info["imu_sources"]["RAW_IMU"]["rate_hz"] == pytest.approx(50.0, rel=0.01)
    assert info["imu_sources"]["RAW_IMU"]["accel_norm_ms2"]["median"] == pytest.approx(9.8, abs=0.2)
    assert info["sensors"]["ground_truth"] == "SIMSTATE"
    assert info["message_counts"]["RAW_IMU"] > 4000
    assert info["declination_deg"] == pytest.approx(5.0, abs=1e-3)
    assert info["declination_source"] == "log parameter COMPASS_DEC, no COMPASS_AUTODEC: set by hand"
    assert info["duration_s"] == pytest.approx(100.0, abs=1.0)


def test_simulate_writes_a_log_replay_reads(tmp_path, capsys):
    out_path = tmp_path / "hover.bin"
    code, out, err = run(capsys, "simulate", "--scenario", "hover", "--duration", "30", "-o", out_path)
    assert code == 0, err
    assert out_path.stat().st_size > 10_000
    code, _, err = run(capsys, "replay", out_path, "--no-view", "--warmup", "5")
    assert code == 0, err
    code, out, _ = run(capsys, "simulate", "--list")
    assert code == 0 and "figure8" in out and "static" in out


@pytest.mark.parametrize("args, code, text", [
    (["replay", "missing.bin"], 1, "missing.bin: no such file"),
    (["info", "missing.tlog"], 1, "missing.tlog: no such file"),
    (["replay", SAMPLE_LOGS / "static.bin", "--estimators", "nope", "--no-view"], 2, "unknown estimator"),
    (["replay", SAMPLE_LOGS / "static.bin", "--imu", "IMU[7]", "--no-view"], 1, "IMU[7]"),
    (["replay", SAMPLE_LOGS / "static.bin", "--warmup", "-1", "--no-view"], 2, "--warmup"),
    (["simulate", "--scenario", "nope", "-o", "x.tlog"], 2, "unknown scenario"),
    (["simulate", "-o", "x.csv"], 2, "must end in .tlog, .bin or .ulg"),
])
def test_errors_are_one_line_with_exit_code(capsys, args, code, text):
    got, out, err = run(capsys, *args)
    assert got == code
    lines = err.strip().splitlines()
    assert len(lines) == 1 and text in lines[0] and "Traceback" not in err


def test_garbage_file_is_one_line_error(tmp_path, capsys):
    bad = tmp_path / "junk.tlog"
    bad.write_bytes(bytes(range(256)) * 10)
    code, _, err = run(capsys, "replay", bad, "--no-view")
    assert code == 1
    assert err.strip().splitlines() == [err.strip()] and str(bad) in err


def test_truth_reference_on_a_log_without_truth(capsys):
    code, _, err = run(capsys, "replay", shared_log("copter-3.4-erlebrain-22.bin"),
                       "--reference", "truth", "--no-view")
    assert code == 1 and "no ground truth" in err


def test_module_and_console_script_help():
    for cmd in ([sys.executable, "-m", "mavattitude", "--help"],
                [sys.executable, "-m", "mavattitude", "replay", "--help"]):
        done = subprocess.run(cmd, capture_output=True, text=True)
        assert done.returncode == 0 and "usage: mavattitude" in done.stdout
    done = subprocess.run([sys.executable, "-m", "mavattitude"], capture_output=True, text=True)
    assert done.returncode == 2


# ---------------------------------------------------------------- every shared log (issue 2, "done when")

# Roll and pitch MAE bounds for mahony against the autopilot's attitude.
COPTER_BIN_MAX_DEG = 3.0
PLANE_BIN_MAX_DEG = 5.0  # 10 Hz IMU, coordinated turns
TLOG_MAX_DEG = 10.0  # telemetry IMU at 1-50 Hz


def _bound(name: str) -> float:
    if name.endswith(".tlog"):
        return TLOG_MAX_DEG
    return PLANE_BIN_MAX_DEG if name.startswith("plane") else COPTER_BIN_MAX_DEG


@pytest.mark.parametrize("path", shared_log_params(slow_above_mb=2))
def test_every_shared_log_replays_with_every_estimator(path, tmp_path, capsys):
    from mavattitude.estimators import all_names

    code, out, err = run(capsys, "replay", path, "--estimators", "all",
                         "--rrd", tmp_path / "r.rrd", "--json", tmp_path / "m.json",
                         "--export", tmp_path / "csv")
    assert code == 0, err
    assert "mahony" in out and "MAE" in out
    metrics = check_outputs(tmp_path, all_names(),
                            json.loads((tmp_path / "m.json").read_text())["reference"]["stream"])
    mahony = metrics["estimators"]["mahony"]
    bound = _bound(path.name)
    assert mahony["roll"]["mae"] <= bound and mahony["pitch"]["mae"] <= bound, (
        f"{path.name}: roll {mahony['roll']['mae']:.2f}°, pitch {mahony['pitch']['mae']:.2f}° > {bound}°")


# ---------------------------------------------------------------- parameters (issue 3)


def test_estimators_lists_every_estimator_with_its_parameters(capsys):
    from mavattitude.estimators import ESTIMATORS

    code, out, _ = run(capsys, "estimators")
    assert code == 0
    for name, cls in ESTIMATORS.items():
        assert f"{name}:" in out
        for field in cls.Params.__dataclass_fields__:
            assert f"--set {name}.{field}" in out
    code, out, _ = run(capsys, "estimators", "--json")
    listing = json.loads(out)
    assert listing["mahony"]["params"]["kp"]["default"] == 0.2
    assert "gain" in listing["mahony"]["params"]["kp"]["help"]


def test_set_and_params_file_reach_the_estimator(tmp_path, capsys):
    (tmp_path / "p.toml").write_text("[mahony]\nkp = 1.5\nki = 0.002\n")
    code, _, err = run(capsys, "replay", SAMPLE_LOGS / "static.bin", "--no-view",
                       "--params", tmp_path / "p.toml", "--set", "mahony.kp=0.7",
                       "--set", "mahony.use_mag=false", "--json", tmp_path / "m.json")
    assert code == 0, err
    params = json.loads((tmp_path / "m.json").read_text())["estimators"]["mahony"]["params"]
    assert params == {"kp": 0.7, "ki": 0.002, "use_mag": False, "accel_tau": 1.0,
                      "strict": False}  # --set wins over the file


def test_plane_log_supplies_the_eq_kf_airspeed_param_unless_the_user_sets_it():
    from types import SimpleNamespace

    from mavattitude.core.params import build, log_defaults

    plane = SimpleNamespace(vehicle="ArduPlane", params={"TRIM_ARSPD_CM": 1200.0})
    values, notes = log_defaults(plane, ["mahony", "eq-kf"])
    assert values == {"eq-kf": {"airspeed": 12.0}} and "TRIM_ARSPD_CM" in notes[0]
    assert build(["eq-kf"], log_values=values)["eq-kf"].airspeed == 12.0
    assert log_defaults(plane, ["eq-kf"], None, ["eq-kf.airspeed=0"]) == ({}, [])
    assert log_defaults(plane, ["eq-kf"], {"eq-kf": {"airspeed": 9.0}}) == ({}, [])
    assert log_defaults(plane, ["mahony"]) == ({}, [])
    copter = SimpleNamespace(vehicle="ArduCopter", params={"TRIM_ARSPD_CM": 1200.0})
    assert log_defaults(copter, ["eq-kf"]) == ({}, [])


@pytest.mark.parametrize("extra, code, text", [
    (["--set", "mahony.kq=1"], 2, "mahony has no parameter 'kq'"),
    (["--set", "mahony.kp"], 2, "expected ESTIMATOR.PARAMETER=VALUE"),
    (["--set", "mahony.kp=fast"], 2, "expected a finite number"),
    (["--set", "mahony.use_mag=maybe"], 2, "expected true or false"),
    (["--set", "nope.kp=1"], 2, "unknown estimator 'nope'"),
    (["--params", "missing.toml"], 1, "missing.toml: no such file"),
])
def test_bad_parameters_are_one_line_errors(capsys, extra, code, text):
    got, _, err = run(capsys, "replay", SAMPLE_LOGS / "static.bin", "--no-view", *extra)
    assert got == code
    assert len(err.strip().splitlines()) == 1 and text in err and "Traceback" not in err


def test_bad_toml_names_the_file(tmp_path, capsys):
    bad = tmp_path / "bad.toml"
    bad.write_text("[mahony\nkp = 1\n")
    got, _, err = run(capsys, "replay", SAMPLE_LOGS / "static.bin", "--no-view", "--params", bad)
    assert got == 1 and str(bad) in err and "not valid TOML" in err
    bad.write_text("mahony = 3\n")
    got, _, err = run(capsys, "replay", SAMPLE_LOGS / "static.bin", "--no-view", "--params", bad)
    assert got == 1 and "must be a table" in err


# ---------------------------------------------------------------- stop signals


def test_a_ctrl_c_that_numba_returns_as_a_system_error_is_an_interrupt(tmp_path, capsys, monkeypatch):
    from mavattitude.commands import replay as pipeline
    from mavattitude.errors import is_interrupt

    assert is_interrupt(KeyboardInterrupt()) and not is_interrupt(SystemError("a bug")) and not is_interrupt(None)
    monkeypatch.setattr(pipeline, "replay_flight", kernel_interrupt)
    code, out, err = run(capsys, "replay", SAMPLE_LOGS / "figure8.tlog", "--no-view", "--json", tmp_path / "m.json")
    assert code == 130 and err.strip().splitlines()[-1] == "interrupted" and "Traceback" not in err
    assert list(tmp_path.iterdir()) == []  # no --json, no temporary file left


def test_a_system_error_that_is_no_interrupt_stays_a_bug(capsys, monkeypatch):
    from mavattitude.commands import replay as pipeline

    def bug(*args, **kwargs):
        raise SystemError("a bug")
    monkeypatch.setattr(pipeline, "replay_flight", bug)
    with pytest.raises(SystemError):
        main(["replay", str(SAMPLE_LOGS / "figure8.tlog"), "--no-view"])


def test_stop_signals_are_handled_only_while_main_runs(capsys):
    before = signal.getsignal(signal.SIGINT), signal.getsignal(signal.SIGTERM)
    assert main(["estimators"]) == 0
    assert (signal.getsignal(signal.SIGINT), signal.getsignal(signal.SIGTERM)) == before


def test_a_stop_signal_in_numbas_own_code_waits_until_it_lands_elsewhere():
    """Raised in the Python code numba runs from inside a compiled call, a KeyboardInterrupt
    leaves the call half done (a SystemError, or a crash): the signal is sent again instead."""
    from mavattitude import signals

    in_numba = compile("import signal, os; os.kill(os.getpid(), signal.SIGINT); import time; time.sleep(0.05)",
                       os.path.join("site-packages", "numba", "core", "dispatcher.py"), "exec")
    previous = signals.install()
    try:
        exec(in_numba, {})  # the handler runs there: not raised, not counted
        assert signals.received() is None
        with pytest.raises(KeyboardInterrupt):
            time.sleep(1.0)  # sent again: raised here
        assert signals.received() == signal.SIGINT
        os.kill(os.getpid(), signal.SIGTERM)  # a second signal while stopping: noted, not raised
        time.sleep(0.05)
        assert signals.exit_code() == 130 and signals.message() == "interrupted"
    finally:
        signals.restore(previous)


def _start(args, tmp_path) -> subprocess.Popen:
    return subprocess.Popen([sys.executable, "-m", "mavattitude", *map(str, args)], cwd=tmp_path, text=True,
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE)


def _signal_at(proc: subprocess.Popen, *times_and_signals) -> tuple[str, str]:
    """Send each (seconds after the start, signal) while the process runs; its output."""
    start = time.monotonic()
    for at, signum in times_and_signals:
        time.sleep(max(0.0, start + at - time.monotonic()))
        if proc.poll() is None:
            proc.send_signal(signum)
    return proc.communicate(timeout=120)


def _stopped_cleanly(proc, err: str, code: int, line: str) -> None:
    assert proc.returncode == code, err
    assert "Traceback" not in err and err.strip().splitlines()[-1] == line


@pytest.mark.slow
def test_ctrl_c_in_the_first_second_is_one_line_and_130(tmp_path):
    for at in (0.2, 0.6):  # importing numpy, numba
        proc = _start(["replay", SAMPLE_LOGS / "figure8.tlog", "--no-view"], tmp_path)
        out, err = _signal_at(proc, (at, signal.SIGINT))
        _stopped_cleanly(proc, err, 130, "interrupted")


@pytest.mark.slow
def test_a_second_ctrl_c_still_ends_with_130_and_no_file_left(tmp_path):
    proc = _start(["replay", SAMPLE_LOGS / "figure8.tlog", "--json", tmp_path / "m.json", "--rrd",
                   tmp_path / "r.rrd"], tmp_path)
    out, err = _signal_at(proc, (1.0, signal.SIGINT), (1.02, signal.SIGINT))
    _stopped_cleanly(proc, err, 130, "interrupted")
    assert list(tmp_path.iterdir()) == []


@pytest.mark.slow
def test_sigterm_ends_a_replay_with_143_and_no_temporary_file(tmp_path):
    log = shared_log("sitl-copter-4.7-400hz.bin")  # 3-5 s of work
    proc = _start(["replay", log, "--estimators", "all", "--json", tmp_path / "m.json", "--rrd",
                   tmp_path / "r.rrd"], tmp_path)
    out, err = _signal_at(proc, (1.5, signal.SIGTERM))
    _stopped_cleanly(proc, err, 143, "terminated (SIGTERM)")
    assert list(tmp_path.iterdir()) == []


@pytest.mark.slow
def test_ctrl_c_while_the_kernels_run_is_one_line_and_130(tmp_path):
    """Sent at moments spread over the estimation of the 400 Hz shared log: numba's compiled
    code returned some of these as a SystemError (a traceback, exit 1), and some landed while
    numba loaded a cached kernel, which crashed the process (SIGSEGV)."""
    log = shared_log("sitl-copter-4.7-400hz.bin")
    args = ["replay", log, "--estimators", "all", "--no-view"]
    start = time.monotonic()
    proc = _start(args, tmp_path)
    proc.communicate(timeout=300)
    took = time.monotonic() - start
    assert proc.returncode == 0
    for fraction in (0.45, 0.5, 0.55, 0.65, 0.75, 0.85):  # reading is the first 40 % or so
        proc = _start(args, tmp_path)
        out, err = _signal_at(proc, (fraction * took, signal.SIGINT))
        if proc.returncode == 0:
            continue  # done before the signal came
        _stopped_cleanly(proc, err, 130, "interrupted")


@pytest.mark.slow
@pytest.mark.skipif(not Path("/proc/self/stat").exists(), reason="needs Linux's /proc")
def test_sigterm_during_a_first_compile_leaves_no_compiling_process(tmp_path):
    """SIGTERM to the command alone (not its group, as a terminal's Ctrl-C): the processes
    compiling for it end too. (It failed on CI, and 2 runs in 22 here: the signal landed in
    pymavlink's import of its quaternions, whose bare ``except`` swallowed it, and the command ran
    on to exit 0; ``signals.check`` now raises it again at the next progress report.)"""
    env = dict(os.environ, NUMBA_CACHE_DIR=str(tmp_path / "cold-cache"))
    proc = subprocess.Popen([sys.executable, "-m", "mavattitude", "replay", str(SAMPLE_LOGS / "figure8.tlog"),
                             "--estimators", "all", "--no-view"], env=env, cwd=tmp_path, text=True,
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, start_new_session=True)
    deadline = time.monotonic() + 180  # bounds against a hang only: under heavy load a first compile took 60-130 s
    while len(process_group(proc.pid)) < 2:  # the command (compiling too) and a compiling process
        assert proc.poll() is None and time.monotonic() < deadline, proc.communicate()
        time.sleep(0.1)
    proc.send_signal(signal.SIGTERM)
    out, err = proc.communicate(timeout=180)
    _stopped_cleanly(proc, err, 143, "terminated (SIGTERM)")
    deadline = time.monotonic() + 5.0  # not the tens of seconds their compile takes
    while process_group(proc.pid) and time.monotonic() < deadline:
        time.sleep(0.1)
    assert process_group(proc.pid) == []


@pytest.mark.slow
@pytest.mark.parametrize("signum", [signal.SIGTERM, signal.SIGINT])
def test_a_stop_while_the_command_compiles_an_estimator_itself_ends_it_at_once(tmp_path, signum):
    """The command compiles a share of the estimators too, once its log is read and its core
    compiled, in a thread: a stop then ends it at once (measured 0.02-0.10 s, the compile's
    few seconds not waited for), one line, nothing compiling left behind."""
    env = dict(os.environ, NUMBA_CACHE_DIR=str(tmp_path / "cold-cache"))
    proc = subprocess.Popen([sys.executable, "-m", "mavattitude", "replay", str(SAMPLE_LOGS / "static.bin"),
                             "--estimators", "all", "--no-view"], env=env, cwd=tmp_path, text=True,
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, start_new_session=True)
    said = []
    while not any("estimation core done" in line for line in said):  # the command's own share starts here
        said.append(proc.stderr.readline())
        assert said[-1], said  # ended before
    time.sleep(0.5)  # well inside the first estimator the command compiles (several seconds)
    sent = time.monotonic()
    proc.send_signal(signum)
    out, err = proc.communicate(timeout=180)
    took = time.monotonic() - sent
    _stopped_cleanly(proc, "".join(said) + err, 128 + signum, "interrupted" if signum == signal.SIGINT
                     else "terminated (SIGTERM)")
    assert took < 3.0, took  # not the rest of the compile
    deadline = time.monotonic() + 5.0  # the compiling process sees its parent gone within a second
    while process_group(proc.pid) and time.monotonic() < deadline:
        time.sleep(0.1)
    assert process_group(proc.pid) == []


def test_a_command_without_a_viewer_does_not_import_rerun_to_end():
    """The exit closes viewers only where the command opened one: importing the view there would
    import Rerun, which a Ctrl-C may have left half imported (a traceback after 'interrupted')."""
    code = ("import sys; from mavattitude.cli import main; code = main(['info', sys.argv[1]]); "
            "print(code, 'mavattitude.view.sink' in sys.modules, 'rerun' in sys.modules)")
    run = subprocess.run([sys.executable, "-c", code, str(SAMPLE_LOGS / "static.bin")], capture_output=True,
                         text=True, timeout=120)
    assert run.stdout.split()[-3:] == ["0", "False", "False"], run.stdout + run.stderr


def test_live_without_a_viewer_does_not_import_rerun():
    """``live --no-record`` imports the view's sink module (to know where a view would go) but
    not the view: Rerun's import swallows a Ctrl-C that lands in it (a RerunWarning, and the
    session went on compiling)."""
    code = ("import sys; import mavattitude.live.session; from mavattitude.cli.live import add_parser; "
            "print('mavattitude.view.sink' in sys.modules, 'rerun' in sys.modules)")
    run = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert run.stdout.split()[-2:] == ["True", "False"], run.stdout + run.stderr


def _swallowing_a_sigterm(*args, **kwargs):
    """What pymavlink's ``mavextra`` does with a signal during its import of quaternions
    (``try: ... except: pass``): the KeyboardInterrupt is caught and the work goes on."""
    try:
        os.kill(os.getpid(), signal.SIGTERM)
        time.sleep(1.0)  # the handler raises here
    except BaseException:
        pass


def test_a_stop_that_something_swallowed_still_ends_the_command_and_commits_nothing(tmp_path, capsys,
                                                                                     monkeypatch):
    """Found on CI: a SIGTERM landed in pymavlink's import inside the tlog reader, was caught by
    its bare ``except``, and the replay ran to the end with exit 0. The signal is noted before
    it is raised: the next progress report raises it again, and no output is put in place."""
    from mavattitude.readers import tlog

    collect_events = tlog._collect_events

    def reading(*args, **kwargs):
        _swallowing_a_sigterm()
        return collect_events(*args, **kwargs)
    monkeypatch.setattr(tlog, "_collect_events", reading)
    code, out, err = run(capsys, "replay", SAMPLE_LOGS / "figure8.tlog", "--estimators", "mahony", "--no-view",
                         "--json", tmp_path / "m.json")
    assert code == 143 and one_line(err) == "terminated (SIGTERM)"
    assert list(tmp_path.iterdir()) == []


def _dropping_a_sigint():
    """What Python does with a signal that lands in a weakref callback (seen on CI: importlib's
    module-lock callback, in an import of the command's first second): the KeyboardInterrupt is
    reported ("Exception ignored in ...", with a traceback) and dropped, and the work goes on."""
    import weakref

    class Held:
        pass

    def callback(ref):
        os.kill(os.getpid(), signal.SIGINT)
        time.sleep(1.0)  # the handler raises here, in the callback

    held = Held()
    ref = weakref.ref(held, callback)
    del held  # the callback runs now
    return ref


def test_a_stop_that_python_dropped_ends_the_command_as_a_stop(capsys, monkeypatch):
    """The command reports no progress and writes nothing after it: it ends with 130 and its one
    line when it returns, and the dropped exception is not reported."""
    from mavattitude.cli import estimators

    list_them = estimators.run

    def listing(args):
        _dropping_a_sigint()
        return list_them(args)
    monkeypatch.setattr(estimators, "run", listing)
    code, out, err = run(capsys, "estimators")
    assert code == 130 and one_line(err) == "interrupted"
    assert "Exception ignored" not in err and "Traceback" not in err


def test_outputs_are_not_committed_after_a_swallowed_stop(tmp_path):
    from mavattitude import signals
    from mavattitude.outputs import Outputs

    previous = signals.install()
    try:
        with pytest.raises(KeyboardInterrupt):
            with Outputs() as outputs:
                out = outputs.file(tmp_path / "m.json", "--json", "json")
                out.write_path.write_text("{}")
                _swallowing_a_sigterm()
        assert signals.exit_code() == 143
    finally:
        signals.restore(previous)
    assert list(tmp_path.iterdir()) == []
    assert signals.received() is None  # forgotten with the handlers


def test_an_interrupt_swallowed_by_the_code_it_landed_in_is_raised_after_it():
    """What Rerun's import does with a Ctrl-C (an exception while it builds its classes becomes a
    warning): ``holding_interrupts`` raises it once the block is over, as the command's own."""
    from mavattitude import signals

    previous = signals.install()
    try:
        with pytest.raises(KeyboardInterrupt):
            with signals.holding_interrupts():
                try:
                    os.kill(os.getpid(), signal.SIGINT)
                    time.sleep(1.0)  # the signal arrives here
                except KeyboardInterrupt:
                    pass  # swallowed
        assert signals.received() == signal.SIGINT
    finally:
        signals.restore(previous)


@pytest.mark.slow  # a replay in a process of its own: seconds, kept out of the quick loop
def test_replay_to_a_file_imports_rerun_only_once_estimated(tmp_path):
    """An .rrd is checked and made before the read (``plan_sink``); Rerun (57 MB imported) is
    opened for it only when there is a recording to write, not held through the estimation."""
    code = ("import sys; import mavattitude.commands.replay as r; inner = r.replay_flight\n"
            "def seen(*a, **k):\n    print('rerun before', 'rerun' in sys.modules); return inner(*a, **k)\n"
            "r.replay_flight = seen\nfrom mavattitude.cli import main\n"
            "code = main(['replay', sys.argv[1], '--estimators', 'mahony', '--rrd', sys.argv[2], '-q'])\n"
            "print('code', code, 'rerun after', 'rerun' in sys.modules)")
    out = tmp_path / "x.rrd"
    run = subprocess.run([sys.executable, "-c", code, str(SAMPLE_LOGS / "static.bin"), str(out)],
                         capture_output=True, text=True, timeout=180)
    assert "rerun before False" in run.stdout and "code 0 rerun after True" in run.stdout, run.stdout + run.stderr
    assert out.stat().st_size > 0
