"""The progress line: on a terminal only, after a while, with a rate and the time left."""
from __future__ import annotations

import io
import os

from mavattitude import progress as progress_module
from mavattitude.progress import ProgressBar


def _terminal_output(monkeypatch, steps, **options) -> str:
    monkeypatch.setattr(progress_module, "SHOW_AFTER_S", 0.0)
    monkeypatch.setattr(progress_module, "REDRAW_S", 0.0)
    master, slave = os.openpty()
    with os.fdopen(slave, "w") as terminal:
        with ProgressBar("reading x.bin", quiet=options.get("quiet", False), stream=terminal,
                         total=options.get("total"), unit="B") as bar:
            for fraction in steps:
                bar(fraction)
    return _drain(master)


def _drain(master: int) -> str:
    """What was written to the terminal: every read until none is left (a read may return one
    write of several; EIO on Linux once its other end is closed and all is read)."""
    os.set_blocking(master, False)
    out = b""
    try:
        while chunk := os.read(master, 65536):
            out += chunk
    except OSError:  # BlockingIOError or EIO: all read
        return out.decode()
    finally:
        os.close(master)


def test_on_a_terminal_it_shows_rate_and_time_left_then_erases_itself(monkeypatch):
    out = _terminal_output(monkeypatch, [0.25, 0.5, 1.0], total=200e6)
    assert "reading x.bin:  25 %" in out and "MB/s" in out and "left" in out
    assert out.endswith("\r") and out.split("\r")[-2].strip() == ""  # erased: the next line starts clean


def test_quiet_or_not_a_terminal_or_quick_it_says_nothing(monkeypatch):
    assert _terminal_output(monkeypatch, [0.5, 1.0], quiet=True) == ""
    stream = io.StringIO()
    stream.fileno = lambda: 2
    with ProgressBar("reading", stream=stream) as bar:  # not a terminal
        bar(0.5)
    assert stream.getvalue() == ""
    monkeypatch.setattr(progress_module, "SHOW_AFTER_S", 60.0)
    master, slave = os.openpty()
    with os.fdopen(slave, "w") as terminal, ProgressBar("reading", stream=terminal) as bar:
        bar(0.5)  # a run shorter than SHOW_AFTER_S shows nothing
    assert _drain(master) == ""


# ---------------------------------------------------------------- steps (the first compile)


def test_steps_elsewhere_are_a_line_each_then_the_total():
    from mavattitude.progress import StepsLine

    stream = io.StringIO()
    steps = StepsLine("compiling (first run only)", 3, stream=stream)
    steps.step("mahony", 4.2)
    steps.tick()  # a clock only a terminal shows
    steps.step("cpf-ekf", 21.0)
    steps.close()
    lines = stream.getvalue().splitlines()
    assert lines[:2] == ["compiling (first run only): mahony done at 4 s (1/3)",
                         "compiling (first run only): cpf-ekf done at 21 s (2/3)"]
    assert lines[2].startswith("compiling (first run only): 2/3 done in ") and lines[2].endswith(" s")
    assert len(lines) == 3
    quiet = io.StringIO()
    with_quiet = StepsLine("compiling", 1, quiet=True, stream=quiet)
    with_quiet.step("mahony")
    with_quiet.close()
    assert quiet.getvalue() == ""


def test_steps_on_a_terminal_are_one_line_redrawn_that_stays(monkeypatch):
    from mavattitude.progress import StepsLine

    monkeypatch.setattr(progress_module, "REDRAW_S", 0.0)
    master, slave = os.openpty()
    with os.fdopen(slave, "w") as terminal:
        steps = StepsLine("compiling (first run only)", 3, stream=terminal)
        steps.tick()
        steps.step("mahony", 4.0)
        steps.step("ekf", 9.4)
        steps.close()
    out = _drain(master)
    drawn = out.split("\r")
    assert drawn[1].startswith("compiling (first run only): 0/3, 0:0")  # the clock, before anything is done
    assert drawn[3].startswith("compiling (first run only): mahony 4 s, ekf 9 s, 2/3, 0:0")
    assert out.endswith("\n")  # the last line stays, with every step's time
    assert drawn[-2].startswith("compiling (first run only): 2/3 done in ") and "s (mahony 4 s, ekf 9 s)" in drawn[-2]
