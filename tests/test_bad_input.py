"""Bad options, damaged files, unreachable viewers: one line and an exit status, never a
traceback, a hang or a user's log lost (issue 16). The README's "When something is wrong"
table is this file's list of cases."""
from __future__ import annotations

import math
import os
import random
import shutil
import signal
import socket
import subprocess
import sys
import threading
import time
import warnings
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from conftest import SAMPLE_LOGS, SHARED_LOGS, installed_estimators, one_line, run
from mavattitude.errors import InputError
from mavattitude.estimators import ESTIMATORS, create
from mavattitude.core.params import describe
from mavattitude.readers import read_log
from mavattitude.readers.dfrecords import open_log, scan_log
from mavattitude.sim import simulate, write_log

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "scripts"))
from fuzz_logs import KINDS, mutate, replay_or_error  # noqa: E402

LOG = SAMPLE_LOGS / "static.bin"




@pytest.fixture
def victim(tmp_path):
    """A copy of a sample log that a test may try to destroy."""
    path = tmp_path / "victim.bin"
    shutil.copy(LOG, path)
    return path


# ---------------------------------------------------------------- 1. outputs never overwrite an input


@pytest.mark.parametrize("option", ["--rrd", "--json"])
def test_an_output_never_replaces_the_input_log(capsys, victim, option):
    before = victim.read_bytes()
    code, _, err = run(capsys, "replay", victim, option, victim, "--force")
    assert code == 1 and "would write over the input" in one_line(err)
    assert victim.read_bytes() == before


def test_an_output_never_replaces_the_parameter_file(capsys, tmp_path):
    params = tmp_path / "p.toml"
    params.write_text("[mahony]\nkp = 0.3\n")
    code, _, err = run(capsys, "replay", LOG, "--params", params, "--json", params, "--no-view")
    assert code == 1 and "would write over the input" in one_line(err)
    assert params.read_text() == "[mahony]\nkp = 0.3\n"


def test_a_file_of_another_kind_needs_force(capsys, tmp_path):
    notes = tmp_path / "notes.txt"
    notes.write_text("my flight notes\n")
    code, _, err = run(capsys, "replay", LOG, "--rrd", notes)
    assert code == 1 and "is not a Rerun recording" in one_line(err) and "--force" in err
    assert notes.read_text() == "my flight notes\n"
    assert not list(tmp_path.glob(".*partial"))  # nothing left behind
    code, _, err = run(capsys, "replay", LOG, "--rrd", notes, "--force")
    assert code == 0, err and notes.read_bytes()[:3] == b"RRF"


def test_an_output_of_its_own_kind_is_replaced(capsys, tmp_path):
    rrd, js = tmp_path / "a.rrd", tmp_path / "m.json"
    for _ in range(2):
        code, _, err = run(capsys, "replay", LOG, "--rrd", rrd, "--json", js)
        assert code == 0, err
    assert rrd.read_bytes()[:3] == b"RRF" and js.read_text().startswith("{")
    assert oct(rrd.stat().st_mode & 0o777) == oct(0o666 & ~_umask())  # as any new file


def _umask() -> int:
    mask = os.umask(0)
    os.umask(mask)
    return mask


def test_two_outputs_on_one_path_are_refused(capsys, tmp_path):
    code, _, err = run(capsys, "replay", LOG, "--rrd", tmp_path / "x", "--json", tmp_path / "x")
    assert code == 1 and "named by both --json and --rrd" in one_line(err)


def test_simulate_never_writes_over_a_flight_log(capsys, tmp_path):
    real = tmp_path / "flight.bin"
    real.write_bytes(b"\xa3\x95\x80" + bytes(200))  # a log not made by the simulator
    code, _, err = run(capsys, "simulate", "--duration", "5", "-o", real)
    assert code == 1 and "a flight log the simulator did not write" in one_line(err)
    sim = tmp_path / "sim.bin"
    for _ in range(2):  # its own output it replaces
        code, _, err = run(capsys, "simulate", "--duration", "5", "-o", sim)
        assert code == 0, err


def test_a_live_recording_never_replaces_a_file(capsys, tmp_path):
    existing = tmp_path / "old.tlog"
    existing.write_bytes(b"precious")
    code, _, err = run(capsys, "live", "udpin:127.0.0.1:9", "--record", existing, "--duration", "0.2")
    assert code == 1 and "never writes over a file" in one_line(err)
    assert existing.read_bytes() == b"precious"


# ---------------------------------------------------------------- 2. outputs and endpoints, checked first


@pytest.fixture
def no_reading(monkeypatch):
    """Fails the test if the log is read: the option must be refused before."""
    from mavattitude.cli import info, replay

    def refuse(*args, **kwargs):
        raise AssertionError("the log was read before a bad option was refused")
    for command in (info, replay):  # the commands that read one log here
        monkeypatch.setattr(command, "read_log_file", refuse)


def test_missing_folders_are_created(capsys, tmp_path):
    rrd = tmp_path / "no" / "such" / "dir" / "x.rrd"
    js = tmp_path / "other" / "m.json"
    code, _, err = run(capsys, "replay", LOG, "--rrd", rrd, "--json", js)
    assert code == 0, err
    assert rrd.read_bytes()[:3] == b"RRF" and js.exists()


@pytest.mark.parametrize("target, text", [
    ("afile/x.rrd", "not a folder"),
    ("adir", "names a folder"),
    ("/proc/x.rrd", "cannot create a file here"),
])
def test_an_rrd_that_cannot_be_written_fails_before_the_replay(capsys, tmp_path, no_reading, target, text):
    if target.startswith("/proc") and not os.path.isdir("/proc"):
        pytest.skip("no /proc on this system")
    (tmp_path / "afile").write_text("x")
    (tmp_path / "adir").mkdir()
    path = target if target.startswith("/") else tmp_path / target
    code, _, err = run(capsys, "replay", LOG, "--rrd", path)
    assert code == 1 and text in one_line(err)


@pytest.mark.parametrize("option", ["--rrd", "--json"])
def test_a_full_disk_is_one_line(capsys, option):
    if not os.path.exists("/dev/full"):
        pytest.skip("no /dev/full on this system")
    code, _, err = run(capsys, "replay", LOG, option, "/dev/full", *(["--no-view"] if option == "--json" else []))
    assert code == 1 and "/dev/full" in one_line(err) and "No space left" in err


@pytest.mark.parametrize("target", ["a-file", "/dev/full"])
def test_export_to_a_file_is_refused(capsys, tmp_path, no_reading, target):
    (tmp_path / "a-file").write_text("x")
    path = target if target.startswith("/") else tmp_path / target
    if not os.path.exists(path):
        pytest.skip(f"no {path} on this system")
    code, _, err = run(capsys, "replay", LOG, "--export", path, "--no-view")
    assert code == 1 and "not a folder" in one_line(err)


def test_a_malformed_viewer_url_is_a_usage_error(capsys, no_reading):
    code, _, err = run(capsys, "replay", LOG, "--connect", "bogus")
    assert code == 2 and "expected a Rerun URL" in one_line(err)


def test_a_viewer_that_is_not_there_fails_at_once(capsys, no_reading):
    port = _closed_port()
    start = time.monotonic()
    code, _, err = run(capsys, "replay", LOG, "--connect", f"rerun+http://127.0.0.1:{port}/proxy")
    assert code == 1 and "no Rerun viewer answers there" in one_line(err)
    assert time.monotonic() - start < 10


def test_spawn_without_a_display_fails_at_once(capsys, monkeypatch, no_reading):
    monkeypatch.delenv("DISPLAY", raising=False)
    monkeypatch.delenv("WAYLAND_DISPLAY", raising=False)
    # the viewer installed beside this Python, as an activated environment has it on PATH
    monkeypatch.setenv("PATH", os.pathsep.join([str(Path(sys.executable).parent), os.environ.get("PATH", "")]))
    if not sys.platform.startswith("linux"):
        pytest.skip("the display check is for Linux")
    code, _, err = run(capsys, "replay", LOG, "--spawn")
    assert code == 1 and "no display" in one_line(err)


def test_web_ports_in_use_move_to_free_ones(capsys):
    from mavattitude.view.sink import DEFAULT_GRPC_PORT, DEFAULT_WEB_PORT, plan_sink

    held = []
    for port in (DEFAULT_WEB_PORT, DEFAULT_GRPC_PORT):
        s = socket.socket()
        try:
            s.bind(("0.0.0.0", port))
            s.listen()
            held.append(s)
        except OSError:
            s.close()  # already taken by someone else: taken all the same
    try:
        sink = plan_sink("web", None)
        assert sink.web_port != DEFAULT_WEB_PORT and sink.grpc_port != DEFAULT_GRPC_PORT
        assert sink.web_port != sink.grpc_port
        assert "is in use" in capsys.readouterr().err
    finally:
        for s in held:
            s.close()


def _closed_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


# ---------------------------------------------------------------- 3. a viewer that stops answering


class BlackHole:
    """A TCP server that accepts and never answers: a viewer that hung."""

    def __init__(self):
        self.sock = socket.socket()
        self.sock.bind(("127.0.0.1", 0))
        self.sock.listen(8)
        self.port = self.sock.getsockname()[1]
        self.conns = []
        threading.Thread(target=self._accept, daemon=True).start()

    def _accept(self):
        try:
            while True:
                self.conns.append(self.sock.accept()[0])
        except OSError:
            pass

    def close(self):
        for c in self.conns:
            c.close()
        self.sock.close()


def _cli_process(args, timeouts="FLUSH_TIMEOUT_S=3; s.SHUTDOWN_TIMEOUT_S=2", mark=None):
    """The command in a child process, with the sink's timeouts set; ``mark``: a file the child
    creates as it begins to wait for the viewer to take the recording (``close_sink``)."""
    code = f"import sys; import mavattitude.view.sink as s; s.{timeouts}\n"
    if mark is not None:
        code += ("close = s.close_sink\n"
                 "def marked(*args, **kwargs):\n"
                 f"    open({str(mark)!r}, 'w').close()\n"
                 "    return close(*args, **kwargs)\n"
                 "s.close_sink = marked\n")
    code += f"from mavattitude.cli import main; sys.exit(main({[str(a) for a in args]!r}))"
    # Ctrl-C as a terminal delivers it: a test run started as a background job (`cmd &` in a
    # script, some CI runners) ignores SIGINT, and its children inherit that
    return subprocess.Popen([sys.executable, "-c", code], stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                            text=True, preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL))


@pytest.mark.slow
def test_a_viewer_that_hangs_costs_a_bounded_wait():
    hole = BlackHole()
    try:
        start = time.monotonic()
        proc = _cli_process(["replay", LOG, "--connect", f"rerun+http://127.0.0.1:{hole.port}/proxy"],
                            timeouts="FLUSH_TIMEOUT_S=1; s.SHUTDOWN_TIMEOUT_S=1")
        _, err = proc.communicate(timeout=60)
        assert proc.returncode == 1 and "did not take the recording within 1 s" in err and "Traceback" not in err
        assert time.monotonic() - start < 25
    finally:
        hole.close()


@pytest.mark.slow
def test_ctrl_c_works_while_a_viewer_hangs(tmp_path):
    """Ctrl-C during the (10 min) wait for a viewer that takes nothing: sent once the command is
    in that wait, whatever the machine's load made of the time it took to get there."""
    hole = BlackHole()
    mark = tmp_path / "waiting"
    try:
        proc = _cli_process(["replay", LOG, "--connect", f"rerun+http://127.0.0.1:{hole.port}/proxy"],
                            timeouts="FLUSH_TIMEOUT_S=600; s.SHUTDOWN_TIMEOUT_S=2", mark=mark)
        deadline = time.monotonic() + 120
        while not mark.exists():
            assert proc.poll() is None and time.monotonic() < deadline, proc.communicate()
            time.sleep(0.05)
        time.sleep(1.5)  # well into the wait: past its first 1 s step
        proc.send_signal(signal.SIGINT)
        start = time.monotonic()
        _, err = proc.communicate(timeout=30)
        assert proc.returncode == 130 and "interrupted" in err and "Traceback" not in err
        assert time.monotonic() - start < 15
    finally:
        hole.close()


# ---------------------------------------------------------------- 4. damaged logs


def damaged_logs():
    """(name, path) of logs to damage: a sample log always, shared real logs where present."""
    logs = [pytest.param(LOG, id="sample-static.bin")]
    for name in ("copter-3.3-loiter-rtl.bin", "corpus/real-copter-4.5.7-pixhawk6x-tipover-quiver088.bin"):
        if (SHARED_LOGS / name).exists():
            logs.append(pytest.param(SHARED_LOGS / name, id=name.split("/")[-1]))
    return logs


def _imu_span(flight) -> float:
    imu = flight.imu["IMU[0]"]
    return float(imu.t[-1] - imu.t[0])


@pytest.mark.parametrize("log", damaged_logs())
def test_an_unknown_record_type_loses_a_record_not_the_log(capsys, tmp_path, log):
    data = bytearray(log.read_bytes())
    scan = scan_log(open_log(str(log)), ["IMU"])
    hit = int(scan.offsets["IMU"][len(scan.offsets["IMU"]) // 10])  # 10 % into the flight
    data[hit + 2] = 0xFE  # a type no FMT defines: pymavlink stops reading here
    bad = tmp_path / "damaged.bin"
    bad.write_bytes(bytes(data))
    whole, damaged = read_log(str(log)), read_log(str(bad))
    assert _imu_span(damaged) >= 0.99 * _imu_span(whole)
    assert len(damaged.imu["IMU[0]"].t) == len(whole.imu["IMU[0]"].t) - 1
    assert any("skipped" in w and "corrupt data" in w for w in damaged.warnings)
    code, out, _ = run(capsys, "info", bad)  # said on screen, in info ...
    assert code == 0 and "warning: skipped" in out
    code, _, err = run(capsys, "replay", bad, "--no-view")  # ... as in replay
    assert code == 0 and "warning: skipped" in err


@pytest.mark.parametrize("log", damaged_logs())
def test_a_corrupt_time_is_not_a_reboot(tmp_path, log):
    data = bytearray(log.read_bytes())
    scan = scan_log(open_log(str(log)), ["IMU"])
    fmt = next(f for f in scan.formats.values() if f.name == "IMU")
    column = "TimeUS" if "TimeUS" in fmt.columns else "TimeMS"
    field = fmt.dtype().fields[column]
    offsets = scan.offsets["IMU"]
    for k, shift in ((len(offsets) // 2, -100.0), (len(offsets) // 3, 4.0)):  # back 100 s, ahead 4 s
        at = int(offsets[k]) + 3 + field[1]
        value = np.frombuffer(bytes(data[at:at + field[0].itemsize]), field[0])[0]
        scale = 1e6 if column == "TimeUS" else 1e3
        data[at:at + field[0].itemsize] = np.array([value + shift * scale], field[0]).tobytes()
    bad = tmp_path / "time.bin"
    bad.write_bytes(bytes(data))
    whole, damaged = read_log(str(log)), read_log(str(bad))
    assert len(damaged.segments) == len(whole.segments) == 1
    assert _imu_span(damaged) == pytest.approx(_imu_span(whole))
    assert any("dropped 2 samples whose time fits neither" in w for w in damaged.warnings)


def test_imu_data_that_is_all_rejected_is_named(tmp_path):
    sim = simulate("static", 10.0, seed=1, imu_rate=50.0)
    dead = [replace(track, gyro=np.zeros_like(track.gyro), accel=np.zeros_like(track.accel)) for track in sim.imu]
    path = write_log(replace(sim, imu=dead), tmp_path / "dead.bin")
    with pytest.raises(InputError, match=r"IMU data present but none usable: IMU\[0\]: 500 samples, all zeros"):
        read_log(str(path))
    wild = [replace(track, accel=np.full_like(track.accel, 1e4)) for track in sim.imu]
    path = write_log(replace(sim, imu=wild), tmp_path / "wild.bin")
    with pytest.raises(InputError, match="none within ±50 rad/s and ±50 g"):
        read_log(str(path))


def test_nan_samples_are_dropped_without_numpy_warnings(capfd, tmp_path):
    """NaN and infinite floats where a log has floats: the .bin IMU and the .tlog ATTITUDE."""
    sim = simulate("figure8", 20.0, seed=2, imu_rate=50.0)
    imu = sim.imu[0]
    gyro, accel, att = imu.gyro.copy(), imu.accel.copy(), sim.autopilot_q.copy()
    gyro[100:110] = np.nan
    accel[200, 2] = np.inf
    att[300:320] = np.nan
    damaged = {".bin": replace(sim, imu=[replace(imu, gyro=gyro, accel=accel), *sim.imu[1:]]),
               ".tlog": replace(sim, autopilot_q=att)}  # RAW_IMU holds integers: no NaN there
    for suffix, flight_with_nans in damaged.items():
        path = write_log(flight_with_nans, tmp_path / f"nan{suffix}")
        with warnings.catch_warnings():
            warnings.simplefilter("error", RuntimeWarning)
            flight = read_log(str(path))
            assert replay_or_error(path, ("mahony", "ekf", "cpf-ekf")) == "read"
        for series in flight.imu.values():
            assert np.isfinite(series.gyro).all() and np.isfinite(series.accel).all()
        assert np.isfinite(flight.attitude.q).all()
        if suffix == ".bin":
            assert any("IMU[0]: dropped 11 samples with impossible values" in w for w in flight.warnings)
    assert "RuntimeWarning" not in capfd.readouterr().err


# ---------------------------------------------------------------- fuzz: truncations, flips, FMT damage

FUZZ_CASES = 2 * len(KINDS) + 2  # per log, each kind of damage twice; scripts/fuzz_logs.py runs thousands


def fuzz_logs():
    logs = [pytest.param(SAMPLE_LOGS / "figure8.bin", id="figure8.bin"),
            pytest.param(SAMPLE_LOGS / "hover.tlog", id="hover.tlog")]
    for name in ("copter-3.3-loiter-rtl.bin", "copter-4.1-flight.tlog", "ulog/px4-sitl-events-31s.ulg"):
        if (SHARED_LOGS / name).exists():
            logs.append(pytest.param(SHARED_LOGS / name, id=name.split("/")[-1], marks=pytest.mark.slow))
    return logs


@pytest.mark.parametrize("log", fuzz_logs())
def test_fuzzed_logs_read_or_fail_cleanly(tmp_path, log):
    data = log.read_bytes()
    rng = random.Random(log.name)
    outcomes = []
    with warnings.catch_warnings():
        warnings.simplefilter("error", RuntimeWarning)  # numpy must not complain about corrupt data
        for case in range(FUZZ_CASES):
            path = tmp_path / f"case{case}{log.suffix}"
            path.write_bytes(mutate(data, rng, KINDS[case % len(KINDS)]))
            outcomes.append(replay_or_error(path))  # raises on anything but InputError
    assert outcomes.count("read") >= FUZZ_CASES // 2  # damage costs data, not the log


# ---------------------------------------------------------------- 5. values that mean nothing


@pytest.mark.parametrize("args, text", [
    (["--warmup", "nan"], "argument --warmup"),
    (["--warmup", "inf"], "argument --warmup"),
    (["--warmup", "-1"], "argument --warmup"),
    (["--declination", "nan"], "argument --declination"),
    (["--declination", "400"], "argument --declination"),
    (["--segment", "-1"], "argument --segment"),
    (["--set", "mahony.kp=-5"], "mahony.kp = -5 is outside its valid range [0, 1e6]"),
    (["--set", "mahony.kp=nan"], "expected a finite number"),
    (["--estimators", "ekf", "--set", "ekf.r_accel=-1"], "ekf.r_accel = -1 is outside its valid range [1e-12, 1e6]"),
    (["--estimators", "ekf", "--set", "ekf.r_accel=0"], "outside its valid range [1e-12, 1e6]"),
    (["--estimators", "eq-kf", "--set", "eq-kf.norm_lo=0.3"], "eq-kf.norm_lo (0.3) must be below eq-kf.norm_hi"),
    (["--estimators", "cpf-ekf", "--set", "cpf-ekf.reset_cycles=0"], "outside its valid range [1, inf)"),
])
def test_meaningless_values_are_usage_errors(capsys, args, text):
    code, _, err = run(capsys, "replay", LOG, "--no-view", *args)
    assert code == 2 and text in one_line(err)


@pytest.mark.parametrize("body, text", [
    ("[mahony\nkp = 1\n", "not valid TOML"),
    ("[mahony]\nkp = \"fast\"\n", "mahony.kp: expected a finite number"),
    ("[mahony]\nkp = -1.0\n", "outside its valid range"),
    ("[nope]\nkp = 1\n", "unknown estimator 'nope'"),
])
def test_a_bad_parameter_file_is_an_input_error_naming_it(capsys, tmp_path, body, text):
    path = tmp_path / "p.toml"
    path.write_text(body)
    code, _, err = run(capsys, "replay", LOG, "--no-view", "--params", path)
    line = one_line(err)
    assert code == 1 and str(path) in line and text in line


def interval_values(valid, default, decades: bool = False) -> list:
    """Each end of a parameter's interval (the next float inside an open end, the largest float
    below an unbounded one) and, with ``decades``, every power of ten 1e-300 ... 1e300 inside."""
    low = valid.lo if valid.lo_closed else math.nextafter(valid.lo, math.inf)
    high = valid.hi if valid.hi_closed else math.nextafter(valid.hi, -math.inf)
    values = [low, high] + ([10.0 ** k for k in range(-300, 301, 10) if 10.0 ** k in valid] if decades else [])
    if isinstance(default, int):
        values = [v for v in values if v < 2**62]  # the kernels take int64
        values = sorted({int(math.ceil(low)), int(min(high, 2**62))} | {int(v) for v in values if v >= 1})
    return values


def check_every_value_runs(decades: bool) -> None:
    import simtruth

    sim = simtruth.flight("figure8", 12.0, seed=5, imu_rate=50.0)
    for name in installed_estimators():
        cls = ESTIMATORS[name]
        runner = simtruth.run_aided if cls.uses_aiding else simtruth.run
        for field, default, valid, _ in describe(cls.Params):
            if valid is None:
                values = [not default]
            else:
                assert default in valid
                values = interval_values(valid, default, decades)
            for value in values:
                params = replace(cls.Params(), **{field: value})
                with warnings.catch_warnings():
                    warnings.simplefilter("error")  # an overflow in numpy is no "works" either
                    q, _ = runner(name, sim, params)
                norm = np.linalg.norm(q, axis=1)
                assert np.all(np.abs(norm - 1.0) < 1e-6), f"{name}.{field} = {value}"


def test_every_parameter_default_is_valid_and_every_valid_edge_runs():
    """Each end of every parameter's interval (the next float inside an open one, the largest
    float below infinity) gives finite unit quaternions on a short simulated flight, without
    an exception or a numpy warning: a value the CLI accepts works (ekf.r_accel=1e-308 was a
    ZeroDivisionError, eskf.gyro_arw=1e300 an OverflowError)."""
    check_every_value_runs(decades=False)


@pytest.mark.slow
def test_every_decade_inside_every_parameter_interval_runs():
    check_every_value_runs(decades=True)


# ---------------------------------------------------------------- 6. smaller


@pytest.mark.parametrize("args, code", [
    (["replay", LOG, "--segment", "99", "--no-view"], 1),  # the log does not have it
    (["replay", LOG, "--imu", "IMU[7]", "--no-view"], 1),
    (["replay", LOG, "--reference", "truth", "--no-view"], 0),  # the simulator's log has truth
    (["replay", LOG, "--imu-rate", "5"], 2),  # no such option
    (["replay", LOG, "--no-view", "--set", "mahony.kp=x"], 2),
])
def test_exit_codes_follow_one_rule(capsys, args, code):
    got, _, err = run(capsys, *args)
    assert got == code, err
    if code:
        one_line(err)


def test_a_closed_pipe_is_not_an_error():
    proc = subprocess.Popen([sys.executable, "-m", "mavattitude", "estimators"], stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE)
    proc.stdout.readline()
    proc.stdout.close()  # as `| head -1` does
    err = proc.stderr.read().decode()
    assert proc.wait(timeout=60) == 141 and err == ""


def test_a_log_shorter_than_the_warmup_says_nothing_was_scored(capsys, tmp_path):
    path = write_log(simulate("static", 8.0, seed=1, imu_rate=50.0), tmp_path / "short.bin")
    code, out, err = run(capsys, "replay", path, "--no-view")
    assert code == 0 and "nothing scored" in err and "--warmup" in err


def test_update_before_initialize_says_so():
    for name in installed_estimators():
        with pytest.raises(RuntimeError, match=rf"{name}: call initialize\(q0, gyro_bias\) before update"):
            create(name).update(np.zeros(2), np.zeros((2, 3)), np.zeros((2, 3)), None)


def test_a_ulog_topic_whose_format_lost_its_timestamp_is_a_warning(tmp_path):
    """A damaged format definition can leave a topic without its timestamp field: that topic is
    left out with a warning, not a KeyError (found by scripts/fuzz_logs.py --seed 6 --case 149)."""
    from conftest import shared_log

    source = shared_log("ulog/px4-sitl-events-31s.ulg")
    path = tmp_path / "case.ulg"
    path.write_bytes(mutate(source.read_bytes(), random.Random(6 * 1_000_003 + 149)))
    assert replay_or_error(path, ["mahony"]) in ("read", "error")
