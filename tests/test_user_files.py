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

from conftest import SAMPLE_LOGS, one_line, run

LOG = SAMPLE_LOGS / "static.bin"
needs_fifo = pytest.mark.skipif(not hasattr(os, "mkfifo"), reason="no FIFOs on this system")




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


@needs_fifo
def test_evaluate_and_tune_pass_by_a_fifo_in_a_folder_or_pattern(capsys, tmp_path):
    from argparse import Namespace

    from mavattitude.cli.common import logs_to_run

    logs = tmp_path / "logs"
    logs.mkdir()
    os.symlink(LOG, logs / "static.bin")
    os.mkfifo(logs / "flight.bin")
    for paths in ([logs], [logs / "*.bin"]):
        with deadline(20):
            found = logs_to_run(Namespace(scheduler=None, paths=[str(p) for p in paths]))
        assert [os.path.basename(p) for p in found] == ["static.bin"]
        assert capsys.readouterr().err == f"note: passed by {logs / 'flight.bin'} (a FIFO): not a regular file\n"


@pytest.mark.parametrize("option", ["--json", "--rrd", "--export"])
def test_a_fifo_as_an_output_is_refused_before_the_replay(capsys, monkeypatch, tmp_path, fifo, option):
    from mavattitude.cli import replay

    monkeypatch.setattr(replay, "read_log_file", lambda *a, **k: pytest.fail("the log was read before the output was refused"))
    target = fifo
    if option == "--export":  # a FIFO where one of its CSV files goes
        target = tmp_path / "out"
        target.mkdir()
        os.mkfifo(target / "mahony.csv")
    with deadline(20):
        code, _, err = run(capsys, "replay", LOG, option, target, *([] if option == "--rrd" else ["--no-view"]))
        assert code == 1 and "a FIFO" in one_line(err)
        code, _, err = run(capsys, "replay", LOG, option, target, "--force",
                           *([] if option == "--rrd" else ["--no-view"]))
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


# ---------------------------------------------------------------- files of others


@pytest.mark.parametrize("force", [[], ["--force"]])
def test_simulate_never_replaces_a_real_log_even_with_force(capsys, tmp_path, force):
    from conftest import shared_log

    for name in ("ulog/px4-real-cubeorange-ground-6s.ulg", "copter-4.1-flight.tlog"):
        real = tmp_path / os.path.basename(name)
        real.write_bytes(shared_log(name).read_bytes())
        before = real.read_bytes()
        code, _, err = run(capsys, "simulate", "--duration", "5", "-o", real, *force)
        assert code == 1 and "a flight log the simulator did not write" in one_line(err)
        assert "even with --force" in err and real.read_bytes() == before
    assert not list(tmp_path.glob(".*partial"))


def test_simulate_replaces_its_own_log_and_with_force_a_file_that_is_no_log(capsys, tmp_path):
    notes = tmp_path / "notes.ulg"
    notes.write_text("my notes\n")
    code, _, err = run(capsys, "simulate", "--duration", "5", "-o", notes)
    assert code == 1 and "--force" in one_line(err) and notes.read_text() == "my notes\n"
    for _ in range(2):  # the second replaces the simulator's own log
        code, _, err = run(capsys, "simulate", "--duration", "5", "-o", notes, "--force")
        assert code == 0, err
    assert notes.read_bytes().startswith(b"ULog")


def someones(folder, name: str) -> bytes:
    """A file of a user's that only looks like ours by its name and kind."""
    text = {".json": b'{"mine": true}\n', ".svg": b'<svg xmlns="http://www.w3.org/2000/svg"></svg>\n',
            ".csv": b"log,speed\nflight.bin,3\n", ".md": b"# My notes\n", ".parquet": b"PAR1" + bytes(20) + b"PAR1",
            ".toml": b"[mahony]\nkp = 0.3\n"}[os.path.splitext(name)[1]]
    (folder / name).write_bytes(text)
    return text


def test_evaluate_replaces_only_its_own_files(capsys, tmp_path):
    logs = tmp_path / "logs"
    logs.mkdir()
    os.symlink(LOG, logs / "static.bin")
    out = tmp_path / "ev"
    out.mkdir()
    names = ["results.csv", "summary.json", "report.md", "tilt_error.svg", "results.parquet"]  # claimed in this order
    texts = {name: someones(out, name) for name in names}
    for name in names:  # each refused in turn, before any log is replayed
        code, _, err = run(capsys, "evaluate", logs, "--out", out, "-q", "-j", "1")
        assert code == 1 and f"{out / name}: exists and is not a" in one_line(err) and "--force" in err
        assert (out / name).read_bytes() == texts[name] and not list(out.glob(".*partial"))
        (out / name).unlink()
    for _ in range(2):  # its own it replaces, the second time from the record it resumes from
        code, _, err = run(capsys, "evaluate", logs, "--out", out, "-q", "-j", "1")
        assert code == 0, err
    from mavattitude.commands.evalreport import has_parquet
    assert sorted(p.name for p in out.iterdir() if p.is_file()) == sorted(names[:None if has_parquet() else -1])


def test_our_json_toml_and_figure_say_who_wrote_them(capsys, tmp_path):
    from mavattitude.outputs import is_kind

    js, own_toml, other = tmp_path / "m.json", tmp_path / "t.toml", tmp_path / "package.json"
    code, _, err = run(capsys, "replay", LOG, "--json", js, "--no-view")
    assert code == 0, err
    assert is_kind(js, "json") and js.read_text().startswith('{\n  "written_by": "mavattitude ')
    someones(tmp_path, "package.json")
    other.write_text('{"written_by": "someone else", "mavattitude": 1}')
    code, _, err = run(capsys, "replay", LOG, "--json", other, "--no-view")
    assert code == 1 and "is not a JSON file written by mavattitude" in one_line(err)
    someones(tmp_path, "t.toml")
    assert not is_kind(own_toml, "toml")  # a parameter file of the user's own is not tune's
    own_toml.write_text("# written by: mavattitude tune flights/ --estimator mahony\n[mahony]\nkp = 0.3\n")
    assert is_kind(own_toml, "toml")


def test_export_writes_only_into_an_empty_folder_or_one_of_its_csv_files(capsys, tmp_path):
    out = tmp_path / "out"
    out.mkdir()
    text = someones(out, "data.csv")
    code, _, err = run(capsys, "replay", LOG, "--export", out, "--no-view")
    assert code == 1 and "holds files mavattitude did not write (data.csv)" in one_line(err)
    assert sorted(p.name for p in out.iterdir()) == ["data.csv"]
    code, _, err = run(capsys, "replay", LOG, "--export", out, "--no-view", "--force")
    assert code == 0, err
    assert (out / "data.csv").read_bytes() == text
    (out / "data.csv").unlink()
    code, _, err = run(capsys, "replay", LOG, "--export", out, "--no-view", "--estimators", "mahony,eskf")
    assert code == 0, err  # a folder of its own CSV files (mahony.csv from before) it writes into
    assert sorted(p.name for p in out.iterdir()) == ["eskf.csv", "mahony.csv", "reference.csv"]


def sqlite_of_another_program(path):
    import sqlite3

    with sqlite3.connect(path) as db:
        db.execute("CREATE TABLE contacts (name TEXT, phone TEXT)")
        db.execute("INSERT INTO contacts VALUES ('Ada', '123')")
    db.close()
    return path.read_bytes()


def test_a_study_is_only_ever_optunas(capsys, tmp_path):
    pytest.importorskip("optuna")
    other = tmp_path / "contacts.db"
    before = sqlite_of_another_program(other)
    args = ["tune", LOG, "--estimator", "mahony", "--trials", "2", "--folds", "0", "-o", tmp_path / "t.toml", "-q"]
    code, _, err = run(capsys, *args, "--study", other)
    assert code == 1 and "a database of another program (its tables contacts are not Optuna's)" in one_line(err)
    assert other.read_bytes() == before
    corrupt = tmp_path / "corrupt.db"
    corrupt.write_bytes(before[:100] + b"\xff" * (len(before) - 100))  # SQLite's header, pages of garbage
    code, _, err = run(capsys, *args, "--study", corrupt)
    assert code == 1 and f"{corrupt}: --study: " in one_line(err) and "SQLAlchemy" not in err
    from mavattitude.outputs import Outputs
    from mavattitude.commands.tune import open_study

    study = tmp_path / "study.db"
    for _ in range(2):  # a new study, then Optuna's own (test_tune runs and resumes one)
        assert open_study(Outputs().database(study, "--study")) is not None


def test_a_study_that_cannot_be_written_is_one_line(capsys, tmp_path):
    pytest.importorskip("optuna")
    if not os.path.isdir("/proc"):
        pytest.skip("no /proc on this system")
    args = ["tune", LOG, "--estimator", "mahony", "--trials", "2", "--folds", "0", "-o", tmp_path / "t.toml", "-q"]
    code, _, err = run(capsys, *args, "--study", "/proc/study.db")  # no file can be made there, even by root
    assert code == 1 and "/proc" in one_line(err) and "Traceback" not in err
    if os.geteuid() != 0:  # root writes read-only files
        study = tmp_path / "study.db"
        assert run(capsys, *args, "--study", study)[0] == 0
        study.chmod(0o444)
        code, _, err = run(capsys, *args, "--study", study)
        assert code == 1 and f"{study}: --study: not writable" in one_line(err)


def test_the_optuna_tables_are_optunas_own():
    """OPTUNA_TABLES, against the tables this Optuna makes."""
    pytest.importorskip("optuna")
    from optuna.storages._rdb import models

    from mavattitude.outputs import OPTUNA_TABLES
    assert set(models.BaseModel.metadata.tables) <= OPTUNA_TABLES


# ---------------------------------------------------------------- an interrupted command


@pytest.mark.parametrize("interrupt", [KeyboardInterrupt, SystemExit])  # Ctrl-C; SIGTERM, made an exception
def test_an_interrupted_replay_replaces_nothing_and_leaves_nothing(capsys, monkeypatch, tmp_path, interrupt):
    import mavattitude.view as view

    js, rrd, export = tmp_path / "m.json", tmp_path / "a.rrd", tmp_path / "out"
    code, _, err = run(capsys, "replay", LOG, "--json", js, "--rrd", rrd, "--export", export)
    assert code == 0, err
    before = {p: p.read_bytes() for p in (js, rrd, *export.iterdir())}
    log_replay = view.log_replay

    def stopped_while_viewing(result, rec):  # after --json and --export were written
        log_replay(result, rec)
        raise interrupt(143) if interrupt is SystemExit else interrupt()
    monkeypatch.setattr(view, "log_replay", stopped_while_viewing)
    try:
        code, _, err = run(capsys, "replay", LOG, "--json", js, "--rrd", rrd, "--export", export,
                           "--estimators", "mahony,eskf")
    except SystemExit as exc:
        code = exc.code
    assert code in (130, 143)
    assert {p: p.read_bytes() for p in (js, rrd, *export.iterdir())} == before  # no eskf.csv either
    assert not [p.name for p in tmp_path.rglob("*") if p.name.endswith(".partial")]


def test_our_own_stdout_is_written_directly_not_replaced(capfd):
    """--json /dev/stdout with stdout a file (pytest's capture here): written through, never a
    temporary file renamed over /dev/stdout."""
    from mavattitude.outputs import Outputs

    if not os.path.exists("/dev/stdout"):
        pytest.skip("no /dev/stdout on this system")
    out = Outputs().file("/dev/stdout", "--json", "json")
    assert str(out.write_path) == "/dev/stdout"
