"""Which IMU and compass to estimate from, the vehicle that wrote a log, and MAVLink names."""
from __future__ import annotations

import re

from ..flight import DEFAULT_FAMILIES, IMU_FAMILIES, Flight, ImuSeries, imu_family, median_step

# IMU sources, best first, among those with the same sample rate: float SI data beats
# integer mG/mrad/s, and the primary instance beats the others.
IMU_PREFERENCE = ["HIGHRES_IMU", "IMU[0]", "sensor_combined", "RAW_IMU", "SCALED_IMU", "SCALED_IMU2", "IMU[1]",
                  "SCALED_IMU3", "IMU[2]"]


def identify_vehicle(texts: list[str]) -> tuple[str | None, str | None]:
    """(vehicle, firmware) from the version strings the autopilot wrote."""
    for text in texts:
        m = re.search(r"(Ardu(?:Copter|Plane|Rover|Sub)|APM:(?:Copter|Plane|Rover)|PX4)[^\n]*", text)
        if m:
            firmware = m.group(0).strip()
            vehicle = m.group(1).replace("APM:", "Ardu")
            return vehicle, firmware
    version = next((t[len("version "):] for t in texts if t.startswith("version ")), None)
    for text in texts:
        if text.startswith("heartbeat "):
            _, _, mav_type, _, autopilot = text.split()
            vehicle = enum_name("MAV_TYPE", int(mav_type))
            autopilot_name = enum_name("MAV_AUTOPILOT", int(autopilot))
            return vehicle, " ".join(x for x in (autopilot_name, version) if x)
    return None, version


def enum_name(enum: str, value: int) -> str:
    """'QUADROTOR' for MAV_TYPE 2: MAVLink's own name, without its prefix."""
    from pymavlink.dialects.v20 import ardupilotmega as mavlink
    entry = mavlink.enums.get(enum, {}).get(value)
    return entry.name.replace(enum + "_", "") if entry else f"{enum} {value}"


def imu_rate(series: ImuSeries) -> float:
    """Median sample rate, Hz."""
    if len(series.t) < 2:
        return 0.0
    return 1.0 / median_step(series.t)


def best_imu_source(flight: Flight, family: str | None = None) -> str:
    """The IMU to estimate from: of ``family`` (default: the first of DEFAULT_FAMILIES the log
    has), the highest sample count (within 2 %), then IMU_PREFERENCE. KeyError (naming what
    there is) when the log has no IMU of that family."""
    counts = {k: len(s.t) for k, s in flight.imu.items()}
    if family is None:
        family = next((f for f in DEFAULT_FAMILIES if any(imu_family(k) == f for k in counts)), "imu")
    mine = {k: n for k, n in counts.items() if imu_family(k) == family}
    if not mine:
        have = sorted({imu_family(k) for k in counts})
        raise KeyError(f"has no IMU of the {family!r} family ({IMU_FAMILIES[family]}); it has: {', '.join(have)}")
    return pick_imu(mine)


def pick_imu(counts: dict[str, int]) -> str:
    """``best_imu_source`` on {source: sample count} (a log's, or what a live link has sent)."""
    top = max(counts.values())
    candidates = [k for k, n in counts.items() if n >= 0.98 * top]

    def rank(key):
        return IMU_PREFERENCE.index(key) if key in IMU_PREFERENCE else len(IMU_PREFERENCE)
    return sorted(candidates, key=lambda k: (rank(k), k))[0]


def mag_for_imu(flight: Flight, imu_source: str) -> str | None:
    """The magnetometer to pair with an IMU: the one in the same message (tlog), else the first."""
    return pick_mag(list(flight.mag), imu_source)


def pick_mag(mag_sources: list[str], imu_source: str) -> str | None:
    """``mag_for_imu`` on a list of magnetometer sources."""
    if imu_source in mag_sources:
        return imu_source
    for key in ("MAG[0]", "vehicle_magnetometer[0]", "HIGHRES_IMU", "RAW_IMU", "SCALED_IMU", "SCALED_IMU2"):
        if key in mag_sources:
            return key
    return mag_sources[0] if mag_sources else None
