"""Rigid-body trajectories: the true motion every simulated sensor observes.

A scenario is an analytic motion: position, velocity and acceleration (NED, m, m/s, m/s²) and
attitude (quaternion, body FRD -> NED) as closed-form functions of time, in seconds since the
log starts. ``sample`` evaluates it at any times, vectorised, and adds

- the body rates, ω_b = 2 q* ⊗ q̇, with q̇ from a 4th-order central difference of the analytic
  attitude over a 1 kHz stencil (±1, ±2 ms): error ~1e-11 rad/s, a few 1e-6 rad/s within 2 ms of
  the end of a smoothstep (where the fourth derivative of position jumps). Exact for every
  purpose here, at any sample times, with no interpolation;
- the specific force, f_b = C(q)ᵀ (a_n - g_n).

Every scenario sits still on the ground first (``still_until``): estimators look for that
still period to measure the gyro bias. Motions start and stop through quintic smoothsteps, so
acceleration is continuous and jerk finite (no impossible step in thrust or body rate).

A scenario is a small record in ``REGISTRY``: to add one, write its motion function from the
helpers below and ``register`` it; ``sensor_overrides`` lets it change sensor parameters
(e.g. vibration) without touching the sensor code.
"""
from __future__ import annotations

from dataclasses import dataclass, field, fields
from typing import Callable, Mapping, NamedTuple

import numpy as np

from .. import quaternion as quat
from ..flight import GRAVITY

GRAVITY_NED = np.array([0.0, 0.0, GRAVITY])  # m/s², g_n
STENCIL_STEP = 1e-3  # s: the rate stencil's step (a 1 kHz internal grid)
SAMPLE_CHUNK = 65_536  # samples evaluated at a time


class Motion(NamedTuple):
    """What a scenario's motion function returns for an array of N times."""

    pos: np.ndarray  # (N, 3) m, NED relative to home
    vel: np.ndarray  # (N, 3) m/s
    acc: np.ndarray  # (N, 3) m/s², kinematic (not specific force)
    q: np.ndarray  # (N, 4) body -> NED


@dataclass
class TrajectorySample:
    """The true state at N times."""

    t: np.ndarray  # (N,) s
    pos_ned: np.ndarray  # (N, 3) m, relative to home (down positive)
    vel_ned: np.ndarray  # (N, 3) m/s
    acc_ned: np.ndarray  # (N, 3) m/s²
    q: np.ndarray  # (N, 4) unit quaternions [w, x, y, z], body -> NED, sign-continuous
    omega_b: np.ndarray  # (N, 3) rad/s, body rates (FRD)
    specific_force_b: np.ndarray  # (N, 3) m/s², what a perfect accelerometer reads


@dataclass(frozen=True)
class Scenario:
    name: str
    description: str
    motion: Callable[[np.ndarray], Motion]  # t (s since log start) -> Motion
    still_until: float  # s since log start: at rest on the ground before this
    sensor_overrides: Mapping[str, float] = field(default_factory=dict)  # SensorParams fields


REGISTRY: dict[str, Scenario] = {}


def register(scenario: Scenario) -> Scenario:
    REGISTRY[scenario.name] = scenario
    return scenario


def sample(scenario: Scenario, t) -> TrajectorySample:
    """The scenario's true state at times ``t`` (s since log start), rates and specific force included."""
    t = np.asarray(t, dtype=float)
    # In chunks: long, fast logs (an hour at 400 Hz) stay cache-sized instead of gigabytes of temporaries.
    parts = [_sample(scenario, t[i:i + SAMPLE_CHUNK]) for i in range(0, max(len(t), 1), SAMPLE_CHUNK)]
    joined = TrajectorySample(*(np.concatenate([getattr(p, f.name) for p in parts])
                                for f in fields(TrajectorySample)))
    joined.q = quat.make_continuous(joined.q)
    return joined


def _sample(scenario: Scenario, t: np.ndarray) -> TrajectorySample:
    m = scenario.motion(t)
    q = quat.make_continuous(quat.normalize(m.q))

    def q_at(offset):
        qn = quat.normalize(scenario.motion(t + offset).q)
        return qn * np.where(np.sum(qn * q, axis=-1) < 0, -1.0, 1.0)[:, None]  # same hemisphere as q

    h = STENCIL_STEP
    q_dot = (q_at(-2 * h) - 8 * q_at(-h) + 8 * q_at(h) - q_at(2 * h)) / (12 * h)
    omega_b = 2.0 * quat.multiply(quat.conjugate(q), q_dot)[:, 1:]
    specific_force_b = quat.rotate(quat.conjugate(q), m.acc - GRAVITY_NED)
    return TrajectorySample(t, m.pos, m.vel, m.acc, q, omega_b, specific_force_b)


# ---------------------------------------------------------------- building blocks


def smoothstep(u):
    """Quintic smoothstep of u clipped to [0, 1] and its first two derivatives w.r.t. u.

    s(0) = 0, s(1) = 1, with s' and s'' zero at both ends: a motion eased in with it has
    continuous acceleration.
    """
    u = np.clip(np.asarray(u, dtype=float), 0.0, 1.0)
    s = u ** 3 * (10 - 15 * u + 6 * u ** 2)
    ds = 30 * u ** 2 * (1 - u) ** 2
    dds = 60 * u * (1 - u) * (1 - 2 * u)
    return s, ds, dds


def eased(t, start, duration):
    """A 0 -> 1 transition over [start, start + duration] (s): value, rate (1/s), acceleration (1/s²)."""
    s, ds, dds = smoothstep((np.asarray(t, dtype=float) - start) / duration)
    return s, ds / duration, dds / duration ** 2


def ramped_progress(t, start, duration):
    """Time integral of ``eased``: progress that starts still and reaches rate 1 after the ramp.

    Returns (progress in s, rate, acceleration). Multiply by an angular rate to get a phase that
    eases from standstill to constant speed without a jerk step.
    """
    t = np.asarray(t, dtype=float)
    u = np.clip((t - start) / duration, 0.0, 1.0)
    during = duration * u ** 4 * (2.5 - 3 * u + u ** 2)  # ∫ smoothstep, = duration/2 at u = 1
    progress = np.where(t > start + duration, duration / 2 + (t - start - duration), during)
    rate, rate_dot, _ = eased(t, start, duration)
    return progress, rate, rate_dot


def eased_sines(t, envelope, amplitudes, periods, phases):
    """Σ aᵢ sin(2π t / Tᵢ + φᵢ), scaled by an envelope (value, rate, acceleration); with derivatives.

    Returns (value, first derivative, second derivative) w.r.t. t, each shaped like t.
    """
    t = np.asarray(t, dtype=float)
    e, de, dde = envelope
    x = np.zeros_like(t)
    dx = np.zeros_like(t)
    ddx = np.zeros_like(t)
    for a, period, phase in zip(amplitudes, periods, phases):
        w = 2 * np.pi / period
        x += a * np.sin(w * t + phase)
        dx += a * w * np.cos(w * t + phase)
        ddx += -a * w * w * np.sin(w * t + phase)
    return e * x, de * x + e * dx, dde * x + 2 * de * dx + e * ddx


def thrust_aligned(acc_ned, yaw):
    """Multirotor attitude: body z along -(a_n - g_n) (thrust opposes specific force), Euler yaw ``yaw``.

    In the heading frame (NED turned by -yaw) ZYX Euler angles give body z =
    [sin θ cos φ, -sin φ, cos θ cos φ]; equating it with -f/|f| gives roll and pitch.
    The accelerometer then reads [0, 0, -|f|]: what a multirotor flying coordinated feels.
    """
    f = np.asarray(acc_ned, dtype=float) - GRAVITY_NED
    cy, sy = np.cos(yaw), np.sin(yaw)
    fx = cy * f[:, 0] + sy * f[:, 1]  # specific force in the heading frame
    fy = -sy * f[:, 0] + cy * f[:, 1]
    fz = f[:, 2]
    roll = np.arctan2(fy, np.hypot(fx, fz))
    pitch = np.arctan2(-fx, -fz)
    return quat.from_euler(roll, pitch, yaw)


def take_off(t, start, duration, height):
    """Vertical climb from the ground to ``height`` (m): NED down position, velocity, acceleration."""
    s, ds, dds = eased(t, start, duration)
    return -height * s, -height * ds, -height * dds


def _stack(n, x=None, y=None, z=None):
    """Three per-axis arrays (or None for zero) into an (n, 3) array."""
    return np.stack([np.zeros(n) if a is None else np.broadcast_to(a, (n,)) for a in (x, y, z)], axis=-1)


# ---------------------------------------------------------------- scenarios

STILL_S = 6.0  # s on the ground, still, at the start of every scenario


def _static_motion(t):
    n = len(t)
    q = np.broadcast_to(quat.from_euler(np.radians(2.0), np.radians(-1.0), np.radians(30.0)), (n, 4))
    zeros = np.zeros((n, 3))
    return Motion(zeros, zeros, zeros, np.array(q))


register(Scenario(
    "static",
    "on the ground, still, tilted roll 2°, pitch -1°, yaw 30°",
    _static_motion,
    still_until=np.inf,
))


HOVER_HEIGHT = 5.0  # m
HOVER_CLIMB = (STILL_S, 6.0)  # climb start, duration (s)
HOVER_EASE_IN = (HOVER_CLIMB[0] + HOVER_CLIMB[1], 5.0)  # motions grow in over this span
HOVER_YAW = np.radians(75.0)


def _hover_motion(t):
    n = len(t)
    env = eased(t, *HOVER_EASE_IN)
    # Position wander: tens of centimetres with periods of seconds (amplitudes m, periods s, phases rad).
    pn = eased_sines(t, env, (0.4, 0.15), (13.0, 4.1), (0.5, 1.3))
    pe = eased_sines(t, env, (0.35, 0.12), (11.0, 3.7), (2.1, 0.2))
    pd = eased_sines(t, env, (0.2, 0.05), (9.0, 2.9), (2.2, 0.9))
    climb = take_off(t, *HOVER_CLIMB, HOVER_HEIGHT)
    pos = _stack(n, pn[0], pe[0], climb[0] + pd[0])
    vel = _stack(n, pn[1], pe[1], climb[1] + pd[1])
    acc = _stack(n, pn[2], pe[2], climb[2] + pd[2])
    # Attitude motions: a few degrees, a slow and a quick component per axis. Prescribed rather
    # than thrust-aligned, so the accelerometer sees the tilt, as hover-tuned estimators assume.
    roll = eased_sines(t, env, np.radians((3.0, 1.2)), (5.3, 1.9), (0.3, 1.1))[0]
    pitch = eased_sines(t, env, np.radians((2.5, 1.0)), (6.1, 2.3), (2.0, 0.4))[0]
    yaw = HOVER_YAW + eased_sines(t, env, np.radians((8.0,)), (17.0,), (0.7,))[0]
    return Motion(pos, vel, acc, quat.from_euler(roll, pitch, yaw))


register(Scenario(
    "hover",
    "take-off to 5 m, hover with attitude motions of a few degrees and position wander of ~0.5 m",
    _hover_motion,
    still_until=HOVER_CLIMB[0],
))


# Figure-eight: a lemniscate of Bernoulli, half-length 40 m, one lap in 32 s once up to speed:
# 5.6-7.9 m/s, coordinated turns up to 25° of bank, yaw rate up to 34°/s. It starts at the
# crossing point (an inflection, so the ramp-in begins straight), heading south-west.
FIG8_HALF_LENGTH = 40.0  # m
FIG8_LAP = 32.0  # s per lap at full speed
FIG8_HEIGHT = 10.0  # m
FIG8_CLIMB = (STILL_S, 6.0)  # climb start, duration (s)
FIG8_RAMP = (FIG8_CLIMB[0] + FIG8_CLIMB[1] + 2.0, 10.0)  # after 2 s of hover, 10 s to full speed
FIG8_START_PHASE = np.pi / 2  # the crossing point, at home


def _lemniscate(phi):
    """Bernoulli lemniscate x = a cos φ / (1 + sin²φ), y = a sin φ cos φ / (1 + sin²φ) (north, east)
    and its first two derivatives w.r.t. φ, each (N, 2)."""
    a = FIG8_HALF_LENGTH
    s, c = np.sin(phi), np.cos(phi)
    d = 1 + s * s
    p = np.stack([a * c / d, a * s * c / d], axis=-1)
    dp = np.stack([-a * s * (3 - s * s) / d ** 2, a * (1 - 3 * s * s) / d ** 2], axis=-1)
    ddp = np.stack([-a * c * (3 - 12 * s * s + s ** 4) / d ** 3,
                    -2 * a * s * c * (5 - 3 * s * s) / d ** 3], axis=-1)
    return p, dp, ddp


def _figure8_motion(t):
    n = len(t)
    progress, rate, rate_dot = ramped_progress(t, *FIG8_RAMP)
    omega = 2 * np.pi / FIG8_LAP
    phi, phi_dot, phi_ddot = FIG8_START_PHASE + omega * progress, omega * rate, omega * rate_dot
    p, dp, ddp = _lemniscate(phi)
    climb = take_off(t, *FIG8_CLIMB, FIG8_HEIGHT)
    pos = _stack(n, p[:, 0], p[:, 1], climb[0])
    vel = _stack(n, dp[:, 0] * phi_dot, dp[:, 1] * phi_dot, climb[1])
    acc = _stack(n, *(ddp[:, i] * phi_dot ** 2 + dp[:, i] * phi_ddot for i in range(2)), climb[2])
    # Yaw along the path tangent: the velocity heading once moving, and already the
    # heading the ramp will start along while still (the tangent never vanishes).
    yaw = np.arctan2(dp[:, 1], dp[:, 0])
    return Motion(pos, vel, acc, thrust_aligned(acc, yaw))


register(Scenario(
    "figure8",
    "take-off to 10 m, then a 80 m x 28 m figure-eight at 5.6-7.9 m/s, coordinated turns up to 25° bank",
    _figure8_motion,
    still_until=FIG8_CLIMB[0],
))


# Sustained linear acceleration: a vehicle on a straight north-south track, level (pitch 2°,
# nose north), speeding up to 30 m/s over 12 s (0.25 g on average, 0.48 g at the peak),
# cruising 8 s, slowing to a stop over 12 s, pausing 4 s, then the same run back south. A
# level attitude with seconds of horizontal specific force: the case where an estimator
# that trusts the accelerometer as gravity tilts by atan(a/g), up to 25°.
ACCEL_SPEED = 30.0  # m/s
ACCEL_RAMP = 12.0  # s, speeding up and slowing down each
ACCEL_CRUISE = 8.0  # s
ACCEL_PAUSE = 4.0  # s at rest between runs
ACCEL_LEG = 2 * ACCEL_RAMP + ACCEL_CRUISE + ACCEL_PAUSE
ACCEL_ATTITUDE = (0.0, np.radians(2.0), 0.0)  # roll, pitch, yaw


def _accel_motion(t):
    n = len(t)
    since = np.maximum(np.asarray(t, dtype=float) - STILL_S, 0.0)
    leg = np.floor(since / ACCEL_LEG)
    local = since - leg * ACCEL_LEG
    up = ramped_progress(local, 0.0, ACCEL_RAMP)
    down = ramped_progress(local, ACCEL_RAMP + ACCEL_CRUISE, ACCEL_RAMP)
    dist, speed, acc = (ACCEL_SPEED * (u - d) for u, d in zip(up, down))
    run_length = ACCEL_SPEED * (ACCEL_RAMP + ACCEL_CRUISE)
    backwards = leg % 2 == 1  # even legs run north from home, odd legs back south
    north = np.where(backwards, run_length - dist, dist)
    direction = np.where(backwards, -1.0, 1.0)
    pos = _stack(n, north)
    vel = _stack(n, direction * speed)
    accel = _stack(n, direction * acc)
    q = np.broadcast_to(quat.from_euler(*ACCEL_ATTITUDE), (n, 4))
    return Motion(pos, vel, accel, np.array(q))


register(Scenario(
    "accel",
    "level on a straight track: 0-30 m/s in 12 s, cruise 8 s, stop in 12 s, pause 4 s, back again",
    _accel_motion,
    still_until=STILL_S,
))


# Circling flight (paper 003 §2.3: a loaded multirotor circling a point, 5 m/s): take off to
# 30 m, then a 75 m radius circle clockwise seen from above (north, then east), yaw along the
# track, coordinated (thrust-aligned): 5 m/s, one lap in 94 s, centripetal 0.33 m/s² (1.9°
# of bank). It starts at home, heading north, the circle's centre 75 m east.
CIRCLE_RADIUS = 75.0  # m
CIRCLE_SPEED = 5.0  # m/s
CIRCLE_HEIGHT = 30.0  # m
CIRCLE_CLIMB = (STILL_S, 8.0)  # climb start, duration (s)
CIRCLE_RAMP = (CIRCLE_CLIMB[0] + CIRCLE_CLIMB[1] + 2.0, 8.0)  # after 2 s of hover, 8 s to full speed


def _ramped_circle(t, radius, speed, ramp, climb):
    """A clockwise circle (seen from above) from home heading north, its centre ``radius`` east,
    the speed ramped up over ``ramp`` (start, duration), with the vertical motion ``climb``
    ((down, rate, accel) arrays of ``take_off``). Returns pos, vel, acc (NED) and φ, the angle
    travelled (the track's heading) with its rate."""
    n = len(t)
    progress, rate, rate_dot = ramped_progress(t, *ramp)
    omega = speed / radius
    phi, phi_dot, phi_ddot = omega * progress, omega * rate, omega * rate_dot
    r, s, c = radius, np.sin(phi), np.cos(phi)
    pos = _stack(n, r * s, r * (1 - c), climb[0])
    vel = _stack(n, r * c * phi_dot, r * s * phi_dot, climb[1])
    acc = _stack(n, r * (c * phi_ddot - s * phi_dot ** 2), r * (s * phi_ddot + c * phi_dot ** 2), climb[2])
    return pos, vel, acc, phi, phi_dot


def _circle_motion(t):
    climb = take_off(t, *CIRCLE_CLIMB, CIRCLE_HEIGHT)
    pos, vel, acc, phi, _ = _ramped_circle(t, CIRCLE_RADIUS, CIRCLE_SPEED, CIRCLE_RAMP, climb)
    return Motion(pos, vel, acc, thrust_aligned(acc, phi))  # yaw along the track: the heading is φ


register(Scenario(
    "circle",
    "take-off to 30 m, then circling at 5 m/s on a 75 m radius (94 s per lap), yaw along the track",
    _circle_motion,
    still_until=CIRCLE_CLIMB[0],
))


# Fixed-wing orbit: the turn a plane flies, for the turn compensation of eq-kf. From rest at
# home, heading north, the vehicle speeds up to 15 m/s along a 35 m radius circle clockwise
# seen from above (centre 35 m east) over 10 s, then circles, climbing 40 m over 20 s on the
# way: 6.4 m/s² centripetal, 33° of bank, 14.7 s per lap. Unlike the multirotor scenarios the
# body x axis points along the velocity (pitch = flight-path angle) and the bank is the one
# that keeps the specific force in the body x-z plane (a coordinated turn, no sideslip), so
# the accelerometer reads the turn's ω × V x̂ on top of gravity.
ORBIT_RADIUS = 35.0  # m
ORBIT_SPEED = 15.0  # m/s
ORBIT_RAMP = (STILL_S, 10.0)  # speed-up start, duration (s)
ORBIT_CLIMB = (ORBIT_RAMP[0] + ORBIT_RAMP[1] + 2.0, 20.0, 40.0)  # climb start (s), duration (s), height (m)


def _orbit_motion(t):
    climb = take_off(t, *ORBIT_CLIMB)
    pos, vel, acc, phi, phi_dot = _ramped_circle(t, ORBIT_RADIUS, ORBIT_SPEED, ORBIT_RAMP, climb)
    s, c = np.sin(phi), np.cos(phi)
    yaw = phi  # along the track
    pitch = np.arctan2(-climb[1], ORBIT_RADIUS * phi_dot)  # body x along the velocity (0 at rest)
    f = acc - GRAVITY_NED  # roll: no body-y specific force, tan φ = f'_y / -f'_z in the yaw-pitch frame
    fx = c * f[:, 0] + s * f[:, 1]
    fy = -s * f[:, 0] + c * f[:, 1]
    fz = np.sin(pitch) * fx + np.cos(pitch) * f[:, 2]
    roll = np.arctan2(fy, -fz)
    return Motion(pos, vel, acc, quat.from_euler(roll, pitch, yaw))


register(Scenario(
    "orbit",
    "fixed-wing: speeds up to 15 m/s on a 35 m radius circle, then circles at 33° of bank, "
    "climbing 40 m, body x along the velocity (14.7 s per lap)",
    _orbit_motion,
    still_until=ORBIT_RAMP[0],
))
