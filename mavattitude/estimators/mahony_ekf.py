"""Mahony-EKF: a quaternion EKF whose measurement is the Mahony filter's quaternion.

Paper 000 (Chu, Zhao, Feng 2020, "UAV attitude calculation algorithm based on Mahony-EKF"),
§2.3; restated in ../shared/ALGORITHMS.md "mahony-ekf". Each IMU sample:

1. Mahony step (§2.3 1), Fig. 4): the complementary filter of ``mahony`` runs alongside, with
   its own gains, from the same initial attitude; its quaternion q_M is the measurement. The
   maths is mahony's, step for step (gravity error α = a × C(q)ᵀ[0,0,-1], heading error
   β = γ C(q)ᵀ[0,0,1], PI correction, exact integration of the trapezoidal rate), written
   on scalars so the loop allocates nothing; with ``k_mahony = 0`` it gives mahony's numbers
   (a test checks this).
2. Predict (eq 13-15, 18-19), the step shared with ``ekf``: ω̂ = gyro - still-period bias
   (§2.2), Φ = I + (T/2) Ω(ω̂), X⁻ = Φ X, P⁻ = Φ P Φᵀ + G Q Gᵀ, G = (T/2) Ξ(X),
   Q = q_gyro I₃ = 10⁻² I₃ (eq 12). The paper prints G (eq 15) without the ½ and with the
   opposite sign; the ½ belongs there (eq 11), the sign cancels in G Q Gᵀ.
3. Measurement (eq 16): Z = q_M, H = I₄. q_M and -q_M are one attitude: Z ← -Z when
   Z·X⁻ < 0.
4. Adaptive noise (eq 17): R = r0 [1 + k_accel |‖a‖ - g|] I₄, r0 = 10⁻⁴. The paper writes
   (‖a‖ - g), negative below g; a reading below g is as non-gravitational as one above, so
   the absolute value is used (ALGORITHMS.md).
5. Update (eq 20-22): K = P⁻ (P⁻ + R)⁻¹, X = X⁻ + K (Z - X⁻),
   P = (I - K) P⁻ (I - K)ᵀ + K R Kᵀ (Joseph form); normalise X. P₀ = I₄, X₀ = the shared
   alignment's attitude from accelerometer and magnetometer (as eq 4-6).

Choices the paper leaves open, made here (sweeps over tests/simtruth's flights and the
shared logs; the numbers are in the issue-3 report):
- k_accel = 1000 /(m/s²) (the paper: only k > 0). At rest the EKF follows q_M with a time
  constant of about 2 √(R / q_gyro) = 0.2 s; R's growth stretches it by √(1 + k_accel |‖a‖ - g|),
  to ≈ 6 s in a 25° coordinated turn (‖a‖ - g ≈ 1 m/s²).
- The internal Mahony's gravity error is weighted by w = 1 / (1 + k_mahony |ā - ā_ref|)
  (k_mahony = 100 /(m/s²); 0 gives the paper's unweighted filter). Not in the paper, and
  needed: R's adaptation (eq 17) only lets the EKF coast on the gyro while ‖a‖ ≠ g, but q_M
  itself is pulled off by the non-gravity acceleration (the Mahony filter has memory), and
  the EKF returns to it afterwards. No choice of Kp then meets both of the paper's claims on
  simulated truth: the static error < 0.1° needs Kp ≥ 0.5 /s (the gyro bias walks; the tilt
  error is about bias / Kp) and the coordinated-turn (figure-eight) error < 1° needs
  Kp ≤ 0.05 /s. With the weight, the accelerometer steers q_M at rest and not in turns.
  ā is ‖a‖ - g low-passed with ``accel_lp_s`` = 0.5 s (the per-sample norm is too noisy);
  ā_ref is ā's slow baseline (``accel_ref_s`` = 60 s; a running mean over the first
  minute), which absorbs an accelerometer scale error (two of the shared real logs read
  0.4-0.6 m/s² high at rest) and the rectified vibration. Sustained accelerations longer
  than about a minute (a plane's loiter) become the baseline and are trusted again.
  Below ``weight_min_rate`` = 20 Hz (the mean step, smoothed over ~100 samples) the weight
  stays 1: at a few Hz the gyro integrates too coarsely to carry the attitude alone, and
  weighting made the 1 Hz and 4 Hz shared logs 2-2.5× worse.
- The internal Mahony's gains: Kp = 0.5 /s, Ki = 0.005 /s² (mahony's defaults are 0.2 and
  0.0005): with the accelerometer weighted out in manoeuvres, the stiffer loop holds the
  static tilt within 0.1° against the gyro bias walk (Kp = 0.2, Ki = 0.0005: 0.18°).
- Issue 10: the weight above, tuned on 100 Hz simulated truth, made mahony-ekf worse than
  mahony on real 25 Hz flights (real-copter-4.1.3-cubeblack-* 1.64-2.00× mahony's tilt MAE,
  pixracer-dcm-lowbatt 1.82×, sub compasscal-handrotated-orca126 3.47×). The weight held
  ≈ 0.05-0.2 through whole flights (rectified vibration and manoeuvres in ‖a‖), so q_M
  coasted on a gyro integrated coarsely at 25 Hz; after orca126's 100 s of hand rotation
  ā_ref had absorbed the rotation (0.4 m/s²) and kept the accelerometer locked out at
  rest, and the integral term (Ki 10× mahony's) had wound up on the integration error
  (2-3° left at rest, decaying over Kp/Ki ≈ 100 s). Three additions, each with a value
  that turns it off; ``strict = true`` turns all of them and the weight off (k_mahony = 0:
  the paper's unweighted Mahony, eq 16-17 as published). On the 31 shared logs then (48 now; tilt MAE,
  mean of roll and pitch, against the autopilot; mahony's median 1.195°), before → after:
  median 1.323 → 0.976°, mean 2.002 → 1.753°, worst log real-plane-4.3.1-kakutef7-crash
  8.920 → 7.850° (1.21 → 1.06× mahony; now copter-4.1-flight.tlog, 1 Hz, 8.068 → 7.980°,
  0.97×), worst ratio 3.47 → 1.34× (mohai009), logs above
  1.5× mahony 5 → 0: cubeblack-crash-flip-fyp-test4 1.514 → 1.132 (1.64 → 1.22×),
  cubeblack-loggap-fyp-test1 1.323 → 0.790 (2.00 → 1.19×), cubeblack-mission-fyp-test3
  1.801 → 1.204 (1.73 → 1.16×), pixracer-dcm-lowbatt 0.794 → 0.476 (1.82 → 1.09×),
  compasscal-handrotated-orca126 1.553 → 0.348 (3.47 → 0.78×). Most moved otherwise:
  sitl-copter-4.7-vibration 3.238 → 1.794, sitl-plane-4.7-circuit 2.441 → 4.202 (its
  long coordinated turns now lean on the accelerometer after the coasting limit; still
  0.54× mahony), plane-3.1-flight-329 4.224 → 2.865, compasscal-handrotated-orca-0925.tlog
  1.758 → 0.976, copter-3.3-loiter-rtl 1.285 → 1.426. strict = true: median 1.073°, mean
  2.082°, worst ratio 1.47×. Each addition off in turn (others on): median / mean / worst
  ratio below.
  * Rest (``rest_gyro`` = 0.05 rad/s, alignment's still threshold; ``rest_accel`` =
    0.02 m/s²; ``rest_ref_s`` = 2 s): the low-passed |ω - b| below rest_gyro and ā within
    rest_accel of its value at the last rest (the start is at rest) mean the vehicle is
    at rest: the weight is 1 and ā_ref follows ā with a 2 s time constant, so the
    accelerometer is trusted again as soon as a lockout ends. ā must agree with rest, or a
    linear acceleration with the gyro quiet (simulated "accel") would count as rest (0.1
    m/s² let the figure-eight's pitch MAE reach 1.03°; 0.02: 0.82°). Off: 1.080° / 1.795°
    / 1.36× (SITL copters lose most: 400 Hz 0.664 → 1.106).
  * Coasting limit (``lock_s`` = 100 s at 100 Hz): the debt D grows by (1 - w) dt while the
    weight w is below 1 and is paid back at w Kp D; the weight is at least D / (D + B),
    with the budget B = lock_s (100 Hz / f)²: a lockout may last as long as the gyro can
    carry the attitude, and the trapezoidal integration's error grows with the step
    squared (B ≈ 6 s at 25 Hz, 25 s at 50 Hz, 100 s at 100 Hz; a budget ∝ f instead, i.e.
    25 s at 25 Hz, left mohai009 at 1.75×; 7.5 s at 25 Hz ∝ f, i.e. lock_s = 30, broke the
    figure-eight's 1° claim). Off: 0.976° / 1.817° / 2.05× with 5 logs above 1.5×
    (cubeblack-mission 1.85×, lowbatt 1.95×, mohai009 2.05×).
  * Integral gating (``ki_step`` = 0.01 rad): the integral term learns with Ki w / (1 +
    (|ω - b| T / ki_step)²): not while the accelerometer is weighted out, nor while the
    gyro turns more than about 0.5° a sample (where the coarse integration's error, not
    the bias, is what the gravity error shows). Below 20 Hz, where the weight stays 1,
    this is what changes: plane-3.1-flight-329 4.224 → 2.865, orca-0925.tlog (10 Hz)
    1.758 → 0.976. Off: 1.079° / 1.916° / 1.47× (orca126 0.348 → 0.654).
  Not done: scaling k_mahony with the noise of ā measured at rest or in flight; the
  in-flight noise of ‖a‖ did not separate the logs the weight helps (forumlog0039,
  quiver083: gyro-only error ≈ 0.55-0.75°) from those it hurts (cubeblack, mohai subs:
  gyro-only 2-36°); the gyro's drift did, which the coasting limit bounds instead.
- Eq 17's g (issue 25) is the accelerometer's reading of g at the still start (``gravity``,
  bounded to ±25 %; 9.80665 with ``strict`` or without a still start): against 9.80665 a
  15 % scale error grew R some 150 times at rest. Simulated figure 8 at 0.85 / 1.15 g: tilt
  1.24° / 1.17° → 0.83° / 0.73° (0.79° at 1.0). Corpus: erle-20141222-41 (reads -16 %)
  5.28° → 1.89° (its worst DCM-reference log, now real-plane-3.1.2b1 5.11°), althold-error
  (-20 %) 1.38° → 1.41°; medians per reference family within 0.005°. BROAD inclination RMSE
  0-0.02° lower per trial. Not learned on in flight: the rest detection above could, not done.
- The EKF predicts with the still-period bias only, as the paper does; the internal
  Mahony's integral term (its running bias correction) stays inside the Mahony filter.
- The trapezoidal rate and gap handling follow mahony: the first sample, and any step
  longer than ``MAX_STEP_S``, neither predicts nor updates.
- The update is written out element by element: S = P⁻ + R is inverted by its adjugate, and
  as K = I - r S⁻¹ is symmetric, I - K = r S⁻¹, the Joseph form needs no further inverse.
- The accelerometer low-passed in an almost-inertial frame (``inertial_accel``,
  ``accel_tau``, 1 s; strict: the reading as it is).
  As in mahony (its numbers there); its rest test and weights read the low-passed
  reading too. 0 -> 1 s: BROAD 1.47° -> 0.80° (worst 5.7× -> 1.9× VQF), corpus 1.07° -> 1.10°,
  SITL 0.84° -> 1.00° (sitl-copter-4.7-400hz 0.65° -> 0.99°, wind 1.22° -> 1.43° against their
  near-truth EKF3: a cost, said here), worst 1.53× -> 1.58× mahony (real-copter-3.3dev alt-issue,
  0.11°). Tried: the weights and the rest test on the reading itself, the internal Mahony on the
  low-passed one: BROAD 0.73° (worst 2.2× VQF), corpus 1.05°, SITL 0.97° (400 Hz 0.70°, but the
  plane circuit 4.16° -> 5.18°): no clear gain, not kept.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import NamedTuple

import numpy as np

from ..flight import GRAVITY
from ..kernel_cache import kernel
from ..paramspec import param
from .alignment import STILL_GYRO_RAD_S
from .base import MAX_STEP_S, Estimator
from .inertial_accel import lowpass_in_inertial_frame
from .timestep import integrates, step_dt, step_rate
from .gravity import scale_effect
from .ekf import predict
from .mahony import mahony_step


@dataclass
class MahonyEkfParams:
    kp: float = param(0.5, "[0, 1e6]", "log [0.01, 10]")  # internal Mahony proportional gain, 1/s (mahony's: 0.2; see the docstring)
    ki: float = param(0.005, "[0, 1e6]", "log [1e-5, 0.1]")  # internal Mahony integral gain, 1/s² (mahony's: 0.0005)
    use_mag: bool = param(True)  # the internal Mahony corrects heading from the magnetometer
    q_gyro: float = param(1e-2, "(0, 1e6]", "log [1e-5, 1]")  # gyro noise variance per axis (eq 12: Q = 1e-2 I₃), (rad/s)²
    r0: float = param(1e-4, "[1e-12, 1e6]", "log [1e-7, 0.1]")  # measurement noise variance per quaternion component at rest (eq 17), 1
    k_accel: float = param(1000.0, "[0, 1e9]", "log [1, 1e5]")  # eq 17's k: R = r0 [1 + k_accel |‖a‖ - g|], 1/(m/s²)
    k_mahony: float = param(100.0, "[0, inf)", "log [0.1, 1e4]")  # Mahony gravity-error weight 1/(1 + k_mahony |ā - ā_ref|); 0: none, 1/(m/s²)
    accel_lp_s: float = param(0.5, "[0, inf)", "log [0.02, 5]")  # time constant of ā, the low-passed ‖a‖ - g, s
    accel_ref_s: float = param(60.0, "[0, inf)")  # time constant of ā_ref, ā's slow baseline (0: none, ā_ref = 0), s
    weight_min_rate: float = param(20.0, "[0, inf)")  # IMU rate below which the weight stays 1, Hz
    rest_gyro: float = param(STILL_GYRO_RAD_S, "[0, inf)")  # low-passed |ω - b| below this is rest: weight 1, rad/s (0: off)
    rest_accel: float = param(0.02, "(0, inf)")  # ... and ā within this of its value at rest, m/s²
    rest_ref_s: float = param(2.0, "(0, inf)")  # time constant of ā_ref (and ā's value at rest) at rest, s
    lock_s: float = param(100.0, "[0, inf)")  # gyro-only coasting allowed at 100 Hz (∝ rate²), s (0: no limit)
    ki_step: float = param(0.01, "[0, inf)")  # rotation per step halving the integral gain, rad (0: ki as is)
    accel_tau: float = param(1.0, "[0, 60]", "linear [0, 5]")  # s: the accelerometer low-passed in an almost-inertial frame (inertial_accel); 0: the reading as it is
    strict: bool = param(False)  # the paper's Mahony-EKF: unweighted Mahony measurement, none of the additions


@kernel(inline="always")
def quaternion_update(x, P, z0, z1, z2, z3, r):
    """Update with Z = (z0..z3), H = I₄, R = r I₄ (eq 20-22), in place. S = P + r I is
    inverted by its adjugate (one division); K = P S⁻¹ = I - r S⁻¹ is symmetric and I - K =
    r S⁻¹, so the Joseph form is P = (r S⁻¹ P)(r S⁻¹) + r K K. Written out element by element."""
    p00, p01, p02, p03 = P[0, 0], P[0, 1], P[0, 2], P[0, 3]
    p11, p12, p13 = P[1, 1], P[1, 2], P[1, 3]
    p22, p23 = P[2, 2], P[2, 3]
    p33 = P[3, 3]
    a00, a01, a02, a03 = p00 + r, p01, p02, p03
    a11, a12, a13 = p11 + r, p12, p13
    a22, a23 = p22 + r, p23
    a33 = p33 + r
    # 2×2 minors of rows 0-1 (m) and rows 2-3 (c) of S
    m0 = a00 * a11 - a01 * a01
    m1 = a00 * a12 - a02 * a01
    m2 = a00 * a13 - a03 * a01
    m3 = a01 * a12 - a02 * a11
    m4 = a01 * a13 - a03 * a11
    m5 = a02 * a13 - a03 * a12
    c5 = a22 * a33 - a23 * a23
    c4 = a12 * a33 - a13 * a23
    c3 = a12 * a23 - a13 * a22
    c2 = a02 * a33 - a03 * a23
    c1 = a02 * a23 - a03 * a22
    c0 = a02 * a13 - a03 * a12
    inv = 1.0 / (m0 * c5 - m1 * c4 + m2 * c3 + m3 * c2 - m4 * c1 + m5 * c0)
    # S⁻¹ (symmetric)
    i00 = (a11 * c5 - a12 * c4 + a13 * c3) * inv
    i01 = (-a01 * c5 + a02 * c4 - a03 * c3) * inv
    i02 = (a13 * m5 - a23 * m4 + a33 * m3) * inv
    i03 = (-a12 * m5 + a22 * m4 - a23 * m3) * inv
    i11 = (a00 * c5 - a02 * c2 + a03 * c1) * inv
    i12 = (-a03 * m5 + a23 * m2 - a33 * m1) * inv
    i13 = (a02 * m5 - a22 * m2 + a23 * m1) * inv
    i22 = (a03 * m4 - a13 * m2 + a33 * m0) * inv
    i23 = (-a02 * m4 + a12 * m2 - a23 * m0) * inv
    i33 = (a02 * m3 - a12 * m1 + a22 * m0) * inv
    # K = I - r S⁻¹
    k00 = 1.0 - r * i00
    k01 = -r * i01
    k02 = -r * i02
    k03 = -r * i03
    k11 = 1.0 - r * i11
    k12 = -r * i12
    k13 = -r * i13
    k22 = 1.0 - r * i22
    k23 = -r * i23
    k33 = 1.0 - r * i33
    y0, y1, y2, y3 = z0 - x[0], z1 - x[1], z2 - x[2], z3 - x[3]
    x[0] += k00 * y0 + k01 * y1 + k02 * y2 + k03 * y3
    x[1] += k01 * y0 + k11 * y1 + k12 * y2 + k13 * y3
    x[2] += k02 * y0 + k12 * y1 + k22 * y2 + k23 * y3
    x[3] += k03 * y0 + k13 * y1 + k23 * y2 + k33 * y3
    # C = (I - K) P = r S⁻¹ P
    e00 = r * (i00 * p00 + i01 * p01 + i02 * p02 + i03 * p03)
    e01 = r * (i00 * p01 + i01 * p11 + i02 * p12 + i03 * p13)
    e02 = r * (i00 * p02 + i01 * p12 + i02 * p22 + i03 * p23)
    e03 = r * (i00 * p03 + i01 * p13 + i02 * p23 + i03 * p33)
    e10 = r * (i01 * p00 + i11 * p01 + i12 * p02 + i13 * p03)
    e11 = r * (i01 * p01 + i11 * p11 + i12 * p12 + i13 * p13)
    e12 = r * (i01 * p02 + i11 * p12 + i12 * p22 + i13 * p23)
    e13 = r * (i01 * p03 + i11 * p13 + i12 * p23 + i13 * p33)
    e20 = r * (i02 * p00 + i12 * p01 + i22 * p02 + i23 * p03)
    e21 = r * (i02 * p01 + i12 * p11 + i22 * p12 + i23 * p13)
    e22 = r * (i02 * p02 + i12 * p12 + i22 * p22 + i23 * p23)
    e23 = r * (i02 * p03 + i12 * p13 + i22 * p23 + i23 * p33)
    e30 = r * (i03 * p00 + i13 * p01 + i23 * p02 + i33 * p03)
    e31 = r * (i03 * p01 + i13 * p11 + i23 * p12 + i33 * p13)
    e32 = r * (i03 * p02 + i13 * p12 + i23 * p22 + i33 * p23)
    e33 = r * (i03 * p03 + i13 * p13 + i23 * p23 + i33 * p33)
    # P = C (I - K)ᵀ + r K Kᵀ
    P[0, 0] = (r * (e00 * i00 + e01 * i01 + e02 * i02 + e03 * i03)
                + r * (k00 * k00 + k01 * k01 + k02 * k02 + k03 * k03))
    P[0, 1] = P[1, 0] = (r * (e00 * i01 + e01 * i11 + e02 * i12 + e03 * i13)
                + r * (k00 * k01 + k01 * k11 + k02 * k12 + k03 * k13))
    P[0, 2] = P[2, 0] = (r * (e00 * i02 + e01 * i12 + e02 * i22 + e03 * i23)
                + r * (k00 * k02 + k01 * k12 + k02 * k22 + k03 * k23))
    P[0, 3] = P[3, 0] = (r * (e00 * i03 + e01 * i13 + e02 * i23 + e03 * i33)
                + r * (k00 * k03 + k01 * k13 + k02 * k23 + k03 * k33))
    P[1, 1] = (r * (e10 * i01 + e11 * i11 + e12 * i12 + e13 * i13)
                + r * (k01 * k01 + k11 * k11 + k12 * k12 + k13 * k13))
    P[1, 2] = P[2, 1] = (r * (e10 * i02 + e11 * i12 + e12 * i22 + e13 * i23)
                + r * (k01 * k02 + k11 * k12 + k12 * k22 + k13 * k23))
    P[1, 3] = P[3, 1] = (r * (e10 * i03 + e11 * i13 + e12 * i23 + e13 * i33)
                + r * (k01 * k03 + k11 * k13 + k12 * k23 + k13 * k33))
    P[2, 2] = (r * (e20 * i02 + e21 * i12 + e22 * i22 + e23 * i23)
                + r * (k02 * k02 + k12 * k12 + k22 * k22 + k23 * k23))
    P[2, 3] = P[3, 2] = (r * (e20 * i03 + e21 * i13 + e22 * i23 + e23 * i33)
                + r * (k02 * k03 + k12 * k13 + k22 * k23 + k23 * k33))
    P[3, 3] = (r * (e30 * i03 + e31 * i13 + e32 * i23 + e33 * i33)
                + r * (k03 * k03 + k13 * k13 + k23 * k23 + k33 * k33))


class MahonyEkfState(NamedTuple):
    """What the filter carries between chunks (arrays, updated in place)."""
    x: np.ndarray  # (4,) the EKF's quaternion
    P: np.ndarray  # (4, 4) its covariance
    qm: np.ndarray  # (4,) the internal Mahony's attitude
    bias_correction: np.ndarray  # (3,) the internal Mahony's integral term, rad/s
    t_prev: np.ndarray  # (1,) the last sample's time, NaN before the first
    gyro_prev: np.ndarray  # (3,) the last gyro sample
    accel_filt: np.ndarray  # (7,) [ā, ā_ref, samples seen, mean step, low-passed |ω - b|, coasting debt, ā at rest]
    bias: np.ndarray  # (3,) the still-period gyro bias (constant), rad/s


class MahonyEkfSettings(NamedTuple):
    """The parameters as the kernel takes them (see ``MahonyEkfParams``)."""
    kp: float
    ki: float
    use_mag: bool
    q_gyro: float
    r0: float
    k_accel: float
    k_mahony: float
    accel_lp_s: float
    accel_ref_s: float
    weight_min_rate: float
    rest_gyro: float
    rest_accel: float
    rest_ref_s: float
    lock_s: float
    ki_step: float
    gravity: float
    cos_dec: float
    sin_dec: float
    max_step: float


class MahonyEkfDiagnostics(NamedTuple):
    """Per-sample outputs besides the attitude (keys of ``MahonyEkf.DIAGNOSTICS``)."""
    cov_trace: np.ndarray
    adaptive_r: np.ndarray
    mahony_weight: np.ndarray


@kernel
def mahony_ekf_run(s, state, cfg, out, diag, mahony_out):
    """Run the filter over a chunk of samples ``s`` (``base.Samples``); ``state``
    (``MahonyEkfState``) is updated in place. Writes per sample: the attitude to ``out``, the
    internal Mahony quaternion to ``mahony_out`` (when it has a row per sample), and ``diag``:
    trace(P), R's diagonal and the Mahony weight."""
    t, gyro, accel, mag = s.t, s.gyro, s.accel, s.mag
    over_step = s.rate_over_step  # each gyro sample the mean over its step (timestep.step_rate)
    x, P, qm, bias_correction = state.x, state.P, state.qm, state.bias_correction
    t_prev, gyro_prev, accel_filt, bias = state.t_prev, state.gyro_prev, state.accel_filt, state.bias
    kp, ki, use_mag, q_gyro, r0 = cfg.kp, cfg.ki, cfg.use_mag, cfg.q_gyro, cfg.r0
    k_accel, k_mahony, accel_lp_s, accel_ref_s = cfg.k_accel, cfg.k_mahony, cfg.accel_lp_s, cfg.accel_ref_s
    weight_min_rate, gravity, cos_dec, sin_dec, max_step = (cfg.weight_min_rate, cfg.gravity, cfg.cos_dec,
                                                            cfg.sin_dec, cfg.max_step)
    rest_gyro, rest_accel, rest_ref_s = cfg.rest_gyro, cfg.rest_accel, cfg.rest_ref_s
    lock_s, ki_step = cfg.lock_s, cfg.ki_step
    keep_mahony = mahony_out.shape[0] == len(t)
    cov_trace, adaptive_r, mahony_weight = diag.cov_trace, diag.adaptive_r, diag.mahony_weight
    tp = t_prev[0]
    gp0, gp1, gp2 = gyro_prev[0], gyro_prev[1], gyro_prev[2]
    lp, ref, count, mean_dt = accel_filt[0], accel_filt[1], accel_filt[2], accel_filt[3]
    glp, debt, rest_lp = accel_filt[4], accel_filt[5], accel_filt[6]
    for i in range(len(t)):
        dt = step_dt(t[i], tp)
        tp = t[i]
        step = integrates(dt, max_step)
        g0, g1, g2 = gyro[i, 0], gyro[i, 1], gyro[i, 2]
        w0, w1, w2 = step_rate(g0, g1, g2, gp0, gp1, gp2, dt, over_step)
        gp0, gp1, gp2 = g0, g1, g2
        a0, a1, a2 = accel[i, 0], accel[i, 1], accel[i, 2]
        a_norm = np.sqrt(a0 * a0 + a1 * a1 + a2 * a2)
        dev = a_norm - gravity  # non-gravity acceleration, as eq 17 measures it
        r = r0 * (1.0 + k_accel * abs(dev))  # eq 17, with |·|

        # weight of the internal Mahony's gravity error (a choice: see the module docstring)
        rot = np.sqrt((w0 - bias[0]) ** 2 + (w1 - bias[1]) ** 2 + (w2 - bias[2]) ** 2)  # |ω - b|
        if glp != glp:
            glp = rot
        elif step:
            glp += (min(dt / accel_lp_s, 1.0) if accel_lp_s > 0.0 else 1.0) * (rot - glp)
        rest = False
        if dev == dev:
            if lp != lp:
                lp = ref = rest_lp = dev
                count = 1.0
            elif step:
                count += 1.0
                mean_dt = dt if mean_dt != mean_dt else mean_dt + 0.01 * (dt - mean_dt)
                lp += (min(dt / accel_lp_s, 1.0) if accel_lp_s > 0.0 else 1.0) * (dev - lp)
                # rest: the gyro quiet and ā where it was at rest before (the start is at rest)
                rest = rest_gyro > 0.0 and glp < rest_gyro and abs(lp - rest_lp) < rest_accel
                if rest:
                    rest_lp += max(min(dt / rest_ref_s, 1.0), 1.0 / count) * (lp - rest_lp)
                if accel_ref_s > 0.0:  # a running mean at first, then exponential; at rest, quickly
                    if rest:
                        ref += max(min(dt / rest_ref_s, 1.0), 1.0 / count) * (lp - ref)
                    else:
                        ref += max(min(dt / accel_ref_s, 1.0), 1.0 / count) * (lp - ref)
        weight = 1.0
        if k_mahony > 0.0 and lp == lp and not mean_dt * weight_min_rate > 1.0 and not rest:
            weight = 1.0 / (1.0 + k_mahony * abs(lp - (ref if accel_ref_s > 0.0 else 0.0)))
            if lock_s > 0.0 and debt > 0.0:  # the coasting debt raises the weight (its budget ∝ the IMU rate)
                budget = lock_s * (0.01 / mean_dt) ** 2  # trapezoidal integration: error ∝ step² (may underflow to 0)
                weight = max(weight, debt / (debt + budget))
        if step and k_mahony > 0.0:  # debt: time coasted on the gyro, paid back as the accelerometer corrects
            debt = max(debt + dt * (1.0 - weight) - dt * weight * kp * debt, 0.0)
        ki_eff = ki
        if k_mahony > 0.0 and ki_step > 0.0:  # the bias is learned where the gyro integrates finely
            th = rot * dt / ki_step
            ki_eff = ki * weight / (1.0 + th * th)

        qm[0], qm[1], qm[2], qm[3], bias_correction[0], bias_correction[1], bias_correction[2] = mahony_step(
            qm[0], qm[1], qm[2], qm[3], bias_correction[0], bias_correction[1], bias_correction[2], w0, w1, w2,
            a0, a1, a2, mag[i, 0], mag[i, 1], mag[i, 2], use_mag, cos_dec, sin_dec, kp, ki_eff, dt, step, weight)
        if step:
            predict(x, P, w0 - bias[0], w1 - bias[1], w2 - bias[2], dt, q_gyro)
            # q_M and -q_M are one attitude: measure the one on X⁻'s side
            sign = 1.0 if qm[0] * x[0] + qm[1] * x[1] + qm[2] * x[2] + qm[3] * x[3] >= 0.0 else -1.0
            if r == r:  # a NaN accelerometer sample: prediction only
                quaternion_update(x, P, sign * qm[0], sign * qm[1], sign * qm[2], sign * qm[3], r)
            n = np.sqrt(x[0] * x[0] + x[1] * x[1] + x[2] * x[2] + x[3] * x[3])
            x[0], x[1], x[2], x[3] = x[0] / n, x[1] / n, x[2] / n, x[3] / n
        out[i, 0], out[i, 1], out[i, 2], out[i, 3] = x[0], x[1], x[2], x[3]
        if keep_mahony:
            mahony_out[i, 0], mahony_out[i, 1] = qm[0], qm[1]
            mahony_out[i, 2], mahony_out[i, 3] = qm[2], qm[3]
        cov_trace[i] = P[0, 0] + P[1, 1] + P[2, 2] + P[3, 3]
        adaptive_r[i] = r
        mahony_weight[i] = weight
    t_prev[0] = tp
    gyro_prev[0], gyro_prev[1], gyro_prev[2] = gp0, gp1, gp2
    accel_filt[0], accel_filt[1], accel_filt[2], accel_filt[3] = lp, ref, count, mean_dt
    accel_filt[4], accel_filt[5], accel_filt[6] = glp, debt, rest_lp
    return out


class MahonyEkf(Estimator):
    """Mahony-EKF (paper 000): see the module docstring."""
    name = "mahony-ekf"
    Params = MahonyEkfParams
    kernels = (lowpass_in_inertial_frame, mahony_ekf_run)
    color = (120, 90, 0)
    compile_seconds = 3.0  # CPU s, one core (scripts/compile_profile.py)
    PAPER = dict(k_mahony=0.0, accel_tau=0.0)  # strict: the unweighted Mahony measurement (eq 16-17); the additions act on the weight
    keep_mahony = False  # set True to keep the internal Mahony attitude of each chunk in ``mahony_q``
    DIAGNOSTICS = {
        "cov_trace": "trace of the 4×4 quaternion covariance P (dimensionless)",
        "adaptive_r": "diagonal of the measurement noise R = r0 [1 + k_accel |‖a‖ - g|] (eq 17)",
        "mahony_weight": "weight of the internal Mahony's gravity error, 1/(1 + k_mahony |ā - ā_ref|), at least "
                         "the coasting limit's D/(D + B), 1 at rest, 0-1",
    }

    def accel_scale_effect(self, scale_error: float) -> str | None:
        """Eq 17 takes ‖a‖ - g for a manoeuvre: against GRAVITY (no still start, or strict) R
        grows with a scale error all the time."""
        p = self.params
        growth = 1.0 + p.k_accel * abs(scale_error) * GRAVITY
        if growth < 2.0:
            return None
        return scale_effect(f"its accelerometer noise (eq 17: R grows with |‖a‖ - g|) is {growth:.0f} times its rest value "
                            f"even at rest: the accelerometer's pull on the tilt about {np.sqrt(growth):.0f} times "
                            "slower", scale_error, bool(p.strict))

    def initialize(self, q0, gyro_bias, accel_g: float = GRAVITY) -> None:
        q0 = np.array(q0, dtype=np.float64)
        x = q0 / np.linalg.norm(q0)
        bias = np.array(gyro_bias, dtype=np.float64).reshape(3)
        # paper 000: P₀ = I₄; the internal Mahony's integral starts at -bias, as mahony's
        self._state = MahonyEkfState(x, np.eye(4), x.copy(), -bias.copy(), np.array([np.nan]), np.zeros(3),
                                     np.array([np.nan, np.nan, np.nan, np.nan, np.nan, 0.0, np.nan]), bias)
        p = self.run_params()
        self._settings = MahonyEkfSettings(
            kp=float(p.kp), ki=float(p.ki), use_mag=bool(p.use_mag), q_gyro=float(p.q_gyro), r0=float(p.r0),
            k_accel=float(p.k_accel), k_mahony=float(p.k_mahony), accel_lp_s=float(p.accel_lp_s),
            accel_ref_s=float(p.accel_ref_s), weight_min_rate=float(p.weight_min_rate), rest_gyro=float(p.rest_gyro),
            rest_accel=float(p.rest_accel), rest_ref_s=float(p.rest_ref_s), lock_s=float(p.lock_s),
            ki_step=float(p.ki_step), gravity=GRAVITY if p.strict else float(accel_g),
            cos_dec=float(np.cos(self.declination)), sin_dec=float(np.sin(self.declination)), max_step=MAX_STEP_S)
        self.mahony_q = np.empty((0, 4))  # the internal Mahony attitude over the last chunk
        self._ready(q0, gyro_bias)

    def _run(self, s, out, aiding) -> dict:
        n = len(s.t)
        self.mahony_q = np.empty((n if self.keep_mahony else 0, 4))
        diag = MahonyEkfDiagnostics(np.empty(n), np.empty(n), np.empty(n))
        mahony_ekf_run(s, self._state, self._settings, out, diag, self.mahony_q)
        return diag._asdict()
