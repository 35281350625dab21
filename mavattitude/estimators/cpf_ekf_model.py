"""cpf-ekf's state and its prediction (paper 003, eq 1-10): the layout of the 20 numbers, the
settings as the kernel takes them, the step f(x) and its Jacobian F, P₀. The filter, its paper and
the rest of its choices: ``cpf_ekf``.

Jacobians (the printed F and G blocks of eq 8 and 10 have typos, e.g. a₃ and all of b, c; they
are derived here and checked against finite differences in tests/test_cpf_ekf.py). With
L(q), R(p) the matrices of q ⊗ p = L(q) p = R(p) q, Exp(v) = [cos ½|v|, sin ½|v| v/|v|] and
D(v) = ∂Exp(v)/∂v (4×3):
    F_qq = R(Exp(φ))                 (exact: q ⊗ Exp(φ) is linear in q; the paper's F_4×4 is
                                     its first-order form I + ½Ω(ω-ω_b)Δt, printed without Δt)
    F_qω = -Δt L(q) D(φ)             (first order -½ Ξ(q)Δt: the paper's F_4×3, without Δt)
    F_Vq = Δt J(q_mid, a') R(Exp(φ/2)),  J(q, a) = ∂(C(q) a)/∂q (3×4, C in the homogeneous
                                     quadratic form, as eq 2 at |q| = 1)
    F_Vω = -½ Δt² J(q_mid, a') L(q) D(φ/2)   (second order; the paper has none)
    F_Va = -Δt C(q_mid) e_z          (the paper's F_3×1)
    F_S  = I_S + Δt I_V + ½ Δt (F_V - I_V)   (from the trapezoidal position step)
  and G maps the gyro noise (½ Ξ(q⁺)Δt, so G Q Gᵀ = ¼ σ_g²Δt (I - q⁺q⁺ᵀ) for white rate noise
  of density σ_g) and the accelerometer noise (C(q)Δt: σ_a²Δt I for an isotropic density σ_a).
  Q_s: random walks of ω_b, a_zb, M and m_b. F P Fᵀ is formed with F's sparsity (rows and
  columns of q, V, S only), about 1.5k multiply-adds per sample instead of 16k.
  Magnetometer H_x = [∂m_x/∂q, 0…, ∂m_x/∂M = first column of C(q), ∂m_x/∂m_xb = 1, 0, 0]
  (eq 12-13), likewise for y, z.

Choices the paper leaves open, made here:
- Integration: exact rotation for the trapezoidal rate (as ``mahony``) instead of eq 5's
  first-order step, and the specific force turned with the mid-step attitude (at the 10-50 Hz
  of many logs, the start attitude tilts the integrated acceleration in turns); F is the
  Jacobian of exactly this step.
"""
from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np

from ..flight import GRAVITY
from ..kernel_cache import kernel
from ..quaternion import left_matrix_into, normalize_head, right_matrix_into, rotate_into
from .base import MAX_STEP_S

NX = 20
IQ, IV, IS, IB, IA, IM, IMB = 0, 4, 7, 10, 13, 14, 17  # first index of each state block
TESLA_TO_GAUSS = 1e4
RING = 512  # rows of the predicted-increment history (for gps_delay_s)
SYNTH_PERIOD_S = 0.2  # synthetic zero-velocity fusion period without GPS

# Diagnostic columns (the kernel writes one row of these per sample).
DIAG_KEYS = (
    "cov_trace", "reset", "watchdog_distance",
    "gyro_bias_x", "gyro_bias_y", "gyro_bias_z", "accel_bias_z",
    "mag_bias_x", "mag_bias_y", "mag_bias_z",
    "earth_field_n", "earth_field_e", "earth_field_d",
    "vel_n", "vel_e", "vel_d", "pos_n", "pos_e", "pos_d",
    "innov_mag_x", "innov_mag_y", "innov_mag_z",
    "innov_gps_vel_n", "innov_gps_vel_e", "innov_gps_vel_d",
    "innov_gps_pos_n", "innov_gps_pos_e", "innov_gps_pos_d", "innov_baro",
)
D_TRACE, D_RESET, D_WD, D_BG, D_BA, D_MB, D_M, D_V, D_S, D_IM, D_IV, D_IP, D_IB = (
    0, 1, 2, 3, 6, 7, 10, 13, 16, 19, 22, 25, 28)
NDIAG = len(DIAG_KEYS)

# aux: the filter's scalar memory between chunks
A_TPREV, A_GYRO, A_ACC, A_COUNT, A_MAGINIT, A_TGPS, A_TBARO, A_TSYNTH, A_GVEL, A_GPOS, \
    A_HEAD, A_FILL, A_RESETS, A_LASTMAG, A_WDBIN = 0, 1, 4, 7, 8, 9, 10, 11, 12, 15, 18, 19, 20, 21, 24
NAUX = 25


# parameter vector layout for the kernel
class CpfEkfSettings(NamedTuple):
    """The parameters as the kernel takes them (``CpfEkfParams``; angles in radians, flags as
    1.0 / 0.0), and the declination."""
    gyro_noise: float
    accel_noise: float
    gyro_bias_walk: float
    accel_bias_walk: float
    earth_field_walk: float
    body_field_walk: float
    mag_noise: float
    declination_noise: float  # rad
    gps_vel_noise: float
    gps_pos_noise: float
    gps_pos_noise_min: float
    gps_alt_noise: float
    gps_delay: float
    baro_noise: float
    gps_timeout: float
    baro_timeout: float
    synthetic_vel_noise: float
    innovation_gate: float
    tilt_sigma0: float  # rad
    yaw_sigma0: float  # rad
    vel_sigma0: float
    pos_sigma0: float
    reset_threshold: float
    reset_cycles: float
    kp: float
    ki: float
    declination: float  # rad
    use_mag: float
    watchdog: float
    gravity: float
    max_step: float
    yaw_sigma0_nomag: float  # rad
    earth_field_sigma0: float
    watchdog_period: float
    reset_bias: float
    gyro_bias_sigma0: float  # rad/s
    accel_bias_sigma0: float
    body_field_sigma0: float
    heading_hold_noise: float  # rad
    mag_tilt: float

    @classmethod
    def of(cls, p, declination: float) -> CpfEkfSettings:
        """From ``CpfEkfParams`` ``p`` and the declination (rad)."""
        r = math.radians
        return cls(
            gyro_noise=float(p.gyro_noise), accel_noise=float(p.accel_noise),
            gyro_bias_walk=float(p.gyro_bias_walk), accel_bias_walk=float(p.accel_bias_walk),
            earth_field_walk=float(p.earth_field_walk), body_field_walk=float(p.body_field_walk),
            mag_noise=float(p.mag_noise), declination_noise=r(p.declination_noise_deg),
            gps_vel_noise=float(p.gps_vel_noise), gps_pos_noise=float(p.gps_pos_noise),
            gps_pos_noise_min=float(p.gps_pos_noise_min), gps_alt_noise=float(p.gps_alt_noise),
            gps_delay=float(p.gps_delay_s), baro_noise=float(p.baro_noise), gps_timeout=float(p.gps_timeout_s),
            baro_timeout=float(p.baro_timeout_s), synthetic_vel_noise=float(p.synthetic_vel_noise),
            innovation_gate=float(p.innovation_gate), tilt_sigma0=r(p.tilt_sigma0_deg),
            yaw_sigma0=r(p.yaw_sigma0_deg), vel_sigma0=float(p.vel_sigma0), pos_sigma0=float(p.pos_sigma0),
            reset_threshold=float(p.reset_threshold), reset_cycles=float(p.reset_cycles), kp=float(p.cpf_kp),
            ki=float(p.cpf_ki), declination=float(declination), use_mag=float(p.use_mag),
            watchdog=float(p.watchdog), gravity=GRAVITY, max_step=MAX_STEP_S,
            yaw_sigma0_nomag=r(p.yaw_sigma0_nomag_deg), earth_field_sigma0=float(p.earth_field_sigma0),
            watchdog_period=float(p.watchdog_period_s), reset_bias=float(p.reset_bias_covariance),
            gyro_bias_sigma0=r(p.gyro_bias_sigma0_dps), accel_bias_sigma0=float(p.accel_bias_sigma0),
            body_field_sigma0=float(p.body_field_sigma0), heading_hold_noise=r(p.heading_hold_noise_deg),
            mag_tilt=float(p.mag_tilt))


class CpfEkfState(NamedTuple):
    """What the filter carries between chunks (arrays, updated in place)."""
    x: np.ndarray  # (NX,) [q, V, S, ω_b, a_zb, M (gauss), m_b (gauss)]
    P: np.ndarray  # (NX, NX)
    qc: np.ndarray  # (4,) the complementary filter's attitude
    bc: np.ndarray  # (3,) its integral term
    aux: np.ndarray  # (NAUX,) scalar memory, see the A_* indices
    ring: np.ndarray  # (RING, 7) predicted increments, for a delayed GPS fix


class AidingRows(NamedTuple):
    """A chunk's GPS and baro on the IMU clock (``aiding.Aiding``), NaN where none, and
    whether to fuse them."""
    gps_pos: np.ndarray  # (N, 3)
    gps_vel: np.ndarray  # (N, 3)
    gps_hacc: np.ndarray  # (N,)
    gps_vacc: np.ndarray  # (N,)
    baro: np.ndarray  # (N,)
    use_gps: bool
    use_baro: bool


# ---------------------------------------------------------------- model functions (compiled)


@kernel
def exp_dexp_pair(v, e, d, eh, dh):
    """e = Exp(v) (4,) and d = ∂Exp(v)/∂v (4×3), and likewise eh, dh of v/2, written in place
    from one sine and cosine (of θ/4, θ = |v|; series below θ = 1e-4):
    Exp(v) = [cos ½θ, f₁ v], f₁ = sin(½θ)/θ;  ∂Exp/∂v = [-½ f₁ vᵀ; f₁ I + f₂ v vᵀ],
    f₂ = (½θ cos ½θ - sin ½θ)/θ³."""
    th2 = v[0] * v[0] + v[1] * v[1] + v[2] * v[2]
    th = math.sqrt(th2)
    hh2 = 0.25 * th2
    if th < 1e-4:
        c, f1, f2 = 1.0 - th2 / 8.0, 0.5 - th2 / 48.0, -1.0 / 24.0 + th2 / 960.0
        ch, f1h, f2h = 1.0 - hh2 / 8.0, 0.5 - hh2 / 48.0, -1.0 / 24.0 + hh2 / 960.0
    else:
        s4 = math.sin(0.25 * th)  # sin, cos of θ/4 give both of θ/2 and, as they are, of θ/4
        c4 = math.cos(0.25 * th)
        s = 2.0 * s4 * c4
        c = c4 * c4 - s4 * s4
        f1 = s / th
        f2 = (0.5 * th * c - s) / (th2 * th)
        hh = 0.5 * th
        ch = c4
        f1h = s4 / hh
        f2h = (0.5 * hh * c4 - s4) / (hh2 * hh)
    e[0] = c
    eh[0] = ch
    for i in range(3):
        vi = v[i]
        hi = 0.5 * vi
        e[1 + i] = f1 * vi
        eh[1 + i] = f1h * hi
        d[0, i] = -0.5 * f1 * vi
        dh[0, i] = -0.5 * f1h * hi
        for j in range(3):
            d[1 + i, j] = f2 * vi * v[j]
            dh[1 + i, j] = f2h * hi * 0.5 * v[j]
        d[1 + i, i] += f1
        dh[1 + i, i] += f1h


@kernel
def rot_jacobian(q, a, out):
    """J = ∂(C(q) a)/∂q (3×4), C in the homogeneous quadratic form of eq 2."""
    q0, q1, q2, q3 = q[0], q[1], q[2], q[3]
    ax, ay, az = a[0], a[1], a[2]
    out[0, 0] = 2 * (q0 * ax - q3 * ay + q2 * az)
    out[0, 1] = 2 * (q1 * ax + q2 * ay + q3 * az)
    out[0, 2] = 2 * (-q2 * ax + q1 * ay + q0 * az)
    out[0, 3] = 2 * (-q3 * ax - q0 * ay + q1 * az)
    out[1, 0] = 2 * (q3 * ax + q0 * ay - q1 * az)
    out[1, 1] = 2 * (q2 * ax - q1 * ay - q0 * az)
    out[1, 2] = 2 * (q1 * ax + q2 * ay + q3 * az)
    out[1, 3] = 2 * (q0 * ax - q3 * ay + q2 * az)
    out[2, 0] = 2 * (-q2 * ax + q1 * ay + q0 * az)
    out[2, 1] = 2 * (q3 * ax + q0 * ay - q1 * az)
    out[2, 2] = 2 * (-q0 * ax + q3 * ay - q2 * az)
    out[2, 3] = 2 * (q1 * ax + q2 * ay + q3 * az)


@kernel
def _step_rotations(x, w_mean, a_mean, dt):
    """What a step turns by (see the module docstring): Exp(φ) and its derivative, Exp(φ/2)
    and its derivative, R(Exp(φ/2)), the mid-step attitude q_mid and the specific force a'
    (z bias removed)."""
    phi = np.empty(3)
    for i in range(3):
        phi[i] = (w_mean[i] - x[IB + i]) * dt
    e, d, eh, dh = np.empty(4), np.empty((4, 3)), np.empty(4), np.empty((4, 3))
    exp_dexp_pair(phi, e, d, eh, dh)
    rh = np.empty((4, 4))
    right_matrix_into(eh, rh)
    qm = np.zeros(4)
    for i in range(4):
        for k in range(4):
            qm[i] += rh[i, k] * x[k]
    ap = np.empty(3)
    ap[0], ap[1], ap[2] = a_mean[0], a_mean[1], a_mean[2] - x[IA]
    return e, d, dh, rh, qm, ap


@kernel
def predict_state(x, w_mean, a_mean, dt, g, xn):
    """The state step f(x) of eq 5-7 as implemented (see the module docstring), into ``xn``."""
    e, d, dh, rh, qm, ap = _step_rotations(x, w_mean, a_mean, dt)
    rm = np.empty((4, 4))
    right_matrix_into(e, rm)
    for i in range(4):
        s = 0.0
        for k in range(4):
            s += rm[i, k] * x[k]
        xn[i] = s
    an = np.empty(3)
    rotate_into(qm, ap, an)
    an[2] += g
    for i in range(3):
        xn[IV + i] = x[IV + i] + an[i] * dt
        xn[IS + i] = x[IS + i] + 0.5 * (x[IV + i] + xn[IV + i]) * dt
    for k in range(IB, NX):
        xn[k] = x[k]


@kernel
def transition_blocks(x, w_mean, a_mean, dt, fqq, fqb, fvq, fvb, fva):
    """The non-trivial blocks of F (see the module docstring)."""
    e, d, dh, rh, qm, ap = _step_rotations(x, w_mean, a_mean, dt)
    right_matrix_into(e, fqq)
    lq = np.empty((4, 4))
    left_matrix_into(x[:4], lq)
    for i in range(4):
        for j in range(3):
            s = 0.0
            for k in range(4):
                s += lq[i, k] * d[k, j]
            fqb[i, j] = -dt * s
    jm = np.empty((3, 4))
    rot_jacobian(qm, ap, jm)
    ez = np.zeros(3)
    ez[2] = 1.0
    cz = np.empty(3)
    rotate_into(qm, ez, cz)
    for i in range(3):
        for j in range(4):
            s = 0.0
            for k in range(4):
                s += jm[i, k] * rh[k, j]
            fvq[i, j] = dt * s
        for j in range(3):
            s = 0.0
            for k in range(4):
                lk = 0.0
                for m in range(4):
                    lk += lq[k, m] * dh[m, j]
                s += jm[i, k] * lk
            fvb[i, j] = -0.5 * dt * dt * s
        fva[i] = -dt * cz[i]


def transition_matrix(x, w_mean, a_mean, dt) -> np.ndarray:
    """The full 20×20 F of ``predict_state`` at ``x`` (for tests; the kernel uses the blocks)."""
    fqq, fqb, fvq, fvb, fva = np.empty((4, 4)), np.empty((4, 3)), np.empty((3, 4)), np.empty((3, 3)), np.empty(3)
    transition_blocks(np.asarray(x, dtype=float), np.asarray(w_mean, dtype=float),
                      np.asarray(a_mean, dtype=float), float(dt), fqq, fqb, fvq, fvb, fva)
    F = np.eye(NX)
    F[IQ:IQ + 4, IQ:IQ + 4] = fqq
    F[IQ:IQ + 4, IB:IB + 3] = fqb
    F[IV:IV + 3, IQ:IQ + 4] = fvq
    F[IV:IV + 3, IB:IB + 3] = fvb
    F[IV:IV + 3, IA] = fva
    F[IS:IS + 3, :] += 0.5 * dt * (F[IV:IV + 3, :] - np.eye(NX)[IV:IV + 3])
    F[IS:IS + 3, IV:IV + 3] += dt * np.eye(3)
    return F



# ------------------------------------------------ P₀


@kernel
def _init_attitude_cov(P, q, sig_tilt, sig_yaw):
    """P_qq = ¼ Σ_k σ_k² (e_k ⊗ q)(e_k ⊗ q)ᵀ: navigation-frame tilt and yaw errors."""
    rq = np.empty((4, 4))
    right_matrix_into(q, rq)  # column k of R(q) is e_k ⊗ q
    for i in range(4):
        for j in range(4):
            s = 0.0
            for k in range(1, 4):
                sig = sig_yaw if k == 3 else sig_tilt
                s += sig * sig * rq[i, k] * rq[j, k]
            P[i, j] = 0.25 * s


@kernel
def init_covariance(P, x, cfg, heading, bias_var):
    """P₀: attitude, velocity and position from the parameters; the bias blocks get
    ``bias_var`` (7,: ω_b (3), a_zb, ...) on the diagonal; earth field and body field P₀."""
    for i in range(NX):
        for j in range(NX):
            P[i, j] = 0.0
    _init_attitude_cov(P, x, cfg.tilt_sigma0, cfg.yaw_sigma0 if heading else cfg.yaw_sigma0_nomag)
    for i in range(3):
        P[IV + i, IV + i] = cfg.vel_sigma0 ** 2
        P[IS + i, IS + i] = cfg.pos_sigma0 ** 2
        P[IB + i, IB + i] = bias_var[i]
        P[IM + i, IM + i] = bias_var[4]
        P[IMB + i, IMB + i] = bias_var[5]
    P[IA, IA] = bias_var[3]



# ------------------------------------------------ prediction (eq 4-9)
# F's blocks are formed in the kernel's loop itself: as a function of its own (30 scratch arrays
# passed on every sample) the prediction ran at half the speed; these three are inlined.


@kernel(inline="always")
def propagate_covariance(P, fp, fqq, fqb, fvq, fvb, fva, dt):
    """P ← F P Fᵀ with F's sparsity: only its q, V and S rows differ from I (rows 0-9 of
    F P into ``fp``, then against every column)."""
    # F P, rows 0-9, over all columns, row by row (contiguous, vectorised over j)
    for r in range(4):
        f0, f1, f2, f3 = fqq[r, 0], fqq[r, 1], fqq[r, 2], fqq[r, 3]
        fb0, fb1, fb2 = fqb[r, 0], fqb[r, 1], fqb[r, 2]
        for j in range(NX):
            fp[r, j] = (f0 * P[0, j] + f1 * P[1, j] + f2 * P[2, j] + f3 * P[3, j]
                        + fb0 * P[IB, j] + fb1 * P[IB + 1, j] + fb2 * P[IB + 2, j])
    hdt = 0.5 * dt
    for r in range(3):
        f0, f1, f2, f3 = fvq[r, 0], fvq[r, 1], fvq[r, 2], fvq[r, 3]
        fb0, fb1, fb2, fa = fvb[r, 0], fvb[r, 1], fvb[r, 2], fva[r]
        for j in range(NX):
            dvr = (f0 * P[0, j] + f1 * P[1, j] + f2 * P[2, j] + f3 * P[3, j]
                   + fb0 * P[IB, j] + fb1 * P[IB + 1, j] + fb2 * P[IB + 2, j] + fa * P[IA, j])
            pv = P[IV + r, j]
            fp[IV + r, j] = pv + dvr
            fp[IS + r, j] = P[IS + r, j] + dt * pv + hdt * dvr
    # P' = (F P) Fᵀ: rows 0-9 against every column; columns >= 10 are F P itself
    for r in range(10):
        for c in range(10, NX):
            P[r, c] = fp[r, c]
            P[c, r] = fp[r, c]
    for r in range(10):
        a0, a1, a2, a3 = fp[r, 0], fp[r, 1], fp[r, 2], fp[r, 3]
        ab0, ab1, ab2, aa = fp[r, IB], fp[r, IB + 1], fp[r, IB + 2], fp[r, IA]
        for c in range(4):
            if c >= r:
                v = (a0 * fqq[c, 0] + a1 * fqq[c, 1] + a2 * fqq[c, 2] + a3 * fqq[c, 3]
                     + ab0 * fqb[c, 0] + ab1 * fqb[c, 1] + ab2 * fqb[c, 2])
                P[r, c] = v
                P[c, r] = v
        for c in range(3):
            dvc = (a0 * fvq[c, 0] + a1 * fvq[c, 1] + a2 * fvq[c, 2] + a3 * fvq[c, 3]
                   + ab0 * fvb[c, 0] + ab1 * fvb[c, 1] + ab2 * fvb[c, 2] + aa * fva[c])
            av = fp[r, IV + c]
            if IV + c >= r:
                v = av + dvc
                P[r, IV + c] = v
                P[IV + c, r] = v
            if IS + c >= r:
                v = fp[r, IS + c] + dt * av + 0.5 * dt * dvc
                P[r, IS + c] = v
                P[IS + c, r] = v


@kernel(inline="always")
def step_state(x, q_new, acc_ned, dt, ring, aux, ti, delayed):
    """Eq 5-7: the new attitude, and V, S from the NED acceleration (trapezoidal); with a GPS
    delay, the increments go into the ring a delayed fix is compared through."""
    for r in range(4):
        x[r] = q_new[r]
    normalize_head(x)
    for r in range(3):
        vnew = x[IV + r] + acc_ned[r] * dt
        dsr = 0.5 * (x[IV + r] + vnew) * dt
        if delayed:
            h = int(aux[A_HEAD])
            ring[h, 1 + r] = acc_ned[r] * dt
            ring[h, 4 + r] = dsr
        x[IS + r] += dsr
        x[IV + r] = vnew
    if delayed:
        h = int(aux[A_HEAD])
        ring[h, 0] = ti
        aux[A_HEAD] = (h + 1) % RING
        aux[A_FILL] = min(aux[A_FILL] + 1.0, RING)


@kernel(inline="always")
def add_process_noise(x, P, dt, cfg):
    """G Q Gᵀ (gyro noise on q, accelerometer noise on V) + Q_s (the random walks)."""
    qg = 0.25 * cfg.gyro_noise ** 2 * dt
    for r in range(4):
        for c in range(r, 4):
            v = -qg * x[r] * x[c]
            if r == c:
                v += qg
            P[r, c] += v
            if c != r:
                P[c, r] += v
    for r in range(3):
        P[IV + r, IV + r] += cfg.accel_noise ** 2 * dt
        P[IB + r, IB + r] += cfg.gyro_bias_walk ** 2 * dt
        P[IM + r, IM + r] += cfg.earth_field_walk ** 2 * dt
        P[IMB + r, IMB + r] += cfg.body_field_walk ** 2 * dt
    P[IA, IA] += cfg.accel_bias_walk ** 2 * dt

