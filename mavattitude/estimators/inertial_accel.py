"""The accelerometer low-passed in an almost-inertial frame: gravity kept, motion averaged out.

A filter that takes the accelerometer's direction for "down" is pulled off by every acceleration
that is not gravity. In the body frame those cannot be filtered away without delaying the
attitude: the body turns, so "down" moves in the body frame as fast as the vehicle rotates. In a
frame that does not turn with the body, gravity stands still and the rest does not: hand motion,
vibration, a tap or a bump average towards zero, and a circle's centripetal pull, constant in the
body, turns round and cancels. This is VQF's central idea (Laidig & Seel, "VQF: Highly accurate
IMU orientation estimation with bias estimation and magnetic disturbance rejection", Information
Fusion 91, 2023, §3.1: the accelerometer is low-passed "in an almost inertial frame" given by
gyroscope strapdown integration). Here it is a step in front of a filter, not a filter of its own:

1. strapdown: q_I ← q_I ⊗ Exp((ω - b) dt), with ω the step's rate as our filters take it
   (``timestep.step_rate``) and b the gyro bias known at the start (the alignment's);
2. into that frame: a_I = C(q_I) a;
3. low-pass: two first-order lags in series, each exact for its own step, time constant τ/2
   each, so τ in all (a critically damped second order);
4. back into the body frame: ā = C(q_I)ᵀ ā_I, which the filter then takes in place of a.

The frame drifts at the gyro's remaining bias; gravity moves with it, and the low-pass follows
with a lag of about τ: an error of (remaining bias · τ), 0.1° at 0.1 °/s and τ = 1 s.

Choices (VQF makes them differently; ours fit a pre-step shared by the seven filters):
- two exact first-order lags rather than VQF's second-order Butterworth with coefficients for a
  fixed sample time: the logs' steps vary (jitter, dropped samples), and an exact lag is right at
  any step;
- the bias is the alignment's, not a running estimate: the pre-step runs the same whatever the
  filter behind it does, and replay and live stay identical sample for sample;
- the lags start at the first sample's reading (the run starts still, ``alignment``), and start
  again after a step longer than ``base.MAX_STEP_S`` (a gap: the vehicle may be anywhere since).
"""
from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np

from ..kernel_cache import kernel
from ..quaternion import integrate_gyro_scalar
from .timestep import integrates, step_dt, step_rate


class InertialAccelState(NamedTuple):
    """What the pre-step carries from one chunk to the next (arrays, updated in place)."""
    q: np.ndarray  # (4,) the strapdown frame: body -> almost-inertial
    first: np.ndarray  # (3,) the first lag's output, in the inertial frame, m/s²; NaN before a reading
    second: np.ndarray  # (3,) the second lag's output: the low-passed acceleration, m/s²
    t_prev: np.ndarray  # (1,) the last sample's time, NaN before the first
    gyro_prev: np.ndarray  # (3,) the last gyro sample, rad/s
    bias: np.ndarray  # (3,) the gyro bias taken off before the strapdown, rad/s


def start(q0, gyro_bias) -> InertialAccelState:
    """A pre-step starting at attitude ``q0`` (so the frame begins as NED) with ``gyro_bias``."""
    q0 = np.array(q0, dtype=np.float64)
    return InertialAccelState(q0 / np.linalg.norm(q0), np.full(3, np.nan), np.full(3, np.nan), np.array([np.nan]),
                              np.zeros(3), np.array(gyro_bias, dtype=np.float64).reshape(3))


@kernel
def lowpass_in_inertial_frame(s, state, tau, max_step, out):
    """Steps 1-4 of the module docstring over a chunk of samples ``s`` (``base.Samples``): the
    low-passed accelerometer into ``out`` (N, 3); ``state`` (``InertialAccelState``) updated in place."""
    t, gyro, accel = s.t, s.gyro, s.accel
    over_step = s.rate_over_step  # each gyro sample the mean over its step (timestep.step_rate)
    q0, q1, q2, q3 = state.q[0], state.q[1], state.q[2], state.q[3]
    lag1, lag2, bias = state.first, state.second, state.bias
    gp0, gp1, gp2 = state.gyro_prev[0], state.gyro_prev[1], state.gyro_prev[2]
    tp = state.t_prev[0]
    half_tau = 0.5 * tau
    for i in range(len(t)):
        dt = step_dt(t[i], tp, math.inf)  # inf before the first sample: a start, as after a gap
        tp = t[i]
        g0, g1, g2 = gyro[i, 0], gyro[i, 1], gyro[i, 2]
        if integrates(dt, max_step):
            r0, r1, r2 = step_rate(g0, g1, g2, gp0, gp1, gp2, dt, over_step)
            q0, q1, q2, q3 = integrate_gyro_scalar(q0, q1, q2, q3, r0 - bias[0], r1 - bias[1], r2 - bias[2], dt)
        gp0, gp1, gp2 = g0, g1, g2
        # C(q): body -> inertial
        c00 = 1 - 2 * (q2 * q2 + q3 * q3)
        c01 = 2 * (q1 * q2 - q0 * q3)
        c02 = 2 * (q1 * q3 + q0 * q2)
        c10 = 2 * (q1 * q2 + q0 * q3)
        c11 = 1 - 2 * (q1 * q1 + q3 * q3)
        c12 = 2 * (q2 * q3 - q0 * q1)
        c20 = 2 * (q1 * q3 - q0 * q2)
        c21 = 2 * (q2 * q3 + q0 * q1)
        c22 = 1 - 2 * (q1 * q1 + q2 * q2)
        a0, a1, a2 = accel[i, 0], accel[i, 1], accel[i, 2]
        x0 = c00 * a0 + c01 * a1 + c02 * a2
        x1 = c10 * a0 + c11 * a1 + c12 * a2
        x2 = c20 * a0 + c21 * a1 + c22 * a2
        if x0 == x0 and x1 == x1 and x2 == x2:  # a non-finite reading leaves the lags as they are
            if dt > max_step or lag2[0] != lag2[0]:  # the first reading, or after a gap: start from it
                lag1[0], lag1[1], lag1[2] = x0, x1, x2
                lag2[0], lag2[1], lag2[2] = x0, x1, x2
            elif dt > 0.0:
                k = -math.expm1(-dt / half_tau)  # 1 - exp(-dt / (τ/2)), exact for the step
                lag1[0] += k * (x0 - lag1[0])
                lag1[1] += k * (x1 - lag1[1])
                lag1[2] += k * (x2 - lag1[2])
                lag2[0] += k * (lag1[0] - lag2[0])
                lag2[1] += k * (lag1[1] - lag2[1])
                lag2[2] += k * (lag1[2] - lag2[2])
        if lag2[0] != lag2[0]:  # no finite reading yet: pass the reading on as it is
            out[i, 0], out[i, 1], out[i, 2] = a0, a1, a2
            continue
        # back into the body frame: C(q)ᵀ
        out[i, 0] = c00 * lag2[0] + c10 * lag2[1] + c20 * lag2[2]
        out[i, 1] = c01 * lag2[0] + c11 * lag2[1] + c21 * lag2[2]
        out[i, 2] = c02 * lag2[0] + c12 * lag2[1] + c22 * lag2[2]
    state.q[0], state.q[1], state.q[2], state.q[3] = q0, q1, q2, q3
    state.gyro_prev[0], state.gyro_prev[1], state.gyro_prev[2] = gp0, gp1, gp2
    state.t_prev[0] = tp
    return out
