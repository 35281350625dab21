"""The earth and its atmosphere, once: the WGS-84 ellipsoid around a point (the flat-earth NED
frame GPS fixes are fused in) and the standard atmosphere (a pressure as a height).

The readers, the estimation core, the view and the simulator all use these, so a log the
simulator writes reads back to the same metres. Only numpy: the bottom of the package.
"""
from __future__ import annotations

import numpy as np

# WGS-84 ellipsoid
WGS84_A = 6_378_137.0  # m, semi-major axis
WGS84_E2 = 6.694_379_990_14e-3  # first eccentricity squared

# ICAO standard atmosphere, troposphere, in the form autopilots use: height = H (1 - (p/p0)^N)
SEA_LEVEL_PA = 101325.0  # p0
ISA_HEIGHT_M = 44330.77  # H = T0 / L: 288.15 K over 0.0065 K/m, as the autopilots round it
ISA_EXPONENT = 0.190263  # N = R L / (g M)


def radii(lat0_deg: float) -> tuple[float, float]:
    """Meridian and prime-vertical radii of curvature (m) at a latitude."""
    s = np.sin(np.radians(lat0_deg))
    w = np.sqrt(1.0 - WGS84_E2 * s * s)
    return WGS84_A * (1.0 - WGS84_E2) / w ** 3, WGS84_A / w


def geodetic_to_ned(origin, lat_deg, lon_deg, alt_m) -> np.ndarray:
    """(N, 3) NED metres of geodetic points relative to ``origin`` (lat °, lon °, alt m): flat
    earth with the WGS-84 radii of curvature at the origin (millimetre-exact over a few km)."""
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


def pressure_height(pressure_pa: np.ndarray) -> np.ndarray:
    """Height (m) in the ICAO standard atmosphere; only differences are used. NaN for a
    pressure not above 0 (a corrupt sample), without numpy's warning."""
    pressure = np.asarray(pressure_pa, dtype=float)
    return ISA_HEIGHT_M * (1.0 - (np.where(pressure > 0, pressure, np.nan) / SEA_LEVEL_PA) ** ISA_EXPONENT)


def height_pressure(height_m: np.ndarray) -> np.ndarray:
    """``pressure_height``'s inverse: the pressure (Pa) at a standard-atmosphere height (m).
    NaN at or above the formula's top, 44331 m, where the pressure would be 0 or less (a
    corrupt height: "invalid value in power" was numpy's warning)."""
    base = 1.0 - np.asarray(height_m, dtype=float) / ISA_HEIGHT_M
    return SEA_LEVEL_PA * np.where(base > 0, base, np.nan) ** (1 / ISA_EXPONENT)
