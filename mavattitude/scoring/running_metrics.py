"""``metrics.compare`` of a session of hours, in constant memory: the errors scored as they come.

A log is scored at the end, from every error at once. A live session cannot keep every error
for hours, so ``RunningComparison`` takes them a part at a time, in time order (the errors
``compare`` gives on the new part of the reference), and keeps per axis only:

- sums: n, MAE, MSE/RMSE, max and the bucket shares are those of ``compare`` (to the order
  of summation);
- R²: the reference's spread about its mean, merged part by part (Chan, Golub and LeVeque's
  update); for yaw, about the circular mean, from sums per degree of heading: exact but for
  the degree opposite the mean, whose samples wrap to ±180° on either side of it;
- sigma1 and sigma3 (quantiles of |error|): from counts in bins ``SKETCH_RATIO`` apart on a
  log scale (1e-6° to 180°), read at the bin's geometric middle and interpolated as numpy
  does: within 0.1 % of ``np.quantile`` (tested).

Yaw without a heading reference gets ``compare``'s offset per span between restarts, the
circular mean of its first scored second: the span's errors from its first scored sample on
wait (about a second of them) until that second is complete.

Spans of reference not to be trusted (``compare``'s ``exclude``) can be known only later: a
check finds them looking back (``running_refcheck``). ``update`` takes the spans known so far
and a time, ``settled``, before which they are final, and scores only the reference samples
before it: the later ones wait for the next update (the caller keeps them, and the estimate
around them), and the end of the session settles everything.
"""
from __future__ import annotations

import math

import numpy as np

from ..flight import AttitudeSeries
from .metrics import (AXES, BUCKET_EDGES_DEG, SIGMA1_LEVEL, SIGMA3_LEVEL, YAW_ALIGN_WINDOW_S, AxisMetrics,
                      Comparison, circular_mean_deg, compare)
from ..quaternion import normalize, to_euler, wrap_deg

SKETCH_MIN_DEG = 1e-6  # |error| below this counts in the first bin
SKETCH_RATIO = 1.002  # neighbouring bin edges: 0.2 % apart, so a bin's middle is within 0.1 % of its values
_EDGES = SKETCH_MIN_DEG * SKETCH_RATIO ** np.arange(int(math.log(180.0 / SKETCH_MIN_DEG, SKETCH_RATIO)) + 2)
_MIDDLES = np.concatenate([[0.0], np.sqrt(_EDGES[:-1] * _EDGES[1:])])  # bin 0 holds [0, 1e-6)


class RunningAxis:
    """The statistics of ``metrics.axis_metrics`` over errors given a part at a time."""

    def __init__(self, circular: bool = False):
        self.circular = circular
        self.n = 0
        self.abs_sum = self.sq_sum = self.max = 0.0
        self.buckets = np.zeros(len(BUCKET_EDGES_DEG) + 1, np.int64)
        self.sketch = np.zeros(len(_MIDDLES), np.int64)
        self.ref_mean = self.ref_m2 = 0.0  # roll, pitch: running mean and sum of squared deviations
        # yaw: per degree of heading, samples and sums of (heading - the degree's middle) and its square
        self.heading = np.zeros((360, 3)) if circular else None
        self.sin_sum = self.cos_sum = 0.0

    def add(self, error_deg: np.ndarray, reference_deg: np.ndarray) -> None:
        e, ref = np.asarray(error_deg, dtype=float), np.asarray(reference_deg, dtype=float)
        if not e.size:
            return
        a = np.abs(e)
        self.abs_sum += float(a.sum())
        self.sq_sum += float(np.dot(e, e))
        self.max = max(self.max, float(a.max()))
        np.add.at(self.buckets, np.searchsorted(np.asarray(BUCKET_EDGES_DEG), a, side="right"), 1)
        np.add.at(self.sketch, np.searchsorted(_EDGES, a, side="right"), 1)
        if self.circular:
            r = np.radians(ref)
            self.sin_sum += float(np.sin(r).sum())
            self.cos_sum += float(np.cos(r).sum())
            degree = np.clip(np.floor(ref + 180.0), 0, 359).astype(np.int64)
            u = ref - (degree - 179.5)
            np.add.at(self.heading, degree, np.column_stack([np.ones_like(u), u, u * u]))
        else:
            n_b, mean_b = len(ref), float(ref.mean())
            m2_b = float(np.dot(ref - mean_b, ref - mean_b))
            n = self.n + n_b
            delta = mean_b - self.ref_mean
            self.ref_mean += delta * n_b / n
            self.ref_m2 += m2_b + delta * delta * self.n * n_b / n
        self.n += len(e)

    def _ss_tot(self) -> float:
        if not self.circular:
            return self.ref_m2
        mean = wrap_deg(math.degrees(math.atan2(self.sin_sum, self.cos_sum)))
        middle = np.arange(360) - 179.5
        d = wrap_deg(middle - mean)  # each degree's deviation from the mean, wrapped as its samples are
        count, s1, s2 = self.heading.T
        return float(np.sum(s2 + 2.0 * d * s1 + count * d * d))

    def quantile(self, level: float) -> float:
        """np.quantile (linear) of |error| at ``level``, from the sketch."""
        cumulative = np.cumsum(self.sketch)
        position = (self.n - 1) * level
        lo, hi = math.floor(position), math.ceil(position)
        at = _MIDDLES[np.searchsorted(cumulative, [lo + 1, hi + 1])]
        return float(at[0] + (at[1] - at[0]) * (position - lo))

    def metrics(self) -> AxisMetrics | None:
        if not self.n:
            return None
        mse = self.sq_sum / self.n
        ss_tot = self._ss_tot()
        return AxisMetrics(n=self.n, mae=self.abs_sum / self.n, rmse=math.sqrt(mse), mse=mse,
                           r2=1.0 - self.sq_sum / ss_tot if ss_tot > 0 else float("nan"), max=self.max,
                           sigma1=min(self.quantile(SIGMA1_LEVEL), self.max),
                           sigma3=min(self.quantile(SIGMA3_LEVEL), self.max),
                           buckets=tuple(float(c) / self.n for c in self.buckets))


class RunningComparison:
    """``compare(reference, estimate, warmup_s, align_yaw, restarts)`` over a whole session,
    fed as the two grow (``update``); ``result`` is its ``Comparison`` without the per-sample
    arrays (``t``, ``error_deg`` and ``scored`` are empty)."""

    def __init__(self, estimator: str, reference: str, warmup_s: float):
        self.estimator, self.reference, self.warmup_s = estimator, reference, warmup_s
        self.axes = {axis: RunningAxis(circular=axis == "yaw") for axis in AXES}
        self.first_t: float | None = None  # the estimate's first valid sample: the warm-up counts from it
        self.until = -math.inf  # reference time scored up to
        self.estimate_until = -math.inf  # estimate time seen up to (its NaN rows counted)
        self.n_nan_estimate = self.n_in_gaps = self.n_excluded = 0
        self.t_first = self.t_last = math.nan  # reference times inside the estimate
        self.offsets: list[tuple[float, float]] = []  # (span start, yaw offset): compare's yaw_offsets_deg
        self.aligned = False
        self._span = -1  # the span (between restarts) the held rows belong to
        self._span_t0 = math.nan  # its first reference time
        self._align = False
        self._offset: float | None = None
        self._first_scored: float | None = None
        self._held: list[tuple] = []  # (t, error, reference, scored) of the current span, offset pending

    def update(self, reference: AttitudeSeries, estimate: AttitudeSeries, restarts=(), align_yaw=(False,),
               exclude=(), settled: float = math.inf):
        """Score the reference samples after ``until`` that ``estimate`` now covers, and that are
        earlier than ``settled``. Both series need only hold their latest part: the reference from
        ``until``, the estimate from its sample before the first of them. Restarts are times (s);
        span k (after k restarts) is yaw-aligned if ``align_yaw[k]`` (the last entry stands for
        later spans). ``exclude``: (start, end) spans not scored, final before ``settled``. Returns what
        became final, of these samples and of those held before: (t, error, scored), the error
        with its yaw offset removed (yaw NaN before a span's first scored sample, whose offset
        is not known yet); None if nothing."""
        new = estimate.t > self.estimate_until
        if new.any():
            ok = np.isfinite(estimate.q[new]).all(axis=1)
            self.n_nan_estimate += int(np.count_nonzero(~ok))
            if self.first_t is None and ok.any():
                self.first_t = float(estimate.t[new][ok][0])
            self.estimate_until = float(estimate.t[-1])
        if not len(reference.t) or not len(estimate.t):
            return None
        r0 = int(np.searchsorted(reference.t, self.until, side="right"))
        r1 = int(np.searchsorted(reference.t, estimate.t[-1], side="right"))
        r1 = min(r1, int(np.searchsorted(reference.t, settled, side="left")))
        if r1 <= r0:
            return None
        e0 = max(int(np.searchsorted(estimate.t, reference.t[r0])) - 1, 0)
        ref = AttitudeSeries(reference.source, reference.t[r0:r1], reference.q[r0:r1])
        part = compare(ref, AttitudeSeries(estimate.source, estimate.t[e0:], estimate.q[e0:]), warmup_s=0.0,
                       restarts=restarts, exclude=exclude)
        self.until = float(ref.t[-1])
        self.n_excluded += part.n_excluded
        t, error = part.t, part.error_deg.copy()
        if not len(t):
            return None
        reference_deg = np.degrees(to_euler(normalize(ref.q[np.searchsorted(ref.t, t)])))
        self.n_in_gaps += part.n_in_gaps
        self.t_first = t[0] if math.isnan(self.t_first) else self.t_first
        self.t_last = t[-1]
        scored = part.scored & (t >= (self.first_t + self.warmup_s if self.first_t is not None else math.inf))
        span = np.searchsorted(np.asarray(restarts, dtype=float), t, side="right")
        out = []
        for k in np.unique(span):
            rows = span == k
            if k != self._span:
                out += self._close_span()
                self._span, self._span_t0 = int(k), float(t[rows][0])
                self._align = bool(align_yaw[min(k, len(align_yaw) - 1)])
                self.aligned |= self._align
            out += self._take(t[rows], error[rows], reference_deg[rows], scored[rows])
        return joined(out)

    @property
    def yaw_offset(self) -> float | None:
        """The yaw offset (deg) removed in the current span, once known; None without alignment."""
        return self._offset if self._align else None

    def _take(self, t, error, reference, scored) -> list[tuple]:
        if not self._align or self._offset is not None:
            return [self._score(t, error, reference, scored)]
        out = []
        if self._first_scored is None:  # before the span's first scored sample: no offset to show yet
            first = int(np.argmax(scored)) if scored.any() else len(t)
            if first:
                early = error[:first].copy()
                early[:, 2] = np.nan
                out.append((t[:first], early, scored[:first]))
            if first == len(t):
                return out
            self._first_scored = float(t[first])
            t, error, reference, scored = t[first:], error[first:], reference[first:], scored[first:]
        self._held.append((t, error, reference, scored))
        if t[-1] >= self._first_scored + YAW_ALIGN_WINDOW_S:
            out += self._release()
        return out

    def _release(self) -> list[tuple]:
        """The span's first scored second is complete: its offset, then everything held."""
        held, self._held = self._held, []
        t, error, reference, scored = (np.concatenate(c) for c in zip(*held))
        window = scored & (t < self._first_scored + YAW_ALIGN_WINDOW_S)
        self._offset = circular_mean_deg(error[window, 2])
        self.offsets.append((self._span_t0, self._offset))
        return [self._score(t, error, reference, scored)]

    def _close_span(self) -> list[tuple]:
        out = self._release() if self._held else []
        self._offset, self._first_scored = None, None
        return out

    def _score(self, t, error, reference, scored) -> tuple:
        if self._align:
            error[:, 2] = wrap_deg(error[:, 2] - self._offset)
        for k, axis in enumerate(AXES):
            self.axes[axis].add(error[scored, k], reference[scored, k])
        return t, error, scored

    def result(self) -> Comparison:
        self._close_span()
        offsets = tuple(self.offsets)
        return Comparison(
            estimator=self.estimator, reference=self.reference, t=np.empty(0), error_deg=np.empty((0, 3)),
            scored=np.empty(0, bool), axes={axis: a.metrics() for axis, a in self.axes.items()},
            yaw_aligned=self.aligned, yaw_offset_deg=offsets[0][1] if offsets else 0.0, yaw_offsets_deg=offsets,
            warmup_s=float(self.warmup_s), n_nan_estimate=self.n_nan_estimate, n_in_gaps=self.n_in_gaps,
            n_excluded=self.n_excluded,
            overlap_s=None if math.isnan(self.t_first) else float(self.t_last - self.t_first))


def joined(parts: list[tuple]) -> tuple | None:
    """Parts of columns (tuples of arrays, in order) as one tuple of columns; None if empty."""
    parts = [p for p in parts if len(p[0])]
    if not parts:
        return None
    return tuple(np.concatenate(c) for c in zip(*parts))
