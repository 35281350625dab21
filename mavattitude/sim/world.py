"""The simulated world: where home is, the magnetic field and the clocks (the ellipsoid and the
atmosphere are the package's one ``earth`` module, so the readers turn what the simulator
writes back into the same metres).

Fixed constants, so a given scenario and seed always give byte-identical logs.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..readers.collect import GPS_EPOCH_UNIX, GPS_LEAP_SECONDS  # the reader's, so writing and reading agree

# Clocks. The autopilot clock (seconds since boot) is what every log timestamp is on; the first
# sample is taken a little after boot, not at 0, as on a real autopilot (readers must not
# assume a zero start). The boot happened at a fixed, fake UNIX time: tlog record stamps,
# SYSTEM_TIME and the .bin GPS week/ms all derive from it.
BOOT_TIME_AT_START = 1.0  # s on the autopilot clock at the first sample
EPOCH_UNIX_AT_BOOT = 1_717_243_200.0  # s, 2024-06-01 12:00:00 UTC


@dataclass(frozen=True)
class Home:
    """Take-off point: the origin of the simulation's NED frame, on the ground."""

    lat_deg: float = 47.397742
    lon_deg: float = 8.545594
    alt_m: float = 488.0  # above mean sea level

    @property
    def origin(self) -> tuple[float, float, float]:
        """(lat °, lon °, alt m): the origin of ``earth``'s NED frame (``earth.ned_to_geodetic``)."""
        return self.lat_deg, self.lon_deg, self.alt_m


@dataclass(frozen=True)
class EarthField:
    """A uniform geomagnetic field. Positive inclination points the field down (northern hemisphere)."""

    total_t: float = 50e-6  # tesla (0.5 gauss)
    inclination_rad: float = np.radians(60.0)
    declination_rad: float = np.radians(5.0)  # magnetic north east of true north; logged as COMPASS_DEC

    def ned(self) -> np.ndarray:
        """The field vector (3,) in the NED frame, tesla."""
        horizontal = self.total_t * np.cos(self.inclination_rad)
        return np.array([horizontal * np.cos(self.declination_rad),
                         horizontal * np.sin(self.declination_rad),
                         self.total_t * np.sin(self.inclination_rad)])


def gps_week_ms(unix_s) -> tuple[np.ndarray, np.ndarray]:
    """GPS week number and milliseconds into the week for UNIX times (s)."""
    gps_ms = np.round((np.asarray(unix_s, dtype=float) - GPS_EPOCH_UNIX + GPS_LEAP_SECONDS) * 1000.0)
    gps_ms = gps_ms.astype(np.int64)
    week_ms = 7 * 86_400_000
    return gps_ms // week_ms, gps_ms % week_ms
