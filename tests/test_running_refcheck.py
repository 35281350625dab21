"""``RunningReferenceCheck``, fed a log a part at a time, finds the spans ``refcheck`` finds on the
whole log: the same kinds, times and words, whatever the parts' sizes."""
from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import pytest

from conftest import read_shared
from mavattitude import quaternion as quat
from mavattitude.phase import detect_phase
from mavattitude.readers import read_log
from mavattitude.readers.attitudes import name_attitudes
from mavattitude.scoring.refcheck import autopilot_disagreement, check_reference, compared_streams
from mavattitude.scoring.running_refcheck import RunningReferenceCheck
from mavattitude.sim import SensorParams, simulate, write_log


def whole_log(flight, imu_key, trim=None):
    """replay's suspects (``commands.replay``), the phase from the log's heights."""
    ref, phase = flight.attitude, detect_phase(flight)
    suspects = check_reference(ref, flight.imu[imu_key], trim, phase.on_clock if phase is not None else None,
                               flight.gps)
    return sorted(suspects + autopilot_disagreement(ref, flight), key=lambda s: s.start)


def running(flight, imu_key, chunk_s, trim=None, check_settled=True):
    """The same, fed ``chunk_s`` of every series at a time (the IMU's clock), judged after each."""
    ref, phase, imu, gps = flight.attitude, detect_phase(flight), flight.imu[imu_key], flight.gps
    named = name_attitudes(flight)
    check = RunningReferenceCheck(ref.source, trim)
    check.algorithm = next(n.algorithm for n in named if n.key == ref.source)
    check.compared = {n.key: n.algorithm for n in compared_streams(ref, named)} if len(flight.attitudes) > 1 else {}
    others = {k: s for k, s in flight.attitudes.items() if k != ref.source}
    edges = np.arange(imu.t[0], imu.t[-1] + chunk_s, chunk_s)
    settled, spans_then = -math.inf, []
    for a, b in zip(edges[:-1], edges[1:]):
        def part(t):
            return (t >= a) & (t < b) if a > edges[0] else t < b
        k = part(imu.t)
        check.add_imu(imu.t[k], imu.gyro[k], imu.accel[k])
        check.add_reference(ref.t[part(ref.t)], ref.q[part(ref.t)])
        if gps is not None:
            check.add_gps(gps.t[part(gps.t)], gps.vel_ned[part(gps.t), :2])
        if phase is not None:
            check.add_phase(phase.t[part(phase.t)], phase.in_air[part(phase.t)])
        for key, s in others.items():
            check.add_stream(key, s.t[part(s.t)], s.q[part(s.t)])
        check.advance()
        assert check.settled >= settled  # never takes back what it settled
        settled = check.settled
        spans_then.append((settled, check.excluded()))
    check.finish()
    if check_settled:  # what was said settled then is what the end says, before that time
        final = check.suspects
        for settled, spans in spans_then:
            def covered(t, spans):
                return any(s <= t <= e for s, e in spans)
            probe = ref.t[ref.t < settled][-2000:]
            assert [covered(t, spans) for t in probe] == [covered(t, [(s.start, s.end) for s in final])
                                                          for t in probe]
    return check.suspects


def faulty_log(path):
    """A figure-eight with a DCM primary (AHRS2 the EKF's), its reference faulty: 10° of roll
    while still on the ground (5-12 s), a 60° jump out and back (40 s, 2 s long), and 20° off
    the EKF for 15 s (60-75 s, a 1 s dip inside)."""
    sim = simulate("figure8", 90.0, seed=3, imu_rate=50.0, params=SensorParams(dcm_bias=(0.01, 0.0, 0.0)))
    t = sim.t
    roll = np.where((t >= 5.0) & (t < 12.0) & (t < sim.still_until), math.radians(10.0), 0.0)
    roll += np.where((t >= 40.0) & (t < 42.0), math.radians(60.0), 0.0)
    roll += np.where((t >= 60.0) & (t < 75.0) & ~((t >= 67.0) & (t < 68.0)), math.radians(20.0), 0.0)
    bad = quat.from_euler(roll, np.zeros_like(t), np.zeros_like(t))
    sim = replace(sim, autopilot_q=quat.multiply(sim.autopilot_q, bad))
    return write_log(sim, path)


@pytest.fixture(scope="module")
def faulty(tmp_path_factory):
    return read_log(str(faulty_log(tmp_path_factory.mktemp("refwatch") / "faulty.tlog")))


@pytest.mark.parametrize("chunk_s", [pytest.param(0.05, marks=pytest.mark.slow), 0.37, 3.0, 1000.0])
def test_the_running_check_finds_the_whole_logs_spans_in_any_chunks(faulty, chunk_s):
    key = max(faulty.imu, key=lambda k: len(faulty.imu[k].t))
    expected = whole_log(faulty, key)
    assert {s.kind for s in expected} == {"tilt at rest", "tilt jump", "autopilot disagrees"}
    assert running(faulty, key, chunk_s, check_settled=chunk_s > 0.1) == expected


def test_the_running_check_turns_the_accelerometer_by_the_trim(faulty):
    key = max(faulty.imu, key=lambda k: len(faulty.imu[k].t))
    trim = (math.radians(4.0), math.radians(-2.0))
    expected = whole_log(faulty, key, trim)
    assert expected != whole_log(faulty, key) and running(faulty, key, 1.3, trim) == expected


@pytest.mark.slow  # reads shared logs, judged in parts
@pytest.mark.parametrize("name, kinds", [
    ("corpus/real-copter-3.3dev-erlepxf-dcm-gps-flight-erle-20141009-31.bin", {"autopilot disagrees", "tilt at rest"}),
    ("corpus/real-copter-3.3dev-erlepxf-dcm-long-erle-20140923-51.bin", {"autopilot disagrees"}),
    ("corpus/real-plane-4.3.1-kakutef7-crash-bixler-scottyob.bin", {"tilt jump", "autopilot disagrees"}),
    ("sitl-copter-4.7-vibration.tlog", {"tilt jump", "tilt at rest"}),
    ("sitl-quadplane-vtol.tlog", {"autopilot disagrees"}),
    ("copter-4.1-flight.tlog", set())])
def test_the_running_check_finds_the_whole_logs_spans_on_shared_logs(name, kinds):
    flight = read_shared(name)
    key = max(flight.imu, key=lambda k: len(flight.imu[k].t))
    expected = whole_log(flight, key)
    assert {s.kind for s in expected} == kinds
    for chunk_s in (0.5, 7.0):
        assert running(flight, key, chunk_s, check_settled=False) == expected, chunk_s
