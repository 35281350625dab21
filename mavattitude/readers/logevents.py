"""What a log says happened: its flight modes, arming and text lines, as ``Flight.modes``,
``arming`` and ``messages`` (``flight.LabelSeries``), on the autopilot clock.

Each reader hands its rows to the collector (``Collector.add_events``), which places them on the
clock as it places the samples, under three kinds:

| kind | value | label | .bin | .tlog | .ulg |
|---|---|---|---|---|---|
| mode | the autopilot's mode number | its name ("" : named here) | MODE Mode (ModeNum) | HEARTBEAT custom_mode | vehicle_status nav_state |
| armed | 1 armed, 0 disarmed | | EV Id 10 / 11 (else ARM ArmState) | HEARTBEAT base_mode bit 7 | vehicle_status arming_state 2, 3 (1, 4: disarmed) |
| text | MAVLink severity (0 emergency .. 7 debug) | the text | MSG (6 info), ERR (3 error) | STATUSTEXT | logged messages |

Names: a .tlog's modes by pymavlink (``mavutil.mode_string_v10``); a .bin's numbers by pymavlink's
table for its vehicle (``mavutil.mode_mapping_bynumber``; the vehicle from the log's version
text); PX4's nav_state by ``PX4_NAV_STATES`` (PX4's ``vehicle_status.msg``: no library has it).
A mode or arming state repeated (a heartbeat every second, a .bin's MODE written twice) is one row.
"""
from __future__ import annotations

import numpy as np

from ..flight import Flight, LabelSeries
from .collect import Collector

INFO, ERROR = 6, 3  # MAVLink severities (MAV_SEVERITY)
ARMED_EVENTS = {10: 1, 11: 0}  # ArduPilot's LogEvent: ARMED, DISARMED
# ArduPilot's APM_BUILD types (a VER record's BU): the vehicle where no text names it
BUILD_TYPES = {1: "ArduRover", 2: "ArduCopter", 3: "ArduPlane", 4: "AntennaTracker", 7: "ArduSub"}
# ArduPilot's vehicles as MAVLink types, for pymavlink's mode tables
MAV_TYPES = {"ArduCopter": 2, "ArduPlane": 1, "ArduRover": 10, "ArduSub": 12, "AntennaTracker": 5}
# ArduPilot's LogErrorSubsystem (AP_Logger.h): the ERR message's Subsys; ECode 0 is "resolved"
ERR_SUBSYSTEMS = {
    1: "MAIN", 2: "RADIO", 3: "COMPASS", 4: "OPTFLOW", 5: "FAILSAFE_RADIO", 6: "FAILSAFE_BATT",
    7: "FAILSAFE_GPS", 8: "FAILSAFE_GCS", 9: "FAILSAFE_FENCE", 10: "FLIGHT_MODE", 11: "GPS",
    12: "CRASH_CHECK", 13: "FLIP", 14: "AUTOTUNE", 15: "PARACHUTES", 16: "EKFCHECK",
    17: "FAILSAFE_EKFINAV", 18: "BARO", 19: "CPU", 20: "FAILSAFE_ADSB", 21: "TERRAIN", 22: "NAVIGATION",
    23: "FAILSAFE_TERRAIN", 24: "EKF_PRIMARY", 25: "THRUST_LOSS_CHECK", 26: "FAILSAFE_SENSORS",
    27: "FAILSAFE_LEAK", 28: "PILOT_INPUT", 29: "FAILSAFE_VIBE", 30: "INTERNAL_ERROR", 31: "FAILSAFE_DEADRECKON",
}
# PX4's vehicle_status.nav_state (msg/VehicleStatus.msg; numbers kept across versions, some retired)
PX4_NAV_STATES = {
    0: "MANUAL", 1: "ALTCTL", 2: "POSCTL", 3: "AUTO_MISSION", 4: "AUTO_LOITER", 5: "AUTO_RTL",
    6: "POSITION_SLOW", 7: "AUTO_RTGS", 8: "AUTO_LANDENGFAIL", 9: "AUTO_LANDGPSFAIL", 10: "ACRO",
    12: "DESCEND", 13: "TERMINATION", 14: "OFFBOARD", 15: "STAB", 16: "RATTITUDE", 17: "AUTO_TAKEOFF",
    18: "AUTO_LAND", 19: "AUTO_FOLLOW_TARGET", 20: "AUTO_PRECLAND", 21: "ORBIT", 22: "AUTO_VTOL_TAKEOFF",
}
# vehicle_status.arming_state: 1 standby (disarmed), 2 armed; before 1.14 also 3 armed with an
# error, 4 standby with one (0 init, 5 reboot, 6 in-air restore say neither)
PX4_ARMED = (2, 3)
PX4_ARMING_STATES = (1, 2, 3, 4)


def err_text(subsystem: int, code: int) -> str:
    """An ERR record in words: "ERR: FAILSAFE_GPS 1", "ERR: GPS 0 (resolved)"."""
    name = ERR_SUBSYSTEMS.get(int(subsystem), f"subsystem {int(subsystem)}")
    return f"ERR: {name} {int(code)}" + (" (resolved)" if int(code) == 0 else "")


def ardupilot_mode_names(vehicle: str | None) -> dict[int, str]:
    """pymavlink's mode numbers -> names for an ArduPilot vehicle ("ArduCopter"); {} if unknown."""
    from pymavlink import mavutil

    return mavutil.mode_mapping_bynumber(MAV_TYPES.get(vehicle or "", -1)) or {}


def fill_events(flight: Flight, col: Collector, segment: int, vehicle: str | None) -> None:
    """The flight's modes, arming and messages from the collector's event rows in ``segment``;
    ``vehicle`` ("ArduCopter") names a .bin's mode numbers."""
    names = ardupilot_mode_names(vehicle)
    for attr, kind in (("modes", "mode"), ("arming", "armed"), ("messages", "text")):
        rows = [(key, *col.events(kind, key, segment)) for key in col.event_keys(kind)]
        rows = [r for r in rows if len(r[1])]
        if not rows:
            continue
        if kind == "armed" and len(rows) > 1:  # EV and ARM both say it: EV's, as every version writes it
            rows = [r for r in rows if r[0] == "EV"] or rows[:1]
        source = "+".join(r[0] for r in rows)
        t = np.concatenate([r[1] for r in rows])
        value = np.concatenate([r[2] for r in rows]).astype(np.int64)
        label = [x for r in rows for x in r[3]]
        if kind == "text":
            order = np.argsort(t, kind="stable")  # MSG and ERR together, by time
        else:
            order = np.arange(len(t))
            keep = np.concatenate([[True], value[1:] != value[:-1]])  # changes only
            order = order[keep]
        t, value, label = t[order], value[order], [label[i] for i in order]
        if kind == "mode":
            label = [x or names.get(int(v), f"mode {int(v)}") for v, x in zip(value, label)]
        elif kind == "armed":
            label = ["armed" if v else "disarmed" for v in value]
        setattr(flight, attr, LabelSeries(source, t, value, label))
