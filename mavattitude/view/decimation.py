"""Which samples the recording gets (the rules in the package docstring), in one place that does
not import Rerun: the replay keeps an estimate only at the rows the view draws (``drawn_rows``),
chosen before it estimates, whether or not a viewer is open."""
from __future__ import annotations

import numpy as np

from ..flight import median_step

# What a screen can show: a time plot is 500-800 px wide; zoomed to 10 s, 50 Hz is a point
# every 1-2 px, and the error and diagnostic lines keep each bin's minimum and maximum, so no
# spike is lost. The 3D boxes move at 25 frames per second. (Was 200 Hz and 50 Hz: 4.7-19.6 MB
# per minute of log; scripts/rrd_size.py.)
SCALAR_MAX_HZ = 50.0
SCALAR_MAX_POINTS = 60_000
TRANSFORM_MAX_HZ = 25.0
TRANSFORM_MAX_POINTS = 45_000

MINMAX_ROWS = 1 << 17  # samples binned at a time by _bin_minmax (whole bins: a few more)


def _faster_than(t: np.ndarray, hz: float) -> bool:
    """Whether a series comes faster than hz on average (else decimating it keeps everything)."""
    return len(t) >= 2 and hz > 0 and len(t) > hz * float(t[-1] - t[0]) + 1


def _bin_first(t: np.ndarray, hz: float) -> np.ndarray:
    """Indices keeping the first sample of each 1/hz bin of absolute time (all of them when
    the series is not faster than hz on average)."""
    n = len(t)
    if not _faster_than(t, hz):
        return np.arange(n)
    b = t * hz
    np.floor(b, out=b)  # (in place: one temporary of the series, not two)
    keep = np.empty(n, dtype=bool)
    # The first sample opens a bin unless the sample before it (one typical step earlier,
    # possibly in the previous chunk) was in the same bin: chunks then keep what the
    # whole series would.
    step = median_step(t)
    keep[0] = np.floor((t[0] - step) * hz) != b[0]
    keep[1:] = b[1:] != b[:-1]
    return np.flatnonzero(keep)


def _bin_minmax(t: np.ndarray, y: np.ndarray, hz: float) -> np.ndarray:
    """Peak-preserving decimation to about hz: the (first) argmin and argmax of y in each
    2/hz bin, in time order; all samples when the series is not faster than hz. O(n). Done a
    run of whole bins at a time (``MINMAX_ROWS``): an hour's temporaries were 80 MB a line."""
    n = len(t)
    if not _faster_than(t, hz):
        return np.arange(n)
    b = t * (hz / 2.0)
    np.floor(b, out=b)
    if np.any(np.diff(b) < 0):  # unsorted time: keep the simple rule
        return _bin_first(t, hz)
    picks, a = [], 0
    while a < n:  # bins are independent: cut at a bin's end, the picks are the same
        e = n if a + MINMAX_ROWS >= n else \
            max(int(np.searchsorted(b, b[a + MINMAX_ROWS - 1], side="right")), a + MINMAX_ROWS)
        picks.append(a + _bin_minmax_sorted(b[a:e], y[a:e]))
        a = e
    return np.concatenate(picks)


def _bin_minmax_sorted(b: np.ndarray, y: np.ndarray) -> np.ndarray:
    """``_bin_minmax`` of whole bins: ``b`` each sample's bin number (non-decreasing)."""
    n = len(b)
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


def drawn_rows(t: np.ndarray, duration_s: float) -> np.ndarray:
    """The rows of a series at times ``t`` that ``log_attitude_columns`` draws for a log of
    ``duration_s`` (its Euler plots' and its box's), with the first and the last (its span): an
    estimate kept at these alone is drawn as kept whole."""
    t = np.asarray(t, dtype=np.float64)
    ends = [0, len(t) - 1] if len(t) else []
    return np.union1d(np.union1d(_bin_first(t, scalar_rate_for(duration_s)),
                                 _bin_first(t, transform_rate_for(duration_s))), ends).astype(np.int64)


def drawn_duration(flight, times) -> float:
    """The length a replay's rates are chosen for (``scalar_rate_for``, ``transform_rate_for``):
    the flight's span, or the longest of the drawn series' ``times`` if longer (a stream logged
    past the flight's other series)."""
    a, b = flight.time_span
    return max(b - a, max((float(t[-1] - t[0]) for t in times if len(t)), default=0.0))
