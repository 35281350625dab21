"""What eq-kf (paper 002) and ncs-eskf (paper 001, an addition) share to tell an attitude error
from a manoeuvre by the accelerometer alone: vectors carried with the body's rotation, a
stillness detector and the consistency test (the accelerometer's own reading of g it takes
is ``gravity``'s).

The consistency test: a horizontal manoeuvre that turns the specific force by ρ away from
gravity also lengthens it to g/cos ρ. A residual angle ρ (the low-passed accelerometer f̃
against the predicted gravity direction) beyond the angle φ_m = arccos(g_a/‖f̃‖) that the
measured length explains is attitude error, not a manoeuvre. g_a is learned while still:
old logs read a few % off g, and a g_a learned in flight would learn a sustained acceleration.

Every body-frame memory (f̃, the still reference) is carried with the rotation of each step,
v ← C(p̂)ᵀ v: in a turn a body-frame low-pass otherwise lags the rotating gravity and reads as
a residual (ncs-eskf's test used a plain body-frame low-pass until eq-kf's was shared: see
its "choices" for the numbers).
"""
from __future__ import annotations

import math

from ..kernel_cache import kernel


@kernel(inline="always")
def step_rotation_into(dx, dy, dz, a):
    """a = C(p̂)ᵀ for the step rotation p = [1 - θ²/8, (½ - θ²/48) Δθ] (θ = |Δθ|, second order),
    normalised: the matrix that carries a navigation-fixed vector's body coordinates across
    the step."""
    th2 = dx * dx + dy * dy + dz * dz
    c0 = 1.0 - th2 / 8.0
    c1 = 0.5 - th2 / 48.0
    pw, px, py, pz = c0, c1 * dx, c1 * dy, c1 * dz
    ww, xx, yy, zz = pw * pw, px * px, py * py, pz * pz
    n = 1.0 / (ww + xx + yy + zz)
    n2 = 2.0 * n
    a[0, 0] = (ww + xx - yy - zz) * n
    a[1, 1] = (ww - xx + yy - zz) * n
    a[2, 2] = (ww - xx - yy + zz) * n
    a[1, 0] = (px * py - pw * pz) * n2
    a[0, 1] = (px * py + pw * pz) * n2
    a[2, 0] = (px * pz + pw * py) * n2
    a[0, 2] = (px * pz - pw * py) * n2
    a[2, 1] = (py * pz - pw * px) * n2
    a[1, 2] = (py * pz + pw * px) * n2


@kernel(inline="always")
def carried(a, v0, v1, v2):
    """a v: a body vector carried across a step."""
    return (a[0, 0] * v0 + a[0, 1] * v1 + a[0, 2] * v2,
            a[1, 0] * v0 + a[1, 1] * v1 + a[1, 2] * v2,
            a[2, 0] * v0 + a[2, 1] * v1 + a[2, 2] * v2)


@kernel(inline="always")
def track_stillness(ref0, ref1, ref2, still_t, ax, ay, az, a, stepped, rate2, still_rate2, still_acc2, dt):
    """Still: rotating slower than √still_rate2 with the accelerometer within √still_acc2 of
    its reading at the span's start, carried with the rotation. Returns the reference and
    the seconds still so far; a new span starts at a sample that is not still."""
    if stepped and rate2 < still_rate2:
        ref0, ref1, ref2 = carried(a, ref0, ref1, ref2)
        if (ax - ref0) ** 2 + (ay - ref1) ** 2 + (az - ref2) ** 2 < still_acc2:
            still_t += dt
        else:
            still_t = -1.0
    else:
        still_t = -1.0
    if not (still_t >= 0.0):  # not still (or NaN): a new span starts here
        still_t = 0.0
        ref0, ref1, ref2 = ax, ay, az
    return ref0, ref1, ref2, still_t


@kernel(inline="always")
def attitude_error(cos_rho, eps, cos_tol, sin_tol):
    """Whether the residual angle ρ exceeds φ_m + tol: cos ρ < cos(φ_m + tol), with
    cos φ_m = g_a/‖f̃‖ = 1 / (1 + eps) (no lengthening: φ_m = 0)."""
    cphi = 1.0 / (1.0 + max(eps, 0.0))
    return cos_rho < cphi * cos_tol - math.sqrt(1.0 - cphi * cphi) * sin_tol
