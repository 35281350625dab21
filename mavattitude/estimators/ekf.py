"""Conventional quaternion EKF: the baseline of papers 000 and 001.

Restated in ../shared/ALGORITHMS.md "ekf". State X = q (4), covariance P (4×4). Each IMU sample:

1. Predict as paper 000 eq 13-15, 18-19 (the same step as ``mahony-ekf``): with the
   bias-corrected rate ω̂ (gyro minus the still-period bias, paper 000 §2.2),
   Φ = I + (T/2) Ω(ω̂),  X⁻ = Φ X,  P⁻ = Φ P Φᵀ + G Q Gᵀ,  G = (T/2) Ξ(X),
   Ξ(q) = [[-x,-y,-z],[w,-z,y],[z,w,-x],[-y,x,w]],  Q = q_gyro I₃.
   Paper 000 prints G (eq 15) without the ½ and with the opposite sign; the ½ belongs there
   (eq 11), the sign cancels in G Q Gᵀ. As Ξ Ξᵀ = |q|² I - q qᵀ,
   G Q Gᵀ = q_gyro (T/2)² (|q|² I - q qᵀ).
2. Accelerometer update: z = a / ‖a‖ against the reading the attitude predicts,
   h_a(q) = C(q̂)ᵀ [0, 0, -1] (q̂ = q / |q|), R = r_accel I₃. Without the normalisation,
       h_a(q) = -[2(xz - wy), 2(yz + wx), w² - x² - y² + z²] / |q|²,
   with Jacobian H_a = (H₀ - 2 h_a qᵀ) / |q|²,  H₀ = -2 [[-y, z, -w, x], [x, w, z, y], [w, -x, -y, z]]
   (columns w, x, y, z).
3. Magnetometer update (a fresh field sample and ``use_mag``): the heading, as a scalar.
   Choice: level the measured field with the attitude after step 2, v = m - (m·d) d with
   d = C(q̂)ᵀ [0, 0, 1] (its component along the estimated vertical removed), and measure the
   azimuth of that levelled field in NED,
       h_m(q) = atan2(U_y, U_x),  U = |q|² C(q̂) v   (scale invariant),
   against z = δ, the declination (the levelled field points at magnetic north; true =
   magnetic + δ). The innovation δ - h_m is mahony's heading error γ, wrapped to ±π;
   R = r_mag. Jacobian: H_m = (U_x ∂U_y/∂q - U_y ∂U_x/∂q) / (U_x² + U_y²). Because C(q̂) v is
   horizontal, H_m is a pure rotation about NED z at the estimate: the compass moves roll and
   pitch only through P's correlations. (The alternatives were worse: ZYX yaw as the measured
   function, with z = yaw + γ, has a tilt sensitivity of tan θ, and γ itself moves with
   tilt by tan(inclination); on the SITL logs that loop pulled roll/pitch by tens of degrees.
   The normalised field vector would let magnetic disturbances tilt the attitude.)
4. Updates in the Joseph form, P = (I - KH) P (I - KH)ᵀ + K R Kᵀ (filterpy's form). Then
   normalise X and map P through the normalisation's Jacobian J = (I - q̂ q̂ᵀ) / |X|:
   P ← J P Jᵀ. Both measurements depend on the direction of q only, so its norm is
   unobservable; without the projection its variance would grow with Φ's slight stretch for
   ever. With it P is rank 3 (positive semi-definite) and its trace is the attitude
   uncertainty alone (¼ of the summed attitude-angle variances, rad²).

Choices the baseline leaves open, made here:
- P₀ = I₄ as in paper 000; the first step projects it onto the attitude's tangent space.
- q_gyro = 1e-2 (rad/s)², paper 000's Q. With an accelerometer update every sample the tilt
  follows the accelerometer with a time constant of about 10 √r_accel seconds, whatever the
  IMU rate (the paper's discrete Q scales with T²).
- r_accel = 0.25 (a σ of 0.5 on the normalised accelerometer: non-gravity acceleration and
  vibration, not sensor noise): a tilt time constant of ≈ 5 s, as mahony's Kp = 0.2. Swept on
  the shared logs (0.01-1): 0.25 is near the best mean roll/pitch MAE, and 0.5 and above
  break the 0.2° static bound (the gyro bias walk is then corrected too slowly).
- r_mag = 0.01 rad² (σ 5.7° on the heading: tilt error, residual iron). With the levelled
  field the result hardly depends on it (0.001-0.1 within 0.05° mean MAE on the shared logs).
- The rate is the trapezoidal mean of the samples at both ends of the step, as in mahony.
  The first sample, and any step longer than ``MAX_STEP_S`` (a gap), neither predict nor
  update: the attitude is held.
- An accelerometer sample of zero norm (a dropout) or NaN skips that update.
- The paper's "improved EKF" (measuring the attitude solved from accelerometer and
  magnetometer, H = I) is not offered: it is ``mahony-ekf``'s structure with a noisier
  measurement, and the brief made it optional.
- The hot loop calls scalar helpers written out element by element (P's upper triangle read
  and written once); loops over small arrays ran 3-5× slower. The array forms of the model
  (``transition``, ``accel_model``, ``heading_model``) wrap the same scalar code for tests.
- The accelerometer low-passed in an almost-inertial frame (``inertial_accel``,
  ``accel_tau``, 1 s; strict: the reading as it is).
  As in mahony (its numbers there). 0 -> 1 s: BROAD 1.16° -> 0.64° (worst 8.5× -> 1.6× VQF),
  corpus 1.29° -> 1.30°, SITL 2.03° -> 2.01° (but the SITL plane circuit 6.45° -> 7.86°); worst
  log real-sub-4.1.0 mohai009 1.70° -> 2.02° (1.57× mahony's 0 s figure).
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import NamedTuple

import numpy as np

from ..flight import GRAVITY
from ..kernel_cache import kernel
from ..paramspec import param
from ..quaternion import wrap_pi_s
from .base import MAX_STEP_S, Estimator, filter_state, run_with_trace
from .inertial_accel import lowpass_in_inertial_frame
from .timestep import integrates, step_dt, step_rate


@dataclass
class EkfParams:
    q_gyro: float = param(1e-2, "(0, 1e6]", "log [1e-6, 1]")  # gyro noise variance per axis (paper 000's Q), (rad/s)²
    r_accel: float = param(0.25, "[1e-12, 1e6]", "log [1e-4, 10]")  # noise variance per axis of the normalised accelerometer a/‖a‖, 1
    r_mag: float = param(0.01, "(0, inf)", "log [1e-4, 1]")  # compass heading noise variance, rad²
    use_mag: bool = param(True)  # measure heading from the magnetometer when the log has one
    accel_tau: float = param(1.0, "[0, 60]", "linear [0, 5]")  # s: the accelerometer low-passed in an almost-inertial frame (inertial_accel); 0: the reading as it is
    strict: bool = param(False)  # the filter as published: accel_tau = 0, whatever it says


# ---------------------------------------------------------------- model functions (compiled)
# The scalar cores (``*_s``) are what the kernel runs; the array forms wrap them for tests
# (Jacobians against finite differences, the same model in filterpy).


@kernel
def transition(w, dt, out):
    """Φ = I + (T/2) Ω(ω) into out (4, 4), paper 000 eq 14."""
    a0, a1, a2 = 0.5 * dt * w[0], 0.5 * dt * w[1], 0.5 * dt * w[2]
    out[0, 0], out[0, 1], out[0, 2], out[0, 3] = 1.0, -a0, -a1, -a2
    out[1, 0], out[1, 1], out[1, 2], out[1, 3] = a0, 1.0, a2, -a1
    out[2, 0], out[2, 1], out[2, 2], out[2, 3] = a1, -a2, 1.0, a0
    out[3, 0], out[3, 1], out[3, 2], out[3, 3] = a2, a1, -a0, 1.0
    return out


@kernel
def accel_model_s(w, x, y, z):
    """h_a(q) = C(q/|q|)ᵀ [0, 0, -1] and its Jacobian H_a (3×4, row-major): a 15-tuple
    (h0, h1, h2, H00 .. H23)."""
    n2 = w * w + x * x + y * y + z * z
    h0 = -2.0 * (x * z - w * y) / n2
    h1 = -2.0 * (y * z + w * x) / n2
    h2 = -(w * w - x * x - y * y + z * z) / n2
    # H = (H₀ - 2 h qᵀ) / |q|², H₀ = -2 [[-y, z, -w, x], [x, w, z, y], [w, -x, -y, z]]
    f = 2.0 / n2
    return (h0, h1, h2,
            f * (y - h0 * w), f * (-z - h0 * x), f * (w - h0 * y), f * (-x - h0 * z),
            f * (-x - h1 * w), f * (-w - h1 * x), f * (-z - h1 * y), f * (-y - h1 * z),
            f * (-w - h2 * w), f * (x - h2 * x), f * (y - h2 * y), f * (-z - h2 * z))


@kernel
def accel_model(q, h, H):
    """h_a(q) into h (3,), its Jacobian into H (3, 4); returns h."""
    r = accel_model_s(q[0], q[1], q[2], q[3])
    h[0], h[1], h[2] = r[0], r[1], r[2]
    H[0, 0], H[0, 1], H[0, 2], H[0, 3] = r[3], r[4], r[5], r[6]
    H[1, 0], H[1, 1], H[1, 2], H[1, 3] = r[7], r[8], r[9], r[10]
    H[2, 0], H[2, 1], H[2, 2], H[2, 3] = r[11], r[12], r[13], r[14]
    return h


@kernel
def heading_model_s(w, x, y, z, v0, v1, v2):
    """h_m(q) = azimuth of C(q) v, v = (v0, v1, v2) a body-frame vector (the levelled field),
    and its Jacobian: (h, H0, H1, H2, H3). h = atan2(U_y, U_x) with U = |q|² C(q/|q|) v, so h
    is scale invariant. Zero Jacobian (and h = 0) when C(q) v is vertical."""
    ux = ((w * w + x * x - y * y - z * z) * v0 + 2.0 * (x * y - w * z) * v1
          + 2.0 * (x * z + w * y) * v2)
    uy = (2.0 * (x * y + w * z) * v0 + (w * w - x * x + y * y - z * z) * v1
          + 2.0 * (y * z - w * x) * v2)
    s = ux * ux + uy * uy
    if not s > 0.0:
        return 0.0, 0.0, 0.0, 0.0, 0.0
    # ∂U/∂q (columns w, x, y, z), halved
    dx0, dx1 = w * v0 - z * v1 + y * v2, x * v0 + y * v1 + z * v2
    dx2, dx3 = -y * v0 + x * v1 + w * v2, -z * v0 - w * v1 + x * v2
    dy0, dy1 = z * v0 + w * v1 - x * v2, y * v0 - x * v1 - w * v2
    dy2, dy3 = x * v0 + y * v1 + z * v2, w * v0 - z * v1 + y * v2
    f = 2.0 / s
    return (np.arctan2(uy, ux), f * (ux * dy0 - uy * dx0), f * (ux * dy1 - uy * dx1),
            f * (ux * dy2 - uy * dx2), f * (ux * dy3 - uy * dx3))


@kernel
def heading_model(q, v, H):
    """h_m(q) for the body vector v (3,); its Jacobian into H (1, 4). Returns h_m."""
    r = heading_model_s(q[0], q[1], q[2], q[3], v[0], v[1], v[2])
    H[0, 0], H[0, 1], H[0, 2], H[0, 3] = r[1], r[2], r[3], r[4]
    return r[0]


@kernel
def level_field(q, m0, m1, m2):
    """The field m with its component along the vertical of attitude q removed (body frame):
    m - (m·d) d, d = C(q/|q|)ᵀ [0, 0, 1]. Returns a 3-tuple."""
    w, x, y, z = q[0], q[1], q[2], q[3]
    f = 2.0 / (w * w + x * x + y * y + z * z)
    d0, d1, d2 = f * (x * z - w * y), f * (y * z + w * x), 1.0 - f * (x * x + y * y)
    k = m0 * d0 + m1 * d1 + m2 * d2
    return m0 - k * d0, m1 - k * d1, m2 - k * d2


# ---------------------------------------------------------------- in-place filter steps (compiled)
# Written out element by element on local scalars (P symmetric: its upper triangle is read
# once and written once): small-matrix loops over arrays ran 3-5× slower.


@kernel(inline="always")
def predict(x, P, w0, w1, w2, dt, q_gyro):
    """X⁻ = Φ X, P⁻ = Φ P Φᵀ + G Q Gᵀ (paper 000 eq 18-19), in place. Φ = I + (T/2) Ω(ω)
    (eq 14); G = (T/2) Ξ(X) at the state before the step (eq 15), so
    G Q Gᵀ = q_gyro (T/2)² (|X|² I - X Xᵀ)."""
    a0, a1, a2 = 0.5 * dt * w0, 0.5 * dt * w1, 0.5 * dt * w2
    q0, q1, q2, q3 = x[0], x[1], x[2], x[3]
    p00, p01, p02, p03 = P[0, 0], P[0, 1], P[0, 2], P[0, 3]
    p11, p12, p13 = P[1, 1], P[1, 2], P[1, 3]
    p22, p23 = P[2, 2], P[2, 3]
    p33 = P[3, 3]
    x[0] = q0 - a0 * q1 - a1 * q2 - a2 * q3
    x[1] = a0 * q0 + q1 + a2 * q2 - a1 * q3
    x[2] = a1 * q0 - a2 * q1 + q2 + a0 * q3
    x[3] = a2 * q0 + a1 * q1 - a0 * q2 + q3
    # B = Φ P
    b00 = p00 - a0 * p01 - a1 * p02 - a2 * p03
    b01 = p01 - a0 * p11 - a1 * p12 - a2 * p13
    b02 = p02 - a0 * p12 - a1 * p22 - a2 * p23
    b03 = p03 - a0 * p13 - a1 * p23 - a2 * p33
    b10 = a0 * p00 + p01 + a2 * p02 - a1 * p03
    b11 = a0 * p01 + p11 + a2 * p12 - a1 * p13
    b12 = a0 * p02 + p12 + a2 * p22 - a1 * p23
    b13 = a0 * p03 + p13 + a2 * p23 - a1 * p33
    b20 = a1 * p00 - a2 * p01 + p02 + a0 * p03
    b21 = a1 * p01 - a2 * p11 + p12 + a0 * p13
    b22 = a1 * p02 - a2 * p12 + p22 + a0 * p23
    b23 = a1 * p03 - a2 * p13 + p23 + a0 * p33
    b30 = a2 * p00 + a1 * p01 - a0 * p02 + p03
    b31 = a2 * p01 + a1 * p11 - a0 * p12 + p13
    b32 = a2 * p02 + a1 * p12 - a0 * p22 + p23
    b33 = a2 * p03 + a1 * p13 - a0 * p23 + p33
    g = q_gyro * 0.25 * dt * dt
    n2 = q0 * q0 + q1 * q1 + q2 * q2 + q3 * q3
    # P = B Φᵀ + g (|q|² I - q qᵀ)
    P[0, 0] = b00 - a0 * b01 - a1 * b02 - a2 * b03 + g * (n2 - q0 * q0)
    P[0, 1] = P[1, 0] = a0 * b00 + b01 + a2 * b02 - a1 * b03 - g * q0 * q1
    P[0, 2] = P[2, 0] = a1 * b00 - a2 * b01 + b02 + a0 * b03 - g * q0 * q2
    P[0, 3] = P[3, 0] = a2 * b00 + a1 * b01 - a0 * b02 + b03 - g * q0 * q3
    P[1, 1] = a0 * b10 + b11 + a2 * b12 - a1 * b13 + g * (n2 - q1 * q1)
    P[1, 2] = P[2, 1] = a1 * b10 - a2 * b11 + b12 + a0 * b13 - g * q1 * q2
    P[1, 3] = P[3, 1] = a2 * b10 + a1 * b11 - a0 * b12 + b13 - g * q1 * q3
    P[2, 2] = a1 * b20 - a2 * b21 + b22 + a0 * b23 + g * (n2 - q2 * q2)
    P[2, 3] = P[3, 2] = a2 * b20 + a1 * b21 - a0 * b22 + b23 - g * q2 * q3
    P[3, 3] = a2 * b30 + a1 * b31 - a0 * b32 + b33 + g * (n2 - q3 * q3)


@kernel(inline="always")
def accel_update(x, P, u0, u1, u2, r):
    """Kalman update with the normalised accelerometer (u0, u1, u2) against h_a(X), R = r I₃,
    Joseph form P = (I - KH) P (I - KH)ᵀ + K R Kᵀ, in place (the 3×3 innovation covariance
    inverted by its adjugate). Written out element by element."""
    (h0, h1, h2, H00, H01, H02, H03, H10, H11, H12, H13,
     H20, H21, H22, H23) = accel_model_s(x[0], x[1], x[2], x[3])
    p00, p01, p02, p03 = P[0, 0], P[0, 1], P[0, 2], P[0, 3]
    p11, p12, p13 = P[1, 1], P[1, 2], P[1, 3]
    p22, p23 = P[2, 2], P[2, 3]
    p33 = P[3, 3]
    # V = P Hᵀ
    v00 = p00 * H00 + p01 * H01 + p02 * H02 + p03 * H03
    v01 = p00 * H10 + p01 * H11 + p02 * H12 + p03 * H13
    v02 = p00 * H20 + p01 * H21 + p02 * H22 + p03 * H23
    v10 = p01 * H00 + p11 * H01 + p12 * H02 + p13 * H03
    v11 = p01 * H10 + p11 * H11 + p12 * H12 + p13 * H13
    v12 = p01 * H20 + p11 * H21 + p12 * H22 + p13 * H23
    v20 = p02 * H00 + p12 * H01 + p22 * H02 + p23 * H03
    v21 = p02 * H10 + p12 * H11 + p22 * H12 + p23 * H13
    v22 = p02 * H20 + p12 * H21 + p22 * H22 + p23 * H23
    v30 = p03 * H00 + p13 * H01 + p23 * H02 + p33 * H03
    v31 = p03 * H10 + p13 * H11 + p23 * H12 + p33 * H13
    v32 = p03 * H20 + p13 * H21 + p23 * H22 + p33 * H23
    # S = H V + R
    s00 = H00 * v00 + H01 * v10 + H02 * v20 + H03 * v30 + r
    s01 = H00 * v01 + H01 * v11 + H02 * v21 + H03 * v31
    s02 = H00 * v02 + H01 * v12 + H02 * v22 + H03 * v32
    s11 = H10 * v01 + H11 * v11 + H12 * v21 + H13 * v31 + r
    s12 = H10 * v02 + H11 * v12 + H12 * v22 + H13 * v32
    s22 = H20 * v02 + H21 * v12 + H22 * v22 + H23 * v32 + r
    c00 = s11 * s22 - s12 * s12
    c01 = s02 * s12 - s01 * s22
    c02 = s01 * s12 - s02 * s11
    c11 = s00 * s22 - s02 * s02
    c12 = s01 * s02 - s00 * s12
    c22 = s00 * s11 - s01 * s01
    inv = 1.0 / (s00 * c00 + s01 * c01 + s02 * c02)
    t00, t01, t02, t11, t12, t22 = c00 * inv, c01 * inv, c02 * inv, c11 * inv, c12 * inv, c22 * inv
    # K = V S⁻¹
    k00 = v00 * t00 + v01 * t01 + v02 * t02
    k01 = v00 * t01 + v01 * t11 + v02 * t12
    k02 = v00 * t02 + v01 * t12 + v02 * t22
    k10 = v10 * t00 + v11 * t01 + v12 * t02
    k11 = v10 * t01 + v11 * t11 + v12 * t12
    k12 = v10 * t02 + v11 * t12 + v12 * t22
    k20 = v20 * t00 + v21 * t01 + v22 * t02
    k21 = v20 * t01 + v21 * t11 + v22 * t12
    k22 = v20 * t02 + v21 * t12 + v22 * t22
    k30 = v30 * t00 + v31 * t01 + v32 * t02
    k31 = v30 * t01 + v31 * t11 + v32 * t12
    k32 = v30 * t02 + v31 * t12 + v32 * t22
    y0, y1, y2 = u0 - h0, u1 - h1, u2 - h2
    x[0] += k00 * y0 + k01 * y1 + k02 * y2
    x[1] += k10 * y0 + k11 * y1 + k12 * y2
    x[2] += k20 * y0 + k21 * y1 + k22 * y2
    x[3] += k30 * y0 + k31 * y1 + k32 * y2
    # A = I - K H
    a00 = 1.0 - (k00 * H00 + k01 * H10 + k02 * H20)
    a01 = -(k00 * H01 + k01 * H11 + k02 * H21)
    a02 = -(k00 * H02 + k01 * H12 + k02 * H22)
    a03 = -(k00 * H03 + k01 * H13 + k02 * H23)
    a10 = -(k10 * H00 + k11 * H10 + k12 * H20)
    a11 = 1.0 - (k10 * H01 + k11 * H11 + k12 * H21)
    a12 = -(k10 * H02 + k11 * H12 + k12 * H22)
    a13 = -(k10 * H03 + k11 * H13 + k12 * H23)
    a20 = -(k20 * H00 + k21 * H10 + k22 * H20)
    a21 = -(k20 * H01 + k21 * H11 + k22 * H21)
    a22 = 1.0 - (k20 * H02 + k21 * H12 + k22 * H22)
    a23 = -(k20 * H03 + k21 * H13 + k22 * H23)
    a30 = -(k30 * H00 + k31 * H10 + k32 * H20)
    a31 = -(k30 * H01 + k31 * H11 + k32 * H21)
    a32 = -(k30 * H02 + k31 * H12 + k32 * H22)
    a33 = 1.0 - (k30 * H03 + k31 * H13 + k32 * H23)
    # B = A P
    b00 = a00 * p00 + a01 * p01 + a02 * p02 + a03 * p03
    b01 = a00 * p01 + a01 * p11 + a02 * p12 + a03 * p13
    b02 = a00 * p02 + a01 * p12 + a02 * p22 + a03 * p23
    b03 = a00 * p03 + a01 * p13 + a02 * p23 + a03 * p33
    b10 = a10 * p00 + a11 * p01 + a12 * p02 + a13 * p03
    b11 = a10 * p01 + a11 * p11 + a12 * p12 + a13 * p13
    b12 = a10 * p02 + a11 * p12 + a12 * p22 + a13 * p23
    b13 = a10 * p03 + a11 * p13 + a12 * p23 + a13 * p33
    b20 = a20 * p00 + a21 * p01 + a22 * p02 + a23 * p03
    b21 = a20 * p01 + a21 * p11 + a22 * p12 + a23 * p13
    b22 = a20 * p02 + a21 * p12 + a22 * p22 + a23 * p23
    b23 = a20 * p03 + a21 * p13 + a22 * p23 + a23 * p33
    b30 = a30 * p00 + a31 * p01 + a32 * p02 + a33 * p03
    b31 = a30 * p01 + a31 * p11 + a32 * p12 + a33 * p13
    b32 = a30 * p02 + a31 * p12 + a32 * p22 + a33 * p23
    b33 = a30 * p03 + a31 * p13 + a32 * p23 + a33 * p33
    # P = B Aᵀ + r K Kᵀ
    P[0, 0] = b00 * a00 + b01 * a01 + b02 * a02 + b03 * a03 + r * (k00 * k00 + k01 * k01 + k02 * k02)
    P[0, 1] = P[1, 0] = (b00 * a10 + b01 * a11 + b02 * a12 + b03 * a13
                          + r * (k00 * k10 + k01 * k11 + k02 * k12))
    P[0, 2] = P[2, 0] = (b00 * a20 + b01 * a21 + b02 * a22 + b03 * a23
                          + r * (k00 * k20 + k01 * k21 + k02 * k22))
    P[0, 3] = P[3, 0] = (b00 * a30 + b01 * a31 + b02 * a32 + b03 * a33
                          + r * (k00 * k30 + k01 * k31 + k02 * k32))
    P[1, 1] = b10 * a10 + b11 * a11 + b12 * a12 + b13 * a13 + r * (k10 * k10 + k11 * k11 + k12 * k12)
    P[1, 2] = P[2, 1] = (b10 * a20 + b11 * a21 + b12 * a22 + b13 * a23
                          + r * (k10 * k20 + k11 * k21 + k12 * k22))
    P[1, 3] = P[3, 1] = (b10 * a30 + b11 * a31 + b12 * a32 + b13 * a33
                          + r * (k10 * k30 + k11 * k31 + k12 * k32))
    P[2, 2] = b20 * a20 + b21 * a21 + b22 * a22 + b23 * a23 + r * (k20 * k20 + k21 * k21 + k22 * k22)
    P[2, 3] = P[3, 2] = (b20 * a30 + b21 * a31 + b22 * a32 + b23 * a33
                          + r * (k20 * k30 + k21 * k31 + k22 * k32))
    P[3, 3] = b30 * a30 + b31 * a31 + b32 * a32 + b33 * a33 + r * (k30 * k30 + k31 * k31 + k32 * k32)


@kernel(inline="always")
def scalar_update(x, P, H0, H1, H2, H3, innov, r):
    """Kalman update with a scalar measurement, H = [H0..H3], innovation ``innov``, R = r,
    Joseph form (A P = P - k (P H)ᵀ for A = I - k H), in place."""
    p00, p01, p02, p03 = P[0, 0], P[0, 1], P[0, 2], P[0, 3]
    p11, p12, p13 = P[1, 1], P[1, 2], P[1, 3]
    p22, p23 = P[2, 2], P[2, 3]
    p33 = P[3, 3]
    v0 = p00 * H0 + p01 * H1 + p02 * H2 + p03 * H3
    v1 = p01 * H0 + p11 * H1 + p12 * H2 + p13 * H3
    v2 = p02 * H0 + p12 * H1 + p22 * H2 + p23 * H3
    v3 = p03 * H0 + p13 * H1 + p23 * H2 + p33 * H3
    s = H0 * v0 + H1 * v1 + H2 * v2 + H3 * v3 + r
    k0, k1, k2, k3 = v0 / s, v1 / s, v2 / s, v3 / s
    x[0] += k0 * innov
    x[1] += k1 * innov
    x[2] += k2 * innov
    x[3] += k3 * innov
    # B = A P = P - k vᵀ; P = B Aᵀ + r k kᵀ = B - (B H) kᵀ + r k kᵀ
    b00 = p00 - k0 * v0
    b01 = p01 - k0 * v1
    b02 = p02 - k0 * v2
    b03 = p03 - k0 * v3
    b10 = p01 - k1 * v0
    b11 = p11 - k1 * v1
    b12 = p12 - k1 * v2
    b13 = p13 - k1 * v3
    b20 = p02 - k2 * v0
    b21 = p12 - k2 * v1
    b22 = p22 - k2 * v2
    b23 = p23 - k2 * v3
    b30 = p03 - k3 * v0
    b31 = p13 - k3 * v1
    b32 = p23 - k3 * v2
    b33 = p33 - k3 * v3
    c0 = b00 * H0 + b01 * H1 + b02 * H2 + b03 * H3
    c1 = b10 * H0 + b11 * H1 + b12 * H2 + b13 * H3
    c2 = b20 * H0 + b21 * H1 + b22 * H2 + b23 * H3
    c3 = b30 * H0 + b31 * H1 + b32 * H2 + b33 * H3
    P[0, 0] = b00 - c0 * k0 + r * k0 * k0
    P[0, 1] = P[1, 0] = b01 - c0 * k1 + r * k0 * k1
    P[0, 2] = P[2, 0] = b02 - c0 * k2 + r * k0 * k2
    P[0, 3] = P[3, 0] = b03 - c0 * k3 + r * k0 * k3
    P[1, 1] = b11 - c1 * k1 + r * k1 * k1
    P[1, 2] = P[2, 1] = b12 - c1 * k2 + r * k1 * k2
    P[1, 3] = P[3, 1] = b13 - c1 * k3 + r * k1 * k3
    P[2, 2] = b22 - c2 * k2 + r * k2 * k2
    P[2, 3] = P[3, 2] = b23 - c2 * k3 + r * k2 * k3
    P[3, 3] = b33 - c3 * k3 + r * k3 * k3


@kernel(inline="always")
def normalize_project(x, P):
    """X ← X / |X|, P ← J P Jᵀ with J = (I - q̂ q̂ᵀ) / |X|, the Jacobian of the normalisation;
    in place."""
    n = np.sqrt(x[0] * x[0] + x[1] * x[1] + x[2] * x[2] + x[3] * x[3])
    q0, q1, q2, q3 = x[0] / n, x[1] / n, x[2] / n, x[3] / n
    x[0], x[1], x[2], x[3] = q0, q1, q2, q3
    p00, p01, p02, p03 = P[0, 0], P[0, 1], P[0, 2], P[0, 3]
    p11, p12, p13 = P[1, 1], P[1, 2], P[1, 3]
    p22, p23 = P[2, 2], P[2, 3]
    p33 = P[3, 3]
    v0 = p00 * q0 + p01 * q1 + p02 * q2 + p03 * q3
    v1 = p01 * q0 + p11 * q1 + p12 * q2 + p13 * q3
    v2 = p02 * q0 + p12 * q1 + p22 * q2 + p23 * q3
    v3 = p03 * q0 + p13 * q1 + p23 * q2 + p33 * q3
    s = q0 * v0 + q1 * v1 + q2 * v2 + q3 * v3
    inv = 1.0 / (n * n)
    # (P - v q̂ᵀ - q̂ vᵀ + s q̂ q̂ᵀ) / |X|²
    P[0, 0] = (p00 - v0 * q0 - q0 * v0 + s * q0 * q0) * inv
    P[0, 1] = P[1, 0] = (p01 - v0 * q1 - q0 * v1 + s * q0 * q1) * inv
    P[0, 2] = P[2, 0] = (p02 - v0 * q2 - q0 * v2 + s * q0 * q2) * inv
    P[0, 3] = P[3, 0] = (p03 - v0 * q3 - q0 * v3 + s * q0 * q3) * inv
    P[1, 1] = (p11 - v1 * q1 - q1 * v1 + s * q1 * q1) * inv
    P[1, 2] = P[2, 1] = (p12 - v1 * q2 - q1 * v2 + s * q1 * q2) * inv
    P[1, 3] = P[3, 1] = (p13 - v1 * q3 - q1 * v3 + s * q1 * q3) * inv
    P[2, 2] = (p22 - v2 * q2 - q2 * v2 + s * q2 * q2) * inv
    P[2, 3] = P[3, 2] = (p23 - v2 * q3 - q2 * v3 + s * q2 * q3) * inv
    P[3, 3] = (p33 - v3 * q3 - q3 * v3 + s * q3 * q3) * inv


class EkfSettings(NamedTuple):
    """The parameters as the kernel takes them (see ``EkfParams``)."""
    q_gyro: float
    r_accel: float
    r_mag: float
    declination: float  # rad
    use_mag: bool
    max_step: float  # s


@kernel
def ekf_run(s, state, cfg, out, cov_trace):
    """Run the filter over a chunk of samples ``s`` (``base.Samples``); ``state``
    (``base.FilterState``, the quaternion as ``q``) is updated in place. Writes the attitude
    after each sample to ``out`` and trace(P) to ``cov_trace``."""
    t, gyro, accel, mag = s.t, s.gyro, s.accel, s.mag
    over_step = s.rate_over_step  # each gyro sample the mean over its step (timestep.step_rate)
    x, P, t_prev, gyro_prev, bias = state.q, state.P, state.t_prev, state.gyro_prev, state.bias
    q_gyro, r_accel, r_mag, declination, use_mag, max_step = (cfg.q_gyro, cfg.r_accel, cfg.r_mag,
                                                              cfg.declination, cfg.use_mag, cfg.max_step)
    for i in range(len(t)):
        dt = step_dt(t[i], t_prev[0])
        t_prev[0] = t[i]
        g0, g1, g2 = gyro[i, 0], gyro[i, 1], gyro[i, 2]
        if integrates(dt, max_step):
            # the step's rate, minus the still-period bias
            w0, w1, w2 = step_rate(g0, g1, g2, gyro_prev[0], gyro_prev[1], gyro_prev[2], dt, over_step)
            predict(x, P, w0 - bias[0], w1 - bias[1], w2 - bias[2], dt, q_gyro)
            a0, a1, a2 = accel[i, 0], accel[i, 1], accel[i, 2]
            a_norm = np.sqrt(a0 * a0 + a1 * a1 + a2 * a2)
            if a_norm > 0.0:  # not a dropout, not NaN
                accel_update(x, P, a0 / a_norm, a1 / a_norm, a2 / a_norm, r_accel)
            if use_mag and mag[i, 0] == mag[i, 0]:
                v0, v1, v2 = level_field(x, mag[i, 0], mag[i, 1], mag[i, 2])
                h, H0, H1, H2, H3 = heading_model_s(x[0], x[1], x[2], x[3], v0, v1, v2)
                if H0 != 0.0 or H1 != 0.0 or H2 != 0.0 or H3 != 0.0:
                    # the levelled field points to magnetic north: azimuth = declination
                    scalar_update(x, P, H0, H1, H2, H3, wrap_pi_s(declination - h), r_mag)
            normalize_project(x, P)
        gyro_prev[0], gyro_prev[1], gyro_prev[2] = g0, g1, g2
        out[i, 0], out[i, 1], out[i, 2], out[i, 3] = x[0], x[1], x[2], x[3]
        cov_trace[i] = P[0, 0] + P[1, 1] + P[2, 2] + P[3, 3]
    return out


class Ekf(Estimator):
    """Conventional quaternion EKF (baseline of papers 000, 001); see the module docstring."""
    name = "ekf"
    Params = EkfParams
    kernels = (lowpass_in_inertial_frame, ekf_run)
    color = (0, 135, 255)
    compile_seconds = 4.0  # CPU s, one core (scripts/compile_profile.py)
    PAPER = dict(accel_tau=0.0)  # strict: the accelerometer as it reads
    DIAGNOSTICS = {"cov_trace": "trace of the 4×4 quaternion covariance P (dimensionless)"}

    def initialize(self, q0, gyro_bias, accel_g: float = GRAVITY) -> None:
        self._state = filter_state(q0, np.eye(4), gyro_bias)  # paper 000: P₀ = I₄
        p = self.params
        self._settings = EkfSettings(
            q_gyro=float(p.q_gyro), r_accel=float(p.r_accel), r_mag=float(p.r_mag), declination=self.declination,
            use_mag=bool(p.use_mag), max_step=MAX_STEP_S)
        self._ready(q0, gyro_bias)

    def _run(self, s, out, aiding) -> dict:
        return run_with_trace(ekf_run, s, self._state, self._settings, out)
