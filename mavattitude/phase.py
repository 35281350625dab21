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

from collections import deque
from dataclasses import dataclass

import numpy as np

from .flight import BaroSeries, Flight, GpsSeries
from .growing import Growing

AIR_ABOVE_M = 3.0  # m above the start: in the air
GROUND_BELOW_M = 1.5  # m above the start: back on the ground
SMOOTH_S = 1.0  # s: heights are median-filtered over this span first
START_S = 3.0  # s: the start height is the median over this first span
STALE_S = 2.0  # s: beyond this from the last height sample, the phase is unknown
SEA_LEVEL_PA = 101325.0


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


def pressure_height(pressure_pa: np.ndarray) -> np.ndarray:
    """Height (m) in the ICAO standard atmosphere; only differences are used."""
    return 44330.77 * (1.0 - (np.asarray(pressure_pa) / SEA_LEVEL_PA) ** 0.190263)


def detect_phase(flight: Flight) -> PhaseSeries | None:
    """The ground/air phase over the flight, or None when the log has no height source."""
    height = _baro_height(flight.baro) or _gps_height(flight.gps)
    if height is None:
        return None
    source, t, h = height
    h = _running_median(t, h, SMOOTH_S)
    h = h - np.median(h[t <= t[0] + START_S])
    # Hysteresis: the last threshold crossed decides; the start is on the ground.
    mark = np.where(h > AIR_ABOVE_M, 1.0, np.where(h < GROUND_BELOW_M, 0.0, np.nan))
    mark[0] = 0.0 if np.isnan(mark[0]) else mark[0]
    last = np.maximum.accumulate(np.where(np.isnan(mark), 0, np.arange(len(mark))))
    return PhaseSeries(source, t, h, mark[last])


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


def _running_median(t: np.ndarray, x: np.ndarray, span_s: float) -> np.ndarray:
    """Median over a centred window of about ``span_s`` seconds (odd sample count)."""
    period = float(np.median(np.diff(t))) if len(t) > 1 else span_s
    k = int(span_s / period) // 2 if period > 0 else 0
    if k < 1:
        return x.copy()
    padded = np.pad(x, k, mode="edge")
    windows = np.lib.stride_tricks.sliding_window_view(padded, 2 * k + 1)
    return np.median(windows, axis=1)


class PhaseTracker:
    """The ground/air phase sample by sample, for a live link (``detect_phase`` sees the
    whole log; this sees only the past). Same thresholds and hysteresis; causal versions of
    the rest: the height is the median of the last ``SMOOTH_S`` of samples, the start is the
    median of the samples of the first ``START_S`` (of those seen so far, until then).

    ``add(t, height)`` takes a chunk of raw heights (baro pressure height, or GPS altitude)
    in time order; ``on_clock(t)`` gives the phase at other times like ``PhaseSeries.on_clock``.
    """

    def __init__(self, source: str):
        self.source = source
        self._recent: deque[tuple[float, float]] = deque()  # (t, raw height) of the last SMOOTH_S
        self._start_heights: list[float] = []
        self._t0: float | None = None
        self._state = 0.0
        self._rows = Growing(3)  # t, height above the start (smoothed), in_air

    def add(self, t, height) -> None:
        for ti, hi in zip(np.asarray(t, dtype=float).tolist(), np.asarray(height, dtype=float).tolist()):
            last = self._rows.last
            if not np.isfinite(hi) or (last is not None and ti <= last[0]):
                continue
            if self._t0 is None:
                self._t0 = ti
            if ti <= self._t0 + START_S:
                self._start_heights.append(hi)
            self._recent.append((ti, hi))
            while self._recent[0][0] < ti - SMOOTH_S:
                self._recent.popleft()
            h = float(np.median([x for _, x in self._recent])) - float(np.median(self._start_heights))
            if h > AIR_ABOVE_M:
                self._state = 1.0
            elif h < GROUND_BELOW_M:
                self._state = 0.0
            self._rows.append((ti, h, self._state))

    @property
    def n(self) -> int:
        return len(self._rows)

    def series(self) -> PhaseSeries:
        rows = self._rows.view()
        return PhaseSeries(self.source, rows[:, 0], rows[:, 1], rows[:, 2])

    def on_clock(self, t: np.ndarray) -> np.ndarray:
        if not len(self._rows):
            return np.full(len(t), np.nan)
        return self.series().on_clock(np.asarray(t, dtype=float))
