"""A progress line for work that takes a while (reading a log, estimating an hour of it).

Shown on stderr only when it is a terminal, only once the work has run ``SHOW_AFTER_S``
(a short run prints nothing), never with ``quiet``; redrawn at most every ``REDRAW_S``, and
erased when done. It writes to its own handle on the terminal: the log reader captures the
process's stderr while pymavlink decodes.
"""
from __future__ import annotations

import os
import sys
import time

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


def _rate(x: float, unit: str) -> str:
    """'81.9 MB/s', '280 k samples/s': a prefix joins a one-letter unit, else stands apart."""
    value, prefix = (x / 1e6, "M") if x >= 1e6 else (x / 1e3, "k") if x >= 1e4 else (x, "")
    number = f"{value:.1f}" if prefix == "M" else f"{value:.0f}"
    return f"{number} {prefix}{unit}/s" if len(unit) == 1 else f"{number} {prefix + ' ' if prefix else ''}{unit}/s"


def clock(seconds: float) -> str:
    seconds = int(round(seconds))
    return f"{seconds // 3600}:{seconds // 60 % 60:02d}:{seconds % 60:02d}" if seconds >= 3600 \
        else f"{seconds // 60}:{seconds % 60:02d}"
