"""The filters people use instead (``estimators.rivals``: vqf, imufusion): their frames and signs
against ours, chunked equal to whole, parameters reaching the filter, a missing package in one
line, and a replay that scores them. The contract tests (test_contract.py) cover them as well."""
from __future__ import annotations

import math
import sys

import numpy as np
import pytest

import simtruth as st
from mavattitude import quaternion as quat
from mavattitude.cli import main
from mavattitude.estimators import ESTIMATORS, all_names, available, create
from mavattitude.estimators.rivals import START_STEPS
from mavattitude.flight import GRAVITY

RIVALS = [pytest.param(n, marks=pytest.mark.skipif(bool(available(n)), reason=available(n) or ""))
          for n in ("vqf", "imufusion")]
FIELD_NED = np.array([2e-5, 0.0, 4e-5])  # T, declination 0 here: magnetic north is true north
RATE = 100.0


def steady(q_truth, seconds=30.0, rate_rad_s=0.0):
    """(t, gyro, accel, mag) of a body starting at ``q_truth`` turning about the down axis at
    ``rate_rad_s`` (roll and pitch kept), and the true attitude at each sample."""
    t = np.arange(int(seconds * RATE)) / RATE
    q = quat.yaw_turned(np.broadcast_to(q_truth, (len(t), 4)), rate_rad_s * t)
    # the rate about NED down, in the body: C(q)ᵀ [0, 0, ω]
    def in_body(v_ned):
        return quat.rotate(quat.conjugate(q), np.broadcast_to(v_ned, (len(t), 3)))
    gyro = in_body([0.0, 0.0, rate_rad_s])
    return t, gyro, in_body([0.0, 0.0, -GRAVITY]), in_body(FIELD_NED), q  # accel: specific force


def run(name, inputs, q0, use_mag=True, **values):
    t, gyro, accel, mag, _ = inputs
    f = create(name, use_mag=use_mag, **values)
    f.initialize(q0, np.zeros(3))
    return f.update(t, gyro, accel, mag if use_mag else None)


def euler_error_deg(q, q_truth):
    return np.degrees(np.abs(quat.wrap_pi(quat.to_euler(q) - quat.to_euler(q_truth))))


@pytest.mark.parametrize("name", RIVALS)
@pytest.mark.parametrize("use_mag", [True, False])
@pytest.mark.parametrize("roll_deg, rate_deg_s", [(0.0, 0.0), (30.0, 0.0), (0.0, 30.0), (20.0, 45.0)])
def test_static_tilted_and_turning_attitudes_match_ours(name, use_mag, roll_deg, rate_deg_s):
    """Level, rolled 30° right (FRD: right wing down is positive roll), and turning right about
    the vertical: the estimate converges to the truth in roll and pitch from a level start,
    and in yaw (9D) from a start 40° off, or (6D) follows the gyro from a true start."""
    truth0 = quat.from_euler(math.radians(roll_deg), 0.0, 0.3)
    inputs = steady(truth0, rate_rad_s=math.radians(rate_deg_s))
    yaw_off = 0.7 if use_mag else 0.0  # 6D has no heading to converge to
    q0 = quat.from_euler(0.0, 0.0, 0.3 + yaw_off)
    extra = {"magnetic_rejection": 0.0, "acceleration_rejection": 0.0} if name == "imufusion" else {}
    q = run(name, inputs, q0, use_mag, **extra)
    err = euler_error_deg(q[-500:], inputs[4][-500:])  # the last 5 s
    assert err[:, :2].max() < 0.5, err[:, :2].max(axis=0)
    assert err[:, 2].max() < (1.0 if use_mag else 0.5), err[:, 2].max()


@pytest.mark.parametrize("name", RIVALS)
def test_tracks_the_simulated_flight(name):
    """figure8, 120 s at 100 Hz, from the shared alignment, defaults: roll, pitch and (9D) yaw
    near the truth. Bounds: the measured RMS (vqf 3.1/9.5/4.7°, imufusion 8.4/7.0/16.6°: its
    gain 0.5 leans on an accelerometer that sees the turns; mahony 2.7/4.9/3.3°) + margin;
    a sign or frame error makes tens of degrees."""
    sim = st.figure8_120()
    q, _ = st.run(name, sim)
    rms = np.sqrt((st.errors_deg(sim, q) ** 2).mean(axis=0))
    assert (rms < {"vqf": [4.0, 11.0, 6.0], "imufusion": [10.0, 9.0, 20.0]}[name]).all(), rms


@pytest.mark.parametrize("name", RIVALS)
def test_declination_turns_the_heading_to_true_north(name):
    truth0 = quat.from_euler(0.0, 0.0, 0.3)
    inputs = steady(truth0)
    decl = 0.2  # rad, east positive: magnetic north is 0.2 rad east of true north
    t, gyro, accel, _, q_truth = inputs
    field = quat.rotate(quat.from_euler(0.0, 0.0, decl), FIELD_NED)
    mag = quat.rotate(quat.conjugate(q_truth), np.broadcast_to(field, (len(t), 3)))
    f = create(name, declination=decl, **({"magnetic_rejection": 0.0} if name == "imufusion" else {}))
    f.initialize(quat.from_euler(0.0, 0.0, 0.8), np.zeros(3))  # 0.5 rad off: the heading must come from the compass
    q = f.update(t, gyro, accel, mag)
    assert euler_error_deg(q[-100:], q_truth[-100:]).max() < 1.0


@pytest.mark.parametrize("name", RIVALS)
def test_chunked_equals_whole_and_a_gap_holds(name):
    sim = st.figure8_120()
    t, gyro, accel, mag = st.inputs(sim)
    t = t.copy()
    t[5000:] += 3.0  # a gap: not integrated
    whole = create(name)
    whole.initialize(np.array([1.0, 0, 0, 0]), np.zeros(3))
    q_whole = whole.update(t, gyro, accel, mag)
    live = create(name)
    live.initialize(np.array([1.0, 0, 0, 0]), np.zeros(3))
    cuts = [0, 1, 7, 4999, 5000, 5001, 9000, len(t)]
    q_live = np.vstack([live.update(t[a:b], gyro[a:b], accel[a:b], mag[a:b]) for a, b in zip(cuts, cuts[1:])])
    np.testing.assert_array_equal(q_live, q_whole)
    np.testing.assert_array_equal(q_whole[5000], q_whole[4999])
    # the first sample is no step, the next START_STEPS wait for the sample time (their median)
    np.testing.assert_array_equal(q_whole[:START_STEPS + 1], np.tile([1.0, 0, 0, 0], (START_STEPS + 1, 1)))
    assert not np.array_equal(q_whole[START_STEPS + 1], q_whole[START_STEPS])
    assert whole._ts == np.median(np.diff(t[:START_STEPS + 1]))


@pytest.mark.parametrize("name, field, value", [
    pytest.param("vqf", "tau_acc", 1000.0, marks=RIVALS[0].marks),
    pytest.param("imufusion", "gain", 5.0, marks=RIVALS[1].marks),
])
def test_a_parameter_reaches_the_filter(name, field, value):
    sim = st.figure8_120()
    default, _ = st.run(name, sim)
    changed, _ = st.run(name, sim, ESTIMATORS[name].Params(**{field: value}))
    assert np.degrees(np.abs(quat.to_euler(default) - quat.to_euler(changed))[:, :2]).max() > 0.5


def test_all_is_ours_and_the_rivals_are_named():
    assert "vqf" not in all_names() and "imufusion" not in all_names()
    assert {"mahony", "cpf-ekf"} <= set(all_names())


@pytest.mark.parametrize("name", ["vqf", "imufusion"])
def test_a_missing_package_is_one_line_with_the_pip_command(name, monkeypatch, capsys):
    monkeypatch.setitem(sys.modules, name, None)  # import raises ImportError, find_spec says None
    code = main(["replay", "sample_logs/static.bin", "--no-view", "--estimators", f"mahony,{name}"])
    err = capsys.readouterr().err
    lines = err.strip().splitlines()
    assert code == 2 and len(lines) == 1 and "Traceback" not in err, err
    assert name in lines[0] and "pip install 'mavattitude[rivals]'" in lines[0]
    assert main(["estimators"]) == 0
    listed = [line for line in capsys.readouterr().out.splitlines() if line.startswith(f"{name}: ")]
    assert len(listed) == 1 and listed[0].endswith("(optional: pip install 'mavattitude[rivals]'; not installed)")
    from mavattitude.errors import UsageError
    with pytest.raises(UsageError, match="pip install"):
        create(name)


@pytest.mark.skipif(any(available(n) for n in ("vqf", "imufusion")), reason="needs vqf and imufusion")
def test_replay_scores_them_beside_ours(tmp_path, capsys):
    """The same runner and scoring as ours: rows in the table and the JSON, against the truth."""
    import json

    out = tmp_path / "r.json"
    code = main(["replay", "sample_logs/figure8.tlog", "--no-view", "--reference", "truth",
                 "--estimators", "mahony,vqf,imufusion", "--json", str(out)])
    table = capsys.readouterr().out
    assert code == 0
    scores = json.loads(out.read_text())["estimators"]
    for name in ("vqf", "imufusion"):
        assert any(line.startswith(f"{name} ") for line in table.splitlines()), table
        assert scores[name]["meaningful"] and scores[name]["roll"]["n"] == scores["mahony"]["roll"]["n"]
        # measured: vqf 3.1/9.8/4.5°, imufusion 7.6/6.7/15.1° RMSE; a frame error makes tens of degrees
        assert all(scores[name][axis]["rmse"] < 20.0 for axis in ("roll", "pitch", "yaw")), scores[name]


@pytest.mark.parametrize("name", RIVALS[:1])
def test_vqf_says_when_it_detects_rest_and_a_disturbed_field(name):
    """Its rest and magnetic-disturbance detection as diagnostics: NaN while the first steps
    wait, rest at the end of a still start, never while turning at 1 rad/s; on figure8 it
    accepts the field part of the time (VQF accepts a new field only in motion: magNewMinGyr)."""
    inputs = steady(quat.from_euler(0.0, 0.0, 0.3))
    f = create(name)
    f.initialize(quat.from_euler(0.0, 0.0, 0.3), np.zeros(3))
    f.update(*inputs[:4])
    rest = f.diagnostics["rest"]
    assert np.isnan(rest[:START_STEPS + 1]).all() and rest[-1] == 1.0
    turning = steady(quat.from_euler(0.0, 0.0, 0.3), rate_rad_s=1.0)
    g = create(name, use_mag=False)
    g.initialize(quat.from_euler(0.0, 0.0, 0.3), np.zeros(3))
    g.update(*turning[:3], None)
    assert set(g.diagnostics) == {"rest"} and (g.diagnostics["rest"][START_STEPS + 1:] == 0.0).all()
    _, h = st.run(name, st.figure8_120())
    assert set(np.unique(h.diagnostics["mag_disturbed"][START_STEPS + 1:])) == {0.0, 1.0}
