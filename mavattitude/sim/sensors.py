"""Sensor models: what an autopilot's IMU, compass, GPS and barometer report for a true motion,
and the autopilot's own attitude estimate.

All outputs are SI (tesla for the field) on the autopilot clock (s since boot). Each sensor
draws from its own random stream, spawned from the seed, so changing one sensor's rate or
parameters leaves the others' noise unchanged; constant biases are drawn before any noise,
so they do not depend on the duration either.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .. import earth
from .. import quaternion as quat
from . import world
from .trajectory import TrajectorySample


@dataclass(frozen=True)
class Rates:
    """Sample rates, Hz."""

    imu: float = 100.0  # IMU; also the .tlog ATTITUDE and SIMSTATE rate
    att: float = 25.0  # .bin ATT and SIM: every round(imu/att)-th IMU sample, as ArduPilot logs ATT in its loop
    mag: float = 10.0  # compass; the .tlog repeats the latest sample in every RAW_IMU
    gps: float = 5.0
    baro: float = 10.0

    @property
    def att_every(self) -> int:
        """ATT/SIM are written with every ``att_every``-th IMU sample."""
        return max(1, int(round(self.imu / self.att)))


@dataclass(frozen=True)
class SensorParams:
    """Sensor error model. Noise densities turn into per-sample σ = density · √rate."""

    gyro_noise_density: float = 1.5e-4  # rad/s/√Hz white noise (σ 0.09°/s at 100 Hz)
    gyro_bias_sigma: float = 0.005  # rad/s, 1σ per axis of the constant bias (≈ 0.3°/s)
    gyro_bias_walk: float = 2e-5  # rad/s/√s, bias random walk
    accel_noise_density: float = 3e-3  # m/s²/√Hz white noise (σ 0.03 m/s² at 100 Hz)
    accel_bias_sigma: float = 0.02  # m/s², 1σ per axis of the constant bias
    imu_temperature_c: float = 35.0
    mag_noise: float = 2e-7  # T (2 mGauss), 1σ per axis per sample
    mag_hard_iron_sigma: float = 1e-5  # T (100 mGauss), 1σ per axis; compensated before logging
    gps_pos_noise_h: float = 0.3  # m, 1σ per horizontal axis
    gps_pos_noise_v: float = 0.5  # m, 1σ
    gps_vel_noise: float = 0.05  # m/s, 1σ per axis
    gps_satellites: int = 10
    baro_alt_noise: float = 0.1  # m, 1σ
    baro_temperature_c: float = 30.0
    autopilot_tilt_error: float = np.radians(0.15)  # rad, RMS of the autopilot's roll and pitch error
    autopilot_yaw_error: float = np.radians(0.3)  # rad, RMS of its yaw error
    autopilot_error_periods: tuple[float, float] = (15.0, 120.0)  # s, range of the error's wander periods
    # Off by default (zero): when off, no random numbers are drawn for them, so every other
    # output stays bit-identical.
    accel_vibration: tuple[float, float, float] = (0.0, 0.0, 0.0)  # m/s², peak per axis (x, y, z) of
    # motor vibration in the accelerometer: white, uniform in ±peak, independent per sample (a
    # multirotor's vibration aliased by a low logging rate; paper 003 measured ±0.49 g x/y, ±0.73 g z)
    accel_vibration_start: float = 0.0  # s since log start: the motors start; no vibration before
    mag_bias: tuple[float, float, float] = (0.0, 0.0, 0.0)  # T, body frame: hard iron the
    # autopilot's calibration left in the logged field (constant)
    mag_fault_window: tuple[float, float] = (0.0, 0.0)  # s since log start: [start, end) of a
    # magnetometer fault (e.g. a current-carrying cable or steel nearby); empty = no fault
    mag_fault_field: tuple[float, float, float] = (0.0, 0.0, 0.0)  # T, body frame, added during the fault
    mag_fault_scale: float = 1.0  # the field reads this many times the true one during the fault
    # A DCM primary (off: None): the autopilot's attitude (ATT, ATTITUDE) is then its DCM, truth
    # plus this constant [roll, pitch, yaw] bias (rad) and white noise of RMS ``dcm_noise`` per
    # axis, and the EKF's estimate (the one above) is logged beside it (EKF1 and AHR2, AHRS2)
    dcm_bias: tuple[float, float, float] | None = None
    dcm_noise: float = np.radians(0.3)  # rad


@dataclass
class ImuTrack:
    """One IMU's output at the IMU timestamps."""

    t: np.ndarray  # (N,) s
    gyro: np.ndarray  # (N, 3) rad/s, FRD
    accel: np.ndarray  # (N, 3) m/s², specific force, FRD
    gyro_bias: np.ndarray  # (N, 3) rad/s, the true bias in ``gyro`` (constant + random walk)
    accel_bias: np.ndarray  # (3,) m/s², the true constant bias in ``accel``
    temperature_c: float


@dataclass
class MagTrack:
    """Compass output as ArduPilot logs it: hard iron already removed (MAG.MagX, RAW_IMU.xmag)."""

    t: np.ndarray  # (N,) s
    field: np.ndarray  # (N, 3) tesla, FRD: C(q)ᵀ m_n + noise
    offsets: np.ndarray  # (3,) tesla: the offsets the autopilot added to the raw reading (= -hard iron)


@dataclass
class GpsTrack:
    t: np.ndarray  # (N,) s
    lat_deg: np.ndarray
    lon_deg: np.ndarray
    alt_m: np.ndarray  # above mean sea level
    vel_ned: np.ndarray  # (N, 3) m/s
    fix_type: int  # 3: 3D fix
    num_sats: int
    hdop: float
    vdop: float
    h_acc_m: float  # reported 1σ accuracies
    v_acc_m: float
    speed_acc_ms: float


@dataclass
class BaroTrack:
    t: np.ndarray  # (N,) s
    pressure_pa: np.ndarray
    alt_m: np.ndarray  # altitude above the boot (ground) level from the pressure, as BARO.Alt
    climb_rate: np.ndarray  # m/s, up positive: the autopilot's filtered climb rate (BARO.CRt), taken as exact
    temperature_c: float


def sample_times(duration: float, rate: float) -> np.ndarray:
    """Times k / rate (s since log start) of the samples of a sensor running for ``duration`` s."""
    return np.arange(int(np.floor(duration * rate + 1e-9))) / rate


def imu(truth: TrajectorySample, params: SensorParams, rate: float, rng: np.random.Generator,
        t_offset: float) -> ImuTrack:
    """Gyro = ω + bias(t) + noise; accel = f + bias + noise, at the truth's sample times."""
    n = len(truth.t)
    gyro_bias0 = rng.normal(0.0, params.gyro_bias_sigma, 3)
    accel_bias = rng.normal(0.0, params.accel_bias_sigma, 3)
    walk = rng.normal(0.0, params.gyro_bias_walk / np.sqrt(rate), (n, 3))
    walk[0] = 0.0  # the walk starts at the constant bias
    gyro_bias = gyro_bias0 + np.cumsum(walk, axis=0)
    gyro = truth.omega_b + gyro_bias + rng.normal(0.0, params.gyro_noise_density * np.sqrt(rate), (n, 3))
    accel = (truth.specific_force_b + accel_bias
             + rng.normal(0.0, params.accel_noise_density * np.sqrt(rate), (n, 3)))
    peak = np.asarray(params.accel_vibration, dtype=float)
    if np.any(peak != 0.0):  # drawn last, so the other errors do not depend on it
        running = (truth.t >= params.accel_vibration_start)[:, None]
        accel = accel + rng.uniform(-1.0, 1.0, (n, 3)) * peak * running
    return ImuTrack(truth.t + t_offset, gyro, accel, gyro_bias, accel_bias, params.imu_temperature_c)


def magnetometer(truth: TrajectorySample, field: world.EarthField, params: SensorParams,
                 rng: np.random.Generator, t_offset: float) -> MagTrack:
    """The earth field seen in the body frame, plus noise.

    ArduPilot logs the field after applying its calibration offsets (COMPASS_OFS_*), so the
    hard iron is drawn but only reported, as the offsets that cancelled it.
    """
    hard_iron = rng.normal(0.0, params.mag_hard_iron_sigma, 3)
    body = quat.rotate(quat.conjugate(truth.q), field.ned())
    noisy = body + rng.normal(0.0, params.mag_noise, body.shape)
    if any(b != 0.0 for b in params.mag_bias):
        noisy = noisy + np.asarray(params.mag_bias, dtype=float)
    start, end = params.mag_fault_window
    if end > start:  # no random numbers: the fault is deterministic
        during = (truth.t >= start) & (truth.t < end)
        noisy[during] = (noisy[during] * params.mag_fault_scale
                         + np.asarray(params.mag_fault_field, dtype=float))
    return MagTrack(truth.t + t_offset, noisy, -hard_iron)


def gps(truth: TrajectorySample, home: world.Home, params: SensorParams,
        rng: np.random.Generator, t_offset: float) -> GpsTrack:
    """Position and NED velocity with white noise; a steady 3D fix. No latency is modelled."""
    n = len(truth.t)
    sigma = np.array([params.gps_pos_noise_h, params.gps_pos_noise_h, params.gps_pos_noise_v])
    pos = truth.pos_ned + rng.normal(0.0, 1.0, (n, 3)) * sigma
    vel = truth.vel_ned + rng.normal(0.0, params.gps_vel_noise, (n, 3))
    lat, lon, alt = earth.ned_to_geodetic(home.origin, pos)
    return GpsTrack(truth.t + t_offset, lat, lon, alt, vel, fix_type=3,
                    num_sats=params.gps_satellites, hdop=1.2, vdop=2.0,
                    h_acc_m=params.gps_pos_noise_h, v_acc_m=params.gps_pos_noise_v,
                    speed_acc_ms=params.gps_vel_noise)


def barometer(truth: TrajectorySample, home: world.Home, params: SensorParams,
              rng: np.random.Generator, t_offset: float) -> BaroTrack:
    """Standard-atmosphere pressure of the (noisy) altitude; Alt relative to the ground at home."""
    alt_amsl = home.alt_m - truth.pos_ned[:, 2] + rng.normal(0.0, params.baro_alt_noise, len(truth.t))
    pressure = earth.height_pressure(alt_amsl)
    ground = earth.pressure_height(earth.height_pressure(home.alt_m))
    return BaroTrack(truth.t + t_offset, pressure, earth.pressure_height(pressure) - ground,
                     -truth.vel_ned[:, 2], params.baro_temperature_c)


def autopilot_attitude(truth: TrajectorySample, params: SensorParams,
                       rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """The autopilot's attitude estimate: truth with a small, slowly wandering Euler-angle error.

    Each axis' error is a sum of four sines with random periods in ``autopilot_error_periods``
    and random phases, scaled to the configured RMS: smooth, zero-mean, bounded, like a
    converged EKF's. Returns (q (N, 4), error (N, 3) = [roll, pitch, yaw] rad).
    """
    t = truth.t
    rms = np.array([params.autopilot_tilt_error, params.autopilot_tilt_error, params.autopilot_yaw_error])
    n_sines = 4
    lo, hi = params.autopilot_error_periods
    periods = rng.uniform(lo, hi, (3, n_sines))
    phases = rng.uniform(0.0, 2 * np.pi, (3, n_sines))
    amplitude = rms * np.sqrt(2.0 / n_sines)  # each sine has RMS a/√2; independent sines add in power
    error = np.stack([amplitude[i] * np.sin(2 * np.pi * t[:, None] / periods[i] + phases[i]).sum(axis=1)
                      for i in range(3)], axis=-1)
    euler = quat.to_euler(truth.q) + error
    q = quat.make_continuous(quat.from_euler(euler[:, 0], euler[:, 1], euler[:, 2]))
    return q, error


def dcm_attitude(truth: TrajectorySample, params: SensorParams,
                 rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """A DCM primary's attitude (``SensorParams.dcm_bias``): truth plus the constant bias and
    white noise. Returns (q (N, 4), error (N, 3) = [roll, pitch, yaw] rad)."""
    error = np.asarray(params.dcm_bias) + rng.normal(0.0, params.dcm_noise, (len(truth.t), 3))
    euler = quat.to_euler(truth.q) + error
    return quat.make_continuous(quat.from_euler(euler[:, 0], euler[:, 1], euler[:, 2])), error
