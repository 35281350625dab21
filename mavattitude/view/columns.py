"""What goes into the recording: static styling and the columnar logging of every series
(decimated by ``decimation``'s rules)."""
from __future__ import annotations

from typing import TYPE_CHECKING

import math
from collections.abc import Iterable, Sequence

import numpy as np
import rerun as rr

from .. import quaternion as quat
from ..aiding import ned_to_geodetic
from ..flight import GpsSeries
from ..scoring.metrics import AXES
from ..core.runner import REINIT_GAP_S
from .decimation import MINMAX_ROWS, _bin_first, _bin_minmax, scalar_rate_for, transform_rate_for  # noqa: F401
from .style import *  # noqa: F403

if TYPE_CHECKING:  # for types only: replay (commands.replay) is above the view and draws through it
    from ..commands.replay import ReplayResult


# ---------------------------------------------------------------- static set-up

def slot_position(slot: int) -> tuple[float, float, float]:
    """NED position of a box's slot: rows of ``SLOTS_PER_ROW`` along east, the next row north."""
    row, col = divmod(slot, SLOTS_PER_ROW)
    return (ROW_SPACING * row, SLOT_SPACING * col, 0.0)


def setup_world(rec: rr.RecordingStream) -> None:
    # NED at the root (x north, y east, z down): the 3D views open at "/", so that a series'
    # subtree holds its box and its track beside its plots
    rec.log("/", rr.ViewCoordinates.FRD, static=True)


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
    base = slot_path(name)
    rec.log(base, rr.Transform3D(translation=slot_position(slot)), static=True)
    rec.log(body_path(name),
            rr.Boxes3D(half_sizes=[BOX_HALF_SIZES], colors=[(*color, 255)], fill_mode="Solid"),
            rr.TransformAxes3D(AXIS_LENGTH),
            static=True)
    # The name floats above the slot (NED: up is -z) and does not turn with the box; neighbours'
    # names at two heights, so that long ones ("autopilot (ATT, DCM) = reference") do not overlap
    height = 1.25 if slot % 2 == 0 else 1.85
    rec.log(f"{base}/label", rr.Points3D(positions=[(0.0, 0.0, -height)], radii=[0.001],
                                         colors=[color], labels=[label], show_labels=True),
            static=True)
    if ghost:
        rec.log(ghost_path(name),
                rr.Boxes3D(half_sizes=[tuple(1.04 * h for h in BOX_HALF_SIZES)],
                           colors=[GHOST_COLOR], fill_mode="MajorWireframe", radii=[0.012]),
                static=True)


# ---------------------------------------------------------------- columnar logging


def _time(t: np.ndarray) -> rr.TimeColumn:
    return rr.TimeColumn(TIMELINE, duration=np.asarray(t, dtype=np.float64))


def log_bars(rec: rr.RecordingStream, path: str, starts, ends, y: float, color, width: float, name: str) -> None:
    """A bar at ``y`` over each span from ``starts[k]`` to ``ends[k]``, named ``name`` (the legend
    and the hover say it): one line, broken after each span (the viewer breaks a line at a NaN)."""
    b = np.asarray(ends, dtype=np.float64)
    t = np.column_stack([np.asarray(starts, dtype=np.float64), b, b + 1e-6]).ravel()
    values = np.full(len(t), float(y))
    values[2::3] = np.nan
    rec.log(path, rr.SeriesLines(colors=[color], names=[name[:100]], widths=[width]), static=True)
    rec.send_columns(path, indexes=[_time(t)], columns=rr.Scalars.columns(scalars=values))


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


def _binned_attitudes(t, q, max_hz: float, rows=None) -> tuple[np.ndarray, np.ndarray]:
    """The first quaternion of each 1/``max_hz`` bin (``_bin_first``) and its time. ``rows``:
    ``q`` holds only these rows of ``t`` (sorted, among them every row picked: ``drawn_rows``)."""
    t = np.asarray(t, dtype=np.float64)
    idx = _bin_first(t, max_hz)
    at = idx if rows is None else np.searchsorted(rows, idx)
    return t[idx], np.asarray(np.asarray(q)[at], dtype=np.float64)  # picked, then widened: not a whole float32 estimate


def log_euler_columns(rec: rr.RecordingStream, name: str, t, q, *,
                      max_hz: float = SCALAR_MAX_HZ, rows=None) -> None:
    """Roll, pitch, yaw (degrees) of quaternions ``q`` (N, 4) at ``t`` to attitude/<axis>/<name>
    (``rows``: see ``_binned_attitudes``)."""
    t, q = _binned_attitudes(t, q, max_hz, rows)
    if len(t) == 0:
        return
    euler = np.degrees(quat.to_euler(q))
    for k, axis in enumerate(AXES):
        _send_scalars(rec, attitude_path(axis, name), t, euler[:, k])


def log_transform_columns(rec: rr.RecordingStream, path: str, t, q, *,
                          max_hz: float = TRANSFORM_MAX_HZ, rows=None) -> None:
    """An animated rotation (body -> NED quaternions [w, x, y, z]) at ``path`` (``rows``: see
    ``_binned_attitudes``)."""
    t, qs = _binned_attitudes(t, q, max_hz, rows)
    ok = np.all(np.isfinite(qs), axis=1)
    t, qs = t[ok], qs[ok]
    if len(t) == 0:
        return
    xyzw = quat.normalize(qs)[:, [1, 2, 3, 0]].astype(np.float32)
    rec.send_columns(path, indexes=[_time(t)],
                     columns=rr.Transform3D.columns(quaternion=xyzw))


def log_attitude_columns(rec: rr.RecordingStream, name: str, t, q, *,
                         scalar_max_hz: float = SCALAR_MAX_HZ,
                         transform_max_hz: float = TRANSFORM_MAX_HZ,
                         box: bool = True, ghost_in: Sequence[str] = (), rows=None) -> None:
    """One chunk of an attitude series: its Euler plots and its box in the 3D view; a
    reference also passes ``ghost_in`` (the other series) to animate their ghosts. ``rows``:
    ``q`` holds only these rows of ``t`` (``drawn_rows``)."""
    log_euler_columns(rec, name, t, q, max_hz=scalar_max_hz, rows=rows)
    if box:
        log_transform_columns(rec, body_path(name), t, q, max_hz=transform_max_hz, rows=rows)
    for other in ghost_in:
        log_transform_columns(rec, ghost_path(other), t, q, max_hz=transform_max_hz, rows=rows)


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
        tf, yf = (t, y) if ok.all() else (t[ok], y[ok])  # (no copies of an hour when all are finite)
        idx = _bin_minmax(tf, yf, max_hz)
        tk, yk = _break_lines(tf[idx], yf[idx], angle=False)
        rec.send_columns(diagnostic_path(key, name), indexes=[_time(tk)], columns=rr.Scalars.columns(scalars=yk))


STATE_COLORS = ((215, 40, 40), (235, 140, 0), (120, 90, 200), (40, 150, 160), (150, 150, 60))
STATE_WIDTH = 8.0  # ui points: bars


def state_label(code: int, state: str, width: int = 26) -> str:
    """A state's name short enough for a legend beside small plots: "2 skipped: horizontal man…"
    (the estimator's own words; ``mavattitude estimators`` has them whole)."""
    text = f"{code} {state.split(' (')[0]}"
    return text if len(text) <= width else text[:width - 1] + "…"


def log_state_spans(rec: rr.RecordingStream, name: str, t, codes, states, *,
                    join_s: float = 1.0 / DIAGNOSTIC_MAX_HZ) -> None:
    """An estimator's accelerometer-state codes (``states``: the meaning of each, 0 used) as
    bars: one entity per code other than 0, at y = code, over each run of it, named by its
    meaning (the legend and the hover say it). Runs of one code closer than ``join_s`` are one
    bar: a screen cannot show them apart, and a barcode of single samples reads as nothing."""
    t = np.asarray(t, dtype=np.float64)
    codes = np.asarray(codes)
    ok = np.isfinite(codes.astype(np.float64))
    t, codes = t[ok], codes[ok].astype(np.int64)
    if len(t) < 2:
        return
    change = np.flatnonzero(np.diff(codes)) + 1
    starts = np.concatenate([[0], change])
    ends = np.concatenate([change, [len(t) - 1]])  # a run lasts until the next one's first sample
    for code in np.unique(codes[starts]):
        if code == 0 or code >= len(states):
            continue
        mine = codes[starts] == code
        a, b = t[starts[mine]], t[ends[mine]]
        keep = np.concatenate([[True], a[1:] - b[:-1] > join_s])  # a new bar where the gap is wide
        a, b = a[keep], np.concatenate([b[np.flatnonzero(keep)[1:] - 1], b[-1:]])
        log_bars(rec, f"{series_root(name)}/diagnostics/{STATE_GROUP}/{code}", a, b, float(code),
                 STATE_COLORS[(code - 1) % len(STATE_COLORS)], STATE_WIDTH, state_label(code, states[code]))


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
            first = int(np.argmax(ok))
            if ok[first:].all() and ok[first]:  # finite from the first fix on: the same rows, not copied
                out[name] = (imu_t[first:], ned[first:])
            elif ok.any():
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
    gps = aiding.gps_pos[np.isfinite(aiding.gps_pos).all(axis=1)]
    if len(gps):
        rec.log("track/gps", rr.LineStrips3D([_thin(gps, GPS_TRACK_MAX_POINTS)], colors=[TRACK_COLOR],
                                             radii=rr.Radius.ui_points(1.5), labels=["GPS"]),
                static=True)
    for name, (t, ned) in tracks.items():
        color = colors.get(name, (200, 200, 200))
        rec.log(f"{series_root(name)}/track", rr.LineStrips3D([_thin(ned, GPS_TRACK_MAX_POINTS)], colors=[color],
                                                         radii=rr.Radius.ui_points(1.5), labels=[name]),
                static=True)
        # latitude and longitude of the rows drawn only (all of an hour's took 100 MB)
        line, idx = _thin(np.arange(len(ned))[:, None], GPS_TRACK_MAX_POINTS)[:, 0], _bin_first(t, GPS_MARKER_MAX_HZ)
        rows = np.union1d(line, idx)
        lat, lon, _ = ned_to_geodetic(aiding.origin, ned[rows])
        ll = np.column_stack([lat, lon])
        path = f"{series_root(name)}/map"
        rec.log(path, rr.GeoLineStrings(lat_lon=[ll[np.searchsorted(rows, line)]],
                                        radii=rr.Radius.ui_points(2.5), colors=[color]), static=True)
        rec.log(f"{path}/position", rr.GeoPoints.from_fields(radii=rr.Radius.ui_points(5.0), colors=[color]),
                static=True)
        rec.send_columns(f"{path}/position", indexes=[_time(t[idx])],
                         columns=rr.GeoPoints.columns(positions=ll[np.searchsorted(rows, idx)]))
    return True


