"""An estimate scored without being kept whole, to the bit.

``metrics.compare`` (and ``broadscore.broad_measures``) read an hour-long estimate at few of
its rows: the pair of rows that brackets each reference time (``quaternion.interpolate``
blends those two), the first and last finite rows (the span scored), and around a hole of
non-finite rows the hole itself and the finite row on each side (not interpolated across, or
counted as a gap). ``bracket_rows`` names the pairs before estimating; ``ScoredRows`` keeps,
as each step is estimated, those rows and the others, in float64 as estimated. Scored on
them, an estimate gives the same numbers as scored whole (the pairs are the same rows, the
same distance apart in time and in rows of the estimate), at 6 MB for an hour at 400 Hz
against a 25 Hz reference instead of 46 MB. The replay then keeps the whole estimate in
float32, for the view only.
"""
from __future__ import annotations

import numpy as np

from ..flight import AttitudeSeries


def bracket_rows(t: np.ndarray, at: np.ndarray) -> np.ndarray:
    """The rows of ``t`` (increasing) that ``quaternion.interpolate`` reads to interpolate at the
    times ``at`` (its pair: the last row at or before each time, and the next), sorted."""
    t = np.asarray(t, dtype=float)
    if len(t) < 2:
        return np.arange(len(t))
    at = np.asarray(at, dtype=float)
    at = at[np.isfinite(at) & (at >= t[0]) & (at <= t[-1])]
    i = np.clip(np.searchsorted(t, at, side="right") - 1, 0, len(t) - 2)
    return np.unique(np.concatenate([i, i + 1]))


class ScoredRows:
    """One estimator's attitude at the rows scoring reads (see the module docstring)."""

    def __init__(self, wanted: np.ndarray):
        self.wanted = np.asarray(wanted, dtype=np.int64)  # sorted rows (``bracket_rows``)
        self._rows: list[np.ndarray] = []
        self._q: list[np.ndarray] = []
        self._last_finite: tuple[int, np.ndarray] | None = None  # (row, q) of the last finite row so far
        self._after_hole = False  # the last row added was not finite: the next finite one is kept
        self._seen_finite = False

    def add(self, a: int, q: np.ndarray) -> None:
        """Rows ``a``, ``a + 1``, ... of the estimate, as estimated (float64)."""
        n = len(q)
        if not n:
            return
        keep = np.zeros(n, dtype=bool)
        lo, hi = np.searchsorted(self.wanted, [a, a + n])
        keep[self.wanted[lo:hi] - a] = True
        finite = np.isfinite(q).all(axis=1)
        good = np.flatnonzero(finite)
        if len(good) and (self._after_hole or not self._seen_finite):
            keep[good[0]] = True  # the first finite row after a hole, or of all
        bad = np.flatnonzero(~finite)
        if len(bad):
            keep[bad] = True
            after = np.searchsorted(good, bad)  # each hole's finite neighbours
            keep[good[after[after < len(good)]]] = True
            keep[good[after[after > 0] - 1]] = True
            if (after == 0).any() and self._last_finite is not None:  # the one before is in an earlier step
                self._rows.append(np.array([self._last_finite[0]]))
                self._q.append(self._last_finite[1][None, :])
            self._after_hole = bool(bad[-1] > (good[-1] if len(good) else -1))
        elif len(good):
            self._after_hole = False
        if len(good):
            self._seen_finite = True
            self._last_finite = (a + int(good[-1]), q[good[-1]].astype(float))  # a copy, not a view
        kept = np.flatnonzero(keep)
        self._rows.append(a + kept)
        self._q.append(np.asarray(q[kept], dtype=float))

    def series(self, name: str, t: np.ndarray, release: bool = False) -> AttitudeSeries:
        """The rows kept, and the last finite one, at their times ``t[row]``. ``release``: the
        rows kept are let go as they are joined (not held twice: an hour's seven estimates, 40
        MB); nothing is left for a later call."""
        rows, q = list(self._rows), list(self._q)
        if self._last_finite is not None:
            rows.append(np.array([self._last_finite[0]]))
            q.append(self._last_finite[1][None, :])
        if not rows:
            return AttitudeSeries(name, np.empty(0), np.empty((0, 4)))
        if release:
            self._rows, self._q, self._last_finite = [], [], None
        rows_all, q_all = np.concatenate(rows), np.concatenate(q)
        del rows, q
        unique, first = np.unique(rows_all, return_index=True)
        return AttitudeSeries(name, np.asarray(t)[unique], q_all[first])
