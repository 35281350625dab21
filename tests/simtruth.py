"""Simulated flights with known truth, made once per test session, and a way to run any
estimator over one. Every estimator's accuracy tests use these, so the suite simulates each
flight once."""
from __future__ import annotations

from dataclasses import replace
from functools import lru_cache

import numpy as np

from mavattitude import quaternion as quat
from mavattitude.estimators import align, create
from mavattitude.flight import MagSeries
from mavattitude.core.runner import held_magnetometer
from mavattitude.sim import SensorParams, simulate


@lru_cache(maxsize=None)
def flight(scenario: str, duration: float, seed: int = 11, imu_rate: float = 100.0,
           accel_bias: bool = True):
    """A simulated flight, cached. ``accel_bias=False`` zeroes the accelerometer bias: at rest
    it tilts every estimator by bias/g (0.1° per 0.017 m/s²), which no attitude-only filter
    can observe, so a static accuracy test would test the sensor, not the filter."""
    params = SensorParams()
    if not accel_bias:
        params = replace(params, accel_bias_sigma=0.0)
    return simulate(scenario, duration, seed=seed, imu_rate=imu_rate, params=params)


def static_300():
    return flight("static", 300.0, accel_bias=False)


def figure8_120():
    return flight("figure8", 120.0, seed=12)


def accel_110():
    """Three runs of sustained 0.25 g linear acceleration (scenario "accel")."""
    return flight("accel", 110.0, seed=13, accel_bias=False)


def inputs(sim, mag: bool = True):
    """(t, gyro, accel, mag on the IMU clock or None) of IMU 0."""
    imu = sim.imu[0]
    m = held_magnetometer(sim.t, MagSeries("mag", sim.mag.t, sim.mag.field)) if mag else None
    return sim.t, imu.gyro, imu.accel, m


def run(name: str, sim, params=None, mag: bool = True, q0=None, in_air=None, accel_g=None):
    """Run estimator ``name`` over ``sim`` from the shared alignment; returns (q, estimator).
    ``accel_g``: the reading of g it is given (default: the alignment's, as replay does)."""
    t, gyro, accel, m = inputs(sim, mag)
    a = align(t, gyro, accel, m, sim.declination_rad)
    f = create(name, params, declination=sim.declination_rad)
    f.initialize(a.q0 if q0 is None else q0, a.gyro_bias, a.accel_g if accel_g is None else accel_g)
    return f.update(t, gyro, accel, m, in_air), f


def errors_deg(sim, q, after_s: float = 10.0) -> np.ndarray:
    """(N, 3) |roll|, |pitch|, |yaw| error in degrees against truth, after ``after_s``."""
    keep = sim.t >= sim.t[0] + after_s
    err = quat.to_euler(q[keep]) - quat.to_euler(sim.truth.q[keep])
    return np.abs(quat.wrap_deg(np.degrees(err)))


def run_aided(name: str, sim, params=None, mag: bool = True, gps: bool = True, q0=None):
    """``run`` for an estimator that takes aiding (``uses_aiding``): also passes the simulated
    GPS and baro on the IMU clock (``aiding.from_sim``), or none with ``gps=False``."""
    from mavattitude.aiding import from_sim

    t, gyro, accel, m = inputs(sim, mag)
    a = align(t, gyro, accel, m, sim.declination_rad)
    f = create(name, params, declination=sim.declination_rad)
    f.initialize(a.q0 if q0 is None else q0, a.gyro_bias, a.accel_g)
    return f.update(t, gyro, accel, m, aiding=from_sim(sim) if gps else None), f
