"""The board trim: ArduPilot reports the vehicle's attitude, the board's turned by AHRS_TRIM_X/Y.

The estimators estimate the board's attitude; scored against the autopilot's (which is the
vehicle's), they are turned by the same trim first, in replay and live alike.
"""
from __future__ import annotations

import math

from . import quaternion as quat
from .flight import AttitudeSeries

TRIM_PARAMS = ("AHRS_TRIM_X", "AHRS_TRIM_Y")  # rad: roll, pitch (ArduPilot 3.1 on)


def board_trim(params: dict) -> tuple[float, float] | None:
    """AHRS_TRIM_X / AHRS_TRIM_Y (rad: roll, pitch) of the autopilot's parameters, when either is
    non-zero.

    ArduPilot reports the attitude of the vehicle body, the board's turned by the trim
    (AP_AHRS: body DCM = DCM · R(trim)ᵀ, R(trim) from the Euler angles (trim_x, trim_y, 0);
    AHRS_TRIM_Z is unused there); the estimators estimate the board's. The IMU is logged after
    AHRS_ORIENTATION is applied, so that needs nothing here."""
    roll, pitch = params.get(TRIM_PARAMS[0], 0.0), params.get(TRIM_PARAMS[1], 0.0)
    if not (math.isfinite(roll) and math.isfinite(pitch)) or (roll == 0.0 and pitch == 0.0):
        return None
    return float(roll), float(pitch)


def trimmed(series: AttitudeSeries, trim: tuple[float, float]) -> AttitudeSeries:
    """The attitude of the vehicle body from the board's, as the autopilot does (``quaternion.trimmed``)."""
    return AttitudeSeries(series.source, series.t, quat.trimmed(series.q, *trim))


def describe(trim: tuple[float, float]) -> str:
    return f"roll {math.degrees(trim[0]):.2f}°, pitch {math.degrees(trim[1]):.2f}°"
