"""Events on the time plots: the events tab's text log, a marker at each warning and take-off or
landing, and a bar along the top of every attitude and error plot over each span the data
cannot be trusted (a gap in the IMU, a stretch of untrusted reference), named by what happened
so that hovering the bar says it."""
from __future__ import annotations

from collections.abc import Sequence

import numpy as np
import rerun as rr

from ..events import Event
from ..scoring.metrics import AXES
from .columns import _time, log_bars

_LEVELS = {"info": rr.TextLogLevel.INFO, "warn": rr.TextLogLevel.WARN,
           "warning": rr.TextLogLevel.WARN, "error": rr.TextLogLevel.ERROR,
           "debug": rr.TextLogLevel.DEBUG}

EVENT_MARKERS = {  # which events get a marker on the time plots, and its look
    "warnings": ((215, 40, 40), "Down"),  # gaps, restarts, resets, an untrusted reference, ...
    "phase": ((120, 120, 120), "Circle"),  # take-off and landing
}
SPAN_COLOR = (215, 40, 40, 110)  # a translucent red bar: the lines under it stay visible
SPAN_WIDTH = 7.0  # ui points: a bar, not a line
MAX_NAMED_SPANS = 24  # each its own entity (its own hover text); the rest share one


def marks_path(plot: str, axis: str) -> str:
    """``marks/attitude/<axis>`` or ``marks/error/<axis>``: what the plot of that axis shows besides the series."""
    return f"marks/{plot}/{axis}"


def log_events(rec: rr.RecordingStream, events: Sequence[Event], path: str = "events") -> None:
    """Events as a TextLog, in one columnar call."""
    if not events:
        return
    ev = sorted(events, key=lambda e: e.t)
    levels = [_LEVELS.get(e.level.lower(), e.level.upper()) for e in ev]
    rec.send_columns(path, indexes=[_time([e.t for e in ev])],
                     columns=rr.TextLog.columns(text=[e.text for e in ev], level=levels))


def log_event_markers(rec: rr.RecordingStream, events: Sequence[Event], top_deg: dict[str, float],
                      plot: str = "attitude") -> None:
    """A marker on each plot of ``plot`` near its top (``top_deg``: axis -> y), at each warning
    and each change of the ground/air phase: where to look; the events tab says what happened."""
    kinds = {"warnings": [e.t for e in events if e.level == "warn"],
             "phase": [e.t for e in events if e.text.startswith(("in the air", "on the ground"))]}
    for kind, times in kinds.items():
        if not times:
            continue
        color, marker = EVENT_MARKERS[kind]
        t = np.sort(np.asarray(times, dtype=np.float64))
        for axis in AXES:
            path = f"{marks_path(plot, axis)}/{kind}"
            rec.log(path, rr.SeriesPoints(colors=[color], markers=[marker], marker_sizes=[5.0],
                                          names=["warning (events tab)" if kind == "warnings" else "take-off, landing"]),
                    static=True)
            rec.send_columns(path, indexes=[_time(t)],
                             columns=rr.Scalars.columns(scalars=np.full(len(t), top_deg.get(axis, 175.0))))


def log_spans(rec: rr.RecordingStream, spans: Sequence[tuple[float, float, str]], top_deg: dict[str, float],
              plot: str = "attitude") -> None:
    """A bar at ``top_deg`` over each (start, end, text) span, named by its text (the hover
    shows it); past ``MAX_NAMED_SPANS`` the remaining spans share one bar."""
    spans = sorted(spans)
    groups = [[sp] for sp in spans[:MAX_NAMED_SPANS]]
    if len(spans) > MAX_NAMED_SPANS:
        groups.append(spans[MAX_NAMED_SPANS:])
    for i, group in enumerate(groups):
        name = group[0][2] if len(group) == 1 else f"{len(group)} more spans (events tab)"
        for axis in AXES:
            log_bars(rec, f"{marks_path(plot, axis)}/spans/{i:02d}", [a for a, _, _ in group], [b for _, b, _ in group],
                     top_deg.get(axis, 175.0), SPAN_COLOR, SPAN_WIDTH, name)
