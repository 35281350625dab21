"""Error-quaternion Kalman filter with accelerometer trust weighting (paper 002, Chu & Yuan 2015).

Paper 002 (Chu, Yuan 2015, 计算机仿真 32(2) 67-73); restated in ../shared/ALGORITHMS.md "eq-kf".
Our copy of the paper is a partial preview: it gives the 3rd-order Picard attitude update
(eq 5, 6) and the error decomposition (eq 13), and says the accelerometer is weighted by a
"trust"; the filter matrices, the trust formula and all tuning are missing. What it gives is
followed; the rest is chosen here and marked "choice".

State and prediction
- Attitude (eq 13): Q = Q̄ ⊗ Q_e, Q̄ the gyro-propagated attitude, Q_e a small error
  quaternion in the body frame. Kalman state x = [e, β]: e = vector part of Q_e
  (Q_e = [√(1-|e|²), e], e ≈ δθ/2) and β = error of the gyro-bias estimate b̂.
  Choice: the bias states are ours. They make the accelerometer/magnetometer corrections a
  PI loop, so a bias the still period missed, or its slow walk, does not leave a standing
  error. Without them (β frozen): static 300 s max pitch error 0.21° instead of 0.08°, yaw
  1.06° instead of 0.35°, mean roll/pitch MAE on the shared logs 2.59° instead of 2.36°.
  initialize() sets b̂ to the still-period bias; P starts small on β (init_bias_sigma).
- Rate ω̄ = ½(ω_k + ω_{k-1}) - b̂ (trapezoidal, as mahony: logs hold rates, not delta
  angles); Δθ = ω̄Δt, Δθ₀ = ‖Δθ‖, ΔΘ = Ω(Δθ).
- Q̄ by eq 5 cut after Δθ₀³ (3rd-order Picard):
      Q̄ ← [(1 - Δθ₀²/8) I + (½ - Δθ₀²/48) ΔΘ] Q̄,   then normalised   (``picard_step``).
  Ω(Δθ) Q̄ = Q̄ ⊗ [0, Δθ] here, so this is Q̄ ⊗ p, p = [1 - Δθ₀²/8, (½ - Δθ₀²/48) Δθ]; its
  error against the exact rotation is O(Δθ₀⁴).
- Error dynamics (differentiating eq 13; derived here): with the true rate ω̄ - β,
  Q_e' = p̂(Δθ)⁻¹ ⊗ Q_e ⊗ p̂(Δθ - βΔt), p̂ = p/|p| (``error_propagate``). At x = 0:
      e' = C(p̂)ᵀ e - ½Δt (I - ½[Δθ]×) β,   β' = β        (``error_transition``)
  P ← Φ P Φᵀ + Q, Q = diag(¼σ_g²Δt + ¼(k_int |ω_k - ω_{k-1}| Δt)², σ_b²Δt): σ_g gyro noise
  density (e is a half angle, hence ¼); σ_b bias random walk; the k_int term (choice) says
  the rotation over a step is known only to a fraction of the rate change across it, which
  matters for the 1-10 Hz IMU of many logs and vanishes at 400 Hz. k_int = 0.02 (it was 0.3:
  see "Real logs" below).
- A step longer than ``MAX_STEP_S`` (a gap) is neither integrated nor propagated.

Accelerometer (gravity direction)
- z = a/‖a‖ against h = C(Q)ᵀ[0, 0, -1] = C(Q_e)ᵀ h̄, h̄ = C(Q̄)ᵀ[0, 0, -1]; ∂h/∂e = 2[h̄]×.
  A unit vector has two degrees of freedom, so the residual is taken in the tangent plane
  of h̄: r = Tᵀ(z - h̄), T = [t₁ t₂] ⟂ h̄, H = Tᵀ 2[h̄]× (rows 2 tᵢ × h̄), zero on β
  (``accel_predict``, ``accel_tangent``, ``accel_jacobian``).
- R_acc = R₀ / w per axis (ALGORITHMS.md), R₀ = σ_a²/Δt: σ_a is a noise density, so the
  correction bandwidth does not change with the log's IMU rate (choice). w = 0: no update.

Turn compensation (our addition, not in the paper: ArduPilot DCM's method; ``airspeed`` > 0)
- A fixed-wing flies along its body x: velocity V x̂ with V ≈ airspeed. Turning at ω, its
  kinematic acceleration in the body frame is ω × V x̂ = V (0, ω_z, -ω_y), so the part of the
  specific force that is gravity is f - V (0, ω_z, -ω_y), ω = ω_k - b̂ (FRD, NED: a level
  right turn at bank φ has ω_z ≈ r cos φ, ω_y ≈ r sin φ and V r = g tan φ, which turns
  f ≈ [0, 0, -g/cos φ] into [0, -g sin φ, -g cos φ], gravity at bank φ). It is applied to the
  accelerometer sample before everything below (low-pass, stillness, trust, update).
- Why: in coordinated turns a plane's accelerometer points 25-35° off gravity for tens of
  seconds (plane-3.1: ~12 circles at 30-50° bank, 12-20 m/s, 10 Hz IMU); the residual gate
  rightly rejects it, the 10 Hz gyro drifts meanwhile, and eq-kf did worse than mahony (mean
  roll/pitch MAE 4.74° against 3.28°). Compensated with V = 12 m/s (the log's TRIM_ARSPD_CM):
  3.13°. The speed change along x (V̇) and wind are not modelled.
- Only where ``in_air`` is 1 or NaN (unknown counts as air, as in ncs-eskf): on the ground a
  plane is slow or stopped, and a taxiing turn would be "compensated" for a speed it does not
  have. With ``airspeed`` 0 (the default) nothing changes. The CLI sets it from an ArduPlane
  log's cruise airspeed (``EqKf.log_defaults``); the kernel itself knows nothing of logs.

Accelerometer trust w ∈ [0, 1] (the paper's formula is not in our copy; choice). With
ramp(x, lo, hi) = 1 for x ≤ lo, 0 for x ≥ hi, linear between:
      w = min( w_norm · w_rate · w_res ,  w_prev + Δt / trust_rise )
- w_norm = ramp(|‖f̃‖/g_a - 1|, norm_lo, norm_hi): the specific force departs from g.
  f̃ is the accelerometer low-passed (time constant trust_lpf) in the body frame with
  rotation compensation, f̃ ← C(p̂)ᵀ f̃ + α(a - C(p̂)ᵀ f̃); g_a is the accelerometer's own
  reading of g (the reading at the still start, ``gravity``, refined while still, both bounded
  to ±25 % of 9.80665; strict: 9.80665. A 5-20 % scale error is common in old logs).
- w_rate = ramp(‖ω̄‖, rate_lo, rate_hi): rotation (centripetal terms, gyro scale errors).
- w_res = ramp(d, gate_lo, gate_hi), d² = rᵀ S_g⁻¹ r, S_g = H P Hᵀ + (σ_gate² + σ_vib²) I₂:
  a normalised innovation test on the gravity *direction* (σ_gate = 0.01 rad, it was 0.005:
  see "Real logs" below). This is the term that holds the
  attitude through sustained linear acceleration: a level vehicle at 0.25 g sees ‖a‖ grow by
  3 %, well inside any norm threshold usable on real data, but the direction turn by 14°.
  S_g holds the filter's own attitude uncertainty, so large residuals pass while P is large
  (the start). σ_vib² is the measured per-sample direction noise: the running mean square
  (time constant vib_time) of the rotation-compensated change of a/‖a‖ between samples,
  divided by 4, so a vibrating airframe widens its own gate.
- The rise limit: trust falls at once but climbs back at most 1/trust_rise per second, so the
  tail of a manoeuvre, whose residual shrinks back through the gate, is faded in rather than
  trusted at once (in the accel scenario it was the largest error left).
- Stillness: rotation below still_rate and an accelerometer that stays within still_accel of
  its value carried in the navigation frame, for still_time: the vehicle is still, the
  residual test is off (w_res = 1). Without it a filter that starts, or lands, a few degrees
  off would keep rejecting a perfectly good accelerometer.
- Consistency: a horizontal acceleration that turns the specific force by ρ away from
  gravity also lengthens it to g/cos ρ. If the residual angle ρ (f̃ against h̄) exceeds the
  angle φ_m = arccos(g_a/‖f̃‖) that the measured length explains by more than cons_tol, for
  cons_time, while |‖f̃‖/g_a - 1| < cons_norm and ‖ω̄‖ ≤ rate_lo, the residual is attitude
  error (a gyro bias that changed in flight), not a manoeuvre: the attitude covariance is
  raised to (ρ/2/gate_lo)² so the gate opens and the bias states relearn. Without it the
  residual test locks a drifting filter out for good (seen on copter-3.3, 20-36° off). A
  vertical acceleration shortens ‖f̃‖ too, hence the cons_norm and cons_time guards (with
  ‖f̃‖ free up to 1.15 g or a 0.5 s hold, braking copters in the SITL logs tripped it).
- accel_state: 0 used (w = 1), 1 down-weighted (0 < w < 1), 2 skipped (w = 0).

Magnetometer (heading; choice of model)
- The measured field, rotated to the navigation frame with Q̄, has horizontal part m_h; its
  body-frame image u = C(Q̄)ᵀ m_h is the measured vector, h(e) = azimuth of C(Q̄ ⊗ Q_e) u,
  z = the declination (azimuth of magnetic north in true NED), innovation γ = z - h(0). At
  e = 0, ∂h/∂e = 2 × (third row of C(Q̄)) (``mag_predict``, ``mag_jacobian``): the update turns
  the attitude about the navigation z axis only, so inclination and field disturbances do
  not tilt roll/pitch directly. The magnetometer arrives zero-order held on the IMU clock,
  so its noise is a density as well: R_m = σ_m²/Δt.

Update and reset: the 2-D accelerometer and 1-D magnetometer updates are joint/scalar
Kalman updates, P ← P - K S Kᵀ kept exactly symmetric; after each, the error is injected,
Q̄ ← Q̄ ⊗ Q_e, b̂ ← b̂ + β, and x = 0 (the reset Jacobian, I - [e]×, is taken as I).
The first sample (and the first after a gap) has no Δt: nothing is propagated or updated.
``in_air`` is used only by the turn compensation.

Strict (``strict=True``): the paper's filter as far as our copy gives it, whatever the other
parameters say. Kept: the error-quaternion state (eq 13), the 3rd-order Picard update (eq 5, 6)
of the trapezoidal rate (a log holds rates, not angles), the accelerometer and magnetometer
updates above, and a trust that falls as ‖a‖ departs from g and as the rate rises, R = R₀/w
(ALGORITHMS.md): w = ramp(|‖a‖/g - 1|, 0.05, 0.2) · ramp(‖ω̄‖, 1, 3 rad/s) on the raw sample
(``STRICT``; the copy prints no thresholds, so these are fixed here once, the values this module
always had). Off: the bias states (b̂ stays the still-period bias), the integration noise, the
residual test, the rise limit, the low-pass, stillness, the learned g_a, the consistency test,
the turn compensation. The noise densities, init_att_sigma and use_mag, which the copy leaves to
the implementer, stay settable. On the 31 shared logs then (48 now; roll/pitch-mean MAE): median 1.126°,
mean 1.851°, worst copter-4.1-flight 8.58° (1.05× mahony); > 1.5× mahony on sub-009 (1.73×),
sub-016 (1.57×), copter-3.6.8 (1.65×).

g (issue 25): g_a starts from the reading at the still start (``gravity``) instead of 9.80665
and is learned on while still as before, both bounded to ±25 % (strict: 9.80665 throughout).
Before, on an accelerometer 15 % off the trust ramp (5-20 % off g) refused it until 2 s of
stillness in flight taught g_a, which a vibrating copter may never give. Simulated figure 8 at
0.85 / 1.15 g: tilt 12.71° / 0.85° → 0.268° / 0.267° (0.267° at 1.0). Corpus: erle-20141222-41
(reads -16 %) 3.04° → 1.71°, gps-flight-20141009 4.88° → 4.58°; a cost on althold-error (-20 %)
1.77° → 2.54° (its accelerometer not skipped 78 % of the time instead of 44 %; the autopilot's own
DCM/EKF1 spread there is 1.5° / 2.2°, so against its DCM reference the order is not meaningful);
DCM-reference median 2.510° → 2.505°, EKF-reference 0.825° → 0.816°, worst logs unchanged.
BROAD inclination RMSE the same per trial but 10 slow translation 0.93° → 0.90°.

Real logs (issue 10 part 5). Numbers: roll/pitch-mean MAE over the 31 logs ../shared/logs had
then (corpus included; 48 now) against the autopilot, `evaluate --estimators mahony,eq-kf`; mahony's median
is 1.195°. Before both changes: median 0.991°, mean 1.557°, worst real-plane-4.3.1-crash 6.22°;
> 1.5× mahony on copter-3.3-loiter-rtl (2.14×), copter-3.4.6-forumlog0039 (2.43×),
copter-3.6dev-suweipeng (5.33×), copter-4.5.7-tipover-quiver088 (1.76×). After: median 0.925°,
mean 1.367°, worst the same crash, 5.29° (0.71×); > 1.5× mahony on copter-3.3 (2.19×), 3.6dev
(1.56×), tipover-quiver088 (2.10×): see "Known limits".
- int_noise 0.3 → 0.02. Many real logs have a 25-50 Hz IMU whose gyro samples carry vibration:
  |ω_k - ω_k-1| is then mostly noise (3.6dev-suweipeng: 0.48 rad/s rms in flight, 0.11 at rest),
  not unresolved rotation, and k_int = 0.3 made the attitude variance so large that even a trust
  of 0.02 let the accelerometer pull the attitude through manoeuvres (3.6dev: 13-20° roll error
  for seconds while w ≈ 0, mahony 0.5°, whose trapezoidal integration of the same gyro is
  plainly far better than k_int = 0.3 claims). A little of it is still needed: at 0 the 8.8 Hz
  copter-4.1 tlog (4.35° → 7.17°) and the plane crash (6.22° → 19.6°) lose, the attitude variance
  no longer growing while the accelerometer is out. 0.3 → 0.02: median 0.991° → 0.943°, mean
  1.557° → 1.373°; forumlog0039 2.43× → 1.10×, 3.6dev 5.33× → 1.58×, the crash 6.22° → 5.27°,
  plane-3.1 2.85° → 2.16°; costs: SITL vibration 1.54° → 2.12° (0.92×), copter-3.3 2.14× →
  2.27×, copter-4.1 4.35° → 4.55°. (0.05: median 0.940°, 3.6dev 1.89×; 0.1: 3.6dev 2.87×.)
- gate_noise (σ_gate) 0.005 → 0.01 rad. σ_vib sees only the *sample-to-sample* change of the
  accelerometer direction, not the slow part of a real accelerometer's error (alignment and
  calibration, of the order of the 1-2° board trims ArduPilot logs carry) nor the gyro's real
  drift, which P (σ_g = 10⁻³ rad/s/√Hz) understates: with a 0.3° floor a real filter a degree
  or two off tends to lock itself out. With int_noise 0.02, 0.005 → 0.01: median 0.943° →
  0.925°, mean 1.373° → 1.367°; sub-016 0.81× → 0.50×, SITL 400 Hz 0.36° → 0.32°; costs: SITL
  plane circuit 0.65° → 1.00° (0.13×), sub-009 1.05× → 1.15×. 0.02 would do much more on the
  logs (median 0.860°, mean 1.307°, copter-3.3 1.09×, 3.6dev 1.41×, sub-009 0.25×) but it lets
  the thrust-aligned accelerometer of a copter's coordinated turns through: tests/simtruth.py's
  figure-eight goes from 0.13° to 1.03° roll MAE (max 5.3°) and fails its test; 0.01 keeps it at
  0.24° (max 1.0°).
- Tried and not kept (each on the whole corpus; the first two with k_int 0.3, the third with
  k_int 0.05, the last two with σ_gate 0.02): the integration noise on the rate's second
  difference (the trapezoid's error) instead of the first: median 1.051°, 6 logs > 1.5×; the
  residual test on the low-passed f̃ instead of the sample: median 0.953°, copter-3.3 2.49×;
  reopening the gate after it had rejected for 3/10/30 s (attitude variance raised to the
  residual, as the consistency test does): copter-3.3 recovered (1.26× at 3 s), but the 400 Hz
  and 50 Hz SITL copter flights went to 1.6-1.8× mahony even at 30 s (a copter circling
  sustains its acceleration); bias states held tighter (init 10⁻⁴, walk 10⁻⁵): tipover 1.57×
  but copter-3.3 1.85× (its bias jumps in flight); the magnetometer gain projected on heading
  alone (attitude and bias): tipover 2.29× → 1.92× but lane-switch-quiver083 1.05× → 1.55×.

Defaults are ours (the copy has no tuning), chosen on tests/simtruth.py's flights (static,
figure-eight with coordinated turns, sustained linear acceleration) and the shared logs.
Known limits: the residual test cannot tell a sustained horizontal acceleration from an
attitude error it has not seen grow, so a gyro whose bias jumps in flight (copter-3.3) is
caught only by the consistency test, after a few degrees; and with a 4-10 Hz IMU in
manoeuvring flight, where both the gyro integration and the accelerometer are poor, it does
worse than mahony, which always blends the accelerometer in (for a fixed-wing the turn
compensation removes most of that). Still above 1.5× mahony on the shared logs:
- copter-3.3 (2.78° against 1.27°): vibrating, and its gyro bias moves in flight; the residual
  test holds the accelerometer out for 30 s at a time while pitch drifts to 12°, and the
  consistency test does not fire because the vibration keeps |‖f̃‖/g_a - 1| above cons_norm.
  σ_gate = 0.02 fixes it (1.09×) at the figure-eight's cost (above).
- 3.6dev-suweipeng (0.68° against 0.44°): violent ±40° roll oscillations at 25 Hz; the gate's
  lockouts and the remaining k_int. With the gate open 0.64° (1.47×).
- tipover-quiver088 (0.79° against 0.38°): after the tip-over the vehicle lies still at 65° roll
  with a compass the autopilot itself called inconsistent; the magnetometer's heading updates,
  through P's correlations and the bias states, turn the gyro-bias estimate so that pitch
  drifts (to 7° in 15 s); the stillness test carries its reference with that bias-corrected
  gyro, so it no longer sees the vehicle as still, and the residual test keeps the
  accelerometer out. Without the magnetometer 0.50° (1.32×). The fix belongs in the stillness
  test (consistency.py's ``track_stillness``, shared with ncs-eskf: stillness judged on the raw
  gyro's constancy, not the bias-corrected rate), not in a threshold here.
- The accelerometer low-passed in an almost-inertial frame (``inertial_accel``, ``accel_tau``
  1 s; strict: off) as a stand-in, as in ncs-eskf: the trust tests read the reading as it is, and
  only where they refuse it (w = 0) is the low-passed reading tried, through the norm and residual
  tests (not the rate test: rotation's own accelerations average out in it); accel_state 3.
  Measured (``scripts/judge_estimators.py``: BROAD 6D median inclination RMSE and worst trial ×
  VQF; corpus median tilt error against the autopilot; SITL logs' median), 0 -> 1 s: BROAD 1.23° ->
  0.74° (worst 3.8× -> 2.9× VQF; stationary magnet 2.49° -> 1.45°), corpus 1.00° -> 0.90°, SITL
  0.37° -> 0.39°; a cost on two SITL flights against their near-truth EKF3 (wind 1.06° -> 2.29°,
  plane circuit 1.00° -> 1.29°; vibration gains, 2.15° -> 1.45°): where gusts refuse the reading,
  the low-passed one still holds the gusts' mean acceleration (passing it only when fully inside
  the tests did not help: wind 2.12°, BROAD 0.91°). 3 s: BROAD 0.69° (worst 2.0×), corpus 0.90°,
  SITL 0.46°. Tried and not kept: ncs-eskf's rule, the closer of the two readings first (BROAD
  0.67°, phone vibration 0.76° -> 0.32° but slow translation 0.88° -> 0.99°, worst 3.3× VQF;
  corpus 0.85°; SITL 0.45°, plane circuit 0.69°, 400 Hz 0.44°): no gain on the whole. The low-passed reading
  in place of the reading, tried first: 1 s BROAD 0.99°, SITL 0.67°; 3 s SITL 1.95°.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import NamedTuple

import numpy as np

from ..flight import GRAVITY
from ..kernel_cache import kernel
from ..paramspec import param
from .base import MAX_STEP_S, Estimator
from .consistency import attitude_error, carried, track_stillness
from .eq_kf_model import (accel_jacobian, accel_tangent, error_transition, inject, mag_jacobian,
                          picard_step, ramp)
from .gravity import learn_gravity, scale_effect
from .inertial_accel import lowpass_in_inertial_frame
from .timestep import integrates, step_dt, step_rate


@dataclass
class EqKfParams:
    gyro_noise: float = param(1e-3, "(0, 1e3]", "log [1e-5, 0.1]")  # rad/s/√Hz, gyro white-noise density (attitude process noise)
    bias_walk: float = param(3e-5, "[0, 1e3]", "log [1e-7, 1e-3]")  # rad/s/√s, gyro-bias random walk
    int_noise: float = param(0.02, "[0, 1e3]", "linear [0, 0.2]")  # 1: step-rotation uncertainty as a fraction of |ω_k - ω_k-1|·Δt
    accel_noise: float = param(0.007, "(0, 1e6]", "log [1e-4, 0.3]")  # rad·√s (1/√Hz), accelerometer direction noise density; R₀ = σ²/Δt
    mag_noise: float = param(0.05, "(0, inf)", "log [1e-3, 1]")  # rad·√s, magnetometer heading noise density; R_m = σ²/Δt
    init_att_sigma: float = param(0.2, "[0, 3.15]")  # rad, initial attitude uncertainty, 1σ per axis
    init_bias_sigma: float = param(5e-4, "[0, 1e6]")  # rad/s, initial gyro-bias uncertainty, 1σ per axis
    norm_lo: float = param(0.05, "[0, inf)", "log [0.01, 0.1]")  # 1 (fraction of g): trust falls from 1 when |‖f̃‖/g - 1| exceeds this ...
    norm_hi: float = param(0.2, "(0, inf)", "log [0.11, 1]")  # 1 (fraction of g): ... to 0 here
    rate_lo: float = param(1.0, "[0, inf)", "log [0.1, 2]")  # rad/s: trust falls from 1 above this rotation rate ...
    rate_hi: float = param(3.0, "(0, inf)", "log [2.1, 10]")  # rad/s: ... to 0 here
    gate_noise: float = param(0.01, "[0, inf)")  # rad, residual direction noise floor of the gate, 1σ
    gate_lo: float = param(3.0, "(0, inf)", "linear [1, 4]")  # 1 (normalised residual d): trust falls from 1 above this ...
    gate_hi: float = param(5.0, "(0, inf)", "linear [4.1, 10]")  # 1: ... to 0 here
    trust_rise: float = param(3.0, "[0, inf)", "linear [0, 10]")  # s: the trust climbs from 0 to 1 no faster than over this time
    trust_lpf: float = param(0.1, "[0, inf)")  # s, time constant of the low-pass f̃ (norm and consistency tests)
    vib_time: float = param(1.0, "[0, inf)")  # s, averaging time of the direction-noise (vibration) estimate
    still_rate: float = param(0.05, "[0, inf)")  # rad/s: still when rotating slower than this ...
    still_accel: float = param(0.2, "[0, inf)")  # m/s²: ... with the accelerometer staying within this ...
    still_time: float = param(2.0, "[0, inf)")  # s: ... for this long
    cons_tol: float = param(0.05, "[0, inf)")  # rad: residual angle beyond what ‖f̃‖ explains that means attitude error ...
    cons_norm: float = param(0.02, "[0, inf)")  # 1 (fraction of g): ... while |‖f̃‖/g - 1| stays below this ...
    cons_time: float = param(1.5, "[0, inf)")  # s: ... for this long
    use_mag: bool = param(True)  # correct heading from the magnetometer when the log has one
    airspeed: float = param(0.0, "[0, 300]")  # m/s, fixed-wing turn compensation: speed along body x (0: off)
    accel_tau: float = param(1.0, "[0, 60]", "linear [0, 5]")  # s: the accelerometer low-passed in an almost-inertial frame (inertial_accel); 0: the reading as it is
    strict: bool = param(False)  # the paper's filter only: every addition of ours off, the fixed trust function STRICT

    ORDERED = (("norm_lo", "norm_hi"), ("rate_lo", "rate_hi"), ("gate_lo", "gate_hi"))  # each a ramp


ACCEL_STATES = ("used", "down-weighted", "skipped", "used the low-passed reading (the reading itself skipped; accel_tau)")

# strict=True: the trust function of ALGORITHMS.md, w = w_norm · w_rate on the raw ‖a‖ and the
# rate. Our copy of paper 002 prints no thresholds, so these are fixed here once (the values
# this module has always used) and no --set changes them. See "Strict" in the module docstring.
STRICT = {"norm_lo": 0.05, "norm_hi": 0.2, "rate_lo": 1.0, "rate_hi": 3.0}

# Indices into the kernel's auxiliary state vector.
_A_LP = 0  # 0-2: low-passed accelerometer f̃, body frame (NaN before the first sample)
_A_DIR = 3  # 3-5: previous accelerometer direction, for the direction-noise estimate
_A_VIB = 6  # direction noise variance per axis, σ_vib²
_A_STILL = 7  # s still so far
_A_W = 8  # last trust w
_A_REF = 9  # 9-11: accelerometer at the start of the still span, carried with the rotation
_A_G = 12  # the accelerometer's reading of g, m/s²
_A_CONS = 13  # s the residual has been inconsistent with ‖f̃‖
_N_AUX = 14



class EqKfState(NamedTuple):
    """What the filter carries between chunks (arrays, updated in place)."""
    q: np.ndarray  # (4,) Q̄, the attitude
    bias: np.ndarray  # (3,) b̂, the gyro-bias estimate, rad/s
    p: np.ndarray  # (6, 6) P of [e, β]
    t_prev: np.ndarray  # (1,)
    gyro_prev: np.ndarray  # (3,)
    aux: np.ndarray  # (_N_AUX,) scalar memory, see the _A_* indices


class EqKfSettings(NamedTuple):
    """The parameters as the kernel takes them (see ``EqKfParams``). Noise levels and the rise
    time are floored at a tiny positive value, so no setting can divide by zero in the kernel."""
    gyro_noise: float
    bias_walk: float
    int_noise: float
    accel_noise: float
    mag_noise: float
    norm_lo: float
    norm_hi: float
    rate_lo: float
    rate_hi: float
    gate_noise: float
    gate_lo: float
    gate_hi: float
    trust_rise: float
    trust_lpf: float
    vib_time: float
    still_rate: float
    still_accel: float
    still_time: float
    cons_tol: float
    cons_norm: float
    cons_time: float
    learn_g: bool
    declination: float
    airspeed: float
    use_mag: bool
    max_step: float
    fallback: bool  # where the trust tests refuse the reading, try the low-passed one (accel_tau > 0)


class EqKfDiagnostics(NamedTuple):
    """Per-sample outputs besides the attitude (keys of ``EqKf.DIAGNOSTICS``)."""
    cov_trace: np.ndarray
    accel_weight: np.ndarray
    accel_state: np.ndarray  # int8


@kernel(inline="always")
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


@kernel(inline="always")
def _normalise_into(qn, q):
    """q ← qn / ‖qn‖."""
    inv = 1.0 / np.sqrt(qn[0] * qn[0] + qn[1] * qn[1] + qn[2] * qn[2] + qn[3] * qn[3])
    for k in range(4):
        q[k] = qn[k] * inv


@kernel(inline="always")
def _propagate_covariance(p, a, b, tp, q_e, qb_var, dt):
    """P ← Φ P Φᵀ + Q for Φ = [[a, b], [0, I]] (``error_transition``), Q = diag(q_e I, qb_var Δt I)."""
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
    for r in range(3, 6):
        p[r, r] += qb_var * dt


@kernel(inline="always")
def _low_pass_carried(a, lp0, lp1, lp2, ax, ay, az, alpha):
    """The low-pass f̃ carried across the step (f̃ ← a f̃, a = C(p̂)ᵀ), then moved by alpha toward the sample."""
    f0, f1, f2 = carried(a, lp0, lp1, lp2)
    return f0 + alpha * (ax - f0), f1 + alpha * (ay - f1), f2 + alpha * (az - f2)


@kernel(inline="always")
def _direction_noise(a, dir0, dir1, dir2, u0, u1, u2, vib, alpha):
    """σ_vib² moved by alpha toward the change of the direction u = a/‖a‖ since the last
    sample's (carried across the step): |Δu|² = 2 axes × 2 samples × σ², so σ² per axis = |Δu|²/4."""
    d0 = u0 - (a[0, 0] * dir0 + a[0, 1] * dir1 + a[0, 2] * dir2)
    d1 = u1 - (a[1, 0] * dir0 + a[1, 1] * dir1 + a[1, 2] * dir2)
    d2 = u2 - (a[2, 0] * dir0 + a[2, 1] * dir1 + a[2, 2] * dir2)
    return vib + alpha * (0.25 * (d0 * d0 + d1 * d1 + d2 * d2) - vib)


@kernel
def _load_aux(aux):
    """The auxiliary state as the loop's locals (the _A_* indices, in order)."""
    return (aux[_A_LP], aux[_A_LP + 1], aux[_A_LP + 2], aux[_A_DIR], aux[_A_DIR + 1], aux[_A_DIR + 2], aux[_A_VIB],
            aux[_A_STILL], aux[_A_W], aux[_A_REF], aux[_A_REF + 1], aux[_A_REF + 2], aux[_A_G], aux[_A_CONS])


@kernel
def _save_aux(aux, lp0, lp1, lp2, dir0, dir1, dir2, vib, still_t, w_prev, ref0, ref1, ref2, g_a, cons_t):
    """The loop's locals back into the auxiliary state (``_load_aux``'s order)."""
    aux[_A_LP], aux[_A_LP + 1], aux[_A_LP + 2] = lp0, lp1, lp2
    aux[_A_DIR], aux[_A_DIR + 1], aux[_A_DIR + 2] = dir0, dir1, dir2
    aux[_A_VIB], aux[_A_STILL], aux[_A_W] = vib, still_t, w_prev
    aux[_A_REF], aux[_A_REF + 1], aux[_A_REF + 2] = ref0, ref1, ref2
    aux[_A_G], aux[_A_CONS] = g_a, cons_t


@kernel(inline="always")
def _gravity_direction(q, hv):
    """h̄ = C(Q̄)ᵀ [0, 0, -1] into hv: where the accelerometer of a vehicle at rest points."""
    w_, x_, y_, z_ = q[0], q[1], q[2], q[3]
    hv[0] = -2.0 * (x_ * z_ - w_ * y_)
    hv[1] = -2.0 * (y_ * z_ + w_ * x_)
    hv[2] = -(1.0 - 2.0 * (x_ * x_ + y_ * y_))


@kernel(inline="always")
def _innovation_covariance(p, hm, ph):
    """P Hᵀ (6×2) into ph; returns H P Hᵀ (2×2) as s00, s01, s11."""
    for r in range(6):
        for j in range(2):
            ph[r, j] = p[r, 0] * hm[j, 0] + p[r, 1] * hm[j, 1] + p[r, 2] * hm[j, 2]
    s00 = hm[0, 0] * ph[0, 0] + hm[0, 1] * ph[1, 0] + hm[0, 2] * ph[2, 0]
    s01 = hm[0, 0] * ph[0, 1] + hm[0, 1] * ph[1, 1] + hm[0, 2] * ph[2, 1]
    s11 = hm[1, 0] * ph[0, 1] + hm[1, 1] * ph[1, 1] + hm[1, 2] * ph[2, 1]
    return s00, s01, s11


@kernel(inline="always")
def _tangent_residual(tb, hv, u0, u1, u2):
    """r = Tᵀ (u - h̄), the residual of a unit vector u in the tangent plane."""
    e0, e1, e2 = u0 - hv[0], u1 - hv[1], u2 - hv[2]
    return tb[0, 0] * e0 + tb[0, 1] * e1 + tb[0, 2] * e2, tb[1, 0] * e0 + tb[1, 1] * e1 + tb[1, 2] * e2


@kernel(inline="always")
def _gate_d2(sa, sb, s01, r0, r1):
    """d² = rᵀ S_g⁻¹ r for S_g = [[sa, s01], [s01, sb]]."""
    return (sb * r0 * r0 - 2.0 * s01 * r0 * r1 + sa * r1 * r1) / (sa * sb - s01 * s01)


@kernel
def _open_gate(p, cos_rho, gate_lo):
    """The consistency test fired: raise the attitude covariance so that the residual angle ρ
    sits at gate_lo σ, and the gate opens for the bias states to relearn."""
    rho = np.arccos(min(max(cos_rho, -1.0), 1.0))
    target = (0.5 * rho / gate_lo) ** 2
    for k in range(3):
        if p[k, k] < target:
            p[k, k] = target


@kernel(inline="always")
def _low_passed_trust(l0, l1, l2, hv, tb, sa, sb, s01, g_a, norm_lo, norm_hi, gate_lo, gate_hi):
    """The reading refused: the trust in the low-passed one (l0, l1, l2; ``accel_tau``) by the norm
    and residual tests (0 where it has no length), and its residual r."""
    ln = np.sqrt(l0 * l0 + l1 * l1 + l2 * l2)
    if not ln > 0.0:
        return 0.0, 0.0, 0.0
    r0, r1 = _tangent_residual(tb, hv, l0 / ln, l1 / ln, l2 / ln)
    d2 = _gate_d2(sa, sb, s01, r0, r1)
    w_low = ramp(abs(ln / g_a - 1.0), norm_lo, norm_hi)
    if d2 > gate_lo * gate_lo:
        w_low *= ramp(np.sqrt(d2), gate_lo, gate_hi)
    return w_low, r0, r1


@kernel(inline="always")
def _heading_innovation(q, m0, m1, m2, cdec, sdec):
    """γ = declination - azimuth(m_h), m_h the horizontal part of the measured field (m0, m1, m2)
    turned to the navigation frame with Q̄: the signed angle from m_h to magnetic north. NaN
    where m_h is zero."""
    w_, x_, y_, z_ = q[0], q[1], q[2], q[3]
    mx = ((1.0 - 2.0 * (y_ * y_ + z_ * z_)) * m0 + 2.0 * (x_ * y_ - w_ * z_) * m1 + 2.0 * (x_ * z_ + w_ * y_) * m2)
    my = (2.0 * (x_ * y_ + w_ * z_) * m0 + (1.0 - 2.0 * (x_ * x_ + z_ * z_)) * m1 + 2.0 * (y_ * z_ - w_ * x_) * m2)
    if mx * mx + my * my > 0.0:
        return np.arctan2(mx * sdec - my * cdec, mx * cdec + my * sdec)
    return np.nan


@kernel(inline="always")
def _scalar_update(p, hm3, v6, rr, gamma, x):
    """A scalar update with H = [hm3, 0] and variance rr: x = K γ, P ← P - K (P Hᵀ)ᵀ, upper
    triangle mirrored."""
    for r in range(6):
        v6[r] = p[r, 0] * hm3[0] + p[r, 1] * hm3[1] + p[r, 2] * hm3[2]
    s = hm3[0] * v6[0] + hm3[1] * v6[1] + hm3[2] * v6[2] + rr
    for r in range(6):
        kr = v6[r] / s
        x[r] = kr * gamma
        for c in range(r, 6):
            pv = p[r, c] - kr * v6[c]
            p[r, c] = pv
            p[c, r] = pv


@kernel(inline="always")
def _accel_state(low_used, w_acc):
    """The accel_state code (``ACCEL_STATES``)."""
    if low_used:
        return 3
    if w_acc >= 1.0:
        return 0
    return 1 if w_acc > 0.0 else 2


@kernel
def eqkf_run(s, state, cfg, out_q, diag):
    """Run the filter over a chunk of samples ``s`` (``base.Samples``; ``in_air`` gates the turn compensation
    only); ``state`` (``EqKfState``) is updated in place. Writes the attitude to ``out_q`` and trace(P), the
    trust w and the accel state code of each sample to ``diag``."""
    # the trust tests read the reading as it is; where they refuse it, the low-passed one (s.accel) may stand in
    t, gyro, accel, accel_low, mag, in_air = s.t, s.gyro, s.accel_read, s.accel, s.mag, s.in_air
    over_step = s.rate_over_step  # each gyro sample the mean over its step (timestep.step_rate)
    q, bias, p, t_prev, gyro_prev, aux = state.q, state.bias, state.p, state.t_prev, state.gyro_prev, state.aux
    out_trace, out_w, out_state = diag.cov_trace, diag.accel_weight, diag.accel_state
    # scratch, once per chunk
    a, b, tp, dth, qn, x = np.empty((3, 3)), np.empty((3, 3)), np.empty((3, 6)), np.empty(3), np.empty(4), np.empty(6)
    hv, tb, hm, ph, hm3, v6 = np.empty(3), np.empty((2, 3)), np.empty((2, 3)), np.empty((6, 2)), np.empty(3), np.empty(6)
    qe_var, qb_var = 0.25 * cfg.gyro_noise * cfg.gyro_noise, cfg.bias_walk * cfg.bias_walk
    acc_var, mag_var = cfg.accel_noise * cfg.accel_noise, cfg.mag_noise * cfg.mag_noise
    gate_var, kint2 = cfg.gate_noise * cfg.gate_noise, cfg.int_noise * cfg.int_noise
    norm_lo, norm_hi, rate_lo, rate_hi = cfg.norm_lo, cfg.norm_hi, cfg.rate_lo, cfg.rate_hi
    gate_lo, gate_hi, use_mag, max_step = cfg.gate_lo, cfg.gate_hi, cfg.use_mag, cfg.max_step
    tau, vib_tau, rise = cfg.trust_lpf, cfg.vib_time, cfg.trust_rise
    still_rate2, still_acc2 = cfg.still_rate * cfg.still_rate, cfg.still_accel * cfg.still_accel
    still_time, airspeed, learn_g, cons_norm, cons_time = cfg.still_time, cfg.airspeed, cfg.learn_g, cfg.cons_norm, cfg.cons_time
    cos_tol, sin_tol, cdec, sdec = np.cos(cfg.cons_tol), np.sin(cfg.cons_tol), np.cos(cfg.declination), np.sin(cfg.declination)
    lp0, lp1, lp2, dir0, dir1, dir2, vib, still_t, w_prev, ref0, ref1, ref2, g_a, cons_t = _load_aux(aux)
    for i in range(len(t)):
        gx, gy, gz = gyro[i, 0], gyro[i, 1], gyro[i, 2]
        ax, ay, az = accel[i, 0], accel[i, 1], accel[i, 2]
        gyro_ok = gx == gx and gy == gy and gz == gz
        if airspeed > 0.0 and gyro_ok and in_air[i] != 0.0:
            # turn compensation (ArduPilot DCM): the kinematic acceleration of V x̂ turning at
            # ω is ω × V x̂ = V (0, ω_z, -ω_y); gravity's share is f - V (0, ω_z, -ω_y)
            ay -= airspeed * (gz - bias[2])
            az += airspeed * (gy - bias[1])
        dt = step_dt(t[i], t_prev[0])
        if t[i] == t[i]:  # a sample without a time leaves the last one's
            t_prev[0] = t[i]
        step = integrates(dt, max_step) and gyro_ok
        rx, ry, rz = step_rate(gx, gy, gz, gyro_prev[0], gyro_prev[1], gyro_prev[2], dt if step else 0.0,
                               over_step)
        rx, ry, rz = rx - bias[0], ry - bias[1], rz - bias[2]
        # the rate change across the step, for the integration noise
        dwx, dwy, dwz = gx - gyro_prev[0], gy - gyro_prev[1], gz - gyro_prev[2]
        if gyro_ok:
            gyro_prev[0], gyro_prev[1], gyro_prev[2] = gx, gy, gz
        an = np.sqrt(ax * ax + ay * ay + az * az)
        accel_ok = an > 0.0 and an == an

        if step:  # the prediction: Picard attitude step (eq 5), P ← Φ P Φᵀ + Q
            dth[0], dth[1], dth[2] = rx * dt, ry * dt, rz * dt
            picard_step(q, dth, qn)
            _normalise_into(qn, q)
            error_transition(dth, dt, a, b)
            q_e = qe_var * dt + 0.25 * kint2 * (dwx * dwx + dwy * dwy + dwz * dwz) * dt * dt
            _propagate_covariance(p, a, b, tp, q_e, qb_var, dt)
        # ---- accelerometer bookkeeping, every vector carried along with the body rotation
        # (v ← C(p̂)ᵀ v): the low-pass f̃, the direction noise, the stillness test
        if step and accel_ok and lp0 == lp0:
            lp0, lp1, lp2 = _low_pass_carried(a, lp0, lp1, lp2, ax, ay, az, dt / (tau + dt))
            if dir0 == dir0:
                vib = _direction_noise(a, dir0, dir1, dir2, ax / an, ay / an, az / an, vib, dt / (vib_tau + dt))
        elif accel_ok:  # start, after a gap or a bad sample: restart the low-pass here
            lp0, lp1, lp2 = ax, ay, az
        if accel_ok:
            dir0, dir1, dir2 = ax / an, ay / an, az / an
        else:
            dir0 = np.nan
        # stillness: little rotation and a specific force that stays put in the navigation frame, for still_time
        rate2 = rx * rx + ry * ry + rz * rz
        ref0, ref1, ref2, still_t = track_stillness(ref0, ref1, ref2, still_t, ax, ay, az, a, step and accel_ok,
                                                    rate2, still_rate2, still_acc2, dt)
        still = still_t >= still_time
        if still and learn_g:  # learn the accelerometer's own reading of g (its scale error)
            g_a = learn_gravity(g_a, an, dt)

        # ---- accelerometer update with trust w
        w_acc, low_used = 0.0, False
        fn = np.sqrt(lp0 ** 2 + lp1 ** 2 + lp2 ** 2)
        if step and accel_ok and fn > 0.0 and fn == fn:
            _gravity_direction(q, hv)
            accel_tangent(hv, tb)  # T and H = Tᵀ 2[h̄]×
            accel_jacobian(hv, tb, hm)
            eps = fn / g_a - 1.0
            w_norm = ramp(abs(eps), norm_lo, norm_hi)
            w_rate = 1.0 if rate2 <= rate_lo * rate_lo else ramp(np.sqrt(rate2), rate_lo, rate_hi)
            # consistency: the residual angle ρ (f̃ against predicted gravity) beyond the angle φ_m a horizontal
            # acceleration would explain given ‖f̃‖, held for cons_time with ‖f̃‖ ≈ g and modest rotation: attitude error
            cosr = (lp0 * hv[0] + lp1 * hv[1] + lp2 * hv[2]) / fn
            inconsistent = w_rate >= 1.0 and abs(eps) < cons_norm and attitude_error(cosr, eps, cos_tol, sin_tol)
            cons_t = cons_t + dt if inconsistent else 0.0
            if cons_t >= cons_time:
                _open_gate(p, cosr, gate_lo)
            s00, s01, s11 = _innovation_covariance(p, hm, ph)
            r0, r1 = _tangent_residual(tb, hv, ax / an, ay / an, az / an)
            # normalised residual d² = rᵀ S_g⁻¹ r, S_g = H P Hᵀ + (σ_gate² + σ_vib²) I
            sa, sb = s00 + gate_var + vib, s11 + gate_var + vib
            d2 = _gate_d2(sa, sb, s01, r0, r1)
            w_res = 1.0 if still or d2 <= gate_lo * gate_lo else ramp(np.sqrt(d2), gate_lo, gate_hi)
            # trust falls at once but rises at most 1/trust_rise per second
            w_acc = min(w_norm * w_rate * w_res, w_prev + dt / rise)
            w_prev = w_acc
            w_upd = w_acc
            if not w_acc > 0.0 and cfg.fallback:  # refused: the low-passed reading, through the norm and residual tests
                w_upd, r0, r1 = _low_passed_trust(accel_low[i, 0], accel_low[i, 1], accel_low[i, 2], hv, tb, sa, sb, s01,
                                                  g_a, norm_lo, norm_hi, gate_lo, gate_hi)
                low_used = w_upd > 0.0
            if w_upd > 0.0:
                _tangent_update(p, ph, s00, s01, s11, r0, r1, acc_var / (dt * w_upd), x)  # R = R₀ / w, R₀ = σ_a²/Δt
                inject(q, bias, x, qn)
        out_state[i] = _accel_state(low_used, w_acc)
        out_w[i] = w_acc

        m0, m1, m2 = mag[i, 0], mag[i, 1], mag[i, 2]
        if use_mag and step and m0 == m0 and m1 == m1 and m2 == m2:  # the magnetometer heading update
            gamma = _heading_innovation(q, m0, m1, m2, cdec, sdec)
            if gamma == gamma:
                mag_jacobian(q, hm3)
                _scalar_update(p, hm3, v6, mag_var / dt, gamma, x)
                inject(q, bias, x, qn)
        out_q[i, 0], out_q[i, 1], out_q[i, 2], out_q[i, 3] = q[0], q[1], q[2], q[3]
        out_trace[i] = p[0, 0] + p[1, 1] + p[2, 2] + p[3, 3] + p[4, 4] + p[5, 5]
    _save_aux(aux, lp0, lp1, lp2, dir0, dir1, dir2, vib, still_t, w_prev, ref0, ref1, ref2, g_a, cons_t)
    return out_q


CRUISE_AIRSPEED_PARAMS = (("TRIM_ARSPD_CM", 0.01), ("AIRSPEED_CRUISE", 1.0))  # name, its unit in m/s (Plane 4.5+: the second)


class EqKf(Estimator):
    """Error-quaternion KF with accelerometer trust (paper 002); see the module docstring."""
    name = "eq-kf"
    Params = EqKfParams
    kernels = (lowpass_in_inertial_frame, eqkf_run, picard_step, error_transition, accel_tangent, accel_jacobian,
               mag_jacobian, ramp, inject)
    color = (0, 195, 195)
    compile_seconds = 6.0  # CPU s, one core (scripts/compile_profile.py)
    PAPER = dict(accel_tau=0.0)  # strict: the accelerometer as it reads (the rest of strict is in initialize)
    ACCEL_STATES = ACCEL_STATES
    DIAGNOSTICS = {
        "cov_trace": "trace of the 6×6 covariance of [e, β] (e: error-quaternion vector part, "
                     "≈ half-angle, rad; β: gyro-bias error, rad/s), mixed units",
        "accel_weight": "accelerometer trust w in [0, 1] (R_acc = R₀ / w; 0: update skipped)",
        "accel_state": "0 used (w = 1), 1 down-weighted (0 < w < 1), 2 skipped (w = 0), 3 the low-passed "
                       "reading used instead (accel_tau)",
    }

    LOG_PARAMS = tuple(key for key, _ in CRUISE_AIRSPEED_PARAMS)

    @classmethod
    def log_defaults(cls, params: dict, vehicle: str) -> dict[str, tuple[object, str]]:
        """``airspeed`` (turn compensation) on an ArduPlane: a plane flies at about its cruise
        airspeed, TRIM_ARSPD_CM (cm/s; AIRSPEED_CRUISE, m/s, from Plane 4.5 on)."""
        if vehicle != "ArduPlane":
            return {}
        for key, scale in CRUISE_AIRSPEED_PARAMS:
            value = params.get(key)
            if value is not None and value == value and 0.0 < value * scale < 200.0:
                return {"airspeed": (float(value) * scale, f"m/s from {key} (the plane's cruise airspeed)")}
        return {}

    def accel_scale_effect(self, scale_error: float) -> str | None:
        """Its trust falls with ‖f̃‖ against g_a: the reading at the still start, learned on while
        still (GRAVITY without a still start until learned; always, strict)."""
        p = self.params
        lo, hi = (STRICT["norm_lo"], STRICT["norm_hi"]) if p.strict else (p.norm_lo, p.norm_hi)
        if abs(scale_error) <= lo:
            return None
        learns = "" if p.strict else (f" unless it learns the reading of g while still ({p.still_time:g} s with the "
                                      f"accelerometer within {p.still_accel:g} m/s²: a vibrating vehicle may never be)")
        return scale_effect(f"its trust in the accelerometer falls from {100 * lo:g} % off g (none at {100 * hi:g} %)"
                            f"{learns}: tilt from the gyro alone meanwhile", scale_error, bool(p.strict))

    def initialize(self, q0, gyro_bias, accel_g: float = GRAVITY) -> None:
        q0 = np.array(q0, dtype=np.float64).reshape(4)
        p = self.params
        strict = bool(p.strict)
        aux = np.full(_N_AUX, np.nan)
        aux[_A_VIB] = 0.0
        aux[_A_STILL] = 0.0
        aux[_A_W] = 1.0
        aux[_A_G] = GRAVITY if strict else accel_g  # the reading at rest, learned on while still
        aux[_A_CONS] = 0.0
        # strict: no bias states (P = 0 on β and no walk: b̂ stays the still-period bias)
        bias_sigma = 0.0 if strict else p.init_bias_sigma
        self._state = EqKfState(q=q0 / np.linalg.norm(q0), bias=np.array(gyro_bias, dtype=np.float64).reshape(3),
                                p=np.diag([0.25 * p.init_att_sigma ** 2] * 3 + [bias_sigma ** 2] * 3),
                                t_prev=np.array([np.nan]), gyro_prev=np.zeros(3), aux=aux)
        tiny = 1e-12
        settings = EqKfSettings(
            gyro_noise=float(p.gyro_noise), bias_walk=float(p.bias_walk), int_noise=float(p.int_noise),
            accel_noise=max(p.accel_noise, tiny), mag_noise=max(p.mag_noise, tiny),
            norm_lo=float(p.norm_lo), norm_hi=float(p.norm_hi), rate_lo=float(p.rate_lo), rate_hi=float(p.rate_hi),
            gate_noise=max(p.gate_noise, tiny), gate_lo=float(p.gate_lo), gate_hi=float(p.gate_hi),
            trust_rise=max(p.trust_rise, tiny), trust_lpf=max(p.trust_lpf, 0.0), vib_time=max(p.vib_time, 0.0),
            still_rate=float(p.still_rate), still_accel=float(p.still_accel), still_time=float(p.still_time),
            cons_tol=float(p.cons_tol), cons_norm=float(p.cons_norm), cons_time=float(p.cons_time), learn_g=True,
            declination=self.declination, airspeed=max(p.airspeed, 0.0), use_mag=bool(p.use_mag),
            max_step=MAX_STEP_S, fallback=p.accel_tau > 0.0)
        if strict:
            # w = w_norm · w_rate on the raw accelerometer (no low-pass), STRICT thresholds; no
            # residual test (gate at infinity), no rise limit, no stillness, no learned g, no
            # consistency test, no integration noise, no turn compensation
            inf = np.inf
            settings = settings._replace(
                bias_walk=0.0, int_noise=0.0, **STRICT, gate_noise=tiny, gate_lo=inf, gate_hi=inf, trust_rise=tiny,
                trust_lpf=0.0, vib_time=0.0, still_rate=0.0, still_accel=0.0, still_time=inf, cons_tol=0.0,
                cons_norm=0.0, cons_time=inf, learn_g=False, airspeed=0.0, fallback=False)
        self._settings = settings
        self._ready(q0, gyro_bias)

    def _run(self, s, out, aiding) -> dict:
        n = len(s.t)
        diag = EqKfDiagnostics(np.empty(n), np.empty(n), np.empty(n, dtype=np.int8))
        eqkf_run(s, self._state, self._settings, out, diag)
        return diag._asdict()

    @property
    def covariance(self) -> np.ndarray:
        """P of [e (3), β (3)], a copy."""
        return self._state.p.copy()

    @property
    def gyro_bias(self) -> np.ndarray:
        """The filter's current gyro-bias estimate b̂, rad/s."""
        return self._state.bias.copy()
