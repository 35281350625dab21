"""Whether a log's IMU can carry an attitude: its sample rate, and its accelerometer's reading
of g at rest. One place for the thresholds and the texts that ``info``, ``replay`` (the
runner's events), ``live`` and ``evaluate`` show.

Rate. Below ``MEANINGFUL_RATE_HZ`` the gyro samples the vehicle's rotation too sparsely for
its integration to follow it, and the scores say more about the rate than about the
estimators: they are shown, marked "not meaningful", and left out of evaluate's rankings.
Evidence: a real flight's IMU point-sampled at lower rates (as a telemetry stream sends it),
all seven estimators against the simulator's truth, tilt MAE (mean of roll and pitch, °;
``python scripts/imu_rate_sweep.py rate``; the figure-eight simulated at each rate, seed 5):
- sitl-copter-4.7-400hz.bin (dashes to ±44°, 90 °/s yaw turns, doublets): cpf-ekf / eq-kf /
  ncs-eskf 0.24 / 0.34 / 0.34 at 400 Hz, 0.25 / 0.37 / 0.33 at 25 Hz, 0.35 / 0.46 / 0.50 at
  20 Hz, 1.02 / 1.67 / 2.82 at 10 Hz, 1.40 / 2.00 / 4.39 at 5 Hz, 2.79 / 3.89 / 4.21 at 2 Hz,
  6.54 / 5.20 / 4.66 at 1 Hz; mahony (held by its accelerometer, not its gyro) 2.04 from
  400 to 10 Hz, 2.25 at 5, 2.85 at 2, 5.33 at 1 Hz;
- sitl-plane-4.7-circuit.tlog (banked turns): ncs-eskf / eq-kf / cpf-ekf 0.68 / 0.98 / 2.30
  at 25 Hz, 5.18 / 1.75 / 2.74 at 8.3 Hz, 12.7 / 3.4 / 2.7 at 5 Hz, 11.5 / 25.2 / 4.3 at 1.9 Hz;
- the simulator's figure-eight (gentle: 25° bank over seconds), 120 s: ncs-eskf / eq-kf
  0.13 / 0.29 at 50 Hz, 0.13 / 0.27 at 10 Hz, 0.25 / 0.29 at 5 Hz, 1.34 / 1.84 at 2 Hz,
  5.8 / 4.2 at 1 Hz.
The line is the sampling theorem's: a multirotor's body rate carries motion up to a few hertz
(attitude loop, doublets, yaw steps), which a gyro sampled below about 10 Hz aliases. Below
it both real flights' rankings are scrambled (ncs-eskf from best or best but one at 25 Hz to
worst at 5 Hz). Not 20 Hz, where the agile copter's best start to lose: at 10 Hz a gentler
flight still scores near its full-rate figures (the figure-eight; the plane's eq-kf 1.8×,
cpf-ekf 1.2×), and 10 Hz is the rate of many older logs (plane-3.1, the BlueROV telemetry).
It is 10 Hz less 5 %: ``imu_rate`` is a median interval, and a nominal 10 Hz stream with a
jittery clock reads 9.6-10 Hz. Between it and ``COARSE_RATE_HZ`` (20 Hz) the scores stand,
with a warning: the estimators that lean on the gyro through manoeuvres lose up to several
times their full-rate accuracy on an agile flight (above).

Accelerometer scale. Measured as the median ‖a‖ over spans at rest (``accel_at_rest``), as a
fraction from g: more than ``ACCEL_SCALE_WARN`` off is a warning that names what it does to
each estimator run (``Estimator.accel_scale_effect``). Of the 48 shared logs
(``python scripts/imu_rate_sweep.py accel``: the 11 of
logs/, the 32 of corpus/, the 5 PX4 ULogs), 43 have a span at rest: 33 of them read g within
2 %, one -2.2 %, one +3.9 %, then a gap to +5.6-7.6 % (three) and -10 to -20 % (five; the
erle-aux copter -18.4 %, 8.00 m/s²); of the five without one, two read far off over the whole
log (-14.3 %, +32.1 %). 5 % sits in that gap, and is where eq-kf's trust in the accelerometer
starts to fall (``norm_lo``) and where ncs-eskf's residual against g passes its 0.01 g air
threshold at 11.5° of tilt.
"""
from __future__ import annotations

import numpy as np

from ..estimators.alignment import MAX_PLAUSIBLE_BIAS_RAD_S, MIN_STILL_S, MIN_STILL_SAMPLES, STILL_ACCEL_MS2, \
    STILL_GYRO_RAD_S
from ..estimators.gravity import G_BOUND, plausible_g
from ..flight import GRAVITY, median_step
from ..quaternion import row_norms

MEANINGFUL_RATE_HZ = 9.5  # Hz: below it, scores are not meaningful (see the module docstring)
COARSE_RATE_HZ = 20.0  # Hz: below it, a warning that estimates are coarse and lag
ACCEL_SCALE_WARN = 0.05  # |‖a‖ at rest / g - 1| above this is a warning


def rate_not_meaningful(rate_hz: float) -> str | None:
    """Why scores at this IMU rate (Hz, a median interval) are not meaningful; None when they are."""
    if rate_hz >= MEANINGFUL_RATE_HZ:
        return None
    return f"IMU at {rate_hz:.1f} Hz, below {MEANINGFUL_RATE_HZ:g} Hz: gyro integration cannot follow the vehicle"


def rate_warning(rate_hz: float) -> str | None:
    """The warning for a low IMU rate, None at COARSE_RATE_HZ and above."""
    if rate_not_meaningful(rate_hz) is not None:
        return (f"low IMU rate: {rate_hz:.1f} Hz, below {MEANINGFUL_RATE_HZ:g} Hz: gyro integration cannot follow the "
                "vehicle; scores are not meaningful (they measure the sampling, not the estimators)")
    if rate_hz < COARSE_RATE_HZ:
        return (f"low IMU rate: {rate_hz:.1f} Hz (below {COARSE_RATE_HZ:g} Hz): gyro integration is coarse and "
                "estimates will lag in fast manoeuvres")
    return None


def accel_at_rest(t: np.ndarray, gyro: np.ndarray, accel: np.ndarray) -> tuple[float | None, bool]:
    """The accelerometer's reading of g: (median ‖a‖ in m/s², whether it was measured at rest).

    At rest: windows of MIN_STILL_S (and at least MIN_STILL_SAMPLES samples) over which the
    gyro and the accelerometer each stay within the alignment's still thresholds of the
    window's middle (a range of twice the threshold), turning slower than a plausible gyro
    bias. Not the alignment's own still start: that is refused when ‖a‖ is more than
    G_BOUND from g, and a log may not start still. With no window at rest, the whole
    series' median (False): a vehicle in steady flight reads g on average too. None: no sample."""
    norms = row_norms(accel)  # (kept for the rows at rest below: not a copy of those rows)
    norm = norms[np.isfinite(norms)]
    if not len(norm):
        return None, False
    whole = float(np.median(norm, overwrite_input=True))  # (our own copy: the same median)
    del norm
    if len(t) < MIN_STILL_SAMPLES:
        return whole, False
    window = max(MIN_STILL_S, MIN_STILL_SAMPLES * median_step(t))
    k = t - t[0]  # (then in place: the same numbers, one temporary of the hour's rows, not three)
    k /= window
    k = np.floor(k, out=k).astype(np.int64)
    starts = np.flatnonzero(np.r_[True, k[1:] != k[:-1]])
    counts = np.diff(np.r_[starts, len(t)])

    def spread(x):  # per window: the length of the per-axis range
        return np.linalg.norm(np.maximum.reduceat(x, starts, axis=0) - np.minimum.reduceat(x, starts, axis=0), axis=1)
    turning = np.linalg.norm(np.add.reduceat(gyro, starts, axis=0) / counts[:, None], axis=1)
    with np.errstate(invalid="ignore"):
        rest = ((counts >= MIN_STILL_SAMPLES) & (spread(gyro) < 2 * STILL_GYRO_RAD_S)
                & (spread(accel) < 2 * STILL_ACCEL_MS2) & (turning < MAX_PLAUSIBLE_BIAS_RAD_S))
    at_rest = norms[np.repeat(rest, counts)]
    at_rest = at_rest[np.isfinite(at_rest)]
    if not len(at_rest):
        return whole, False
    return float(np.median(at_rest)), True


def accel_scale_warning(norm: float | None, at_rest: bool, estimators) -> str | None:
    """The warning for an accelerometer whose reading of g (``norm``, m/s²) is more than
    ACCEL_SCALE_WARN off, naming what it does to each of ``estimators`` (instances); None
    when it is within."""
    if norm is None or abs(norm / GRAVITY - 1.0) <= ACCEL_SCALE_WARN:
        return None
    error = norm / GRAVITY - 1.0
    where = "at rest" if at_rest else "over the whole log (no rest span found)"
    texts = {e.name: e.accel_scale_effect(error) for e in estimators}
    effects = [f"{name}: {text}" for name, text in texts.items() if text]
    untouched = [name for name, text in texts.items() if not text]
    if not plausible_g(norm):
        effects.append(f"the start is not recognised as still (more than {100 * G_BOUND:g} % from g), so "
                       "every estimator starts with a gyro bias of 0 and takes standard gravity for g")
    if untouched:
        effects.append(f"{', '.join(untouched)}: little or no effect")
    return (f"accelerometer reads {norm:.2f} m/s² {where}, {100 * error:+.1f} % from g "
            f"(more than {100 * ACCEL_SCALE_WARN:g} %: an uncalibrated or mis-scaled accelerometer); "
            + "; ".join(effects))
