"""The simulated world: where home is, the magnetic field, the atmosphere and the clocks.

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


# WGS-84 ellipsoid, for the radii of curvature at home.
WGS84_A = 6_378_137.0  # m, semi-major axis
WGS84_E2 = 6.694_379_990_14e-3  # first eccentricity squared


@dataclass(frozen=True)
class Home:
    """Take-off point: the origin of the simulation's NED frame, on the ground."""

    lat_deg: float = 47.397742
    lon_deg: float = 8.545594
    alt_m: float = 488.0  # above mean sea level


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


def ned_to_geodetic(home: Home, pos_ned) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Latitude and longitude (degrees) and altitude above sea level (m) of NED positions (m).

    Flat earth around home with the WGS-84 radii of curvature there: exact to millimetres over
    the few hundred metres a scenario covers.
    """
    pos = np.asarray(pos_ned, dtype=float)
    lat0 = np.radians(home.lat_deg)
    w = np.sqrt(1.0 - WGS84_E2 * np.sin(lat0) ** 2)
    r_meridian = WGS84_A * (1.0 - WGS84_E2) / w ** 3
    r_normal = WGS84_A / w
    lat = home.lat_deg + np.degrees(pos[..., 0] / r_meridian)
    lon = home.lon_deg + np.degrees(pos[..., 1] / (r_normal * np.cos(lat0)))
    return lat, lon, home.alt_m - pos[..., 2]


# International Standard Atmosphere, troposphere.
ISA_P0 = 101_325.0  # Pa at sea level
ISA_T0 = 288.15  # K at sea level
ISA_LAPSE = 0.0065  # K/m
ISA_EXPONENT = 5.255_877  # g M / (R L)


def pressure_from_altitude(alt_m):
    """Static pressure (Pa) at an altitude above sea level (m), standard atmosphere."""
    return ISA_P0 * (1.0 - ISA_LAPSE * np.asarray(alt_m, dtype=float) / ISA_T0) ** ISA_EXPONENT


def altitude_from_pressure(pressure_pa):
    """Inverse of ``pressure_from_altitude``: altitude above sea level (m)."""
    ratio = np.asarray(pressure_pa, dtype=float) / ISA_P0
    return ISA_T0 / ISA_LAPSE * (1.0 - ratio ** (1.0 / ISA_EXPONENT))


def gps_week_ms(unix_s) -> tuple[np.ndarray, np.ndarray]:
    """GPS week number and milliseconds into the week for UNIX times (s)."""
    gps_ms = np.round((np.asarray(unix_s, dtype=float) - GPS_EPOCH_UNIX + GPS_LEAP_SECONDS) * 1000.0)
    gps_ms = gps_ms.astype(np.int64)
    week_ms = 7 * 86_400_000
    return gps_ms // week_ms, gps_ms % week_ms
