"""A whole replay into one recording: the series shown, the summary, the ranges the plots open on."""
from __future__ import annotations

from typing import TYPE_CHECKING

import math

import numpy as np
import rerun as rr

from .. import quaternion as quat
from ..declination import NO_DECLINATION
from ..diagcolumns import only
from ..events import Event
from ..flight import AttitudeSeries
from ..memory import give_back_free_pages
from ..scoring.metrics import AXES
from ..commands.report import spread_lines
from ..core.runner import REINIT_GAP_S, STEP_ROWS
from . import ranges
from .blueprint import map_zoom_for, send_blueprint
from .columns import *  # noqa: F403
from .columns import _gps_fix
from .decimation import drawn_duration
from .flightlog import flight_events, has_band, log_flight_band
from .marks import log_event_markers, log_events, log_spans
from .style import *  # noqa: F403

if TYPE_CHECKING:  # for types only: replay (commands.replay) is above the view and draws through it
    from ..commands.replay import ReplayResult

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
        lines.append("- **map**: GPS track near black, an estimator's own track in its colour")
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


def _data_spans(result: ReplayResult) -> list[tuple[float, float, str]]:
    """(start, end, text) of every span the data cannot be trusted: the IMU's gaps (the
    estimators restarted after them) and the reference's untrusted stretches."""
    t = np.asarray(result.flight.imu[result.imu_source].t, dtype=np.float64)
    gaps = np.flatnonzero(np.diff(t) > REINIT_GAP_S)
    out = [(float(t[i]), float(t[i + 1]), f"IMU gap {t[i + 1] - t[i]:.1f} s: estimators re-initialised")
           for i in gaps]
    out += [(s.start, s.end, f"reference not trusted {s.start:.1f}-{s.end:.1f} s: {s.kind} ({s.detail})")
            for s in result.suspects]
    return out


def _diagnostic_ranges(diagnostics: dict[str, dict[str, np.ndarray]], t: np.ndarray,
                       span: tuple[float, float]) -> dict[str, dict[str, tuple[float, float]]]:
    """Each diagnostic plot's y range: the 1st to 99th percentile over ``span`` (a vector's axes
    together), padded: a re-initialisation spike does not set it. None for a flat line."""
    inside = (t >= span[0]) & (t <= span[1])
    out: dict[str, dict[str, tuple[float, float]]] = {}
    for name, diag in diagnostics.items():
        groups: dict[str, list] = {}
        for key in diag:
            groups.setdefault(diagnostic_group(key)[0], []).append(key)
        for group, keys in groups.items():  # a group's series at a time (cpf-ekf's all at once: 250 MB for an hour)
            ys = []
            for key in keys:  # as kept (float32 measures), and in float64 once joined: the same values
                y = np.asarray(diag[key])
                ys.append(y[inside & np.isfinite(y)] if len(y) == len(t) else y)
            y = np.concatenate(ys)
            del ys
            y = y.astype(np.float64)
            if len(y) < 2:
                continue
            lo, hi = np.percentile(y, [1.0, 99.0], overwrite_input=True)  # (y is ours: no copy of it)
            pad = 0.15 * (hi - lo)
            if hi - lo > 1e-12 * max(1.0, abs(hi)):
                out.setdefault(name, {})[group] = (float(lo - pad), float(hi + pad))
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


def _accel_states(name: str, diag) -> tuple:
    """The meanings of an estimator's accel_state codes, when it has them and logged some."""
    from ..estimators import ESTIMATORS

    return tuple(getattr(ESTIMATORS.get(name), "ACCEL_STATES", ())) if "accel_state" in diag else ()


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
    span = ranges.open_span(result)
    att_ranges = ranges.attitude_ranges(result, span)
    err_ranges = ranges.error_ranges(scored, span)
    imu_t = fl.imu[result.imu_source].t
    diagnostic_ranges = _diagnostic_ranges(diagnostics, imu_t, span)
    keys = {}
    for name, diag in diagnostics.items():  # the state codes drawn as spans, on a range of their own
        states = _accel_states(name, diag)
        keys[name] = [STATE_GROUP if states and k == "accel_state" else k for k in diag]
        if states:
            # the bars in the lower half, the legend naming them in the upper
            diagnostic_ranges.setdefault(name, {})[STATE_GROUP] = (0.4, 2.0 * (len(states) - 1) + 0.6)
    if blueprint:
        send_blueprint(rec, series=names, scored=list(scored), n_slots=len(series),
                       error_range_deg=err_ranges, attitude_range_deg=att_ranges,
                       diagnostic_ranges=diagnostic_ranges,
                       has_gps=has_gps, map_zoom=map_zoom_for(gps_ll[:, 0], gps_ll[:, 1]) if has_gps else None,
                       time_span=span, diagnostics=keys,
                       has_phase=result.phase is not None, log_band=has_band(fl),
                       has_track=has_gps and bool(estimated_tracks(result))
                       and result.aiding is not None and result.aiding.origin is not None)

    b = fl.time_span[1]
    duration = drawn_duration(fl, [s.t for _, _, s in series])
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
        kept = key in result.estimates and result.shown_rows is not None  # at the rows drawn only
        log_attitude_columns(rec, key, imu_t if kept else s.t, s.q, scalar_max_hz=hz, transform_max_hz=hz3d,
                             ghost_in=others if key == ref_key else (), rows=result.shown_rows if kept else None)
        give_back_free_pages()  # what Rerun's threads freed once they sent a batch (an hour's: 20 MB)
    for key, c in scored.items():
        log_error_columns(rec, key, c.t, c.error_deg, c.scored, max_hz=hz)
    give_back_free_pages()

    for name, diag in diagnostics.items():
        states = _accel_states(name, diag)
        # each line made as it is drawn: cpf-ekf's 30 all at once were 170 MB for an hour
        lines = only(diag, [k for k in diag if not (states and k == "accel_state")])
        if lines:
            setup_diagnostics(rec, name, lines, color=colors.get(name, (200, 200, 200)))
            log_diagnostic_columns(rec, name, imu_t, lines, max_hz=min(hz, DIAGNOSTIC_MAX_HZ))
        del lines
        if states:
            log_state_spans(rec, name, imu_t, diag["accel_state"], states)
        give_back_free_pages()
    if result.phase is not None:
        log_phase_columns(rec, result.phase.t, result.phase.in_air, result.phase.height_m)
    if has_gps:
        log_gps(rec, fl.gps)
        log_tracks(rec, result, colors)
    rec.log("summary", rr.TextDocument(summary_markdown(result), media_type="text/markdown"),
            static=True)
    log_events(rec, list(result.events) + flight_events(fl) + _summary_events(result, b))
    log_flight_band(rec, fl)
    att_top = {axis: hi - 0.04 * (hi - lo) for axis, (lo, hi) in att_ranges.items()}
    err_top = {axis: 0.92 * r for axis, r in err_ranges.items()}
    spans = _data_spans(result)
    for plot, top in (("attitude", att_top), ("error", err_top)):
        if plot == "error" and not scored:
            continue
        log_event_markers(rec, result.events, top, plot=plot)
        log_spans(rec, spans, top, plot=plot)

