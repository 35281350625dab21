"""``simulate``: a scenario's true motion, the sensors that observe it, and the autopilot's estimate,
held in one ``SimFlight`` that the log writers turn into a .tlog or a .bin."""
from __future__ import annotations

from dataclasses import dataclass, field, replace

import numpy as np

from . import sensors, world
from .sensors import BaroTrack, GpsTrack, ImuTrack, MagTrack, Rates, SensorParams
from .trajectory import REGISTRY, TrajectorySample, sample

SIM_VERSION = "0.1"
IMU_COUNT = 2  # IMU instance 0 (.bin IMU I=0, .tlog RAW_IMU) and 1 (IMU I=1, SCALED_IMU2)
# What one flight may hold. Writing a .tlog takes ~2 KB of memory per IMU sample (measured:
# 200 s at 1 kHz peaked at 515 MB), so an hour at 1 kHz needs ~7 GB; the IMU rate stays
# within what autopilots log (ArduPilot's fast sampling logs up to 8 kHz).
MAX_IMU_SAMPLES = 3_600_000
MAX_IMU_RATE_HZ = 10_000.0


@dataclass(frozen=True)
class LogScript:
    """What the simulated autopilot's logs say happened, written by every writer (tests read it
    back): a flight mode from the first sample, armed at take-off, another mode two seconds
    later with a text line saying so. Times fall on the 1 Hz heartbeat ticks (a .tlog carries
    modes and arming only in its heartbeats)."""
    modes: tuple[tuple[float, int, int, str, str], ...]  # (t, ArduCopter number, PX4 nav_state, their names)
    armed_at: float | None  # s; None: never armed (the vehicle never leaves the ground)
    messages: tuple[tuple[float, str], ...]  # (t, text)


MODES = ((0, 0, "STABILIZE", "MANUAL"), (5, 2, "LOITER", "POSCTL"))  # (ArduCopter, PX4 nav_state, names)


@dataclass
class SimFlight:
    """A simulated flight: ground truth and sensor data, SI, on the autopilot clock (s since boot).

    ``truth`` is sampled at the IMU timestamps (``truth.t == imu[i].t``): its ``q`` is the true
    attitude for each IMU sample, its ``omega_b`` the true body rate; ``imu[i].gyro_bias`` is the
    true gyro bias in each gyro sample.
    """

    scenario: str
    seed: int
    duration: float  # s
    rates: Rates
    params: SensorParams
    home: world.Home
    earth_field: world.EarthField
    epoch_unix_at_boot: float  # s: UNIX time at autopilot boot (t = 0)
    still_until: float  # s, autopilot clock: the vehicle is still, on the ground, before this
    truth: TrajectorySample  # at the IMU timestamps
    imu: list[ImuTrack]
    autopilot_q: np.ndarray  # (N, 4) the autopilot's estimate at the IMU timestamps (ATT, ATTITUDE)
    autopilot_error: np.ndarray  # (N, 3) rad, its [roll, pitch, yaw] error, estimate - truth
    mag: MagTrack
    gps: GpsTrack
    baro: BaroTrack
    firmware: str  # the firmware string the logs carry (MSG, VER, STATUSTEXT)
    # With a DCM primary (SensorParams.dcm_bias): the EKF's estimate, logged beside
    # ``autopilot_q`` (then DCM's) as EKF1 and AHR2 in a .bin, AHRS2 in a .tlog; else None
    ekf_q: np.ndarray | None = None
    extra_params: dict[str, float | None] = field(default_factory=dict)  # more parameters for the logs (tests); None: leave one out

    @property
    def t(self) -> np.ndarray:
        """IMU timestamps, s since boot."""
        return self.truth.t

    @property
    def script(self) -> LogScript:
        """The modes, arming and text line the logs carry (``LogScript``)."""
        t0, end = float(self.t[0]), float(self.t[-1])
        armed = t0 + float(np.ceil(self.still_until - t0)) if np.isfinite(self.still_until) else np.inf
        modes = [(t0, *MODES[0])]
        messages = []
        if armed + 2.0 < end:
            modes.append((armed + 2.0, *MODES[1]))
            messages.append((armed + 2.0, f"mavattitude-sim: {MODES[1][2]}"))
        return LogScript(tuple(modes), armed if armed < end else None, tuple(messages))

    @property
    def gyro_bias(self) -> np.ndarray:
        """(N, 3) rad/s: the true bias of IMU 0, the IMU estimators use by default."""
        return self.imu[0].gyro_bias

    @property
    def declination_rad(self) -> float:
        return float(self.earth_field.declination_rad)

    @property
    def log_params(self) -> dict[str, float]:
        """Autopilot parameters the logs carry: declination (rad) and compass offsets (mGauss),
        and ``extra_params``."""
        offsets_mgauss = self.mag.offsets * 1e7  # tesla -> mGauss
        params = {
            "COMPASS_DEC": self.declination_rad,
            "COMPASS_OFS_X": float(offsets_mgauss[0]),
            "COMPASS_OFS_Y": float(offsets_mgauss[1]),
            "COMPASS_OFS_Z": float(offsets_mgauss[2]),
            **({"AHRS_EKF_USE": 0.0} if self.ekf_q is not None else {}),  # DCM in use, the EKF beside it
            **self.extra_params,
        }
        return {name: value for name, value in params.items() if value is not None}


def simulate(scenario: str, duration: float, seed: int = 0, *, imu_rate: float = 100.0,
             att_rate: float = 25.0, mag_rate: float = 10.0, gps_rate: float = 5.0,
             baro_rate: float = 10.0, params: SensorParams | None = None) -> SimFlight:
    """Simulate ``duration`` seconds of a scenario (see ``SCENARIOS``) with sensor noise from ``seed``.

    Rates are in Hz (``att_rate``: the .bin ATT/SIM rate, see ``Rates``). ``params`` replaces the
    default sensor error model; the scenario's own overrides apply on top of it. The trajectory
    does not depend on the seed: only the sensor errors do.
    """
    if scenario not in REGISTRY:
        raise ValueError(f"unknown scenario {scenario!r}; choose one of {', '.join(sorted(REGISTRY))}")
    rates = Rates(imu=imu_rate, att=att_rate, mag=mag_rate, gps=gps_rate, baro=baro_rate)
    check_length(duration, rates)
    spec = REGISTRY[scenario]
    params = replace(params or SensorParams(), **spec.sensor_overrides)
    home, field = world.Home(), world.EarthField()
    rng_imus, rng_mag, rng_gps, rng_baro, rng_ap = _random_streams(seed)
    t0 = world.BOOT_TIME_AT_START

    truth = sample(spec, sensors.sample_times(duration, rates.imu))
    imus = [sensors.imu(truth, params, rates.imu, rng, t0) for rng in rng_imus]
    autopilot_q, autopilot_error = sensors.autopilot_attitude(truth, params, rng_ap)
    ekf_q = None
    if params.dcm_bias is not None:  # DCM in use: the estimate above is the EKF's
        ekf_q = autopilot_q
        autopilot_q, autopilot_error = sensors.dcm_attitude(truth, params, rng_ap)
    truth = replace(truth, t=truth.t + t0)  # on the autopilot clock from here on

    def at_rate(rate):
        return sample(spec, sensors.sample_times(duration, rate))

    mag = sensors.magnetometer(at_rate(rates.mag), field, params, rng_mag, t0)
    gps = sensors.gps(at_rate(rates.gps), home, params, rng_gps, t0)
    baro = sensors.barometer(at_rate(rates.baro), home, params, rng_baro, t0)
    return SimFlight(
        scenario=scenario, seed=seed, duration=float(duration), rates=rates, params=params,
        home=home, earth_field=field, epoch_unix_at_boot=world.EPOCH_UNIX_AT_BOOT,
        still_until=t0 + min(spec.still_until, duration), truth=truth, imu=imus,
        autopilot_q=autopilot_q, autopilot_error=autopilot_error, mag=mag, gps=gps, baro=baro,
        firmware=f"mavattitude-sim {SIM_VERSION} scenario {scenario}", ekf_q=ekf_q,
    )


def check_length(duration: float, rates: Rates = Rates()) -> None:
    """A ValueError saying why ``duration`` s at ``rates`` is no flight ``simulate`` can make:
    every sensor needs two samples, and the IMU at most ``MAX_IMU_SAMPLES`` at ``MAX_IMU_RATE_HZ``."""
    for name, rate in vars(rates).items():
        if not np.isfinite(rate) or rate <= 0:
            raise ValueError(f"the {name} rate must be a positive number of Hz, not {rate:g}")
    if rates.imu > MAX_IMU_RATE_HZ:
        raise ValueError(f"an IMU rate of {rates.imu:g} Hz is above the simulator's {MAX_IMU_RATE_HZ:g} Hz")
    if not np.isfinite(duration):
        raise ValueError(f"the duration must be a finite number of seconds, not {duration:g}")
    shortest = 2.0 / min(vars(rates).values())
    if duration < shortest:
        raise ValueError(f"{duration:g} s is too short: every sensor needs two samples, "
                         f"which takes {shortest:g} s at these rates")
    longest = MAX_IMU_SAMPLES / rates.imu
    if duration > longest:
        raise ValueError(f"{duration:g} s at {rates.imu:g} Hz is more than the simulator's "
                         f"{MAX_IMU_SAMPLES:,} IMU samples: at most {longest:g} s at that rate")


def _random_streams(seed: int):
    """Independent generators per sensor, so one sensor's settings never shift another's noise."""
    children = [np.random.default_rng(s) for s in np.random.SeedSequence(seed).spawn(IMU_COUNT + 4)]
    return children[:IMU_COUNT], *children[IMU_COUNT:]
