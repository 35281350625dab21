"""cpf-ekf's measurement updates (paper 003, eq 11-19): the compass one axis at a time, GPS
velocity and position, baro height, and what keeps the filter observable without them (a
synthetic zero velocity, a heading hold). Each is a scalar Kalman update with a sparse H. The
filter, its paper and the rest of its choices: ``cpf_ekf``.

Choices the paper leaves open, made here:
- Heading: with M a free state, rotating both the attitude and M about the vertical leaves
  every magnetometer reading unchanged, so the yaw would be fixed only by the initial M. A
  declination pseudo-measurement, atan2(M_E, M_N) = declination (σ ``declination_noise_deg``),
  is fused with each compass sample (as PX4's and ArduPilot's EKFs do). M starts from the first
  compass sample turned to NED by the current attitude (the alignment's heading already uses
  the declination).
- Tilt needs velocity or position aiding: the accelerometer enters only through V (the paper
  uses GPS for it and keeps the accelerometer out of the attitude update, its point for a
  vibrating vehicle). Without GPS for ``gps_timeout_s`` (no GPS in the log, before the first
  fix, a dropout), a synthetic zero velocity (σ ``synthetic_vel_noise``) is fused at 5 Hz,
  horizontally, and vertically too when no height source is fresh — the non-aiding mode of
  ArduPilot's and PX4's EKFs. On the first fix after such a spell, V and S are reset to the
  fix (horizontally; vertically too when there is no baro).
- Height from the baro when it is fresh (≤ ``baro_timeout_s``), else from the GPS altitude.
- GPS noise: the reported horizontal accuracy where the log gives it, else ``gps_pos_noise``;
  velocity ``gps_vel_noise``. ``gps_delay_s`` compares the fix with the state that long ago
  (state minus the predicted increments since, a ring buffer; 0: none).
- No magnetometer in the log (or ``use_mag`` false): M and m_b stay unobserved and decoupled
  (no heading states), and the heading is held: before each GPS or synthetic velocity update
  a zero-innovation heading pseudo-measurement (h = ψ(q), the ZYX yaw, H = ∂ψ/∂q, σ
  ``heading_hold_noise_deg``) keeps GPS velocity from moving the yaw and the z gyro bias, as
  ArduPilot's EKF3 does without a yaw source. The yaw is then the gyro's, like every
  estimator without a heading reference (the metrics align its start). Why: GPS velocity
  makes yaw observable only in accelerated flight, and the start yaw without a compass is
  arbitrary (0, or carried over a logging gap while the vehicle turned); an EKF linearised
  about a yaw tens of degrees off turns the velocity innovations into a z gyro bias instead
  (copter-3.3 after its 22 s gap: 0.9°/s, the yaw drifting 180° in 3 minutes; plane-3.1:
  2°/s). The cost: from a wrong start yaw, GPS velocity in strong manoeuvres now pulls the
  tilt instead (simulated figure-eight, start yaw 90° off: 3.5° mean tilt error, where the
  unheld filter happened to turn its yaw right). Aligning the yaw from GPS (EKF3's
  Gaussian-sum yaw estimator) would remove that; it is not done here.
  The watchdog compares roll and pitch only (the CPF has no heading reference then).
- A compass sample is fresh when its row differs from the previous one (the interface holds
  the latest sample on every IMU row), so each is fused once.
- ``innovation_gate``: an optional χ gate (in σ) per scalar update, off by default as in the
  paper.
- Heading-only compass (``mag_tilt`` false; the paper's eq 12-16, ``mag_tilt`` true or
  ``strict``, let the compass correct the whole quaternion): in each axis's update H_q, the
  ∂m/∂q of eq 12-13, is replaced by its component along u = e_z ⊗ q, the direction in which a
  rotation about the vertical moves q: H_q ← (H_q·u) u (h stays eq 11, evaluated at the full
  attitude; ∂m/∂M and ∂m/∂m_b unchanged). The compass is modelled as seeing the heading only;
  the tilt comes from the velocity aiding, as the paper already has it for the accelerometer.
  Why: real compasses sit next to motor and thruster currents. On the real logs the compass
  innovations run at 100-300 mGauss in flight (6× the 50 mGauss noise, and slowly varying
  with the throttle, so not white as R assumes), and through H_q the full update turned them
  into tilt: loggap-fyp-test1 after its gap (2-5° roll/pitch for 100 s, no resets: the CPF's
  compass-driven tilt was as wrong), tipover-quiver088 (compasses inconsistent), the BlueROV
  dives (thrusters). Over the 31 shared logs then (48 now; tilt, ° mean of roll and pitch MAE;
  mahony's median 1.195): median 1.055 → 0.855, mean 1.566 → 1.395, worst log copter-4.1-flight.tlog
  8.28 → 7.88; logs over 1.5× mahony 3 → 0 (worst ratio 3.31 → 1.45, joeydouglas-flight-b,
  no compass, unchanged). Moved most: loggap-fyp-test1 2.195 → 0.943 (3.31 → 1.42×),
  tipover-quiver088 1.055 → 0.481 (2.81 → 1.28×), signalqual027 (sub, no GPS) 1.010 → 0.385
  (2.41 → 0.92×), compasscal-orca-0925 1.509 → 0.998, mission-fyp-test3 1.266 → 0.883,
  mag-anomaly-quiver090 1.046 → 0.684, crash-flip-fyp-test4 1.210 → 1.021; the largest
  losses: aggressive-loggaps-peterbarker1 1.447 → 1.590 (0.61×), nogps-hover-yladzislay
  0.570 → 0.665, upset-peterbarker3 1.042 → 1.109, simtruth-delorean017 0.229 → 0.277. The
  cost on simulated truth with a clean compass (0.002 G white): the paper's static yaw claim
  (±0.2°, p95 0.47° now) and dynamic tilt claim (mean 0.22°, claim 0.1°, test bound 0.15°)
  are met by ``strict`` only, since there the compass's tilt information is real; with a
  0.5 G disturbing field for 30 s the tilt error is 1.4° mean instead of 7° (tests).
  Tried and not kept: (a) the compass's R measured from its innovations (ν² - H P Hᵀ over
  10 s, floored at mag_noise²): with the heading-only update median 0.855 (same), mean
  1.395 → 1.418 (real-plane-bixler 6.65 → 7.46, quiver083 1.79 → 1.90, against loggap
  0.94 → 0.90); alone it left loggap at 1.36/0.66 = 2.1×: interference is correlated in time,
  a larger R does not make it white. (b) Keeping H whole and projecting the gain's attitude
  part on u instead (Joseph form): the innovation's tilt part then went into M and m_b,
  median 1.086, 7 logs over 1.5×. (c) mag_noise 0.05 → 0.2 G with the full update: median
  0.891, mean 1.428, worst ratio 1.45 (it meets the targets, but it is per-corpus tuning and
  costs the heading).
"""
from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np

from ..kernel_cache import kernel
from ..quaternion import normalize_head, right_matrix_into, rotate_into, wrap_pi_s
from .cpf_ekf_model import (A_FILL, A_GPOS, A_GVEL, A_HEAD, A_MAGINIT, A_TBARO, A_TGPS, D_IB, D_IM, D_IP, D_IV, IM,
                            IMB, IS, IV, NX, RING)


# ------------------------------------------------ measurement models


@kernel
def mag_model(x, axis, h_q):
    """Predicted magnetometer axis ``axis`` (eq 11), m = C(q)ᵀ M + m_b, and ∂m/∂q into h_q (4,).
    ∂m/∂M is row ``axis`` of C(q)ᵀ (column of C), ∂m/∂m_b the unit vector: see ``mag_jacobian``."""
    q0, q1, q2, q3 = x[0], x[1], x[2], x[3]
    mn, me, md = x[IM], x[IM + 1], x[IM + 2]
    if axis == 0:
        h = ((q0 * q0 + q1 * q1 - q2 * q2 - q3 * q3) * mn + 2 * (q1 * q2 + q0 * q3) * me
             + 2 * (q1 * q3 - q0 * q2) * md)
        h_q[0] = 2 * (q0 * mn + q3 * me - q2 * md)
        h_q[1] = 2 * (q1 * mn + q2 * me + q3 * md)
        h_q[2] = 2 * (-q2 * mn + q1 * me - q0 * md)
        h_q[3] = 2 * (-q3 * mn + q0 * me + q1 * md)
    elif axis == 1:
        h = (2 * (q1 * q2 - q0 * q3) * mn + (q0 * q0 - q1 * q1 + q2 * q2 - q3 * q3) * me
             + 2 * (q2 * q3 + q0 * q1) * md)
        h_q[0] = 2 * (-q3 * mn + q0 * me + q1 * md)
        h_q[1] = 2 * (q2 * mn - q1 * me + q0 * md)
        h_q[2] = 2 * (q1 * mn + q2 * me + q3 * md)
        h_q[3] = 2 * (-q0 * mn - q3 * me + q2 * md)
    else:
        h = (2 * (q1 * q3 + q0 * q2) * mn + 2 * (q2 * q3 - q0 * q1) * me
             + (q0 * q0 - q1 * q1 - q2 * q2 + q3 * q3) * md)
        h_q[0] = 2 * (q2 * mn - q1 * me + q0 * md)
        h_q[1] = 2 * (q3 * mn - q0 * me - q1 * md)
        h_q[2] = 2 * (q0 * mn + q3 * me - q2 * md)
        h_q[3] = 2 * (q1 * mn + q2 * me + q3 * md)
    return h + x[IMB + axis]


@kernel
def mag_jacobian(x, axis, H):
    """The full 20-element H row of magnetometer axis ``axis`` (eq 12-13), for tests."""
    h_q = np.zeros(4)
    mag_model(x, axis, h_q)
    for k in range(NX):
        H[k] = 0.0
    for k in range(4):
        H[k] = h_q[k]
    c = np.empty(3)  # column ``axis`` of C(q): row ``axis`` of C(q)ᵀ
    e = np.zeros(3)
    e[axis] = 1.0
    rotate_into(x[:4], e, c)
    for k in range(3):
        H[IM + k] = c[k]
    H[IMB + axis] = 1.0


@kernel
def yaw_model(x, h_q):
    """The ZYX yaw ψ of the attitude in ``x`` and ∂ψ/∂q into h_q (4,), from the homogeneous
    form (ψ does not change with |q|): ψ = atan2(n, d), n = 2(q0q3 + q1q2),
    d = q0² + q1² - q2² - q3². Returns NaN where ψ is undefined (n = d = 0: pitch ±90°)."""
    q0, q1, q2, q3 = x[0], x[1], x[2], x[3]
    n = 2.0 * (q0 * q3 + q1 * q2)
    d = q0 * q0 + q1 * q1 - q2 * q2 - q3 * q3
    den = n * n + d * d
    if not (den > 1e-12):
        return math.nan
    # ∂ψ = (d ∂n - n ∂d) / (n² + d²),  ∂n = 2 [q3, q2, q1, q0],  ∂d = 2 [q0, q1, -q2, -q3]
    h_q[0] = 2.0 * (d * q3 - n * q0) / den
    h_q[1] = 2.0 * (d * q2 - n * q1) / den
    h_q[2] = 2.0 * (d * q1 + n * q2) / den
    h_q[3] = 2.0 * (d * q0 + n * q3) / den
    return math.atan2(n, d)



# ------------------------------------------------ scalar updates


@kernel
def _scalar_update(x, P, idx, val, nh, innov, r, gate, pht):
    """One scalar Kalman update with a sparse H (``nh`` entries ``idx``/``val``). Returns the
    innovation variance S, or -1 when skipped (S not positive, or outside the gate)."""
    for j in range(NX):
        s = 0.0
        for k in range(nh):
            s += P[j, idx[k]] * val[k]
        pht[j] = s
    s_inn = r
    for k in range(nh):
        s_inn += val[k] * pht[idx[k]]
    if not (s_inn > 0.0):
        return -1.0
    if gate > 0.0 and innov * innov > gate * gate * s_inn:
        return -1.0
    inv = 1.0 / s_inn
    for j in range(NX):
        x[j] += pht[j] * inv * innov
    for i in range(NX):
        ki = pht[i] * inv
        for j in range(i, NX):
            v = P[i, j] - ki * pht[j]
            P[i, j] = v
            P[j, i] = v
    return s_inn


@kernel
def _state_update(x, P, k, innov, r, gate, pht, idx, val):
    """Scalar update of a directly measured state ``k``."""
    idx[0] = k
    val[0] = 1.0
    return _scalar_update(x, P, idx, val, np.int64(1), innov, r, gate, pht)


@kernel
def hold_heading(x, P, sigma, pht, idx, val, h_q):
    """Zero-innovation heading measurement (no yaw source): the state stays, the yaw's
    variance and its correlations shrink, so the next update cannot turn the yaw."""
    if sigma > 0.0 and yaw_model(x, h_q) == yaw_model(x, h_q):
        for k in range(4):
            idx[k] = k
            val[k] = h_q[k]
        _scalar_update(x, P, idx, val, np.int64(4), 0.0, sigma * sigma, 0.0, pht)


@kernel
def _reset_yaw_covariance(P, x, sigma, rq):
    """Forget what P says of the heading (the attitude's rotation about the vertical) and give
    it variance σ²: P ← T P Tᵀ + ¼σ² u uᵀ, T = I - u uᵀ on the q block, u = e_z ⊗ q."""
    right_matrix_into(x, rq)  # column 3: e_z ⊗ q, unit
    u0, u1, u2, u3 = rq[0, 3], rq[1, 3], rq[2, 3], rq[3, 3]
    for c in range(NX):  # T P: remove the u component of each column's q part
        s = u0 * P[0, c] + u1 * P[1, c] + u2 * P[2, c] + u3 * P[3, c]
        P[0, c] -= s * u0
        P[1, c] -= s * u1
        P[2, c] -= s * u2
        P[3, c] -= s * u3
    for r in range(NX):  # (T P) Tᵀ
        s = u0 * P[r, 0] + u1 * P[r, 1] + u2 * P[r, 2] + u3 * P[r, 3]
        P[r, 0] -= s * u0
        P[r, 1] -= s * u1
        P[r, 2] -= s * u2
        P[r, 3] -= s * u3
    v = 0.25 * sigma * sigma
    for r in range(4):
        for c in range(4):
            P[r, c] += v * rq[r, 3] * rq[c, 3]
    for r in range(4):  # exactly symmetric
        for c in range(r + 1, NX):
            m = 0.5 * (P[r, c] + P[c, r])
            P[r, c] = m
            P[c, r] = m



class Work(NamedTuple):
    """Scratch arrays of the measurement updates and the reset (allocated once per chunk)."""
    vec: np.ndarray  # (3,) a body vector...
    ned: np.ndarray  # (3,) ...turned to NED
    col: np.ndarray  # (3,) a column of C(q)
    unit: np.ndarray  # (3,) a unit vector
    rq: np.ndarray  # (4, 4) R(q)
    pht: np.ndarray  # (NX,) P Hᵀ of a scalar update, with H's nonzero entries idx, val
    idx: np.ndarray
    val: np.ndarray
    h_q: np.ndarray  # (4,) ∂h/∂q of a scalar measurement
    bias_var: np.ndarray  # (6,) P₀'s bias diagonal at a reset
    body_field_var: np.ndarray  # (3,)


@kernel
def new_work():
    """A ``Work`` for one chunk."""
    return Work(vec=np.empty(3), ned=np.empty(3), col=np.empty(3), unit=np.zeros(3), rq=np.empty((4, 4)),
                pht=np.empty(NX), idx=np.zeros(8, dtype=np.int64), val=np.zeros(8), h_q=np.empty(4),
                bias_var=np.empty(6), body_field_var=np.empty(3))



# ------------------------------------------------ measurement updates (eq 11-19)


@kernel
def start_earth_field(x, mg0, mg1, mg2, cfg, wk):
    """M from a compass sample (gauss) through the current attitude, its horizontal part along
    the declination (the heading's reference), with P_M = σ₀² I and no correlations."""
    wk.vec[0], wk.vec[1], wk.vec[2] = mg0 - x[IMB], mg1 - x[IMB + 1], mg2 - x[IMB + 2]
    rotate_into(x, wk.vec, wk.ned)
    hmag = math.sqrt(wk.ned[0] * wk.ned[0] + wk.ned[1] * wk.ned[1])
    wk.ned[0], wk.ned[1] = hmag * math.cos(cfg.declination), hmag * math.sin(cfg.declination)
    for r in range(3):
        x[IM + r] = wk.ned[r]


@kernel
def fuse_compass(x, P, aux, mg0, mg1, mg2, cfg, wk, drow):
    """Eq 11-16: a fresh compass sample (gauss), one axis at a time, then the declination
    pseudo-measurement. The first sample starts M instead. Unless ``mag_tilt``, ∂m/∂q keeps
    only its component along u = e_z ⊗ q, a rotation about the vertical (H_q ← (H_q·u) u):
    the compass is modelled as seeing the heading, not the tilt; h itself stays eq 11."""
    idx, val, pht, h_q = wk.idx, wk.val, wk.pht, wk.h_q
    if aux[A_MAGINIT] < 0.5:
        start_earth_field(x, mg0, mg1, mg2, cfg, wk)
        for r in range(3):
            for c in range(NX):
                P[IM + r, c] = 0.0
                P[c, IM + r] = 0.0
            P[IM + r, IM + r] = cfg.earth_field_sigma0 ** 2
        # the compass is the heading's reference from now: its uncertainty is σ₀ again,
        # whatever a heading hold before this first sample made of it
        _reset_yaw_covariance(P, x, cfg.yaw_sigma0, wk.rq)
        aux[A_MAGINIT] = 1.0
        return
    r_mag = cfg.mag_noise ** 2
    tilt = cfg.mag_tilt > 0.5
    for axis in range(3):
        hval = mag_model(x, axis, h_q)
        if not tilt:  # heading only: ∂m/∂q reduced to its part along u = e_z ⊗ q (a rotation about the vertical)
            right_matrix_into(x, wk.rq)
            hu = h_q[0] * wk.rq[0, 3] + h_q[1] * wk.rq[1, 3] + h_q[2] * wk.rq[2, 3] + h_q[3] * wk.rq[3, 3]
            for k in range(4):
                h_q[k] = hu * wk.rq[k, 3]
        wk.unit[0], wk.unit[1], wk.unit[2] = 0.0, 0.0, 0.0
        wk.unit[axis] = 1.0
        rotate_into(x, wk.unit, wk.col)
        for k in range(4):
            idx[k] = k
            val[k] = h_q[k]
        for k in range(3):
            idx[4 + k] = IM + k
            val[4 + k] = wk.col[k]
        idx[7] = IMB + axis
        val[7] = 1.0
        z = mg0 if axis == 0 else (mg1 if axis == 1 else mg2)
        innov = z - hval
        if _scalar_update(x, P, idx, val, np.int64(8), innov, r_mag, cfg.innovation_gate, pht) > 0.0:
            drow[D_IM + axis] = innov * 1e3
        normalize_head(x)
    # declination pseudo-measurement: atan2(M_E, M_N) = declination
    mn, me = x[IM], x[IM + 1]
    hh = mn * mn + me * me
    if hh > 0.0:
        idx[0], idx[1] = IM, IM + 1
        val[0], val[1] = -me / hh, mn / hh
        innov = wrap_pi_s(cfg.declination - math.atan2(me, mn))
        _scalar_update(x, P, idx, val, np.int64(2), innov, cfg.declination_noise ** 2, 0.0, pht)
        normalize_head(x)


@kernel
def fuse_baro(x, P, ti, height, aux, cfg, wk, drow):
    """Eq 19's height: baro height (m, up) on S_d."""
    aux[A_TBARO] = ti
    innov = -height - x[IS + 2]
    if _state_update(x, P, IS + 2, innov, cfg.baro_noise ** 2, cfg.innovation_gate, wk.pht, wk.idx, wk.val) > 0.0:
        drow[D_IB] = innov
    normalize_head(x)


@kernel
def fuse_gps(x, P, ring, aux, ti, pos, vel, hacc, vacc, gps_active, baro_fresh, cfg, wk, drow):
    """Eq 17-19: a GPS fix (NED position and velocity, NaN where the fix has none), compared
    with the state ``gps_delay`` ago; on the first fix after a spell without GPS, V and S are
    set to it instead."""
    r_gv = cfg.gps_vel_noise ** 2
    gate = cfg.innovation_gate
    pht, idx, val = wk.pht, wk.idx, wk.val
    has_pos, has_vel = pos[0] == pos[0], vel[0] == vel[0]
    # the state at the fix's time: now minus the predicted increments since
    sv0 = sv1 = sv2 = ss0 = ss1 = ss2 = 0.0
    if cfg.gps_delay > 0.0:
        h = int(aux[A_HEAD])
        for k in range(int(aux[A_FILL])):
            h = (h - 1) % RING
            if ring[h, 0] <= ti - cfg.gps_delay:
                break
            sv0 += ring[h, 1]
            sv1 += ring[h, 2]
            sv2 += ring[h, 3]
            ss0 += ring[h, 4]
            ss1 += ring[h, 5]
            ss2 += ring[h, 6]
    if not gps_active:
        # (re)start aiding: take the fix as it is
        for r in range(3):
            zv = vel[r] if has_vel else math.nan
            zp = pos[r] if has_pos else math.nan
            if r == 2 and baro_fresh:
                zp = math.nan
            if zv == zv:
                x[IV + r] = zv + (sv0 if r == 0 else (sv1 if r == 1 else sv2))
                for c in range(NX):
                    P[IV + r, c] = 0.0
                    P[c, IV + r] = 0.0
                P[IV + r, IV + r] = r_gv
            if zp == zp:
                x[IS + r] = zp + (ss0 if r == 0 else (ss1 if r == 1 else ss2))
                for c in range(NX):
                    P[IS + r, c] = 0.0
                    P[c, IS + r] = 0.0
                sp = hacc if (r < 2 and hacc == hacc) else cfg.gps_pos_noise
                if r == 2:
                    sp = vacc if vacc == vacc else cfg.gps_alt_noise
                P[IS + r, IS + r] = sp * sp
    else:
        if has_vel:
            for r in range(3):
                zv = vel[r]
                if zv == zv:
                    innov = zv - (x[IV + r] - (sv0 if r == 0 else (sv1 if r == 1 else sv2)))
                    if _state_update(x, P, IV + r, innov, r_gv, gate, pht, idx, val) > 0.0:
                        drow[D_IV + r] = innov
                    normalize_head(x)
        if has_pos:
            sp = hacc if hacc == hacc else cfg.gps_pos_noise
            sp = max(sp, cfg.gps_pos_noise_min)
            for r in range(3):
                if r == 2:
                    if baro_fresh:
                        break
                    sp = vacc if vacc == vacc else cfg.gps_alt_noise
                innov = pos[r] - (x[IS + r] - (ss0 if r == 0 else (ss1 if r == 1 else ss2)))
                if _state_update(x, P, IS + r, innov, sp * sp, gate, pht, idx, val) > 0.0:
                    drow[D_IP + r] = innov
                normalize_head(x)
    aux[A_TGPS] = ti
    for r in range(3):
        if has_vel:
            aux[A_GVEL + r] = vel[r]
        if has_pos:
            aux[A_GPOS + r] = pos[r]


@kernel
def fuse_zero_velocity(x, P, baro_fresh, cfg, wk):
    """Non-aiding mode: a synthetic zero velocity keeps the tilt observable without GPS
    (vertically too when no height source is fresh)."""
    r_syn = cfg.synthetic_vel_noise ** 2
    for r in range(3):
        if r == 2 and baro_fresh:
            break
        _state_update(x, P, IV + r, -x[IV + r], r_syn, 0.0, wk.pht, wk.idx, wk.val)
        normalize_head(x)

