"""ekf (the conventional quaternion EKF baseline) on simulated truth; the same model in
filterpy's ExtendedKalmanFilter to 1e-9; Jacobians against finite differences; invariants
and batch/live equivalence."""
from __future__ import annotations

import numpy as np
import pytest
import simtruth as st
from test_contract import hostile
from filterpy.kalman import ExtendedKalmanFilter

from mavattitude import quaternion as quat
from mavattitude.estimators import ESTIMATORS, align
from mavattitude.estimators.ekf import (Ekf, EkfParams, accel_model, heading_model, level_field,
                                        transition)
from mavattitude.core.params import build


def _xi(q):
    w, x, y, z = q
    return np.array([[-x, -y, -z], [w, -z, y], [z, w, -x], [-y, x, w]])


def _exp(v):
    angle = np.linalg.norm(v)
    if angle == 0:
        return np.array([1.0, 0, 0, 0])
    return np.concatenate([[np.cos(angle / 2)], np.sin(angle / 2) * v / angle])


def _accel_h(q):
    h, H = np.empty(3), np.empty((3, 4))
    accel_model(q, h, H)
    return h, H


def _heading_h(q, v):
    H = np.empty((1, 4))
    return heading_model(q, v, H), H


def _fd(f, q, eps=1e-7):
    return np.column_stack([(f(q + eps * e) - f(q - eps * e)) / (2 * eps) for e in np.eye(4)])


# ---------------------------------------------------------------- interface


def test_registered_with_its_parameters():
    """What is particular to ekf; the interface every estimator has is test_contract.py's."""
    assert ESTIMATORS["ekf"] is Ekf and Ekf.uses_mag
    assert EkfParams().q_gyro == 1e-2  # paper 000's Q
    assert build(["ekf"], None, ["ekf.r_accel=0.1"])["ekf"].r_accel == 0.1
    assert set(Ekf.DIAGNOSTICS) == {"cov_trace"}


# ---------------------------------------------------------------- accuracy on simulated truth


def test_sustained_acceleration_tilts_it():
    """The contrast of the issue: the plain EKF takes the apparent gravity of a 0.25 g
    acceleration for the vertical and tilts by degrees, where ncs-eskf and eq-kf hold 1.5°."""
    sim = st.accel_110()
    q, _ = st.run("ekf", sim)
    assert st.errors_deg(sim, q)[:, :2].max() > 1.5


# ---------------------------------------------------------------- the model


def test_measurement_models_follow_the_conventions():
    rng = np.random.default_rng(1)
    for _ in range(20):
        q = rng.normal(size=4)  # not normalised: the models use the direction only
        qn = quat.normalize(q)
        h, _ = _accel_h(q)
        np.testing.assert_allclose(h, quat.to_dcm(qn).T @ [0, 0, -1], atol=1e-14)
        v = rng.normal(size=3)
        u = quat.rotate(qn, v)
        hm, _ = _heading_h(q, v)
        assert hm == pytest.approx(np.arctan2(u[1], u[0]), abs=1e-12)
        # levelled field: no component along the attitude's vertical
        m = rng.normal(size=3)
        lv = np.array(level_field(q, *m))
        assert quat.rotate(qn, lv)[2] == pytest.approx(0.0, abs=1e-12)


def test_jacobians_against_finite_differences():
    rng = np.random.default_rng(2)
    for _ in range(20):
        q = rng.normal(size=4)
        _, H = _accel_h(q)
        np.testing.assert_allclose(H, _fd(lambda p: _accel_h(p)[0], q), atol=1e-6)
        v = rng.normal(size=3)
        _, Hm = _heading_h(q, v)
        np.testing.assert_allclose(Hm[0], _fd(lambda p: np.array([_heading_h(p, v)[0]]), q)[0], atol=1e-6)
        w, dt = rng.normal(size=3), rng.uniform(1e-3, 0.1)
        F = transition(w, dt, np.empty((4, 4)))
        np.testing.assert_allclose(F, _fd(lambda p: p + 0.5 * dt * quat.omega_matrix(w) @ p, q), atol=1e-8)
        np.testing.assert_allclose(
            0.5 * dt * _xi(q),
            np.column_stack([(0.5 * dt * quat.omega_matrix(w + 1e-7 * e) @ q
                              - 0.5 * dt * quat.omega_matrix(w - 1e-7 * e) @ q) / 2e-7 for e in np.eye(3)]),
            atol=1e-8)


def test_heading_jacobian_at_the_estimate_is_a_rotation_about_down():
    """With the field levelled by the attitude itself, the heading measurement responds to a
    rotation about NED z one for one and not at all to tilt: the compass does not pull roll
    and pitch (ZYX yaw as the measured function would, by tan θ)."""
    rng = np.random.default_rng(3)
    for _ in range(20):
        q = quat.from_euler(*rng.uniform(-0.8, 0.8, 3))
        v = np.array(level_field(q, *rng.normal(size=3)))
        _, H = _heading_h(q, v)
        for axis, expected in ((0, 0.0), (1, 0.0), (2, 1.0)):
            # d/dε of h(Exp(ε e_axis) ⊗ q): rotation about the navigation axis
            dq = 0.5 * quat.multiply(np.r_[0.0, np.eye(3)[axis]], q)
            assert H[0] @ dq == pytest.approx(expected, abs=1e-12)


def _filterpy_reference(t, gyro, accel, mag, q0, bias, p, declination):
    """The same model stepped by filterpy: F, Q = G Q Gᵀ, h, H, R, the Joseph update
    (filterpy's), and the same normalisation step X ← X/|X|, P ← J P Jᵀ."""
    ekf = ExtendedKalmanFilter(dim_x=4, dim_z=3)
    ekf.x = q0 / np.linalg.norm(q0)
    ekf.P = np.eye(4)
    xs, Ps = [], []
    for i in range(len(t)):
        if i > 0:
            dt = t[i] - t[i - 1]
            w = 0.5 * (gyro[i] + gyro[i - 1]) - bias
            G = 0.5 * dt * _xi(ekf.x)
            ekf.F = np.eye(4) + 0.5 * dt * quat.omega_matrix(w)
            ekf.Q = G @ (p.q_gyro * np.eye(3)) @ G.T
            ekf.predict()
            ekf.update(accel[i] / np.linalg.norm(accel[i]), lambda x: _accel_h(x)[1],
                       lambda x: _accel_h(x)[0], R=p.r_accel * np.eye(3))
            if not np.isnan(mag[i, 0]):
                d = quat.to_dcm(quat.normalize(ekf.x))[2]  # NED down in the body frame
                v = mag[i] - (mag[i] @ d) * d
                ekf.update(np.array([declination]), lambda x: _heading_h(x, v)[1],
                           lambda x: np.array([_heading_h(x, v)[0]]), R=np.array([[p.r_mag]]),
                           residual=lambda a, b: quat.wrap_pi(a - b))
            n = np.linalg.norm(ekf.x)
            qn = ekf.x / n
            J = (np.eye(4) - np.outer(qn, qn)) / n
            ekf.x = qn
            ekf.P = J @ ekf.P @ J.T
            ekf.P = 0.5 * (ekf.P + ekf.P.T)
        xs.append(ekf.x.copy())
        Ps.append(ekf.P.copy())
    return np.array(xs), np.array(Ps)


def test_matches_filterpy_extended_kalman_filter_to_1e_9():
    sim = st.figure8_120()
    t, gyro, accel, mag = st.inputs(sim)
    a = align(t, gyro, accel, mag, sim.declination_rad)
    s = slice(np.searchsorted(t, sim.still_until + 20.0), None)  # in the turns, moving
    t, gyro, accel, mag = t[s][:400], gyro[s][:400], accel[s][:400], mag[s][:400]
    assert np.sum(~np.isnan(mag[:, 0])) >= 30  # a compass update every 10th sample
    p = EkfParams(r_accel=0.05, r_mag=0.02, accel_tau=0.0)  # filterpy gets the reading as it is
    q0 = quat.multiply(a.q0, _exp(np.radians([3.0, -2.0, 10.0])))  # start off, so the updates work
    f = Ekf(p, declination=sim.declination_rad)
    f.initialize(q0, a.gyro_bias)
    xs, Ps = [], []
    for i in range(len(t)):  # one sample at a time (== one batch, tested below) to see P
        xs.append(f.update(t[i:i + 1], gyro[i:i + 1], accel[i:i + 1], mag[i:i + 1])[0])
        Ps.append(f.covariance)
    ref_x, ref_P = _filterpy_reference(t, gyro, accel, mag, q0, a.gyro_bias, p, sim.declination_rad)
    np.testing.assert_allclose(np.array(xs), ref_x, rtol=0, atol=1e-9)
    scale = np.abs(ref_P).max(axis=(1, 2))[:, None, None]  # P falls from 1 to ~1e-5
    assert (np.abs(np.array(Ps) - ref_P) <= 1e-9 * scale).all()
    assert np.abs(ref_x[-1] - ref_x[0]).max() > 0.1  # it went somewhere


# ---------------------------------------------------------------- invariants and interface


def test_the_covariance_has_nothing_along_the_quaternion():
    """The normalised quaternion's covariance is projected: rank 3, nothing along q itself
    (what ``test_contract`` checks for every filter is not repeated here)."""
    t, gyro, accel, mag, *_ = hostile(100_000)
    f = Ekf(EkfParams(r_accel=0.01, r_mag=1e-3), declination=0.2)
    f.initialize(np.array([1.0, 0, 0, 0]), np.zeros(3))
    for s in np.array_split(np.arange(len(t)), 5):
        x = f.update(t[s], gyro[s], accel[s], mag[s])[-1]
        np.testing.assert_allclose(f.covariance @ x, 0.0, atol=1e-12)

