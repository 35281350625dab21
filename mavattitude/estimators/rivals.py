"""The filters people use instead (VQF, x-io's Fusion), wrapped as estimators for comparison.

- ``vqf``: VQF 2.1 (Laidig & Seel, "VQF: Highly Accurate IMU Orientation Estimation with Bias
  Estimation and Magnetic Disturbance Rejection", Information Fusion 91, 2023; PyPI ``vqf``),
  its online filter (the C++ ``VQF`` class through ``updateBatch``, which runs the same causal
  filter over an array; never ``offlineVQF``, whose forward-backward pass sees the future).
  Its 9D output with the compass, its 6D output with ``use_mag`` off (``--no-mag``).
- ``imufusion``: x-io's Fusion AHRS (PyPI ``imufusion``, its C code behind a per-sample
  Python binding: no batch call, so a Python loop over the samples, as a user of the package
  writes it; ``bench`` gives the speed). ``update`` with a compass sample,
  ``update_no_magnetometer`` without.

Neither is in ``--estimators all`` (the seven of ours); name them: ``--estimators
all,vqf,imufusion``. Both are optional: ``pip install 'mavattitude[rivals]'``.

Frames, converted here and nowhere else (``_to_ned``, ``_from_ned``): both take the body's
axes as they are (FRD) and the specific force as it is (at rest the accelerometer reads
+g along the up axis, (0, 0, -g) in FRD, which is what both expect of "up").
VQF's earth frame is ENU (z up, y north in 9D): its quaternion (w, x, y, z), FRD -> ENU, is
turned into NED by the fixed rotation ENU -> NED. Fusion runs in its NED convention (FRD ->
NED directly), gyro in °/s, accelerometer in g, compass in µT (any unit does). Both give a
heading from magnetic north: the declination turns it to true north (``yaw_turned``), as ours.

Choices made here (neither package takes a time step per sample):
- Each runs at a fixed sample time (the rate its time constants assume): the median of the
  first ``START_STEPS`` steps, which wait for it, the attitude held at the start meanwhile
  (a log's very first step is 0.4-1.5× its usual one in 5 of the 11 shared logs then, 48 now); each
  sample's gyro is scaled by its own step over that time, so the rotation integrated over a
  step is the measured one even where the log's rate jitters.
- A step that is not a step (the first sample, a repeated time, a gap longer than
  ``MAX_STEP_S``) is not fed: the attitude holds, as ours do.
- A missing accelerometer or compass sample (NaN) is fed as zeros, which both filters skip.
- They start from the alignment's attitude and gyro bias (VQF: its state's gyro quaternion and
  bias estimate; Fusion: ``set_quaternion``, its start-up ramp skipped, the bias subtracted:
  Fusion's AHRS does not estimate one).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .. import quaternion as quat
from ..errors import UsageError
from ..flight import GRAVITY
from ..paramspec import param
from .base import MAX_STEP_S, Estimator

INSTALL = "pip install 'mavattitude[rivals]'"
START_STEPS = 16  # steps whose median is the filters' fixed sample time (a log's first step can be 0.4-1.5×)
ENU_TO_NED = np.array([0.0, np.sqrt(0.5), np.sqrt(0.5), 0.0])  # x_ned = y_enu, y_ned = x_enu, z_ned = -z_enu


def missing(cls) -> str | None:
    """Why estimator class ``cls`` cannot run here (its package is not installed), or None."""
    from importlib.util import find_spec

    if not cls.requires or find_spec(cls.requires) is not None:  # None also for sys.modules[name] = None
        return None
    return f"estimator {cls.name} needs the Python package {cls.requires}, which is not installed: {INSTALL}"


def package(cls) -> object:
    """The module ``cls`` wraps, imported; a UsageError with the pip command when it is missing."""
    import importlib

    try:
        return importlib.import_module(cls.requires)
    except ImportError:
        raise UsageError(missing(cls) or f"estimator {cls.name}: its package {cls.requires} cannot be "
                                         f"imported: {INSTALL}") from None


class Rival(Estimator):
    """What both wrappers share: the fixed sample time, the steps fed, the attitude held."""
    in_all = False

    def __init__(self, params=None, declination: float = 0.0):
        super().__init__(params, declination)
        self._module = package(type(self))

    def initialize(self, q0, gyro_bias, accel_g: float = GRAVITY) -> None:
        self._q0 = quat.normalize(np.asarray(q0, dtype=np.float64))
        self._bias0 = np.array(gyro_bias, dtype=np.float64).reshape(3)
        self._filter = None  # made once the first START_STEPS steps give the sample time
        self._first = []  # those steps meanwhile: (dt, gyro, accel, mag) each
        self._ts = np.nan
        self._t_prev = np.nan
        self._q = self._q0.copy()
        self.initialized = True

    @property
    def _heading_from_mag(self) -> bool:
        return self.uses_mag and bool(self.params.use_mag)

    def _from_ned(self, q):
        """Our attitude (FRD -> NED, true north) as the filter's own quaternion."""
        if self._heading_from_mag:
            q = quat.yaw_turned(q, -self.declination)
        return self._frame_from_ned(q)

    def _to_ned(self, q):
        """The filter's quaternions (N, 4) as ours: FRD -> NED, true north, unit in float64."""
        q = quat.normalize(self._frame_to_ned(np.asarray(q, dtype=np.float64)))
        return quat.yaw_turned(q, self.declination) if self._heading_from_mag else q

    def update(self, t, gyro, accel, mag, in_air=None, aiding=None) -> np.ndarray:
        s = self._chunk(t, gyro, accel, mag)
        dt = np.diff(s.t, prepend=self._t_prev)
        if len(s.t):
            self._t_prev = s.t[-1]
        fed = (dt > 0.0) & (dt <= MAX_STEP_S)  # NaN (the first sample) compares False
        steps = np.flatnonzero(fed)
        if self._filter is None:  # the first steps wait, held, until the sample time is known
            waiting, steps = steps[:START_STEPS - len(self._first)], steps[START_STEPS - len(self._first):]
            self._first += [(dt[i], s.gyro[i], s.accel[i], s.mag[i]) for i in waiting]
            if len(self._first) == START_STEPS:
                first = [np.array(column) for column in zip(*self._first)]
                self._ts = float(np.median(first[0]))
                self._filter = self._make_filter(self._ts)
                self._step(*first)  # the filter catches up; those samples' attitudes were already given
        out = np.empty((len(s.t), 4))
        self.diagnostics = {key: np.full(len(s.t), np.nan) for key in self._diagnostic_keys()}
        if len(steps):
            out[steps] = self._step(dt[steps], s.gyro[steps], s.accel[steps], s.mag[steps])
            for key, series in self.diagnostics.items():
                series[steps] = self._fed_diagnostics[key]
        # an attitude that is not fed holds the last one
        index = np.full(len(s.t), -1)
        index[steps] = steps
        last = np.maximum.accumulate(index) if len(s.t) else index
        out[last < 0] = self._q
        out[last >= 0] = out[last[last >= 0]]
        if len(s.t):
            self._q = out[-1].copy()
        return out

    def _diagnostic_keys(self) -> list[str]:
        return []

    def _step(self, dt, gyro, accel, mag) -> np.ndarray:
        """Feed steps to the filter (converted here); our attitude after each."""
        scaled = gyro * (dt / self._ts)[:, None]
        accel = np.nan_to_num(accel, nan=0.0)
        mag = np.nan_to_num(mag, nan=0.0) if self._heading_from_mag else None
        return self._to_ned(self._run(scaled, accel, mag))


@dataclass
class VqfParams:
    # VQF's parameters (VQFParams, its defaults), in its own units, as its documentation gives them
    tau_acc: float = param(3.0, "[0.01, 1e4]", "log [0.3, 30]")  # accelerometer low-pass time constant, s
    tau_mag: float = param(9.0, "[0.01, 1e4]", "log [1, 90]")  # magnetometer (heading) time constant, s
    motion_bias_est: bool = param(True)  # estimate the gyro bias in motion
    rest_bias_est: bool = param(True)  # estimate the gyro bias at rest
    mag_dist_rejection: bool = param(True)  # reject a disturbed magnetic field
    bias_sigma_init: float = param(0.5, "[0.01, 100]", "log [0.05, 5]")  # initial bias uncertainty, °/s
    bias_forgetting_time: float = param(100.0, "[1, 1e6]", "log [10, 1000]")  # bias forgetting time, s
    bias_clip: float = param(2.0, "[0.01, 100]", "log [0.2, 20]")  # largest bias estimate, °/s
    rest_th_gyr: float = param(2.0, "[0.01, 100]", "log [0.2, 20]")  # rest detection: gyro threshold, °/s
    rest_th_acc: float = param(0.5, "[0.01, 10]", "log [0.05, 5]")  # rest detection: accel threshold, m/s²
    use_mag: bool = param(True)  # correct heading from the magnetometer when the log has one (9D, else 6D)


class Vqf(Rival):
    """VQF 2.1, Laidig & Seel 2023 (PyPI vqf): its online filter, 9D with the compass, 6D without"""
    name = "vqf"
    Params = VqfParams
    requires = "vqf"
    color = (255, 120, 255)
    DIAGNOSTICS = {
        "rest": "1 while VQF detects rest (and learns the gyro bias from it), else 0; NaN: sample not fed",
        "mag_disturbed": "1 while VQF rejects the compass as disturbed (9D only), else 0; NaN: sample not fed",
    }

    def _diagnostic_keys(self) -> list[str]:
        return ["rest", "mag_disturbed"] if self._heading_from_mag else ["rest"]

    def _frame_from_ned(self, q):
        return quat.multiply(quat.conjugate(ENU_TO_NED), q)

    def _frame_to_ned(self, q):
        return quat.multiply(ENU_TO_NED, q)

    def _make_filter(self, ts: float):
        p = self.params
        f = self._module.VQF(ts, tauAcc=p.tau_acc, tauMag=p.tau_mag, motionBiasEstEnabled=p.motion_bias_est,
                             restBiasEstEnabled=p.rest_bias_est, magDistRejectionEnabled=p.mag_dist_rejection,
                             biasSigmaInit=p.bias_sigma_init, biasForgettingTime=p.bias_forgetting_time,
                             biasClip=p.bias_clip, restThGyr=p.rest_th_gyr, restThAcc=p.rest_th_acc)
        state = f.state
        state["gyrQuat"] = self._from_ned(self._q0)  # 6D = accQuat (identity) ⊗ gyrQuat, 9D = Δ (0) ⊗ 6D
        f.state = state
        f.setBiasEstimate(self._bias0, -1.0)  # -1: keep the uncertainty bias_sigma_init gives
        return f

    def _run(self, gyro, accel, mag):
        gyro, accel = np.ascontiguousarray(gyro), np.ascontiguousarray(accel)
        if mag is None:
            out = self._filter.updateBatch(gyro, accel)
        else:
            out = self._filter.updateBatch(gyro, accel, np.ascontiguousarray(mag))
        self._fed_diagnostics = {"rest": out["restDetected"].astype(np.float64)}
        if mag is not None:
            self._fed_diagnostics["mag_disturbed"] = out["magDistDetected"].astype(np.float64)
        return out["quat6D" if mag is None else "quat9D"]

    @property
    def gyro_bias(self) -> np.ndarray:
        """VQF's current gyro bias estimate, rad/s."""
        return self._bias0.copy() if self._filter is None else np.asarray(self._filter.getBiasEstimate()[0])


@dataclass
class ImufusionParams:
    # Fusion's settings (FusionAhrsSettings), the values its README recommends
    gain: float = param(0.5, "[0, 100]", "log [0.05, 5]")  # weight of the accelerometer and compass against the gyro
    gyroscope_range: float = param(2000.0, "[0, 1e5]")  # °/s the gyro reads up to (near it: a restart; 0: none)
    acceleration_rejection: float = param(10.0, "[0, 90]", "linear [1, 90]")  # ignore the accelerometer beyond this disagreement, ° (0: never)
    magnetic_rejection: float = param(10.0, "[0, 90]", "linear [1, 90]")  # ignore the compass beyond this disagreement, ° (0: never)
    rejection_timeout: float = param(5.0, "[0, 1e4]", "linear [0.5, 30]")  # s of rejection before it starts over
    use_mag: bool = param(True)  # correct heading from the magnetometer when the log has one


class Imufusion(Rival):
    """x-io's Fusion AHRS (PyPI imufusion), a complementary filter in C, called per sample from Python"""
    name = "imufusion"
    Params = ImufusionParams
    requires = "imufusion"
    color = (45, 105, 90)

    def _frame_from_ned(self, q):
        return q  # Fusion's NED convention: FRD -> NED as ours

    def _frame_to_ned(self, q):
        return q

    def _make_filter(self, ts: float):
        m, p = self._module, self.params
        settings = m.AhrsSettings()
        settings.convention = m.CONVENTION_NED  # imufusion 1.3.3's constructor ignores this argument
        settings.gain = p.gain
        settings.gyroscope_range = p.gyroscope_range
        settings.acceleration_rejection = p.acceleration_rejection
        settings.magnetic_rejection = p.magnetic_rejection
        settings.rejection_timeout = int(round(min(p.rejection_timeout / ts, 2**31 - 1)))  # samples
        ahrs = m.Ahrs()
        ahrs.set_settings(settings)
        ahrs.set_sample_period(ts)
        ahrs.set_quaternion(self._from_ned(self._q0))
        ahrs.skip_startup()  # it starts aligned, as ours do
        return ahrs

    def _run(self, gyro, accel, mag):
        gyro = np.degrees(gyro - self._bias0)  # °/s
        accel = accel / GRAVITY  # g
        n = len(gyro)
        has_mag = np.zeros(n, dtype=bool) if mag is None else np.any(mag != 0.0, axis=1)
        mag = np.zeros((n, 3)) if mag is None else mag * 1e6  # µT: Fusion computes in float32
        ahrs = self._filter
        update, update_no_mag, get_q = ahrs.update, ahrs.update_no_magnetometer, ahrs.get_quaternion
        out = np.empty((n, 4))
        for i in range(n):
            if has_mag[i]:
                update(gyro[i], accel[i], mag[i])
            else:
                update_no_mag(gyro[i], accel[i])
            out[i] = get_q()
        return out
