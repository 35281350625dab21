"""Colours, entity paths and the limits every part of the view shares."""
from __future__ import annotations

import math
from collections.abc import Iterable, Sequence

import numpy as np
import rerun as rr
import rerun.blueprint as rrb

TIMELINE = "time"

SCALAR_MAX_HZ = 200.0
SCALAR_MAX_POINTS = 240_000
TRANSFORM_MAX_HZ = 50.0
TRANSFORM_MAX_POINTS = 90_000
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

# Every colour reads on both the viewer's light and dark themes (mid luminance), so the
# autopilot is a neutral grey rather than black or white.
AUTOPILOT_COLOR: Color = (140, 140, 140)
REFERENCE_COLOR: Color = (100, 125, 150)  # a reference that is neither autopilot nor truth
TRUTH_COLOR: Color = (40, 170, 70)
GHOST_COLOR = (110, 110, 110, 220)
TRACK_COLOR: Color = (230, 40, 140)
POSITION_COLOR: Color = (20, 70, 230)
ESTIMATOR_COLORS: dict[str, Color] = {  # fixed per known estimator (ALGORITHMS.md)
    "mahony": (255, 140, 0),
    "mahony-ekf": (215, 170, 0),
    "ekf": (30, 136, 229),
    "eskf": (142, 60, 200),
    "ncs-eskf": (233, 30, 99),
    "eq-kf": (0, 170, 190),
    "cpf-ekf": (215, 50, 40),
}
FALLBACK_COLORS: tuple[Color, ...] = (
    (255, 140, 0), (30, 136, 229), (233, 30, 99), (0, 170, 190), (142, 60, 200),
    (215, 170, 0), (215, 50, 40), (140, 100, 60), (90, 110, 255), (190, 90, 180),
)
ROLE_COLORS: dict[str, Color] = {
    "autopilot": AUTOPILOT_COLOR, "truth": TRUTH_COLOR, "reference": REFERENCE_COLOR,
}
STREAM_PREFIX = "autopilot:"  # the autopilot's other streams: "autopilot:EKF1 (EKF1)" (pipeline.stream_row)
# muted, as the autopilot's grey
STREAM_COLORS: tuple[Color, ...] = ((120, 100, 80), (90, 140, 160), (160, 120, 150), (110, 150, 110))


def is_role(name: str) -> bool:
    """The autopilot (any of its streams), the truth or another reference: drawn as references are."""
    return name in ROLE_COLORS or name.startswith(STREAM_PREFIX)


def assign_colors(names: Iterable[str]) -> dict[str, Color]:
    """A fixed colour per series: roles and known estimators by name, others from a palette
    (in the order given, skipping colours already taken)."""
    names = list(names)
    out: dict[str, Color] = {}
    streams = [n for n in names if n.startswith(STREAM_PREFIX)]
    for n in names:
        if n in ROLE_COLORS:
            out[n] = ROLE_COLORS[n]
        elif n in streams:
            out[n] = STREAM_COLORS[streams.index(n) % len(STREAM_COLORS)]
        elif n in ESTIMATOR_COLORS:
            out[n] = ESTIMATOR_COLORS[n]
    free = [c for c in FALLBACK_COLORS if c not in out.values()] or list(FALLBACK_COLORS)
    i = 0
    for n in names:
        if n not in out:
            out[n] = free[i % len(free)]
            i += 1
    return out


# ---------------------------------------------------------------- entity paths


def _part(name: str) -> str:
    return rr.escape_entity_path_part(str(name))


def attitude_path(axis: str, name: str) -> str:
    """The estimates under ``estimates/``, the autopilot and truth under ``reference/``: the
    viewer draws a plot's series in path order, so these come last, on top."""
    group = "reference" if is_role(name) else "estimates"
    return f"attitude/{axis}/{group}/{_part(name)}"


def error_path(axis: str, name: str, scored: bool = True) -> str:
    return f"error/{axis}/{_part(name)}" if scored else f"error/{axis}/_unscored/{_part(name)}"


def body_path(name: str) -> str:
    return f"world/{_part(name)}/body"


def ghost_path(name: str) -> str:
    return f"world/{_part(name)}/reference"


