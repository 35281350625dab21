"""eskf (body-frame error-state KF, the baseline of paper 001) on simulated truth, its
Jacobians against finite differences, its invariants and batch/live equivalence."""
from __future__ import annotations

import numpy as np
import simtruth as st

from mavattitude import quaternion as quat
from mavattitude.estimators import ESTIMATORS, align
from mavattitude.estimators.eskf import (Eskf, eskf_accel_jacobian, eskf_accel_model,
                                         eskf_error_transition, kalman_update3)


def _random_unit_quaternions(rng, n):
    return quat.normalize(rng.normal(size=(n, 4)))


def _log(q):
    """Rotation vector of a unit quaternion (shortest)."""
    q = q if q[0] >= 0 else -q
    v = np.linalg.norm(q[1:])
    return np.zeros(3) if v == 0 else q[1:] * 2.0 * np.arctan2(v, q[0]) / v


def test_registered_with_the_interface():
    """What is particular to eskf; the interface every estimator has is test_contract.py's."""
    assert ESTIMATORS["eskf"] is Eskf and not Eskf.uses_mag and set(Eskf.DIAGNOSTICS) == {"cov_trace"}


def test_accelerometer_jacobian_matches_finite_differences():
    rng = np.random.default_rng(1)
    eps = 1e-6
    for q in _random_unit_quaternions(rng, 20):
        H = eskf_accel_jacobian(q)
        fd = np.empty((3, 3))
        for k in range(3):
            d = np.zeros(3)
            d[k] = eps
            fd[:, k] = (eskf_accel_model(q, d) - eskf_accel_model(q, -d)) / (2 * eps)
        np.testing.assert_allclose(H, fd, atol=1e-7)
        # the model at δθ = 0 is C(q)ᵀ(-g_n)
        np.testing.assert_allclose(eskf_accel_model(q, np.zeros(3)),
                                   quat.to_dcm(q).T @ [0, 0, -9.80665], atol=1e-12)


def test_error_transition_matches_finite_differences():
    """F = ∂δθ⁺/∂δθ for q_true = q ⊗ Exp(δθ) propagated by the same gyro step."""
    rng = np.random.default_rng(2)
    eps = 1e-6
    for q in _random_unit_quaternions(rng, 10):
        omega, dt = rng.normal(0, 2.0, 3), 0.1  # large steps: F must be exact, not first order
        nominal = quat.integrate_gyro(q, omega, dt)

        def err_after(d):
            true = quat.integrate_gyro(quat.multiply(q, _exp(d)), omega, dt)
            return _log(quat.multiply(quat.conjugate(nominal), true))

        fd = np.column_stack([(err_after(e) - err_after(-e)) / (2 * eps) for e in np.eye(3) * eps])
        np.testing.assert_allclose(eskf_error_transition(omega, dt), fd, atol=1e-7)
        # and to first order it is I - [ω]× dt (ALGORITHMS.md)
        wx = np.array([[0, -omega[2], omega[1]], [omega[2], 0, -omega[0]], [-omega[1], omega[0], 0]])
        small = eskf_error_transition(omega, 1e-4)
        np.testing.assert_allclose(small, np.eye(3) - wx * 1e-4, atol=1e-7)


def _exp(v):
    angle = np.linalg.norm(v)
    if angle == 0:
        return np.array([1.0, 0, 0, 0])
    return np.concatenate([[np.cos(angle / 2)], np.sin(angle / 2) * v / angle])


def test_kalman_update_is_the_joseph_form():
    rng = np.random.default_rng(3)
    for _ in range(10):
        a = rng.normal(size=(3, 3))
        P = a @ a.T * 1e-3 + np.eye(3) * 1e-5
        H = rng.normal(size=(3, 3)) * 9.8
        r, R = rng.normal(size=3), 0.3
        S = H @ P @ H.T + R * np.eye(3)
        K = P @ H.T @ np.linalg.inv(S)
        A = np.eye(3) - K @ H
        P_expected = A @ P @ A.T + R * K @ K.T
        work = [np.empty((3, 3)) for _ in range(4)]
        P_out = P.copy()
        d = kalman_update3(P_out, H, r[0], r[1], r[2], R, *work)
        np.testing.assert_allclose(d, K @ r, rtol=1e-9, atol=1e-15)
        np.testing.assert_allclose(P_out, P_expected, rtol=1e-8, atol=1e-15)


def test_the_accelerometer_moves_the_heading_when_tilted():
    """The defect paper 001 fixes: on the figure-eight (tilted in turns) the body-frame filter's
    yaw leaves the gyro-only yaw; ncs-eskf's stays with it (see test_ncs_eskf)."""
    sim = st.figure8_120()
    q, _ = st.run("eskf", sim, mag=False)
    q_gyro = _gyro_only(sim)
    dyaw = np.degrees(np.abs(quat.wrap_pi(quat.to_euler(q)[:, 2] - quat.to_euler(q_gyro)[:, 2])))
    assert dyaw.max() > 10.0


def _gyro_only(sim):
    t, gyro, accel, _ = st.inputs(sim, mag=False)
    a = align(t, gyro, accel)
    out = np.empty((len(t), 4))
    q, prev = a.q0.copy(), gyro[0]
    for i in range(len(t)):
        dt = t[i] - t[i - 1] if i else 0.0
        rate = 0.5 * (gyro[i] + prev) if dt > 0 else gyro[i]
        prev = gyro[i]
        if 0 < dt <= 1.5:
            q = quat.integrate_gyro(q, rate - a.gyro_bias, dt)
        out[i] = q
    return out


