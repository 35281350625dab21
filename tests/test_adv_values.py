"""Values an adversarial tester gave the command line, parameters and outputs (issue 23,
point 8, "values" and "messages"): each is one line and its exit status, or works."""
from __future__ import annotations

import argparse
import math
import re
from dataclasses import replace

import pytest

from conftest import SAMPLE_LOGS, one_line, run
from mavattitude.cli import build_parser

LOG = SAMPLE_LOGS / "static.bin"
POSITIONALS = {"info": [LOG], "replay": [LOG], "evaluate": [LOG], "tune": [LOG, "--estimator", "mahony"]}




def options_with_values():
    """(command, action) for every option of every subcommand that takes a value."""
    parser = build_parser()
    commands = next(a for a in parser._actions if isinstance(a, argparse._SubParsersAction)).choices
    return [(command, action) for command, sub in commands.items() for action in sub._actions
            if action.option_strings and action.nargs is None and not isinstance(
                action, (argparse._StoreConstAction, argparse._HelpAction, argparse._VersionAction))]


def numeric_options():
    return [pytest.param(c, a, id=f"{c} {a.option_strings[-1]}") for c, a in options_with_values()
            if getattr(a.type, "__name__", "") == "number"]


def test_every_numeric_option_is_found():
    assert len(numeric_options()) >= 31  # the tester's count; new ones join by themselves


@pytest.mark.parametrize("command, action", numeric_options())
def test_a_dash_dash_value_is_checked_like_any_other(capsys, command, action):
    """argparse without CPython's gh-109475 fix took '--' after '=' for the separator and
    skipped the option's type: bench --seed=-- started a full benchmark."""
    option = action.option_strings[-1]
    code, _, err = run(capsys, command, *POSITIONALS.get(command, []), f"{option}=--")
    line = one_line(err)
    assert code == 2 and f"argument {'/'.join(action.option_strings)}: expected" in line and "'--'" in line


def test_no_option_is_left_without_a_value():
    """Every option given '--' holds '--' (then checked as any string) or is refused."""
    parser = build_parser()
    for command, action in options_with_values():
        option = action.option_strings[-1]
        try:
            args = parser.parse_args([command, *map(str, POSITIONALS.get(command, [])), f"{option}=--"])
        except SystemExit as exc:
            assert exc.code == 2
            continue
        value = getattr(args, action.dest)
        assert value == "--" or value == ["--"], f"{command} {option}: {value!r}"


# ---------------------------------------------------------------- simulate and bench: what can be made


@pytest.mark.parametrize("args, text", [
    (["simulate", "--duration", "0.1", "-o", "x.bin"], "0.1 s is too short: every sensor needs two samples, "
                                                        "which takes 0.4 s"),
    (["simulate", "--duration", "1e308", "-o", "x.bin"], "at most 36000 s at that rate"),
    (["simulate", "--imu-rate", "1e9", "-o", "x.tlog"], "above the simulator's 10000 Hz"),
    (["simulate", "--imu-rate", "0.01", "-o", "x.bin"], "which takes 200 s at these rates"),
    (["simulate", "--duration", "3600", "--imu-rate", "1000.5", "-o", "x.ulg"], "3,600,000 IMU samples"),
    (["simulate", "--live", "udpout:127.0.0.1:9", "--duration", "1e308"], "at most 36000 s"),
    (["bench", "--duration", "1e308"], "at most 9000 s at that rate"),
    (["bench", "--read", "--imu-rate", "1e9"], "above the simulator's 10000 Hz"),
    (["bench", "--live", "--live-seconds", "1e300"], "--live-seconds plus 3 s of settling"),
])
def test_a_flight_the_simulator_cannot_make_is_a_usage_error(capsys, tmp_path, monkeypatch, args, text):
    monkeypatch.chdir(tmp_path)
    code, _, err = run(capsys, *args)
    assert code == 2 and text in one_line(err)
    assert not list(tmp_path.iterdir())  # refused before anything was written


def test_the_shortest_flight_is_made(capsys, tmp_path):
    code, out, err = run(capsys, "simulate", "--duration", "0.4", "-o", tmp_path / "short.bin")
    assert code == 0, err
    code, _, err = run(capsys, "simulate", "--duration", "0.39", "-o", tmp_path / "shorter.bin")
    assert code == 2 and "too short" in one_line(err)


def test_the_longest_flight_is_the_limit_exactly():
    from mavattitude.sim import Rates, simulate
    from mavattitude.sim.simflight import MAX_IMU_RATE_HZ, MAX_IMU_SAMPLES, check_length

    check_length(MAX_IMU_SAMPLES / 400.0, Rates(imu=400.0))
    check_length(1.0, Rates(imu=MAX_IMU_RATE_HZ))
    with pytest.raises(ValueError, match="at most 9000 s"):
        check_length(MAX_IMU_SAMPLES / 400.0 * (1 + 1e-12), Rates(imu=400.0))
    with pytest.raises(ValueError, match="above the simulator's"):
        simulate("figure8", 1.0, imu_rate=MAX_IMU_RATE_HZ * 1.001)
    with pytest.raises(ValueError, match="a finite number of seconds, not inf"):
        simulate("figure8", math.inf)


# ---------------------------------------------------------------- parameter values the estimators cannot take


@pytest.mark.parametrize("setting, text", [
    ("ekf.r_accel=1e-308", "ekf.r_accel = 1e-308 is outside its valid range [1e-12, 1e6]"),
    ("eskf.accel_noise=1e-300", "eskf.accel_noise = 1e-300 is outside its valid range [1e-6, 1e6]"),
    ("mahony-ekf.r0=1e-320", "mahony-ekf.r0 = 9.99989e-321 is outside its valid range [1e-12, 1e6]"),
    ("eskf.gyro_arw=1e300", "eskf.gyro_arw = 1e+300 is outside its valid range (0, 1000]"),
])
def test_values_the_estimators_cannot_take_are_outside_their_interval(capsys, setting, text):
    """(Every value inside works: test_bad_input's edge and decade runs.)"""
    name = setting.partition(".")[0]
    code, _, err = run(capsys, "replay", LOG, "--no-view", "--estimators", name, "--set", setting)
    assert code == 2 and text in one_line(err)


# ---------------------------------------------------------------- files


def deep_toml(path):
    path.write_text("[mahony]\nkp = " + "[" * 5000 + "]" * 5000 + "\n")
    return path


def test_a_deeply_nested_parameter_file_is_one_line_naming_it(capsys, tmp_path):
    path = deep_toml(tmp_path / "deep.toml")
    code, _, err = run(capsys, "replay", LOG, "--no-view", "--params", path)
    line = one_line(err)
    assert code == 1 and str(path) in line and "nest too deeply" in line


def test_a_deeply_nested_file_is_no_parameter_file_to_write_over(capsys, tmp_path):
    path = deep_toml(tmp_path / "deep.toml")
    code, _, err = run(capsys, "tune", LOG, "--estimator", "mahony", "-o", path)
    assert code == 1 and "is not a TOML file written by mavattitude tune" in one_line(err)


# ---------------------------------------------------------------- --set and --params for estimators not run


@pytest.mark.parametrize("args, code, text", [
    (["--set", "ekf.bogus=1"], 2, "ekf is not among the estimators run (mahony): --set ekf.… would do nothing"),
    (["--set", "ekf.r_accel=0.5"], 2, "ekf is not among the estimators run (mahony)"),
    (["--estimators", "ekf", "--set", "ekf.bogus=1"], 2, "ekf has no parameter 'bogus'"),
    (["--set", "nope.x=1"], 2, "unknown estimator 'nope'"),
])
def test_set_is_checked_for_every_estimator(capsys, args, code, text):
    got, _, err = run(capsys, "replay", LOG, "--no-view", *args)
    assert got == code and text in one_line(err)


def test_a_file_table_for_an_estimator_not_run_is_checked_but_allowed(capsys, tmp_path):
    """One file may hold every estimator's parameters; each value in it is checked."""
    path = tmp_path / "p.toml"
    path.write_text("[ekf]\nr_accel = 1e-300\n")
    code, _, err = run(capsys, "replay", LOG, "--no-view", "--params", path)
    assert code == 1 and "ekf.r_accel = 1e-300 is outside its valid range" in one_line(err)
    path.write_text("[ekf]\nr_accel = 0.5\n")
    code, _, err = run(capsys, "replay", LOG, "--no-view", "--params", path, "-q")
    assert code == 0, err


def test_tune_refuses_a_set_for_another_estimator(capsys):
    code, _, err = run(capsys, "tune", LOG, "--estimator", "mahony", "--set", "ekf.r_accel=0.5")
    assert code == 2 and "ekf is not among the estimators run (mahony)" in one_line(err)


# ---------------------------------------------------------------- live: rates a request can carry


@pytest.mark.parametrize("rate", ["1e-300", "0.0004", "65536", "1e9"])
def test_live_refuses_a_rate_mavlink_cannot_ask_for(capsys, rate):
    code, _, err = run(capsys, "live", "udpin:127.0.0.1:0", "--imu-rate", rate, "--no-record")
    assert code == 2 and "--imu-rate" in one_line(err) and "65535 Hz" in err


def test_the_rate_limits_pack_in_both_requests():
    """At each limit, SET_MESSAGE_INTERVAL (unanswered twice) and REQUEST_DATA_STREAM are sent."""
    import io
    from types import SimpleNamespace

    from mavattitude.live.link import MAX_REQUEST_HZ, MIN_REQUEST_HZ, RateRequester, mavlink2

    sent = io.BytesIO()
    conn = SimpleNamespace(mav=mavlink2.MAVLink(sent, srcSystem=255))
    requester = RateRequester(conn, (1, 1), {"RAW_IMU": MIN_REQUEST_HZ, "ATTITUDE": MAX_REQUEST_HZ})
    requester.start(0.0)
    for now in range(1, 10):
        requester.tick(float(now))
    assert requester.done and "at 65535 Hz (REQUEST_DATA_STREAM)" in " ".join(requester.notes)
    parser = mavlink2.MAVLink(None)
    messages = parser.parse_buffer(sent.getvalue())
    intervals = [m.param2 for m in messages if m.get_type() == "COMMAND_LONG"]
    assert max(intervals) == pytest.approx(2**31 - 1, rel=1e-7)


# ---------------------------------------------------------------- evaluate


def garbage_logs(folder):
    paths = [folder / "a.bin", folder / "b.tlog"]
    for path in paths:
        path.write_bytes(b"\\x00garbage, no log" * 50)
    return paths


def test_evaluate_fails_when_every_log_failed(capsys, tmp_path):
    code, out, err = run(capsys, "evaluate", *garbage_logs(tmp_path), "-j", "1", "-q", "--out", tmp_path / "eval")
    last = err.strip().splitlines()[-1]  # after "evaluating ..." and a "failed: ..." line per log
    assert code == 1 and "Traceback" not in err
    assert last.startswith("mavattitude: error: ") and "every one of the 2 logs failed" in last and "report.md" in last
    assert "2 logs: 0 scored, 0 not meaningful, 2 failed" in out


def test_evaluate_succeeds_when_some_log_was_scored(capsys, tmp_path):
    code, out, err = run(capsys, "evaluate", LOG, *garbage_logs(tmp_path)[:1], "-j", "1", "-q",
                         "--out", tmp_path / "eval")
    assert code == 0 and "2 logs: 1 scored, 0 not meaningful, 1 failed" in out, err


@pytest.mark.parametrize("change, text", [
    ({"warmup_s": []}, "--warmup []"),
    ({"warmup_s": math.nan}, "--warmup nan"),
    ({"declination_deg": 400.0}, "--declination 400.0"),
    ({"segment": -1}, "--segment -1"),
    ({"segment": 1.5}, "--segment 1.5"),
    ({"reference": ""}, "--reference ''"),  # a stream's name is checked per log
])
def test_replay_settings_are_checked_once_before_any_log(change, text):
    """Not per log, as "internal error" for each (evaluate --warmup=-- did that)."""
    from mavattitude.errors import UsageError
    from mavattitude.commands.replay import ReplaySettings

    with pytest.raises(UsageError, match=re.escape(text)):
        replace(ReplaySettings(names=("mahony",)), **change).check()


# ---------------------------------------------------------------- messages: long output names


def test_every_legal_output_name_is_written(capsys, tmp_path):
    """Names of 238-255 bytes were refused: the temporary name beside them was too long."""
    json_name, rrd_name = "j" * 250 + ".json", "r" * 251 + ".rrd"
    assert len(json_name) == len(rrd_name) == 255
    code, _, err = run(capsys, "replay", LOG, "-q", "--json", tmp_path / json_name, "--rrd", tmp_path / rrd_name)
    assert code == 0, err
    assert sorted(p.name for p in tmp_path.iterdir()) == sorted([json_name, rrd_name])  # no temporary left


def test_a_name_too_long_is_refused_before_the_work(capsys, tmp_path):
    code, _, err = run(capsys, "replay", LOG, "--no-view", "--json", tmp_path / ("j" * 252 + ".json"))
    assert code == 1 and "--json: the file name is 257 bytes long; a name has at most 255" in one_line(err)


def test_a_temporary_name_fits_and_keeps_whole_characters():
    from mavattitude.outputs import temporary_name

    for name in ["a.json", "é" * 127 + ".rrd", "x" * 255]:
        temp = temporary_name(name)
        assert len(temp.encode()) <= 255 and temp.startswith(".") and temp.endswith(".partial")
        assert temp.encode().decode() == temp
    assert temporary_name("a.json").startswith(".a.json.")


# ---------------------------------------------------------------- messages: whose warning


def test_only_the_decoders_own_warnings_are_blamed_on_it(monkeypatch):
    """A numpy warning from our code while a log is read was reported as "pymavlink skipped
    corrupt data"; it is issued as itself, and pymavlink's own still counts as corrupt data."""
    import warnings

    import numpy as np
    import pymavlink

    from mavattitude import readers

    real = readers.read_dataflash

    def noisy(path, progress):
        np.log(np.zeros(1))  # RuntimeWarning: divide by zero, raised here, not in pymavlink
        warnings.warn_explicit("bad packet", UserWarning, pymavlink.__file__, 1)
        return real(path, progress)

    monkeypatch.setattr(readers, "read_dataflash", noisy)
    with warnings.catch_warnings(record=True) as seen:
        warnings.simplefilter("always")
        flight = readers.read_log(str(LOG))
    assert [str(w) for w in flight.warnings if "skipped corrupt data" in w] == [
        "pymavlink skipped corrupt data (1 reports; first: UserWarning: bad packet)"]
    assert [(w.category, w.filename) for w in seen] == [(RuntimeWarning, __file__)]


def test_standard_atmosphere_out_of_its_range_is_nan_without_a_warning():
    import warnings

    import numpy as np

    from mavattitude.earth import height_pressure, pressure_height

    with warnings.catch_warnings():
        warnings.simplefilter("error")
        assert np.isnan(height_pressure(np.array([44330.77, 5e4, 1e300]))).all()
        assert np.isnan(pressure_height(np.array([0.0, -5.0]))).all()
        assert pressure_height(height_pressure(np.array([-400.0, 120.0])))[1] == pytest.approx(120.0)


@pytest.mark.parametrize("seed, case", [(2, 35), (3, 750), (3, 765)])
def test_damaged_ulogs_read_without_numpy_warnings(tmp_path, seed, case):
    """The fuzzer's cases (scripts/fuzz_logs.py ulog/*.ulg --seed S --case N): a damaged
    sensor_combined.baro_alt_meter above 44331 m made numpy warn in height_pressure (2, 35),
    a signalling NaN in gyro_rad in the cast to float64 (3, 750 and 765)."""
    import random
    import sys
    import warnings
    from pathlib import Path

    from conftest import shared_log

    sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "scripts"))
    from fuzz_logs import mutate, replay_or_error

    source = shared_log("ulog/px4-real-auav-x21-flight.ulg")
    path = tmp_path / "case.ulg"
    path.write_bytes(mutate(source.read_bytes(), random.Random(seed * 1_000_003 + case)))
    with warnings.catch_warnings():
        warnings.simplefilter("error", RuntimeWarning)
        assert replay_or_error(path) == "read"
