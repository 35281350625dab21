"""What a live session shows: the Rerun recording, streamed as it goes, and the terminal's
one-line status.

The recording has replay's layout and entity paths (``view``), laid out for following the
data, plus a "link" tab: ``rolling/<axis>/<s>`` (MAE over the last ``--window`` seconds),
``link/rate/<message>`` (arrivals per second), ``link/lost`` and ``link/bad`` (packets missing
by sequence number, corrupt data). Everything time-varying is on the autopilot clock and goes
out with ``send_columns``, batched: ``LiveView.push`` collects, ``flush`` sends (a few times a
second), so a 1 kHz IMU does not mean a thousand calls a second.
"""
from __future__ import annotations

import sys
from dataclasses import dataclass

import numpy as np
import rerun as rr

from .. import quaternion as quat
from .. import view
from ..growing import Growing
from ..scoring.metrics import AXES
from ..core.runner import Chunk
from ..live.estimation import LiveEstimation

@dataclass(frozen=True)
class Rates:
    """What the view gets of a live session (the metrics always use every sample): wall
    seconds between sends (each send is a chunk with its own schema: many small ones make a
    large file), and bins a second of the plots, the 3D boxes and diagnostics (an attitude
    keeps a bin's first sample; an error or a diagnostic its minimum and maximum, so a spike
    stays visible)."""
    flush_s: float
    scalar_hz: float
    transform_hz: float
    diagnostic_hz: float
    diagnostic_flush_s: float  # diagnostics (many series per filter) go out less often


# A viewer watching gets a smooth picture; a file (``--rrd``) what reads well when zoomed to a
# second, for about 310 MB an hour of 1 kHz data with all seven estimators
# (``scripts/live_rrd_size.py``; 700 MB at the viewer's rates).
VIEWER = Rates(flush_s=0.25, scalar_hz=100.0, transform_hz=25.0, diagnostic_hz=20.0, diagnostic_flush_s=2.0)
FILE = Rates(flush_s=10.0, scalar_hz=25.0, transform_hz=10.0, diagnostic_hz=5.0, diagnostic_flush_s=10.0)
STATUS_PERIOD_S = 1.0  # rolling metrics and link figures


class LiveView:
    """Streams a ``LiveEstimation`` to ``rec`` (a Rerun recording stream)."""

    def __init__(self, rec: rr.RecordingStream, estimation: LiveEstimation, window_s: float,
                 to_file: bool = False):
        self.rec = rec
        self.rates = FILE if to_file else VIEWER
        self._flushed_at = -np.inf
        self.est = estimation
        self.window_s = window_s
        names = estimation.names
        ref_key = "truth" if estimation.reference == "truth" else "autopilot"
        self.ref_key = ref_key
        self.series = [ref_key] + (["autopilot"] if ref_key == "truth" else []) + names
        self.colors = view.assign_colors(self.series)
        self.has_gps = False
        self.diagnostic_keys: dict[str, list[str]] = {}  # estimator -> its diagnostic keys
        self._send_blueprint()
        view.setup_world(rec)
        labels = {"autopilot": "autopilot (ATTITUDE)", "truth": "truth (SIMSTATE)"}
        for slot, key in enumerate(self.series):
            label = labels.get(key, key) + (" = reference" if key == ref_key else "")
            view.setup_series(rec, key, color=self.colors[key], label=label, slot=slot,
                              ghost=key != ref_key, errors=key in names, reference=key == ref_key)
        for axis, shade in zip(AXES, (1.0, 0.7, 0.45)):  # one colour per filter, an axis a shade
            for name in names:
                rec.log(f"rolling/{axis}/{view._part(name)}",
                        rr.SeriesLines(colors=[tuple(int(c * shade) for c in self.colors[name])],
                                       names=[f"{name} {axis}"], widths=[1.5]), static=True)
        self._pending: list[Chunk] = []
        self._diag_pending: list[Chunk] = []
        self._diag_sent_at = -np.inf
        self._status_at = -np.inf
        self._ref_sent = {"autopilot": -np.inf, "truth": -np.inf}
        self._gps_sent = 0  # GPS rows taken (of every one the segment received)
        self._track = Growing(2)  # lat, lon of the GPS track, thinned to GPS_TRACK_MAX_POINTS or so
        self._events_sent = 0
        self._segment = 0

    def _send_blueprint(self) -> None:
        view.send_blueprint(self.rec, series=self.series, scored=self.series[1:], has_gps=self.has_gps, live=True,
                            diagnostics=self.diagnostic_keys, live_window=self.window_s)

    def push(self, chunk: Chunk) -> None:
        self._pending.append(chunk)

    def status_due(self, now: float) -> bool:
        if now - self._status_at >= STATUS_PERIOD_S:
            self._status_at = now
            return True
        return False

    def flush(self, now: float | None = None) -> None:
        """Send what arrived since the last flush, if the flush period has passed since then
        (``now``: monotonic s; None: now, whatever the period)."""
        if now is not None and now - self._flushed_at < self.rates.flush_s:
            return
        self._flushed_at = now if now is not None else self._flushed_at
        rec, est = self.rec, self.est
        seg = est.seg
        if seg.index != self._segment:  # a reboot: the clock starts again
            self._segment = seg.index
            self._ref_sent = {k: -np.inf for k in self._ref_sent}
            self._gps_sent = 0
        chunks, self._pending = self._pending, []
        self._diag_pending += chunks
        if chunks:  # one send per entity for all the chunks since the last flush
            t = np.concatenate([c.t for c in chunks])
            for name in est.names:
                q = np.vstack([c.q[name] for c in chunks])
                offset = est.yaw_offset_deg(name)
                if offset:  # no heading reference: shown as it is scored
                    q = quat.yaw_turned(q, -np.radians(offset))
                view.log_attitude_columns(rec, name, t, q, scalar_max_hz=self.rates.scalar_hz,
                                          transform_max_hz=self.rates.transform_hz)
        if now is None or now - self._diag_sent_at >= self.rates.diagnostic_flush_s:
            self._diag_sent_at = now if now is not None else self._diag_sent_at
            self._flush_diagnostics()
        for key, series in (("truth", est.reference_series() if self.ref_key == "truth" else None),
                            ("autopilot", est.autopilot_series())):
            if series is None:
                continue
            new = series.t > self._ref_sent[key]
            if new.any():
                ghosts = [k for k in self.series if k != self.ref_key] if key == self.ref_key else ()
                view.log_attitude_columns(rec, key, series.t[new], series.q[new], ghost_in=ghosts,
                                          scalar_max_hz=self.rates.scalar_hz,
                                          transform_max_hz=self.rates.transform_hz)
                self._ref_sent[key] = float(series.t[-1])
        for name in est.names:
            got = est.take_errors(name)
            if got is not None:
                view.log_error_columns(rec, name, *got, max_hz=self.rates.scalar_hz)
        self._flush_gps()
        self._flush_events()

    def _flush_diagnostics(self) -> None:
        chunks, self._diag_pending = self._diag_pending, []
        if not chunks:
            return
        rec, names = self.rec, self.est.names
        changed = False
        for name in names:
            known = self.diagnostic_keys.setdefault(name, [])
            new = [k for k in dict.fromkeys(k for c in chunks for k in c.diagnostics.get(name, {})) if k not in known]
            if new:
                known += new
                view.setup_diagnostics(rec, name, new, color=self.colors[name])
                changed = True
        if changed:
            self._send_blueprint()
        t = np.concatenate([c.t for c in chunks])
        for name in names:
            keys = chunks[-1].diagnostics.get(name, {})
            diagnostics = {k: np.concatenate([c.diagnostics[name][k] for c in chunks]) for k in keys}
            view.log_diagnostic_columns(rec, name, t, diagnostics, max_hz=self.rates.diagnostic_hz)

    def _flush_gps(self) -> None:
        g = self.est.seg.gps
        if g.appended <= self._gps_sent:
            return
        rows = g.view()[max(self._gps_sent - g.forgotten, 0):]
        self._gps_sent = g.appended
        ok = (rows[:, 7] >= 2) & np.isfinite(rows[:, 1]) & ~((rows[:, 1] == 0) & (rows[:, 2] == 0))
        if not ok.any():
            return
        if not self.has_gps:
            self.has_gps = True
            self._send_blueprint()
            self.rec.log("map/position", rr.GeoPoints.from_fields(radii=rr.Radius.ui_points(7.0),
                                                                  colors=[view.POSITION_COLOR]), static=True)
        self._track.extend(rows[ok][:, 1:3])
        if self._track.n > 2 * view.GPS_TRACK_MAX_POINTS:  # every other point: a session of hours stays small
            thinned = self._track.view()[::2].copy()
            self._track = Growing(2)
            self._track.extend(thinned)
        self.rec.log("map/track", rr.GeoLineStrings(lat_lon=[view._thin(self._track.view(), view.GPS_TRACK_MAX_POINTS)],
                                                    radii=rr.Radius.ui_points(2.0), colors=[view.TRACK_COLOR]),
                     static=True)
        self.rec.send_columns("map/position", indexes=[view._time(rows[ok, 0])],
                              columns=rr.GeoPoints.columns(positions=rows[ok][:, 1:3]))

    def _flush_events(self) -> None:
        events = self.est.events[self._events_sent:]
        if events:
            view.log_events(self.rec, events)
            self._events_sent += len(events)

    def status(self, t: float, rates: dict[str, float], lost: int, bad: int,
               rolling: dict[str, tuple[float, float, float]], extra_events=()) -> None:
        """The link and the rolling metrics at autopilot time ``t`` (once a second or so)."""
        rec = self.rec
        idx = [view._time(np.array([t]))]
        for name, value in rates.items():
            rec.send_columns(f"link/rate/{view._part(name)}", indexes=idx,
                             columns=rr.Scalars.columns(scalars=[value]))
        for name, value in (("lost", lost), ("bad", bad)):
            rec.send_columns(f"link/{name}", indexes=idx, columns=rr.Scalars.columns(scalars=[float(value)]))
        for name, maes in rolling.items():
            for axis, value in zip(AXES, maes):
                if np.isfinite(value):
                    rec.send_columns(f"rolling/{axis}/{view._part(name)}", indexes=idx,
                                     columns=rr.Scalars.columns(scalars=[value]))
        if extra_events:
            view.log_events(rec, list(extra_events))


class StatusLine:
    """A status line on stderr: redrawn in place about once a second on a terminal; on a
    pipe or file, a full line every ``every_s`` seconds."""

    def __init__(self, stream=None, every_s: float = 5.0):
        self.stream = stream or sys.stderr
        self.tty = self.stream.isatty()
        self.every_s = 1.0 if self.tty else every_s
        self._last = -np.inf
        self._width = 0

    def due(self, now: float) -> bool:
        return now - self._last >= self.every_s

    def show(self, text: str, now: float) -> None:
        self._last = now
        if self.tty:
            pad = max(self._width - len(text), 0)
            self.stream.write("\r" + text + " " * pad)
            self._width = len(text)
        else:
            self.stream.write(text + "\n")
        self.stream.flush()

    def message(self, text: str) -> None:
        """A line of its own, above the status line."""
        if self.tty and self._width:
            self.stream.write("\r" + " " * self._width + "\r")
            self._width = 0
        self.stream.write(text + "\n")
        self.stream.flush()

    def end(self) -> None:
        if self.tty and self._width:
            self.stream.write("\n")
            self.stream.flush()
            self._width = 0
