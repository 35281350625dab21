"""The magnetic declination the estimators use, and where it came from: one policy for replay,
evaluate, tune, live and the API (a front end only gathers the inputs: a log's or a vehicle's
parameters, its first good GPS fix, its date).

In order, the first that applies:

1. ``--declination``;
2. the autopilot's declination parameter where it is authoritative: ArduPilot's COMPASS_DEC when
   COMPASS_AUTODEC is 0 (or absent), PX4's EKF2_MAG_DECL when bit 0 of EKF2_DECL_TYPE ("use the
   geo_lookup declination") is clear (or it is absent), ATT_MAG_DECL when ATT_MAG_DECL_A is 0
   (or absent). The user set it by hand and the autopilot used it;
3. the World Magnetic Model at ``--home LAT,LON``, else at the first good GPS fix, on the log's
   date: what the autopilot does with the automatic declination on (ArduPilot's default, PX4's
   too). ArduPilot computes it once, at the first 3D fix (AP_Compass::set_initial_location), and
   keeps it in memory only: the log's COMPASS_DEC shows the value of the PARM dump, 0 or a
   stale one when the dump came before the fix. PX4 looks it up at its first good fix and saves
   it to EKF2_MAG_DECL for the next flight: the log's value is the last flight's;
4. with the automatic declination on but no position: the parameter as logged, the value the
   autopilot held without a fix;
5. none: 0, with a warning (``NO_DECLINATION``), where there is a compass.

The model is the WMM (pygeomag's bundled 2010-2025 coefficients), the one whose five-year span
holds the date; a date outside every span uses the nearest model, extrapolated, and the source
says so; no date at all uses the newest model at its epoch, and the source says "date unknown".
The WMM is ArduPilot's and PX4's source too (their tables are sampled from it).

Measured on the shared logs (COMPASS_AUTODEC=1, a fix): where the PARM dump came after the fix
(COMPASS_DEC not 0) the autopilot's value and the model's differ by 0.0-1.3°, the older
firmware's coarser tables (-5.74° against -7.02° on a 2017 log near Mar del Plata, where IGRF
agrees with the WMM); mahony's yaw MAE against the autopilot moves by -0.6 to +0.7° there. Where
the log carries no parameter (five telemetry logs, a PX4 SITL log; 0° before) it falls on all six,
from 14.7-18.8° to 2.4-14.0° (median 16.2° to 4.8°).
"""
from __future__ import annotations

import datetime
import math
from dataclasses import dataclass
from functools import lru_cache

import numpy as np

# The declination parameters, first match wins: (name, the unit it is in (rad per unit), the
# parameter that turns the automatic declination on, whether a value of it does).
DECLINATION_PARAMS = (
    ("COMPASS_DEC", 1.0, "COMPASS_AUTODEC", lambda v: v != 0),  # ArduPilot, rad
    ("EKF2_MAG_DECL", math.pi / 180, "EKF2_DECL_TYPE", lambda v: int(v) & 1 != 0),  # PX4 EKF2, deg
    ("ATT_MAG_DECL", math.pi / 180, "ATT_MAG_DECL_A", lambda v: v != 0),  # PX4 attitude_estimator_q, deg
)
# WMM models bundled with pygeomag: (first year of the span, pygeomag's base_year, name)
WMM_MODELS = ((2010, 2010, "WMM-2010"), (2015, 2015, "WMM-2015v2"), (2020, 2020, "WMM-2020"),
              (2025, 2025, "WMM-2025"))
WMM_SPAN_YEARS = 5
# A fix good enough to place the vehicle: 3D, and where the log says so, enough satellites and a
# sane horizontal accuracy (ArduPilot computes at the first 3D fix; PX4's checks ask 6 satellites).
MIN_FIX_TYPE = 3
MIN_SATELLITES = 6
MAX_H_ACC_M = 10.0

NO_DECLINATION = ("no declination: no autopilot parameter, GPS fix, --home or --declination gives one: "
                  "using 0°; yaw compares magnetic with true heading")


@dataclass(frozen=True)
class Declination:
    rad: float  # east positive: true heading = magnetic + declination
    source: str  # where it came from, said to the user ("--declination", "log parameter COMPASS_DEC ...")
    # which rule of the module docstring gave it: "option" (1), "parameter" (2), "model" (3),
    # "held" (4: a position would have decided), "none" (5: 0 used); "source": the data's own
    # frame is magnetic (a BROAD trial)
    kind: str = "none"

    @property
    def known(self) -> bool:
        return self.kind != "none"

    @property
    def deg(self) -> float:
        return math.degrees(self.rad)

    def text(self) -> str:
        """'12.34° (source)', for info, the table and the view."""
        return f"{self.deg:.2f}° ({self.source})"


@dataclass(frozen=True)
class Fix:
    """Where the vehicle was: degrees, metres above mean sea level."""
    lat_deg: float
    lon_deg: float
    alt_m: float = 0.0


def _decimal_year(when: datetime.datetime) -> float:
    """The year of the day's start (UTC): the field moves less than 0.001° a day, and a live
    session and the replay of its recording, whose times differ by seconds, get one value."""
    day = when.astimezone(datetime.timezone.utc).date()
    return day.year + (day - datetime.date(day.year, 1, 1)).days / (datetime.date(day.year + 1, 1, 1)
                                                                    - datetime.date(day.year, 1, 1)).days


def _model(when: datetime.datetime | None) -> tuple[int, float, str, str]:
    """(pygeomag base year, decimal year to evaluate at, the model's name, a note on the date or
    "") for a date (None: unknown)."""
    if when is None:
        first, base, name = WMM_MODELS[-1]
        return base, float(first), name, f"date unknown: at the model's epoch {first}.0"
    year = _decimal_year(when)
    for first, base, name in WMM_MODELS:
        if first <= year < first + WMM_SPAN_YEARS:
            return base, year, name, ""
    first, base, name = WMM_MODELS[0] if year < WMM_MODELS[0][0] else WMM_MODELS[-1]
    return base, year, name, f"extrapolated outside its {first}-{first + WMM_SPAN_YEARS} span"


@lru_cache(maxsize=None)
def _geomag(base_year: int):
    from pygeomag import GeoMag
    return GeoMag(base_year=base_year)


def model_declination(lat_deg: float, lon_deg: float, alt_m: float,
                      when: datetime.datetime | None) -> float:
    """The WMM's declination (rad, east positive) at a place (degrees, metres above sea level)
    and UTC time (None: the newest model's epoch; see the module docstring)."""
    base, year, _, _ = _model(when)
    result = _geomag(base).calculate(glat=float(lat_deg), glon=float(lon_deg), alt=float(alt_m) / 1000.0,
                                     time=year, allow_date_outside_lifespan=True)
    return math.radians(result.d)


def is_good_fix(lat_deg, lon_deg, fix_type, num_sats, h_acc_m):
    """Whether GPS samples (arrays or numbers) are good enough to place the vehicle (see
    MIN_FIX_TYPE, MIN_SATELLITES, MAX_H_ACC_M; a count of 0 or an accuracy of NaN: not reported)."""
    lat, lon = np.asarray(lat_deg, float), np.asarray(lon_deg, float)
    sats, h_acc = np.asarray(num_sats), np.asarray(h_acc_m, float)
    return ((np.asarray(fix_type) >= MIN_FIX_TYPE) & (np.abs(lat) <= 90) & (np.abs(lon) <= 180)
            & ((lat != 0) | (lon != 0)) & ((sats >= MIN_SATELLITES) | (sats <= 0)) & ~(h_acc > MAX_H_ACC_M))


def first_good_fix(gps) -> Fix | None:
    """The first sample of a ``flight.GpsSeries`` good enough to place the vehicle
    (``is_good_fix``); None if there is none."""
    if gps is None or not len(gps.t):
        return None
    hits = np.flatnonzero(is_good_fix(gps.lat_deg, gps.lon_deg, gps.fix_type, gps.num_sats, gps.h_acc_m))
    if not len(hits):
        return None
    i = hits[0]
    alt = float(gps.alt_m[i])
    return Fix(float(gps.lat_deg[i]), float(gps.lon_deg[i]), alt if math.isfinite(alt) else 0.0)


def choose(params: dict, fix: Fix | None = None, when: datetime.datetime | None = None,
           override_deg: float | None = None, home: Fix | None = None, where: str = "log",
           magnetic_north: bool = False) -> Declination:
    """The declination and its source (the module docstring's order). ``params``: the log's or
    vehicle's parameters; ``fix``: its first good GPS fix (``first_good_fix``); ``when``: its date
    (UTC); ``home``: --home; ``where``: "log" or "vehicle", for the source text.
    ``magnetic_north``: the data's own north is magnetic (a BROAD trial's truth, ``readers.broad``):
    0 but for --declination, said as the source's own."""
    if override_deg is not None:
        return Declination(math.radians(override_deg), "--declination", "option")
    if magnetic_north:
        return Declination(0.0, "0: BROAD's truth is referenced to magnetic north", "source")
    saved = None
    for name, to_rad, auto_name, is_auto in DECLINATION_PARAMS:
        value = params.get(name)
        if value is None or not math.isfinite(value):
            continue
        auto = params.get(auto_name)
        if auto is None or not math.isfinite(auto) or not is_auto(auto):
            said = f"{auto_name}={auto:g}" if auto is not None else f"no {auto_name}"
            unused = "; --home not used" if home is not None else ""
            return Declination(float(value) * to_rad, f"{where} parameter {name}, {said}: set by hand{unused}", "parameter")
        saved = (name, float(value) * to_rad, f"{auto_name}={auto:g}")
        break
    place = home or fix
    if place is not None:
        _, _, model, note = _model(when)
        at = (f"--home {place.lat_deg:.4f},{place.lon_deg:.4f}" if home is not None else
              f"the first GPS fix {place.lat_deg:.4f},{place.lon_deg:.4f}")
        day = f" on {when:%Y-%m-%d}" if when is not None else ""
        notes = "; ".join(n for n in (note, saved[2] if saved else "") if n)
        return Declination(model_declination(place.lat_deg, place.lon_deg, place.alt_m, when),
                           f"{model} at {at}{day}" + (f"; {notes}" if notes else ""), "model")
    if saved is not None:
        name, value, said = saved
        return Declination(value, f"{where} parameter {name}, {said} but no GPS fix and no --home: "
                                  "the value the autopilot held", "held")
    return Declination(0.0, "none (0)", "none")


def flight_date(flight) -> datetime.datetime | None:
    """A log's date (UTC), None when it has none."""
    return None if flight.utc_s is None else datetime.datetime.fromtimestamp(flight.utc_s, datetime.timezone.utc)


def for_flight(flight, override_deg: float | None = None, home: Fix | None = None) -> Declination:
    """``choose`` for a whole log: its parameters, first good fix and date. A BROAD trial's truth
    is referenced to magnetic north (``readers.broad``): 0 there, said as the source's own."""
    return choose(flight.params, first_good_fix(flight.gps), flight_date(flight), override_deg, home,
                  magnetic_north=flight.format == "broad")


def parse_home(text: str) -> Fix:
    """``--home LAT,LON`` (degrees, or LAT,LON,ALT with metres above sea level); ValueError
    saying what is wrong."""
    parts = [p.strip() for p in text.split(",")]
    if len(parts) not in (2, 3):
        raise ValueError(f"expected LAT,LON in degrees (e.g. -35.36,149.17), not {text!r}")
    try:
        values = [float(p) for p in parts]
    except ValueError:
        raise ValueError(f"expected numbers LAT,LON in degrees, not {text!r}") from None
    if not all(math.isfinite(v) for v in values):
        raise ValueError(f"expected finite numbers LAT,LON, not {text!r}")
    lat, lon = values[0], values[1]
    if not -90 <= lat <= 90:
        raise ValueError(f"latitude {lat:g} is outside -90 to 90 ({text!r}: LAT comes first)")
    if not -180 <= lon <= 180:
        raise ValueError(f"longitude {lon:g} is outside -180 to 180 ({text!r})")
    return Fix(lat, lon, values[2] if len(values) == 3 else 0.0)
