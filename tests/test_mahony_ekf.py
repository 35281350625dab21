"""mahony-ekf (paper 000) on simulated truth: the paper's dynamic claim (its static claim, §3.1,
and the convergence from 30° off are in test_contract.py's tables), the internal Mahony filter
against mahony, the predict/update against their matrix form, the Jacobians against finite
differences, invariants and batch/live equivalence."""
from __future__ import annotations

from dataclasses import fields

import numpy as np
import simtruth as st

from mavattitude import quaternion as quat
from mavattitude.estimators import ESTIMATORS, align, create
from mavattitude.estimators.mahony import MahonyParams
from mavattitude.estimators.mahony_ekf import (MahonyEkf, MahonyEkfParams, predict,
                                               quaternion_update)
from mavattitude.flight import GRAVITY
from mavattitude.core.params import build


def _xi(q):
    """Ξ(q) of ALGORITHMS.md: q̇ = ½ Ξ(q) ω."""
    w, x, y, z = q
    return np.array([[-x, -y, -z], [w, -z, y], [z, w, -x], [-y, x, w]])


def _random_covariance(rng, n=4, scale=1e-3):
    a = rng.normal(size=(n, n))
    return a @ a.T * scale + np.eye(n) * 1e-6


# ---------------------------------------------------------------- interface


def test_registered_with_its_parameters_and_diagnostics():
    """What is particular to mahony-ekf; the interface every estimator has is test_contract.py's."""
    assert ESTIMATORS["mahony-ekf"] is MahonyEkf and MahonyEkf.uses_mag
    p = MahonyEkfParams()
    assert (p.q_gyro, p.r0) == (1e-2, 1e-4)  # paper 000 eq 12 and 17
    names = {f.name for f in fields(MahonyEkfParams)}
    assert {"kp", "ki", "use_mag", "k_accel", "k_mahony"} <= names
    params = build(["mahony-ekf"], None, ["mahony-ekf.k_accel=50", "mahony-ekf.use_mag=false"])
    assert params["mahony-ekf"].k_accel == 50 and params["mahony-ekf"].use_mag is False
    assert set(MahonyEkf.DIAGNOSTICS) == {"cov_trace", "adaptive_r", "mahony_weight"}


# ---------------------------------------------------------------- accuracy on simulated truth


def test_figure8_coordinated_turns_roll_pitch_mae_below_1_deg():
    """Paper 000 §3.2: dynamic error within 1°. Thrust-aligned turns read 'level' on the
    accelerometer: mahony is pulled several degrees; weighted by ‖a‖, the internal Mahony
    keeps to the gyro in the turns and the EKF coasts on the gyro while R is large."""
    sim = st.figure8_120()
    q, f = st.run("mahony-ekf", sim)
    err = st.errors_deg(sim, q)
    assert err[:, 0].mean() < 1.0 and err[:, 1].mean() < 1.0
    q_m, _ = st.run("mahony", sim)
    assert err[:, :2].mean() < st.errors_deg(sim, q_m)[:, :2].mean() / 3
    w = f.diagnostics["mahony_weight"]
    assert ((0.0 < w) & (w <= 1.0)).all()
    assert np.mean(w < 0.2) > 0.3  # most of the turning is weighted out


def test_unweighted_mahony_measurement_fails_the_dynamic_claim():
    """Why the Mahony weight is there (module docstring): with the paper's unweighted Mahony
    filter as the measurement, R's adaptation alone leaves the figure-eight off by degrees."""
    sim = st.figure8_120()
    q, _ = st.run("mahony-ekf", sim, MahonyEkfParams(k_mahony=0.0))
    err = st.errors_deg(sim, q)
    assert err[:, :2].mean() > 1.5


def test_sustained_acceleration_is_mostly_rejected():
    sim = st.accel_110()
    q, _ = st.run("mahony-ekf", sim)
    err = st.errors_deg(sim, q)
    q_m, _ = st.run("mahony", sim)
    assert err[:, :2].max() < st.errors_deg(sim, q_m)[:, :2].max() / 2


def test_strict_is_the_papers_unweighted_mahony_ekf():
    """strict=True: paper 000 as published, the internal Mahony unweighted (mahony's numbers at
    the same gains), none of the additions (Mahony weight, rest, coasting limit, integral
    gating); it equals k_mahony=0, whatever the additions' parameters say."""
    sim = st.figure8_120()
    t, gyro, accel, mag = st.inputs(sim)
    a = align(t, gyro, accel, mag, sim.declination_rad)
    f = MahonyEkf(MahonyEkfParams(strict=True, lock_s=5.0, ki_step=0.001, rest_gyro=1.0), sim.declination_rad)
    f.keep_mahony = True
    f.initialize(a.q0, a.gyro_bias)
    q = f.update(t, gyro, accel, mag)
    m = create("mahony", MahonyParams(kp=f.params.kp, ki=f.params.ki, strict=True), sim.declination_rad)
    m.initialize(a.q0, a.gyro_bias)
    np.testing.assert_allclose(f.mahony_q, m.update(t, gyro, accel, mag), rtol=0, atol=1e-12)
    assert (f.diagnostics["mahony_weight"] == 1.0).all()
    q0, _ = st.run("mahony-ekf", sim, MahonyEkfParams(k_mahony=0.0, accel_tau=0.0), accel_g=GRAVITY)  # strict: standard g
    np.testing.assert_array_equal(q, q0)
    params = build(["mahony-ekf"], None, ["mahony-ekf.strict=true"])
    assert params["mahony-ekf"].strict is True


def test_additions_off_give_the_issue_3_filter():
    """rest_gyro=0, lock_s=0, ki_step=0 turn the issue-10 additions off: the weight is
    1/(1 + k_mahony |ā - ā_ref|) alone again, and it weighs out the figure-eight's turns."""
    sim = st.figure8_120()
    q, f = st.run("mahony-ekf", sim, MahonyEkfParams(rest_gyro=0.0, lock_s=0.0, ki_step=0.0))
    err = st.errors_deg(sim, q)
    assert err[:, 0].mean() < 1.0 and err[:, 1].mean() < 1.0
    assert np.mean(f.diagnostics["mahony_weight"] < 0.2) > 0.8


def test_rest_trusts_the_accelerometer_again_after_a_long_lockout():
    """Linear acceleration with the gyro quiet is not rest (ā moved from its value at rest):
    the accelerometer stays weighted out; once back at rest the weight returns to 1."""
    sim = st.accel_110()
    q, f = st.run("mahony-ekf", sim, MahonyEkfParams(accel_tau=0.0))  # the rest test on the reading itself
    w = f.diagnostics["mahony_weight"]
    dev = np.abs(np.linalg.norm(sim.imu[0].accel, axis=1) - GRAVITY)
    assert np.mean(w[dev > 0.2] < 0.2) > 0.8  # the accelerating runs are weighted out
    t = sim.t - sim.t[0]
    for a in (20.0, 90.0):  # at rest between the runs (after 15 s and 80 s of lockout)
        assert (w[(t >= a) & (t < a + 5.0)] == 1.0).all()
    q_off, _ = st.run("mahony-ekf", sim, MahonyEkfParams(rest_gyro=0.0, accel_tau=0.0))
    assert st.errors_deg(sim, q)[:, :2].mean() < st.errors_deg(sim, q_off)[:, :2].mean()


def test_coasting_limit_scales_with_the_imu_rate_squared():
    """A sustained lockout (the figure-eight's turns) may last lock_s at 100 Hz and
    lock_s (f / 100 Hz)² at f: at 25 Hz the weight rises well above its 100 Hz level."""
    lows = []
    for rate in (100.0, 25.0):
        sim = st.flight("figure8", 120.0, seed=12, imu_rate=rate)
        _, f = st.run("mahony-ekf", sim, MahonyEkfParams(rest_gyro=0.0))
        w = f.diagnostics["mahony_weight"]
        lows.append(np.median(w[sim.t > sim.t[0] + 60.0]))
    assert lows[1] > 2 * lows[0]


# ---------------------------------------------------------------- the model


def test_internal_mahony_is_mahony():
    """Unweighted, the Mahony filter inside gives mahony's numbers with the same gains."""
    sim = st.figure8_120()
    t, gyro, accel, mag = st.inputs(sim)
    a = align(t, gyro, accel, mag, sim.declination_rad)
    gains = MahonyParams(kp=0.3, ki=0.002)
    f = MahonyEkf(MahonyEkfParams(kp=gains.kp, ki=gains.ki, k_mahony=0.0), sim.declination_rad)
    f.keep_mahony = True
    f.initialize(a.q0, a.gyro_bias)
    f.update(t, gyro, accel, mag)
    m = create("mahony", gains, sim.declination_rad)
    m.initialize(a.q0, a.gyro_bias)
    np.testing.assert_allclose(f.mahony_q, m.update(t, gyro, accel, mag), rtol=0, atol=1e-12)


def test_adaptive_r_is_eq_17():
    sim = st.figure8_120()
    t, gyro, accel, mag = st.inputs(sim)
    p = MahonyEkfParams(k_accel=37.0, r0=2e-4, accel_tau=0.0)  # eq 17 on the reading itself
    _, f = st.run("mahony-ekf", sim, p)
    g = align(t, gyro, accel, mag, sim.declination_rad).accel_g  # the reading at the still start, not GRAVITY
    assert abs(g - GRAVITY) > 0.01
    expected = p.r0 * (1 + p.k_accel * np.abs(np.linalg.norm(accel, axis=1) - g))
    np.testing.assert_allclose(f.diagnostics["adaptive_r"], expected, rtol=1e-12)


def test_predict_is_phi_p_phi_t_plus_g_q_g_t():
    rng = np.random.default_rng(1)
    for _ in range(20):
        q = rng.normal(size=4)
        P = _random_covariance(rng)
        w, dt, qg = rng.normal(size=3), rng.uniform(1e-3, 0.1), rng.uniform(1e-3, 1.0)
        phi = np.eye(4) + 0.5 * dt * quat.omega_matrix(w)  # eq 14
        G = 0.5 * dt * _xi(q)  # eq 15, with the ½ of eq 11
        x, P2 = q.copy(), P.copy()
        predict(x, P2, w[0], w[1], w[2], dt, qg)
        np.testing.assert_allclose(x, phi @ q, rtol=1e-14, atol=1e-15)
        np.testing.assert_allclose(P2, phi @ P @ phi.T + G @ (qg * np.eye(3)) @ G.T, rtol=1e-12, atol=1e-16)


def test_transition_and_noise_jacobians_against_finite_differences():
    """X_{k+1} = X + (T/2) Ω(ω̂ + δ) X (eq 9-11): ∂/∂X = Φ (eq 14), ∂/∂δ = (T/2) Ξ(X), the
    paper's eq 15 up to its missing ½ and sign."""
    rng = np.random.default_rng(2)
    eps = 1e-6
    for _ in range(10):
        q, w, dt = rng.normal(size=4), rng.normal(size=3), rng.uniform(1e-3, 0.1)

        def f(x, d):
            return x + 0.5 * dt * quat.omega_matrix(w + d) @ x

        fd_x = np.column_stack([(f(q + eps * e, 0) - f(q - eps * e, 0)) / (2 * eps) for e in np.eye(4)])
        fd_d = np.column_stack([(f(q, eps * e) - f(q, -eps * e)) / (2 * eps) for e in np.eye(3)])
        np.testing.assert_allclose(fd_x, np.eye(4) + 0.5 * dt * quat.omega_matrix(w), atol=1e-9)
        np.testing.assert_allclose(fd_d, 0.5 * dt * _xi(q), atol=1e-9)
        # Ξ is also the integration's noise direction: q ⊗ [0, δ] = Ξ(q) δ
        d = rng.normal(size=3)
        np.testing.assert_allclose(quat.multiply(q, np.r_[0.0, d]), _xi(q) @ d, atol=1e-12)


def test_update_is_the_joseph_form_with_h_identity():
    rng = np.random.default_rng(3)
    for _ in range(20):
        x = quat.normalize(rng.normal(size=4))
        z = quat.normalize(x + rng.normal(scale=0.05, size=4))
        P = _random_covariance(rng, scale=rng.choice([1e-6, 1e-3, 1.0]))
        r = rng.choice([1e-4, 1e-2, 1.0])
        R = r * np.eye(4)
        K = P @ np.linalg.inv(P + R)  # eq 20, H = I
        A = np.eye(4) - K
        x2, P2 = x.copy(), P.copy()
        quaternion_update(x2, P2, z[0], z[1], z[2], z[3], r)
        np.testing.assert_allclose(x2, x + K @ (z - x), rtol=0, atol=1e-14)  # eq 21
        np.testing.assert_allclose(P2, A @ P @ A.T + K @ R @ K.T, rtol=1e-9, atol=1e-18)  # eq 22
        np.testing.assert_array_equal(P2, P2.T)


def test_measurement_sign_follows_the_state():
    """q and -q are one attitude: a Mahony quaternion in the other hemisphere is flipped, not
    averaged through zero."""
    sim = st.figure8_120()
    t, gyro, accel, mag = st.inputs(sim)
    a = align(t, gyro, accel, mag, sim.declination_rad)
    runs = []
    for flip in (False, True):
        f = MahonyEkf(declination=sim.declination_rad)
        f.initialize(a.q0, a.gyro_bias)
        if flip:
            f._state.qm[:] *= -1.0
        runs.append(f.update(t, gyro, accel, mag))
    np.testing.assert_array_equal(runs[0], runs[1])


# ---------------------------------------------------------------- invariants and interface


