"""What every attitude estimator offers, for whole-log replay and live stepping alike.

An estimator is created with its parameters and the magnetic declination, initialised once
with an attitude and a gyro bias (see ``alignment``), then fed consecutive chunks of IMU
samples. Replay sends the whole log as one chunk; live use sends what has arrived. The
state carries over between calls, and the compiled kernel is the same, so both give the
same numbers.

Inputs are SI on the autopilot clock: ``t`` (N,) s, ``gyro`` (N, 3) rad/s, ``accel`` (N, 3)
m/s² specific force, ``mag`` (N, 3) tesla with NaN rows where no fresh magnetometer sample
exists. Output: (N, 4) quaternions [w, x, y, z], body FRD -> NED.
"""
from __future__ import annotations

import os
from dataclasses import dataclass, fields

import numpy as np

# A step longer than this is a gap in the data, not an interval to integrate the gyro over.
MAX_STEP_S = 1.5


class Estimator:
    name: str = ""
    Params: type = None  # a dataclass of tunable parameters with the paper's defaults
    uses_mag: bool = False  # can take its heading from the magnetometer
    kernels: tuple = ()  # the numba functions it runs, to tell when a first run must compile them

    def __init__(self, params=None, declination: float = 0.0):
        self.params = params if params is not None else self.Params()
        self.declination = float(declination)  # rad, east positive: true = magnetic + declination
        self.initialized = False

    def initialize(self, q0, gyro_bias) -> None:
        """Start from attitude ``q0`` with gyro bias ``gyro_bias`` (rad/s) already known."""
        raise NotImplementedError

    def update(self, t, gyro, accel, mag) -> np.ndarray:
        """Process a chunk of samples; returns the attitude after each one, (N, 4)."""
        raise NotImplementedError

    def has_heading_reference(self, mag_available: bool) -> bool:
        """Whether yaw is observed (magnetometer) rather than integrated from the gyro alone."""
        return self.uses_mag and mag_available


def needs_compile(estimator_classes) -> list[str]:
    """Names of the estimators whose compiled kernels are not in numba's cache yet."""
    pending = []
    for cls in estimator_classes:
        for kernel in cls.kernels:
            cache = getattr(kernel, "_cache", None)
            index = getattr(getattr(cache, "_cache_file", None), "_index_path", None)
            if index is not None and not os.path.exists(index):
                pending.append(cls.name)
                break
    return pending


def params_table(params) -> dict:
    return {f.name: getattr(params, f.name) for f in fields(params)}


def as_chunk(t, gyro, accel, mag):
    """Contiguous float64 arrays, as the compiled kernels want them."""
    t = np.ascontiguousarray(t, dtype=np.float64)
    n = len(t)
    gyro = np.ascontiguousarray(gyro, dtype=np.float64).reshape(n, 3)
    accel = np.ascontiguousarray(accel, dtype=np.float64).reshape(n, 3)
    if mag is None:
        mag = np.full((n, 3), np.nan)
    mag = np.ascontiguousarray(mag, dtype=np.float64).reshape(n, 3)
    return t, gyro, accel, mag
