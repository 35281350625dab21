"""FIFOs, devices and files of others (issue 23, point 8): an input or output that is no regular
file is refused at once (a FIFO would make the command wait for ever), and a file the command
did not write is not replaced, nor a database of another program written into."""
from __future__ import annotations

import os
import signal
import subprocess
import sys
from contextlib import contextmanager

import pytest

from conftest import SAMPLE_LOGS
from mavattitude.cli import main

LOG = SAMPLE_LOGS / "static.bin"
needs_fifo = pytest.mark.skipif(not hasattr(os, "mkfifo"), reason="no FIFOs on this system")


def run(capsys, *args):
    code = main([str(a) for a in args])
    out, err = capsys.readouterr()
    return code, out, err


def one_line(err: str) -> str:
    lines = err.strip().splitlines()
    assert len(lines) == 1 and "Traceback" not in err, err
    return lines[0]


@contextmanager
def deadline(seconds: float):
    """Fails the test, rather than hanging the suite, if the body is still waiting (on a FIFO)."""
    def expire(signum, frame):
        raise AssertionError(f"still waiting after {seconds} s (on a FIFO?)")
    previous = signal.signal(signal.SIGALRM, expire)
    signal.setitimer(signal.ITIMER_REAL, seconds)
    try:
        yield
    finally:
        signal.setitimer(signal.ITIMER_REAL, 0)
        signal.signal(signal.SIGALRM, previous)


@pytest.fixture
def fifo(tmp_path):
    if not hasattr(os, "mkfifo"):
        pytest.skip("no FIFOs on this system")
    path = tmp_path / "pipe.bin"
    os.mkfifo(path)
    return path


# ---------------------------------------------------------------- FIFOs and devices


@pytest.mark.parametrize("command", [["info"], ["replay", "--no-view"], ["evaluate", "-q"],
                                     ["tune", "--estimator", "mahony", "--trials", "2"]])
def test_a_fifo_as_the_log_is_one_line_at_once(capsys, tmp_path, fifo, command):
    out = ["--out", tmp_path / "ev"] if command[0] == "evaluate" else []
    with deadline(20):
        code, _, err = run(capsys, command[0], fifo, *command[1:], *out)
    assert code == 1 and one_line(err) == f"mavattitude: error: {fifo}: not a regular file (a FIFO)"


def test_a_fifo_as_the_parameter_file_is_one_line_at_once(capsys, fifo):
    with deadline(20):
        code, _, err = run(capsys, "replay", LOG, "--params", fifo, "--no-view")
    assert code == 1 and f"{fifo}: not a regular file (a FIFO)" in one_line(err)


def test_evaluate_passes_by_a_fifo_in_its_folder(capsys, tmp_path):
    if not hasattr(os, "mkfifo"):
        pytest.skip("no FIFOs on this system")
    logs = tmp_path / "logs"
    logs.mkdir()
    os.symlink(LOG, logs / "static.bin")
    os.mkfifo(logs / "flight.bin")
    with deadline(120):
        code, out, err = run(capsys, "evaluate", logs, "--out", tmp_path / "ev", "-q", "-j", "1")
    assert code == 0, err
    assert f"note: passed by {logs / 'flight.bin'} (a FIFO): not a regular file" in err
    assert "1 logs: 1 scored" in out


@pytest.mark.parametrize("option", ["--json", "--rrd", "--export"])
def test_a_fifo_as_an_output_is_refused_before_the_replay(capsys, monkeypatch, tmp_path, fifo, option):
    import mavattitude.cli as cli

    monkeypatch.setattr(cli, "_read", lambda *a, **k: pytest.fail("the log was read before the output was refused"))
    target = fifo
    if option == "--export":  # a FIFO where one of its CSV files goes
        target = tmp_path / "out"
        target.mkdir()
        os.mkfifo(target / "mahony.csv")
    with deadline(20):
        code, _, err = run(capsys, "replay", LOG, option, target, *([] if option == "--rrd" else ["--no-view"]))
    assert code == 1 and "not a regular file (a FIFO)" in one_line(err)


@needs_fifo
def test_a_fifo_as_a_study_or_simulated_log_is_refused(capsys, tmp_path):
    study = tmp_path / "study.db"
    os.mkfifo(study)
    with deadline(20):
        code, _, err = run(capsys, "tune", LOG, "--estimator", "mahony", "--study", study, "-o", tmp_path / "t.toml")
    assert code == 1 and f"{study}: --study: not a regular file (a FIFO)" in one_line(err)
    log = tmp_path / "sim.bin"
    os.mkfifo(log)
    with deadline(20):
        code, _, err = run(capsys, "simulate", "--duration", "5", "-o", log)
    assert code == 1 and f"{log}: -o: not a regular file (a FIFO)" in one_line(err)


@pytest.mark.slow
def test_a_fifo_never_hangs_the_command_and_stdout_stays_writable(tmp_path):
    """As a user runs it: a FIFO as the log and as --json end in a second with exit 1;
    --json /dev/stdout into a pipe works (the command's own stdout is no FIFO of others)."""
    if not hasattr(os, "mkfifo"):
        pytest.skip("no FIFOs on this system")
    fifo = tmp_path / "pipe"
    os.mkfifo(fifo)
    command = [sys.executable, "-m", "mavattitude"]
    for args in (["info", str(fifo)], ["replay", str(LOG), "--json", str(fifo), "--no-view"]):
        proc = subprocess.run(command + args, capture_output=True, text=True, timeout=120)
        assert proc.returncode == 1 and "not a regular file (a FIFO)" in proc.stderr, proc.stderr
    proc = subprocess.run(command + ["replay", str(LOG), "--json", "/dev/stdout", "--no-view"],
                          stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, timeout=300)
    assert proc.returncode == 0, proc.stderr
    assert '"reference"' in proc.stdout and "metrics written to /dev/stdout" in proc.stdout
