"""Quaternion and frame math: the one place for it.

Conventions (../shared/ALGORITHMS.md "Conventions"): q = [w, x, y, z], Hamilton product,
rotating body (FRD) to navigation (NED): v_n = C(q) v_b. Euler angles are ZYX
(yaw, pitch, roll), yaw in [-pi, pi).

Two kinds of function live here:
- vectorised numpy functions over (N, 4) / (N, 3) arrays, for readers, metrics and the view;
- small compiled kernels (``@kernel``) on single samples, for the compiled estimator loops.
"""
from __future__ import annotations

import math

import numpy as np

from .kernel_cache import kernel

# ---------------------------------------------------------------- vectorised (numpy)


def wrap_pi(angle):
    """Wrap radians to [-pi, pi)."""
    return (np.asarray(angle) + np.pi) % (2.0 * np.pi) - np.pi


def wrap_deg(angle):
    """Wrap degrees to [-180, 180)."""
    return (np.asarray(angle) + 180.0) % 360.0 - 180.0


def from_euler(roll, pitch, yaw) -> np.ndarray:
    """ZYX Euler angles (radians, scalars or arrays) to quaternions (..., 4)."""
    cr, sr = np.cos(np.asarray(roll) / 2), np.sin(np.asarray(roll) / 2)
    cp, sp = np.cos(np.asarray(pitch) / 2), np.sin(np.asarray(pitch) / 2)
    cy, sy = np.cos(np.asarray(yaw) / 2), np.sin(np.asarray(yaw) / 2)
    return np.stack([
        cr * cp * cy + sr * sp * sy,
        sr * cp * cy - cr * sp * sy,
        cr * sp * cy + sr * cp * sy,
        cr * cp * sy - sr * sp * cy,
    ], axis=-1)


def to_euler(q) -> np.ndarray:
    """Quaternions (..., 4) to ZYX Euler angles (..., 3) = [roll, pitch, yaw], radians."""
    q = np.asarray(q, dtype=float)
    w, x, y, z = q[..., 0], q[..., 1], q[..., 2], q[..., 3]
    roll = np.arctan2(2 * (w * x + y * z), 1 - 2 * (x * x + y * y))
    pitch = np.arcsin(np.clip(2 * (w * y - z * x), -1.0, 1.0))
    yaw = np.arctan2(2 * (w * z + x * y), 1 - 2 * (y * y + z * z))
    return np.stack([roll, pitch, wrap_pi(yaw)], axis=-1)


def multiply(p, q) -> np.ndarray:
    """Hamilton product p ⊗ q over the last axis."""
    p, q = np.asarray(p, dtype=float), np.asarray(q, dtype=float)
    pw, px, py, pz = p[..., 0], p[..., 1], p[..., 2], p[..., 3]
    qw, qx, qy, qz = q[..., 0], q[..., 1], q[..., 2], q[..., 3]
    return np.stack([
        pw * qw - px * qx - py * qy - pz * qz,
        pw * qx + px * qw + py * qz - pz * qy,
        pw * qy - px * qz + py * qw + pz * qx,
        pw * qz + px * qy - py * qx + pz * qw,
    ], axis=-1)


def conjugate(q) -> np.ndarray:
    q = np.asarray(q, dtype=float)
    return q * np.array([1.0, -1.0, -1.0, -1.0])


def yaw_turned(q, yaw) -> np.ndarray:
    """``q`` (..., 4) turned about the NED down axis by ``yaw`` (rad, scalar or per row): its
    ZYX yaw grows by ``yaw``, roll and pitch stay."""
    yaw = np.asarray(yaw, dtype=float)
    return multiply(from_euler(0.0 * yaw, 0.0 * yaw, yaw), q)


def trimmed(q, roll: float, pitch: float) -> np.ndarray:
    """The vehicle body's attitude from the board's, for ArduPilot's board trim (AHRS_TRIM_X/Y,
    rad): q ⊗ q_trim*, q_trim from the Euler angles (roll, pitch, 0) (AP_AHRS: DCM · R(trim)ᵀ)."""
    q = np.asarray(q, dtype=float)
    return multiply(q, np.broadcast_to(conjugate(from_euler(roll, pitch, 0.0)), q.shape))


def normalize(q) -> np.ndarray:
    q = np.asarray(q, dtype=float)
    return q / np.linalg.norm(q, axis=-1, keepdims=True)


def row_norms(x: np.ndarray, rows: int = 1 << 16) -> np.ndarray:
    """``np.linalg.norm(x, axis=1)``, the same numbers, made a block of rows at a time: without
    its temporary of every value squared (an hour's gyro at 400 Hz: 35 MB)."""
    out = np.empty(len(x), dtype=np.linalg.norm(x[:1], axis=1).dtype)
    for a in range(0, len(x), rows):
        out[a:a + rows] = np.linalg.norm(x[a:a + rows], axis=1)
    return out


def to_dcm(q) -> np.ndarray:
    """Direction cosine matrices C(q) (..., 3, 3), body -> navigation."""
    q = np.asarray(q, dtype=float)
    w, x, y, z = q[..., 0], q[..., 1], q[..., 2], q[..., 3]
    return np.stack([
        np.stack([1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)], axis=-1),
        np.stack([2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)], axis=-1),
        np.stack([2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)], axis=-1),
    ], axis=-2)


def rotate(q, v) -> np.ndarray:
    """C(q) v: a body-frame vector expressed in the navigation frame."""
    return np.einsum("...ij,...j->...i", to_dcm(q), np.asarray(v, dtype=float))


def to_rotation_vector(q) -> np.ndarray:
    """The rotation vector (axis × angle, rad) of unit quaternions, the shorter way round."""
    q = np.asarray(q, dtype=float)
    q = q * np.where(q[..., :1] < 0, -1.0, 1.0)
    s = np.linalg.norm(q[..., 1:], axis=-1, keepdims=True)
    angle = 2.0 * np.arctan2(s, q[..., :1])
    with np.errstate(invalid="ignore", divide="ignore"):
        scale = np.where(s > 1e-12, angle / s, 2.0)  # small angles: 2 × the vector part
    return q[..., 1:] * scale


def make_continuous(q) -> np.ndarray:
    """Flip signs so consecutive quaternions lie in the same hemisphere (q and -q are one attitude)."""
    q = np.array(q, dtype=float)
    if len(q) < 2:
        return q
    flips = np.sum(q[1:] * q[:-1], axis=-1) < 0
    sign = np.concatenate([[1.0], np.where(np.cumsum(flips) % 2 == 1, -1.0, 1.0)])
    return q * sign[:, None]


def interpolate(t_src, q_src, t_dst) -> np.ndarray:
    """Attitude at times ``t_dst`` by normalised linear interpolation (nlerp) of ``q_src``.

    nlerp differs from slerp by less than 1e-4 rad between samples a few degrees apart,
    which is the case at any IMU rate an estimate is produced at. Outside the source span
    the result is NaN.
    """
    t_src = np.asarray(t_src, dtype=float)
    t_dst = np.asarray(t_dst, dtype=float)
    q_src = np.asarray(q_src, dtype=float)
    out = np.full((len(t_dst), 4), np.nan)
    if len(t_src) < 2:
        return out
    inside = (t_dst >= t_src[0]) & (t_dst <= t_src[-1])
    td = t_dst[inside]
    i = np.clip(np.searchsorted(t_src, td, side="right") - 1, 0, len(t_src) - 2)
    span = t_src[i + 1] - t_src[i]
    a = np.where(span > 0, (td - t_src[i]) / np.where(span > 0, span, 1.0), 0.0)[:, None]
    # q and -q are one attitude: blend each pair in one hemisphere (only the pairs used, not an
    # hour-long source made continuous first)
    before, after = q_src[i], q_src[i + 1]
    after = after * np.where(np.sum(before * after, axis=-1) < 0, -1.0, 1.0)[:, None]
    out[inside] = normalize((1 - a) * before + a * after)
    return out


def tilt_from_accel(accel) -> tuple[np.ndarray, np.ndarray]:
    """Roll and pitch (radians) from specific force, ALGORITHMS.md "Conventions"."""
    f = np.asarray(accel, dtype=float)
    roll = np.arctan2(-f[..., 1], -f[..., 2])
    pitch = np.arctan2(f[..., 0], np.hypot(f[..., 1], f[..., 2]))
    return roll, pitch


def heading_from_mag(roll, pitch, mag, declination=0.0):
    """True heading (radians) from a body-frame field reading and known roll/pitch.

    Levels the field with roll and pitch, then measures the angle of its horizontal part
    from north; adding the declination turns magnetic into true heading.
    """
    level = from_euler(roll, pitch, np.zeros_like(np.asarray(roll, dtype=float)))
    m_level = rotate(level, mag)
    return wrap_pi(-np.arctan2(m_level[..., 1], m_level[..., 0]) + declination)


# ---------------------------------------------------------------- compiled kernels (numba)
# Single-sample helpers for the estimator loops; inputs and outputs are float64 arrays.


@kernel
def qmul(p, q):
    out = np.empty(4)
    out[0] = p[0] * q[0] - p[1] * q[1] - p[2] * q[2] - p[3] * q[3]
    out[1] = p[0] * q[1] + p[1] * q[0] + p[2] * q[3] - p[3] * q[2]
    out[2] = p[0] * q[2] - p[1] * q[3] + p[2] * q[0] + p[3] * q[1]
    out[3] = p[0] * q[3] + p[1] * q[2] - p[2] * q[1] + p[3] * q[0]
    return out


@kernel
def qnormalize(q):
    return q / np.sqrt(q[0] * q[0] + q[1] * q[1] + q[2] * q[2] + q[3] * q[3])


@kernel
def qdcm(q):
    """C(q), body -> navigation."""
    c = np.empty((3, 3))
    dcm_into(q[0], q[1], q[2], q[3], c)
    return c


@kernel
def cross(a, b):
    out = np.empty(3)
    out[0] = a[1] * b[2] - a[2] * b[1]
    out[1] = a[2] * b[0] - a[0] * b[2]
    out[2] = a[0] * b[1] - a[1] * b[0]
    return out


@kernel
def omega_matrix(w):
    """Ω(ω) with q̇ = ½ Ω(ω) q (ALGORITHMS.md "Conventions")."""
    m = np.zeros((4, 4))
    m[0, 1], m[0, 2], m[0, 3] = -w[0], -w[1], -w[2]
    m[1, 0], m[1, 2], m[1, 3] = w[0], w[2], -w[1]
    m[2, 0], m[2, 1], m[2, 3] = w[1], -w[2], w[0]
    m[3, 0], m[3, 1], m[3, 2] = w[2], w[1], -w[0]
    return m


@kernel
def integrate_gyro(q, w, dt):
    """Rotate q by body rate w over dt, exactly for constant w: q ⊗ Exp(w dt)."""
    angle = np.sqrt(w[0] * w[0] + w[1] * w[1] + w[2] * w[2]) * dt
    dq = np.empty(4)
    if angle < 1e-12:
        dq[0] = 1.0
        dq[1], dq[2], dq[3] = 0.5 * w[0] * dt, 0.5 * w[1] * dt, 0.5 * w[2] * dt
    else:
        s = np.sin(0.5 * angle) / (angle / dt)
        dq[0] = np.cos(0.5 * angle)
        dq[1], dq[2], dq[3] = w[0] * s, w[1] * s, w[2] * s
    return qnormalize(qmul(q, dq))


@kernel
def integrate_gyro_scalar(q0, q1, q2, q3, wx, wy, wz, dt):
    """``integrate_gyro`` on scalars, allocating nothing, for per-sample loops: returns the
    rotated quaternion as a tuple (w, x, y, z). The same operations in the same order as
    ``integrate_gyro``, so the same numbers."""
    angle = np.sqrt(wx * wx + wy * wy + wz * wz) * dt
    if angle < 1e-12:
        d0, d1, d2, d3 = 1.0, 0.5 * wx * dt, 0.5 * wy * dt, 0.5 * wz * dt
    else:
        s = np.sin(0.5 * angle) / (angle / dt)
        d0, d1, d2, d3 = np.cos(0.5 * angle), wx * s, wy * s, wz * s
    r0 = q0 * d0 - q1 * d1 - q2 * d2 - q3 * d3
    r1 = q0 * d1 + q1 * d0 + q2 * d3 - q3 * d2
    r2 = q0 * d2 - q1 * d3 + q2 * d0 + q3 * d1
    r3 = q0 * d3 + q1 * d2 - q2 * d1 + q3 * d0
    norm = np.sqrt(r0 * r0 + r1 * r1 + r2 * r2 + r3 * r3)
    return r0 / norm, r1 / norm, r2 / norm, r3 / norm


# ---------------------------------------------------------------- scalar kernels for the estimator loops
# Allocation-free: scalars in and tuples out, or written into arrays the caller owns. Every
# estimator's loop uses these, so a product or a rotation is written once.


@kernel(inline="always")
def qmul_s(a0, a1, a2, a3, b0, b1, b2, b3):
    """Hamilton product a ⊗ b on scalars."""
    return (a0 * b0 - a1 * b1 - a2 * b2 - a3 * b3,
            a0 * b1 + a1 * b0 + a2 * b3 - a3 * b2,
            a0 * b2 - a1 * b3 + a2 * b0 + a3 * b1,
            a0 * b3 + a1 * b2 - a2 * b1 + a3 * b0)


@kernel(inline="always")
def qmul_into(p, q, out):
    """out = p ⊗ q (arrays of 4)."""
    out[0], out[1], out[2], out[3] = qmul_s(p[0], p[1], p[2], p[3], q[0], q[1], q[2], q[3])


@kernel(inline="always")
def exp_s(vx, vy, vz):
    """Exp(v): the unit quaternion of rotation vector v (rad)."""
    a2 = vx * vx + vy * vy + vz * vz
    if a2 < 1e-4:  # |v| < 0.01 rad: Taylor series, exact to rounding (next terms < 1e-17)
        a4 = a2 * a2
        s = 0.5 - a2 * (1.0 / 48.0) + a4 * (1.0 / 3840.0)
        return 1.0 - a2 * 0.125 + a4 * (1.0 / 384.0), vx * s, vy * s, vz * s
    angle = math.sqrt(a2)
    s = math.sin(0.5 * angle) / angle
    return math.cos(0.5 * angle), vx * s, vy * s, vz * s


@kernel(inline="always")
def normalize_into(q, w, x, y, z):
    """q[:4] = [w, x, y, z] / norm."""
    n = 1.0 / math.sqrt(w * w + x * x + y * y + z * z)
    q[0], q[1], q[2], q[3] = w * n, x * n, y * n, z * n


@kernel
def normalize_head(x):
    """The quaternion in x[:4] to unit length, in place (a state vector's attitude part)."""
    n = math.sqrt(x[0] * x[0] + x[1] * x[1] + x[2] * x[2] + x[3] * x[3])
    for i in range(4):
        x[i] /= n


@kernel
def dcm_into(w, x, y, z, c):
    """c = C(q), body -> navigation, for a unit quaternion q."""
    c[0, 0] = 1.0 - 2.0 * (y * y + z * z)
    c[0, 1] = 2.0 * (x * y - w * z)
    c[0, 2] = 2.0 * (x * z + w * y)
    c[1, 0] = 2.0 * (x * y + w * z)
    c[1, 1] = 1.0 - 2.0 * (x * x + z * z)
    c[1, 2] = 2.0 * (y * z - w * x)
    c[2, 0] = 2.0 * (x * z - w * y)
    c[2, 1] = 2.0 * (y * z + w * x)
    c[2, 2] = 1.0 - 2.0 * (x * x + y * y)


@kernel(inline="always")
def dcm_transposed_into(w, x, y, z, M):
    """M = C(q)ᵀ = C(q*) for a unit quaternion q."""
    dcm_into(w, -x, -y, -z, M)


@kernel(inline="always")
def gravity_in_body_s(w, x, y, z, g):
    """C(q)ᵀ [0, 0, -g]: what an accelerometer reads at rest at attitude q (not necessarily
    unit: divided by |q|²), as a tuple."""
    n2 = w * w + x * x + y * y + z * z
    return (-g * 2.0 * (x * z - w * y) / n2, -g * 2.0 * (y * z + w * x) / n2,
            -g * (1.0 - 2.0 * (x * x + y * y) / n2))


@kernel
def rotate_into(q, a, out):
    """out = C(q) a, C in the homogeneous quadratic form (= C(q) at |q| = 1; differentiable
    in q without the unit constraint, as an EKF with q in its state needs)."""
    q0, q1, q2, q3 = q[0], q[1], q[2], q[3]
    out[0] = ((q0 * q0 + q1 * q1 - q2 * q2 - q3 * q3) * a[0] + 2 * (q1 * q2 - q0 * q3) * a[1]
              + 2 * (q1 * q3 + q0 * q2) * a[2])
    out[1] = (2 * (q1 * q2 + q0 * q3) * a[0] + (q0 * q0 - q1 * q1 + q2 * q2 - q3 * q3) * a[1]
              + 2 * (q2 * q3 - q0 * q1) * a[2])
    out[2] = (2 * (q1 * q3 - q0 * q2) * a[0] + 2 * (q2 * q3 + q0 * q1) * a[1]
              + (q0 * q0 - q1 * q1 - q2 * q2 + q3 * q3) * a[2])


@kernel
def right_matrix_into(p, out):
    """R(p), the 4×4 matrix with q ⊗ p = R(p) q."""
    out[0, 0], out[0, 1], out[0, 2], out[0, 3] = p[0], -p[1], -p[2], -p[3]
    out[1, 0], out[1, 1], out[1, 2], out[1, 3] = p[1], p[0], p[3], -p[2]
    out[2, 0], out[2, 1], out[2, 2], out[2, 3] = p[2], -p[3], p[0], p[1]
    out[3, 0], out[3, 1], out[3, 2], out[3, 3] = p[3], p[2], -p[1], p[0]


@kernel
def left_matrix_into(q, out):
    """L(q), the 4×4 matrix with q ⊗ p = L(q) p."""
    out[0, 0], out[0, 1], out[0, 2], out[0, 3] = q[0], -q[1], -q[2], -q[3]
    out[1, 0], out[1, 1], out[1, 2], out[1, 3] = q[1], q[0], -q[3], q[2]
    out[2, 0], out[2, 1], out[2, 2], out[2, 3] = q[2], q[3], q[0], -q[1]
    out[3, 0], out[3, 1], out[3, 2], out[3, 3] = q[3], -q[2], q[1], q[0]


@kernel(inline="always")
def cross_matrix_into(x, y, z, M):
    """M = [v]×, the matrix with [v]× u = v × u."""
    M[0, 0], M[0, 1], M[0, 2] = 0.0, -z, y
    M[1, 0], M[1, 1], M[1, 2] = z, 0.0, -x
    M[2, 0], M[2, 1], M[2, 2] = -y, x, 0.0


@kernel
def euler_s(q0, q1, q2, q3):
    """ZYX Euler angles (roll, pitch, yaw; radians) of a unit quaternion, on scalars."""
    roll = math.atan2(2 * (q0 * q1 + q2 * q3), 1 - 2 * (q1 * q1 + q2 * q2))
    s = 2 * (q0 * q2 - q3 * q1)
    s = 1.0 if s > 1.0 else (-1.0 if s < -1.0 else s)
    pitch = math.asin(s)
    yaw = math.atan2(2 * (q0 * q3 + q1 * q2), 1 - 2 * (q2 * q2 + q3 * q3))
    return roll, pitch, yaw


@kernel
def wrap_pi_s(a):
    """An angle to [-π, π), on a scalar."""
    return (a + math.pi) % (2.0 * math.pi) - math.pi
