"""What every attitude estimator offers, for whole-log replay and live stepping alike.

An estimator is created with its parameters and the magnetic declination, initialised once
with an attitude and a gyro bias (see ``alignment``), then fed consecutive chunks of IMU
samples. Replay sends the whole log as one chunk; live use sends what has arrived. The
state carries over between calls, and the compiled kernel is the same, so both give the
same numbers.

Inputs are SI on the autopilot clock: ``t`` (N,) s, ``gyro`` (N, 3) rad/s, ``accel`` (N, 3)
m/s² specific force, ``mag`` (N, 3) tesla: the latest magnetometer sample at each IMU time
(held between samples, as the ``runner`` holds it), NaN where there is
none or it is stale, ``in_air`` (N,) 1.0 in the air, 0.0 on the ground, NaN unknown (see ``phase``).
Every ``update`` takes ``aiding``: the GPS and baro measurements of the chunk on the IMU clock
(``mavattitude.aiding.Aiding``, NaN where none), or None when there are none; only an
estimator with ``uses_aiding`` reads it.
Output: (N, 4) quaternions [w, x, y, z], body FRD -> NED.

Diagnostics: after each ``update`` an estimator leaves per-sample series for that chunk in
``self.diagnostics`` (name -> (N,) array), described in ``DIAGNOSTICS``. Shared names:
``cov_trace`` (trace of the covariance, every Kalman filter) and ``accel_state`` (int8 codes
into ``ACCEL_STATES``: what became of the accelerometer update, 0 = used as is). The pipeline
counts the accel states into the JSON events and the view shows them.
"""
from __future__ import annotations

from dataclasses import fields, is_dataclass, replace
from typing import NamedTuple

import numpy as np

from ..flight import GRAVITY
from ..kernel_cache import cached
from . import inertial_accel

# A step longer than this is a gap in the data, not an interval to integrate the gyro over.
MAX_STEP_S = 1.5


class Estimator:
    name: str = ""
    Params: type = None  # a dataclass of tunable parameters with the paper's defaults
    # can take its heading from the magnetometer; unless a class states it, whether its Params have a
    # ``use_mag`` switch (set in __init_subclass__: the two cannot disagree)
    uses_mag: bool = False
    kernels: tuple = ()  # the numba functions it runs, to tell when a first run must compile them
    DIAGNOSTICS: dict = {}  # diagnostic series name -> what it holds, with its unit
    ACCEL_STATES: tuple = ()  # meaning of each accel_state code, code 0 = "used"
    uses_aiding: bool = False  # takes GPS / baro measurements: update(..., aiding=Aiding)
    PAPER: dict = {}  # parameter values ``strict`` forces: the paper's filter as published
    requires: str = ""  # the Python package a filter from another project runs on (imported when created)
    in_all: bool = True  # one of '--estimators all' (a filter from another project is named explicitly)
    # the gyro's samples are means over the step ending at each (ImuSeries.rate_over_step): the
    # runner sets it from the series before ``initialize``
    rate_over_step: bool = False

    # What the rest of the tool reads about an estimator, so that none of it names one: a new
    # estimator is its module and its test (each default below suits one that states nothing).
    color: tuple[int, int, int] | None = None  # its lines in the view (RGB); None: one of the view's spare colours
    # seconds its kernels take to compile the first time, one core (``warmup.precompile`` hands
    # the longest out first); None with ``kernels``: ``DEFAULT_COMPILE_S``
    compile_seconds: float | None = None
    # diagnostics that mark events (1.0 at each): key -> ``Marked``, the warnings and counts they make
    MARKS: dict = {}
    # ``mavattitude bench``'s targets: at least this many times imufusion's samples/s in the same
    # mode (None: bench.MIN_X_IMUFUSION), and at least ``bench_min_rate`` samples/s (None: none)
    bench_min_x_imufusion: float | None = None
    bench_min_rate: float | None = None
    LOG_PARAMS: tuple[str, ...] = ()  # the autopilot parameters ``log_defaults`` reads (live asks its vehicle)

    @classmethod
    def log_defaults(cls, params: dict, vehicle: str) -> dict[str, tuple[object, str]]:
        """Parameter defaults a flight supplies, from its autopilot parameters (name -> value)
        and its vehicle ("ArduPlane", ...): field -> (value, what it is, from where: said after
        "NAME FIELD VALUE" in the replay's notes). ``params.log_defaults`` applies them where
        the user set nothing. None unless a class says."""
        return {}

    def __init_subclass__(cls, **kwargs):
        super().__init_subclass__(**kwargs)
        if "uses_mag" not in cls.__dict__ and is_dataclass(cls.Params):
            cls.uses_mag = any(f.name == "use_mag" for f in fields(cls.Params))

    def run_params(self):
        """The parameters the filter runs with: ``params``, or with ``strict`` set, ``params``
        with the paper's published values (``PAPER``) whatever they say."""
        return replace(self.params, **self.PAPER) if getattr(self.params, "strict", False) else self.params

    def __init__(self, params=None, declination: float = 0.0):
        self.params = params if params is not None else self.Params()
        self.declination = float(declination)  # rad, east positive: true = magnetic + declination
        self.initialized = False
        self.diagnostics: dict[str, np.ndarray] = {}  # per-sample series of the last update
        self._accel_lowpass = None  # inertial_accel's state, when the filter takes the low-passed reading
        self._accel_tau = 0.0

    def initialize(self, q0, gyro_bias, accel_g: float = GRAVITY) -> None:
        """Start from attitude ``q0`` with gyro bias ``gyro_bias`` (rad/s) already known, and
        ``accel_g`` (m/s²) the accelerometer's reading of g at rest (``gravity``), which a
        filter that compares ‖a‖ with g takes for g unless ``strict``."""
        raise NotImplementedError

    def update(self, t, gyro, accel, mag, in_air=None, aiding=None) -> np.ndarray:
        """Process a chunk of samples; returns the attitude after each one, (N, 4).
        ``aiding``: the chunk's ``aiding.Aiding`` rows, or None; an estimator without
        ``uses_aiding`` ignores it. Here: the inputs as the kernels take them (``_chunk``; no
        compass for a filter without ``uses_mag``), then ``_run``."""
        s = self._chunk(t, gyro, accel, mag if self.uses_mag else None, in_air)
        out = np.empty((len(s.t), 4))
        self.diagnostics = self._run(s, out, aiding)
        return out

    def _run(self, s: Samples, out: np.ndarray, aiding) -> dict[str, np.ndarray]:
        """Run the filter over chunk ``s`` (``Samples``), the attitudes into ``out`` (N, 4);
        returns the chunk's diagnostics. What an estimator that keeps ``update`` as it is defines."""
        raise NotImplementedError

    def _chunk(self, t, gyro, accel, mag, in_air=None) -> Samples:
        """The inputs as the compiled kernels want them (``as_chunk``), once ``initialize``
        has given the filter a state to start from; the accelerometer low-passed in an
        almost-inertial frame where ``_start_accel_lowpass`` turned that on."""
        if not self.initialized:
            raise RuntimeError(f"{self.name}: call initialize(q0, gyro_bias) before update()")
        s = as_chunk(t, gyro, accel, mag, in_air, self.rate_over_step)
        if self._accel_lowpass is None:
            return s
        return s._replace(accel=inertial_accel.lowpass_in_inertial_frame(
            s, self._accel_lowpass, self._accel_tau, MAX_STEP_S, np.empty_like(s.accel)))

    def _start_accel_lowpass(self, q0, gyro_bias, tau: float) -> None:
        """From ``initialize``: take the accelerometer low-passed with time constant ``tau`` (s) in
        an almost-inertial frame (``inertial_accel``) from now on; 0: the reading as it is."""
        self._accel_tau = float(tau)
        self._accel_lowpass = inertial_accel.start(q0, gyro_bias) if tau > 0 else None

    def _ready(self, q0, gyro_bias) -> None:
        """The end of ``initialize``: the accelerometer low-passed as ``accel_tau`` says (``run_params``:
        strict turns it off where the paper's ``PAPER`` does), and the filter ready for ``update``."""
        self._start_accel_lowpass(q0, gyro_bias, self.run_params().accel_tau)
        self.initialized = True

    @property
    def covariance(self) -> np.ndarray | None:
        """The current state covariance (a copy): the ``P`` of the filter's state where it has one
        (``FilterState`` and the like), else None."""
        P = getattr(getattr(self, "_state", None), "P", None)
        return None if P is None else P.copy()

    def has_heading_reference(self, mag_available: bool) -> bool:
        """Whether yaw is observed (magnetometer) rather than integrated from the gyro alone:
        the estimator can use one, the log has one, and its ``use_mag`` parameter (if it has
        that parameter) does not turn it off."""
        return self.uses_mag and mag_available and bool(getattr(self.params, "use_mag", True))

    def accel_scale_effect(self, scale_error: float) -> str | None:
        """What an accelerometer that reads g at rest as (1 + ``scale_error``) g does to this
        estimator, in a few words for a warning (``imucheck``); None: nothing worth saying (it
        takes the reading's direction only, or learns the scale)."""
        return None


# The first compile of an estimator whose class states no ``compile_seconds`` (about a Kalman
# filter's of ours), for the order the work is handed out in.
DEFAULT_COMPILE_S = 5.0


class Marked(NamedTuple):
    """A diagnostic that marks events, 1.0 at each (cpf-ekf's watchdog ``reset``): a warning
    at each, and their count and times in the JSON's per-estimator events."""
    text: str  # the warning, after "NAME: "
    kind: str  # what its repeats share on one terminal line (``events.Event.kind``), after "NAME: "
    counted_as: str  # its key among the estimator's events in the JSON: {count, times}


def needs_compile(estimator_classes) -> list[str]:
    """Names of the estimators whose compiled kernels are not in numba's cache yet."""
    return [cls.name for cls in estimator_classes if not all(cached(kernel) for kernel in cls.kernels)]


class FilterState(NamedTuple):
    """What a Kalman filter carries from one chunk to the next (arrays, updated in place)."""
    q: np.ndarray  # (4,) attitude, body -> NED
    P: np.ndarray  # the state covariance
    t_prev: np.ndarray  # (1,) the last sample's time, NaN before the first
    gyro_prev: np.ndarray  # (3,) the last gyro sample, rad/s
    bias: np.ndarray  # (3,) the still-period gyro bias, rad/s


def filter_state(q0, P0: np.ndarray, gyro_bias) -> FilterState:
    q0 = np.array(q0, dtype=np.float64)
    return FilterState(q0 / np.linalg.norm(q0), np.array(P0, dtype=np.float64), np.array([np.nan]), np.zeros(3),
                       np.array(gyro_bias, dtype=np.float64).reshape(3))


def run_with_trace(kernel, s, state, settings, out) -> dict[str, np.ndarray]:
    """``_run`` of a Kalman filter whose kernel writes trace(P) after each sample (ekf, eskf):
    ``kernel(s, state, settings, out, cov_trace)``; the diagnostics."""
    cov_trace = np.empty(len(s.t))
    kernel(s, state, settings, out, cov_trace)
    return {"cov_trace": cov_trace}


class Samples(NamedTuple):
    """A chunk of inputs as every compiled kernel takes them: contiguous float64, SI."""
    t: np.ndarray  # (N,) s
    gyro: np.ndarray  # (N, 3) rad/s
    accel: np.ndarray  # (N, 3) m/s²: what the filter takes (low-passed where inertial_accel is on)
    mag: np.ndarray  # (N, 3) tesla, NaN where none
    in_air: np.ndarray  # (N,) 1.0 air, 0.0 ground, NaN unknown
    rate_over_step: bool  # each gyro sample is the mean rate over the step ending at it (see step_rate)
    accel_read: np.ndarray  # (N, 3) m/s²: the reading as it is, where ``accel`` is low-passed (inertial_accel)


def as_chunk(t, gyro, accel, mag, in_air=None, rate_over_step: bool = False) -> Samples:
    """Contiguous float64 arrays, as the compiled kernels want them; absent inputs become NaN."""
    t = np.ascontiguousarray(t, dtype=np.float64)
    n = len(t)
    gyro = np.ascontiguousarray(gyro, dtype=np.float64).reshape(n, 3)
    accel = np.ascontiguousarray(accel, dtype=np.float64).reshape(n, 3)
    if mag is None:
        mag = np.full((n, 3), np.nan)
    mag = np.ascontiguousarray(mag, dtype=np.float64).reshape(n, 3)
    if in_air is None:
        in_air = np.full(n, np.nan)
    in_air = np.ascontiguousarray(in_air, dtype=np.float64).reshape(n)
    return Samples(t, gyro, accel, mag, in_air, bool(rate_over_step), accel)
