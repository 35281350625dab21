"""metrics.compare and axis_metrics on cases whose answers are known by hand."""
from __future__ import annotations

import numpy as np
import pytest

from mavattitude.flight import AttitudeSeries
from mavattitude.scoring.metrics import AXES, axis_metrics, compare
from mavattitude.quaternion import from_euler


def series(t, roll_deg, pitch_deg, yaw_deg, source="test") -> AttitudeSeries:
    """An AttitudeSeries from ZYX Euler angles in degrees (scalars broadcast over t)."""
    t = np.asarray(t, dtype=float)
    r, p, y = (np.broadcast_to(np.radians(np.asarray(a, dtype=float)), t.shape)
               for a in (roll_deg, pitch_deg, yaw_deg))
    return AttitudeSeries(source=source, t=t, q=from_euler(r, p, y))


def moving_reference(t, source="ATT"):
    """A reference that moves on all three axes (so R² is defined)."""
    return series(t, 10 * np.sin(0.3 * t), 5 * np.cos(0.2 * t), 60 * np.sin(0.05 * t), source)


# ---------------------------------------------------------------- axis_metrics on exact numbers


def test_axis_metrics_known_sequence():
    e = np.array([0.2, -0.4, 0.6, -0.8, 1.0, -1.5, 2.0, -3.0, 0.5, 0.0])
    ref = np.arange(10.0)  # mean 4.5, SS_tot = 82.5
    m = axis_metrics(e, ref)
    assert m.n == 10
    assert m.mae == pytest.approx(1.0)  # sum |e| = 10
    assert m.mse == pytest.approx(1.77)  # sum e² = 17.7
    assert m.rmse == pytest.approx(np.sqrt(1.77))
    assert m.max == 3.0
    # sorted |e| = 0, .2, .4, .5, .6, .8, 1, 1.5, 2, 3; linear quantile at position 9 p
    assert m.sigma1 == pytest.approx(1.0 + (9 * 0.6826 - 6) * 0.5)  # 1.0717
    assert m.sigma3 == pytest.approx(2.0 + (9 * 0.9973 - 8) * 1.0)  # 2.9757
    assert m.r2 == pytest.approx(1 - 17.7 / 82.5)
    # [0,0.5): 0, .2, .4 | [0.5,1): .5, .6, .8 | [1,2): 1, 1.5 | [2,inf): 2, 3
    assert m.buckets == pytest.approx((0.3, 0.3, 0.2, 0.2))


def test_axis_metrics_bucket_edges_are_half_open():
    m = axis_metrics(np.array([0.4999, 0.5, -0.9999, 1.0, 1.9999, -2.0]), np.arange(6.0))
    assert m.buckets == pytest.approx((1 / 6, 2 / 6, 2 / 6, 1 / 6))
    assert sum(m.buckets) == pytest.approx(1.0)


def test_axis_metrics_empty_and_constant_reference():
    assert axis_metrics(np.array([]), np.array([])) is None
    m = axis_metrics(np.array([1.0, 1.0]), np.array([3.0, 3.0]))
    assert np.isnan(m.r2)  # SS_tot = 0: R² undefined


def test_axis_metrics_yaw_r2_uses_circular_mean():
    # Reference yaw around ±180: arithmetic deviations would be ~180°, circular ones are 10°.
    ref = np.array([170.0, -170.0, 175.0, -175.0])  # circular mean -180 (== 180)
    e = np.array([1.0, -1.0, 1.0, -1.0])
    ss_tot = 10.0 ** 2 * 2 + 5.0 ** 2 * 2
    m = axis_metrics(e, ref, circular=True)
    assert m.r2 == pytest.approx(1 - 4.0 / ss_tot)


# ---------------------------------------------------------------- compare


def test_constant_roll_offset():
    t = np.arange(0.0, 60.0, 0.02)
    ref = moving_reference(t)
    est = series(t, 10 * np.sin(0.3 * t) + 1.0, 5 * np.cos(0.2 * t), 60 * np.sin(0.05 * t), "mahony")
    c = compare(ref, est, warmup_s=0.0)
    roll = c.axes["roll"]
    assert c.estimator == "mahony" and c.reference == "ATT"
    assert roll.n == len(t)
    assert roll.mae == pytest.approx(1.0, abs=1e-9)
    assert roll.rmse == pytest.approx(1.0, abs=1e-9)
    assert roll.mse == pytest.approx(1.0, abs=1e-8)
    assert roll.max == pytest.approx(1.0, abs=1e-9)
    assert roll.sigma1 == pytest.approx(1.0, abs=1e-9)
    # every |e| is 1° up to rounding: all in [0.5, 1) or [1, 2), none elsewhere
    assert roll.buckets[0] == 0 and roll.buckets[3] == 0
    assert roll.buckets[1] + roll.buckets[2] == pytest.approx(1.0)
    np.testing.assert_allclose(c.error_deg[:, 0], 1.0, atol=1e-9)
    for axis in ("pitch", "yaw"):
        assert c.axes[axis].mae < 1e-9
        assert c.axes[axis].buckets == (1.0, 0.0, 0.0, 0.0)


def test_constant_offset_buckets_through_compare():
    t = np.arange(0.0, 20.0, 0.1)
    ref = moving_reference(t)
    est = series(t, 10 * np.sin(0.3 * t) - 0.75, 5 * np.cos(0.2 * t) + 1.5,
                 60 * np.sin(0.05 * t) + 3.0)
    c = compare(ref, est, warmup_s=0.0)
    assert c.axes["roll"].buckets == (0.0, 1.0, 0.0, 0.0)
    assert c.axes["pitch"].buckets == (0.0, 0.0, 1.0, 0.0)
    assert c.axes["yaw"].buckets == (0.0, 0.0, 0.0, 1.0)
    assert c.axes["roll"].mae == pytest.approx(0.75)
    np.testing.assert_allclose(c.error_deg[:, 0], -0.75, atol=1e-9)  # sign: estimate - reference


def test_yaw_wraps_around():
    t = np.arange(0.0, 5.0, 0.1)
    c = compare(series(t, 0, 0, -179.0), series(t, 0, 0, 179.0), warmup_s=0.0)
    np.testing.assert_allclose(c.error_deg[:, 2], -2.0, atol=1e-9)
    assert c.axes["yaw"].mae == pytest.approx(2.0)
    assert c.axes["yaw"].max == pytest.approx(2.0)
    assert np.all(c.error_deg[:, 2] >= -180) and np.all(c.error_deg[:, 2] < 180)


def test_perfect_estimate_has_r2_one():
    t = np.arange(0.0, 30.0, 0.05)
    ref = moving_reference(t)
    c = compare(ref, moving_reference(t, "copy"), warmup_s=0.0)
    for axis in AXES:
        m = c.axes[axis]
        assert m.r2 == pytest.approx(1.0, abs=1e-12)
        assert m.mae < 1e-9 and m.max < 1e-9
        assert m.buckets == (1.0, 0.0, 0.0, 0.0)


def test_warmup_is_kept_but_not_scored():
    t_ref = np.arange(0.0, 40.0, 0.5)
    t_est = np.arange(5.0, 40.0, 0.5)  # the estimate starts 5 s late: warm-up ends at 15 s
    ref = moving_reference(t_ref)
    converging = np.where(t_est < 15.0, 5.0, 0.5)  # 5° off while converging, 0.5° after
    est = series(t_est, 10 * np.sin(0.3 * t_est) + converging, 5 * np.cos(0.2 * t_est),
                 60 * np.sin(0.05 * t_est))
    c = compare(ref, est, warmup_s=10.0)
    np.testing.assert_array_equal(c.t, t_est)  # reference times inside the estimate's span
    np.testing.assert_array_equal(c.scored, c.t >= 15.0)
    assert c.axes["roll"].n == np.count_nonzero(t_est >= 15.0)
    assert c.axes["roll"].mae == pytest.approx(0.5)
    assert c.axes["roll"].max == pytest.approx(0.5)
    np.testing.assert_allclose(c.error_deg[~c.scored, 0], 5.0, atol=1e-9)  # kept for the view
    assert c.warmup_s == 10.0


def test_estimate_interpolated_at_reference_times():
    # Estimate at 1 Hz, roll stepping 10° a second; reference at the half seconds.
    # nlerp equals slerp at the midpoint, so the interpolated roll is exactly 10 k + 5.
    t_est = np.arange(0.0, 11.0)
    est = series(t_est, 10.0 * t_est, 0, 0)
    t_ref = np.arange(0.5, 10.0, 1.0)
    ref = series(t_ref, 10.0 * t_ref, 0, 0)
    c = compare(ref, est, warmup_s=0.0)
    assert c.axes["roll"].n == len(t_ref)
    assert c.axes["roll"].max < 1e-9
    # and a reference off the estimate's line by 1° sees exactly that
    c = compare(series(t_ref, 10.0 * t_ref + 1.0, 0, 0), est, warmup_s=0.0)
    np.testing.assert_allclose(c.error_deg[:, 0], -1.0, atol=1e-9)


def test_reference_outside_the_estimate_span_is_dropped():
    t_ref = np.arange(0.0, 10.0, 0.1)
    t_est = np.arange(2.0, 8.0, 0.1)
    c = compare(moving_reference(t_ref), moving_reference(t_est), warmup_s=0.0)
    assert c.t.min() >= t_est[0] - 1e-12 and c.t.max() <= t_est[-1] + 1e-12
    assert c.scored.all()


def test_yaw_alignment_removes_a_40_degree_offset():
    t = np.arange(0.0, 60.0, 0.05)
    ref = moving_reference(t)
    yaw_ref = 60 * np.sin(0.05 * t)
    # During the warm-up the filter's yaw is 90° off; it settles at a 40° offset afterwards.
    offset = np.where(t < 10.0, 90.0, 40.0)
    est = series(t, 10 * np.sin(0.3 * t), 5 * np.cos(0.2 * t), yaw_ref + offset, "ncs-eskf")

    plain = compare(ref, est, warmup_s=10.0)
    assert not plain.yaw_aligned
    assert plain.axes["yaw"].mae == pytest.approx(40.0)

    c = compare(ref, est, warmup_s=10.0, align_yaw=True)
    assert c.yaw_aligned
    assert c.yaw_offset_deg == pytest.approx(40.0)
    assert c.axes["yaw"].mae < 1e-9
    assert c.axes["yaw"].r2 == pytest.approx(1.0)
    np.testing.assert_allclose(c.error_deg[~c.scored, 2], 50.0, atol=1e-9)  # warm-up shifted too
    # roll and pitch untouched
    assert c.axes["roll"].mae == pytest.approx(plain.axes["roll"].mae)


def test_yaw_alignment_across_plus_minus_180():
    # The yaw error is ±180 ± 1: a plain mean would give ~0; the circular mean gives 180.
    t = np.arange(0.0, 5.0, 0.01)
    wobble = np.where(np.arange(len(t)) % 2 == 0, 1.0, -1.0)
    c = compare(series(t, 0, 0, 0), series(t, 0, 0, 180.0 + wobble), warmup_s=0.0,
                align_yaw=True)
    assert abs(abs(c.yaw_offset_deg) - 180.0) < 1e-9
    assert c.axes["yaw"].max == pytest.approx(1.0)


def test_nan_rows_are_excluded_and_counted():
    t = np.arange(0.0, 10.0, 1.0)  # estimate and reference on the same clock
    ref = moving_reference(t)
    ref.q[3] = np.nan
    ref.t[7] = np.nan
    t_est = np.arange(0.0, 10.0, 0.5)
    est = moving_reference(t_est, "est")
    est.q[11] = np.nan  # t = 5.5: the reference sample at 5.0 lands on a valid sample, 6.0 too
    est.q[15] = np.nan  # t = 7.5 (the reference sample at 7 s has a NaN time anyway)
    c = compare(ref, est, warmup_s=0.0)
    assert c.n_nan_reference == 2 and c.n_nan_estimate == 2
    assert len(c.t) == 9  # the NaN time cannot be placed; the NaN attitude is kept as a gap
    assert np.isnan(c.error_deg[c.t == 3.0]).all()
    assert c.axes["roll"].n == 8
    assert np.isfinite(c.error_deg[c.scored]).all()
    assert c.axes["roll"].mae < 1e-9


def test_no_interpolation_across_a_nan_hole():
    t_est = np.arange(0.0, 10.0, 1.0)
    est = moving_reference(t_est, "est")
    est.q[5] = np.nan  # hole between 4 s and 6 s
    t_ref = np.array([3.5, 4.0, 4.5, 5.0, 5.5, 6.0, 6.5])
    c = compare(moving_reference(t_ref), est, warmup_s=0.0)
    np.testing.assert_array_equal(c.scored, [True, True, False, False, False, True, True])
    assert np.isnan(c.error_deg[~c.scored]).all()


def test_no_overlap_gives_empty_axes():
    c = compare(moving_reference(np.arange(0.0, 5.0)), moving_reference(np.arange(10.0, 15.0)))
    assert len(c.t) == 0 and c.error_deg.shape == (0, 3)
    assert all(c.axes[a] is None for a in AXES)
    c = compare(moving_reference(np.arange(0.0, 5.0)), moving_reference(np.arange(0.0, 5.0)),
                warmup_s=100.0)
    assert all(c.axes[a] is None for a in AXES) and len(c.t) == 5


def test_unsorted_estimate_is_sorted():
    t = np.arange(0.0, 10.0, 0.1)
    est = moving_reference(t, "est")
    shuffled = AttitudeSeries("est", est.t[::-1].copy(), est.q[::-1].copy())
    a = compare(moving_reference(t), est, warmup_s=0.0)
    b = compare(moving_reference(t), shuffled, warmup_s=0.0)
    np.testing.assert_allclose(a.error_deg, b.error_deg, atol=1e-12)


def test_million_samples():
    """An hour-scale log: every sample after the warm-up is scored (speed is benchmarked, not tested)."""
    t = np.arange(0.0, 2500.0, 0.0025)  # 10^6 reference samples at 400 Hz
    ref = moving_reference(t)
    est = series(t + 0.001, 10 * np.sin(0.3 * t) + 0.3, 5 * np.cos(0.2 * t), 60 * np.sin(0.05 * t))
    c = compare(ref, est, align_yaw=True)
    assert c.axes["roll"].n == np.count_nonzero((t >= t[0] + 10.001) & (t <= t[-1] + 0.001))


def test_yaw_is_aligned_again_after_each_restart():
    # An estimator without heading reference restarted at t = 50 s with an unrelated yaw:
    # each span gets its own offset, so both spans score their drift only.
    t = np.arange(0.0, 100.0, 0.1)
    ref = AttitudeSeries("ATT", t, from_euler(0.0 * t, 0.0 * t, np.radians(10.0) * np.ones_like(t)))
    yaw = np.where(t < 50.0, np.radians(40.0), np.radians(-100.0)) + np.radians(0.01) * t
    est = AttitudeSeries("x", t, from_euler(0.0 * t, 0.0 * t, yaw))
    c = compare(ref, est, warmup_s=5.0, align_yaw=True, restarts=[50.0])
    assert c.axes["yaw"].max < 0.6  # the drift within a span, not the 140° jump
    assert c.yaw_offset_deg == pytest.approx(30.0 + 0.05, abs=0.1)
    whole = compare(ref, est, warmup_s=5.0, align_yaw=True)
    assert whole.axes["yaw"].max > 100.0
