"""eq-kf's equations (paper 002): the 3rd-order Picard step (eq 5, 6), the error dynamics of
the error quaternion (eq 13) and the accelerometer and magnetometer models with their Jacobians,
then the steps of one sample that ``eqkf_run`` takes in order: the prediction, the
accelerometer's bookkeeping, the consistency test, the accelerometer update with its trust and
the magnetometer's heading update. What each computes and why: ``eq_kf``'s docstring.
"""
from __future__ import annotations

import numpy as np
from numba import njit

from ..quaternion import dcm_into, qmul_into
from .consistency import attitude_error, carried, step_rotation_into


# ---------------------------------------------------------------- model functions (njit)
# Written with output arguments so the kernel calls them without allocating; the tests call
# the same functions to check them against finite differences and the exact rotation.


@njit(cache=True)
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


@njit(cache=True)
def error_transition(dtheta, dt, a, b):
    """Φ's blocks for one step: a = C(p̂)ᵀ (∂e'/∂e), b = -½Δt (I - ½[Δθ]×) (∂e'/∂β)."""
    dx, dy, dz = dtheta[0], dtheta[1], dtheta[2]
    step_rotation_into(dx, dy, dz, a)  # a = C(p̂)ᵀ, p the Picard step's rotation
    h = -0.5 * dt
    k = 0.25 * dt  # b = -½Δt I + ¼Δt [Δθ]×
    b[0, 0], b[0, 1], b[0, 2] = h, -k * dz, k * dy
    b[1, 0], b[1, 1], b[1, 2] = k * dz, h, -k * dx
    b[2, 0], b[2, 1], b[2, 2] = -k * dy, k * dx, h


@njit(cache=True)
def _error_quaternion(e):
    """Q_e = [√(1 - |e|²), e] from its vector part (allocates: tests and setup only)."""
    s = e[0] * e[0] + e[1] * e[1] + e[2] * e[2]
    return np.array([np.sqrt(max(1.0 - s, 0.0)), e[0], e[1], e[2]])


@njit(cache=True)
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


@njit(cache=True)
def accel_predict(qbar, e, out):
    """h(e) = C(Q̄ ⊗ Q_e)ᵀ [0, 0, -1]: the accelerometer direction the attitude predicts."""
    q = np.empty(4)
    qmul_into(qbar, _error_quaternion(e), q)
    w, x, y, z = q[0], q[1], q[2], q[3]
    out[0] = -2.0 * (x * z - w * y)
    out[1] = -2.0 * (y * z + w * x)
    out[2] = -(1.0 - 2.0 * (x * x + y * y))


@njit(cache=True)
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


@njit(cache=True)
def accel_jacobian(h, t, hm):
    """hm (2×3) = ∂(Tᵀ h(e))/∂e at e = 0 = Tᵀ 2[h̄]×, rows 2 (tᵢ × h̄)."""
    for r in range(2):
        hm[r, 0] = 2.0 * (t[r, 1] * h[2] - t[r, 2] * h[1])
        hm[r, 1] = 2.0 * (t[r, 2] * h[0] - t[r, 0] * h[2])
        hm[r, 2] = 2.0 * (t[r, 0] * h[1] - t[r, 1] * h[0])


@njit(cache=True)
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


@njit(cache=True)
def mag_jacobian(qbar, hm):
    """hm (3,) = ∂(azimuth)/∂e at e = 0 = 2 × third row of C(Q̄)."""
    w, x, y, z = qbar[0], qbar[1], qbar[2], qbar[3]
    hm[0] = 2.0 * 2.0 * (x * z - w * y)
    hm[1] = 2.0 * 2.0 * (y * z + w * x)
    hm[2] = 2.0 * (1.0 - 2.0 * (x * x + y * y))


@njit(cache=True)
def ramp(x, lo, hi):
    if x <= lo:
        return 1.0
    if x >= hi:
        return 0.0
    return (hi - x) / (hi - lo)


@njit(cache=True)
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


# ---------------------------------------------------------------- the steps of a sample (inlined in eqkf_run)


@njit(cache=True, inline="always")
def _tangent_update(p, ph, s00, s01, s11, r0, r1, rr, x):
    """The 2-D tangent-plane update with measurement variance rr per axis: K = P Hᵀ S⁻¹ (6×2);
    x = K r; P ← P - K (P Hᵀ)ᵀ, upper triangle mirrored."""
    sa, sb = s00 + rr, s11 + rr
    idet = 1.0 / (sa * sb - s01 * s01)
    i00, i01, i11 = sb * idet, -s01 * idet, sa * idet
    for r in range(6):
        k0 = ph[r, 0] * i00 + ph[r, 1] * i01
        k1 = ph[r, 0] * i01 + ph[r, 1] * i11
        x[r] = k0 * r0 + k1 * r1
        for c in range(r, 6):
            s = p[r, c] - (k0 * ph[c, 0] + k1 * ph[c, 1])
            p[r, c] = s
            p[c, r] = s


@njit(cache=True, inline="always")
def predict(q, p, a, b, tp, dth, qn, rx, ry, rz, dwx, dwy, dwz, dt, cfg):
    """The prediction: Picard attitude step (eq 5) of the bias-corrected rate r, then
    P ← Φ P Φᵀ + Q, the integration noise from the rate change dw across the step. Leaves Φ's
    blocks in ``a`` (C(p̂)ᵀ, which carries body vectors across the step) and ``b``."""
    dth[0], dth[1], dth[2] = rx * dt, ry * dt, rz * dt
    picard_step(q, dth, qn)
    inv = 1.0 / np.sqrt(qn[0] * qn[0] + qn[1] * qn[1] + qn[2] * qn[2] + qn[3] * qn[3])
    for k in range(4):
        q[k] = qn[k] * inv
    error_transition(dth, dt, a, b)
    qe_var = 0.25 * cfg.gyro_noise * cfg.gyro_noise
    kint2 = cfg.int_noise * cfg.int_noise
    q_e = qe_var * dt + 0.25 * kint2 * (dwx * dwx + dwy * dwy + dwz * dwz) * dt * dt
    # tp = rows 0-2 of Φ P
    for r in range(3):
        for c in range(6):
            tp[r, c] = (a[r, 0] * p[0, c] + a[r, 1] * p[1, c] + a[r, 2] * p[2, c]
                        + b[r, 0] * p[3, c] + b[r, 1] * p[4, c] + b[r, 2] * p[5, c])
    # P_ee = tp Φ[0:3]ᵀ (upper triangle, mirrored); P_eb = tp[:, 3:6]; P_bb += Q_b
    for r in range(3):
        for c in range(r, 3):
            s = (tp[r, 0] * a[c, 0] + tp[r, 1] * a[c, 1] + tp[r, 2] * a[c, 2]
                 + tp[r, 3] * b[c, 0] + tp[r, 4] * b[c, 1] + tp[r, 5] * b[c, 2])
            if r == c:
                s += q_e
            p[r, c] = s
            p[c, r] = s
        for c in range(3, 6):
            p[r, c] = tp[r, c]
            p[c, r] = tp[r, c]
    qb_var = cfg.bias_walk * cfg.bias_walk
    for r in range(3, 6):
        p[r, r] += qb_var * dt


@njit(cache=True, inline="always")
def track_accel(a, lp0, lp1, lp2, dir0, dir1, dir2, vib, ax, ay, az, an, accel_ok, carried_on, dt, cfg):
    """The accelerometer's bookkeeping, every vector carried along with the body rotation
    (v ← C(p̂)ᵀ v, ``a``) where ``carried_on`` (a step with a good reading): the low-pass f̃
    and the direction noise σ_vib². Returns f̃, the reading's direction and σ_vib²."""
    if carried_on and lp0 == lp0:
        f0, f1, f2 = carried(a, lp0, lp1, lp2)
        alpha = dt / (cfg.trust_lpf + dt)
        lp0 = f0 + alpha * (ax - f0)
        lp1 = f1 + alpha * (ay - f1)
        lp2 = f2 + alpha * (az - f2)
        if dir0 == dir0:
            # |Δu|² = 2 axes × 2 samples × σ², so σ² per axis = |Δu|²/4
            d0 = ax / an - (a[0, 0] * dir0 + a[0, 1] * dir1 + a[0, 2] * dir2)
            d1 = ay / an - (a[1, 0] * dir0 + a[1, 1] * dir1 + a[1, 2] * dir2)
            d2 = az / an - (a[2, 0] * dir0 + a[2, 1] * dir1 + a[2, 2] * dir2)
            vib += dt / (cfg.vib_time + dt) * (0.25 * (d0 * d0 + d1 * d1 + d2 * d2) - vib)
    elif accel_ok:  # start, after a gap or a bad sample: restart the low-pass here
        lp0, lp1, lp2 = ax, ay, az
    if accel_ok:
        dir0, dir1, dir2 = ax / an, ay / an, az / an
    else:
        dir0 = np.nan
    return lp0, lp1, lp2, dir0, dir1, dir2, vib


@njit(cache=True, inline="always")
def _consistency(p, hv, lp0, lp1, lp2, fn, eps, w_rate, cons_t, dt, cos_tol, sin_tol, cfg):
    """The consistency test: the residual angle ρ (f̃ against predicted gravity h̄) beyond the
    angle φ_m a horizontal acceleration would explain given ‖f̃‖, held for cons_time with
    ‖f̃‖ ≈ g and modest rotation, is attitude error, not a manoeuvre: the attitude covariance
    is raised so that the residual sits at gate_lo σ. Returns the seconds inconsistent so far."""
    cosr = (lp0 * hv[0] + lp1 * hv[1] + lp2 * hv[2]) / fn
    inconsistent = False
    if w_rate >= 1.0 and abs(eps) < cfg.cons_norm:
        inconsistent = attitude_error(cosr, eps, cos_tol, sin_tol)
    if inconsistent:
        cons_t += dt
    else:
        cons_t = 0.0
    if cons_t >= cfg.cons_time:
        rho = np.arccos(min(max(cosr, -1.0), 1.0))
        target = (0.5 * rho / cfg.gate_lo) ** 2
        for k in range(3):
            if p[k, k] < target:
                p[k, k] = target
    return cons_t


@njit(cache=True, inline="always")
def _residual(tb, hv, u0, u1, u2, sa, sb, s01):
    """A direction u's residual in the tangent plane, r = Tᵀ (u - h̄), and its normalised
    square d² = rᵀ S_g⁻¹ r, S_g = [[sa, s01], [s01, sb]]."""
    e0, e1, e2 = u0 - hv[0], u1 - hv[1], u2 - hv[2]
    r0 = tb[0, 0] * e0 + tb[0, 1] * e1 + tb[0, 2] * e2
    r1 = tb[1, 0] * e0 + tb[1, 1] * e1 + tb[1, 2] * e2
    return r0, r1, (sb * r0 * r0 - 2.0 * s01 * r0 * r1 + sa * r1 * r1) / (sa * sb - s01 * s01)


@njit(cache=True, inline="always")
def accel_update(q, bias, p, x, qn, hv, tb, hm, ph, ax, ay, az, an, lp0, lp1, lp2, fn, rate2, dt, still, g_a,
                  vib, cons_t, w_prev, low, i, cos_tol, sin_tol, cfg):
    """The accelerometer update with trust w (see ``eq_kf``'s docstring); where w = 0 and
    ``cfg.fallback``, the low-passed reading ``low[i]`` through the norm and residual tests.
    Returns w, the seconds inconsistent so far and whether the low-passed reading was used."""
    w_, x_, y_, z_ = q[0], q[1], q[2], q[3]
    hv[0] = -2.0 * (x_ * z_ - w_ * y_)  # C(Q̄)ᵀ [0, 0, -1]
    hv[1] = -2.0 * (y_ * z_ + w_ * x_)
    hv[2] = -(1.0 - 2.0 * (x_ * x_ + y_ * y_))
    accel_tangent(hv, tb)
    accel_jacobian(hv, tb, hm)
    eps = fn / g_a - 1.0
    w_norm = ramp(abs(eps), cfg.norm_lo, cfg.norm_hi)
    rate_lo = cfg.rate_lo
    w_rate = 1.0 if rate2 <= rate_lo * rate_lo else ramp(np.sqrt(rate2), rate_lo, cfg.rate_hi)
    cons_t = _consistency(p, hv, lp0, lp1, lp2, fn, eps, w_rate, cons_t, dt, cos_tol, sin_tol, cfg)
    # P Hᵀ (6×2) and H P Hᵀ (2×2)
    for r in range(6):
        for j in range(2):
            ph[r, j] = p[r, 0] * hm[j, 0] + p[r, 1] * hm[j, 1] + p[r, 2] * hm[j, 2]
    s00 = hm[0, 0] * ph[0, 0] + hm[0, 1] * ph[1, 0] + hm[0, 2] * ph[2, 0]
    s01 = hm[0, 0] * ph[0, 1] + hm[0, 1] * ph[1, 1] + hm[0, 2] * ph[2, 1]
    s11 = hm[1, 0] * ph[0, 1] + hm[1, 1] * ph[1, 1] + hm[1, 2] * ph[2, 1]
    # the reading's residual against S_g = H P Hᵀ + (σ_gate² + σ_vib²) I
    gate_var = cfg.gate_noise * cfg.gate_noise
    sa, sb = s00 + gate_var + vib, s11 + gate_var + vib
    r0, r1, d2 = _residual(tb, hv, ax / an, ay / an, az / an, sa, sb, s01)
    gate_lo, gate_hi = cfg.gate_lo, cfg.gate_hi
    w_res = 1.0 if still or d2 <= gate_lo * gate_lo else ramp(np.sqrt(d2), gate_lo, gate_hi)
    # trust falls at once but rises at most 1/trust_rise per second
    w_acc = min(w_norm * w_rate * w_res, w_prev + dt / cfg.trust_rise)
    acc_var = cfg.accel_noise * cfg.accel_noise
    if w_acc > 0.0:
        _tangent_update(p, ph, s00, s01, s11, r0, r1, acc_var / (dt * w_acc), x)  # R = R₀ / w, R₀ = σ_a²/Δt
        inject(q, bias, x, qn)
        return w_acc, cons_t, False
    if cfg.fallback:  # the reading refused: the low-passed one through the norm and residual tests
        l0, l1, l2 = low[i, 0], low[i, 1], low[i, 2]
        ln = np.sqrt(l0 * l0 + l1 * l1 + l2 * l2)
        if ln > 0.0:
            r0, r1, d2 = _residual(tb, hv, l0 / ln, l1 / ln, l2 / ln, sa, sb, s01)
            w_low = ramp(abs(ln / g_a - 1.0), cfg.norm_lo, cfg.norm_hi)
            if d2 > gate_lo * gate_lo:
                w_low *= ramp(np.sqrt(d2), gate_lo, gate_hi)
            if w_low > 0.0:
                _tangent_update(p, ph, s00, s01, s11, r0, r1, acc_var / (dt * w_low), x)
                inject(q, bias, x, qn)
                return w_acc, cons_t, True
    return w_acc, cons_t, False


@njit(cache=True, inline="always")
def mag_update(q, bias, p, x, qn, hm3, v6, m0, m1, m2, cdec, sdec, dt, cfg):
    """The magnetometer's heading update (scalar): the innovation γ = declination - azimuth of
    the field's horizontal part in the navigation frame, R_m = σ_m²/Δt."""
    w_, x_, y_, z_ = q[0], q[1], q[2], q[3]
    mx = ((1.0 - 2.0 * (y_ * y_ + z_ * z_)) * m0 + 2.0 * (x_ * y_ - w_ * z_) * m1
          + 2.0 * (x_ * z_ + w_ * y_) * m2)
    my = (2.0 * (x_ * y_ + w_ * z_) * m0 + (1.0 - 2.0 * (x_ * x_ + z_ * z_)) * m1
          + 2.0 * (y_ * z_ - w_ * x_) * m2)
    if mx * mx + my * my > 0.0:
        # innovation γ = declination - azimuth(m_h): signed angle from m_h to magnetic north
        gamma = np.arctan2(mx * sdec - my * cdec, mx * cdec + my * sdec)
        mag_jacobian(q, hm3)
        for r in range(6):
            v6[r] = p[r, 0] * hm3[0] + p[r, 1] * hm3[1] + p[r, 2] * hm3[2]
        s = hm3[0] * v6[0] + hm3[1] * v6[1] + hm3[2] * v6[2] + cfg.mag_noise * cfg.mag_noise / dt
        for r in range(6):
            kr = v6[r] / s
            x[r] = kr * gamma
            for c in range(r, 6):
                pv = p[r, c] - kr * v6[c]
                p[r, c] = pv
                p[c, r] = pv
        inject(q, bias, x, qn)

