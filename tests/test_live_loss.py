"""Samples lost on a link, from the autopilot's clock (``live.loss``): bursts of any length."""
from __future__ import annotations

import numpy as np
import pytest

from mavattitude.live.loss import SampleLoss


def _feed(times) -> SampleLoss:
    loss = SampleLoss()
    for t in times:
        loss.add(float(t))
    return loss


@pytest.mark.parametrize("burst", [1, 5, 127, 200, 256, 300, 5000])  # at 1 kHz
def test_a_burst_of_any_length_is_counted_exactly(burst):
    """The 8-bit sequence number sees 200 lost as 200, 256 as 0, 300 as 44: the clock sees them all."""
    t = np.arange(40_000) * 1e-3
    rng = np.random.default_rng(burst)
    t = t + rng.uniform(-2e-4, 2e-4, len(t))  # jitter of the sample times
    kept = np.ones(len(t), bool)
    for start in (3000, 15000, 27000):
        kept[start:start + burst] = False
    loss = _feed(t[kept])
    # exact for bursts of hundreds; within 0.1 % for seconds of loss (the interval is measured)
    assert loss.lost == pytest.approx(3 * burst, abs=3 * burst * 1e-3)
    assert loss.received == np.count_nonzero(kept)


def test_a_late_sample_and_an_early_one_lose_nothing():
    t = list(np.arange(100) * 0.02)
    t[50] += 0.012  # 1.6 intervals after the one before, 0.4 before the next
    assert _feed(t).lost == 0


def test_a_lower_rate_is_not_a_loss_and_a_reboot_starts_again():
    fast = np.arange(0, 10, 0.001)
    slow = 10 + np.arange(1, 500) * 0.02  # asked for 50 Hz instead of 1 kHz
    rebooted = np.arange(0, 5, 0.001)  # the clock starts again
    loss = _feed(np.concatenate([fast, slow, rebooted]))
    assert loss.lost == 0
    with_gap = np.concatenate([rebooted[:2000], rebooted[2100:]])
    assert _feed(np.concatenate([fast, with_gap])).lost == 100
