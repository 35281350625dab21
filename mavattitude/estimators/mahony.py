"""Mahony nonlinear complementary filter.

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
  angles, and at the 1-50 Hz of many logs the end sample alone leaves visible error.
- A step longer than ``MAX_STEP_S`` (a gap in the log) is not integrated.
- The heading error uses γ (radians, up to ±π) as the paper does, not sin γ, so a large
  initial heading error converges at the same rate as a small one.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numba import njit

from ..quaternion import cross, integrate_gyro, qdcm
from .base import MAX_STEP_S, Estimator, as_chunk


@dataclass
class MahonyParams:
    kp: float = 0.2  # proportional gain, 1/s
    ki: float = 0.0005  # integral gain, 1/s²
    use_mag: bool = True  # correct heading from the magnetometer when the log has one


@njit(cache=True)
def mahony_run(t, gyro, accel, mag, q, bias_correction, t_prev, gyro_prev, kp, ki, declination,
               use_mag, max_step, out):
    """Run the filter over a chunk; ``q``, ``bias_correction``, ``t_prev`` (1-element array)
    and ``gyro_prev`` are the state, updated in place. Writes the attitude after each sample
    to ``out``."""
    north = np.array([np.cos(declination), np.sin(declination)])
    for i in range(len(t)):
        dt = t[i] - t_prev[0] if t_prev[0] == t_prev[0] else 0.0  # NaN before the first sample
        t_prev[0] = t[i]
        rate = 0.5 * (gyro[i] + gyro_prev) if dt > 0.0 else gyro[i]  # trapezoidal over the step
        gyro_prev[:] = gyro[i]
        c = qdcm(q)
        e = np.zeros(3)
        a = accel[i]
        a_norm = np.sqrt(a[0] * a[0] + a[1] * a[1] + a[2] * a[2])
        if a_norm > 0.0:
            k = np.array([-c[2, 0], -c[2, 1], -c[2, 2]])  # C(q)ᵀ [0, 0, -1]
            e += cross(a / a_norm, k)
        m = mag[i]
        if use_mag and m[0] == m[0]:  # not NaN
            m_n = c @ m
            h_norm = np.sqrt(m_n[0] * m_n[0] + m_n[1] * m_n[1])
            if h_norm > 0.0:
                # signed angle from h to magnetic north, about the navigation z axis
                gamma = np.arctan2(m_n[0] * north[1] - m_n[1] * north[0],
                                   m_n[0] * north[0] + m_n[1] * north[1])
                e += gamma * c[2, :]  # C(q)ᵀ [0, 0, γ]
        if 0.0 < dt <= max_step:
            bias_correction += ki * e * dt
            w = rate + kp * e + bias_correction
            q[:] = integrate_gyro(q, w, dt)
        out[i, :] = q
    return out


class Mahony(Estimator):
    """Mahony complementary filter (paper 000 §2.3 (1)); see the module docstring."""
    name = "mahony"
    Params = MahonyParams
    uses_mag = True
    kernels = (mahony_run,)

    def initialize(self, q0, gyro_bias) -> None:
        self._q = np.array(q0, dtype=np.float64)
        self._bias_correction = -np.array(gyro_bias, dtype=np.float64)
        self._t_prev = np.array([np.nan])
        self._gyro_prev = np.zeros(3)
        self.initialized = True

    def update(self, t, gyro, accel, mag, in_air=None) -> np.ndarray:
        t, gyro, accel, mag, _ = as_chunk(t, gyro, accel, mag)
        out = np.empty((len(t), 4))
        p = self.params
        return mahony_run(t, gyro, accel, mag, self._q, self._bias_correction, self._t_prev,
                          self._gyro_prev, p.kp, p.ki, self.declination, p.use_mag, MAX_STEP_S, out)

    def has_heading_reference(self, mag_available: bool) -> bool:
        return self.params.use_mag and mag_available

    @property
    def gyro_bias(self) -> np.ndarray:
        """The filter's current gyro bias estimate, rad/s."""
        return -self._bias_correction.copy()
