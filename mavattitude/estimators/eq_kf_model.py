"""eq-kf's equations (paper 002): the 3rd-order Picard step (eq 5, 6), the error dynamics of
the error quaternion (eq 13), the accelerometer and magnetometer models with their Jacobians,
and the error's injection into the attitude. The filter that runs them, and why each is as it
is: ``eq_kf``.
"""
from __future__ import annotations

import numpy as np

from ..kernel_cache import kernel
from ..quaternion import dcm_into, qmul_into
from .consistency import step_rotation_into


# ---------------------------------------------------------------- model functions (compiled)
# Written with output arguments so the kernel calls them without allocating; the tests call
# the same functions to check them against finite differences and the exact rotation.


@kernel
def picard_step(q, dtheta, out):
    """Eq 5 to 3rd order: out = [(1 - Δθ₀²/8) I + (½ - Δθ₀²/48) Ω(Δθ)] q (not normalised)."""
    dx, dy, dz = dtheta[0], dtheta[1], dtheta[2]
    th2 = dx * dx + dy * dy + dz * dz
    c0 = 1.0 - th2 / 8.0
    c1 = 0.5 - th2 / 48.0
    w, x, y, z = q[0], q[1], q[2], q[3]
    # Ω(Δθ) q, rows of Ω as in ALGORITHMS.md "Conventions"
    o0 = -dx * x - dy * y - dz * z
    o1 = dx * w + dz * y - dy * z
    o2 = dy * w - dz * x + dx * z
    o3 = dz * w + dy * x - dx * y
    out[0] = c0 * w + c1 * o0
    out[1] = c0 * x + c1 * o1
    out[2] = c0 * y + c1 * o2
    out[3] = c0 * z + c1 * o3


@kernel
def error_transition(dtheta, dt, a, b):
    """Φ's blocks for one step: a = C(p̂)ᵀ (∂e'/∂e), b = -½Δt (I - ½[Δθ]×) (∂e'/∂β)."""
    dx, dy, dz = dtheta[0], dtheta[1], dtheta[2]
    step_rotation_into(dx, dy, dz, a)  # a = C(p̂)ᵀ, p the Picard step's rotation
    h = -0.5 * dt
    k = 0.25 * dt  # b = -½Δt I + ¼Δt [Δθ]×
    b[0, 0], b[0, 1], b[0, 2] = h, -k * dz, k * dy
    b[1, 0], b[1, 1], b[1, 2] = k * dz, h, -k * dx
    b[2, 0], b[2, 1], b[2, 2] = -k * dy, k * dx, h


@kernel
def _error_quaternion(e):
    """Q_e = [√(1 - |e|²), e] from its vector part (allocates: tests and setup only)."""
    s = e[0] * e[0] + e[1] * e[1] + e[2] * e[2]
    return np.array([np.sqrt(max(1.0 - s, 0.0)), e[0], e[1], e[2]])


@kernel
def error_propagate(e, beta, rate, dt, out):
    """The nonlinear error step the Jacobians linearise: out = vec(p̂(Δθ)⁻¹ ⊗ Q_e ⊗ p̂(Δθ - βΔt)),
    Δθ = rate·Δt, p̂ the normalised Picard increment (tests only; allocates)."""
    one = np.array([1.0, 0.0, 0.0, 0.0])
    p1 = np.empty(4)
    picard_step(one, rate * dt, p1)
    p1 /= np.sqrt(np.sum(p1 * p1))
    p2 = np.empty(4)
    picard_step(one, (rate - beta) * dt, p2)
    p2 /= np.sqrt(np.sum(p2 * p2))
    p1inv = np.array([p1[0], -p1[1], -p1[2], -p1[3]])
    tmp = np.empty(4)
    res = np.empty(4)
    qmul_into(p1inv, _error_quaternion(e), tmp)
    qmul_into(tmp, p2, res)
    if res[0] < 0.0:
        res = -res
    out[0], out[1], out[2] = res[1], res[2], res[3]


@kernel
def accel_predict(qbar, e, out):
    """h(e) = C(Q̄ ⊗ Q_e)ᵀ [0, 0, -1]: the accelerometer direction the attitude predicts."""
    q = np.empty(4)
    qmul_into(qbar, _error_quaternion(e), q)
    w, x, y, z = q[0], q[1], q[2], q[3]
    out[0] = -2.0 * (x * z - w * y)
    out[1] = -2.0 * (y * z + w * x)
    out[2] = -(1.0 - 2.0 * (x * x + y * y))


@kernel
def accel_tangent(h, t):
    """Rows of t (2×3): an orthonormal basis of the plane ⟂ the unit vector h."""
    ax, ay, az = abs(h[0]), abs(h[1]), abs(h[2])
    # t₁ = normalise(e_k × h) with e_k the axis least aligned with h
    if ax <= ay and ax <= az:
        t0, t1, t2 = 0.0, -h[2], h[1]
    elif ay <= az:
        t0, t1, t2 = h[2], 0.0, -h[0]
    else:
        t0, t1, t2 = -h[1], h[0], 0.0
    inv = 1.0 / np.sqrt(t0 * t0 + t1 * t1 + t2 * t2)
    t0, t1, t2 = t0 * inv, t1 * inv, t2 * inv
    t[0, 0], t[0, 1], t[0, 2] = t0, t1, t2
    # t₂ = h × t₁
    t[1, 0] = h[1] * t2 - h[2] * t1
    t[1, 1] = h[2] * t0 - h[0] * t2
    t[1, 2] = h[0] * t1 - h[1] * t0


@kernel
def accel_jacobian(h, t, hm):
    """hm (2×3) = ∂(Tᵀ h(e))/∂e at e = 0 = Tᵀ 2[h̄]×, rows 2 (tᵢ × h̄)."""
    for r in range(2):
        hm[r, 0] = 2.0 * (t[r, 1] * h[2] - t[r, 2] * h[1])
        hm[r, 1] = 2.0 * (t[r, 2] * h[0] - t[r, 0] * h[2])
        hm[r, 2] = 2.0 * (t[r, 0] * h[1] - t[r, 1] * h[0])


@kernel
def mag_predict(qbar, e, u):
    """h(e) = azimuth (rad) of C(Q̄ ⊗ Q_e) u, u the body-frame image of the field's
    horizontal part (see ``eq_kf``'s docstring)."""
    q = np.empty(4)
    qmul_into(qbar, _error_quaternion(e), q)
    c = np.empty((3, 3))
    dcm_into(q[0], q[1], q[2], q[3], c)
    vx = c[0, 0] * u[0] + c[0, 1] * u[1] + c[0, 2] * u[2]
    vy = c[1, 0] * u[0] + c[1, 1] * u[1] + c[1, 2] * u[2]
    return np.arctan2(vy, vx)


@kernel
def mag_jacobian(qbar, hm):
    """hm (3,) = ∂(azimuth)/∂e at e = 0 = 2 × third row of C(Q̄)."""
    w, x, y, z = qbar[0], qbar[1], qbar[2], qbar[3]
    hm[0] = 2.0 * 2.0 * (x * z - w * y)
    hm[1] = 2.0 * 2.0 * (y * z + w * x)
    hm[2] = 2.0 * (1.0 - 2.0 * (x * x + y * y))


@kernel
def ramp(x, lo, hi):
    if x <= lo:
        return 1.0
    if x >= hi:
        return 0.0
    return (hi - x) / (hi - lo)


@kernel
def inject(q, bias, x, qtmp):
    """Q̄ ← Q̄ ⊗ [√(1-|e|²), e] (normalised), b̂ ← b̂ + β."""
    s = x[0] * x[0] + x[1] * x[1] + x[2] * x[2]
    if s < 1.0:
        ew, ex, ey, ez = np.sqrt(1.0 - s), x[0], x[1], x[2]
    else:
        r = 1.0 / np.sqrt(s)
        ew, ex, ey, ez = 0.0, x[0] * r, x[1] * r, x[2] * r
    w, a, b, c = q[0], q[1], q[2], q[3]
    qtmp[0] = w * ew - a * ex - b * ey - c * ez
    qtmp[1] = w * ex + a * ew + b * ez - c * ey
    qtmp[2] = w * ey - a * ez + b * ew + c * ex
    qtmp[3] = w * ez + a * ey - b * ex + c * ew
    inv = 1.0 / np.sqrt(qtmp[0] * qtmp[0] + qtmp[1] * qtmp[1] + qtmp[2] * qtmp[2] + qtmp[3] * qtmp[3])
    for k in range(4):
        q[k] = qtmp[k] * inv
    for k in range(3):
        bias[k] += x[3 + k]
