"""A filter's time step between IMU samples: its length, whether to integrate it, and the rate
to integrate over it. One rule for every kernel."""
from __future__ import annotations

from ..kernel_cache import kernel


@kernel(inline="always")
def step_dt(t_i, t_prev, before_first=0.0):
    """Seconds from the previous sample's time ``t_prev`` to ``t_i``; ``before_first`` where
    there is no previous sample (``t_prev`` NaN)."""
    return t_i - t_prev if t_prev == t_prev else before_first


@kernel(inline="always")
def integrates(dt, max_step):
    """Whether a step of ``dt`` is one to integrate: not the first sample (dt 0) and not a gap
    in the data (longer than ``max_step``, ``base.MAX_STEP_S``: the vehicle may be anywhere
    since)."""
    return 0.0 < dt <= max_step


@kernel(inline="always")
def step_rate(g0, g1, g2, gp0, gp1, gp2, dt, rate_over_step):
    """The rate to integrate over a step of ``dt`` that ends at sample g (gp: the sample before):
    the mean of the two ends where a sample is the rate at its time (trapezoidal: ArduPilot and
    MAVLink log instantaneous, filtered rates, and at their 10-50 Hz the end sample alone leaves
    visible error); the sample alone where it is the mean over the step (``rate_over_step``:
    delta angles over their intervals, BROAD's samples), and at the first sample or after a gap
    (dt = 0)."""
    if dt > 0.0 and not rate_over_step:
        return 0.5 * (g0 + gp0), 0.5 * (g1 + gp1), 0.5 * (g2 + gp2)
    return g0, g1, g2
