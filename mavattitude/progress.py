"""Progress on stderr for work that takes a while.

``ProgressBar`` (reading a log, estimating an hour of it): shown only when stderr is a
terminal, only once the work has run ``SHOW_AFTER_S`` (a short run prints nothing), never with
``quiet``; redrawn at most every ``REDRAW_S``, and erased when done. It writes to its own
handle on the terminal: the log reader captures the process's stderr while pymavlink decodes.

``StepsLine`` (work in named steps: the estimators' first compile, which takes minutes on a
loaded machine, where silence looks hung): a line redrawn on a terminal, else a line per step.
"""
from __future__ import annotations

import os
import shutil
import sys
import time

from . import signals

SHOW_AFTER_S = 2.0
REDRAW_S = 0.2


class ProgressBar:
    """``bar(fraction)`` as the work goes; ``total`` (in ``unit``) gives a rate; ``close()``."""

    def __init__(self, label: str, total: float | None = None, unit: str = "", quiet: bool = False,
                 stream=None):
        self.label, self.total, self.unit = label, total, unit
        self.start = self.last = time.monotonic()
        stream = stream or sys.stderr
        self.stream = (os.fdopen(os.dup(stream.fileno()), "w") if not quiet and stream.isatty() else None)
        self.width = 0

    def __call__(self, fraction: float) -> None:
        signals.check()  # every long loop reports here: a stop that something swallowed ends it now
        now = time.monotonic()
        if self.stream is None or now - self.start < SHOW_AFTER_S or now - self.last < REDRAW_S:
            return
        self.last = now
        elapsed = now - self.start
        line = f"{self.label}: {100 * fraction:3.0f} %"
        if self.total and fraction > 0:
            line += f", {_rate(fraction * self.total / elapsed, self.unit)}"
        if 0 < fraction < 1:
            line += f", about {clock(elapsed * (1 - fraction) / fraction)} left"
        self.width = max(self.width, len(line))
        print("\r" + line.ljust(self.width), end="", file=self.stream, flush=True)

    def close(self) -> None:
        if self.stream is not None:
            if self.width:
                print("\r" + " " * self.width + "\r", end="", file=self.stream, flush=True)
            self.stream.close()
            self.stream = None

    def __enter__(self) -> ProgressBar:
        return self

    def __exit__(self, *exc) -> None:
        self.close()


class StepsLine:
    """Named steps of one piece of work, done one by one or side by side (the estimators'
    first compile), and the time so far, on stderr: on a terminal one line redrawn ("compiling
    (first run only): mahony 4 s, ekf 9 s, 3/8, 0:21"; ``tick`` keeps its clock going), else a
    line per step; a last line says when all were done. Nothing with ``quiet``."""

    def __init__(self, label: str, total: int = 0, quiet: bool = False, stream=None):
        self.label, self.total = label, total
        self.start = self.last = time.monotonic()
        self.done: list[tuple[str, float]] = []
        self.stream = None if quiet else stream or sys.stderr
        self.tty = self.stream is not None and self.stream.isatty()
        self.width = 0

    def step(self, name: str, at_s: float | None = None) -> None:
        """``name`` is done, ``at_s`` seconds after the start (default: now)."""
        at_s = time.monotonic() - self.start if at_s is None else at_s
        self.done.append((name, at_s))
        if self.stream is None:
            return
        if self.tty:
            self._draw()
        else:
            print(f"{self.label}: {name} done at {at_s:.0f} s ({len(self.done)}/{self.total})",
                  file=self.stream, flush=True)

    def tick(self) -> None:
        """Redraw the terminal line if its clock moved on (the work is not hung)."""
        signals.check()
        if self.tty and time.monotonic() - self.last >= REDRAW_S:
            self._draw()

    def _draw(self) -> None:
        self.last = time.monotonic()
        tail = f"{len(self.done)}/{self.total}, {clock(self.last - self.start)}"
        shown = [f"{name} {at:.0f} s" for name, at in self.done]
        room = shutil.get_terminal_size().columns - 1  # a line that wraps cannot be redrawn
        while shown and len(f"{self.label}: … {', '.join(shown)}, {tail}") > room:
            shown.pop(0)  # the latest steps stay
        more = "… " if len(shown) < len(self.done) else ""
        line = f"{self.label}: {more}{', '.join(shown + [tail])}"
        self.width = max(self.width, len(line))
        print("\r" + line.ljust(self.width), end="", file=self.stream, flush=True)

    def close(self) -> None:
        """The last line: how many steps were done and the time they took (on a terminal, the
        time of each too: it replaces the line that showed them)."""
        if self.stream is None:
            return
        line = f"{self.label}: {len(self.done)}/{self.total} done in {time.monotonic() - self.start:.0f} s"
        if self.tty:
            steps = ", ".join(f"{name} {at:.0f} s" for name, at in self.done)
            line = "\r" + (line + (f" ({steps})" if steps else "")).ljust(self.width)
        print(line, file=self.stream, flush=True)
        self.stream = None


def _rate(x: float, unit: str) -> str:
    """'81.9 MB/s', '280 k samples/s': a prefix joins a one-letter unit, else stands apart."""
    value, prefix = (x / 1e6, "M") if x >= 1e6 else (x / 1e3, "k") if x >= 1e4 else (x, "")
    number = f"{value:.1f}" if prefix == "M" else f"{value:.0f}"
    return f"{number} {prefix}{unit}/s" if len(unit) == 1 else f"{number} {prefix + ' ' if prefix else ''}{unit}/s"


def clock(seconds: float) -> str:
    seconds = int(round(seconds))
    return f"{seconds // 3600}:{seconds // 60 % 60:02d}:{seconds % 60:02d}" if seconds >= 3600 \
        else f"{seconds // 60}:{seconds % 60:02d}"
