"""Which algorithm made each attitude the autopilot logged (``Flight.attitudes``), and which is the primary.

ArduPilot runs DCM (a complementary filter) and, beside it, an EKF (EKF1 in 3.2-3.3, EKF2 in
3.4+, EKF3 in 3.6+, each with one core per IMU): ATT (ATTITUDE in a .tlog) is the one in use,
AHR2 (AHRS2) the other one (``AP_AHRS::get_secondary_attitude``, every version: DCM when an EKF
is in use, else the EKF), EKF1 / NKF1 / XKF1[i] each EKF core, DCM (4.5+) DCM, AHRS3 (3.x-4.0
telemetry) EKF2. Which one ATT is, the evidence in this order:

1. ATT.AEKF (4.1+): the estimator in use at each sample (0 DCM, 2 EKF2, 3 EKF3, 10 SITL, 11 external);
2. ATT equals the simulator's truth (SITL) or an EKF stream (to the log's 0.01°) on most samples;
3. the parameters: AHRS_EKF_USE (3.2-3.3: 0 DCM, 1 EKF1), AHRS_EKF_TYPE (3.4+: 0 DCM, 2 EKF2,
   3 EKF3, 10 SITL, 11 external; ArduCopter always uses an EKF, 0 meaning EKF2 there: the
   constructor flag FLAG_ALWAYS_USE_EKF); parameters without either: a firmware before the EKF, DCM;
4. the firmware's default (4.1+: EKF3); a copter's EKF (3.4+: the one whose EKn_ parameters the log has);
else "unknown". The parameters lose to the comparison: ATT that equals no EKF stream logged is DCM
(with AHRS_EKF_USE=1, an EKF that never became healthy left ATT to DCM).

PX4 (.ulg): ``vehicle_attitude`` is EKF2's where it equals an ``estimator_attitude[i]`` (EKF2
instance i of a multi-EKF PX4), else the estimator SYS_MC_EST_GROUP selects (2: EKF2; 0, 1, 3:
the Q complementary filter) or, 1.14+, ATT_EN (Q) / EKF2_EN.
"""
from __future__ import annotations

import re
from dataclasses import dataclass, field

import numpy as np

from .. import quaternion as quat
from ..flight import AttitudeSeries, Flight

ACTIVE_TYPES = {0: "DCM", 1: "EKF1", 2: "EKF2", 3: "EKF3", 10: "SITL", 11: "external AHRS"}
AHRS_EKF_USE = {0: "DCM", 1: "EKF1", 2: "EKF2"}
COPTER_TYPES = ("ARDUCOPTER", "QUADROTOR", "HEXAROTOR", "OCTOROTOR", "TRICOPTER", "COAXIAL", "HELICOPTER",
                "DECAROTOR", "DODECAROTOR")  # MAV_TYPE names (a .tlog's vehicle) ArduCopter flies
PRIMARY_KEYS = ("ATT", "ATTITUDE", "ATTITUDE_QUATERNION", "vehicle_attitude")
SECONDARY_KEYS = ("AHR2", "AHRS2")
MATCH_S = 0.005  # samples of two streams this close in time were written in the same loop
SAME_DEG = 0.02  # two attitudes this close are one estimate (ATT and the EKF log 0.01° steps)
MIN_MATCHED = 20  # fewer samples in common: no comparison
MOST = 0.5  # equal on more than this share of the common samples: the same stream


@dataclass
class NamedAttitude:
    key: str  # its key in Flight.attitudes: "ATT", "XKF1[1]", "AHRS2", "estimator_attitude[0]"
    algorithm: str  # "DCM", "EKF1", "EKF2 core 0", "EKF3", "PX4 EKF2", "unknown", ...
    primary: bool  # the autopilot's own attitude (Flight.attitude)
    evidence: str  # how the name was found, for ``info``
    equals: dict[str, float] = field(default_factory=dict)  # another stream -> share of samples equal to it


def name_attitudes(flight: Flight) -> list[NamedAttitude]:
    """Every stream of ``flight.attitudes`` named, the primary first."""
    streams = flight.attitudes
    primary = flight.attitude.source if flight.attitude is not None else None
    if flight.format == "ulg":
        named = [_px4(key, streams, flight.params, key == primary) for key in streams]
    else:
        named = _ardupilot(flight, primary)
    for n in named:  # which other streams each one equals (a lane switch: two cores, in turns)
        others = {m.key: streams[m.key] for m in named if m.key != n.key and m.key not in n.equals}
        n.equals.update(_equal_shares(streams[n.key], others))
    order = list(streams)
    return sorted(named, key=lambda n: (not n.primary, order.index(n.key)))


def _ardupilot(flight: Flight, primary: str | None) -> list[NamedAttitude]:
    """ArduPilot's streams: those their message names, then ATT, then the secondary."""
    streams = flight.attitudes
    named = [NamedAttitude(key, _own_name(key), False, "its message") for key in streams if _own_name(key)]
    ekfs = [n for n in named if n.algorithm.startswith("EKF")]
    if primary is None:
        return named + [_secondary(key, streams[key], None, ekfs, streams, flight.params)
                        for key in streams if key in SECONDARY_KEYS]
    first = _ardupilot_primary(flight, streams[primary], ekfs)
    for key in streams:
        if key in PRIMARY_KEYS and key != primary:  # ATTITUDE_QUATERNION beside ATTITUDE
            named.append(NamedAttitude(key, first.algorithm, False, f"the same attitude as {primary}"))
        elif key in SECONDARY_KEYS:
            named.append(_secondary(key, streams[key], first, ekfs, streams, flight.params))
    return named + [first]


def _own_name(key: str) -> str | None:
    """The algorithm a message belongs to by its name alone; None for ATT and the secondary."""
    base, core = re.fullmatch(r"(\w+?)(?:\[(\d+)\])?", key).groups()
    if base == "DCM":
        return "DCM"
    if base == "EKF1":
        return "EKF1"
    if base in ("NKF1", "XKF1"):
        return f"EKF{2 if base == 'NKF1' else 3} core {core}"
    if base == "AHRS3":
        return "EKF2"  # GCS_MAVLINK::send_ahrs3: EKF2's attitude (3.x-4.0)
    return None


def _ardupilot_primary(flight: Flight, att: AttitudeSeries, ekfs: list[NamedAttitude]) -> NamedAttitude:
    """ATT (ATTITUDE): the evidence in the order of the module docstring."""
    key = att.source
    if att.active is not None and len(att.active):
        types, counts = np.unique(att.active, return_counts=True)
        names = [ACTIVE_TYPES.get(int(t), f"type {int(t)}") for t in types]
        main = int(np.argmax(counts))
        rest = [f"{name} {100.0 * c / len(att.active):.0f} %" for i, (name, c) in enumerate(zip(names, counts))
                if i != main]
        return NamedAttitude(key, names[main], True, f"ATT.AEKF{' (also ' + ', '.join(rest) + ')' if rest else ''}")
    if flight.truth is not None:  # AHRS_EKF_TYPE=10: the simulator's truth is the attitude
        truth = _equal_shares(att, {flight.truth.source: flight.truth})
        if truth.get(flight.truth.source, 0.0) > MOST:
            return NamedAttitude(key, "SITL", True, f"equals the simulator's truth ({flight.truth.source})", truth)
    shares = _equal_shares(att, {n.key: flight.attitudes[n.key] for n in ekfs})
    if shares:
        best = max(shares, key=shares.get)
        if shares[best] > MOST:
            algorithm = next(n.algorithm for n in ekfs if n.key == best).split(" core")[0]
            return NamedAttitude(key, algorithm, True, "the EKF stream it equals", shares)
    configured, why = configured_estimator(flight)
    if shares and configured in (None, "EKF", "EKF1", "EKF2", "EKF3"):  # ATT is none of the EKFs: DCM
        return NamedAttitude(key, "DCM", True, f"{key} equals no EKF stream ({why})", shares)
    return NamedAttitude(key, configured or "unknown", True, why, shares)


def configured_estimator(flight: Flight) -> tuple[str | None, str]:
    """(algorithm, why) the parameters (or the firmware's default) select for ATT; None if they do not say."""
    params = flight.params
    if "AHRS_EKF_TYPE" in params:
        value = int(params["AHRS_EKF_TYPE"])
        if value == 0 and _is_copter(flight):
            return "EKF2", "AHRS_EKF_TYPE=0, which ArduCopter reads as EKF2 (it always uses an EKF)"
        return ACTIVE_TYPES.get(value), f"AHRS_EKF_TYPE={value}"
    if "AHRS_EKF_USE" in params:
        value = int(params["AHRS_EKF_USE"])
        return AHRS_EKF_USE.get(value), f"AHRS_EKF_USE={value}"
    ekf_logged = any(key.startswith(("EKF1", "NKF1", "XKF1")) for key in flight.attitudes)
    if any(name.startswith("AHRS_") for name in params) and not ekf_logged:
        return "DCM", "AHRS parameters without AHRS_EKF_USE/AHRS_EKF_TYPE, no EKF logged: a firmware before the EKF"
    found = re.search(r"V(\d+)\.(\d+)", flight.firmware or "")
    version = (int(found[1]), int(found[2])) if found else None
    if version and version >= (4, 1):
        return "EKF3", f"AHRS_EKF_TYPE not in the log: EKF3, the default of ArduPilot 4.1+ ({flight.firmware})"
    if _is_copter(flight) and (version is None or version >= (3, 4)):  # the EKF whose parameters the log holds
        ekf = "EKF3" if any(k.startswith("EK3_") for k in params) else \
            "EKF2" if any(k.startswith("EK2_") for k in params) else "EKF"
        which = f"; {ekf} parameters in the log" if ekf != "EKF" else ""
        return ekf, f"a copter ({flight.vehicle}) always uses an EKF{which}"
    return None, "nothing in the log says (no AHRS_EKF_TYPE/AHRS_EKF_USE, no firmware version)"


def _is_copter(flight: Flight) -> bool:
    """ArduCopter (its firmware string, or a .tlog's MAV_TYPE): it always uses an EKF once one
    has started (the AHRS flag FLAG_ALWAYS_USE_EKF; ATT.AEKF shows DCM only before that)."""
    return "Copter" in (flight.firmware or "") or (flight.vehicle or "").upper() in COPTER_TYPES


def _secondary(key: str, series: AttitudeSeries, first: NamedAttitude | None, ekfs: list[NamedAttitude],
               streams: dict, params: dict) -> NamedAttitude:
    """AHR2 (AHRS2): the estimator not in use; an EKF stream it equals names it."""
    shares = _equal_shares(series, {n.key: streams[n.key] for n in ekfs})
    best = max(shares, key=shares.get) if shares else None
    if best is not None and shares[best] > MOST:
        algorithm = next(n.algorithm for n in ekfs if n.key == best).split(" core")[0]
        return NamedAttitude(key, algorithm, False, "the EKF stream it equals", shares)
    if first is None or first.algorithm == "unknown":
        return NamedAttitude(key, "unknown", False, "the estimator not in use, and which one is in use is unknown",
                             shares)
    if first.algorithm != "DCM":
        return NamedAttitude(key, "DCM", False, f"the estimator not in use ({first.key} is {first.algorithm})", shares)
    ekf = next((n.algorithm.split(" core")[0] for n in ekfs), None) or _enabled_ekf(params)
    return NamedAttitude(key, ekf or "EKF", False, f"the estimator not in use ({first.key} is DCM)", shares)


def _enabled_ekf(params: dict) -> str | None:
    """The EKF the parameters run beside DCM: EKF1 where AHRS_EKF_USE exists (3.2-3.3), else
    the AHRS_EKF_TYPE, else the one enabled (EK3_ENABLE, EK2_ENABLE)."""
    if "AHRS_EKF_USE" in params:
        return "EKF1"
    if int(params.get("AHRS_EKF_TYPE", 0)) in (2, 3):
        return f"EKF{int(params['AHRS_EKF_TYPE'])}"
    return "EKF3" if params.get("EK3_ENABLE") == 1 else "EKF2" if params.get("EK2_ENABLE") == 1 else None


def _px4(key: str, streams: dict, params: dict, primary: bool) -> NamedAttitude:
    """PX4's streams (see the module docstring): vehicle_attitude is EKF2 where it equals an EKF2
    instance, else what the parameters enable."""
    instance = re.fullmatch(r"estimator_attitude\[(\d+)\]", key)
    if instance:
        return NamedAttitude(key, f"PX4 EKF2 instance {instance[1]}", primary, "its topic")
    ekfs = {k: s for k, s in streams.items() if k.startswith("estimator_attitude[")}
    shares = _equal_shares(streams[key], ekfs)
    if shares and max(shares.values()) > MOST:
        return NamedAttitude(key, "PX4 EKF2", primary, "the EKF2 instance it equals", shares)
    if "SYS_MC_EST_GROUP" in params:
        group = int(params["SYS_MC_EST_GROUP"])
        return NamedAttitude(key, "PX4 EKF2" if group == 2 else "PX4 Q", primary, f"SYS_MC_EST_GROUP={group}", shares)
    if params.get("ATT_EN") == 1 and (params.get("EKF2_EN") == 0 or shares):  # Q on; EKF2 off, or not this
        return NamedAttitude(key, "PX4 Q", primary, "ATT_EN=1" + (", and it equals no EKF2 instance" if shares else ""),
                             shares)
    return NamedAttitude(key, "PX4 EKF2", primary, "EKF2_EN=1" if params.get("EKF2_EN") == 1
                         else "PX4's default estimator (SYS_MC_EST_GROUP/EKF2_EN not in the log)", shares)


def _equal_shares(series: AttitudeSeries, others: dict[str, AttitudeSeries]) -> dict[str, float]:
    """For each other stream with at least MIN_MATCHED samples within MATCH_S of one of
    ``series``': the share of those where the two attitudes are within SAME_DEG."""
    shares = {}
    for key, other in others.items():
        if len(other.t) < 2 or len(series.t) < 2:
            continue
        after = np.clip(np.searchsorted(other.t, series.t), 1, len(other.t) - 1)
        nearest = np.where(series.t - other.t[after - 1] <= other.t[after] - series.t, after - 1, after)
        close = np.abs(other.t[nearest] - series.t) <= MATCH_S
        if np.count_nonzero(close) < MIN_MATCHED:
            continue
        apart = attitude_difference_deg(series.q[close], other.q[nearest[close]])
        shares[key] = float(np.mean(apart <= SAME_DEG))
    return shares


def attitude_difference_deg(q_a: np.ndarray, q_b: np.ndarray) -> np.ndarray:
    """The angle of the rotation from each attitude of ``q_a`` to ``q_b``'s, in degrees."""
    relative = quat.multiply(quat.conjugate(q_a), q_b)
    return np.degrees(2.0 * np.arctan2(np.linalg.norm(relative[:, 1:], axis=1), np.abs(relative[:, 0])))
