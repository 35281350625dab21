"""Reports of a replay: a terminal table, a JSON summary and per-series CSV files.

All angles are in degrees; times in seconds on the autopilot's clock, as the flight stores them.
"""
from __future__ import annotations

import re
from pathlib import Path

import numpy as np

from ..flight import AttitudeSeries
from ..scoring.metrics import AXES, AxisMetrics, Comparison
from ..outputs import json_text
from ..quaternion import to_euler, wrap_deg

BUCKET_KEYS = ("lt_0.5", "0.5_1", "1_2", "gt_2")  # [0,0.5), [0.5,1), [1,2), [2,inf) degrees
YAW_DRIFT = "drift (no heading reference)"  # beside the yaw of an estimator without one
YAW_ALIGNED_NOTE = ("* yaw drift (no heading reference: no compass used): the gyro's yaw, its start aligned to the "
                    "reference; not a heading, so not comparable with an estimator that has one")
NOT_MEANINGFUL = "NOT MEANINGFUL"
CSV_HEADER = "time_s,roll_deg,pitch_deg,yaw_deg"
CSV_DECIMALS = 6  # µs for time (ArduPilot stamps in µs), 1e-6° for angles


# ---------------------------------------------------------------- terminal table


def format_table(comparisons: dict[str, Comparison], reference_name: str, declination=None,
                 streams: dict[str, Comparison] | None = None, reference_algorithm: str | None = None) -> str:
    """A fixed-width table: per estimator and axis, n and MAE, RMSE, max |error| (degrees), R².

    ``streams``: the autopilot's other streams scored against the same reference, as rows after
    the estimators, and under the table a line per axis comparing the estimators' spread with
    the autopilot's own (``spread_lines``; ``reference_algorithm`` names the reference there).

    Yaw is shown as ``yaw*``, marked as drift (YAW_DRIFT, with a footnote) where the estimator
    had no heading reference and its initial yaw was aligned; an axis with no scored sample
    shows "n/a". Scores that are not meaningful (``Comparison.not_meaningful``: an IMU too slow
    to follow the vehicle) are shown with one decimal, under a line that says why. ``declination``
    (a ``declination.Declination``): said under the title, with where it came from.
    """
    streams = streams or {}
    name_w = max([len("estimator")] + [len(name) for name in [*comparisons, *streams]])
    cols = ("n", "MAE", "RMSE", "max", "R²")
    widths = (9, 8, 8, 8, 8)

    def row(name: str, axis: str, cells) -> str:
        body = "  ".join(f"{c:>{w}}" for c, w in zip(cells, widths))
        return f"{name:<{name_w}}  {axis:<5}  {body}".rstrip()

    header = row("estimator", "axis", cols)
    lines = [f"Attitude error against {reference_name} (degrees; R² unitless)"]
    if declination is not None:
        lines.append(f"declination {declination.text()}")
    for why in dict.fromkeys(c.not_meaningful for c in comparisons.values() if c.not_meaningful):
        lines.append(f"{NOT_MEANINGFUL}: {why}. The scores below are shown, not to be relied on or ranked.")
    lines += [header, "-" * len(header)]
    any_aligned = False
    for name, comp in {**comparisons, **streams}.items():
        digits, r2_digits = (1, 2) if comp.not_meaningful else (3, 4)
        for k, axis in enumerate(AXES):
            label, remark = axis, ""
            if axis == "yaw" and comp.yaw_aligned:
                label, remark, any_aligned = "yaw*", f"  {YAW_DRIFT}", True
            m = comp.axes.get(axis)
            if m is None:
                cells = ("0", "n/a", "n/a", "n/a", "n/a")
            else:
                cells = (f"{m.n:d}", f"{m.mae:.{digits}f}", f"{m.rmse:.{digits}f}", f"{m.max:.{digits}f}",
                         "n/a" if not np.isfinite(m.r2) else f"{m.r2:.{r2_digits}f}")
            lines.append(row(name if k == 0 else "", label, cells) + remark)
    if not comparisons:
        lines.append("(no estimates)")
    if any_aligned:
        lines.append(YAW_ALIGNED_NOTE)
    if reference_algorithm != "truth":  # against truth the streams are scored, not a spread
        lines += spread_lines(comparisons, streams, reference_algorithm or reference_name)
    return "\n".join(lines) + "\n"


def reference_spread(streams: dict[str, Comparison]) -> dict | None:
    """The reference's own spread: how far the autopilot's other estimates are from it.

    ``roll`` and ``pitch``: the smallest MAE (°) on that axis among the autopilot's other
    streams scored against the reference (``commands.replay.score_autopilot_streams``; copies of the
    reference left out); ``tilt``: the smallest mean of roll and pitch MAE among them (one
    stream's). The closest other estimate is the least the reference is known to be uncertain
    by: a lead between estimators smaller than this is not measured by this reference. Each
    value is None where no stream scored that axis; the whole is None without another stream."""
    if not streams:
        return None
    out = {}
    for axis in ("roll", "pitch"):
        maes = [c.axes[axis].mae for c in streams.values() if c.axes.get(axis) is not None]
        out[axis] = min(maes) if maes else None
    tilts = [0.5 * (c.axes["roll"].mae + c.axes["pitch"].mae) for c in streams.values()
             if c.axes.get("roll") is not None and c.axes.get("pitch") is not None]
    out["tilt"] = min(tilts) if tilts else None
    return out


def spread_lines(comparisons: dict[str, Comparison], streams: dict[str, Comparison], reference: str) -> list[str]:
    """Per axis (roll, pitch), against the autopilot's own spread (``reference_spread``): whether
    the estimators' order on it means anything. Nothing without another stream or two scored
    estimators (the "autopilot" row against truth is not an estimator)."""
    lines = []
    for axis in ("roll", "pitch"):
        scored = {n: c.axes[axis] for n, c in streams.items() if c.axes.get(axis) is not None}
        maes = [c.axes[axis].mae for n, c in comparisons.items()
                if n != "autopilot" and c.axes.get(axis) is not None and not c.not_meaningful]
        if not scored or len(maes) < 2:
            continue
        closest = min(scored, key=lambda n: scored[n].mae)
        spread, span = scored[closest].mae, max(maes) - min(maes)
        other = closest.split(":", 1)[1].split(" (")[0]  # "autopilot:EKF1 (EKF1)" -> "EKF1"
        said = (f"the estimators' MAEs span {span:.2f}° ({min(maes):.2f}-{max(maes):.2f}), "
                f"{'less' if span < spread else 'more'} than the autopilot's own spread {spread:.2f}° "
                f"({reference} vs {other})")
        lines.append(f"{axis}: {said}: " + ("their order on it is not meaningful against this reference"
                                           if span < spread else "a lead smaller than that is not meaningful"))
    return lines


# ---------------------------------------------------------------- JSON summary


def to_json_dict(log: str, reference: dict, comparisons: dict[str, Comparison],
                 extras: dict[str, dict] | None = None, scoring: dict | None = None, events=None,
                 declination=None, streams: dict[str, Comparison] | None = None) -> dict:
    """The JSON summary: ``{"log", "reference", "estimators": {name: {"roll": M, "pitch": M, "yaw": M}}}``.

    ``reference``: ``{"stream": "ATT", "algorithm": "DCM", "choice": "autopilot"}`` (``commands.replay.Reference``;
    a live session's algorithm is null). ``streams`` (the autopilot's other streams scored
    against the reference, ``commands.replay.score_autopilot_streams``) adds ``autopilot_streams``
    ({row name: as an estimator's, without extras}) and ``reference_spread_deg`` ({"roll",
    "pitch", "tilt"}: ``reference_spread``; null without another stream, and against truth).

    M holds ``n``, ``mae``, ``rmse``, ``mse`` (deg²), ``r2``, ``max``, ``sigma1``, ``sigma3``
    (degrees) and ``buckets`` (shares keyed by ``BUCKET_KEYS``); the yaw M also holds
    ``aligned`` (true: drift, no heading reference). M is null for an axis with no scored sample; a
    non-finite number is null. ``meaningful``: false where the scores do not measure the
    estimator (``why``: the reason, e.g. an IMU too slow to follow the vehicle; null when true).
    ``unscored_in_gaps``: reference samples in a gap of the estimate or across a restart;
    ``unscored_suspect_reference``: in a span where the reference is not trusted (``refcheck``) or that
    the source says not to score (BROAD's rest phases). Against a truth, ``broad``: {total_rmse_deg,
    heading_rmse_deg, inclination_rmse_deg} (``broadscore``; total and heading null with no heading reference).
    ``extras`` adds keys per estimator next to the axes: ``events`` (what became of its
    accelerometer updates: {state: {samples, spans, seconds}}; a watchdog's resets:
    ``resets``: {count, times}), ``diagnostics`` (median and
    max of each diagnostic series) and ``params``. ``events``: every ``events.Event`` as
    {t_s, level, kind, text}, each one (the terminal shows a line per kind). ``declination`` (a ``declination.Declination``)
    adds ``declination_deg`` (null where none was found and 0 used) and ``declination_source``.
    """
    estimators = {str(name): _comparison_dict(comp, (extras or {}).get(name, {})) for name, comp in comparisons.items()}
    out = {"log": str(log), "reference": dict(reference), "estimators": estimators}
    if streams is not None:
        out["autopilot_streams"] = {str(name): _comparison_dict(comp, {}) for name, comp in streams.items()}
        against_truth = reference.get("algorithm") == "truth"
        spread = None if against_truth else reference_spread(streams)
        out["reference_spread_deg"] = None if spread is None else {k: _number(v) if v is not None else None
                                                                   for k, v in spread.items()}
    if declination is not None:
        out["declination_deg"] = round(declination.deg, 4) if declination.known else None
        out["declination_source"] = declination.source
    if scoring is not None:
        out["scoring"] = _clean(scoring)
    if events is not None:
        out["events"] = [e.as_dict() for e in sorted(events, key=lambda e: e.t)]
    return out


def _comparison_dict(comp: Comparison, extras: dict) -> dict:
    """One row of the JSON: per axis its metrics, then how it was scored, then ``extras``."""
    axes = {}
    for axis in AXES:
        m = comp.axes.get(axis)
        entry = None if m is None else _metrics_dict(m)
        if entry is not None and axis == "yaw":
            entry["aligned"] = bool(comp.yaw_aligned)
        axes[axis] = entry
    axes["meaningful"] = comp.not_meaningful is None
    axes["why"] = comp.not_meaningful
    axes["unscored_in_gaps"] = comp.n_in_gaps
    axes["unscored_suspect_reference"] = comp.n_excluded
    if comp.broad is not None:  # against a truth: BROAD's error-quaternion measures
        axes["broad"] = comp.broad
    axes.update(_clean(extras))
    return axes


def _clean(value):
    """JSON-safe: non-finite numbers to null, numpy scalars to Python."""
    if isinstance(value, dict):
        return {str(k): _clean(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_clean(v) for v in value]
    if isinstance(value, (bool, np.bool_)):
        return bool(value)
    if isinstance(value, (int, np.integer)):
        return int(value)
    if isinstance(value, (float, np.floating)):
        return _number(value)
    return value


def estimator_extras(result) -> dict[str, dict]:
    """Per estimator: its events, a summary of its diagnostics and its parameters (for the JSON)."""
    from dataclasses import asdict

    out = {}
    for name in result.estimates:
        diag = {}
        for key, series in result.diagnostics.get(name, {}).items():
            if key == "accel_state":
                continue
            finite = series[np.isfinite(series)]
            diag[key] = {"median": float(np.median(finite)) if len(finite) else None,
                         "max": float(finite.max()) if len(finite) else None}
        params = result.params.get(name)
        nonfinite = result.nonfinite[name] if name in result.nonfinite else \
            int(np.count_nonzero(~np.isfinite(result.estimates[name].q).all(axis=1)))  # (kept at every row)
        out[name] = {"events": result.estimator_events.get(name, {}), "diagnostics": diag,
                     "nonfinite_samples": nonfinite,
                     "params": asdict(params) if params is not None else {}}
    return out


def nothing_scored(comparisons: dict[str, Comparison], warmup_s: float) -> str | None:
    """Why no sample was scored, when none was: a log (or session) about as short as the
    warm-up, an estimate that never overlaps the reference, or a reference not trusted
    anywhere after the warm-up (``refcheck``). None when something was."""
    if not comparisons or any(a is not None for c in comparisons.values() for a in c.axes.values()):
        return None
    spans = [c.overlap_s for c in comparisons.values() if c.overlap_s is not None]
    if not spans:
        return "nothing scored: the estimates and the reference never overlap in time"
    if max(spans) > warmup_s and any(c.n_excluded for c in comparisons.values()):
        return (f"nothing scored: the reference is not trusted anywhere the estimates overlap it after the "
                f"{warmup_s:g} s warm-up (the 'reference not trusted' warnings say where and why)")
    return (f"nothing scored: the estimates overlap the reference for {max(spans):.1f} s, no more than the "
            f"{warmup_s:g} s warm-up (use a shorter --warmup)")


def format_events(result) -> str:
    """One line per estimator state other than "used": how often and how long the
    accelerometer update was skipped or down-weighted (a watchdog's resets are warnings)."""
    lines = [modes] if (modes := modes_line(result.flight)) else []
    n = len(result.flight.imu[result.imu_source].t)
    for name, states in result.estimator_events.items():
        for state, c in states.items():
            if c.get("samples"):  # not a marked event's {count, times} (Estimator.MARKS: warnings)
                lines.append(f"{name}: accelerometer {state}: {c['spans']} span{'s' if c['spans'] != 1 else ''}, "
                             f"{c['seconds']:.1f} s "
                             f"({100.0 * c['samples'] / max(n, 1):.1f} % of samples)")
    return "\n".join(lines) + ("\n" if lines else "")


def modes_line(flight) -> str | None:
    """The flight modes the log says were flown, each with its time in all ("modes: ALT_HOLD
    31.2 s, LOITER 52.0 s"), in the order first flown; None when the log has none."""
    if flight.modes is None:
        return None
    held: dict[str, float] = {}
    for start, end, _, name in flight.modes.spans(flight.time_span[1]):
        held[name] = held.get(name, 0.0) + end - start
    return "modes: " + ", ".join(f"{name} {seconds:.1f} s" for name, seconds in held.items())


def write_json(path, log: str, reference: dict, comparisons: dict[str, Comparison],
               extras: dict[str, dict] | None = None, scoring: dict | None = None, link: dict | None = None,
               events=None, declination=None, streams: dict[str, Comparison] | None = None) -> Path:
    """Write ``to_json_dict`` to ``path`` (strict JSON: no NaN), creating its directory;
    ``link``: a live session's link figures, as "link"."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    data = to_json_dict(log, reference, comparisons, extras, scoring, events, declination, streams)
    if link is not None:
        data["link"] = link
    path.write_text(json_text(data, allow_nan=False), encoding="utf-8")
    return path


def _metrics_dict(m: AxisMetrics) -> dict:
    return {
        "n": int(m.n),
        "mae": _number(m.mae),
        "rmse": _number(m.rmse),
        "mse": _number(m.mse),
        "r2": _number(m.r2),
        "max": _number(m.max),
        "sigma1": _number(m.sigma1),
        "sigma3": _number(m.sigma3),
        "buckets": {key: _number(share) for key, share in zip(BUCKET_KEYS, m.buckets)},
    }


def _number(x) -> float | None:
    x = float(x)
    return x if np.isfinite(x) else None


# ---------------------------------------------------------------- CSV export


def write_csv(directory, reference: AttitudeSeries, estimates: dict[str, AttitudeSeries],
              paths: dict[str, Path] | None = None) -> dict[str, Path]:
    """Write ``DIR/reference.csv`` and ``DIR/<estimator>.csv``; returns {"reference"|name: path}.
    ``paths``: where to write each instead ({"reference"|name: path}, temporary files that
    ``outputs`` puts in place).

    Columns ``time_s,roll_deg,pitch_deg,yaw_deg``: time as stored (s, autopilot clock), ZYX
    Euler angles in degrees with yaw in [-180, 180), six decimals; NaN rows are written as
    ``nan``. Characters other than letters, digits, ``.``, ``-`` and ``_`` in an estimator's
    name become ``_`` in its file name. The text is built with array operations (no per-row
    Python), so 10^6 rows take a fraction of a second.
    """
    directory = Path(directory)
    directory.mkdir(parents=True, exist_ok=True)
    targets = {"reference": (directory / "reference.csv", reference)}
    for name, series in estimates.items():
        path = directory / csv_file_name(name)
        if any(path == p for p, _ in targets.values()):
            raise ValueError(f"estimator {name!r} would overwrite {path.name}")
        targets[name] = (path, series)
    for name, (path, series) in targets.items():
        _write_attitude_csv((paths or {}).get(name, path), series)
    return {name: path for name, (path, _) in targets.items()}


def csv_file_name(name: str) -> str:
    """The CSV file ``write_csv`` writes for a series named ``name``."""
    stem = re.sub(r"[^A-Za-z0-9._-]", "_", str(name)).lstrip(".")
    return (stem or "_") + ".csv"


def _write_attitude_csv(path: Path, series: AttitudeSeries) -> None:
    t = np.asarray(series.t, dtype=float).reshape(-1)
    q = np.asarray(series.q, dtype=float).reshape(-1, 4)
    with np.errstate(invalid="ignore"):
        euler = np.degrees(to_euler(q))
    # Round before wrapping so that a yaw of 179.9999999° cannot print as 180.000000.
    euler[:, 2] = wrap_deg(np.round(euler[:, 2], CSV_DECIMALS))
    body = _fixed_point_csv(np.column_stack([t, euler]), CSV_DECIMALS)
    with open(path, "wb") as f:
        f.write(CSV_HEADER.encode("ascii") + b"\n")
        f.write(body)


def _fixed_point_csv(values: np.ndarray, decimals: int) -> bytes:
    """Rows of comma-separated fixed-point numbers (``-12.345678``), each row ending in a newline.

    Vectorised: every field is laid out as bytes in a fixed-width (rows, columns, width) array,
    digits computed by integer arithmetic, unused positions filled with 0 and dropped at the end.
    Non-finite values are written ``nan``. Values too large for exact int64 scaling (never an
    attitude or a flight time) fall back to Python's formatting.
    """
    values = np.asarray(values, dtype=float)
    if values.ndim != 2 or decimals < 1:
        raise ValueError("expected a 2-D array and at least one decimal")
    if values.size == 0:
        return b""
    n_rows, n_cols = values.shape
    finite = np.isfinite(values)
    scale = 10 ** decimals
    scaled = np.round(np.where(finite, values, 0.0) * scale)
    if np.abs(scaled).max() >= 2.0 ** 53:
        fmt = ",".join([f"%.{decimals}f"] * n_cols) + "\n"
        return "".join(fmt % tuple(r) for r in values.tolist()).encode("ascii")

    units = np.abs(scaled).astype(np.uint64)  # value in 10^-decimals
    whole = units // np.uint64(scale)
    n_int = max(1, len(str(int(whole.max()))))  # integer digits of the widest value
    # 32-bit division is about twice as fast; the fraction always fits, the integer part nearly always.
    frac = (units - whole * np.uint64(scale)).astype(np.uint32)
    whole = whole.astype(np.uint32) if n_int < 10 else whole
    width = 1 + n_int + 1 + decimals + 1  # sign, integer part, '.', fraction, separator
    out = np.zeros((n_rows, n_cols, width), dtype=np.uint8)
    out[..., 0] = np.where(scaled < 0, ord("-"), 0)
    ten, zero = whole.dtype.type(10), np.uint8(ord("0"))
    for pos in range(n_int, 0, -1):  # integer digits, units first; leading zeros stay 0 (dropped)
        significant = (whole > 0) | (pos == n_int)
        rest = whole // ten
        digit = (whole - rest * ten).astype(np.uint8) + zero
        out[..., pos] = np.where(significant, digit, 0) if pos < n_int else digit
        whole = rest
    out[..., n_int + 1] = ord(".")
    ten = np.uint32(10)
    for pos in range(width - 2, n_int + 1, -1):  # fraction digits, last first
        rest = frac // ten
        out[..., pos] = (frac - rest * ten).astype(np.uint8) + zero
        frac = rest
    if not finite.all():
        bad = ~finite
        out[bad, :-1] = 0
        out[bad, -4:-1] = np.frombuffer(b"nan", dtype=np.uint8)
    out[..., -1] = ord(",")
    out[:, -1, -1] = ord("\n")
    return out.tobytes().replace(b"\x00", b"")
