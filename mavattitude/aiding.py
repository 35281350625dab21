"""Aiding measurements on the IMU clock: GPS position and velocity, barometric height.

Estimators that fuse more than the IMU and the compass (``cpf-ekf``) receive these with each
IMU chunk. Every array has one row per IMU sample and is NaN except at the first IMU sample
at or after a fresh measurement's time, so each measurement is fused exactly once, at most
one IMU period after it was taken (that latency is not compensated here; at 50 Hz it is
≤ 20 ms, at the 4-10 Hz of some telemetry logs ≤ 0.25 s).

- GPS position: NED metres relative to the first good fix (``origin``), flat earth with the
  WGS-84 radii of curvature at the origin (millimetre-exact over a few kilometres);
- GPS velocity: NED m/s as the receiver reports it (the vertical is NaN where the message has
  none, e.g. GPS_RAW_INT);
- GPS accuracy: the reported horizontal (and vertical) 1σ position accuracy in metres, NaN
  where the log does not give it;
- baro height: metres up, from the pressure through the standard atmosphere
  (``earth.pressure_height``), relative to the first good sample.

Each measurement is fused at the first IMU sample to arrive with or after it (``Placer``; by
time where there is no arrival order) whose time is not earlier than its own. Dropped, not
fused: fixes below 3D (``fix_type`` < 3) or at 0°/0°; a sample not newer than the previous
one kept (out of order); a sample whose IMU sample comes more than ``MAX_LATENCY_S`` (or two
IMU intervals, if longer: a telemetry log's IMU at 4 Hz) after it (stale: an IMU gap); of two
samples that fall on the same IMU sample, the older.
"""
from __future__ import annotations

from dataclasses import dataclass, fields

import numpy as np

from .earth import geodetic_to_ned, pressure_height
from .earth import ned_to_geodetic  # noqa: F401 - the view draws the GPS track with it, from here
from .flight import BaroSeries, GpsSeries

MAX_LATENCY_S = 0.5  # s: a measurement reaching the IMU clock later than this is stale
MIN_PRESSURE_PA = 1e3  # below this a pressure reading is not plausible


_SHARED = ("origin", "baro_zero")


@dataclass
class Aiding:
    """Per-IMU-sample aiding measurements; NaN where none is fused (see the module docstring)."""

    gps_pos: np.ndarray  # (N, 3) m, NED relative to ``origin``
    gps_vel: np.ndarray  # (N, 3) m/s, NED
    gps_h_acc: np.ndarray  # (N,) m, reported horizontal 1σ accuracy; NaN unknown
    gps_v_acc: np.ndarray  # (N,) m, reported vertical 1σ accuracy; NaN unknown
    baro_height: np.ndarray  # (N,) m, up, relative to the baro's start
    origin: tuple[float, float, float] | None = None  # (lat °, lon °, alt m AMSL) of the first good fix
    baro_zero: float | None = None  # m, the standard-atmosphere height ``baro_height`` is relative to

    COLUMNS = ("gps_pos", "gps_vel", "gps_h_acc", "gps_v_acc", "baro_height")  # the per-sample arrays

    def __len__(self) -> int:
        return len(self.baro_height)

    def __getitem__(self, s: slice) -> "Aiding":
        """The rows of an IMU chunk (a slice); the origin and baro zero are shared."""
        return Aiding(*(getattr(self, f.name)[s] for f in fields(self) if f.name not in _SHARED),
                      origin=self.origin, baro_zero=self.baro_zero)

    @property
    def has_gps(self) -> bool:
        return bool(np.isfinite(self.gps_pos[:, 0]).any() or np.isfinite(self.gps_vel[:, 0]).any())

    @property
    def has_baro(self) -> bool:
        return bool(np.isfinite(self.baro_height).any())

    @classmethod
    def empty(cls, n: int) -> "Aiding":
        """No aiding at all for ``n`` IMU samples."""
        return cls(np.full((n, 3), np.nan), np.full((n, 3), np.nan), np.full(n, np.nan),
                   np.full(n, np.nan), np.full(n, np.nan))


GPS_COLUMNS = ("t", "lat", "lon", "alt", "vn", "ve", "vd", "fix", "sats", "h_acc", "v_acc", "arrival")
BARO_COLUMNS = ("t", "pressure", "arrival")


class Placer:
    """Measurements onto the IMU clock as they arrive: what ``build`` does for whole arrays,
    the estimation core (``runner``) does a chunk at a time, with the same result.

    ``place`` decides, for the samples of a kind added since its last call (rows of
    ``GPS_COLUMNS`` or ``BARO_COLUMNS``), the IMU row each is fused at: the first IMU row to
    arrive with or after it whose time is not earlier than its own; samples whose row has not
    arrived yet wait for the next call. ``take`` hands over the measurements of IMU rows
    [a, b). The GPS origin is the first good fix, the baro zero the first good sample."""

    def __init__(self):
        self.origin: tuple[float, float, float] | None = None
        self.baro_zero: float | None = None
        self.done = {"gps": 0, "baro": 0}  # samples decided (placed or dropped)
        self._last_kept = {"gps": -np.inf, "baro": -np.inf}
        self._placed = {"gps": np.empty((0, 9)), "baro": np.empty((0, 2))}  # IMU row, values

    def place(self, kind: str, samples: np.ndarray, imu_t: np.ndarray, imu_arrival: np.ndarray) -> None:
        rows = samples[self.done[kind]:]
        if not len(rows):
            return
        row = np.maximum(np.searchsorted(imu_arrival, rows[:, -1], side="left"),
                         np.searchsorted(imu_t, rows[:, 0], side="left"))
        waiting = np.flatnonzero(row >= len(imu_t))
        n = int(waiting[0]) if len(waiting) else len(rows)  # the rest wait for their IMU row
        rows, row = rows[:n], row[:n]
        self.done[kind] += n
        good = _usable(kind, rows)
        good &= rows[:, 0] > np.maximum.accumulate(
            np.concatenate([[self._last_kept[kind]], np.where(good, rows[:, 0], -np.inf)]))[:-1]
        if good.any():
            self._last_kept[kind] = float(rows[good, 0].max())
        # the IMU interval before the row's predecessor: not one that ends in a gap
        period = np.where(row > 1, imu_t[np.maximum(row - 1, 0)] - imu_t[np.maximum(row - 2, 0)], 0.0)
        good &= imu_t[row] - rows[:, 0] <= np.maximum(MAX_LATENCY_S, 2.0 * period)  # else stale: an IMU gap
        rows, row = rows[good], row[good]
        if not len(rows):
            return
        if kind == "baro":
            h = pressure_height(rows[:, 1])
            if self.baro_zero is None:
                self.baro_zero = float(h[0])
            values = (h - self.baro_zero)[:, None]
        else:
            if self.origin is None:
                self.origin = (float(rows[0, 1]), float(rows[0, 2]), float(rows[0, 3]))
            pos = geodetic_to_ned(self.origin, rows[:, 1], rows[:, 2], rows[:, 3])
            h_acc = np.where(rows[:, 9] > 0, rows[:, 9], np.nan)
            v_acc = np.where(rows[:, 10] > 0, rows[:, 10], np.nan)
            values = np.column_stack([pos, rows[:, 4:7], h_acc, v_acc])
        self._placed[kind] = np.vstack([self._placed[kind], np.column_stack([row, values])])

    def forget(self, rows: int, done: int) -> None:
        """The IMU clock lost its first ``rows`` rows (``done`` of those left are taken)."""
        for kind, placed in self._placed.items():
            placed = placed.copy()
            placed[:, 0] -= rows
            self._placed[kind] = placed[placed[:, 0] >= done]  # an earlier row is never taken

    def take(self, a: int, b: int) -> Aiding:
        """The measurements fused at IMU rows [a, b); of two on one row, the newer."""
        out = Aiding.empty(b - a)
        for kind, placed in self._placed.items():
            mine = (placed[:, 0] >= a) & (placed[:, 0] < b)
            rows, values = placed[mine, 0].astype(np.int64) - a, placed[mine, 1:]
            if kind == "baro":
                out.baro_height[rows] = values[:, 0]
            else:
                out.gps_pos[rows], out.gps_vel[rows] = values[:, 0:3], values[:, 3:6]
                out.gps_h_acc[rows], out.gps_v_acc[rows] = values[:, 6], values[:, 7]
            self._placed[kind] = placed[~mine]
        out.origin, out.baro_zero = self.origin, self.baro_zero
        return out


def _usable(kind: str, rows: np.ndarray) -> np.ndarray:
    """Samples worth fusing: a 3D fix away from 0°/0°; a plausible pressure."""
    ok = np.isfinite(rows[:, 0])
    if kind == "baro":
        return ok & np.isfinite(rows[:, 1]) & (rows[:, 1] > MIN_PRESSURE_PA)
    lat, lon, alt = rows[:, 1], rows[:, 2], rows[:, 3]
    return ok & (rows[:, 7] >= 3) & np.isfinite(lat) & np.isfinite(lon) & np.isfinite(alt) & ~((lat == 0) & (lon == 0))


def gps_rows(gps: GpsSeries, arrival: np.ndarray) -> np.ndarray:
    """A GPS series as rows of ``GPS_COLUMNS``."""
    n = len(gps.t)
    v_acc = gps.v_acc_m if gps.v_acc_m is not None else np.full(n, np.nan)
    return np.column_stack([gps.t, gps.lat_deg, gps.lon_deg, gps.alt_m, gps.vel_ned, gps.fix_type, gps.num_sats,
                            gps.h_acc_m, v_acc, arrival]).astype(float)


def baro_rows(baro: BaroSeries, arrival: np.ndarray) -> np.ndarray:
    """A baro series as rows of ``BARO_COLUMNS``."""
    return np.column_stack([baro.t, baro.pressure_pa, arrival]).astype(float)


def build(imu_t: np.ndarray, gps: GpsSeries | None, baro: BaroSeries | None) -> Aiding:
    """The aiding measurements of ``gps`` and ``baro`` on the IMU timestamps ``imu_t``, time
    standing in for arrival (``Placer`` over the whole arrays)."""
    imu_t = np.asarray(imu_t, dtype=float)
    placer = Placer()
    if gps is not None and len(gps.t):
        placer.place("gps", gps_rows(gps, gps.t), imu_t, imu_t)
    if baro is not None and len(baro.t):
        placer.place("baro", baro_rows(baro, baro.t), imu_t, imu_t)
    return placer.take(0, len(imu_t))


def from_sim(sim) -> Aiding:
    """``build`` from a simulated flight (``sim.SimFlight``) on its IMU timestamps, as a log of
    it would read: a steady 3D fix with its reported horizontal and vertical accuracy."""
    g = sim.gps
    n = len(g.t)
    gps = GpsSeries("sim", g.t, g.lat_deg, g.lon_deg, g.alt_m, g.vel_ned, np.full(n, g.fix_type),
                    np.full(n, g.num_sats), np.full(n, g.h_acc_m), v_acc_m=np.full(n, g.v_acc_m))
    baro = BaroSeries("sim", sim.baro.t, sim.baro.pressure_pa, sim.baro.alt_m)
    return build(sim.t, gps, baro)
