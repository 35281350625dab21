"""The streaming scorer of a live session (``running_metrics``) against ``metrics.compare`` of
the whole series at once: a session fed part by part, through windows of its latest data."""
from __future__ import annotations

import numpy as np
import pytest

from mavattitude import quaternion as quat
from mavattitude.flight import AttitudeSeries
from mavattitude.scoring.metrics import AXES, compare
from mavattitude.scoring.running_metrics import SKETCH_RATIO, RunningAxis, RunningComparison


def _session(seed: int, yaw_offsets=(0.0, 0.0)):
    """A reference at 50 Hz and an estimate at 400 Hz with a gap and a restart at 43 s (a new
    yaw offset after it), a few NaN estimate rows; yaw turning through ±180°."""
    rng = np.random.default_rng(seed)
    t_ref = np.arange(0.0, 100.0, 0.02) + 1.0
    t_est = np.arange(0.0, 100.0, 0.0025) + 1.003
    t_est = t_est[(t_est < 40.0) | (t_est >= 43.0)]

    def truth(t):
        return np.column_stack([0.3 * np.sin(0.2 * t), 0.2 * np.cos(0.13 * t), 0.07 * t - 2.0])
    ref = truth(t_ref)
    est = truth(t_est) + rng.normal(0, 0.01, (len(t_est), 3))
    est[:, 2] += np.where(t_est < 43.0, np.radians(yaw_offsets[0]), np.radians(yaw_offsets[1]))
    q_est = quat.from_euler(est[:, 0], est[:, 1], est[:, 2])
    q_est[5000:5003] = np.nan
    return (AttitudeSeries("ATT", t_ref, quat.from_euler(ref[:, 0], ref[:, 1], ref[:, 2])),
            AttitudeSeries("est", t_est, q_est), [43.0])


def _fed(ref, est, restarts, align, seed: int, window_s: float = 3.0):
    """RunningComparison fed in random steps, each time only the series' last ``window_s``
    (and what it has not scored yet)."""
    rng = np.random.default_rng(seed)
    running = RunningComparison("est", ref.source, warmup_s=10.0)
    out = []
    t_now = ref.t[0]
    while t_now < ref.t[-1] + 1.0:
        t_now += rng.uniform(0.01, 2.0)
        lag = rng.uniform(0.0, 0.2)  # the estimate trails the reference a little
        r = (ref.t <= t_now) & (ref.t > min(running.until, t_now - window_s))
        e_end = np.searchsorted(est.t, t_now - lag, side="right")
        e_start = max(min(np.searchsorted(est.t, running.until) - 1, np.searchsorted(est.t, t_now - window_s)), 0)
        got = running.update(AttitudeSeries(ref.source, ref.t[r], ref.q[r]),
                             AttitudeSeries("est", est.t[e_start:e_end], est.q[e_start:e_end]),
                             restarts=restarts, align_yaw=(align,))
        if got is not None:
            out.append(got)
    return running.result(), out


@pytest.mark.parametrize("align", [False, True])
def test_running_comparison_equals_compare_of_the_whole(align):
    ref, est, restarts = _session(1, yaw_offsets=(30.0, -120.0) if align else (0.0, 0.0))
    whole = compare(ref, est, warmup_s=10.0, align_yaw=align, restarts=restarts, name="est")
    running, parts = _fed(ref, est, restarts, align, seed=2)
    assert running.yaw_aligned == align and running.n_in_gaps == whole.n_in_gaps
    assert running.n_nan_estimate == whole.n_nan_estimate == 3
    assert running.overlap_s == pytest.approx(whole.overlap_s)
    if align:
        assert [s for s, _ in running.yaw_offsets_deg] == pytest.approx([s for s, _ in whole.yaw_offsets_deg])
        assert [o for _, o in running.yaw_offsets_deg] == pytest.approx([o for _, o in whole.yaw_offsets_deg],
                                                                          abs=1e-9)
    for axis in AXES:
        a, b = running.axes[axis], whole.axes[axis]
        assert a.n == b.n > 3000, axis
        for field in ("mae", "rmse", "mse", "max", "r2"):
            assert getattr(a, field) == pytest.approx(getattr(b, field), rel=1e-9, abs=1e-12), (axis, field)
        assert a.buckets == pytest.approx(b.buckets, abs=1e-12)
        for field in ("sigma1", "sigma3"):  # the sketch: within its resolution
            assert getattr(a, field) == pytest.approx(getattr(b, field), rel=(SKETCH_RATIO - 1) / 2), (axis, field)
    # what the view is given: every reference sample inside the estimate once, in time order, as compare has them
    t, error, scored = (np.concatenate(c) for c in zip(*parts))
    assert np.array_equal(t, whole.t) and np.array_equal(scored, whole.scored)
    shown = np.isfinite(error[:, 2])
    assert np.allclose(error[:, :2], whole.error_deg[:, :2], equal_nan=True)
    assert np.allclose(error[shown, 2], whole.error_deg[shown, 2], atol=1e-9)
    assert shown[scored].all()  # only the yaw of a warm-up before its offset is known is not shown
    assert align or shown[np.isfinite(whole.error_deg[:, 2])].all()


def test_running_axis_quantiles_and_circular_r2_on_wide_errors():
    rng = np.random.default_rng(3)
    error = np.concatenate([rng.standard_cauchy(20000) % 360 - 180, [0.0, 1e-9, 179.99]])
    heading = rng.uniform(-180, 180, len(error))
    running = RunningAxis(circular=True)
    for part in np.array_split(np.arange(len(error)), 7):
        running.add(error[part], heading[part])
    from mavattitude.scoring.metrics import axis_metrics
    whole = axis_metrics(error, heading, circular=True)
    got = running.metrics()
    assert got.sigma1 == pytest.approx(whole.sigma1, rel=1e-3) and got.sigma3 == pytest.approx(whole.sigma3, rel=1e-3)
    assert got.r2 == pytest.approx(whole.r2, rel=1e-6) and got.max == whole.max
