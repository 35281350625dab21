"""ArduPilot DataFlash (.bin) writer.

A .bin is a stream of records: 0xA3 0x95, a message-type byte, then the packed little-endian
payload. FMT records (type 128, "BBnNZ": Type, Length, Name, Format, Columns) define every
type, FMT itself first; UNIT, MULT and FMTU records give units as modern ArduPilot writes them.
The layouts below are copied from ArduCopter 4.4.4 (``sitl-copter-4.4.bin``), type ids included,
so a reader sees exactly what the real firmware writes.

Records are built as numpy structured arrays, one column per field, and merged into one
time-ordered byte buffer without a per-record Python loop: a one-hour 400 Hz log writes in
seconds.

What is written (TimeUS: µs since boot):

- a header stamped with the first sample time: FMT for every type, UNIT, MULT, FMTU, PARM
  (COMPASS_DEC rad, COMPASS_OFS_X/Y/Z mGauss), VER and MSG (the firmware string, "Frame: QUAD/X");
- IMU, I = 0 and 1, at the IMU rate: GyrX.. rad/s, AccX.. m/s² (specific force);
- with ``imt=True``, IMT, I = 0 and 1, on the same ticks: the delta angle (rad) and delta
  velocity (m/s) over the step to each sample, as ArduPilot integrates its sensor-rate samples.
  The true part is exact (the rotation between the true attitudes, the trapezoid of the true
  specific force); the sensor's bias and noise are those of the IMU sample, times the step;
- MAG, I = 0, at the compass rate: MagX.. mGauss after offsets, OfsX.. the offsets applied;
- GPS and GPA, I = 0, at the GPS rate: Status 3, Lat/Lng degrees, Alt m, Spd m/s, GCrs deg,
  VZ m/s down; GWk/GMS from the fake boot epoch, so pymavlink's clock gives that UNIX time;
- BARO, I = 0, at the baro rate: Alt m above the ground at boot, Press Pa, Temp degC;
- with a DCM primary (``SimFlight.ekf_q``): ATT is DCM's (AEKF 0), and EKF1 and AHR2 carry the
  EKF's estimate on ATT's ticks (their other fields zero, or AHR2's position the truth's);
- MODE at each mode change, EV (Id 10, armed) at take-off and MSG with the text line of the
  flight's ``script`` (``SimFlight.script``);
- ATT (the autopilot's estimate; DesRoll.. = Roll.., AEKF 3) and SIM (truth: Roll/Pitch/Yaw deg,
  Alt m above sea level, Lat/Lng deg, Q1..Q4 with Q1 >= 0) on every ``att_every``-th IMU sample,
  25 Hz by default. Yaw fields are 0-360° headings.

Values handed to ``LogFormat.records`` are in the units pymavlink returns when it reads the
field back: format letters c/C/e/E (×0.01) and L (×1e-7) are scaled here, so ATT Roll is given
in degrees and GPS Lat in degrees. Fields whose scaling ArduPilot states only in FMTU (MAG in
mGauss, BARO Press in Pa) are given in those units.
"""
from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from .. import earth
from .. import quaternion as quat
from . import world

HEAD = (0xA3, 0x95)

# DataFlash format letter -> numpy type (little-endian), and the scale pymavlink applies on read.
_NUMPY_TYPE = {
    "b": "i1", "B": "u1", "M": "u1", "h": "<i2", "H": "<u2", "i": "<i4", "I": "<u4", "q": "<i8", "Q": "<u8",
    "f": "<f4", "d": "<f8", "n": "S4", "N": "S16", "Z": "S64",
    "c": "<i2", "C": "<u2", "e": "<i4", "E": "<u4", "L": "<i4",
}
_READ_SCALE = {"c": 0.01, "C": 0.01, "e": 0.01, "E": 0.01, "L": 1e-7}


@dataclass(frozen=True)
class LogFormat:
    """One message type: id, name, DataFlash format string, columns, FMTU unit and multiplier ids."""

    type_id: int
    name: str
    fmt: str
    columns: str  # comma-separated, as in the FMT record
    units: str  # one UNIT id per column
    mults: str  # one MULT id per column

    @property
    def dtype(self) -> np.dtype:
        names = self.columns.split(",")
        assert len(names) == len(self.fmt) == len(self.units) == len(self.mults), self.name
        return np.dtype([("_h1", "u1"), ("_h2", "u1"), ("_type", "u1")]
                        + [(c, _NUMPY_TYPE[f]) for c, f in zip(names, self.fmt)])

    @property
    def length(self) -> int:
        """Record length in bytes, header included (the FMT ``Length``)."""
        return self.dtype.itemsize

    def records(self, n: int, **values) -> np.ndarray:
        """``n`` records; each value is a scalar or an (n,) array in the units pymavlink reads.

        Every column must be given. Integers are rounded and must fit their field.
        """
        dtype = self.dtype
        out = np.zeros(n, dtype=dtype)
        out["_h1"], out["_h2"], out["_type"] = HEAD[0], HEAD[1], self.type_id
        missing = set(dtype.names[3:]) - set(values)
        extra = set(values) - set(dtype.names[3:])
        if missing or extra:
            raise ValueError(f"{self.name}: missing columns {sorted(missing)}, unknown {sorted(extra)}")
        for column, letter in zip(dtype.names[3:], self.fmt):
            value = values[column]
            kind = dtype[column]
            if kind.kind == "S":
                out[column] = value.encode() if isinstance(value, str) else value
                continue
            value = np.asarray(value, dtype=float) / _READ_SCALE.get(letter, 1.0)
            if kind.kind in "iu":
                value = np.rint(value)
                info = np.iinfo(kind)
                if np.any(value < info.min) or np.any(value > info.max):
                    raise ValueError(f"{self.name}.{column} out of range for format {letter!r}")
            out[column] = value
        return out


# ArduCopter 4.4.4 layouts (LogStructure.h), with their FMTU unit and multiplier ids.
FMT = LogFormat(128, "FMT", "BBnNZ", "Type,Length,Name,Format,Columns", "-b---", "-----")
UNIT = LogFormat(114, "UNIT", "QbZ", "TimeUS,Id,Label", "s--", "F--")
FMTU = LogFormat(113, "FMTU", "QBNN", "TimeUS,FmtType,UnitIds,MultIds", "s---", "F---")
MULT = LogFormat(115, "MULT", "Qbd", "TimeUS,Id,Mult", "s--", "F--")
PARM = LogFormat(32, "PARM", "QNff", "TimeUS,Name,Value,Default", "s---", "F---")
MSG = LogFormat(59, "MSG", "QZ", "TimeUS,Message", "s-", "F-")
VER = LogFormat(200, "VER", "QBHBBBBIZHB", "TimeUS,BT,BST,Maj,Min,Pat,FWT,GH,FWS,APJ,BU",
           "s----------", "F----------")
IMU = LogFormat(162, "IMU", "QBffffffIIfBBHH",
           "TimeUS,I,GyrX,GyrY,GyrZ,AccX,AccY,AccZ,EG,EA,T,GH,AH,GHz,AHz",
           "s#EEEooo--O--zz", "F-000000-----00")
MAG = LogFormat(108, "MAG", "QBhhhhhhhhhBI",
           "TimeUS,I,MagX,MagY,MagZ,OfsX,OfsY,OfsZ,MOX,MOY,MOZ,Health,S",
           "s#GGGGGGGGG-s", "F-CCCCCCCCC-F")
GPS = LogFormat(89, "GPS", "QBBIHBcLLeffffB",
           "TimeUS,I,Status,GMS,GWk,NSats,HDop,Lat,Lng,Alt,Spd,GCrs,VZ,Yaw,U",
           "s#---SmDUmnhnh-", "F----0BGGB000--")
GPA = LogFormat(90, "GPA", "QBCCCCfBIHf", "TimeUS,I,VDop,HAcc,VAcc,SAcc,YAcc,VV,SMS,Delta,Und",
           "s#mmmnd-ssm", "F-BBBB0-CC0")
BARO = LogFormat(64, "BARO", "QBffcfIffB", "TimeUS,I,Alt,Press,Temp,CRt,SMS,Offset,GndTemp,Health",
            "s#mPOnsmO-", "F-00B0C?0-")
ATT = LogFormat(70, "ATT", "QccccCCCCB", "TimeUS,DesRoll,Roll,DesPitch,Pitch,DesYaw,Yaw,ErrRP,ErrYaw,AEKF",
           "sddddhhdh-", "FBBBBBBBB-")
SIM = LogFormat(75, "SIM", "QccCfLLffff", "TimeUS,Roll,Pitch,Yaw,Alt,Lat,Lng,Q1,Q2,Q3,Q4",
           "sddhmDU????", "FBBB0GG????")
IMT = LogFormat(204, "IMT", "QBfffffffff", "TimeUS,I,DelT,DelvT,DelaT,DelAX,DelAY,DelAZ,DelVX,DelVY,DelVZ",
           "s#sssrrrnnn", "F-000000000")
MODE = LogFormat(117, "MODE", "QMBB", "TimeUS,Mode,ModeNum,Rsn", "s---", "F---")
EV = LogFormat(180, "EV", "QB", "TimeUS,Id", "s-", "F-")
FORMATS = (FMT, UNIT, FMTU, MULT, PARM, MSG, VER, IMU, IMT, MAG, GPS, GPA, BARO, ATT, SIM, MODE, EV)
# With a DCM primary (``SimFlight.ekf_q``): the EKF beside it (ArduCopter 3.4's EKF1 layout) and the
# secondary AHR2, which is the EKF while DCM is in use
EKF1 = LogFormat(142, "EKF1", "QccCfffffffccc", "TimeUS,Roll,Pitch,Yaw,VN,VE,VD,dPD,PN,PE,PD,GX,GY,GZ",
            "sddhnnnnmmmkkk", "FBBB0000000BBB")
AHR2 = LogFormat(68, "AHR2", "QccCfLLffff", "TimeUS,Roll,Pitch,Yaw,Alt,Lat,Lng,Q1,Q2,Q3,Q4",
            "sddhmDU????", "FBBB0GG????")

# The UNIT and MULT tables ArduPilot 4.4 writes (id character -> label / multiplier).
UNITS = {
    "-": "", "?": "UNKNOWN", "A": "A", "a": "Ah", "d": "deg", "b": "B", "k": "deg/s", "D": "deglatitude",
    "e": "deg/s/s", "E": "rad/s", "G": "Gauss", "h": "degheading", "i": "A.s", "J": "W.s", "l": "l",
    "L": "rad/s/s", "m": "m", "n": "m/s", "o": "m/s/s", "O": "degC", "%": "%", "S": "satellites",
    "s": "s", "q": "rpm", "r": "rad", "U": "deglongitude", "u": "ppm", "v": "V", "P": "Pa",
    "w": "Ohm", "W": "Watt", "X": "W.h", "y": "l/s", "Y": "us", "z": "Hz", "#": "instance",
}
MULTS = {
    "-": 0.0, "?": 1.0, "2": 1e2, "1": 1e1, "0": 1.0, "A": 1e-1, "B": 1e-2, "C": 1e-3, "D": 1e-4,
    "E": 1e-5, "F": 1e-6, "G": 1e-7, "I": 1e-9, "!": 3.6, "/": 3600.0,
}

# Values for the VER record: board type SITL, official firmware type, build type Copter.
VER_BOARD_TYPE, VER_FIRMWARE_TYPE, VER_BUILD_TYPE = 3, 255, 2


def _us(t) -> np.ndarray:
    return np.rint(np.asarray(t, dtype=float) * 1e6).astype(np.uint64)


def _header(sim, t_us: int) -> list[np.ndarray]:
    """FMT for every type (FMT first), UNIT, MULT, FMTU, then parameters, version and firmware text."""
    formats = FORMATS + ((EKF1, AHR2) if sim.ekf_q is not None else ())
    n = len(formats)
    blocks = [FMT.records(
        n, Type=[f.type_id for f in formats], Length=[f.length for f in formats],
        Name=np.array([f.name for f in formats], dtype="S4"),
        Format=np.array([f.fmt for f in formats], dtype="S16"),
        Columns=np.array([f.columns for f in formats], dtype="S64"))]
    blocks.append(UNIT.records(len(UNITS), TimeUS=t_us, Id=[ord(k) for k in UNITS],
                               Label=np.array(list(UNITS.values()), dtype="S64")))
    blocks.append(MULT.records(len(MULTS), TimeUS=t_us, Id=[ord(k) for k in MULTS], Mult=list(MULTS.values())))
    blocks.append(FMTU.records(n, TimeUS=t_us, FmtType=[f.type_id for f in formats],
                               UnitIds=np.array([f.units for f in formats], dtype="S16"),
                               MultIds=np.array([f.mults for f in formats], dtype="S16")))
    params = sim.log_params
    blocks.append(PARM.records(len(params), TimeUS=t_us, Name=np.array(list(params), dtype="S16"),
                               Value=list(params.values()), Default=0.0))
    blocks.append(VER.records(1, TimeUS=t_us, BT=VER_BOARD_TYPE, BST=0, Maj=0, Min=1, Pat=0,
                              FWT=VER_FIRMWARE_TYPE, GH=0, FWS=sim.firmware, APJ=0, BU=VER_BUILD_TYPE))
    blocks.append(MSG.records(2, TimeUS=t_us, Message=np.array([sim.firmware, "Frame: QUAD/X"], dtype="S64")))
    return blocks


def _data(sim, imt: bool = False) -> list[np.ndarray]:
    """Sensor, attitude and truth records, each block in time order."""
    blocks = []
    for instance, imu in enumerate(sim.imu):
        g, a = imu.gyro, imu.accel
        blocks.append(IMU.records(
            len(imu.t), TimeUS=_us(imu.t), I=instance, GyrX=g[:, 0], GyrY=g[:, 1], GyrZ=g[:, 2],
            AccX=a[:, 0], AccY=a[:, 1], AccZ=a[:, 2], EG=0, EA=0, T=imu.temperature_c, GH=1, AH=1,
            GHz=round(sim.rates.imu), AHz=round(sim.rates.imu)))
        if imt:
            blocks.append(_imt_records(sim, instance, imu))

    mag = sim.mag
    mg = mag.field * 1e7  # tesla -> mGauss
    ofs = mag.offsets * 1e7
    t_us = _us(mag.t)
    blocks.append(MAG.records(
        len(mag.t), TimeUS=t_us, I=0, MagX=mg[:, 0], MagY=mg[:, 1], MagZ=mg[:, 2],
        OfsX=ofs[0], OfsY=ofs[1], OfsZ=ofs[2], MOX=0, MOY=0, MOZ=0, Health=1, S=t_us % 2 ** 32))

    gps = sim.gps
    t_us = _us(gps.t)
    week, week_ms = world.gps_week_ms(sim.epoch_unix_at_boot + gps.t)
    v = gps.vel_ned
    blocks.append(GPS.records(
        len(gps.t), TimeUS=t_us, I=0, Status=gps.fix_type, GMS=week_ms, GWk=week, NSats=gps.num_sats,
        HDop=gps.hdop, Lat=gps.lat_deg, Lng=gps.lon_deg, Alt=gps.alt_m, Spd=np.hypot(v[:, 0], v[:, 1]),
        GCrs=np.degrees(np.arctan2(v[:, 1], v[:, 0])) % 360.0, VZ=v[:, 2], Yaw=0.0, U=1))
    blocks.append(GPA.records(
        len(gps.t), TimeUS=t_us, I=0, VDop=gps.vdop, HAcc=gps.h_acc_m, VAcc=gps.v_acc_m,
        SAcc=gps.speed_acc_ms, YAcc=0.0, VV=1, SMS=(t_us // 1000) % 2 ** 32,
        Delta=round(1000.0 / sim.rates.gps), Und=0.0))

    baro = sim.baro
    t_us = _us(baro.t)
    blocks.append(BARO.records(
        len(baro.t), TimeUS=t_us, I=0, Alt=baro.alt_m, Press=baro.pressure_pa, Temp=baro.temperature_c,
        CRt=baro.climb_rate, SMS=(t_us // 1000) % 2 ** 32, Offset=0.0, GndTemp=baro.temperature_c, Health=1))

    # The autopilot's estimate (ATT) and the truth (SIM) on the same ticks, every att_every-th IMU sample.
    every = slice(None, None, sim.rates.att_every)
    t_us = _us(sim.truth.t[every])
    n = len(t_us)
    est = np.degrees(quat.to_euler(sim.autopilot_q[every]))
    est_yaw = _heading_deg(est[:, 2])
    dcm = sim.ekf_q is not None
    blocks.append(ATT.records(
        n, TimeUS=t_us, DesRoll=est[:, 0], Roll=est[:, 0], DesPitch=est[:, 1], Pitch=est[:, 1],
        DesYaw=est_yaw, Yaw=est_yaw, ErrRP=0.0, ErrYaw=0.0, AEKF=0 if dcm else 3))
    if dcm:
        ekf = np.degrees(quat.to_euler(sim.ekf_q[every]))
        ekf_yaw = _heading_deg(ekf[:, 2])
        blocks.append(EKF1.records(n, TimeUS=t_us, Roll=ekf[:, 0], Pitch=ekf[:, 1], Yaw=ekf_yaw, VN=0.0, VE=0.0,
                                   VD=0.0, dPD=0.0, PN=0.0, PE=0.0, PD=0.0, GX=0.0, GY=0.0, GZ=0.0))
        lat, lon, alt = earth.ned_to_geodetic(sim.home.origin, sim.truth.pos_ned[every])
        q = sim.ekf_q[every] * np.where(sim.ekf_q[every][:, :1] < 0, -1.0, 1.0)
        blocks.append(AHR2.records(n, TimeUS=t_us, Roll=ekf[:, 0], Pitch=ekf[:, 1], Yaw=ekf_yaw, Alt=alt,
                                   Lat=lat, Lng=lon, Q1=q[:, 0], Q2=q[:, 1], Q3=q[:, 2], Q4=q[:, 3]))
    blocks += _script_records(sim.script)
    q = quat.normalize(sim.truth.q[every])
    q = q * np.where(q[:, :1] < 0, -1.0, 1.0)  # ArduPilot logs the quaternion with w >= 0
    true = np.degrees(quat.to_euler(q))
    lat, lon, alt = earth.ned_to_geodetic(sim.home.origin, sim.truth.pos_ned[every])
    blocks.append(SIM.records(
        n, TimeUS=t_us, Roll=true[:, 0], Pitch=true[:, 1], Yaw=_heading_deg(true[:, 2]), Alt=alt,
        Lat=lat, Lng=lon, Q1=q[:, 0], Q2=q[:, 1], Q3=q[:, 2], Q4=q[:, 3]))
    return blocks


def _script_records(script) -> list[np.ndarray]:
    """MODE, EV and MSG records of the flight's script (``SimFlight.script``)."""
    number = [m[1] for m in script.modes]
    blocks = [MODE.records(len(number), TimeUS=_us([m[0] for m in script.modes]), Mode=number, ModeNum=number, Rsn=0)]
    if script.armed_at is not None:
        blocks.append(EV.records(1, TimeUS=_us([script.armed_at]), Id=10))
    if script.messages:
        blocks.append(MSG.records(len(script.messages), TimeUS=_us([t for t, _ in script.messages]),
                                  Message=np.array([text for _, text in script.messages], dtype="S64")))
    return blocks


def _imt_records(sim, instance: int, imu) -> np.ndarray:
    """IMT: each step's delta angle and velocity (see the module docstring), from the second sample."""
    truth = sim.truth
    dt = np.diff(imu.t)[:, None]
    turn = quat.to_rotation_vector(quat.multiply(quat.conjugate(truth.q[:-1]), truth.q[1:]))
    delta_angle = turn + (imu.gyro - truth.omega_b)[1:] * dt
    f = truth.specific_force_b
    delta_velocity = 0.5 * (f[:-1] + f[1:]) * dt + (imu.accel - f)[1:] * dt
    da, dv = delta_angle, delta_velocity
    return IMT.records(len(dt), TimeUS=_us(imu.t[1:]), I=instance, DelT=dt[:, 0], DelvT=dt[:, 0], DelaT=dt[:, 0],
                       DelAX=da[:, 0], DelAY=da[:, 1], DelAZ=da[:, 2], DelVX=dv[:, 0], DelVY=dv[:, 1], DelVZ=dv[:, 2])


def _heading_deg(yaw_deg) -> np.ndarray:
    """Yaw as a 0-360° heading whose centidegree value stays below 36000 after rounding."""
    return (np.rint(np.asarray(yaw_deg) * 100.0) % 36000) / 100.0


def _merge(blocks: list[np.ndarray]) -> np.ndarray:
    """One uint8 buffer holding every record of every block, ordered by TimeUS (stable)."""
    times = np.concatenate([b["TimeUS"] for b in blocks])
    block_id = np.concatenate([np.full(len(b), i) for i, b in enumerate(blocks)])
    order = np.lexsort((block_id, times))  # by time, then block order; within a block, as given
    lengths = np.concatenate([np.full(len(b), b.dtype.itemsize) for b in blocks])[order]
    starts = np.empty(len(order), dtype=np.int64)
    starts[order] = np.cumsum(lengths) - lengths  # byte offset of every record, in block order
    out = np.empty(int(lengths.sum()), dtype=np.uint8)
    first = 0
    for b in blocks:
        raw = np.ascontiguousarray(b).view(np.uint8).reshape(len(b), b.dtype.itemsize)
        index = starts[first:first + len(b), None] + np.arange(b.dtype.itemsize)
        out[index] = raw
        first += len(b)
    return out


def write_bin(sim, path, imt: bool = False) -> None:
    """Write ``sim`` (a SimFlight) as an ArduPilot DataFlash log at ``path`` (``imt``: with
    delta angles and velocities)."""
    t_start = int(_us(sim.truth.t[0]))
    header = np.concatenate([np.ascontiguousarray(b).view(np.uint8) for b in _header(sim, t_start)])
    with open(Path(path), "wb") as f:
        f.write(header.tobytes())
        f.write(_merge(_data(sim, imt)).tobytes())
