"""Mahony nonlinear complementary filter (paper 000 §2.3 (1); the "CPF" of paper 003).

Paper 000 §2.3 (1) (Chu, Zhao, Feng 2020), also the "CPF" of paper 003 (Wu et al. 2018);
restated in ../shared/ALGORITHMS.md "mahony". Each IMU sample:

1. gravity error  α = a × k, with a the normalised accelerometer reading and
   k = C(q)ᵀ [0, 0, -1] the reading the current attitude predicts;
2. heading error  β = C(q)ᵀ [0, 0, γ], γ the signed angle from the horizontal part of the
   field in the navigation frame, m_n = C(q) m_b, to magnetic north (true north turned by
   the declination). The paper maps γ to the body frame with C_b^n; the body-frame mapping
   is C_n^b = C(q)ᵀ, used here. No magnetometer sample: β = 0;
3. e = α + β;  δω = Kp e + Ki ∫e dt;  ω' = ω + δω;  q̇ = ½ Ω(ω') q, then normalise.

Choices the paper leaves open, made here:
- Gains: the paper gives none. Kp = 0.2 /s and Ki = 0.0005 /s², chosen by sweeping the
  shared real and SITL logs (``scripts/sweep_mahony_gains.py``). A larger Kp lets the
  accelerometer pull the tilt toward thrust and centripetal acceleration in sustained
  manoeuvres (a multirotor's accelerometer sees little of its tilt; a plane's sees its
  turns); a larger Ki, inside the usual 0.01-0.1, winds those errors into the bias term.
  Ki sits below the usual range because the initial still period already gives the bias.
- The integral term starts at minus the gyro bias from the still period (``initialize``),
  so Ki ∫e dt is the running bias correction from the first sample.
- Integration uses the exact rotation for a constant rate over the step, q ⊗ Exp(ω' dt),
  rather than a first-order step, with the rate taken as the mean of the samples at both
  ends of the step (trapezoidal): ArduPilot logs instantaneous, filtered rates, not delta
  angles, and at the 1-50 Hz of many logs the end sample alone leaves visible error. A series
  of means over each step (delta angles, BROAD) is integrated sample by sample
  (``timestep.step_rate``, every filter alike; BROAD 6D median 0.61° -> 0.53°).
- A step longer than ``MAX_STEP_S`` (a gap in the log) is not integrated.
- The heading error uses γ (radians, up to ±π) as the paper does, not sin γ, so a large
  initial heading error converges at the same rate as a small one.
- The accelerometer low-passed in an almost-inertial frame (``inertial_accel``,
  ``accel_tau``, 1 s; strict: the reading as it is).
  A circle's pull, hand motion and vibration no longer tilt the estimate. Measured (``scripts/judge_estimators.py``;
  BROAD 6D median inclination RMSE, worst trial × VQF; corpus median tilt error against the autopilot,
  SITL logs' median), 0 -> 1 s: BROAD 1.01° -> 0.61° (worst 10.0× -> 1.6× VQF; stationary-magnet
  trial 7.28° -> 1.60°), corpus 1.22° -> 1.25°, SITL 1.94° -> 1.92°; the cost is on two BlueROV logs
  (1.29° -> 1.61°, 1.51° -> 1.76°). 0.3 s: BROAD 0.75°; 3 s: BROAD 0.66°, but 1.76× on a BlueROV log.
  The gains swept again with it (Kp 0.2/0.5 × Ki 0.0005/0.005/0.02): the defaults stay best on
  BROAD and SITL (Ki 0.005: corpus 1.25° -> 1.05° against the autopilot, but BROAD 0.56°, SITL
  2.09°, a BlueROV log 2.0× its old figure; Kp 0.5: BROAD 0.57°, SITL 2.91°).
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import NamedTuple

import numpy as np

from ..flight import GRAVITY
from ..kernel_cache import kernel
from ..quaternion import integrate_gyro_scalar
from ..paramspec import param
from .base import MAX_STEP_S, Estimator
from .inertial_accel import lowpass_in_inertial_frame
from .timestep import integrates, step_dt, step_rate


@dataclass
class MahonyParams:
    kp: float = param(0.2, "[0, 1e6]", "log [0.01, 10]")  # proportional gain, 1/s
    ki: float = param(0.0005, "[0, 1e6]", "log [1e-5, 0.1]")  # integral gain, 1/s²
    use_mag: bool = param(True)  # correct heading from the magnetometer when the log has one
    accel_tau: float = param(1.0, "[0, 60]", "linear [0, 5]")  # s: the accelerometer low-passed in an almost-inertial frame (inertial_accel); 0: the reading as it is
    strict: bool = param(False)  # the filter as published: accel_tau = 0, whatever it says


@kernel(inline="always")
def mahony_step(q0, q1, q2, q3, bc0, bc1, bc2, r0, r1, r2, a0, a1, a2, m0, m1, m2, use_mag,
                north_x, north_y, kp, ki, dt, step, accel_weight=1.0):
    """One sample of the filter on scalars (steps 1-3 of the module docstring): attitude
    (q0..q3), integral term (bc0..bc2), gyro rate r, accelerometer a, magnetometer m (NaN: none);
    integrates only when ``step``. Returns the new (q0, q1, q2, q3, bc0, bc1, bc2). The gravity
    error is multiplied by ``accel_weight`` (1: this filter exactly; mahony-ekf weighs it).
    Shared with mahony-ekf, whose measurement it is, and cpf-ekf, whose watchdog runs it."""
    # third row of C(q): k = C(q)ᵀ [0, 0, -1] = -(c20, c21, c22)
    c20 = 2 * (q1 * q3 - q0 * q2)
    c21 = 2 * (q2 * q3 + q0 * q1)
    c22 = 1 - 2 * (q1 * q1 + q2 * q2)
    e0 = e1 = e2 = 0.0
    a_norm = np.sqrt(a0 * a0 + a1 * a1 + a2 * a2)
    if a_norm > 0.0:
        u0, u1, u2 = a0 / a_norm, a1 / a_norm, a2 / a_norm
        k0, k1, k2 = -c20, -c21, -c22
        e0 += accel_weight * (u1 * k2 - u2 * k1)  # (a / |a|) × k
        e1 += accel_weight * (u2 * k0 - u0 * k2)
        e2 += accel_weight * (u0 * k1 - u1 * k0)
    if use_mag and m0 == m0:  # not NaN
        # horizontal part of m_n = C(q) m
        mn0 = ((1 - 2 * (q2 * q2 + q3 * q3)) * m0 + 2 * (q1 * q2 - q0 * q3) * m1
               + 2 * (q1 * q3 + q0 * q2) * m2)
        mn1 = (2 * (q1 * q2 + q0 * q3) * m0 + (1 - 2 * (q1 * q1 + q3 * q3)) * m1
               + 2 * (q2 * q3 - q0 * q1) * m2)
        h_norm = np.sqrt(mn0 * mn0 + mn1 * mn1)
        if h_norm > 0.0:
            # signed angle from h to magnetic north, about the navigation z axis
            gamma = np.arctan2(mn0 * north_y - mn1 * north_x, mn0 * north_x + mn1 * north_y)
            e0 += gamma * c20  # C(q)ᵀ [0, 0, γ]
            e1 += gamma * c21
            e2 += gamma * c22
    if step:
        bc0 += ki * e0 * dt
        bc1 += ki * e1 * dt
        bc2 += ki * e2 * dt
        q0, q1, q2, q3 = integrate_gyro_scalar(q0, q1, q2, q3, r0 + kp * e0 + bc0,
                                               r1 + kp * e1 + bc1, r2 + kp * e2 + bc2, dt)
    return q0, q1, q2, q3, bc0, bc1, bc2


class MahonyState(NamedTuple):
    """What the filter carries from one chunk to the next (arrays, updated in place)."""
    q: np.ndarray  # (4,) attitude, body -> NED
    bias_correction: np.ndarray  # (3,) the integral term: minus the gyro bias, rad/s
    t_prev: np.ndarray  # (1,) time of the last sample, NaN before the first
    gyro_prev: np.ndarray  # (3,) the last gyro sample, rad/s


class MahonySettings(NamedTuple):
    """The parameters as the kernel takes them."""
    kp: float
    ki: float
    north_x: float  # cos(declination): magnetic north in the NED frame
    north_y: float  # sin(declination)
    use_mag: bool
    max_step: float  # s: a longer step is a gap, not integrated


@kernel
def mahony_run(s, state, cfg, out):
    """Run the filter over a chunk of samples ``s`` (``base.Samples``); ``state``
    (``MahonyState``) is updated in place. Writes the attitude after each sample to ``out``.

    The loop allocates nothing: the state lives in scalars while it runs (C(q) is formed
    element by element, only the entries used) and goes back to the arrays at the end."""
    t, gyro, accel, mag = s.t, s.gyro, s.accel, s.mag
    over_step = s.rate_over_step  # each gyro sample the mean over its step (timestep.step_rate)
    q, bias_correction = state.q, state.bias_correction
    q0, q1, q2, q3 = q[0], q[1], q[2], q[3]
    bc0, bc1, bc2 = bias_correction[0], bias_correction[1], bias_correction[2]
    gp0, gp1, gp2 = state.gyro_prev[0], state.gyro_prev[1], state.gyro_prev[2]
    tp = state.t_prev[0]
    for i in range(len(t)):
        dt = step_dt(t[i], tp)
        tp = t[i]
        g0, g1, g2 = gyro[i, 0], gyro[i, 1], gyro[i, 2]
        r0, r1, r2 = step_rate(g0, g1, g2, gp0, gp1, gp2, dt, over_step)
        gp0, gp1, gp2 = g0, g1, g2
        q0, q1, q2, q3, bc0, bc1, bc2 = mahony_step(
            q0, q1, q2, q3, bc0, bc1, bc2, r0, r1, r2, accel[i, 0], accel[i, 1], accel[i, 2],
            mag[i, 0], mag[i, 1], mag[i, 2], cfg.use_mag, cfg.north_x, cfg.north_y, cfg.kp, cfg.ki, dt,
            integrates(dt, cfg.max_step))
        out[i, 0], out[i, 1], out[i, 2], out[i, 3] = q0, q1, q2, q3
    q[0], q[1], q[2], q[3] = q0, q1, q2, q3
    bias_correction[0], bias_correction[1], bias_correction[2] = bc0, bc1, bc2
    state.gyro_prev[0], state.gyro_prev[1], state.gyro_prev[2] = gp0, gp1, gp2
    state.t_prev[0] = tp
    return out


class Mahony(Estimator):
    """Mahony complementary filter (paper 000 §2.3 (1)); see the module docstring."""
    name = "mahony"
    Params = MahonyParams
    kernels = (lowpass_in_inertial_frame, mahony_run)
    color = (255, 150, 0)
    compile_seconds = 1.5  # CPU s, one core (scripts/compile_profile.py)
    bench_min_rate = 1e6  # samples/s, bench's target beside the one every estimator has
    PAPER = dict(accel_tau=0.0)  # strict: the accelerometer as it reads

    def initialize(self, q0, gyro_bias, accel_g: float = GRAVITY) -> None:
        p = self.params
        self._state = MahonyState(np.array(q0, dtype=np.float64), -np.array(gyro_bias, dtype=np.float64),
                                  np.array([np.nan]), np.zeros(3))
        self._settings = MahonySettings(
            kp=float(p.kp), ki=float(p.ki), north_x=math.cos(self.declination), north_y=math.sin(self.declination),
            use_mag=bool(p.use_mag), max_step=MAX_STEP_S)
        self._ready(q0, gyro_bias)

    def _run(self, s, out, aiding) -> dict:
        mahony_run(s, self._state, self._settings, out)
        return {}

    @property
    def gyro_bias(self) -> np.ndarray:
        """The filter's current gyro bias estimate, rad/s."""
        return -self._state.bias_correction.copy()
