"""Aiding measurements on the IMU clock (mavattitude.aiding): GPS NED from lat/lon/alt around the
first good 3D fix, baro height from pressure, each measurement fused once, bad ones dropped."""
from __future__ import annotations

import numpy as np
import pytest

from mavattitude import aiding, earth
from mavattitude.earth import pressure_height
from mavattitude.flight import BaroSeries, GpsSeries
from mavattitude.sim import simulate

ORIGIN = (47.4, 8.5, 500.0)


def _gps(t, ned, fix=3, vel=None, h_acc=np.nan):
    t = np.asarray(t, dtype=float)
    n = len(t)
    lat, lon, alt = earth.ned_to_geodetic(ORIGIN, np.asarray(ned, dtype=float))
    vel = np.zeros((n, 3)) if vel is None else np.asarray(vel, dtype=float)
    return GpsSeries("gps", t, lat, lon, alt, vel, np.broadcast_to(fix, (n,)).astype(int),
                     np.full(n, 10), np.broadcast_to(h_acc, (n,)).astype(float))


def test_geodetic_round_trip_and_the_wgs84_radii():
    ned = np.array([[0.0, 0.0, 0.0], [120.0, -340.0, -25.0], [-900.0, 1500.0, 3.0]])
    lat, lon, alt = earth.ned_to_geodetic(ORIGIN, ned)
    np.testing.assert_allclose(earth.geodetic_to_ned(ORIGIN, lat, lon, alt), ned, atol=1e-9)
    # the radii of curvature at 45°, as geodesy tables give them (m)
    np.testing.assert_allclose(earth.radii(45.0), (6_367_381.8, 6_388_838.3), atol=0.1)


def test_each_fix_lands_once_on_the_first_imu_sample_at_or_after_it():
    imu_t = np.arange(0.0, 10.0, 0.01)
    t = np.array([1.003, 1.2, 1.4])
    ned = np.array([[0.0, 0.0, 0.0], [3.0, 4.0, -1.0], [6.0, 8.0, -2.0]])
    a = aiding.build(imu_t, _gps(t, ned, vel=[[1, 2, 3]] * 3, h_acc=0.7), None)
    rows = np.flatnonzero(np.isfinite(a.gps_pos[:, 0]))
    np.testing.assert_array_equal(rows, np.searchsorted(imu_t, t, side="left"))
    assert np.all(imu_t[rows] >= t) and np.all(imu_t[rows] - t < 0.01)
    np.testing.assert_allclose(a.gps_pos[rows], ned - ned[0], atol=1e-6)
    np.testing.assert_allclose(a.gps_vel[rows], [[1, 2, 3]] * 3)
    np.testing.assert_allclose(a.gps_h_acc[rows], 0.7)
    assert np.isnan(a.gps_v_acc).all()  # GpsSeries has no vertical accuracy
    assert a.origin == pytest.approx(tuple(np.array(earth.ned_to_geodetic(ORIGIN, ned[0]))))
    assert np.count_nonzero(np.isfinite(a.gps_vel[:, 0])) == 3 and not a.has_baro and a.has_gps


def test_fixes_below_3d_out_of_order_stale_and_superseded_are_dropped():
    imu_t = np.concatenate([np.arange(0.0, 5.0, 0.02), np.arange(8.0, 10.0, 0.02)])  # a 3 s gap
    t = np.array([0.5, 1.001, 1.5, 1.4, 2.001, 2.002, 2.004, 6.0, 9.001])
    fix = np.array([2, 3, 3, 3, 3, 3, 3, 3, 3])
    ned = np.arange(len(t) * 3, dtype=float).reshape(-1, 3)
    a = aiding.build(imu_t, _gps(t, ned, fix=fix), None)
    kept = np.flatnonzero(np.isfinite(a.gps_pos[:, 0]))
    # 0.5 s: 2D fix (and not the origin); 1.4 s: older than 1.5 s; 2.001 and 2.002 s: the IMU
    # sample at 2.02 s gets only the newest of three; 6.0 s: inside the gap, 2 s stale by 8.0 s.
    np.testing.assert_allclose(imu_t[kept], [1.02, 1.5, 2.02, 9.02], atol=1e-6)
    first = earth.geodetic_to_ned(a.origin, *earth.ned_to_geodetic(ORIGIN, ned[1]))
    np.testing.assert_allclose(first, 0.0, atol=1e-6)  # the origin is the first good 3D fix
    np.testing.assert_allclose(a.gps_pos[kept[2]], ned[6] - ned[1], atol=1e-4)  # radii at another latitude


def test_no_good_fix_means_no_gps_and_no_origin():
    imu_t = np.arange(0.0, 5.0, 0.02)
    a = aiding.build(imu_t, _gps([1.0, 2.0], [[0, 0, 0], [1, 1, 1]], fix=1), None)
    assert a.origin is None and not a.has_gps
    a = aiding.build(imu_t, None, None)
    assert not a.has_gps and not a.has_baro and len(a) == len(imu_t)


def test_baro_height_is_up_from_the_first_sample():
    imu_t = np.arange(0.0, 20.0, 0.01)
    t = np.arange(0.05, 20.0, 0.1)
    height = np.where(t > 10.0, 12.0, 0.0)
    pressure = earth.height_pressure(400.0 + height)
    a = aiding.build(imu_t, None, BaroSeries("baro", t, pressure, np.full(len(t), np.nan)))
    rows = np.flatnonzero(np.isfinite(a.baro_height))
    assert len(rows) == len(t)
    h = a.baro_height[rows]
    np.testing.assert_allclose(h[t < 10.0], 0.0, atol=1e-9)
    expected = pressure_height(pressure[-1]) - pressure_height(pressure[0])
    np.testing.assert_allclose(h[-1], expected)
    assert h[-1] == pytest.approx(12.0, abs=0.1)  # the standard atmosphere both ways


def test_slices_and_the_simulated_flight():
    sim = simulate("circle", 40.0, seed=1, imu_rate=50.0, gps_rate=5.0)
    a = aiding.from_sim(sim)
    assert len(a) == len(sim.t) and a.origin is not None
    rows = np.isfinite(a.gps_pos[:, 0])
    assert np.count_nonzero(rows) == len(sim.gps.t)
    # NED around the first fix: the truth's track moved by that fix's (noisy) position
    first_fix = np.flatnonzero(rows)[0]
    offset = sim.truth.pos_ned[first_fix] - a.gps_pos[first_fix]
    err = a.gps_pos[rows] + offset - sim.truth.pos_ned[rows]
    assert np.abs(err[:, :2]).max() < 6 * sim.params.gps_pos_noise_h
    np.testing.assert_allclose(a.gps_h_acc[rows], sim.params.gps_pos_noise_h)
    np.testing.assert_allclose(a.gps_v_acc[rows], sim.params.gps_pos_noise_v)
    part = a[100:200]
    assert len(part) == 100 and part.origin == a.origin
    np.testing.assert_array_equal(part.gps_pos, a.gps_pos[100:200])
    np.testing.assert_array_equal(part.baro_height, a.baro_height[100:200])
