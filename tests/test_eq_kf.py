"""eq-kf (paper 002): accuracy on simulated truth, its model functions against finite
differences and the exact rotation, invariants, and batch/live equivalence."""
from __future__ import annotations

import numpy as np
import pytest
import simtruth
from test_contract import hostile

from mavattitude import quaternion as quat
from mavattitude.estimators import ESTIMATORS, create
from mavattitude.estimators.eq_kf import ACCEL_STATES, EqKf, EqKfParams
from mavattitude.estimators.eq_kf_model import (accel_jacobian, accel_predict, accel_tangent, error_propagate,
                                                error_transition, mag_jacobian, mag_predict, picard_step)
from mavattitude.flight import GRAVITY

# Every trust mechanism off: the filter then takes the accelerometer as gravity at all times.
NO_TRUST = dict(norm_lo=10.0, norm_hi=20.0, rate_lo=100.0, rate_hi=200.0, gate_lo=1e9, gate_hi=2e9,
                trust_rise=1e-9, still_time=1e9, cons_tol=10.0)


def _random_unit_quaternions(rng, n):
    q = rng.normal(size=(n, 4))
    return q / np.linalg.norm(q, axis=1, keepdims=True)


def test_registered_with_its_interface():
    """What is particular to eq-kf; the interface every estimator has is test_contract.py's."""
    assert ESTIMATORS["eq-kf"] is EqKf and EqKf.uses_mag
    assert EqKf.ACCEL_STATES == ACCEL_STATES and {"accel_state", "cov_trace"} <= set(EqKf.DIAGNOSTICS)
    f = create("eq-kf", declination=0.1)
    f.initialize(quat.from_euler(0.1, -0.2, 0.3), np.array([0.01, -0.02, 0.003]))
    np.testing.assert_allclose(f.gyro_bias, [0.01, -0.02, 0.003])


# ---------------------------------------------------------------- accuracy on simulated truth


def test_figure8_coordinated_turns_roll_pitch_mae_below_1_deg():
    """The accelerometer of a multirotor in coordinated turns reads 'level' (thrust-aligned):
    the residual test keeps it out of the turns."""
    sim = simtruth.figure8_120()
    q, f = simtruth.run("eq-kf", sim)
    err = simtruth.errors_deg(sim, q)
    assert err[:, 0].mean() < 1.0 and err[:, 1].mean() < 1.0
    assert err[:, :2].max() < 3.0
    # the same filter without its trust weighting is pulled toward level
    q_plain, _ = simtruth.run("eq-kf", sim, EqKfParams(**NO_TRUST))
    assert simtruth.errors_deg(sim, q_plain)[:, :2].mean() > 2.0


def test_sustained_linear_acceleration_holds_attitude():
    """0.25 g for 12 s at a time, level: ‖a‖ grows by only 3-10 %, its direction turns by up
    to 25°. eq-kf stays within 1.5°; with the trust weighting off it tilts by atan(a/g)."""
    sim = simtruth.accel_110()
    q, f = simtruth.run("eq-kf", sim)
    err = simtruth.errors_deg(sim, q)
    assert err[:, 0].max() < 1.5 and err[:, 1].max() < 1.5
    # the reading was skipped while the vehicle accelerated hard (> 0.1 g); the low-passed one
    # stood in where it passed (3), mostly at the accelerations' onsets and ends
    f_b = sim.imu[0].accel
    hard = np.hypot(f_b[:, 0], f_b[:, 1]) > 0.1 * 9.80665
    assert hard.sum() > 1000 and np.mean(np.isin(f.diagnostics["accel_state"][hard], (2, 3))) > 0.95
    w = f.diagnostics["accel_weight"]
    assert np.all((w >= 0.0) & (w <= 1.0))
    assert np.all((w > 0.0) == (f.diagnostics["accel_state"] < 2))
    assert np.all((w == 1.0) == (f.diagnostics["accel_state"] == 0))
    q_plain, _ = simtruth.run("eq-kf", sim, EqKfParams(**NO_TRUST))
    assert simtruth.errors_deg(sim, q_plain)[:, 1].max() > 10.0


def test_a_confident_filter_started_off_recovers_while_still():
    """P says 0.06°, the attitude is 10° off: the residual test alone would reject the
    accelerometer for good; the stillness test lets it back in."""
    sim = simtruth.static_300()
    truth0 = quat.to_euler(sim.truth.q[0])
    q, _ = simtruth.run("eq-kf", sim, EqKfParams(init_att_sigma=1e-3),
                        q0=quat.from_euler(truth0[0] + np.radians(10.0), truth0[1], truth0[2]))
    err = simtruth.errors_deg(sim, q, after_s=0.0)
    assert err[0, 0] > 9.5
    assert err[sim.t >= sim.t[0] + 10.0, 0].max() < 0.2


def test_without_magnetometer_accelerometer_does_not_touch_heading_much():
    sim = simtruth.figure8_120()
    q, f = simtruth.run("eq-kf", sim, mag=False)
    assert not f.has_heading_reference(False)
    err = simtruth.errors_deg(sim, q)
    assert err[:, 0].mean() < 1.0 and err[:, 1].mean() < 1.0


# ---------------------------------------------------------------- model functions


def test_picard_update_is_the_exact_rotation_to_third_order():
    """Eq 5 cut after Δθ₀³: the error against q ⊗ Exp(Δθ) falls as Δθ₀⁴ (÷16 per halving)."""
    rng = np.random.default_rng(1)
    q = _random_unit_quaternions(rng, 1)[0]
    axis = rng.normal(size=3)
    axis /= np.linalg.norm(axis)
    errors = []
    for angle in [0.2, 0.1, 0.05, 0.025]:
        dtheta = axis * angle
        out = np.empty(4)
        picard_step(q, dtheta, out)
        exact = quat.multiply(q, np.r_[np.cos(angle / 2), np.sin(angle / 2) * axis])
        errors.append(np.linalg.norm(out - exact))
        # the matrix form of eq 5: [(1 - Δθ₀²/8) I + (½ - Δθ₀²/48) Ω(Δθ)] q
        m = (1 - angle ** 2 / 8) * np.eye(4) + (0.5 - angle ** 2 / 48) * quat.omega_matrix(dtheta)
        np.testing.assert_allclose(out, m @ q, atol=1e-15)
    ratios = np.array(errors[:-1]) / np.array(errors[1:])
    np.testing.assert_allclose(ratios, 16.0, rtol=0.05)
    # the leading error term is the Δθ₀⁴/384 of cos(Δθ₀/2)
    assert errors[-1] == pytest.approx(0.025 ** 4 / 384, rel=0.05)


def _jacobian_fd(fun, x0, h=1e-7):
    y0 = fun(x0)
    jac = np.empty((len(y0), len(x0)))
    for k in range(len(x0)):
        dx = np.zeros(len(x0))
        dx[k] = h
        jac[:, k] = (fun(x0 + dx) - fun(x0 - dx)) / (2 * h)
    return jac


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_error_transition_against_finite_differences(seed):
    rng = np.random.default_rng(seed)
    rate = rng.normal(0.0, 2.0, 3)  # rad/s
    dt = 0.02
    a, b = np.empty((3, 3)), np.empty((3, 3))
    error_transition(rate * dt, dt, a, b)

    def f_e(e):
        out = np.empty(3)
        error_propagate(e, np.zeros(3), rate, dt, out)
        return out

    def f_beta(beta):
        out = np.empty(3)
        error_propagate(np.zeros(3), beta, rate, dt, out)
        return out

    np.testing.assert_allclose(a, _jacobian_fd(f_e, np.zeros(3)), atol=1e-8)
    # b is -½Δt J_r(Δθ) to second order in Δθ (here ≈ 0.05 rad): its ¼Δt[Δθ]× term is 2.5 % of
    # b, what is left out ~Δθ²/12 ≈ 0.02 %
    fd = _jacobian_fd(f_beta, np.zeros(3))
    np.testing.assert_allclose(b, fd, atol=5e-4 * dt)
    assert np.abs(fd - (-0.5 * dt * np.eye(3))).max() > 20 * np.abs(fd - b).max()


@pytest.mark.parametrize("seed", [0, 1, 2, 3])
def test_accel_jacobian_against_finite_differences(seed):
    rng = np.random.default_rng(seed)
    qbar = _random_unit_quaternions(rng, 1)[0]
    h = np.empty(3)
    accel_predict(qbar, np.zeros(3), h)
    np.testing.assert_allclose(h, quat.to_dcm(qbar).T @ [0.0, 0.0, -1.0], atol=1e-14)
    t = np.empty((2, 3))
    accel_tangent(h, t)
    np.testing.assert_allclose(t @ t.T, np.eye(2), atol=1e-14)
    np.testing.assert_allclose(t @ h, 0.0, atol=1e-14)
    hm = np.empty((2, 3))
    accel_jacobian(h, t, hm)

    def fun(e):
        out = np.empty(3)
        accel_predict(qbar, e, out)
        return t @ out

    np.testing.assert_allclose(hm, _jacobian_fd(fun, np.zeros(3)), atol=1e-7)


@pytest.mark.parametrize("seed", [0, 1, 2, 3])
def test_mag_jacobian_against_finite_differences(seed):
    rng = np.random.default_rng(seed)
    qbar = _random_unit_quaternions(rng, 1)[0]
    m_b = rng.normal(size=3)
    c = quat.to_dcm(qbar)
    m_n = c @ m_b
    u = c.T @ np.r_[m_n[0], m_n[1], 0.0]  # the field's horizontal part, in the body frame
    hm = np.empty(3)
    mag_jacobian(qbar, hm)
    np.testing.assert_allclose(hm, 2.0 * c[2], atol=1e-14)

    def fun(e):
        return np.array([mag_predict(qbar, e, u)])

    assert mag_predict(qbar, np.zeros(3), u) == pytest.approx(np.arctan2(m_n[1], m_n[0]))
    np.testing.assert_allclose(hm, _jacobian_fd(fun, np.zeros(3))[0], atol=1e-7)


# ---------------------------------------------------------------- invariants and equivalence


def test_trust_stays_in_range_and_a_zero_reading_is_skipped():
    """On hostile data (``test_contract`` checks the rest): the accelerometer weight stays in
    [0, 1] and a zero reading (a sensor dropout) is never fused."""
    t, gyro, accel, mag, *_ = hostile(200_000)
    f = EqKf(declination=0.2)
    f.initialize(np.array([1.0, 0, 0, 0]), np.zeros(3))
    states = []
    for s in np.array_split(np.arange(len(t)), 5):
        f.update(t[s], gyro[s], accel[s], mag[s])
        d = f.diagnostics
        assert np.all((d["accel_weight"] >= 0) & (d["accel_weight"] <= 1))
        states.append(d["accel_state"])
    assert np.all(np.concatenate(states)[::1000][1:] == 2)

def test_params_are_floats_and_bools():
    """The CLI sets parameters as --set eq-kf.<field>=value: floats and bools only."""
    from dataclasses import fields
    for fld in fields(EqKfParams):
        assert fld.type in ("float", "bool", float, bool), fld


def _orbit_roll_error(params, in_air=None):
    sim = simtruth.flight("orbit", 120.0, seed=14, imu_rate=10.0)  # a plane's 10 Hz IMU
    q, f = simtruth.run("eq-kf", sim, params, in_air=in_air)
    return q, simtruth.errors_deg(sim, q, after_s=20.0)[:, 0], f.diagnostics["accel_weight"]


def test_turn_compensation_on_a_fixed_wing_orbit():
    """33° coordinated turns at 15 m/s: without the compensation the accelerometer is ~33° off
    gravity and gated out almost throughout; with it the accelerometer is used again."""
    n = len(simtruth.flight("orbit", 120.0, seed=14, imu_rate=10.0).t)
    q_off, err_off, w_off = _orbit_roll_error(EqKfParams())
    q_on, err_on, w_on = _orbit_roll_error(EqKfParams(airspeed=15.0), np.ones(n))
    assert w_off.mean() < 0.2 and w_on.mean() > 0.8
    assert err_on.mean() < 0.5 * err_off.mean() and err_on.mean() < 0.2
    assert err_on.max() < err_off.max()
    # unknown phase counts as air
    np.testing.assert_array_equal(_orbit_roll_error(EqKfParams(airspeed=15.0))[0], q_on)
    # on the ground, and with airspeed 0 whatever the phase: exactly the uncompensated filter
    np.testing.assert_array_equal(_orbit_roll_error(EqKfParams(airspeed=15.0), np.zeros(n))[0], q_off)
    np.testing.assert_array_equal(_orbit_roll_error(EqKfParams(), np.ones(n))[0], q_off)


def test_strict_is_the_papers_filter_whatever_the_other_parameters():
    """strict=True: the trust w = w_norm · w_rate of ALGORITHMS.md on the raw sample with the
    fixed STRICT thresholds, no bias states, and none of our additions, however they are set."""
    from mavattitude.estimators.eq_kf import STRICT
    sim = simtruth.figure8_120()
    n = len(sim.t)
    q, f = simtruth.run("eq-kf", sim, EqKfParams(strict=True))
    bias0 = f.gyro_bias
    # every addition and threshold set far from its default: nothing changes
    wild = dict(bias_walk=1e-2, int_noise=3.0, init_bias_sigma=0.1, norm_lo=0.5, norm_hi=0.9,
                rate_lo=0.01, rate_hi=0.02, gate_noise=1e-4, gate_lo=0.1, gate_hi=0.2, trust_rise=30.0,
                trust_lpf=2.0, vib_time=0.01, still_rate=1.0, still_accel=5.0, still_time=0.1, cons_tol=0.0,
                cons_norm=0.5, cons_time=0.0, airspeed=30.0)
    q_wild, f_wild = simtruth.run("eq-kf", sim, EqKfParams(strict=True, **wild), in_air=np.ones(n))
    np.testing.assert_array_equal(q_wild, q)
    np.testing.assert_array_equal(f_wild.diagnostics["accel_weight"], f.diagnostics["accel_weight"])
    # the bias is never learned
    np.testing.assert_array_equal(f.gyro_bias, bias0)
    assert np.all(f.covariance[3:, 3:] == 0.0)
    # the same as the full filter with every addition switched off by its parameters
    off = dict(bias_walk=0.0, init_bias_sigma=0.0, int_noise=0.0, gate_lo=1e300, gate_hi=2e300, trust_rise=0.0,
               trust_lpf=0.0, still_time=1e300, cons_norm=0.0, cons_time=1e300, airspeed=0.0, **STRICT)
    q_off, _ = simtruth.run("eq-kf", sim, EqKfParams(**off), accel_g=GRAVITY)  # strict keeps standard gravity
    np.testing.assert_array_equal(q_off, q)
    # the trust is exactly ramp(|‖a‖/g - 1|) · ramp(‖ω̄‖) on the raw samples
    t, gyro, accel, _ = simtruth.inputs(sim, True)

    def ramp(x, lo, hi):
        return np.clip((hi - x) / (hi - lo), 0.0, 1.0)

    rate = np.linalg.norm(0.5 * (gyro[1:] + gyro[:-1]) - bias0, axis=1)
    eps = np.abs(np.linalg.norm(accel[1:], axis=1) / 9.80665 - 1.0)
    w = ramp(eps, STRICT["norm_lo"], STRICT["norm_hi"]) * ramp(rate, STRICT["rate_lo"], STRICT["rate_hi"])
    np.testing.assert_allclose(f.diagnostics["accel_weight"][1:], w, atol=1e-9)
    assert f.diagnostics["accel_weight"][0] == 0.0  # the first sample has no Δt
    assert 0.0 < w.mean() < 1.0  # the figure-eight exercises the trust
    # and the default filter is not the strict one
    assert not np.array_equal(simtruth.run("eq-kf", sim)[0], q)
