"""The Rerun view of a replay: one recording per replay, laid out by a blueprint.

Everything time-varying goes through ``rr.send_columns`` (one call per entity and chunk of
samples); ``rec.log`` is used only for static styling, the summary and the GPS track. The
helpers take a chunk of samples and always write the same entity paths, so a live session
(estimates arriving in chunks) reuses ``send_blueprint``, ``setup_series`` and the
``log_*_columns`` functions unchanged.

Timeline: ``"time"``, a duration in seconds on the autopilot clock (seconds since boot).

Entity paths (``<s>`` is a series key: ``autopilot``, ``truth``, ``reference`` when the
reference is neither of those, one of the autopilot's other streams (``autopilot:EKF1 (EKF1)``),
or an estimator's name, escaped for entity paths):

- ``attitude/{roll,pitch,yaw}/estimates/<s>``, ``attitude/{roll,pitch,yaw}/reference/<s>`` (the
  autopilot and its streams, truth: drawn on top)  Scalars, degrees (+ static SeriesLines: colour, label)
- ``error/{roll,pitch,yaw}/<s>``  Scalars, estimate - reference, degrees, scored samples
- ``error/{roll,pitch,yaw}/_unscored/<s>``  the samples the statistics skip (warm-up), faded;
  named as the scored line, so the legend has one entry for both (the viewer merges equal
  names; its dot shows the faded colour)
- ``world``  static ViewCoordinates FRD: the 3D world is NED (x north, y east, z down)
- ``world/<s>``  static Transform3D: the series' slot, ``SLOTS_PER_ROW`` side by side along
  east, further rows behind (north)
- ``world/<s>/body``  Transform3D quaternion column (body -> NED), static Boxes3D + axes
- ``world/<s>/label``  static Points3D carrying the series' name above its box
- ``world/<s>/reference``  the reference attitude again, as a grey wireframe "ghost" in
  every other slot, so an estimate's error is visible as the gap between box and ghost
- ``map/track``  static GeoLineStrings of the GPS track; ``map/position`` GeoPoints over time
- ``map/estimate/<s>``  static GeoLineStrings of an estimator's own track (``pos_n``/``pos_e``
  diagnostics, NED around the first GPS fix), ``map/estimate/<s>/position`` GeoPoints over time
- ``track``  static ViewCoordinates FRD (NED); ``track/gps`` and ``track/<s>``: static LineStrips3D
  of the GPS track and the estimated track, metres from the first fix (a "track" tab)
- ``events``  TextLog of the replay's events (and one metrics line per comparison at the end)
- ``diagnostics/<key>/<s>``  Scalars: what each filter exposes (``cov_trace``, ``adaptive_r``,
  ``accel_weight``, ...), peak-preserving like the errors; ``accel_state`` is the filter's
  accelerometer state code over time (0 used; see ``mavattitude estimators`` for the codes).
  Keys of one vector, ``<group>_<axis>`` with the axis x, y, z or n, e, d (``gyro_bias_x``,
  ``vel_n``), share a plot: ``diagnostics/<group>/<s>/<axis>``
- ``phase/in_air``, ``phase/height``  the ground/air phase (1 = air) and the height above the
  start it comes from
- ``summary``  static TextDocument (markdown): the flight and the metrics table

Decimation (what the viewer gets; the metrics are always computed on every sample):

- attitude scalars: every sample while a series' mean rate is <= ``SCALAR_MAX_HZ`` (200 Hz);
  faster series keep the first sample of each 1/200 s bin. Long logs are further capped at
  ``SCALAR_MAX_POINTS`` per series (the rate becomes ``SCALAR_MAX_POINTS / duration``:
  200 Hz up to 20 min, 67 Hz for an hour);
- error scalars: the same rate, but peak-preserving: the minimum and the maximum of each
  bin of two output samples, so no error spike disappears;
- 3D transforms: at most ``TRANSFORM_MAX_HZ`` (50 Hz), first sample per bin, and at most
  ``TRANSFORM_MAX_POINTS`` per series (50 Hz up to 30 min, 25 Hz for an hour);
- GPS marker at most ``GPS_MARKER_MAX_HZ`` (10 Hz); the static track at most
  ``GPS_TRACK_MAX_POINTS`` points.

Bins are on absolute time (``floor(t * hz)``) and a chunk's first sample counts as opening a
bin only if one sample step earlier lies in another bin, so a regularly sampled series sent in
chunks keeps the same samples as sent whole (min/max bins straddling a chunk boundary may add
a point or two).
"""
from __future__ import annotations

import math
from collections.abc import Iterable, Sequence

import numpy as np
import rerun as rr
import rerun.blueprint as rrb

from . import quaternion as quat
from .aiding import ned_to_geodetic
from .diagcolumns import only
from .declination import NO_DECLINATION
from .flight import AttitudeSeries, GpsSeries
from .metrics import AXES
from .events import Event
from .pipeline import ReplayResult
from .report import spread_lines
from .runner import REINIT_GAP_S, STEP_ROWS

TIMELINE = "time"

SCALAR_MAX_HZ = 200.0
SCALAR_MAX_POINTS = 240_000
TRANSFORM_MAX_HZ = 50.0
TRANSFORM_MAX_POINTS = 90_000
GPS_MARKER_MAX_HZ = 10.0
GPS_TRACK_MAX_POINTS = 5_000

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


# ---------------------------------------------------------------- blueprint


def _text_log_columns():
    """Time, level and text: the entity path column says nothing here (always /events)."""
    enc = rrb.encodings
    try:
        return rrb.TextLogColumns(
            timeline_columns=[enc.TimelineColumn(TIMELINE)],
            text_log_columns=[enc.TextLogColumn("LogLevel"), enc.TextLogColumn("Body"),
                              enc.TextLogColumn("EntityPath", visible=False)])
    except Exception:  # noqa: BLE001 - unstable blueprint type; the default is fine
        return None


_TEXT_LOG_COLUMNS = _text_log_columns()


def make_blueprint(*, has_gps: bool = True, n_slots: int = 4, error_range_deg=None,
                   map_zoom: float | None = None, time_span: tuple[float, float] | None = None,
                   live: bool = False, diagnostics: dict[str, Sequence[str]] | None = None,
                   has_phase: bool = False, has_track: bool = False,
                   live_window: float | None = None, attitude_range_deg=None) -> rrb.Blueprint:
    """The layout: per-axis attitude and error plots on the left, the 3D attitude boxes top
    right, map / summary / events in tabs below it.

    ``n_slots``: how many boxes stand side by side in the 3D view (frames the camera).
    ``error_range_deg``: optional {axis: half-range} for the error plots' y axes, so a large
    warm-up transient does not flatten the scored part (the user can still zoom out).
    ``map_zoom``: the map's zoom level (``map_zoom_for``); None lets the viewer choose.
    ``attitude_range_deg``: optional {axis: (low, high)} the attitude plots open on (the
    flight, not a tip-over on the ground).
    ``time_span``: (start, end) seconds the plots open on (the scored span); None: the
    viewer's default.
    ``live``: the time panel follows incoming data instead of standing paused.
    ``diagnostics``: {estimator: its diagnostic keys}: a "diagnostics" tab holding a tab per
    estimator, a plot per key (the axes of one vector in one plot), and the ground/air phase
    when ``has_phase``.
    ``has_track``: a "track" tab, the GPS and estimated tracks in 3D.
    ``live_window``: a live session's "link" tab (its first): the rolling MAE over that many
    seconds (``rolling/<axis>/<s>``) and the link's arrival rates and losses (``link/...``).

    One legend names every estimator's colour, in the roll error plot's lower right corner
    (errors stay near 0 in a range fitted to their peak: the corner is mostly empty); the
    reference is the thick line of the value plots, and the boxes in 3D carry names.
    """
    # With a known span, each plot opens on the whole replay. Rerun 0.41 reads a linked
    # plot's range from a global setting the SDK cannot set, and its fallback opened on a
    # window near the time cursor in our screenshots, so replay plots zoom independently;
    # without a span (live), the plots are linked and follow the data.
    if time_span is not None:
        whole = rr.TimeRange(start=rrb.TimeRangeBoundary.absolute(seconds=float(time_span[0])),
                             end=rrb.TimeRangeBoundary.absolute(seconds=float(time_span[1])))
        link = rrb.TimeAxis(link="Independent", view_range=whole)
    else:
        link = rrb.TimeAxis(link="LinkToGlobal")
    rows = []
    for axis in AXES:
        err_kwargs = {}
        if error_range_deg and error_range_deg.get(axis):
            r = float(error_range_deg[axis])
            err_kwargs["axis_y"] = rrb.ScalarAxis(range=(-r, r))
        att_kwargs = {}
        if attitude_range_deg and attitude_range_deg.get(axis):
            att_kwargs["axis_y"] = rrb.ScalarAxis(range=tuple(float(v) for v in attitude_range_deg[axis]))
        rows.append(rrb.Horizontal(
            rrb.TimeSeriesView(origin=f"attitude/{axis}", name=f"{axis} (deg; thick: the reference)", axis_x=link,
                               plot_legend=rrb.PlotLegend(visible=False), **att_kwargs),
            rrb.TimeSeriesView(origin=f"error/{axis}",
                               name=f"{axis} error: estimate - reference (deg)", axis_x=link,
                               plot_legend=rrb.PlotLegend(corner="RightBottom", visible=axis == AXES[0]),
                               **err_kwargs),
            column_shares=[3, 2],
        ))
    span = SLOT_SPACING * (min(n_slots, SLOTS_PER_ROW) - 1)
    depth = ROW_SPACING * ((max(n_slots, 1) - 1) // SLOTS_PER_ROW)
    # Look north from behind and above the rows of boxes (NED: up is -z), a little from
    # the west so the boxes read as 3D; far enough back to frame every slot.
    d = 0.95 * (span + 3.0) + depth
    eye = rrb.EyeControls3D(
        kind="Orbital",
        position=(depth / 2 - 0.85 * d, span / 2 - 0.12 * d, -0.45 * d),
        look_target=(depth / 2, span / 2, 0.0),
        eye_up=(0.0, 0.0, -1.0),
    )
    view3d = rrb.Spatial3DView(origin="world", name="attitude, NED (boxes: FRD body)",
                               eye_controls=eye, line_grid=rrb.LineGrid3D(visible=True,
                                                                          spacing=1.0))
    tabs = [rrb.TextDocumentView(origin="summary", name="summary"),
            rrb.TextLogView(origin="events", name="events", columns=_TEXT_LOG_COLUMNS)]
    per_estimator = [_diagnostics_tab(name, keys, link) for name, keys in (diagnostics or {}).items() if keys]
    if has_phase:
        per_estimator.append(rrb.Vertical(rrb.TimeSeriesView(
            origin="phase", name="ground/air phase (1 = air), height (m)", axis_x=link), name="phase"))
    if per_estimator:
        tabs.append(rrb.Tabs(*per_estimator, name="diagnostics"))
    if has_track:
        tabs.insert(0, rrb.Spatial3DView(origin="track", name="track, NED (m)"))
    if has_gps:
        tabs.insert(0, rrb.MapView(origin="map", name="GPS track", zoom=map_zoom))
    if live_window is not None:
        tabs.insert(0, rrb.Vertical(
            rrb.TimeSeriesView(origin="rolling", name=f"rolling MAE over the last {live_window:g} s (deg)",
                               axis_x=link),
            rrb.TimeSeriesView(origin="link", name="link: arrivals (Hz), packets lost and corrupt",
                               axis_x=link),
            name="link"))
    right = rrb.Vertical(view3d, rrb.Tabs(*tabs, active_tab=0), row_shares=[3, 2])
    return rrb.Blueprint(
        rrb.Horizontal(rrb.Vertical(*rows), right, column_shares=[3, 2]),
        rrb.BlueprintPanel(state="collapsed"),
        rrb.SelectionPanel(state="collapsed"),
        rrb.TimePanel(state="collapsed", timeline=TIMELINE,
                      play_state="Following" if live else "Paused"),
    )


def _diagnostics_tab(name: str, keys: Sequence[str], link) -> rrb.Vertical:
    """An estimator's diagnostics: a plot per quantity, a vector's axes in one (with a legend)."""
    axes: dict[str, list] = {}
    for key in keys:
        group, axis = diagnostic_group(key)
        axes.setdefault(group, []).append(axis)
    return rrb.Vertical(*(rrb.TimeSeriesView(origin=f"diagnostics/{_part(group)}/{_part(name)}",
                                             name=DIAGNOSTIC_TITLES.get(group, group), axis_x=link,
                                             plot_legend=rrb.PlotLegend(corner="RightTop",
                                                                        visible=any(parts)))
                          for group, parts in axes.items()), name=name)


def send_blueprint(rec: rr.RecordingStream, **layout) -> None:
    """Send ``make_blueprint(**layout)`` and make it the active and default layout."""
    rec.send_blueprint(make_blueprint(**layout), make_active=True, make_default=True)


def map_zoom_for(lat_deg, lon_deg, pixels: float = 300.0) -> float:
    """The web-map zoom level at which the points' extent spans about ``pixels``."""
    lat = np.asarray(lat_deg, dtype=float)
    lon = np.asarray(lon_deg, dtype=float)
    ok = np.isfinite(lat) & np.isfinite(lon)
    if not ok.any():
        return 16.0
    lat, lon = lat[ok], lon[ok]
    mid = math.radians(float(np.mean(lat)))
    extent_m = max(float(np.ptp(lat)) * 111_320.0,
                   float(np.ptp(lon)) * 111_320.0 * math.cos(mid), 10.0)
    metres_per_pixel = extent_m / pixels
    zoom = math.log2(156_543.03 * math.cos(mid) / metres_per_pixel)
    return float(np.clip(zoom, 2.0, 19.0))


# ---------------------------------------------------------------- static set-up

REFERENCE_WIDTH = 3.0  # the reference's lines: thicker than the estimates they are drawn over
SLOT_SPACING = 2.5  # metres (arbitrary units) between boxes, along east
SLOTS_PER_ROW = 4  # boxes in a row: eight in one row would each be a few pixels wide
ROW_SPACING = 3.0  # metres between rows, along north (behind the first, seen from above)
BOX_HALF_SIZES = (0.75, 0.5, 0.12)  # forward, right, down: a flat, nose-long box
AXIS_LENGTH = 1.1


def slot_position(slot: int) -> tuple[float, float, float]:
    """NED position of a box's slot: rows of ``SLOTS_PER_ROW`` along east, the next row north."""
    row, col = divmod(slot, SLOTS_PER_ROW)
    return (ROW_SPACING * row, SLOT_SPACING * col, 0.0)


def setup_world(rec: rr.RecordingStream) -> None:
    rec.log("world", rr.ViewCoordinates.FRD, static=True)  # NED: x north, y east, z down


def setup_series(rec: rr.RecordingStream, name: str, *, color: Color, label: str | None = None,
                 slot: int | None = None, ghost: bool = False, errors: bool = False,
                 reference: bool = False) -> None:
    """Static styling of one series: its plot lines (the ``reference``'s thicker), and its box
    at ``slot`` in the 3D view (with a reference ghost when ``ghost``); ``errors`` also styles
    its error plots."""
    label = label or name
    for axis in AXES:
        rec.log(attitude_path(axis, name),
                rr.SeriesLines(colors=[color], names=[label], widths=[REFERENCE_WIDTH if reference else 1.5]),
                static=True)
        if errors:
            rec.log(error_path(axis, name),
                    rr.SeriesLines(colors=[color], names=[label], widths=[1.5],
                                   aggregation_policy="MinMax"), static=True)
            rec.log(error_path(axis, name, scored=False),
                    rr.SeriesLines(colors=[(*color, 90)], names=[label],
                                   widths=[1.0], aggregation_policy="MinMax"), static=True)
    if slot is None:
        return
    base = f"world/{_part(name)}"
    rec.log(base, rr.Transform3D(translation=slot_position(slot)), static=True)
    rec.log(body_path(name),
            rr.Boxes3D(half_sizes=[BOX_HALF_SIZES], colors=[(*color, 255)], fill_mode="Solid"),
            rr.TransformAxes3D(AXIS_LENGTH),
            static=True)
    # The name floats above the slot (NED: up is -z) and does not turn with the box.
    rec.log(f"{base}/label", rr.Points3D(positions=[(0.0, 0.0, -1.25)], radii=[0.001],
                                         colors=[color], labels=[label], show_labels=True),
            static=True)
    if ghost:
        rec.log(ghost_path(name),
                rr.Boxes3D(half_sizes=[tuple(1.04 * h for h in BOX_HALF_SIZES)],
                           colors=[GHOST_COLOR], fill_mode="MajorWireframe", radii=[0.012]),
                static=True)


# ---------------------------------------------------------------- decimation


def _bin_first(t: np.ndarray, hz: float) -> np.ndarray:
    """Indices keeping the first sample of each 1/hz bin of absolute time (all of them when
    the series is not faster than hz on average)."""
    n = len(t)
    if n < 2 or hz <= 0:
        return np.arange(n)
    span = float(t[-1] - t[0])
    if n <= hz * span + 1:
        return np.arange(n)
    b = np.floor(t * hz)
    keep = np.empty(n, dtype=bool)
    # The first sample opens a bin unless the sample before it (one typical step earlier,
    # possibly in the previous chunk) was in the same bin: chunks then keep what the
    # whole series would.
    step = float(np.median(np.diff(t)))
    keep[0] = np.floor((t[0] - step) * hz) != b[0]
    keep[1:] = b[1:] != b[:-1]
    return np.flatnonzero(keep)


def _bin_minmax(t: np.ndarray, y: np.ndarray, hz: float) -> np.ndarray:
    """Peak-preserving decimation to about hz: the (first) argmin and argmax of y in each
    2/hz bin, in time order; all samples when the series is not faster than hz. O(n)."""
    n = len(t)
    if n < 2 or hz <= 0:
        return np.arange(n)
    span = float(t[-1] - t[0])
    if n <= hz * span + 1:
        return np.arange(n)
    b = np.floor(t * (hz / 2.0))
    if np.any(np.diff(b) < 0):  # unsorted time: keep the simple rule
        return _bin_first(t, hz)
    new = np.empty(n, dtype=bool)
    new[0] = True
    new[1:] = b[1:] != b[:-1]
    starts = np.flatnonzero(new)
    counts = np.diff(np.append(starts, n))
    bin_of = np.repeat(np.arange(len(starts)), counts)
    picks = []
    for ufunc, fill in ((np.maximum, -np.inf), (np.minimum, np.inf)):
        yy = np.where(np.isnan(y), fill, y)
        extreme = ufunc.reduceat(yy, starts)
        hits = np.flatnonzero(yy == np.repeat(extreme, counts))
        hb = bin_of[hits]
        first = np.ones(len(hits), dtype=bool)
        first[1:] = hb[1:] != hb[:-1]
        picks.append(hits[first])
    idx = np.sort(np.concatenate(picks))
    keep = np.ones(len(idx), dtype=bool)
    keep[1:] = idx[1:] != idx[:-1]
    return idx[keep]


def scalar_rate_for(duration_s: float) -> float:
    """The scalar rate for a log of this length (see the module docstring)."""
    if duration_s <= 0:
        return SCALAR_MAX_HZ
    return min(SCALAR_MAX_HZ, SCALAR_MAX_POINTS / duration_s)


def transform_rate_for(duration_s: float) -> float:
    """The 3D transform rate for a log of this length (see the module docstring)."""
    if duration_s <= 0:
        return TRANSFORM_MAX_HZ
    return min(TRANSFORM_MAX_HZ, TRANSFORM_MAX_POINTS / duration_s)


# ---------------------------------------------------------------- columnar logging


def _time(t: np.ndarray) -> rr.TimeColumn:
    return rr.TimeColumn(TIMELINE, duration=np.asarray(t, dtype=np.float64))


def _break_lines(t: np.ndarray, y: np.ndarray, angle: bool = True) -> tuple[np.ndarray, np.ndarray]:
    """A NaN between consecutive samples more than REINIT_GAP_S apart (a gap in the data) or,
    for an ``angle``, more than 180° apart (wrapping at ±180°), so the plot breaks the line
    there instead of drawing a stroke across it (the viewer breaks a line at a NaN)."""
    jumps = np.flatnonzero(((np.abs(np.diff(y)) > 180.0) if angle else False) | (np.diff(t) > REINIT_GAP_S))
    if len(jumps) == 0:
        return t, y
    t_mid = 0.5 * (t[jumps] + t[jumps + 1])
    return (np.insert(t, jumps + 1, t_mid), np.insert(y, jumps + 1, np.nan))


def _send_scalars(rec: rr.RecordingStream, path: str, t: np.ndarray, y: np.ndarray) -> None:
    if len(t) == 0:
        return
    t, y = _break_lines(np.asarray(t, dtype=np.float64), np.asarray(y, dtype=np.float64))
    rec.send_columns(path, indexes=[_time(t)],
                     columns=rr.Scalars.columns(scalars=np.asarray(y, dtype=np.float64)))


def log_euler_columns(rec: rr.RecordingStream, name: str, t, q, *,
                      max_hz: float = SCALAR_MAX_HZ) -> None:
    """Roll, pitch, yaw (degrees) of quaternions ``q`` (N, 4) at ``t`` to attitude/<axis>/<name>."""
    t = np.asarray(t, dtype=np.float64)
    idx = _bin_first(t, max_hz)
    if len(idx) == 0:
        return
    euler = np.degrees(quat.to_euler(np.asarray(q, dtype=np.float64)[idx]))
    for k, axis in enumerate(AXES):
        _send_scalars(rec, attitude_path(axis, name), t[idx], euler[:, k])


def log_transform_columns(rec: rr.RecordingStream, path: str, t, q, *,
                          max_hz: float = TRANSFORM_MAX_HZ) -> None:
    """An animated rotation (body -> NED quaternions [w, x, y, z]) at ``path``."""
    t = np.asarray(t, dtype=np.float64)
    idx = _bin_first(t, max_hz)
    if len(idx) == 0:
        return
    qs = np.asarray(q, dtype=np.float64)[idx]
    ok = np.all(np.isfinite(qs), axis=1)
    idx, qs = idx[ok], qs[ok]
    if len(idx) == 0:
        return
    xyzw = quat.normalize(qs)[:, [1, 2, 3, 0]].astype(np.float32)
    rec.send_columns(path, indexes=[_time(t[idx])],
                     columns=rr.Transform3D.columns(quaternion=xyzw))


def log_attitude_columns(rec: rr.RecordingStream, name: str, t, q, *,
                         scalar_max_hz: float = SCALAR_MAX_HZ,
                         transform_max_hz: float = TRANSFORM_MAX_HZ,
                         box: bool = True, ghost_in: Sequence[str] = ()) -> None:
    """One chunk of an attitude series: its Euler plots and its box in the 3D view; a
    reference also passes ``ghost_in`` (the other series) to animate their ghosts."""
    log_euler_columns(rec, name, t, q, max_hz=scalar_max_hz)
    if box:
        log_transform_columns(rec, body_path(name), t, q, max_hz=transform_max_hz)
    for other in ghost_in:
        log_transform_columns(rec, ghost_path(other), t, q, max_hz=transform_max_hz)


def log_error_columns(rec: rr.RecordingStream, name: str, t, error_deg, scored, *,
                      max_hz: float = SCALAR_MAX_HZ) -> None:
    """One chunk of a comparison: estimate - reference (degrees, (N, 3)) to error/<axis>/<name>,
    the unscored samples (warm-up) to error/<axis>/_unscored/<name>."""
    t = np.asarray(t, dtype=np.float64)
    err = np.asarray(error_deg, dtype=np.float64)
    scored = np.asarray(scored, dtype=bool)
    for is_scored, mask in ((True, scored), (False, ~scored)):
        if not mask.any():
            continue
        tm, em = t[mask], err[mask]
        for k, axis in enumerate(AXES):
            idx = _bin_minmax(tm, em[:, k], max_hz)
            _send_scalars(rec, error_path(axis, name, is_scored), tm[idx], em[idx, k])


DIAGNOSTIC_TITLES = {
    "cov_trace": "covariance trace",
    "accel_state": "accelerometer update (0 used, 1+ skipped / down-weighted)",
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
    path = f"diagnostics/{_part(group)}/{_part(name)}"
    return f"{path}/{axis}" if axis else path


def setup_diagnostics(rec: rr.RecordingStream, name: str, keys: Iterable[str], *, color: Color) -> None:
    """Static styling of one estimator's diagnostic lines: its colour, a vector's axes red,
    green and blue (x, y, z or north, east, down; the estimator's tab names it)."""
    for key in keys:
        axis = diagnostic_group(key)[1]
        rec.log(diagnostic_path(key, name),
                rr.SeriesLines(colors=[AXIS_COLORS.get(axis, color)], names=[axis or name], widths=[1.5],
                               aggregation_policy="MinMax"),
                static=True)


def log_diagnostic_columns(rec: rr.RecordingStream, name: str, t, diagnostics: dict, *,
                           max_hz: float = SCALAR_MAX_HZ) -> None:
    """One chunk of an estimator's diagnostics ({key: (N,) series}) to diagnostics/<key>/<name>,
    min/max per bin so a one-sample skip stays visible."""
    t = np.asarray(t, dtype=np.float64)
    for key, y in diagnostics.items():
        y = np.asarray(y, dtype=np.float64)
        ok = np.isfinite(y)
        idx = _bin_minmax(t[ok], y[ok], max_hz)
        tk, yk = _break_lines(t[ok][idx], y[ok][idx], angle=False)
        rec.send_columns(diagnostic_path(key, name), indexes=[_time(tk)], columns=rr.Scalars.columns(scalars=yk))


def log_phase_columns(rec: rr.RecordingStream, t, in_air, height_m) -> None:
    """The ground/air phase (a step line, 1 = air) and the height it comes from."""
    rec.log("phase/in_air", rr.SeriesLines(colors=[(230, 120, 40)], names=["in air"], widths=[2.0]),
            static=True)
    rec.log("phase/height", rr.SeriesLines(colors=[(140, 140, 140)], names=["height above start (m)"],
                                           widths=[1.0]), static=True)
    t = np.asarray(t, dtype=np.float64)
    rec.send_columns("phase/in_air", indexes=[_time(t)],
                     columns=rr.Scalars.columns(scalars=np.asarray(in_air, dtype=np.float64)))
    rec.send_columns("phase/height", indexes=[_time(t)],
                     columns=rr.Scalars.columns(scalars=np.asarray(height_m, dtype=np.float64)))


_LEVELS = {"info": rr.TextLogLevel.INFO, "warn": rr.TextLogLevel.WARN,
           "warning": rr.TextLogLevel.WARN, "error": rr.TextLogLevel.ERROR,
           "debug": rr.TextLogLevel.DEBUG}


def log_events(rec: rr.RecordingStream, events: Sequence[Event], path: str = "events") -> None:
    """Events as a TextLog, in one columnar call."""
    if not events:
        return
    ev = sorted(events, key=lambda e: e.t)
    levels = [_LEVELS.get(e.level.lower(), e.level.upper()) for e in ev]
    rec.send_columns(path, indexes=[_time([e.t for e in ev])],
                     columns=rr.TextLog.columns(text=[e.text for e in ev], level=levels))


EVENT_MARKERS = {  # which events get a marker on the attitude plots, and its look
    "warnings": ((215, 40, 40), "Down"),  # gaps, restarts, resets, an untrusted reference, ...
    "phase": ((120, 120, 120), "Circle"),  # take-off and landing
}


def log_event_markers(rec: rr.RecordingStream, events: Sequence[Event], top_deg: dict[str, float]) -> None:
    """A marker on each attitude plot, near its top (``top_deg``: axis -> y), at each warning and
    each change of the ground/air phase: where to look; the events tab says what happened."""
    kinds = {"warnings": [e.t for e in events if e.level == "warn"],
             "phase": [e.t for e in events if e.text.startswith(("in the air", "on the ground"))]}
    for kind, times in kinds.items():
        if not times:
            continue
        color, marker = EVENT_MARKERS[kind]
        t = np.sort(np.asarray(times, dtype=np.float64))
        for axis in AXES:
            path = f"attitude/{axis}/events/{kind}"
            rec.log(path, rr.SeriesPoints(colors=[color], markers=[marker], marker_sizes=[5.0],
                                          names=[f"{kind} (events tab)" if kind == "warnings" else "take-off, landing"]),
                    static=True)
            rec.send_columns(path, indexes=[_time(t)],
                             columns=rr.Scalars.columns(scalars=np.full(len(t), top_deg.get(axis, 175.0))))


def _gps_fix(gps: GpsSeries) -> tuple[np.ndarray, np.ndarray]:
    """Times and (lat, lon) of the samples with a usable fix."""
    lat = np.asarray(gps.lat_deg, dtype=np.float64)
    lon = np.asarray(gps.lon_deg, dtype=np.float64)
    fix = np.asarray(gps.fix_type)
    ok = np.isfinite(lat) & np.isfinite(lon) & (fix >= 2) & ~((lat == 0) & (lon == 0))
    return np.asarray(gps.t, dtype=np.float64)[ok], np.column_stack([lat[ok], lon[ok]])


def log_gps(rec: rr.RecordingStream, gps: GpsSeries) -> bool:
    """The GPS track (static line) and the vehicle's position over time. False if no fix."""
    t, ll = _gps_fix(gps)
    if len(t) == 0:
        return False
    stride = max(1, math.ceil(len(ll) / GPS_TRACK_MAX_POINTS))
    track = ll[::stride]
    if len(track) and not np.array_equal(track[-1], ll[-1]):
        track = np.vstack([track, ll[-1:]])
    # thinner than the estimated tracks drawn with it, so neither hides the other
    rec.log("map/track", rr.GeoLineStrings(lat_lon=[track], radii=rr.Radius.ui_points(1.2),
                                           colors=[TRACK_COLOR]), static=True)
    rec.log("map/position", rr.GeoPoints.from_fields(radii=rr.Radius.ui_points(7.0),
                                                     colors=[POSITION_COLOR]), static=True)
    idx = _bin_first(t, GPS_MARKER_MAX_HZ)
    rec.send_columns("map/position", indexes=[_time(t[idx])],
                     columns=rr.GeoPoints.columns(positions=ll[idx]))
    return True


def estimated_tracks(result: ReplayResult) -> dict[str, tuple[np.ndarray, np.ndarray]]:
    """{estimator: (t, (N, 3) NED m)} of the estimators that estimate a position."""
    imu_t = result.flight.imu[result.imu_source].t
    out = {}
    for name, diag in result.diagnostics.items():
        if all(k in diag for k in ("pos_n", "pos_e", "pos_d")):
            ned = np.column_stack([diag["pos_n"], diag["pos_e"], diag["pos_d"]])
            ok = np.isfinite(ned).all(axis=1)
            if ok.any():
                out[name] = (imu_t[ok], ned[ok])
    return out


def _thin(x: np.ndarray, n_max: int) -> np.ndarray:
    """At most about ``n_max`` rows of ``x``, evenly strided, the last one kept."""
    stride = max(1, math.ceil(len(x) / n_max))
    out = x[::stride]
    return out if len(x) == 0 or (len(out) - 1) * stride == len(x) - 1 else np.vstack([out, x[-1:]])


def log_tracks(rec: rr.RecordingStream, result: ReplayResult, colors: dict[str, Color]) -> bool:
    """Each estimated track next to the GPS one: on the map (around the first fix) and in
    3D (``track``). False when there is none (no GPS origin, or no estimator with a position)."""
    aiding = result.aiding
    tracks = estimated_tracks(result)
    if aiding is None or aiding.origin is None or not tracks:
        return False
    rec.log("track", rr.ViewCoordinates.FRD, static=True)  # NED: x north, y east, z down
    gps = aiding.gps_pos[np.isfinite(aiding.gps_pos).all(axis=1)]
    if len(gps):
        rec.log("track/gps", rr.LineStrips3D([_thin(gps, GPS_TRACK_MAX_POINTS)], colors=[TRACK_COLOR],
                                             radii=rr.Radius.ui_points(1.5), labels=["GPS"]),
                static=True)
    for name, (t, ned) in tracks.items():
        color = colors.get(name, (200, 200, 200))
        rec.log(f"track/{_part(name)}", rr.LineStrips3D([_thin(ned, GPS_TRACK_MAX_POINTS)], colors=[color],
                                                         radii=rr.Radius.ui_points(1.5), labels=[name]),
                static=True)
        lat, lon, _ = ned_to_geodetic(aiding.origin, ned)
        ll = np.column_stack([lat, lon])
        path = f"map/estimate/{_part(name)}"
        rec.log(path, rr.GeoLineStrings(lat_lon=[_thin(ll, GPS_TRACK_MAX_POINTS)],
                                        radii=rr.Radius.ui_points(2.5), colors=[color]), static=True)
        rec.log(f"{path}/position", rr.GeoPoints.from_fields(radii=rr.Radius.ui_points(5.0), colors=[color]),
                static=True)
        idx = _bin_first(t, GPS_MARKER_MAX_HZ)
        rec.send_columns(f"{path}/position", indexes=[_time(t[idx])],
                         columns=rr.GeoPoints.columns(positions=ll[idx]))
    return True


# ---------------------------------------------------------------- the whole replay


def _reference_key(result: ReplayResult) -> str | None:
    """Which series the reference is: "truth", "autopilot", "reference" (another one) or None."""
    ref, fl = result.reference, result.flight
    if ref is None:
        return None
    for key, s in (("truth", fl.truth), ("autopilot", fl.attitude)):
        if s is None:
            continue
        if ref is s or (ref.source == s.source and len(ref.t) == len(s.t)
                        and np.array_equal(ref.t, s.t)):
            return key
    return "reference"


def _series(result: ReplayResult) -> list[tuple[str, str, AttitudeSeries]]:
    """(key, label, series) of every attitude shown: the reference first (when there is
    one), then the autopilot and truth (where not the reference, nor one of the autopilot's
    other streams), those streams, then the estimates."""
    fl = result.flight
    ref_key = _reference_key(result)
    out = []
    if ref_key is not None:
        info = result.reference_info
        said = result.reference.source if info is None or info.algorithm == "truth" else \
            f"{info.stream}, {info.algorithm}"
        out.append((ref_key, f"{ref_key} ({said}) = reference", result.reference))
    streams = result.stream_series
    for key, s in (("autopilot", fl.attitude), ("truth", fl.truth)):
        if s is not None and len(s.t) and key != ref_key and not any(s is v for v in streams.values()):
            out.append((key, f"{key} ({s.source})", s))
    out += [(row, row, s) for row, s in streams.items() if len(s.t)]
    for name, s in result.estimates.items():
        shown = shown_estimate(s, result.comparisons.get(name), result.restarts)
        out.append((name, name + (" *" if shown is not s else ""), shown))
    return out


def shown_estimate(series: AttitudeSeries, comparison, restarts) -> AttitudeSeries:
    """An estimate as its plots and box show it. Without a heading reference its yaw is
    arbitrary and the metrics remove an offset per span between restarts
    (``Comparison.yaw_offsets_deg``): the view turns it by the same offsets, so the yaw plot,
    the box and the yaw error agree. Other estimates are shown as they are."""
    if comparison is None or not comparison.yaw_aligned or not comparison.yaw_offsets_deg:
        return series
    bounds = np.sort(np.asarray(restarts, dtype=float))
    offset = np.zeros(len(bounds) + 1)
    for start, removed in comparison.yaw_offsets_deg:
        offset[np.searchsorted(bounds, start, side="right")] = math.radians(removed)
    q = np.empty_like(series.q)
    for a in range(0, len(q), STEP_ROWS):  # in steps: an hour's temporaries stay small
        b = min(a + STEP_ROWS, len(q))
        q[a:b] = quat.yaw_turned(series.q[a:b], -offset[np.searchsorted(bounds, series.t[a:b], side="right")])
    return AttitudeSeries(series.source, series.t, q)


def _fmt(x) -> str:
    return "–" if x is None or not np.isfinite(x) else f"{x:.2f}"


def summary_markdown(result: ReplayResult) -> str:
    fl = result.flight
    a, b = fl.time_span
    lines = [
        "# Replay summary", "",
        f"- **log**: `{fl.path}` ({fl.format})",
        f"- **vehicle**: {fl.vehicle or '?'} · **firmware**: {fl.firmware or '?'}",
        f"- **span**: {a:.1f}–{b:.1f} s ({b - a:.1f} s) on the autopilot clock",
        f"- **IMU**: {result.imu_source} · **reference**: "
        f"{result.reference_info.label if result.reference_info is not None else _source(result.reference)}",
        f"- **compass**: {result.mag_source or 'none'} · **declination**: {result.declination.text()}",
    ]
    if result.mag_source and not result.declination.known:
        lines.append(f"- **warning**: {NO_DECLINATION}")
    if fl.gps is not None and any("pos_n" in d for d in result.diagnostics.values()):
        lines.append("- **map**: GPS track in magenta, an estimator's own track in its colour")
    if len(fl.segments) > 1:
        lines.append(f"- **clock segments**: {len(fl.segments)} (showing #{fl.segment_index})")
    if not result.comparisons:
        lines += ["", "Nothing was scored (no attitude reference in this log)."]
    else:
        n = max((m.n for c in result.comparisons.values() for m in c.axes.values() if m is not None), default=0)
        warmup = next(iter(result.comparisons.values())).warmup_s
        lines += ["", f"## Errors against {result.reference.source} (deg): RMSE / max", "",
                  f"Scored: {n:,} reference samples after a {warmup:g} s warm-up.", ""]
        for why in dict.fromkeys(c.not_meaningful for c in result.comparisons.values() if c.not_meaningful):
            lines += [f"**Not meaningful**: {why}. The scores are shown, not to be relied on or ranked.", ""]
        lines += ["| estimate | roll | pitch | yaw |", "|---|---|---|---|"]
    aligned = []
    for name, c in _scored(result).items():
        cells = [f"{_fmt(m.rmse)} / {_fmt(m.max)}" if m is not None else "–"
                 for m in (c.axes.get(axis) for axis in AXES)]
        mark = " \\*" if c.yaw_aligned else ""
        lines.append(f"| {name}{mark} | {' | '.join(cells)} |")
        if c.yaw_aligned:
            aligned.append(f"- {name}: " + ", ".join(f"{off:+.1f}° from {start:.0f} s" for start, off in c.yaw_offsets_deg))
    if result.comparisons and result.reference_info is not None and result.reference_info.algorithm != "truth":
        spread = spread_lines(result.comparisons, result.stream_comparisons, result.reference_info.algorithm)
        lines += [""] + [f"- {line}" for line in spread] if spread else []
    if aligned:
        lines += ["", "\\* yaw drift (no heading reference): a yaw offset per span between restarts is removed from "
                      "its yaw error, and from its yaw in the plots and the 3D view:", ""] + aligned
    if fl.warnings:
        lines += ["", "## Data the reader left out", ""] + [f"- {w}" for w in fl.warnings]
    if fl.notes:
        lines += ["", "## Reader notes", ""] + [f"- {n}" for n in fl.notes]
    return "\n".join(lines) + "\n"


def _source(series: AttitudeSeries | None) -> str:
    return series.source if series is not None else "none"


def _scored(result: ReplayResult) -> dict:
    """Every comparison shown: the estimators' (and the autopilot against truth), then the autopilot's other streams."""
    return {**result.comparisons, **result.stream_comparisons}


def _summary_events(result: ReplayResult, t_end: float) -> list[Event]:
    out = []
    for name, c in _scored(result).items():
        parts = []
        for axis in AXES:
            m = c.axes.get(axis)
            parts.append(f"{axis} {_fmt(m.rmse) if m else '–'}")
        out.append(Event(t_end, "info", f"{name} vs {c.reference}: RMSE deg " + ", ".join(parts)))
    return out


def _error_ranges(result: ReplayResult) -> dict[str, float]:
    """Half-range of each error plot: the largest scored |error| (at least 1°) plus 15 %."""
    out = {}
    for k, axis in enumerate(AXES):
        peak = 0.0
        for c in result.comparisons.values():
            e = np.asarray(c.error_deg)[np.asarray(c.scored, dtype=bool), k]
            e = e[np.isfinite(e)]
            if len(e):
                peak = max(peak, float(np.max(np.abs(e))))
        if peak > 0:
            out[axis] = 1.15 * max(peak, 1.0)
    return out


def _scored_span(result: ReplayResult) -> tuple[float, float]:
    """From the first scored reference sample to the last (the flight, past the warm-up and
    the ground before it), or the whole log when nothing was scored."""
    times = [c.t[np.asarray(c.scored, dtype=bool)] for c in result.comparisons.values()]
    times = [t for t in times if len(t)]
    if not times:
        return result.flight.time_span
    return min(float(t[0]) for t in times), max(float(t[-1]) for t in times)


def _attitude_ranges(result: ReplayResult, span: tuple[float, float]) -> dict[str, tuple[float, float]]:
    """Roll and pitch ranges the plots open on: the reference's extremes over ``span`` while in
    the air (all of it without a phase), padded. A tip-over on the ground at ±180° would
    flatten the flight to a line; the user zooms out for it."""
    ref = result.reference
    if ref is None or not len(ref.t):
        return {}
    inside = (ref.t >= span[0]) & (ref.t <= span[1])
    if result.phase is not None:
        flying = inside & (result.phase.on_clock(ref.t) == 1.0)
        inside = flying if flying.any() else inside
    euler = np.degrees(quat.to_euler(ref.q[inside]))
    out = {}
    for k, axis in enumerate(AXES[:2]):
        e = euler[np.isfinite(euler[:, k]), k]
        if len(e):
            lo, hi = float(e.min()), float(e.max())
            pad = max(5.0, 0.15 * (hi - lo))
            out[axis] = (max(lo - pad, -190.0), min(hi + pad, 190.0))
    return out


def _plotted_diagnostics(result: ReplayResult) -> dict[str, dict[str, np.ndarray]]:
    """The diagnostics worth a line: not all zero or NaN, and no compass quantities without a compass."""
    out = {}
    for name, diag in result.diagnostics.items():
        kept = []
        for key, y in diag.items():
            if result.mag_source is None and diagnostic_group(key)[0] in COMPASS_GROUPS:
                continue
            finite = np.asarray(y)[np.isfinite(y)]
            if len(finite) and np.any(finite != 0):
                kept.append(key)
        out[name] = only(diag, kept)  # a replay's: still made one at a time, as drawn
    return out


def log_replay(result: ReplayResult, rec: rr.RecordingStream, *, blueprint: bool = True) -> None:
    """Log a whole replay into ``rec`` (one recording), with the blueprint unless told not to."""
    fl = result.flight
    series = _series(result)
    ref_key = _reference_key(result)
    scored = _scored(result)
    names = [k for k, _, _ in series] + [k for k in scored if k not in {s[0] for s in series}]
    colors = assign_colors(names)
    gps_t, gps_ll = _gps_fix(fl.gps) if fl.gps is not None else (np.empty(0), None)
    has_gps = len(gps_t) > 0
    diagnostics = _plotted_diagnostics(result)
    span = _scored_span(result)
    ranges = _attitude_ranges(result, span)
    if blueprint:
        send_blueprint(rec, has_gps=has_gps, n_slots=len(series),
                       error_range_deg=_error_ranges(result), attitude_range_deg=ranges,
                       map_zoom=map_zoom_for(gps_ll[:, 0], gps_ll[:, 1]) if has_gps else None,
                       time_span=span, diagnostics={n: list(d) for n, d in diagnostics.items()},
                       has_phase=result.phase is not None,
                       has_track=has_gps and bool(estimated_tracks(result))
                       and result.aiding is not None and result.aiding.origin is not None)

    a, b = fl.time_span
    duration = max(b - a, max((float(s.t[-1] - s.t[0]) for _, _, s in series if len(s.t)),
                              default=0.0))
    hz = scalar_rate_for(duration)
    hz3d = transform_rate_for(duration)

    setup_world(rec)
    for slot, (key, label, s) in enumerate(series):
        setup_series(rec, key, color=colors[key], label=label, slot=slot,
                     ghost=ref_key is not None and key != ref_key,
                     errors=key in scored, reference=key == ref_key)
    for key, c in scored.items():
        if key not in {s[0] for s in series}:
            setup_series(rec, key, color=colors[key], errors=True)

    others = [k for k, _, _ in series if k != ref_key]
    for key, _, s in series:
        if len(s.t) == 0:
            continue
        log_attitude_columns(rec, key, s.t, s.q, scalar_max_hz=hz, transform_max_hz=hz3d,
                             ghost_in=others if key == ref_key else ())
    for key, c in scored.items():
        log_error_columns(rec, key, c.t, c.error_deg, c.scored, max_hz=hz)

    imu_t = fl.imu[result.imu_source].t
    for name, diag in diagnostics.items():
        if diag:
            setup_diagnostics(rec, name, diag, color=colors.get(name, (200, 200, 200)))
            log_diagnostic_columns(rec, name, imu_t, diag, max_hz=hz)
    if result.phase is not None:
        log_phase_columns(rec, result.phase.t, result.phase.in_air, result.phase.height_m)
    if has_gps:
        log_gps(rec, fl.gps)
        log_tracks(rec, result, colors)
    rec.log("summary", rr.TextDocument(summary_markdown(result), media_type="text/markdown"),
            static=True)
    log_events(rec, list(result.events) + _summary_events(result, b))
    log_event_markers(rec, result.events, {axis: hi - 0.04 * (hi - lo) for axis, (lo, hi) in ranges.items()})
