"""Ground or air: the flight phase that ncs-eskf's segmented thresholds need (paper 001 §3.2).

The phase comes from what the log has, best first:

1. barometric height above the start (pressure through the standard atmosphere, so it does
   not depend on the autopilot's own altitude estimate);
2. GPS altitude above the first 3D fix, when there is no barometer.

In the air means more than ``AIR_ABOVE_M`` above the start; back on the ground means below
``GROUND_BELOW_M`` again (hysteresis, so baro noise near the threshold does not flicker).
A height of a few metres is what tells flying from taxiing: a plane rolls at 20 m/s on the
runway, a multirotor hovers at 0 m/s, so GPS speed alone cannot decide. Where the log has
neither sensor the phase is unknown (NaN) and ncs-eskf uses its documented default.

Baro drifts with weather, a few metres per hour at most: an hour-long flight that lands
slightly below or above its start is still judged correctly by the hysteresis band.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .earth import pressure_height
from .flight import BaroSeries, Flight, GpsSeries
from .growing import Growing
from .kernel_cache import kernel

AIR_ABOVE_M = 3.0  # m above the start: in the air
GROUND_BELOW_M = 1.5  # m above the start: back on the ground
SMOOTH_S = 1.0  # s: heights are median-filtered over this span first
START_S = 3.0  # s: the start height is the median over this first span
STALE_S = 2.0  # s: beyond this from the last height sample, the phase is unknown


@dataclass
class PhaseSeries:
    source: str  # "baro height", "GPS height"
    t: np.ndarray  # (N,) s
    height_m: np.ndarray  # (N,) above the start, smoothed
    in_air: np.ndarray  # (N,) 1.0 in the air, 0.0 on the ground

    def on_clock(self, t: np.ndarray) -> np.ndarray:
        """The phase at times ``t`` (zero-order hold), NaN before the first sample or when stale."""
        idx = np.searchsorted(self.t, t, side="right") - 1
        out = self.in_air[np.clip(idx, 0, None)].astype(float)
        age = t - self.t[np.clip(idx, 0, None)]
        out[(idx < 0) | (age > STALE_S)] = np.nan
        return out


def detect_phase(flight: Flight) -> PhaseSeries | None:
    """The ground/air phase over a whole flight (``PhaseTracker`` over its best height
    source), or None when the log has no height source."""
    height = _baro_height(flight.baro) or _gps_height(flight.gps)
    if height is None:
        return None
    source, t, h = height
    tracker = PhaseTracker(source)
    tracker.add(t, h)
    return tracker.series()


def _baro_height(baro: BaroSeries | None):
    if baro is None:
        return None
    ok = np.isfinite(baro.pressure_pa) & (baro.pressure_pa > 1e3)
    if np.count_nonzero(ok) < 2:
        return None
    return "baro height", baro.t[ok], pressure_height(baro.pressure_pa[ok])


def _gps_height(gps: GpsSeries | None):
    if gps is None:
        return None
    ok = (gps.fix_type >= 3) & np.isfinite(gps.alt_m)
    if np.count_nonzero(ok) < 2:
        return None
    return "GPS height", gps.t[ok], gps.alt_m[ok]


@kernel
def _median(v, work):
    """np.median of ``v`` (finite values, at least one): the middle value, or the mean of the
    two middle ones, by quickselect in ``work`` (scratch at least as long). Not numba's
    np.median: its generic helpers took 0.8-1.0 s of every first compile, this 0.2 s."""
    n = len(v)
    for m in range(n):
        work[m] = v[m]
    k = (n - 1) // 2  # the middle one, or the lower of the two
    a, b = 0, n - 1
    while a < b:  # Hoare's partition about the middle element, until k sits between the parts
        pivot = work[(a + b) >> 1]
        i, j = a, b
        while i <= j:
            while work[i] < pivot:
                i += 1
            while work[j] > pivot:
                j -= 1
            if i <= j:
                work[i], work[j] = work[j], work[i]
                i += 1
                j -= 1
        if k <= j:
            b = j
        elif k >= i:
            a = i
        else:
            break
    low = work[k]
    if n % 2 == 1:
        return low
    high = work[k + 1]  # the next: the least of those after k, all >= work[k]
    for m in range(k + 2, n):
        if work[m] < high:
            high = work[m]
    return (low + high) / 2


@kernel
def _track(t, h, start, lo, state):
    """Heights above the start and the phase for samples [start, len(t)) of the accepted ones
    (``t`` increasing): the median of the last SMOOTH_S of samples, minus the median of the
    first START_S of samples (of those so far); hysteresis between the thresholds.
    ``lo``: a sample no later than SMOOTH_S before the first new one. ``state``: [in_air].
    Returns (height, in_air) of the new samples."""
    n = len(t) - start
    height = np.empty(n)
    in_air = np.empty(n)
    work = np.empty(len(t))  # _median's scratch
    n_start = 0
    while n_start < len(t) and t[n_start] <= t[0] + START_S:
        n_start += 1
    for k in range(n):
        i = start + k
        while t[lo] < t[i] - SMOOTH_S:
            lo += 1
        h_rel = _median(h[lo:i + 1], work) - _median(h[:min(i + 1, n_start)], work)
        if h_rel > AIR_ABOVE_M:
            state[0] = 1.0
        elif h_rel < GROUND_BELOW_M:
            state[0] = 0.0
        height[k] = h_rel
        in_air[k] = state[0]
    return height, in_air


class PhaseTracker:
    """The ground/air phase sample by sample, seeing only the past (the estimation core feeds
    it heights as they arrive, a whole log's at once or a link's a few at a time, with the
    same result): the height is the median of the last ``SMOOTH_S`` of samples, the start the
    median of the samples of the first ``START_S`` (of those seen so far, until then).

    ``add(t, height)`` takes raw heights (baro pressure height, or GPS altitude) in time order,
    ignoring non-finite ones and any not newer than the last, and says which it took; ``n``
    counts the phase rows.
    """

    def __init__(self, source: str):
        self.source = source
        self._heights = Growing(2)  # t, raw height of every sample accepted
        self._rows = Growing(3)  # t, height above the start (smoothed), in_air
        self._state = np.zeros(1)

    def add(self, t, height) -> np.ndarray:
        """Take the samples that are finite and newer than every one before; (N,) bool: which."""
        t = np.asarray(t, dtype=float).reshape(-1)
        height = np.asarray(height, dtype=float).reshape(-1)
        last = self._heights.last[0] if self._heights.n else -np.inf
        ok = np.isfinite(height) & np.isfinite(t)
        ok &= t > np.maximum.accumulate(np.concatenate([[last], np.where(ok, t, -np.inf)]))[:-1]
        if not ok.any():
            return ok
        start = self._heights.n
        self._heights.extend(np.column_stack([t[ok], height[ok]]))
        rows = self._heights.view()
        t_all = np.ascontiguousarray(rows[:, 0])
        lo = int(np.searchsorted(t_all, t_all[start] - SMOOTH_S))
        h_rel, in_air = _track(t_all, np.ascontiguousarray(rows[:, 1]), start, lo, self._state)
        self._rows.extend(np.column_stack([rows[start:, 0], h_rel, in_air]))
        return ok

    @property
    def n(self) -> int:
        return len(self._rows)

    def forget(self, rows: int) -> None:
        """Drop the first ``rows`` phase rows, and the heights no later sample reads: those
        after the first START_S and before the last SMOOTH_S (a live session of hours)."""
        self._rows.forget(rows)
        h = self._heights.view()
        if not len(h):
            return
        first = int(np.searchsorted(h[:, 0], h[0, 0] + START_S, side="right"))
        recent = int(np.searchsorted(h[:, 0], h[-1, 0] - SMOOTH_S, side="left"))
        if recent > first:
            kept = np.vstack([h[:first], h[recent:]])
            self._heights = Growing(2)
            self._heights.extend(kept)

    def series(self) -> PhaseSeries:
        rows = self._rows.view()
        return PhaseSeries(self.source, rows[:, 0], rows[:, 1], rows[:, 2])

    def on_clock(self, t: np.ndarray) -> np.ndarray:
        if not len(self._rows):
            return np.full(len(t), np.nan)
        return self.series().on_clock(np.asarray(t, dtype=float))
