"""Colours, entity paths and the limits every part of the view shares."""
from __future__ import annotations

from collections.abc import Iterable

import rerun as rr

TIMELINE = "time"

# the rates of the time plots and the 3D boxes: ``decimation`` (which does not import Rerun)
from .decimation import SCALAR_MAX_HZ, SCALAR_MAX_POINTS, TRANSFORM_MAX_HZ, TRANSFORM_MAX_POINTS  # noqa: E402,F401
DIAGNOSTIC_MAX_HZ = 10.0  # diagnostics drift slowly; min/max bins keep a reset's one-sample spike
GPS_MARKER_MAX_HZ = 10.0
GPS_TRACK_MAX_POINTS = 5_000

# 3D layout
REFERENCE_WIDTH = 3.0  # the reference's lines: thicker than the estimates they are drawn over
SLOT_SPACING = 2.5  # metres (arbitrary units) between boxes, along east
SLOTS_PER_ROW = 4  # boxes in a row: eight in one row would each be a few pixels wide
ROW_SPACING = 3.0  # metres between rows, along north (behind the first, seen from above)
BOX_HALF_SIZES = (0.75, 0.5, 0.12)  # forward, right, down: a flat, nose-long box
AXIS_LENGTH = 1.1

# ---------------------------------------------------------------- colours

Color = tuple[int, int, int]

# Every colour reads on both the viewer's light and dark themes (CIE L* 40-72), so the
# autopilot is a neutral grey rather than black or white. The palette was picked greedily for
# the largest smallest CIEDE2000 difference between any two of the sixteen colours a replay can
# show at once (nine estimators, autopilot, truth, another reference, four autopilot streams):
# at least 19 (tests/test_view_layout.py), where the previous one had 14 (ekf / imufusion) and
# 16 among the seven of the papers (ncs-eskf / cpf-ekf). The estimators' own are in their classes.
AUTOPILOT_COLOR: Color = (140, 140, 140)
REFERENCE_COLOR: Color = (105, 90, 120)  # a reference that is neither autopilot nor truth
TRUTH_COLOR: Color = (40, 170, 70)
GHOST_COLOR = (110, 110, 110, 220)
TRACK_COLOR: Color = (40, 40, 40)  # the GPS track: near black, no estimator's colour
POSITION_COLOR: Color = (20, 70, 230)
# An estimator's colour is its class's (``Estimator.color``); one whose class states none takes
# the first of these not in use (in the order given), then the other estimators' colours.
SPARE_COLORS: tuple[Color, ...] = ((255, 135, 135), (180, 165, 0), (165, 165, 225), (150, 105, 90))
ROLE_COLORS: dict[str, Color] = {
    "autopilot": AUTOPILOT_COLOR, "truth": TRUTH_COLOR, "reference": REFERENCE_COLOR,
}
STREAM_PREFIX = "autopilot:"  # the autopilot's other streams: "autopilot:EKF1 (EKF1)" (commands.replay.stream_row)
STREAM_COLORS: tuple[Color, ...] = ((180, 165, 0), (255, 135, 135), (165, 165, 225), (150, 105, 90))


def is_role(name: str) -> bool:
    """The autopilot (any of its streams), the truth or another reference: drawn as references are."""
    return name in ROLE_COLORS or name.startswith(STREAM_PREFIX)


def assign_colors(names: Iterable[str]) -> dict[str, Color]:
    """A fixed colour per series: roles by name, estimators as their classes say, others from
    a palette (in the order given, skipping colours already taken)."""
    from ..estimators import ESTIMATORS

    stated = {n: tuple(cls.color) for n, cls in ESTIMATORS.items() if cls.color is not None}
    names = list(names)
    out: dict[str, Color] = {}
    streams = [n for n in names if n.startswith(STREAM_PREFIX)]
    for n in names:
        if n in ROLE_COLORS:
            out[n] = ROLE_COLORS[n]
        elif n in streams:
            out[n] = STREAM_COLORS[streams.index(n) % len(STREAM_COLORS)]
        elif n in stated:
            out[n] = stated[n]
    spare = (*SPARE_COLORS, *stated.values())
    free = [c for c in spare if c not in out.values()] or list(spare)
    i = 0
    for n in names:
        if n not in out:
            out[n] = free[i % len(free)]
            i += 1
    return out


# ---------------------------------------------------------------- entity paths


def _part(name: str) -> str:
    return rr.escape_entity_path_part(str(name))


# One subtree per series: ``est/<s>`` for an estimate, ``ref/<s>`` for the reference, the
# autopilot and the truth, ``alt/<s>`` for the autopilot's other streams. Everything a series draws (its attitude and error
# lines, its box and ghost in 3D, its track, its diagnostics) lives under it, so hiding that one
# entity (in the blueprint panel: "Hide in all views") hides the series in every view. The
# viewer draws a plot's series in path order: ``alt`` first (context), then ``est``,
# ``ref`` last: the references on top.


def series_root(name: str) -> str:
    group = "alt" if name.startswith(STREAM_PREFIX) else "ref" if is_role(name) else "est"
    return f"{group}/{_part(name)}"


def attitude_path(axis: str, name: str) -> str:
    return f"{series_root(name)}/attitude/{axis}"


def error_path(axis: str, name: str, scored: bool = True) -> str:
    """The scored error samples, or the warm-up's (faded, named as the scored line)."""
    return f"{series_root(name)}/{'error' if scored else 'warmup'}/{axis}"


def slot_path(name: str) -> str:
    return f"{series_root(name)}/box"


def body_path(name: str) -> str:
    return f"{slot_path(name)}/body"


def ghost_path(name: str) -> str:
    return f"{slot_path(name)}/reference"


# ---------------------------------------------------------------- diagnostics

DIAGNOSTIC_TITLES = {
    "cov_trace": "covariance trace",
    "accel_state": "accelerometer update (0 used, 1+ skipped / down-weighted)",
    "accel_states": "accelerometer update: bars where not used (legend: why)",
    "adaptive_r": "mahony-ekf adaptive R",
    "accel_weight": "accelerometer trust w (1 full, 0 skipped)",
    "reset": "watchdog reset (1 at a reset)",
    "watchdog_distance": "EKF vs complementary filter, Σ Δangle² (rad²)",
    "gyro_bias": "gyro bias (°/s)",
    "accel_bias": "z-accelerometer bias (m/s²)",
    "mag_bias": "magnetometer bias (mGauss)",
    "earth_field": "earth field NED (mGauss)",
    "vel": "velocity NED (m/s)",
    "pos": "position NED (m)",
    "innov_mag": "magnetometer innovation (mGauss)",
    "innov_gps_vel": "GPS velocity innovation (m/s)",
    "innov_gps_pos": "GPS position innovation (m)",
    "innov_baro": "baro height innovation (m)",
    "mahony_weight": "weight of the internal Mahony's gravity error (1 at rest, 0-1)",
    "h_residual": "horizontal manoeuvre acceleration (g)",
    "h_gate": "horizontal acceleration threshold applied (g)",
}
STATE_GROUP = "accel_states"  # a replay's accel_state codes as spans (``columns.log_state_spans``)
COMPASS_GROUPS = ("mag_bias", "earth_field", "innov_mag")  # not plotted without a compass
AXIS_SUFFIXES = ("x", "y", "z", "n", "e", "d")
AXIS_COLORS: dict[str, Color] = {"x": (220, 60, 60), "n": (220, 60, 60), "y": (50, 160, 60),
                                  "e": (50, 160, 60), "z": (40, 100, 230), "d": (40, 100, 230)}


def diagnostic_group(key: str) -> tuple[str, str | None]:
    """("gyro_bias", "x") for "gyro_bias_x": the vector a key belongs to and its axis;
    (key, None) for a key of its own."""
    head, _, tail = key.rpartition("_")
    return (head, tail) if head and tail in AXIS_SUFFIXES else (key, None)


def diagnostic_path(key: str, name: str) -> str:
    group, axis = diagnostic_group(key)
    path = f"{series_root(name)}/diagnostics/{_part(group)}"
    return f"{path}/{axis}" if axis else path
