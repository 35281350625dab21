"""The accelerometer's own reading of g: what a filter that gates or weighs the accelerometer
against g compares with, in place of standard gravity.

Old logs read g 10-20 % off at rest (2014-15 copters: 8.0 m/s² on one), and a filter that
takes ‖a‖ - 9.80665 for a manoeuvre then refuses the accelerometer for the whole flight. The
reading is learned once, at the still start (``reading_at_rest``: the median ‖a‖ over the span
``alignment`` finds still, gyro quiet and the accelerometer steady, whatever its length), and
where a filter tells it is still in flight, slowly (``learn_gravity``, time constant
``G_LEARN_S``). Both are bounded to ``G_BOUND`` of standard gravity: beyond that it is no
accelerometer reading g, and a sustained acceleration learned as g would hide manoeuvres.
``strict`` filters keep the published constant (their ``initialize``).
"""
from __future__ import annotations

import numpy as np

from ..flight import GRAVITY
from ..kernel_cache import kernel

G_BOUND = 0.25  # a reading of g is taken within ±25 % of standard gravity
G_MIN = GRAVITY * (1.0 - G_BOUND)
G_MAX = GRAVITY * (1.0 + G_BOUND)
G_LEARN_S = 5.0  # s, time constant of learning the reading of g while still in flight


def plausible_g(norm: float) -> bool:
    """Whether ``norm`` (m/s²) can be an accelerometer's reading of g at rest."""
    return G_MIN <= norm <= G_MAX


def reading_at_rest(accel) -> float:
    """The accelerometer's reading of g over still samples ``accel`` (N, 3): the median ‖a‖,
    bounded to G_MIN..G_MAX; GRAVITY when there are none."""
    norms = np.linalg.norm(np.asarray(accel, dtype=np.float64).reshape(-1, 3), axis=1)
    norms = norms[np.isfinite(norms)]
    return float(np.clip(np.median(norms), G_MIN, G_MAX)) if len(norms) else GRAVITY


@kernel(inline="always")
def learn_gravity(g_a, accel_norm, dt):
    """One step of learning the accelerometer's reading of g (while still), bounded."""
    g_a += dt / (G_LEARN_S + dt) * (accel_norm - g_a)
    return min(max(g_a, G_MIN), G_MAX)


def scale_effect(effect: str | None, scale_error: float, strict: bool) -> str | None:
    """An ``accel_scale_effect`` of a filter that takes the reading at the still start for g:
    ``effect``, what the scale error does against standard gravity, only without a still start
    (or with ``strict``, which keeps standard gravity; or beyond G_BOUND, where no start is
    still)."""
    if effect is None or strict or not plausible_g(GRAVITY * (1.0 + scale_error)):
        return effect
    return ("none when the log starts still (g is then the accelerometer's reading there); "
            f"without a still start {effect}")
