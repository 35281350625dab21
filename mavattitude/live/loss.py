"""Samples lost on a live link, counted from the autopilot's own clock.

MAVLink's sequence number has 8 bits: a burst of 256 lost packets looks like none, and one of
300 like 44. An IMU stream carries the autopilot's time of each sample, though: a step of k
sample intervals where one was due means k - 1 samples never arrived, however many.

The interval is the stream's own, measured: the mean of its steps since the rate was last set
(gaps left out; the first ``MIN_STEPS`` screened by their median). A mean of steps is the time
they span over their number, so the timestamps' jitter cancels out of it: after a few thousand
samples the interval is exact to a few parts in 10⁵, and a burst of thousands is counted to
the sample. A step of ``GAP_FACTOR`` intervals or more is a gap; it counts once the steps after
it are back at the interval (``CONFIRM_STEPS`` of them), over the whole span (a late sample
followed by an early one is no loss); if they stay long, the vehicle was asked for a lower rate,
and nothing was lost. A clock that goes back (a reboot) starts the count again.
"""
from __future__ import annotations

import numpy as np

MIN_STEPS = 16  # steps seen before any gap counts (the interval must be known first)
GAP_FACTOR = 1.5  # a step this many intervals long or more: samples were lost
CONFIRM_STEPS = 3  # steps at the old interval after a gap: it was a loss, not a new rate


class SampleLoss:
    """``add(t)`` each sample's time (s, autopilot clock) in arrival order; ``lost`` counts
    the samples that should have come between them and did not."""

    def __init__(self):
        self.lost = 0
        self.received = 0
        self._last: float | None = None
        self._first_steps: list[float] = []  # until MIN_STEPS: screened by their median
        self._sum, self._count = 0.0, 0  # the normal steps since the rate was set
        self._interval = float("nan")
        self._gap_span = 0.0  # s from the sample before a gap to the latest one (0: no gap open)
        self._gap_steps = 0  # steps in that span

    def add(self, t: float) -> None:
        self.received += 1
        last, self._last = self._last, t
        if last is None:
            return
        step = t - last
        if step < 0:  # the clock went back: a reboot; its stream starts afresh
            self._new_rate()
            return
        if step == 0:
            return
        interval = self._interval
        long_step = self._count > 0 and step >= GAP_FACTOR * interval
        if self._gap_span:
            if long_step:  # two long steps in a row: the rate went down, nothing was lost
                self._new_rate()
                return
            self._gap_span += step
            self._gap_steps += 1
            if self._gap_steps > CONFIRM_STEPS:
                # over the whole span, so that a late sample followed by an early one is no loss
                self.lost += max(int(round(self._gap_span / interval)) - self._gap_steps, 0)
                self._gap_span, self._gap_steps = 0.0, 0
        elif long_step:
            self._gap_span, self._gap_steps = step, 1
            return
        if self._count:
            self._sum += step
            self._count += 1
            self._interval = self._sum / self._count
            return
        self._first_steps.append(step)
        if len(self._first_steps) == MIN_STEPS:
            steps = np.array(self._first_steps)
            normal = steps[steps < GAP_FACTOR * np.median(steps)]
            self._sum, self._count = float(normal.sum()), len(normal)
            self._interval = self._sum / self._count

    def _new_rate(self) -> None:
        self._first_steps = []
        self._sum, self._count = 0.0, 0
        self._interval = float("nan")
        self._gap_span, self._gap_steps = 0.0, 0

    @property
    def expected(self) -> int:
        """Samples the stream should have delivered: received and lost."""
        return self.received + self.lost

    @property
    def percent(self) -> float:
        return 100.0 * self.lost / self.expected if self.expected else 0.0
