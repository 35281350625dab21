"""What the plots open on: the flight, not a crash, a tip-over or a tumble at the end of the log.

A vehicle on its side or upside down for seconds (tilt beyond ``UPSET_TILT_DEG`` for
``UPSET_HOLD_S``, or near the log's end) has crashed, tipped over or been carried: the plots open
on the longest stretch between such upsets (copter-3.3-loiter-rtl.bin is on its side for 2.3 s
at 49 s, before take-off; the 3.2.1 upset log tumbles at its end). A flip passes through that tilt in well under a second and stays in. The
value plots' ranges are the reference's extremes over that span (in the air, outside the spans
of untrusted reference); the error plots' from the scored errors' spread, robustly: one
estimator that diverges (or tumbles with the vehicle) runs off its plot (it is in the table, and zooming out shows it) instead
of flattening everyone else's.
"""
from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from .. import quaternion as quat
from ..scoring.metrics import AXES

if TYPE_CHECKING:  # for types only: replay (commands.replay) is above the view and draws through it
    from ..commands.replay import ReplayResult

UPSET_TILT_DEG = 65.0  # beyond this the vehicle is not flying level enough to be in a normal flight
UPSET_HOLD_S = 2.0  # and staying there this long (a flip is a fraction of a second)
END_WINDOW_S = 5.0  # any tilt beyond it this close to the log's end: the tumble the log ends in
UPSET_MARGIN_S = 3.0  # the plots end this long before the upset starts (the roll into it included)
ERROR_QUANTILE = 99.0  # each comparison's |error| percentile; the range fits the second largest
ERROR_PAD = 1.3


def tilt_deg(q: np.ndarray) -> np.ndarray:
    """The angle between the body's down axis and the earth's (0 level, 180 upside down)."""
    q = np.asarray(q, dtype=np.float64)
    r22 = 1.0 - 2.0 * (q[:, 1] ** 2 + q[:, 2] ** 2)  # body z · NED z, for a unit quaternion
    return np.degrees(np.arccos(np.clip(r22, -1.0, 1.0)))


def upset_runs(t: np.ndarray, q: np.ndarray) -> list[tuple[float, float]]:
    """(start, end) of each stretch tilted beyond ``UPSET_TILT_DEG`` for ``UPSET_HOLD_S`` or
    more; a stretch of any length within ``END_WINDOW_S`` of the series' end runs to that end
    (the 3.2.1 upset log tumbles through 65° twice for a second each in its last 3 s)."""
    t = np.asarray(t, dtype=np.float64)
    if len(t) == 0:
        return []
    over = tilt_deg(q) > UPSET_TILT_DEG
    edges = np.flatnonzero(np.diff(np.concatenate([[False], over, [False]]).astype(np.int8)))
    out = []
    for a, b in zip(edges[::2], edges[1::2]):  # runs [a, b) of tilted samples
        if t[b - 1] >= t[-1] - END_WINDOW_S:
            out.append((float(t[a]), float(t[-1])))
            break
        if t[b - 1] - t[a] >= UPSET_HOLD_S:
            out.append((float(t[a]), float(t[b - 1])))
    return out


def upset_start(t: np.ndarray, q: np.ndarray) -> float | None:
    """When the vehicle first tilts beyond ``UPSET_TILT_DEG`` and stays (``upset_runs``); None when it never does."""
    runs = upset_runs(t, q)
    return runs[0][0] if runs else None


def _outside(t: np.ndarray, spans) -> np.ndarray:
    ok = np.ones(len(t), dtype=bool)
    for a, b in spans:
        ok &= ~((t >= a) & (t <= b))
    return ok


def scored_span(result: ReplayResult) -> tuple[float, float]:
    """From the first scored reference sample to the last (the flight, past the warm-up and
    the ground before it), or the whole log when nothing was scored."""
    times = [c.t[np.asarray(c.scored, dtype=bool)] for c in result.comparisons.values()]
    times = [t for t in times if len(t)]
    if not times:
        return result.flight.time_span
    return min(float(t[0]) for t in times), max(float(t[-1]) for t in times)


def open_span(result: ReplayResult) -> tuple[float, float]:
    """The span the time plots open on: the longest stretch of the scored span between upsets
    of the reference (``UPSET_MARGIN_S`` kept clear on either side): the flight, not the crash
    at its end nor the vehicle carried on its side before take-off."""
    a, b = scored_span(result)
    ref = result.reference
    if ref is None or not len(ref.t):
        return a, b
    cuts = [(u - UPSET_MARGIN_S, v + UPSET_MARGIN_S) for u, v in upset_runs(ref.t, ref.q)]
    pieces, start = [], a
    for u, v in sorted(cuts):
        pieces.append((start, min(u, b)))
        start = max(start, v)
    pieces.append((start, b))
    best = max(pieces, key=lambda p: p[1] - p[0])
    return best if best[1] - best[0] > 1.0 else (a, b)


def untrusted_spans(result: ReplayResult) -> list[tuple[float, float]]:
    return [(s.start, s.end) for s in result.suspects]


def attitude_ranges(result: ReplayResult, span: tuple[float, float]) -> dict[str, tuple[float, float]]:
    """Each value plot's range: the reference's extremes over ``span`` while in the air (all of
    it without a phase) and trusted, padded; a tumble outside the span would flatten the flight."""
    ref = result.reference
    if ref is None or not len(ref.t):
        return {}
    inside = (ref.t >= span[0]) & (ref.t <= span[1]) & _outside(ref.t, untrusted_spans(result))
    if result.phase is not None:
        flying = inside & (result.phase.on_clock(ref.t) == 1.0)
        inside = flying if flying.any() else inside
    if not inside.any():
        return {}
    euler = np.degrees(quat.to_euler(ref.q[inside]))
    out = {}
    for k, axis in enumerate(AXES):
        e = euler[np.isfinite(euler[:, k]), k]
        if len(e):
            lo, hi = float(e.min()), float(e.max())
            pad = max(5.0, 0.1 * (hi - lo))
            out[axis] = (max(lo - pad, -185.0), min(hi + pad, 185.0))
    return out


def error_ranges(comparisons: dict, span: tuple[float, float]) -> dict[str, float]:
    """Each error plot's half-range: per comparison the ``ERROR_QUANTILE`` of its scored |error|
    inside ``span``; the second largest of those (the largest with fewer than three comparisons),
    times ``ERROR_PAD``, at least 1°. One estimator that diverges runs off the plot."""
    out = {}
    for k, axis in enumerate(AXES):
        peaks = []
        for c in comparisons.values():
            t = np.asarray(c.t)
            keep = np.asarray(c.scored, dtype=bool) & (t >= span[0]) & (t <= span[1])
            e = np.abs(np.asarray(c.error_deg)[keep, k])
            e = e[np.isfinite(e)]
            if len(e):
                peaks.append(float(np.percentile(e, ERROR_QUANTILE)))
        if peaks:
            peaks.sort()
            out[axis] = ERROR_PAD * max(peaks[-2] if len(peaks) >= 3 else peaks[-1], 1.0)
    return out
