"""The layout: the blueprint that opens a replay (or a live session) on the flight."""
from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np
import rerun as rr
import rerun.blueprint as rrb

from ..scoring.metrics import AXES
from .style import *  # noqa: F403
from .style import _part
from .flightlog import BAND, BAND_RANGE

# ---------------------------------------------------------------- blueprint


def text_log_columns(timeline: str = TIMELINE):
    """Time (or ``timeline``), level and text: the entity path column says nothing here (the
    line says what it is about)."""
    enc = rrb.encodings
    try:
        return rrb.TextLogColumns(
            timeline_columns=[enc.TimelineColumn(timeline)],
            text_log_columns=[enc.TextLogColumn("LogLevel"), enc.TextLogColumn("Body"),
                              enc.TextLogColumn("EntityPath", visible=False)])
    except Exception:  # noqa: BLE001 - unstable blueprint type; the default is fine
        return None


_TEXT_LOG_COLUMNS = text_log_columns()


def _contents(names: Sequence[str], sub, extra: Sequence[str] = ()) -> list[str]:
    """A view's entity filter: each series' root (so "Hide in all views" on it reaches every
    view that shows it), the part of it this view draws (``sub(name)``: a path or None), and
    ``extra`` subtrees."""
    rules = []
    for n in names:
        part = sub(n)
        if part is not None:
            rules += [f"+ /{series_root(n)}", f"+ /{part}/**"]
    return rules + [f"+ /{e}/**" for e in extra]


def make_blueprint(*, series: Sequence[str] = (), has_gps: bool = True, n_slots: int | None = None,
                   error_range_deg=None, map_zoom: float | None = None,
                   time_span: tuple[float, float] | None = None, live: bool = False,
                   diagnostics: dict[str, Sequence[str]] | None = None, has_phase: bool = False,
                   has_track: bool = False, live_window: float | None = None, attitude_range_deg=None,
                   diagnostic_ranges: dict[str, dict[str, tuple[float, float]]] | None = None,
                   scored: Sequence[str] | None = None, log_band: bool = False) -> rrb.Blueprint:
    """The layout: per-axis attitude and error plots on the left, the 3D attitude boxes top
    right, map / summary / events in tabs below it.

    ``series``: every series' key (the estimators, the autopilot and its streams, the truth),
    in slot order; each view lists the part of each series' subtree it draws.
    ``scored``: the keys with error lines (default: every key in ``series``).
    ``n_slots``: how many boxes stand side by side in the 3D view (default: one per series).
    ``error_range_deg``: optional {axis: half-range} for the error plots' y axes (``ranges``).
    ``map_zoom``: the map's zoom level (``map_zoom_for``); None lets the viewer choose.
    ``attitude_range_deg``: optional {axis: (low, high)} the attitude plots open on.
    ``time_span``: (start, end) seconds the plots open on; None: the viewer's default.
    ``live``: the time panel follows incoming data instead of standing paused.
    ``diagnostics``: {estimator: its diagnostic keys}: a "diagnostics" tab holding a tab per
    estimator (pages of at most four plots, a vector's axes in one), and the ground/air phase
    when ``has_phase``; ``diagnostic_ranges`` {estimator: {group: (low, high)}} their y ranges.
    ``has_track``: a "track" tab, the GPS and estimated tracks in 3D.
    ``live_window``: a live session's "link" tab (its first): the rolling MAE over that many
    seconds (``rolling/<axis>/<s>``) and the link's arrival rates and losses (``link/...``).
    ``log_band``: a band plot above the time plots with the log's own modes, arming and text
    lines (``flightlog``); the legend names the modes' colours.

    One legend names every colour, in a narrow plot of its own between the time plots and the
    3D view (it covers no data); the reference is the thick line of the value plots, and the
    boxes in 3D carry names.
    """
    series = list(series)
    scored = series if scored is None else list(scored)
    n_slots = len(series) if n_slots is None else n_slots
    link = _time_axis(time_span)
    values, errors = _time_plots(series, scored, link, error_range_deg, attitude_range_deg)
    # The legend has a plot of its own beside the others: the roll lines of every series on a
    # y range no line reaches, so it names every colour and covers no data.
    legend = _legend_plot("legend", link, _contents(series, lambda n: attitude_path(AXES[0], n)))
    # The log's own modes, arming and lines: a band atop each column of time plots (so it lines
    # up with both), and a legend of the modes' colours under the series' legend.
    columns = [values, errors]
    if log_band:
        columns = [[rrb.TimeSeriesView(origin="/", name=name, axis_x=link, contents=[f"+ /{BAND}/**"],
                                       plot_legend=rrb.PlotLegend(visible=False),
                                       axis_y=rrb.ScalarAxis(range=BAND_RANGE, zoom_lock=True)), *views]
                   for name, views in (("the log's modes (bars: hover, legend), armed, its lines (◆: hover)", values),
                                       ("the log's own account (as left)", errors))]
        legend = rrb.Vertical(legend, _legend_plot("flight modes", link, [f"+ /{BAND}/modes/**", f"+ /{BAND}/armed"]),
                              row_shares=[3, 2])
    tabs = _tabs(series, link, has_gps=has_gps, map_zoom=map_zoom, has_track=has_track, has_phase=has_phase,
                 diagnostics=diagnostics, diagnostic_ranges=diagnostic_ranges, live_window=live_window)
    # the tabs (summary table, events, diagnostics) as tall as the boxes: the table shows whole
    right = rrb.Vertical(_attitude_3d(series, n_slots), rrb.Tabs(*tabs, active_tab=0), row_shares=[1, 1])
    return rrb.Blueprint(
        rrb.Horizontal(*[rrb.Vertical(*views, row_shares=[1] * (len(views) - 3) + [4] * 3) for views in columns],
                       legend, right, column_shares=[42, 28, 15, 45]),
        rrb.BlueprintPanel(state="collapsed"),
        rrb.SelectionPanel(state="collapsed"),
        rrb.TimePanel(state="collapsed", timeline=TIMELINE,
                      play_state="Following" if live else "Paused"),
    )


def _time_axis(time_span: tuple[float, float] | None) -> rrb.TimeAxis:
    # With a known span, each plot opens on the flight. Rerun 0.41 reads a linked plot's range
    # from a global setting the SDK cannot set, and its fallback opened on a window near the
    # time cursor in our screenshots, so replay plots zoom independently (a double-click resets
    # one); without a span (live), the plots are linked and follow the data.
    if time_span is None:
        return rrb.TimeAxis(link="LinkToGlobal")
    whole = rr.TimeRange(start=rrb.TimeRangeBoundary.absolute(seconds=float(time_span[0])),
                         end=rrb.TimeRangeBoundary.absolute(seconds=float(time_span[1])))
    return rrb.TimeAxis(link="Independent", view_range=whole)


def _time_plots(series: list[str], scored: list[str], link, error_range_deg, attitude_range_deg):
    """Per axis, the value plot (every series) and the error plot (the scored ones)."""
    values, errors = [], []
    for axis in AXES:
        err_kwargs = {}
        if error_range_deg and error_range_deg.get(axis):
            r = float(error_range_deg[axis])
            err_kwargs["axis_y"] = rrb.ScalarAxis(range=(-r, r))
        att_kwargs = {}
        if attitude_range_deg and attitude_range_deg.get(axis):
            att_kwargs["axis_y"] = rrb.ScalarAxis(range=tuple(float(v) for v in attitude_range_deg[axis]))
        values.append(
            rrb.TimeSeriesView(origin="/", name=f"{axis} (deg; thick: the reference)", axis_x=link,
                               contents=_contents(series, lambda n, a=axis: attitude_path(a, n),
                                                  [f"marks/attitude/{axis}"]),
                               plot_legend=rrb.PlotLegend(visible=False), **att_kwargs))
        errors.append(
            rrb.TimeSeriesView(origin="/", name=f"{axis} error: estimate - reference (deg)", axis_x=link,
                               contents=_contents(scored, lambda n, a=axis: error_path(a, n),
                                                  [f"marks/error/{axis}"])
                               + [f"+ /{error_path(axis, n, scored=False)}/**" for n in scored],
                               plot_legend=rrb.PlotLegend(visible=False),
                               **err_kwargs))
    return values, errors


def _legend_plot(name: str, link, contents) -> rrb.TimeSeriesView:
    """A plot that is only a legend: its lines on a y range none of them reaches."""
    return rrb.TimeSeriesView(origin="/", name=name, axis_x=link, contents=contents,
                              axis_y=rrb.ScalarAxis(range=(LEGEND_Y, LEGEND_Y + 1.0), zoom_lock=True),
                              plot_legend=rrb.PlotLegend(corner="LeftTop", visible=True))


def _attitude_3d(series: list[str], n_slots: int) -> rrb.Spatial3DView:
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
    return rrb.Spatial3DView(origin="/", name="attitude, NED (boxes: FRD body)",
                             contents=_contents(series, slot_path),
                             eye_controls=eye, line_grid=rrb.LineGrid3D(visible=True, spacing=1.0))


def _tabs(series: list[str], link, *, has_gps, map_zoom, has_track, has_phase, diagnostics, diagnostic_ranges,
          live_window) -> list:
    """The tabs under the 3D view: (link,) (map, track,) summary, events (, diagnostics)."""
    tabs = [rrb.TextDocumentView(origin="summary", name="summary"),
            rrb.TextLogView(origin="events", name="events", columns=_TEXT_LOG_COLUMNS)]
    per_estimator = [_diagnostics_tab(name, keys, link, (diagnostic_ranges or {}).get(name, {}))
                     for name, keys in (diagnostics or {}).items() if keys]
    if has_phase:
        per_estimator.append(rrb.Vertical(rrb.TimeSeriesView(
            origin="phase", name="ground/air phase (1 = air), height (m)", axis_x=link), name="phase"))
    if per_estimator:
        tabs.append(rrb.Tabs(*per_estimator, name="diagnostics"))
    if has_track:
        tabs.insert(0, rrb.Spatial3DView(origin="/", name="track, NED (m)",
                                         contents=_contents(series, lambda n: f"{series_root(n)}/track", ["track"])))
    if has_gps:
        tabs.insert(0, rrb.MapView(origin="/", name="GPS track", zoom=map_zoom,
                                   contents=_contents(series, lambda n: f"{series_root(n)}/map", ["map"])))
    if live_window is not None:
        tabs.insert(0, rrb.Vertical(
            rrb.TimeSeriesView(origin="rolling", name=f"rolling MAE over the last {live_window:g} s (deg)",
                               axis_x=link),
            rrb.TimeSeriesView(origin="link", name="link: arrivals (Hz), packets lost and corrupt",
                               axis_x=link),
            name="link"))
    return tabs


LEGEND_Y = 200.0  # above any angle (±180°): the legend plot shows no line, short tick labels
DIAGNOSTIC_PLOTS_PER_PAGE = 4  # 2 x 2: each plot tall enough to read its curve and its axis


def _diagnostics_tab(name: str, keys: Sequence[str], link, ranges: dict[str, tuple[float, float]]):
    """An estimator's diagnostics: a plot per quantity (a vector's axes in one, with a legend),
    four to a page in a 2 x 2 grid, each on its robust range (``diagnostic_ranges``)."""
    axes: dict[str, list] = {}
    for key in keys:
        group, axis = diagnostic_group(key)
        axes.setdefault(group, []).append(axis)
    plots = []
    for group, parts in axes.items():
        extra = {"axis_y": rrb.ScalarAxis(range=ranges[group])} if group in ranges else {}
        plots.append(rrb.TimeSeriesView(
            origin="/", name=DIAGNOSTIC_TITLES.get(group, group), axis_x=link,
            contents=[f"+ /{series_root(name)}", f"+ /{series_root(name)}/diagnostics/{_part(group)}/**"],
            plot_legend=rrb.PlotLegend(corner="RightTop", visible=any(parts) or group == STATE_GROUP), **extra))
    n = DIAGNOSTIC_PLOTS_PER_PAGE
    pages = [rrb.Grid(*plots[i:i + n], grid_columns=2 if len(plots[i:i + n]) > 1 else 1,
                      name=name if len(plots) <= n else f"{name} {i // n + 1}")
             for i in range(0, len(plots), n)]
    return pages[0] if len(pages) == 1 else rrb.Tabs(*pages, name=name)


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


