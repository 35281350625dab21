"""Collected samples -> the ``Flight``'s series: one clock segment, plausible values, SI units.

Shared by both readers (and, for its limits and compass-unit rule, by the live link).
"""
from __future__ import annotations

import numpy as np

from .. import quaternion as quat
from ..flight import AttitudeSeries, BaroSeries, Flight, GpsSeries, ImuSeries, MagSeries, means_over_steps
from ..kernel_cache import kernel
from .collect import Collector

# Beyond what any autopilot IMU measures (ArduPilot: ±16 g, ±2000 °/s) or any magnetometer
# reads on Earth: such samples are corrupt records.
IMU_LIMITS = [(slice(0, 3), 50.0), (slice(3, 6), 50 * 9.81)]  # rad/s, m/s²
MAG_LIMITS = [(slice(0, 3), 1e-3)]  # tesla (10 gauss)
ACCEL_GAP_S = 0.02  # a gyro sample this far from any accelerometer sample has none (sensor_rate_imu)


def fill_series(flight: Flight, col: Collector, segment: int) -> list[str]:
    """Fill the flight's series from one clock segment; returns why each IMU series that
    holds data was not usable (none when every one was). The collector gives up each series
    as it is taken: its rows and the series' own arrays are not all held at once."""
    def columns(kind, key):
        c = col.columns(kind, key, segment, take=True)
        if c.duplicates:
            flight.repeated[key] = c.duplicates
        # a message that feeds two series (RAW_IMU: IMU and compass) has the same fixes in both
        for text in ((f"{key}: dropped {c.duplicates} samples with repeated timestamps" if c.duplicates else None),
                     (f"{key}: dropped {c.reordered} samples older than one before them (out of order)"
                      if c.reordered else None)):
            if text and text not in flight.notes:
                flight.notes.append(text)
        return c.t, c.values, c.arrival

    def plausible(key, v, limits):
        """Rows that are finite and within physical ranges (corrupt records decode as anything),
        and rows not all zeros."""
        ok, nonzero = row_checks(v, limits)
        if np.count_nonzero(~ok):
            flight.warnings.append(f"{key}: dropped {np.count_nonzero(~ok)} samples with impossible values")
        return ok, nonzero

    unusable = []
    imus = [(key, *columns("imu", key)) for key in col.keys("imu")]
    for key in col.keys("gyr"):
        accel_key = "ACC" + key[len("GYR"):]
        if accel_key in col.keys("acc"):
            imus.append((key, *sensor_rate_imu(columns("gyr", key), columns("acc", accel_key))))
    while imus:  # each let go once its series is made
        key, t, v, arrival = imus.pop(0)
        ok, fitted = plausible(key, v, IMU_LIMITS)  # (an unfitted sensor sends all zeros)
        live = fitted & ok
        if np.count_nonzero(live) >= 2:
            if not live.all():  # (on a sound log every row is: nothing to leave out, nothing copied)
                t, v, arrival = t[live], v[live], arrival[live]
            # each array its own and contiguous (a .tlog's t is a column of the collector's rows)
            flight.imu[key] = ImuSeries(key, np.ascontiguousarray(t), v[:, :3].copy(), v[:, 3:6].copy(),
                                        arrival=np.ascontiguousarray(arrival), rate_over_step=means_over_steps(key))
        elif len(t):
            why = ("all zeros (no sensor fitted?)" if not fitted.any() else
                   "none within ±50 rad/s and ±50 g (saturated or corrupt)" if not live.any() else
                   "fewer than two usable")
            unusable.append(f"{key}: {len(t)} samples, {why}")
    for key in col.keys("mag"):
        t, v, arrival = columns("mag", key)
        live = np.any(v != 0, axis=1) & np.isfinite(v).all(axis=1)
        if np.count_nonzero(live) < 2:
            continue
        # Repair the unit before judging plausibility: a whole series off by 1e6 is a unit
        # bug, not a series of corrupt records.
        t, v, arrival = t[live], _earth_field_scale(flight, key, v[live]), arrival[live]
        live, _ = plausible(key, v, MAG_LIMITS)
        if np.count_nonzero(live) >= 2:
            flight.mag[key] = MagSeries(key, t[live], v[live], arrival=arrival[live])
    for key in col.keys("gps"):
        t, v, arrival = columns("gps", key)
        if len(t):
            flight.gps = GpsSeries(key, t, v[:, 0], v[:, 1], v[:, 2], v[:, 3:6], v[:, 6].astype(int),
                                   v[:, 7].astype(int), v[:, 8], arrival=arrival)
    for key in col.keys("baro"):
        t, v, arrival = columns("baro", key)
        if len(t):
            flight.baro = BaroSeries(key, t, v[:, 0], v[:, 1], arrival=arrival)
    flight.attitudes = _attitudes(col, columns)
    # the primary: of its messages (ATT; ATTITUDE or ATTITUDE_QUATERNION), the one with most samples
    primary = [flight.attitudes[k] for kind in ("att_euler", "att_quat") for k in col.keys(kind)
               if k in flight.attitudes]
    flight.attitude = max(primary, key=lambda s: len(s.t)) if primary else None
    flight.truth = _attitude(col, "truth", segment, columns)
    return unusable


def row_checks(v: np.ndarray, limits: list[tuple[slice, float]]) -> tuple[np.ndarray, np.ndarray]:
    """(ok, nonzero) per row of ``v``: ok where every value is finite and the norm of each
    ``limits`` column slice is below its limit; nonzero where any value is not 0. One pass over
    the rows (numpy's isfinite, where, norm and any made a temporary of every row each)."""
    bounds = np.array([(cols.start, cols.stop, limit) for cols, limit in limits], np.float64)
    ok = np.empty(len(v), np.bool_)
    nonzero = np.empty(len(v), np.bool_)
    _row_checks(np.ascontiguousarray(v, np.float64), bounds, ok, nonzero)
    return ok, nonzero


@kernel
def _row_checks(v, bounds, ok, nonzero):
    for i in range(v.shape[0]):
        good, any_set = True, False
        for j in range(v.shape[1]):
            good &= np.isfinite(v[i, j])
            any_set |= v[i, j] != 0.0
        nonzero[i] = any_set
        for b in range(bounds.shape[0]):
            if not good:
                break
            squares = 0.0
            for j in range(int(bounds[b, 0]), int(bounds[b, 1])):
                squares += v[i, j] * v[i, j]  # in order, as np.linalg.norm sums three columns
            good = np.sqrt(squares) < bounds[b, 2]
        ok[i] = good


def sensor_rate_imu(gyro: tuple, accel: tuple, max_gap_s: float = ACCEL_GAP_S) -> tuple:
    """GYR and ACC (each: t, values, arrival) as one IMU series on the gyro's clock: the
    accelerometer interpolated linearly onto the gyro's sample times. The gyro is the clock
    because the attitude integrates it; the accelerometer only corrects slowly. Gyro samples
    further than ``max_gap_s`` from an accelerometer sample are dropped (no accelerometer
    there to speak of). The interpolation looks at most one accelerometer sample ahead (a
    millisecond at sensor rate) of what had arrived."""
    (t, rate, arrival), (ta, specific_force, _) = gyro, accel
    if len(ta) < 2:
        return t[:0], np.empty((0, 6)), arrival[:0]
    near = np.empty(len(t), np.bool_)
    values = np.empty((len(t), 6))
    n = _resample_onto(t, np.ascontiguousarray(rate, np.float64), ta,
                       np.ascontiguousarray(specific_force, np.float64), max_gap_s, near, values)
    return t[near], values[:n], arrival[near]


@kernel
def _resample_onto(t, rate, ta, specific_force, max_gap_s, near, values):
    """``sensor_rate_imu``'s work in one merge of the two sorted clocks (it was a searchsorted,
    three np.interp and their copies): ``near`` per gyro sample, and the rows kept in
    ``values`` (rate, then the accelerometer by np.interp's own formula, to the bit); returns
    how many rows."""
    n, j, last = 0, 0, len(ta) - 1
    for i in range(len(t)):
        x = t[i]
        while j <= last and ta[j] < x:  # j: the first accelerometer sample at or after x
            j += 1
        after = min(max(j, 1), last)
        near[i] = min(abs(x - ta[after - 1]), abs(ta[after] - x)) <= max_gap_s and ta[0] <= x <= ta[last]
        if not near[i]:
            continue
        values[n, :3] = rate[i]
        for k in range(3):
            y = specific_force[:, k]
            if ta[j] == x:
                values[n, 3 + k] = y[j]
                continue
            slope = (y[j] - y[j - 1]) / (ta[j] - ta[j - 1])
            v = slope * (x - ta[j - 1]) + y[j - 1]
            if np.isnan(v):  # as np.interp: from the other end, then the flat value
                v = slope * (x - ta[j]) + y[j]
                if np.isnan(v) and y[j - 1] == y[j]:
                    v = y[j - 1]
            values[n, 3 + k] = v
        n += 1
    return n


def _earth_field_scale(flight: Flight, key: str, field: np.ndarray) -> np.ndarray:
    """Fix a magnetometer whose unit is off by powers of 1000.

    Earth's field is 0.25-0.65 gauss (25-65 µT) everywhere. ArduPilot 4.7 sends HIGHRES_IMU
    xmag..zmag at 1e6 times the gauss the message defines (seen: 580000 for 0.58 G), so a
    median strength far outside any plausible field is rescaled by the power of 1000 that
    brings it back, and the note says so. Heading only needs the direction, but a field in
    the wrong unit must not leave the reader.
    """
    power, strength = earth_field_power(field)
    if power == 0:
        return field
    flight.notes.append(f"{key}: magnetometer strength {strength * 1e4:.4g} G is implausible; "
                        f"rescaled by 1e{-3 * power} to {strength * 1e4 * 10.0 ** (-3 * power):.3g} G")
    return field * 10.0 ** (-3 * power)


def earth_field_power(field: np.ndarray) -> tuple[int, float]:
    """(k, median strength in tesla): the field reads 1000^k times what the Earth's can be
    (``_earth_field_scale``); k = 0 for a plausible one."""
    strength = float(np.median(np.linalg.norm(field, axis=1)))
    if not strength > 0:
        return 0, strength
    return int(round(np.log10(strength / 50e-6) / 3)), strength


def _attitude(col: Collector, prefix: str, segment: int, columns) -> AttitudeSeries | None:
    """The attitude series with most samples among the Euler and quaternion messages."""
    best = None
    for kind in (f"{prefix}_euler", f"{prefix}_quat"):
        for key in col.keys(kind):
            s = _attitude_series(kind, key, columns)
            if s is not None and (best is None or len(s.t) > len(best.t)):
                best = s
    return best


def _attitudes(col: Collector, columns) -> dict[str, AttitudeSeries]:
    """Every attitude the autopilot logged: the primary's messages and the streams beside them."""
    streams = {}
    for kind in ("att_euler", "att_quat", "stream_euler", "stream_quat"):
        for key in col.keys(kind):
            s = _attitude_series(kind, key, columns)
            if s is not None:
                streams[key] = s
    return streams


def _attitude_series(kind: str, key: str, columns) -> AttitudeSeries | None:
    """One attitude message's samples (roll, pitch, yaw in rad, or a quaternion; a fourth
    Euler column is ATT's AEKF) as quaternions; None when no sample is usable."""
    t, v, _ = columns(kind, key)
    if not len(t):
        return None
    width = 3 if kind.endswith("euler") else 4
    ok = np.isfinite(v).all(axis=1) & (np.abs(v[:, :width]).max(axis=1) < 10.0)  # rad or unit quaternion
    t, v = t[ok], v[ok]
    if kind.endswith("quat"):
        ok = np.linalg.norm(v, axis=1) > 0.5
        t, v = t[ok], v[ok]
    if not len(t):
        return None
    q = quat.from_euler(v[:, 0], v[:, 1], v[:, 2]) if kind.endswith("euler") else quat.normalize(v)
    active = v[:, width].astype(int) if v.shape[1] > width else None
    return AttitudeSeries(key, t, q, active=active)
