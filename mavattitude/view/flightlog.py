"""What the log says happened (``Flight.modes``, ``arming``, ``messages``) on the view: a band
plot above the time plots, on their time axis, with a bar per flight mode (coloured and named
by the mode: the legend names the colours, the hover the bar), a bar while armed, and a dot per
text line (red for errors, orange for warnings) named by its text; and the same as lines in the
events tab.

- ``log/modes/<k>``  SeriesLines at y = 2, a bar over each span of the k-th mode flown, named by it
- ``log/armed``  SeriesLines at y = 1 over each armed span
- ``log/lines/<k>``  SeriesPoints at y = 0: one text line each, named by it (the hover shows it);
  past ``MAX_NAMED_LINES`` the rest share one entity per level
"""
from __future__ import annotations

import numpy as np
import rerun as rr

from ..events import Event
from ..flight import Flight
from .columns import _time, log_bars

BAND = "log"
MODE_Y, ARMED_Y, LINE_Y = 2.0, 1.0, 0.0
BAND_RANGE = (-0.7, 2.7)
MODE_WIDTH, ARMED_WIDTH = 12.0, 6.0  # ui points: bars in a band ~70 px tall
ARMED_COLOR = (90, 90, 90)
# Muted, light colours: bars behind nothing, apart from the estimators' saturated lines
MODE_COLORS = ((141, 182, 220), (240, 170, 110), (150, 200, 140), (205, 150, 200), (225, 205, 110),
               (160, 210, 210), (210, 150, 140), (175, 175, 230), (200, 200, 160), (150, 170, 150))
LINE_COLORS = {"error": (215, 40, 40), "warn": (235, 140, 0), "info": (120, 120, 120)}
MAX_NAMED_LINES = 40  # each its own entity (its own hover text)


def has_band(flight: Flight) -> bool:
    return any(s is not None and len(s.t) for s in (flight.modes, flight.arming, flight.messages))


def _level(severity: int) -> str:
    """MAVLink severity -> the events tab's level: 0-3 error, 4 warning, 5-7 info."""
    return "error" if severity <= 3 else "warn" if severity == 4 else "info"


def flight_events(flight: Flight) -> list[Event]:
    """The log's modes, arming and text lines as events for the events tab, marked "(log)"."""
    out = []
    if flight.modes is not None:
        out += [Event(float(t), "info", f"mode {name} (log)", "log-mode") for t, name in zip(flight.modes.t, flight.modes.label)]
    if flight.arming is not None:
        out += [Event(float(t), "info", f"{name} (log)", "log-arming") for t, name in zip(flight.arming.t, flight.arming.label)]
    if flight.messages is not None:
        out += [Event(float(t), _level(int(v)), f"log: {text}", "log-text")
                for t, v, text in zip(flight.messages.t, flight.messages.value, flight.messages.label)]
    return out


def log_flight_band(rec: rr.RecordingStream, flight: Flight) -> None:
    """The band's entities (see the module docstring)."""
    end = flight.time_span[1]
    if flight.modes is not None:
        by_mode: dict[str, list] = {}
        for a, b, _, name in flight.modes.spans(end):
            by_mode.setdefault(name, []).append((a, b))
        for k, (name, spans) in enumerate(by_mode.items()):
            log_bars(rec, f"{BAND}/modes/{k:02d}", [a for a, _ in spans], [b for _, b in spans], MODE_Y,
                     MODE_COLORS[k % len(MODE_COLORS)], MODE_WIDTH, name)
    if flight.arming is not None:
        armed = [(a, b) for a, b, v, _ in flight.arming.spans(end) if v]
        if armed:
            log_bars(rec, f"{BAND}/armed", [a for a, _ in armed], [b for _, b in armed], ARMED_Y, ARMED_COLOR,
                     ARMED_WIDTH, "armed")
    if flight.messages is not None:
        rows = sorted(zip(flight.messages.t.tolist(), flight.messages.value.tolist(), flight.messages.label))
        groups = [([t], _level(v), text) for t, v, text in rows[:MAX_NAMED_LINES]]
        rest: dict[str, list] = {}
        for t, v, _ in rows[MAX_NAMED_LINES:]:
            rest.setdefault(_level(v), []).append(t)
        groups += [(times, level, f"{len(times)} more {level} lines (events tab)") for level, times in rest.items()]
        for k, (times, level, text) in enumerate(groups):
            path = f"{BAND}/lines/{k:02d}"
            rec.log(path, rr.SeriesPoints(colors=[LINE_COLORS[level]], markers=["Diamond"], marker_sizes=[4.0],
                                          names=[text[:100]]), static=True)
            rec.send_columns(path, indexes=[_time(np.asarray(times, dtype=np.float64))],
                             columns=rr.Scalars.columns(scalars=np.full(len(times), LINE_Y)))
