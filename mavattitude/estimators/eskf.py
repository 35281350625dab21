"""Body-frame error-state Kalman filter: the "ESKF" baseline of paper 001.

Paper 001 (He et al. 2025, §0 and Table 1) compares its navigation-frame filter (``ncs_eskf``)
against the conventional error-state KF, whose attitude error lives in the **body** frame;
restated in ../shared/ALGORITHMS.md "eskf". Each IMU sample:

- Nominal state: the attitude q, integrated from the bias-corrected gyro,
  q ← q ⊗ Exp(ω dt) (paper 001 eq 2-4 for the nominal attitude).
- Error state: δθ in the body frame, q_true = q ⊗ Exp(δθ). Its mean is zero after every
  reset; its covariance is propagated with F = ∂δθ⁺/∂δθ and the gyro noise:
  P ← F P Fᵀ + Q dt.
- Accelerometer update: h(q) = C(q)ᵀ(-g_n) (what the accelerometer reads with no
  manoeuvre), H = ∂h/∂δθ = [h]×; K = P Hᵀ (H P Hᵀ + R)⁻¹, δθ = K (a - h(q)),
  P ← (I - K H) P (I - K H)ᵀ + K R Kᵀ (Joseph form), inject q ← q ⊗ Exp(δθ), reset δθ = 0.

This is the baseline: the paper describes no manoeuvre gating for it, so it has none, and
no magnetometer (ALGORITHMS.md: accelerometer update only). Since P turns with the body
(F P Fᵀ), after rotations the gain can put part of a tilt correction on the body axis that
points along gravity, i.e. the accelerometer moves the heading when tilted: the defect the
navigation-frame filter of paper 001 removes (see ``ncs_eskf``).

Choices the paper leaves open, made here:
- F: the exact error transition for a constant rate over the step, F = Exp(-ω dt) as a
  rotation matrix (δθ⁺ = Exp(ω dt)ᵀ δθ); ALGORITHMS.md's F = I - [ω]× dt is its first-order
  truncation. The increment quaternion is at hand, so the exact form costs nothing, and at
  the 4-25 Hz of many logs the truncation is visible.
- Noise as densities, so the filter behaves the same at any IMU rate: Q dt = σ_g² dt I
  (``gyro_arw``, angle random walk, rad/s/√Hz) and R = σ_a² / dt I (``accel_noise``,
  m/s²/√Hz, turned into a per-sample variance). The time constant of the tilt correction is
  then about σ_a / (σ_g g), independent of the sample rate: ≈ 4 s with the defaults, shorter
  than ncs-eskf's 14 s because with no bias state the tilt follows a drifting gyro bias by
  bias × τ (the 300 s static case needs τ ≲ 6 s).
- No gyro-bias state (the paper's state is the three error angles): the still-period bias
  from the shared alignment is subtracted.
- Integration as in ``mahony``: exact rotation for the trapezoidal mean rate of the step;
  a step longer than ``MAX_STEP_S`` (a gap) is neither integrated nor updated.
- The reset Jacobian (I - ½[δθ]×) is taken as I, as is usual for small corrections.
- A sample with a non-finite accelerometer reading gets no update.

The small numba kernels here (quaternion products on scalars, the 3-state Kalman update)
are shared with ``ncs_eskf``.
- The accelerometer low-passed in an almost-inertial frame (``inertial_accel``,
  ``accel_tau``, 1 s; strict: the reading as it is).
  As in mahony (its numbers there). 0 -> 1 s: BROAD 0.87° -> 0.62° (worst 7.3× -> 1.6× VQF),
  SITL 2.30° -> 2.24°; a cost against the autopilot: corpus median 1.11° -> 1.25° (DCM logs 1.43° ->
  1.38°, BlueROV logs +0.3°). Kept: the truth (BROAD, SITL) says gain.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import NamedTuple

import numpy as np

from ..flight import GRAVITY
from ..kernel_cache import kernel
from ..paramspec import param
from ..quaternion import (
    cross_matrix_into,
    dcm_transposed_into,
    exp_s,
    gravity_in_body_s,
    normalize_into,
    qmul_s,
)
from .base import MAX_STEP_S, Estimator, filter_state, run_with_trace
from .inertial_accel import lowpass_in_inertial_frame
from .timestep import integrates, step_dt, step_rate


@dataclass
class EskfParams:
    gyro_arw: float = param(1e-3, "(0, 1e3]", "log [1e-5, 0.1]")  # gyro rate noise density (angle random walk), rad/s/√Hz
    accel_noise: float = param(0.04, "[1e-6, 1e6]", "log [1e-3, 2]")  # accelerometer noise density, m/s²/√Hz
    p0_deg: float = param(2.0, "[0, 180]")  # initial 1σ of each attitude error angle, degrees
    accel_tau: float = param(1.0, "[0, 60]", "linear [0, 5]")  # s: the accelerometer low-passed in an almost-inertial frame (inertial_accel); 0: the reading as it is
    strict: bool = param(False)  # the filter as published: accel_tau = 0, whatever it says


# ---------------------------------------------------------------- shared scalar kernels
# Scalars in, tuples out: no heap allocation in the per-sample loops.


@kernel(inline="always")
def set_q(q, w, x, y, z):
    """q[:] = [w, x, y, z], not normalised: the loops normalise once per sample, after the
    last product (the products of unit quaternions in between stay unit to rounding)."""
    q[0], q[1], q[2], q[3] = w, x, y, z


@kernel
def kalman_update3(P, H, r0, r1, r2, R, PHt, K, A, T):
    """Kalman update of a 3-state error with a 3-vector measurement, in place.

    ``H`` (3x3) the measurement Jacobian, (r0, r1, r2) the residual, ``R`` the per-axis
    measurement variance (R I). K = P Hᵀ S⁻¹ with S = H P Hᵀ + R I; returns δθ = K r;
    P ← (I - K H) P (I - K H)ᵀ + R K Kᵀ (Joseph form), symmetrised. ``PHt``, ``K``, ``A``,
    ``T`` are 3x3 scratch arrays.
    """
    for i in range(3):
        for j in range(3):
            PHt[i, j] = P[i, 0] * H[j, 0] + P[i, 1] * H[j, 1] + P[i, 2] * H[j, 2]
    # S = H P Hᵀ + R I, symmetric: six distinct entries
    s00 = H[0, 0] * PHt[0, 0] + H[0, 1] * PHt[1, 0] + H[0, 2] * PHt[2, 0] + R
    s01 = H[0, 0] * PHt[0, 1] + H[0, 1] * PHt[1, 1] + H[0, 2] * PHt[2, 1]
    s02 = H[0, 0] * PHt[0, 2] + H[0, 1] * PHt[1, 2] + H[0, 2] * PHt[2, 2]
    s11 = H[1, 0] * PHt[0, 1] + H[1, 1] * PHt[1, 1] + H[1, 2] * PHt[2, 1] + R
    s12 = H[1, 0] * PHt[0, 2] + H[1, 1] * PHt[1, 2] + H[1, 2] * PHt[2, 2]
    s22 = H[2, 0] * PHt[0, 2] + H[2, 1] * PHt[1, 2] + H[2, 2] * PHt[2, 2] + R
    # S⁻¹ by the adjugate
    c00 = s11 * s22 - s12 * s12
    c01 = s02 * s12 - s01 * s22
    c02 = s01 * s12 - s02 * s11
    c11 = s00 * s22 - s02 * s02
    c12 = s01 * s02 - s00 * s12
    c22 = s00 * s11 - s01 * s01
    inv_det = 1.0 / (s00 * c00 + s01 * c01 + s02 * c02)
    i00, i01, i02 = c00 * inv_det, c01 * inv_det, c02 * inv_det
    i11, i12, i22 = c11 * inv_det, c12 * inv_det, c22 * inv_det
    for i in range(3):
        a, b, c = PHt[i, 0], PHt[i, 1], PHt[i, 2]
        K[i, 0] = a * i00 + b * i01 + c * i02
        K[i, 1] = a * i01 + b * i11 + c * i12
        K[i, 2] = a * i02 + b * i12 + c * i22
    d0 = K[0, 0] * r0 + K[0, 1] * r1 + K[0, 2] * r2
    d1 = K[1, 0] * r0 + K[1, 1] * r1 + K[1, 2] * r2
    d2 = K[2, 0] * r0 + K[2, 1] * r1 + K[2, 2] * r2
    for i in range(3):
        for j in range(3):
            A[i, j] = (1.0 if i == j else 0.0) - (K[i, 0] * H[0, j] + K[i, 1] * H[1, j]
                                                  + K[i, 2] * H[2, j])
    for i in range(3):
        for j in range(3):
            T[i, j] = A[i, 0] * P[0, j] + A[i, 1] * P[1, j] + A[i, 2] * P[2, j]
    for i in range(3):
        for j in range(i, 3):
            v = (T[i, 0] * A[j, 0] + T[i, 1] * A[j, 1] + T[i, 2] * A[j, 2]
                 + R * (K[i, 0] * K[j, 0] + K[i, 1] * K[j, 1] + K[i, 2] * K[j, 2]))
            P[i, j] = v
            P[j, i] = v
    return d0, d1, d2


# ---------------------------------------------------------------- models (for the tests too)


@kernel
def eskf_accel_model(q, dtheta):
    """What the accelerometer reads with no manoeuvre at attitude q ⊗ Exp(δθ):
    C(q ⊗ Exp(δθ))ᵀ (-g_n), m/s². ``eskf_accel_jacobian`` is its derivative at δθ = 0."""
    e0, e1, e2, e3 = exp_s(dtheta[0], dtheta[1], dtheta[2])
    w, x, y, z = qmul_s(q[0], q[1], q[2], q[3], e0, e1, e2, e3)
    out = np.empty(3)
    out[0], out[1], out[2] = gravity_in_body_s(w, x, y, z, GRAVITY)
    return out


@kernel
def eskf_accel_jacobian(q):
    """H = ∂h/∂δθ = [h]× with h = C(q)ᵀ(-g_n), the body-frame error convention q ⊗ Exp(δθ)."""
    h = eskf_accel_model(q, np.zeros(3))
    H = np.empty((3, 3))
    cross_matrix_into(h[0], h[1], h[2], H)
    return H


@kernel
def eskf_error_transition(omega, dt):
    """F = ∂δθ⁺/∂δθ over one step at body rate ω: Exp(ω dt)ᵀ as a rotation matrix."""
    F = np.empty((3, 3))
    d0, d1, d2, d3 = exp_s(omega[0] * dt, omega[1] * dt, omega[2] * dt)
    dcm_transposed_into(d0, d1, d2, d3, F)
    return F


# ---------------------------------------------------------------- the filter


class EskfSettings(NamedTuple):
    """The parameters as the kernel takes them (see ``EskfParams``)."""
    arw2: float  # gyro noise density², (rad/s)²/Hz
    acc2: float  # accelerometer noise density², (m/s²)²/Hz
    gravity: float  # m/s²
    max_step: float  # s


@kernel
def eskf_run(s, state, cfg, out, cov_trace):
    """Run the body-frame ESKF over a chunk of samples ``s`` (``base.Samples``); ``state``
    (``base.FilterState``) is updated in place; its ``bias`` is subtracted from the gyro.
    Writes the attitude after each sample to ``out`` and trace(P) to ``cov_trace``."""
    t, gyro, accel = s.t, s.gyro, s.accel
    over_step = s.rate_over_step  # each gyro sample the mean over its step (timestep.step_rate)
    q, P, t_prev, gyro_prev, bias = state.q, state.P, state.t_prev, state.gyro_prev, state.bias
    arw2, acc2, gravity, max_step = cfg.arw2, cfg.acc2, cfg.gravity, cfg.max_step
    F = np.empty((3, 3))
    H = np.empty((3, 3))
    PHt = np.empty((3, 3))
    K = np.empty((3, 3))
    A = np.empty((3, 3))
    T = np.empty((3, 3))
    for i in range(len(t)):
        dt = step_dt(t[i], t_prev[0])
        t_prev[0] = t[i]
        g0, g1, g2 = gyro[i, 0], gyro[i, 1], gyro[i, 2]
        w0, w1, w2 = step_rate(g0, g1, g2, gyro_prev[0], gyro_prev[1], gyro_prev[2], dt, over_step)
        gyro_prev[0], gyro_prev[1], gyro_prev[2] = g0, g1, g2
        if integrates(dt, max_step):
            w0, w1, w2 = w0 - bias[0], w1 - bias[1], w2 - bias[2]
            # predict: nominal q ⊗ Exp(ω dt); error F P Fᵀ + Q dt with F = Exp(ω dt)ᵀ
            d0, d1, d2, d3 = exp_s(w0 * dt, w1 * dt, w2 * dt)
            a0, a1, a2, a3 = qmul_s(q[0], q[1], q[2], q[3], d0, d1, d2, d3)
            set_q(q, a0, a1, a2, a3)
            dcm_transposed_into(d0, d1, d2, d3, F)
            for r in range(3):
                for c in range(3):
                    T[r, c] = F[r, 0] * P[0, c] + F[r, 1] * P[1, c] + F[r, 2] * P[2, c]
            qd = arw2 * dt
            for r in range(3):
                for c in range(r, 3):
                    v = T[r, 0] * F[c, 0] + T[r, 1] * F[c, 1] + T[r, 2] * F[c, 2]
                    if r == c:
                        v += qd
                    P[r, c] = v
                    P[c, r] = v
            ax, ay, az = accel[i, 0], accel[i, 1], accel[i, 2]
            if math.isfinite(ax) and math.isfinite(ay) and math.isfinite(az):
                w, x, y, z = q[0], q[1], q[2], q[3]
                h0 = -gravity * 2.0 * (x * z - w * y)
                h1 = -gravity * 2.0 * (y * z + w * x)
                h2 = -gravity * (1.0 - 2.0 * (x * x + y * y))
                cross_matrix_into(h0, h1, h2, H)
                e0, e1, e2 = kalman_update3(P, H, ax - h0, ay - h1, az - h2, acc2 / dt,
                                            PHt, K, A, T)
                b0, b1, b2, b3 = exp_s(e0, e1, e2)
                a0, a1, a2, a3 = qmul_s(w, x, y, z, b0, b1, b2, b3)  # inject on the right
                set_q(q, a0, a1, a2, a3)
            normalize_into(q, q[0], q[1], q[2], q[3])
        out[i, 0], out[i, 1], out[i, 2], out[i, 3] = q[0], q[1], q[2], q[3]
        cov_trace[i] = P[0, 0] + P[1, 1] + P[2, 2]
    return out


class Eskf(Estimator):
    """Body-frame error-state KF, the baseline of paper 001; see the module docstring."""
    name = "eskf"
    Params = EskfParams
    kernels = (lowpass_in_inertial_frame, eskf_run)
    color = (120, 15, 255)
    compile_seconds = 2.5  # CPU s, one core (scripts/compile_profile.py)
    PAPER = dict(accel_tau=0.0)  # strict: the accelerometer as it reads
    DIAGNOSTICS = {"cov_trace": "trace of the attitude-error covariance P, rad²"}

    def initialize(self, q0, gyro_bias, accel_g: float = GRAVITY) -> None:
        p = self.params
        self._state = filter_state(q0, np.eye(3) * np.radians(p.p0_deg) ** 2, gyro_bias)
        self._settings = EskfSettings(
            arw2=p.gyro_arw ** 2, acc2=p.accel_noise ** 2, gravity=GRAVITY, max_step=MAX_STEP_S)
        self._ready(q0, gyro_bias)

    def _run(self, s, out, aiding) -> dict:
        return run_with_trace(eskf_run, s, self._state, self._settings, out)
