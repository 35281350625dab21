"""load() made cheap after the decode (issue 27 part 3): the compiled passes against the numpy
they replaced, to the bit, and every series of the sample logs as it was."""
from __future__ import annotations

import hashlib

import numpy as np
import pytest

from conftest import SAMPLE_LOGS, read_shared, shared_log
from mavattitude.readers import read_log
from mavattitude.readers.series import IMU_LIMITS, MAG_LIMITS, row_checks, sensor_rate_imu


def _row_checks_numpy(v, limits):
    """The numpy ``fill_series`` used before ``row_checks``."""
    ok = np.isfinite(v).all(axis=1)
    finite = np.where(ok[:, None], v, 0.0)
    for cols, limit in limits:
        ok &= np.linalg.norm(finite[:, cols], axis=1) < limit
    return ok, np.any(v != 0, axis=1)


def _sensor_rate_imu_numpy(gyro, accel, max_gap_s=0.02):
    """The numpy ``sensor_rate_imu`` used before its compiled merge."""
    (t, rate, arrival), (ta, specific_force, _) = gyro, accel
    after = np.clip(np.searchsorted(ta, t), 1, len(ta) - 1)
    near = (np.minimum(np.abs(t - ta[after - 1]), np.abs(ta[after] - t)) <= max_gap_s) & (t >= ta[0]) & (t <= ta[-1])
    t, rate, arrival = t[near], rate[near], arrival[near]
    resampled = np.column_stack([np.interp(t, ta, specific_force[:, k]) for k in range(3)])
    return t, np.hstack([rate, resampled]), arrival


@pytest.mark.parametrize("limits", [IMU_LIMITS, MAG_LIMITS], ids=["imu", "mag"])
def test_row_checks_equal_the_numpy_checks(limits):
    rng = np.random.default_rng(5)
    width = limits[-1][0].stop
    scale = limits[0][1] / np.sqrt(3)  # norms around the limit
    v = rng.normal(0.0, scale, (20_000, width))
    v[::97] = 0.0  # unfitted
    v[::101, 1] = np.nan
    v[::103, -1] = np.inf
    v[::107, 0] = -np.inf
    v[::109, :3] = [limits[0][1], 0.0, 0.0]  # on the limit: not below it
    ok, nonzero = row_checks(v, limits)
    want_ok, want_nonzero = _row_checks_numpy(v, limits)
    assert 0 < np.count_nonzero(ok) < len(v) and not ok[::109].any()
    np.testing.assert_array_equal(ok, want_ok)
    np.testing.assert_array_equal(nonzero, want_nonzero)


def test_sensor_rate_imu_equals_the_numpy_interpolation():
    """Jittered clocks, a hole in the accelerometer, gyro samples before, on and after its
    samples, and values that are not finite: the same rows and values to the bit."""
    rng = np.random.default_rng(7)
    t_gyro = np.cumsum(rng.uniform(0.0005, 0.0012, 6000)) - 0.05
    t_accel = np.cumsum(rng.uniform(0.0008, 0.0015, 3500))
    t_accel = t_accel[(t_accel < 1.5) | (t_accel > 1.6)]  # a 100 ms hole
    t_gyro[100:3000:50] = t_accel[50:1500:25][:len(t_gyro[100:3000:50])]  # some on an accelerometer sample
    t_gyro.sort()
    t_gyro = np.unique(t_gyro)
    accel = rng.normal(0.0, 5.0, (len(t_accel), 3))
    accel[200, 0], accel[300, 1], accel[400:402, 2] = np.nan, np.inf, np.inf
    gyro = (t_gyro, rng.normal(0.0, 1.0, (len(t_gyro), 3)), np.arange(len(t_gyro)) * 2)
    got = sensor_rate_imu(gyro, (t_accel, accel, np.arange(len(t_accel))))
    want = _sensor_rate_imu_numpy(gyro, (t_accel, accel, None))
    assert 0 < len(got[0]) < len(t_gyro)
    for a, b in zip(got, want):
        assert a.dtype == b.dtype and a.shape == b.shape
        np.testing.assert_array_equal(a, b)  # (NaN where NaN)
    assert got[1].flags.c_contiguous


def test_sensor_rate_imu_of_a_real_log_equals_the_numpy_interpolation():
    """GYR/ACC of ArduPilot SITL at 1.2 kHz (the simulator writes none): the IMU series load()
    builds equals the numpy form's on the same columns."""
    from mavattitude.readers.dataflash import read_dataflash

    decoded = read_dataflash(str(shared_log("sitl-copter-4.7-400hz.bin")))
    col = decoded.collector
    col.finish()
    flight = read_shared("sitl-copter-4.7-400hz.bin")
    for i in (0, 1):
        gyro, accel = (col.columns(kind, f"{kind.upper()}[{i}]", flight.segment_index) for kind in ("gyr", "acc"))
        t, values, arrival = _sensor_rate_imu_numpy((gyro.t, gyro.values, gyro.arrival),
                                                    (accel.t, accel.values, accel.arrival))
        series = flight.imu[f"GYR[{i}]"]
        assert len(series.t) == len(t) > 100_000  # every row plausible on this log
        np.testing.assert_array_equal(series.t, t)
        np.testing.assert_array_equal(series.gyro, values[:, :3])
        np.testing.assert_array_equal(series.accel, values[:, 3:])
        np.testing.assert_array_equal(series.arrival, arrival)


def _digest(flight) -> str:
    """Every series of the flight (all_series and the attitude streams), each array's dtype,
    shape and bytes, and what the reader noted."""
    h = hashlib.sha256()
    items = list(flight.all_series()) + [("stream " + k, s) for k, s in flight.attitudes.items()]
    for kind, s in items:
        h.update(f"{kind}:{s.source}".encode())
        for name, v in sorted(vars(s).items()):
            if isinstance(v, np.ndarray):
                h.update(f"{name} {v.dtype} {v.shape}".encode())
                h.update(np.ascontiguousarray(v).tobytes())
    h.update(repr((flight.notes, flight.warnings, flight.repeated, flight.segments)).encode())
    return h.hexdigest()[:16]


# Taken before load() was made cheap (issue 27 part 3). A change here is a change in what a log
# reads as: find out why before taking new values (numpy's sin/cos in the attitudes may differ
# between builds).
SAMPLE_DIGESTS = {
    "figure8.bin": "a3ac96637828bb73",
    "figure8.tlog": "6d2cad7f9f475c9e",
    "hover.tlog": "0f2c17e4e1ac7b0c",
    "static.bin": "edba58e784338c4c",
}


@pytest.mark.parametrize("name", sorted(SAMPLE_DIGESTS))
def test_sample_logs_read_as_before(name):
    assert _digest(read_log(str(SAMPLE_LOGS / name))) == SAMPLE_DIGESTS[name]


def test_a_sensors_instances_are_split_in_file_order():
    """IMU records of interleaved instances (and one of an impossible instance, a corrupt
    record) become one series per instance, each in file order, as masking each did."""
    from mavattitude.readers.collect import Collector
    from mavattitude.readers.dataflash import _collect

    instance = np.array([0, 1, 12, 0, 1, 2, 0, 1], np.uint8)
    columns = {"TimeUS": np.arange(8) * 2500.0, "I": instance,
               **{c: np.arange(8.0) + k for k, c in enumerate(("GyrX", "GyrY", "GyrZ", "AccX", "AccY", "AccZ"))}}
    col = Collector()
    _collect(col, "IMU", columns, np.arange(8) * 50)
    col.finish()
    assert sorted(col.keys("imu")) == ["IMU[0]", "IMU[1]", "IMU[2]"]
    for i in (0, 1, 2):
        mine = instance == i
        c = col.columns("imu", f"IMU[{i}]", 0)
        np.testing.assert_array_equal(c.arrival, np.flatnonzero(mine) * 50)
        np.testing.assert_array_equal(c.t, np.flatnonzero(mine) * 2500.0 * 1e-6)
        np.testing.assert_array_equal(c.values[:, 3], np.flatnonzero(mine) + 3.0)
