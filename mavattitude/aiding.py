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
  (``phase.pressure_height``), relative to the median over its first ``BARO_START_S``.

Dropped, not fused: fixes below 3D (``fix_type`` < 3) or at 0°/0°; a fix not newer than the
previous one kept (out of order); a fix or baro sample whose IMU sample comes more than
``MAX_LATENCY_S`` (or two IMU periods, if longer) after it (stale: an IMU gap); of two
samples that fall on the same IMU sample, the older.
"""
from __future__ import annotations

from dataclasses import dataclass, fields

import numpy as np

from .flight import BaroSeries, GpsSeries
from .phase import pressure_height

WGS84_A = 6_378_137.0  # m, semi-major axis
WGS84_E2 = 6.694_379_990_14e-3  # first eccentricity squared
MAX_LATENCY_S = 0.5  # s: a measurement reaching the IMU clock later than this is stale
BARO_START_S = 3.0  # s: the baro height's zero is the median over this first span
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


def radii(lat0_deg: float) -> tuple[float, float]:
    """Meridian and prime-vertical radii of curvature (m) at a latitude."""
    s = np.sin(np.radians(lat0_deg))
    w = np.sqrt(1.0 - WGS84_E2 * s * s)
    return WGS84_A * (1.0 - WGS84_E2) / w ** 3, WGS84_A / w


def geodetic_to_ned(origin, lat_deg, lon_deg, alt_m) -> np.ndarray:
    """(N, 3) NED metres of geodetic points relative to ``origin`` (lat °, lon °, alt m)."""
    lat0, lon0, alt0 = origin
    r_m, r_n = radii(lat0)
    north = np.radians(np.asarray(lat_deg, dtype=float) - lat0) * r_m
    east = np.radians(np.asarray(lon_deg, dtype=float) - lon0) * r_n * np.cos(np.radians(lat0))
    down = -(np.asarray(alt_m, dtype=float) - alt0)
    return np.stack([north, east, down], axis=-1)


def ned_to_geodetic(origin, ned) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Inverse of ``geodetic_to_ned``: latitude, longitude (degrees) and altitude (m)."""
    lat0, lon0, alt0 = origin
    r_m, r_n = radii(lat0)
    ned = np.asarray(ned, dtype=float)
    lat = lat0 + np.degrees(ned[..., 0] / r_m)
    lon = lon0 + np.degrees(ned[..., 1] / (r_n * np.cos(np.radians(lat0))))
    return lat, lon, alt0 - ned[..., 2]


def _rows(imu_t: np.ndarray, t: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """For measurement times ``t`` (sorted): the IMU row each is fused at and which to keep."""
    n = len(imu_t)
    period = float(np.median(np.diff(imu_t))) if n > 1 else 0.0
    max_latency = max(MAX_LATENCY_S, 2.0 * period)
    row = np.searchsorted(imu_t, t, side="left")
    keep = row < n
    keep[keep] &= imu_t[row[keep]] - t[keep] <= max_latency
    # Of several samples on one IMU row, the newest: keep a sample only if the next kept one
    # lands on another row.
    idx = np.flatnonzero(keep)
    last = np.ones(len(idx), dtype=bool)
    last[:-1] = row[idx[1:]] != row[idx[:-1]]
    keep[idx[~last]] = False
    return row, keep


def _increasing(t: np.ndarray) -> np.ndarray:
    """True where a sample is newer than every earlier sample (out-of-order ones are False)."""
    ok = np.ones(len(t), dtype=bool)
    if len(t) > 1:
        ok[1:] = t[1:] > np.maximum.accumulate(t)[:-1]
    return ok


def build(imu_t: np.ndarray, gps: GpsSeries | None, baro: BaroSeries | None,
          origin: tuple[float, float, float] | None = None, baro_zero: float | None = None) -> Aiding:
    """The aiding measurements of ``gps`` and ``baro`` on the IMU timestamps ``imu_t``.

    ``origin`` and ``baro_zero`` fix the GPS origin and the baro height's zero (live, chunk by
    chunk: each chunk keeps the first's); without them they come from these samples."""
    imu_t = np.asarray(imu_t, dtype=float)
    out = Aiding.empty(len(imu_t))
    out.origin, out.baro_zero = origin, baro_zero
    if len(imu_t) == 0:
        return out
    if gps is not None and len(gps.t):
        lat = np.asarray(gps.lat_deg, dtype=float)
        lon = np.asarray(gps.lon_deg, dtype=float)
        alt = np.asarray(gps.alt_m, dtype=float)
        t = np.asarray(gps.t, dtype=float)
        good = ((np.asarray(gps.fix_type) >= 3) & np.isfinite(lat) & np.isfinite(lon)
                & np.isfinite(alt) & ~((lat == 0) & (lon == 0)) & np.isfinite(t))
        good &= _increasing(np.where(good, t, -np.inf))
        if good.any():
            if out.origin is None:
                first = int(np.flatnonzero(good)[0])
                out.origin = (float(lat[first]), float(lon[first]), float(alt[first]))
            row, keep = _rows(imu_t, np.where(good, t, np.inf))
            keep &= good
            pos = geodetic_to_ned(out.origin, lat, lon, alt)
            r = row[keep]
            out.gps_pos[r] = pos[keep]
            out.gps_vel[r] = np.asarray(gps.vel_ned, dtype=float)[keep]
            out.gps_h_acc[r] = np.asarray(gps.h_acc_m, dtype=float)[keep]
            v_acc = getattr(gps, "v_acc_m", None)
            if v_acc is not None:
                out.gps_v_acc[r] = np.asarray(v_acc, dtype=float)[keep]
            bad_acc = ~(out.gps_h_acc > 0)
            out.gps_h_acc[bad_acc] = np.nan
            bad_acc = ~(out.gps_v_acc > 0)
            out.gps_v_acc[bad_acc] = np.nan
    if baro is not None and len(baro.t):
        p = np.asarray(baro.pressure_pa, dtype=float)
        t = np.asarray(baro.t, dtype=float)
        good = np.isfinite(p) & (p > MIN_PRESSURE_PA) & np.isfinite(t)
        good &= _increasing(np.where(good, t, -np.inf))
        if np.count_nonzero(good) >= (1 if out.baro_zero is not None else 2):
            h = pressure_height(np.where(good, p, np.nan))
            if out.baro_zero is None:
                start = good & (t <= t[good][0] + BARO_START_S)
                out.baro_zero = float(np.median(h[start]))
            h = h - out.baro_zero
            row, keep = _rows(imu_t, np.where(good, t, np.inf))
            keep &= good
            out.baro_height[row[keep]] = h[keep]
    return out


def from_flight(flight, imu_t: np.ndarray) -> Aiding:
    """``build`` from a ``Flight``'s GPS and barometer."""
    return build(imu_t, flight.gps, flight.baro)


def from_sim(sim) -> Aiding:
    """``build`` from a simulated flight (``sim.SimFlight``) on its IMU timestamps, as a log of
    it would read: a steady 3D fix with its reported horizontal and vertical accuracy."""
    g = sim.gps
    n = len(g.t)
    gps = GpsSeries("sim", g.t, g.lat_deg, g.lon_deg, g.alt_m, g.vel_ned,
                    np.full(n, g.fix_type), np.full(n, g.num_sats), np.full(n, g.h_acc_m))
    gps.v_acc_m = np.full(n, g.v_acc_m)
    baro = BaroSeries("sim", sim.baro.t, sim.baro.pressure_pa, sim.baro.alt_m)
    return build(sim.t, gps, baro)
