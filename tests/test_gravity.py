"""The accelerometer's reading of g learned from the data (estimators/gravity.py): found at the
still start whatever the scale, learned on while still and bounded, taken by the filters that
compare ‖a‖ with g, so a 15 % scale error leaves their tilt close to a true accelerometer's;
strict keeps the published constant."""
from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from mavattitude import estimators as est
from mavattitude.estimators.alignment import align
from mavattitude.estimators.eq_kf import _A_G
from mavattitude.estimators.ncs_eskf import ACCEL_TOTAL, C_G
from mavattitude.estimators.gravity import G_MAX, G_MIN, learn_gravity, plausible_g, reading_at_rest
from mavattitude.flight import GRAVITY
from simtruth import accel_110, errors_deg, figure8_120, inputs, run, run_aided, static_300

SCALES = (0.85, 1.0, 1.15)


def scaled(sim, scale: float):
    """``sim`` with every accelerometer reading ``scale`` g (a mis-scaled sensor)."""
    return replace(sim, imu=[replace(imu, accel=imu.accel * scale) for imu in sim.imu])


def tilt_error(name: str, sim, params=None) -> float:
    """Mean of roll and pitch MAE after 10 s, degrees."""
    runner = run_aided if est.create(name).uses_aiding else run
    q, _ = runner(name, sim, params)
    return float(errors_deg(sim, q)[:, :2].mean())


def test_reading_at_rest_is_the_median_norm_bounded():
    rng = np.random.default_rng(1)
    at_rest = np.array([0.0, 0.0, -8.0]) + 0.05 * rng.standard_normal((500, 3))
    assert reading_at_rest(at_rest) == pytest.approx(8.0, abs=0.01)
    assert reading_at_rest(at_rest * 0.5) == G_MIN and reading_at_rest(at_rest * 2.0) == G_MAX
    assert reading_at_rest(np.full((3, 3), np.nan)) == GRAVITY  # no reading: standard gravity
    assert plausible_g(0.8 * GRAVITY) and not plausible_g(0.7 * GRAVITY) and not plausible_g(1.3 * GRAVITY)


def test_learning_converges_at_rest_and_stays_bounded():
    g = GRAVITY
    for _ in range(3000):  # 30 s at 100 Hz, the time constant 5 s
        g = learn_gravity(g, 8.3, 0.01)
    assert g == pytest.approx(8.3, abs=0.01)
    for _ in range(3000):
        g = learn_gravity(g, 3.0, 0.01)  # no accelerometer reading g: held at the bound
    assert g == G_MIN


@pytest.mark.parametrize("scale", SCALES)
def test_the_alignment_finds_the_still_start_and_reads_g_there(scale):
    sim = scaled(figure8_120(), scale)
    t, gyro, accel, mag = inputs(sim)
    a = align(t, gyro, accel, mag, sim.declination_rad)
    assert a.still_span is not None and a.still_span[1] > sim.still_until - 1.0
    assert a.accel_g == pytest.approx(scale * GRAVITY, rel=0.01)


def test_beyond_the_bound_no_still_start_and_standard_gravity():
    sim = scaled(figure8_120(), 0.7)
    a = align(*inputs(sim)[:3])
    assert a.still_span is None and a.accel_g == GRAVITY and not a.gyro_bias.any()


def test_learned_g_does_not_follow_a_sustained_acceleration():
    """Three runs of 0.25 g: ‖a‖ 3 % above g for seconds, which learning in motion would take."""
    _, f = run("eq-kf", accel_110())
    assert f._state.aux[_A_G] == pytest.approx(GRAVITY, rel=0.005)
    _, f = run("ncs-eskf", accel_110())
    assert f._state.cons[C_G] == pytest.approx(GRAVITY, rel=0.005)


def test_ncs_eskf_learns_g_while_still_without_a_still_start():
    """Given standard gravity (no still start found) on an accelerometer reading 0.78 g at rest,
    ncs-eskf's gates learn the reading while still: the total gate, which refuses everything at
    first, lets the accelerometer in within seconds."""
    sim = scaled(static_300(), 0.78)  # beyond the 0.2 g total gate
    _, f = run("ncs-eskf", sim, accel_g=GRAVITY)
    assert f._state.cons[C_G] == pytest.approx(0.78 * GRAVITY, rel=0.005)
    state = f.diagnostics["accel_state"]
    assert state[0] != ACCEL_TOTAL and state[10] == ACCEL_TOTAL  # the first sample has no step to gate
    assert (state[np.searchsorted(sim.t, sim.t[0] + 30.0):] != ACCEL_TOTAL).all()


@pytest.mark.parametrize("name", est.all_names())
def test_tilt_on_a_mis_scaled_accelerometer_stays_close_to_a_true_one(name):
    """Figure 8 with the accelerometer at 0.85 and 1.15 g: before, ncs-eskf 12.5° / 3.0° and
    eq-kf 12.7° / 0.85° (0.16° and 0.27° at 1.0); now each within 15 % + 0.1° of its error at 1.0."""
    sim = figure8_120()
    at_one = tilt_error(name, sim)
    for scale in (0.85, 1.15):
        assert tilt_error(name, scaled(sim, scale)) <= 1.15 * at_one + 0.1, scale


@pytest.mark.parametrize("name", ["ncs-eskf", "eq-kf", "mahony-ekf"])
def test_strict_keeps_standard_gravity(name):
    """strict: the published g whatever the reading at the still start; otherwise the reading."""
    sim = scaled(figure8_120(), 0.85)
    t, gyro, accel, mag = inputs(sim)
    a = align(t, gyro, accel, mag, sim.declination_rad)
    for strict in (False, True):
        learned = est.create(name, strict=strict, declination=sim.declination_rad)
        learned.initialize(a.q0, a.gyro_bias, a.accel_g)
        published = est.create(name, strict=strict, declination=sim.declination_rad)
        published.initialize(a.q0, a.gyro_bias)  # GRAVITY
        same = np.array_equal(learned.update(t, gyro, accel, mag), published.update(t, gyro, accel, mag))
        assert same == strict, strict


def test_replay_gives_each_estimator_the_reading_at_the_still_start(tmp_path):
    """End to end on a log whose accelerometer reads 0.85 g: the still start is found, its reading
    named, and ncs-eskf's total gate (‖a‖ - g beyond 0.2 g) never refuses the accelerometer."""
    import json

    from mavattitude.cli import main
    from test_imucheck import scaled_log

    out = tmp_path / "m.json"
    assert main(["replay", str(scaled_log(tmp_path, 0.85)), "--estimators", "ncs-eskf", "--no-view", "-q",
                 "--json", str(out)]) == 0
    metrics = json.loads(out.read_text())
    still = next(e["text"] for e in metrics["events"] if e["text"].startswith("still "))
    assert "accelerometer reads g as 8.3" in still
    # main's code: no still start, 80 samples past the total gate, roll MAE 0.75° (now 0.20°)
    assert metrics["estimators"]["ncs-eskf"]["events"]["skipped: |a|-g above total threshold"]["samples"] == 0
    assert metrics["estimators"]["ncs-eskf"]["roll"]["mae"] < 0.4
