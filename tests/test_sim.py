"""The simulator: true motion consistent with itself, sensors consistent with the truth, and logs
that pymavlink reads back with ArduPilot's layouts, units and values."""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from pymavlink import mavutil

from mavattitude import earth
from mavattitude import quaternion as quat
from mavattitude.flight import GRAVITY
from mavattitude.sim import SCENARIOS, SensorParams, simulate, write_log
from mavattitude.sim import dataflash, trajectory, world

REAL_44_BIN = Path(__file__).resolve().parents[2] / "shared" / "logs" / "sitl-copter-4.4.bin"
G_NED = np.array([0.0, 0.0, GRAVITY])


def angle_deg(q_a, q_b) -> np.ndarray:
    """Rotation angle (degrees) between two attitudes, per sample."""
    d = quat.multiply(quat.conjugate(q_a), q_b)
    return np.degrees(2 * np.arctan2(np.linalg.norm(d[..., 1:], axis=-1), np.abs(d[..., 0])))


def read_all(path) -> dict[str, list]:
    """Every message of a log, by type, in file order."""
    conn = mavutil.mavlink_connection(str(path))
    out: dict[str, list] = {}
    while (m := conn.recv_msg()) is not None:
        out.setdefault(m.get_type(), []).append(m)
    return out


@pytest.fixture(scope="module")
def fig8():
    return simulate("figure8", 30.0, seed=7, imu_rate=50.0)


# ---------------------------------------------------------------- scenarios and trajectories


def test_registry_lists_the_scenarios_and_rejects_unknown_ones():
    assert {"static", "hover", "figure8"} <= set(SCENARIOS)
    assert all(isinstance(d, str) and d for d in SCENARIOS.values())
    assert set(SCENARIOS) == set(trajectory.REGISTRY)
    with pytest.raises(ValueError, match="figure8"):
        simulate("loop-the-loop", 10.0)
    with pytest.raises(ValueError, match="rate"):
        simulate("static", 10.0, imu_rate=0.0)


@pytest.mark.parametrize("name, duration", [("static", 5.0), ("hover", 30.0), ("figure8", 45.0)])
def test_integrated_body_rates_reproduce_the_attitude(name, duration):
    step = 2e-3
    truth = trajectory.sample(trajectory.REGISTRY[name], np.arange(0.0, duration, step))
    q = truth.q[0]
    worst = 0.0
    for k in range(len(truth.t) - 1):
        q = quat.integrate_gyro(q, 0.5 * (truth.omega_b[k] + truth.omega_b[k + 1]), step)
        if k % 50 == 49:
            worst = max(worst, float(angle_deg(q, truth.q[k + 1])))
    assert worst < 0.01


@pytest.mark.parametrize("name", sorted(trajectory.REGISTRY))
def test_derivatives_and_specific_force_are_consistent(name):
    step = 1e-3
    truth = trajectory.sample(trajectory.REGISTRY[name], np.arange(0.0, 45.0, step))
    inner = slice(2, -2)
    assert np.allclose(np.gradient(truth.pos_ned, step, axis=0)[inner], truth.vel_ned[inner], atol=1e-5)
    assert np.allclose(np.gradient(truth.vel_ned, step, axis=0)[inner], truth.acc_ned[inner], atol=2e-3)
    expected = np.einsum("nji,nj->ni", quat.to_dcm(truth.q), truth.acc_ned - G_NED)  # C(q)ᵀ (a - g)
    assert np.allclose(truth.specific_force_b, expected, atol=1e-9)
    assert np.allclose(np.linalg.norm(truth.q, axis=1), 1.0)


def test_every_scenario_starts_still_on_the_ground():
    for name, spec in trajectory.REGISTRY.items():
        truth = trajectory.sample(spec, np.arange(0.0, 30.0, 0.01))
        still = truth.t < spec.still_until
        assert truth.t[still][-1] >= 5.0 - 0.01, name
        assert np.abs(truth.pos_ned[still]).max() < 1e-12, name  # at home, on the ground
        assert np.abs(truth.vel_ned[still]).max() < 1e-12, name
        assert np.abs(truth.omega_b[still]).max() < 1e-9, name
        assert np.allclose(np.linalg.norm(truth.specific_force_b[still], axis=1), GRAVITY), name
        if np.isfinite(spec.still_until):
            assert np.abs(truth.vel_ned[truth.t > spec.still_until + 2.0]).max() > 0.1, name


def test_figure8_is_a_gentle_then_coordinated_multirotor_flight():
    step = 5e-3
    truth = trajectory.sample(trajectory.REGISTRY["figure8"], np.arange(0.0, 70.0, step))
    roll, pitch, yaw = np.degrees(quat.to_euler(truth.q)).T
    speed = np.linalg.norm(truth.vel_ned[:, :2], axis=1)
    full = truth.t > 30.0  # up to speed
    assert 5.0 < speed[full].min() and speed[full].max() < 8.5
    assert 20.0 < np.abs(roll).max() < 30.0
    # Coordinated: thrust along body -z, so the accelerometer reads only along z.
    assert np.abs(truth.specific_force_b[:, :2]).max() < 1e-9
    # Yaw follows the velocity heading whenever moving.
    moving = speed > 1.0
    heading = np.degrees(np.arctan2(truth.vel_ned[moving, 1], truth.vel_ned[moving, 0]))
    assert np.abs(quat.wrap_deg(yaw[moving] - heading)).max() < 1e-6
    # Smooth start: continuous body rates (no jerk step) and a gentle first 10 s of motion.
    assert np.abs(np.diff(truth.omega_b, axis=0)).max() < 5e-3  # rad/s per 5 ms
    first = (truth.t > trajectory.REGISTRY["figure8"].still_until) & (truth.t < 16.0)
    assert np.abs(roll[first]).max() < 5.0 and np.abs(pitch[first]).max() < 5.0


# ---------------------------------------------------------------- sensors


def test_sensors_match_the_truth(fig8):
    sim = fig8
    imu = sim.imu[0]
    assert np.array_equal(imu.t, sim.truth.t) and np.array_equal(sim.imu[1].t, sim.truth.t)
    assert sim.t[0] == world.BOOT_TIME_AT_START  # the autopilot clock does not start at 0
    rate = sim.rates.imu
    gyro_noise = imu.gyro - sim.truth.omega_b - imu.gyro_bias
    assert np.std(gyro_noise) == pytest.approx(sim.params.gyro_noise_density * np.sqrt(rate), rel=0.1)
    accel_noise = imu.accel - sim.truth.specific_force_b - imu.accel_bias
    assert np.std(accel_noise) == pytest.approx(sim.params.accel_noise_density * np.sqrt(rate), rel=0.1)
    assert np.abs(imu.gyro_bias[0]).max() > 1e-4  # a bias an estimator must remove
    assert not np.allclose(sim.imu[0].gyro_bias, sim.imu[1].gyro_bias)  # two distinct IMUs
    still = sim.t < sim.still_until
    assert np.linalg.norm(imu.accel[still].mean(axis=0)) == pytest.approx(GRAVITY, abs=0.1)

    # Compass: compensated field of the configured strength; heading + declination = true yaw.
    assert np.linalg.norm(sim.mag.field, axis=1).mean() == pytest.approx(sim.earth_field.total_t, rel=0.02)
    euler = quat.to_euler(quat.interpolate(sim.t, sim.truth.q, sim.mag.t))
    heading = quat.heading_from_mag(euler[:, 0], euler[:, 1], sim.mag.field, sim.declination_rad)
    assert np.abs(np.degrees(quat.wrap_pi(heading - euler[:, 2]))).mean() < 1.0

    # The autopilot is close to the truth but not equal to it.
    err = angle_deg(sim.autopilot_q, sim.truth.q)
    assert 0.05 < np.sqrt(np.mean(err ** 2)) < 1.0 and err.max() < 2.0

    # GPS and baro follow the true position.
    assert len(sim.gps.t) == pytest.approx(sim.duration * sim.rates.gps, abs=1)
    lat, lon, alt = earth.ned_to_geodetic(sim.home.origin, trajectory.sample(
        trajectory.REGISTRY["figure8"], sim.gps.t - world.BOOT_TIME_AT_START).pos_ned)
    north_err = (sim.gps.lat_deg - lat) * 111_000
    assert 0.1 < np.std(north_err) < 1.0
    assert np.abs(sim.baro.alt_m[-10:].mean() - trajectory.FIG8_HEIGHT) < 0.3


def test_noise_follows_the_seed_not_the_trajectory():
    a, b, c = (simulate("hover", 20.0, seed=s) for s in (1, 1, 2))
    assert np.array_equal(a.imu[0].gyro, b.imu[0].gyro)
    assert not np.allclose(a.imu[0].gyro, c.imu[0].gyro)
    assert np.array_equal(a.truth.q, c.truth.q)
    quiet = simulate("hover", 20.0, seed=1, params=SensorParams(gyro_noise_density=0.0))
    assert np.array_equal(quiet.imu[0].gyro_bias, a.imu[0].gyro_bias)  # biases drawn before noise


# ---------------------------------------------------------------- log writers


def test_tlog_reads_back_with_ardupilot_units(fig8, tmp_path):
    sim = fig8
    path = write_log(sim, tmp_path / "f8.tlog")
    msgs = read_all(path)
    n = len(sim.t)
    for name in ("RAW_IMU", "SCALED_IMU2", "ATTITUDE", "SIMSTATE"):
        assert len(msgs[name]) == n, name
    assert len(msgs["GPS_RAW_INT"]) == len(sim.gps.t)
    assert len(msgs["SCALED_PRESSURE"]) == len(sim.baro.t)
    assert len(msgs["HEARTBEAT"]) == round(sim.duration)
    hb = msgs["HEARTBEAT"][0]
    assert (hb.type, hb.autopilot) == (mavutil.mavlink.MAV_TYPE_QUADROTOR, mavutil.mavlink.MAV_AUTOPILOT_ARDUPILOTMEGA)
    assert msgs["HEARTBEAT"][-1].base_mode & mavutil.mavlink.MAV_MODE_FLAG_SAFETY_ARMED
    assert "figure8" in msgs["STATUSTEXT"][0].text
    params = {p.param_id: p.param_value for p in msgs["PARAM_VALUE"]}
    assert params["COMPASS_DEC"] == pytest.approx(np.radians(5.0), abs=1e-6)

    # MAVLink 2, with the record stamp = boot epoch + autopilot time.
    assert all(m.get_msgbuf()[0] == 0xFD for m in msgs["RAW_IMU"][:3])  # MAVLink 2 start byte
    assert msgs["RAW_IMU"][0]._timestamp == pytest.approx(sim.epoch_unix_at_boot + sim.t[0], abs=1e-6)
    st = msgs["SYSTEM_TIME"][0]
    assert st.time_unix_usec == pytest.approx((sim.epoch_unix_at_boot + st.time_boot_ms / 1e3) * 1e6, abs=1)

    raw = msgs["RAW_IMU"]
    time_usec = np.array([m.time_usec for m in raw])
    assert np.array_equal(time_usec, np.rint(sim.t * 1e6))  # µs since boot, not epoch
    acc_mg = np.array([[m.xacc, m.yacc, m.zacc] for m in raw], dtype=float)
    gyro_mrad = np.array([[m.xgyro, m.ygyro, m.zgyro] for m in raw], dtype=float)
    mag_mgauss = np.array([[m.xmag, m.ymag, m.zmag] for m in raw], dtype=float)
    assert np.abs(acc_mg - sim.imu[0].accel / GRAVITY * 1e3).max() <= 0.5
    assert np.abs(gyro_mrad - sim.imu[0].gyro * 1e3).max() <= 0.5
    assert np.linalg.norm(acc_mg[:100], axis=1).mean() == pytest.approx(1000.0, abs=10)  # still: 1 g
    assert np.linalg.norm(mag_mgauss, axis=1).mean() == pytest.approx(500.0, rel=0.02)
    imu2 = np.array([[m.xacc, m.yacc, m.zacc] for m in msgs["SCALED_IMU2"]], dtype=float)
    assert np.abs(imu2 - sim.imu[1].accel / GRAVITY * 1e3).max() <= 0.5

    att = np.array([[m.roll, m.pitch, m.yaw] for m in msgs["ATTITUDE"]])
    true = np.array([[m.roll, m.pitch, m.yaw] for m in msgs["SIMSTATE"]])
    assert np.abs(true - quat.to_euler(sim.truth.q)).max() < 1e-6  # float32 radians
    err = np.degrees(quat.wrap_pi(att - true))
    assert 0.02 < np.sqrt(np.mean(err ** 2)) < 1.0 and np.abs(err).max() < 2.0
    force = np.array([[m.xacc, m.yacc, m.zacc] for m in msgs["SIMSTATE"]])
    assert np.abs(force - sim.truth.specific_force_b).max() < 1e-5

    gps = msgs["GPS_RAW_INT"]
    assert {m.fix_type for m in gps} == {3}
    assert np.abs(np.array([m.lat for m in gps]) / 1e7 - sim.gps.lat_deg).max() < 1e-7
    assert np.abs(np.array([m.alt for m in gps]) / 1e3 - sim.gps.alt_m).max() < 1e-3
    assert gps[0].time_usec == round(sim.gps.t[0] * 1e6)
    press = np.array([m.press_abs for m in msgs["SCALED_PRESSURE"]])
    assert np.abs(press * 100 - sim.baro.pressure_pa).max() < 0.1  # hPa


def test_bin_reads_back_with_ardupilot_layouts_and_units(fig8, tmp_path):
    sim = fig8
    path = write_log(sim, tmp_path / "f8.bin")
    msgs = read_all(path)
    imu0 = [m for m in msgs["IMU"] if m.I == 0]
    imu1 = [m for m in msgs["IMU"] if m.I == 1]
    assert len(imu0) == len(imu1) == len(sim.t)
    t_us = np.array([m.TimeUS for m in imu0])
    assert np.array_equal(t_us, np.rint(sim.t * 1e6))
    acc = np.array([[m.AccX, m.AccY, m.AccZ] for m in imu0])
    gyro = np.array([[m.GyrX, m.GyrY, m.GyrZ] for m in imu0])
    assert np.abs(acc - sim.imu[0].accel).max() < 1e-5 and np.abs(gyro - sim.imu[0].gyro).max() < 1e-6
    assert acc[:100, 2].mean() == pytest.approx(-GRAVITY, abs=0.1)
    # pymavlink puts the message on the GPS-derived UNIX clock: our epoch.
    assert imu0[0]._timestamp == pytest.approx(sim.epoch_unix_at_boot + sim.t[0], abs=1e-3)

    mag = np.array([[m.MagX, m.MagY, m.MagZ] for m in msgs["MAG"]], dtype=float)
    assert np.abs(mag - sim.mag.field * 1e7).max() <= 0.5  # mGauss
    params = {m.Name: m.Value for m in msgs["PARM"]}
    assert params["COMPASS_DEC"] == pytest.approx(np.radians(5.0), abs=1e-6)
    assert msgs["MSG"][0].Message == sim.firmware

    # ATT (the autopilot's estimate) and SIM (truth), in degrees, yaw as a 0-360 heading.
    every = sim.rates.att_every
    assert len(msgs["ATT"]) == len(msgs["SIM"]) == len(sim.t[::every])
    att = np.array([[m.Roll, m.Pitch, m.Yaw] for m in msgs["ATT"]])
    sim_rpy = np.array([[m.Roll, m.Pitch, m.Yaw] for m in msgs["SIM"]])
    true = np.degrees(quat.to_euler(sim.truth.q[::every]))
    assert np.abs(quat.wrap_deg(sim_rpy - true)).max() <= 0.006  # centidegree fields
    assert 0.0 <= sim_rpy[:, 2].min() and sim_rpy[:, 2].max() < 360.0
    err = quat.wrap_deg(att - sim_rpy)
    assert 0.02 < np.sqrt(np.mean(err ** 2)) < 1.0 and np.abs(err).max() < 2.0
    sim_q = np.array([[m.Q1, m.Q2, m.Q3, m.Q4] for m in msgs["SIM"]])
    assert angle_deg(sim_q, sim.truth.q[::every]).max() < 1e-3

    gps = msgs["GPS"]
    assert np.abs(np.array([m.Lat for m in gps]) - sim.gps.lat_deg).max() < 1e-7
    assert np.abs(np.array([m.Alt for m in gps]) - sim.gps.alt_m).max() < 0.006  # m
    assert {m.Status for m in gps} == {3}
    baro = msgs["BARO"]
    assert np.abs(np.array([m.Press for m in baro]) - sim.baro.pressure_pa).max() < 0.01  # Pa
    assert np.abs(np.array([m.Alt for m in baro]) - sim.baro.alt_m).max() < 1e-4


def test_bin_declares_formats_and_units_like_arducopter_4_4(tmp_path):
    path = write_log(simulate("static", 3.0), tmp_path / "s.bin")
    conn = mavutil.mavlink_connection(str(path))
    for f in dataflash.FORMATS:
        fmt = conn.formats[f.type_id]
        assert (fmt.name, fmt.format, ",".join(fmt.columns), fmt.len) == (f.name, f.fmt, f.columns, f.length)
    assert conn.formats[dataflash.MAG.type_id].units[2] == "mGauss"
    assert conn.formats[dataflash.IMU.type_id].units[2:8] == ["rad/s"] * 3 + ["m/s/s"] * 3
    assert conn.formats[dataflash.IMU.type_id].instance_field == "I"
    if not REAL_44_BIN.exists():
        pytest.skip(f"{REAL_44_BIN} not available to compare against")
    real = mavutil.mavlink_connection(str(REAL_44_BIN))
    # ArduPilot defines a type when it first logs one: that log has no IMT (its id is a free one there)
    in_real = [f for f in dataflash.FORMATS if f is not dataflash.IMT]
    assert dataflash.IMT.type_id not in real.formats
    for f in in_real:
        r = real.formats[f.type_id]
        assert (r.name, r.format, ",".join(r.columns), r.len) == (f.name, f.fmt, f.columns, f.length)
    real_fmtu, real_units, real_mults = {}, {}, {}
    while (m := real.recv_match(type=["FMTU", "UNIT", "MULT"])) is not None:
        if m.get_type() == "FMTU":
            real_fmtu[m.FmtType] = (m.UnitIds, m.MultIds)
        elif m.get_type() == "UNIT":
            real_units[chr(m.Id)] = m.Label
        else:
            real_mults[chr(m.Id)] = m.Mult
    for f in in_real:
        assert real_fmtu[f.type_id] == (f.units, f.mults), f.name
    assert real_units == dataflash.UNITS and real_mults == dataflash.MULTS


def test_logs_are_deterministic_and_suffix_checked(tmp_path):
    for suffix in (".bin", ".tlog"):
        a = write_log(simulate("hover", 8.0, seed=3), tmp_path / f"a{suffix}").read_bytes()
        b = write_log(simulate("hover", 8.0, seed=3), tmp_path / f"b{suffix}").read_bytes()
        assert a == b
    with pytest.raises(ValueError, match=r"\.tlog, \.bin or \.ulg"):
        write_log(simulate("static", 3.0), tmp_path / "log.csv")
    assert not (tmp_path / "log.csv").exists()
    assert write_log(simulate("static", 3.0), tmp_path / "UPPER.BIN").exists()
