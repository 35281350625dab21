"""Where an estimator starts: gyro bias from an initial still period, attitude from gravity
(and the magnetometer).

Shared by every estimator, so they all start from the same place and differ only in how
they track.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .. import quaternion as quat
from ..flight import GRAVITY
from .gravity import plausible_g, reading_at_rest

# Still means: the gyro stays within STILL_GYRO_RAD_S of its starting value (so a constant
# bias is allowed) and the accelerometer within STILL_ACCEL_MS2 of its starting reading.
# Loose enough for a vehicle on the ground with motors idling, tight enough that a take-off
# or a hand carry ends the period. The starting reading need not be g, only a plausible
# reading of it (``gravity.plausible_g``, ±25 %): it was within 1 m/s² of g, and on the
# 2014-15 logs reading 8.0 m/s² at rest no still start was found (gyro bias 0 everywhere).
# Corpus (evaluate ../shared/logs --estimators all): erle-20141222-41 (reads -16 %) now starts
# still, mahony 2.60° → 1.32°, eskf 2.27° → 1.11°, ekf 2.64° → 1.44°; althold-error (-20 %)
# +0.02-0.05° for mahony, ekf, eskf, cpf-ekf; DCM-reference medians: mahony 1.71° → 1.32°, ekf
# 1.74° → 1.44°, eskf 1.97° → 1.44°; no other log moved. The reading of g there is
# ``Alignment.accel_g``.
# Tried and not kept (issue 25): the test on a 0.25 s moving mean of the samples. It finds the
# still start that idle vibration hides on 6 of the 15 shared logs without one, but it also runs
# the still period into the take-off (its mean lags the first motion) and, after a gap, calls a
# hover still: mahony on px4-real-auav-x21 0.09° -> 1.09°, cubeblack-mission 1.10° -> 1.41°
# (first run only); copter-3.3-loiter 1.26° -> 3.40° (every run).
STILL_GYRO_RAD_S = 0.05  # ≈ 3 °/s
STILL_ACCEL_MS2 = 1.0
MAX_PLAUSIBLE_BIAS_RAD_S = 0.1  # ≈ 6 °/s: more than that at rest is motion, not bias
MIN_STILL_S = 1.0
MIN_STILL_SAMPLES = 5
# The still period averaged at most. A live session waits for it before its first estimate,
# and replay aligns on exactly what live does, so it is short. On the 31 shared logs then (48 now; seven
# estimators, roll/pitch MAE against the autopilot, median / mean over the logs) 10 s loses
# nothing against 60 s (mahony 1.526 / 2.185° both; cpf-ekf 1.539 / 1.851 -> 1.509 / 1.842°;
# eq-kf 1.299 / 2.006 -> 1.283 / 2.005°; the others within 0.01°), where 3 s cost eq-kf 0.025°
# of mean (0.7° on copter-3.3); on paper 003's static flight 10 s gives the best yaw (p95
# 0.133° against 0.151° for 60 s and 0.214° for 3 s: the compass averaged).
MAX_STILL_S = 10.0
START_SAMPLES = 5  # samples averaged for the initial attitude when the vehicle is not still
MAG_START_FACTOR = 20  # ... and START_SAMPLES times this for the heading (compass samples are fewer)


@dataclass
class Alignment:
    q0: np.ndarray  # initial attitude, body -> NED
    gyro_bias: np.ndarray  # rad/s
    still_span: tuple[float, float] | None  # (start, end) s, or None when no still period
    heading_from_mag: bool
    accel_g: float = GRAVITY  # m/s², the accelerometer's reading of g over the still period (GRAVITY without one)


def still_period(t, gyro, accel) -> tuple[int, bool]:
    """(samples at the start during which the vehicle is still, 0 if not still; whether more
    samples after these could change that). Undecided while every sample so far is still and
    they span less than ``MAX_STILL_S``: the next one may move or may not."""
    n = len(t)
    if n < MIN_STILL_SAMPLES:
        return 0, False
    k = min(n, max(START_SAMPLES, int(np.searchsorted(t, t[0] + 0.5))))
    g0 = np.median(gyro[:k], axis=0)
    a0 = np.median(accel[:k], axis=0)
    if np.linalg.norm(g0) > MAX_PLAUSIBLE_BIAS_RAD_S or not plausible_g(np.linalg.norm(a0)):
        return 0, True
    moving = (np.linalg.norm(gyro - g0, axis=1) > STILL_GYRO_RAD_S) | \
             (np.linalg.norm(accel - a0, axis=1) > STILL_ACCEL_MS2)
    cap = int(np.searchsorted(t, t[0] + MAX_STILL_S))
    decided = bool(moving.any()) or cap < n
    end = min(int(np.argmax(moving)) if moving.any() else n, cap)
    if end < MIN_STILL_SAMPLES or t[end - 1] - t[0] < MIN_STILL_S:
        return 0, decided
    return end, decided


def detect_still(t, gyro, accel) -> int:
    """Number of samples at the start during which the vehicle is still (0 if not still)."""
    return still_period(t, gyro, accel)[0]


def alignment_decided(t, gyro, accel, complete: bool) -> bool:
    """Whether ``align`` on these first samples of a run gives what it would given more of
    the run: the still period at the start has ended (or is capped), and without one, the
    samples the heading is averaged over are in. ``complete``: there are no more samples."""
    if complete:
        return True
    n = len(t)
    if n < max(START_SAMPLES, MIN_STILL_SAMPLES) or t[-1] < t[0] + 0.5:
        return False  # the reference window of ``still_period`` is not complete yet
    n_still, decided = still_period(t, gyro, accel)
    return decided and (n_still > 0 or n >= START_SAMPLES * MAG_START_FACTOR)


def align(t, gyro, accel, mag=None, declination: float = 0.0) -> Alignment:
    """Initial attitude and gyro bias from the first samples of a flight.

    ``mag`` is (N, 3) on the IMU timestamps, NaN where absent. Without a still period the
    gyro bias is taken as zero, the reading of g as GRAVITY, and the attitude comes from the
    first few samples.
    """
    n_still = detect_still(t, gyro, accel)
    span = slice(0, n_still if n_still else min(START_SAMPLES, len(t)))
    bias = gyro[span].mean(axis=0) if n_still else np.zeros(3)
    roll, pitch = quat.tilt_from_accel(accel[span].mean(axis=0))
    yaw = 0.0
    use_mag = False
    if mag is not None:
        m = mag[span] if n_still else mag[:START_SAMPLES * MAG_START_FACTOR]
        m = m[~np.isnan(m).any(axis=1)]
        if len(m):
            yaw = float(quat.heading_from_mag(roll, pitch, m.mean(axis=0), declination))
            use_mag = True
    q0 = quat.from_euler(roll, pitch, yaw)
    still_span = (float(t[0]), float(t[n_still - 1])) if n_still else None
    accel_g = reading_at_rest(accel[:n_still]) if n_still else GRAVITY
    return Alignment(q0=q0, gyro_bias=bias, still_span=still_span, heading_from_mag=use_mag, accel_g=accel_g)
