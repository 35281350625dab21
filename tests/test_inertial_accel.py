"""The accelerometer low-passed in an almost-inertial frame (``estimators.inertial_accel``)."""
from __future__ import annotations

import numpy as np
import pytest

from mavattitude import quaternion as quat
from mavattitude.estimators import create, inertial_accel
from mavattitude.estimators.base import MAX_STEP_S, as_chunk
from mavattitude.flight import GRAVITY

RATE = 200.0
TILT = quat.from_euler(0.2, -0.1, 0.5)


def lowpassed(t, gyro, accel, tau=1.0, q0=TILT, bias=(0.0, 0.0, 0.0)):
    state = inertial_accel.start(q0, np.array(bias))
    return inertial_accel.lowpass_in_inertial_frame(as_chunk(t, gyro, accel, None), state, tau, MAX_STEP_S,
                                                    np.empty_like(accel))


def spinning(seconds=20.0, rate=np.array([0.3, -0.5, 1.1])):
    """A body turning at a constant rate with nothing but gravity on its accelerometer: the
    reading is exactly C(q)ᵀ [0, 0, -g] along the attitude the strapdown integrates."""
    t = np.arange(0.0, seconds, 1.0 / RATE)
    gyro = np.tile(rate, (len(t), 1))
    q = np.empty((len(t), 4))
    q[0] = TILT
    for i in range(1, len(t)):
        q[i] = quat.integrate_gyro(q[i - 1], rate, t[i] - t[i - 1])
    accel = quat.rotate(quat.conjugate(q), np.array([0.0, 0.0, -GRAVITY]))
    return t, gyro, accel, q


def circling(seconds=60.0, radius=0.2, hz=1.0):
    """A body held at a fixed tilt and moved round a horizontal circle (BROAD's translation
    trials): the centripetal acceleration is constant in size and turns with the circle."""
    t = np.arange(0.0, seconds, 1.0 / RATE)
    w = 2 * np.pi * hz
    a_n = np.column_stack([-radius * w * w * np.cos(w * t), -radius * w * w * np.sin(w * t), np.zeros_like(t)])
    f_n = a_n - np.array([0.0, 0.0, GRAVITY])  # specific force, NED
    return t, np.zeros((len(t), 3)), quat.rotate(quat.conjugate(TILT), f_n)


def test_gravity_alone_passes_unchanged_however_the_body_turns():
    t, gyro, accel, _ = spinning()
    np.testing.assert_allclose(lowpassed(t, gyro, accel), accel, rtol=0, atol=1e-9)


def test_motion_averages_out_and_gravity_stays():
    t, gyro, accel = circling()
    out = lowpassed(t, gyro, accel)
    down = quat.rotate(quat.conjugate(TILT), np.array([0.0, 0.0, -GRAVITY]))
    after = t > 5.0  # the lags' start
    raw_error = np.degrees(np.arccos(np.clip((accel[after] @ down) / np.linalg.norm(accel[after], axis=1) / GRAVITY, -1, 1)))
    error = np.degrees(np.arccos(np.clip((out[after] @ down) / np.linalg.norm(out[after], axis=1) / GRAVITY, -1, 1)))
    # 1 Hz through two lags of 0.5 s: |H| = 1 / (1 + (2π · 0.5)²) = 0.092, 7.9 m/s² -> 0.73 m/s², 4.2°
    assert raw_error.max() > 35.0 and error.max() < 4.5


def test_a_filter_that_takes_it_is_not_pulled_off_by_a_circle():
    """Simulated truth: mahony on the circle, with and without the pre-step (strict)."""
    t, gyro, accel = circling()
    mag = np.full((len(t), 3), np.nan)
    errors = {}
    for strict in (False, True):
        f = create("mahony", strict=strict)
        f.initialize(TILT, np.zeros(3))
        q = f.update(t, gyro, accel, mag)
        errors[strict] = np.degrees(2 * np.arccos(np.clip(np.abs(q @ TILT), -1, 1)))[t > 30.0].max()
    assert errors[True] > 1.0 and errors[False] < 0.2 * errors[True], errors


def test_chunks_give_the_same_numbers_as_one_call():
    t, gyro, accel = circling(seconds=10.0)
    whole = lowpassed(t, gyro, accel)
    state = inertial_accel.start(TILT, np.zeros(3))
    parts = [inertial_accel.lowpass_in_inertial_frame(as_chunk(t[a:b], gyro[a:b], accel[a:b], None), state, 1.0,
                                                      MAX_STEP_S, np.empty((b - a, 3)))
             for a, b in ((0, 1), (1, 777), (777, len(t)))]
    np.testing.assert_array_equal(np.vstack(parts), whole)


def test_after_a_gap_it_starts_from_the_new_reading():
    t, gyro, accel = circling(seconds=10.0)
    t[1000:] += MAX_STEP_S + 1.0
    out = lowpassed(t, gyro, accel)
    np.testing.assert_allclose(out[1000], accel[1000], rtol=0, atol=1e-12)
    assert not np.allclose(out[1001], accel[1001])


def test_readings_before_the_first_finite_one_pass_through():
    t, gyro, accel = circling(seconds=2.0)
    accel[:3] = np.nan
    out = lowpassed(t, gyro, accel)
    assert np.isnan(out[:3]).all()
    np.testing.assert_allclose(out[3], accel[3], rtol=0, atol=1e-12)
    assert np.isfinite(out[3:]).all()


@pytest.mark.parametrize("name", ["mahony", "mahony-ekf", "ekf", "eskf", "ncs-eskf", "eq-kf"])
def test_strict_takes_the_reading_as_it_is(name):
    t, gyro, accel = circling(seconds=10.0)
    mag = np.full((len(t), 3), np.nan)
    runs = {}
    for values in ({"strict": True, "accel_tau": 2.0}, {"accel_tau": 0.0}, {"accel_tau": 2.0}):
        f = create(name, **values)
        f.initialize(TILT, np.zeros(3))
        runs[tuple(values.items())] = f.update(t, gyro, accel, mag)
    strict, off, on = runs.values()
    if name in ("mahony", "ekf", "eskf"):  # strict changes nothing else in these
        np.testing.assert_array_equal(strict, off)
    assert not np.allclose(on, off)


# (gated filter, shake amplitude m/s², its "low-passed reading used" state code, least share of the
# samples that use it, most tilt error left with it / without it): measured ncs-eskf 5.0° -> 1.5°
# (the bias learned meanwhile), eq-kf 7.7° -> 3.2° (its down-weighted updates of the reading still pull)
STAND_IN = [("ncs-eskf", 4.0, 4, 0.5, 0.4), ("eq-kf", 6.0, 3, 0.2, 0.5)]


@pytest.mark.parametrize("name,amplitude,code,share,ratio", STAND_IN)
def test_a_gated_filter_takes_the_low_passed_reading_only_where_it_refuses_the_reading(name, amplitude, code,
                                                                                        share, ratio):
    """A still, tilted body shaken at 15 Hz (BROAD's phone vibration) with a gyro bias the still
    start did not see: the gates refuse the swinging reading most of the time and the tilt
    drifts; the low-passed reading passes the same gates and stands in (its own state code)."""
    t = np.arange(0.0, 60.0, 1.0 / RATE)
    shake = amplitude * np.sin(2 * np.pi * 15.0 * t)[:, None] * np.array([0.6, 0.0, 0.8])
    accel = quat.rotate(quat.conjugate(TILT), np.array([0.0, 0.0, -GRAVITY])) + shake
    gyro = np.tile([0.004, -0.003, 0.0], (len(t), 1))
    mag = np.full((len(t), 3), np.nan)
    errors, used = {}, {}
    for tau in (0.0, 1.0):
        f = create(name, accel_tau=tau)
        f.initialize(TILT, np.zeros(3))
        q = f.update(t, gyro, accel, mag)
        errors[tau] = np.degrees(2 * np.arccos(np.clip(np.abs(q @ TILT), -1, 1)))[t > 50.0].max()
        used[tau] = np.count_nonzero(f.diagnostics["accel_state"] == code)
    assert used[0.0] == 0 and used[1.0] > share * len(t), used
    assert errors[1.0] < ratio * errors[0.0], errors
