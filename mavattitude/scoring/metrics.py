"""Accuracy of an attitude estimate against a reference (ALGORITHMS.md "Metrics"; paper 001 eq 22-23).

``compare`` puts an estimate on the reference's clock, turns both into ZYX Euler angles and
scores the per-axis error ``estimate - reference`` (degrees, wrapped to [-180, 180) before any
statistic). Everything is vectorised numpy: a 10^6-sample comparison takes well under a second.

Euler errors are what the papers report, with the usual caveat: near pitch ±90° roll and yaw
are ill-defined and their errors meaningless. Quaternion math is delegated to ``quaternion``.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..flight import AttitudeSeries
from ..quaternion import interpolate, normalize, to_euler, wrap_deg

AXES = ("roll", "pitch", "yaw")
BUCKET_EDGES_DEG = (0.5, 1.0, 2.0)  # shares below 0.5°, 0.5-1°, 1-2°, above 2°
SIGMA1_LEVEL = 0.6826  # share of a normal population within ±1σ
SIGMA3_LEVEL = 0.9973  # share of a normal population within ±3σ
YAW_ALIGN_WINDOW_S = 1.0  # s: span at the start of scoring whose mean yaw error is removed


@dataclass
class AxisMetrics:
    """Statistics of the error on one axis over the scored samples.

    Angles in degrees. ``sigma1``/``sigma3`` are quantiles of |error| with numpy's default
    linear interpolation between order statistics. ``buckets`` are the shares of samples with
    |error| in the half-open intervals [0, 0.5), [0.5, 1), [1, 2), [2, inf) degrees; they sum to 1.
    """
    n: int
    mae: float
    rmse: float
    mse: float  # deg²
    r2: float  # against the reference's own mean (the standard R²); NaN if the reference is constant
    max: float
    sigma1: float  # 68.26 % quantile of |error|
    sigma3: float  # 99.73 % quantile of |error|
    buckets: tuple[float, float, float, float]  # shares: <0.5°, 0.5-1°, 1-2°, >=2°


@dataclass
class Comparison:
    """One estimate against one reference."""
    estimator: str
    reference: str
    t: np.ndarray  # reference timestamps inside the estimate's span, s
    error_deg: np.ndarray  # (N, 3) roll, pitch, yaw error (estimate - reference), wrapped to [-180, 180)
    scored: np.ndarray  # (N,) bool: after the warm-up, counted in the statistics
    axes: dict[str, AxisMetrics | None]  # None where no sample was scored
    yaw_aligned: bool = False  # yaw had no heading reference: its initial offset was removed
    yaw_offset_deg: float = 0.0  # the offset removed (of the first span)
    yaw_offsets_deg: tuple = ()  # ((span start s, offset removed °), ...): one per span between restarts
    warmup_s: float = 10.0
    # Input rows with a NaN (time or quaternion component), excluded. A reference time whose
    # interpolation would bridge a NaN estimate row keeps NaN in ``error_deg`` and is not scored.
    n_nan_reference: int = 0
    n_nan_estimate: int = 0
    # Reference samples inside a gap of the estimate (longer than max_gap_s, or across a
    # restart): nothing was estimated there, so they are not scored.
    n_in_gaps: int = 0
    n_excluded: int = 0  # reference samples inside an excluded (suspect) span, not scored
    overlap_s: float | None = None  # s from the first reference time inside the estimate to the last; None: none
    # Why the scores do not measure the estimator (an IMU too slow to follow the vehicle:
    # ``imucheck``), set by the caller; None: they do.
    not_meaningful: str | None = None
    # Against a truth: total, heading and inclination RMSE of the error quaternion
    # (``broadscore.broad_measures``); None otherwise.
    broad: dict | None = None


def compare(reference: AttitudeSeries, estimate: AttitudeSeries, warmup_s: float = 10.0,
            align_yaw: bool = False, name: str | None = None, restarts=(),
            max_gap_s: float = np.inf, exclude=()) -> Comparison:
    """Score ``estimate`` against ``reference`` per Euler axis.

    - The estimate is interpolated (nlerp, ``quaternion.interpolate``) at the reference's
      timestamps inside the estimate's span; it is never extrapolated, and never interpolated
      across a NaN estimate row, a gap longer than ``max_gap_s`` or a restart (that would
      invent an attitude over a hole): reference samples there are not scored, and counted in
      ``n_in_gaps``.
    - ``exclude``: (start, end) spans (s) of a reference not to be trusted (``refcheck``): its
      samples there are not scored, and counted in ``n_excluded``.
    - Warm-up: reference samples earlier than the estimate's first valid sample + ``warmup_s``
      seconds are kept in ``t``/``error_deg`` (so they can be plotted) but not scored: filters
      start from a rough attitude and need time to converge.
    - ``align_yaw`` is for an estimate with no heading reference (its yaw starts at an arbitrary
      value). The removed offset is the circular mean of the yaw error over the first
      ``YAW_ALIGN_WINDOW_S`` of the *scored* span: aligning after the warm-up means the statistics
      measure the yaw drift over the scored span only, and averaging over a second (rather than
      taking one sample) keeps noise out of the offset. The offset is subtracted from every row,
      warm-up included. With no scored sample there is nothing to align with: offset 0.
      ``restarts`` (times, s) are where the estimator started again after a gap in the data:
      with no heading reference its yaw after a gap is unrelated to before, so each span
      between restarts gets its own offset, from its own first scored second.
      ``yaw_offset_deg`` is the first span's.
    - R² is ``1 - SS_res / SS_tot`` with ``SS_tot`` about the reference's mean; for yaw the mean
      is circular and the deviations are wrapped, so a heading around ±180° is not a spread of
      360°. R² is NaN when the reference does not vary (SS_tot = 0: undefined).

    ``name`` defaults to ``estimate.source``. Times in seconds on the same clock; an estimate
    out of time order is sorted first. NaN rows (time or quaternion) of either input are
    excluded and counted in ``n_nan_reference``/``n_nan_estimate``; a reference row with a time
    but a NaN attitude stays in ``t`` as an unscored NaN gap.
    """
    t_ref = np.asarray(reference.t, dtype=float)
    q_ref = np.asarray(reference.q, dtype=float).reshape(-1, 4)
    t_est = np.asarray(estimate.t, dtype=float)
    q_est = np.asarray(estimate.q, dtype=float).reshape(-1, 4)
    if np.any(np.diff(t_est) < 0):
        order = np.argsort(t_est, kind="stable")
        t_est, q_est = t_est[order], q_est[order]

    ref_ok = np.isfinite(t_ref) & np.isfinite(q_ref).all(axis=1)
    est_ok = np.isfinite(t_est) & np.isfinite(q_est).all(axis=1)
    est_index = np.flatnonzero(est_ok)  # positions of the valid rows in the (sorted) estimate
    # (no copy of an hour-long estimate when every row is valid, as nearly always)
    te, qe = (t_est, q_est) if len(est_index) == len(t_est) else (t_est[est_ok], q_est[est_ok])

    if len(te):
        in_span = np.isfinite(t_ref) & (t_ref >= te[0]) & (t_ref <= te[-1])
    else:
        in_span = np.zeros(len(t_ref), dtype=bool)
    t = t_ref[in_span]
    q_ref_span = np.where(ref_ok[in_span, None], q_ref[in_span], np.nan)

    q_at = interpolate(te, qe, t)
    if len(te) < len(t_est):  # some estimate rows were NaN: do not interpolate across them
        q_at[_bridges_hole(te, est_index, t)] = np.nan
    in_gap = _in_gap(te, t, max_gap_s, np.sort(np.asarray(restarts, dtype=float)))
    q_at[in_gap] = np.nan

    with np.errstate(invalid="ignore", divide="ignore"):
        euler_ref = np.degrees(to_euler(normalize(q_ref_span)))
        error = wrap_deg(np.degrees(to_euler(q_at)) - euler_ref)
    valid = np.isfinite(error).all(axis=1)
    excluded = np.zeros(len(t), dtype=bool)
    for start, end in exclude:
        excluded |= (t >= start) & (t <= end)
    scored = valid & ~excluded & (t >= (te[0] + warmup_s if len(te) else np.inf))

    yaw_offset, offsets = 0.0, []
    if align_yaw and scored.any():
        bounds = np.concatenate([[-np.inf], np.sort(np.asarray(restarts, dtype=float)), [np.inf]])
        for start, end in zip(bounds[:-1], bounds[1:]):
            span = (t >= start) & (t < end)
            if not (scored & span).any():
                continue
            window = scored & span & (t < t[scored & span].min() + YAW_ALIGN_WINDOW_S)
            offsets.append((float(t[span][0]), float(circular_mean_deg(error[window, 2]))))
            error[span, 2] = wrap_deg(error[span, 2] - offsets[-1][1])
        yaw_offset = offsets[0][1]

    error_scored, ref_scored = error[scored], euler_ref[scored]
    axes = {axis: axis_metrics(error_scored[:, k], ref_scored[:, k], circular=(axis == "yaw"))
            for k, axis in enumerate(AXES)}
    return Comparison(
        estimator=name if name is not None else estimate.source,
        reference=reference.source,
        t=t,
        error_deg=error,
        scored=scored,
        axes=axes,
        yaw_aligned=bool(align_yaw),
        yaw_offset_deg=yaw_offset,
        yaw_offsets_deg=tuple(offsets),
        warmup_s=float(warmup_s),
        n_nan_reference=int(np.count_nonzero(~ref_ok)),
        n_nan_estimate=int(np.count_nonzero(~est_ok)),
        n_in_gaps=int(np.count_nonzero(in_gap)),
        n_excluded=int(np.count_nonzero(excluded)),
        overlap_s=float(t[-1] - t[0]) if len(t) else None,
    )


def axis_metrics(error_deg: np.ndarray, reference_deg: np.ndarray,
                 circular: bool = False) -> AxisMetrics | None:
    """Statistics of one axis: ``error_deg`` (already wrapped) and the reference angle, degrees.

    ``circular`` (yaw): the reference's mean is the circular mean and deviations from it are
    wrapped to [-180, 180) for R²'s SS_tot. Returns None for an empty axis.
    """
    e = np.asarray(error_deg, dtype=float)
    n = e.size
    if n == 0:
        return None
    ref = np.asarray(reference_deg, dtype=float)
    abs_e = np.abs(e)
    ss_res = float(np.dot(e, e))
    mse = ss_res / n
    if circular:
        deviation = wrap_deg(ref - circular_mean_deg(ref))
    else:
        deviation = ref - ref.mean()
    ss_tot = float(np.dot(deviation, deviation))
    r2 = 1.0 - ss_res / ss_tot if ss_tot > 0 else float("nan")
    sigma1, sigma3 = np.quantile(abs_e, [SIGMA1_LEVEL, SIGMA3_LEVEL])
    # side="right": a value equal to an edge belongs to the bucket above it ([0.5, 1) holds 0.5).
    bucket = np.searchsorted(np.asarray(BUCKET_EDGES_DEG), abs_e, side="right")
    shares = np.bincount(bucket, minlength=len(BUCKET_EDGES_DEG) + 1) / n
    return AxisMetrics(
        n=int(n),
        mae=float(abs_e.mean()),
        rmse=float(np.sqrt(mse)),
        mse=float(mse),
        r2=float(r2),
        max=float(abs_e.max()),
        sigma1=float(sigma1),
        sigma3=float(sigma3),
        buckets=tuple(float(s) for s in shares),
    )


def circular_mean_deg(angles_deg: np.ndarray) -> float:
    """Mean direction of angles (degrees), in [-180, 180): the angle of the mean unit vector."""
    a = np.radians(np.asarray(angles_deg, dtype=float))
    return float(wrap_deg(np.degrees(np.arctan2(np.sin(a).mean(), np.cos(a).mean()))))


def _interpolated(te: np.ndarray, t: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """For each time ``t``: whether the estimate at ``te`` is interpolated there (strictly
    between two of its samples), and the index of the later of the two (``right``)."""
    k = np.searchsorted(te, t, side="left")  # first sample at or after t
    right = np.clip(k, 1, len(te) - 1)  # bracket [right - 1, right] (clipped; masked below)
    return (k > 0) & (k < len(te)) & (te[right] != t), right


def _in_gap(te: np.ndarray, t: np.ndarray, max_gap_s: float, restarts: np.ndarray) -> np.ndarray:
    """True where ``t`` falls strictly between two estimate samples more than ``max_gap_s``
    apart, or with a restart after the first and at or before the second."""
    if len(te) < 2:
        return np.zeros(len(t), dtype=bool)
    inside, right = _interpolated(te, t)
    before, after = te[right - 1], te[right]
    restart = np.searchsorted(restarts, before, side="right") < np.searchsorted(restarts, after, side="right")
    return inside & ((after - before > max_gap_s) | restart)


def _bridges_hole(te: np.ndarray, est_index: np.ndarray, t: np.ndarray) -> np.ndarray:
    """True where interpolating the valid estimate samples ``te`` at ``t`` would span a NaN row.

    ``est_index`` holds each valid sample's position in the full estimate: two neighbouring
    valid samples whose positions differ by more than 1 had NaN rows between them. A time that
    falls exactly on a valid sample needs no interpolation and is never a hole.
    """
    if len(te) < 2:  # nothing to interpolate between
        return np.zeros(len(t), dtype=bool)
    inside, right = _interpolated(te, t)
    return inside & ((est_index[right] - est_index[right - 1]) > 1)
