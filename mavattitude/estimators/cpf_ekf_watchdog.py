"""cpf-ekf's divergence watchdog (paper 003, eq 21): the EKF's Euler angles against the
complementary filter's, and the reset from it. The filter, its paper and the rest of its
choices: ``cpf_ekf``.

Choices the paper leaves open, made here:
- Watchdog cycle: the paper checks eq 21 once per 15 ms solution cycle (IMU 50 Hz). Here one
  check per ``watchdog_period_s`` (0.02 s) of autopilot time, on the first IMU sample of each
  period (every sample when the IMU is slower), so "3 cycles" means the same span at any IMU
  rate; the check's atan2/asin then run at most at 50 Hz.
- Reset details the paper leaves open: the bias *estimates* are kept (its figures 9-10 show
  them continuous through resets); their variances go back to P₀
  (``reset_bias_covariance``), so that biases dragged off by whatever made the EKF diverge
  can come back; cross-covariances are zeroed.
"""
from __future__ import annotations

import math

from ..kernel_cache import kernel
from ..quaternion import euler_s, wrap_pi_s
from .cpf_ekf_model import (A_COUNT, A_GPOS, A_GVEL, A_LASTMAG, A_RESETS, D_RESET, D_WD, IA, IB, IMB, IS, IV, TESLA_TO_GAUSS,
                            init_covariance)
from .cpf_ekf_updates import start_earth_field


@kernel
def watchdog_distance(x, qc, heading):
    """Eq 21's (Δθ)² + (Δφ)² (+ (Δψ)² with a heading reference) between the EKF's and the
    complementary filter's Euler angles, differences wrapped to ±π."""
    er, ep, ey = euler_s(x[0], x[1], x[2], x[3])
    cr, cp, cy = euler_s(qc[0], qc[1], qc[2], qc[3])
    dr, dp = wrap_pi_s(er - cr), wrap_pi_s(ep - cp)
    dist = dr * dr + dp * dp
    if heading:
        dy = wrap_pi_s(ey - cy)
        dist += dy * dy
    return dist


@kernel(inline="always")
def watchdog_due(ti, period, last_bin):
    """Whether the watchdog checks at time ti, once per period (every sample with period 0), and
    the period's number, the next sample's last_bin."""
    if period > 0.0:
        wd_bin = math.floor(ti / period)
        return wd_bin != last_bin, wd_bin
    return True, last_bin


@kernel
def watchdog_cycle(x, P, qc, aux, heading, gps_active, baro_fresh, cfg, wk, drow):
    """One watchdog cycle (eq 21): the distance into the row; with the watchdog on, the count of
    consecutive cycles over N, and at reset_cycles the reset (counted in aux, marked in the row)."""
    dist = watchdog_distance(x, qc, heading)
    drow[D_WD] = dist
    if cfg.watchdog > 0.5:
        aux[A_COUNT] = aux[A_COUNT] + 1.0 if dist > cfg.reset_threshold else 0.0
        if aux[A_COUNT] >= cfg.reset_cycles:
            aux[A_COUNT] = 0.0
            aux[A_RESETS] += 1.0
            drow[D_RESET] = 1.0
            reset_from_cpf(x, P, qc, aux, heading, gps_active, baro_fresh, cfg, wk)


@kernel
def reset_from_cpf(x, P, qc, aux, heading, gps_active, baro_fresh, cfg, wk):
    """Eq 21's reset: attitude from the complementary filter, P, V and S re-initialised (V, S
    to the last GPS fix when GPS is active), bias estimates kept, M from the last compass
    sample."""
    reset_bias = cfg.reset_bias > 0.5
    bias_var, mbv = wk.bias_var, wk.body_field_var
    for r in range(3):
        mbv[r] = cfg.body_field_sigma0 ** 2 if reset_bias else P[IMB + r, IMB + r]
        bias_var[r] = cfg.gyro_bias_sigma0 ** 2 if reset_bias else P[IB + r, IB + r]
    bias_var[3] = cfg.accel_bias_sigma0 ** 2 if reset_bias else P[IA, IA]
    bias_var[4] = cfg.earth_field_sigma0 ** 2  # earth field: re-initialised below
    bias_var[5] = 0.0
    for r in range(4):
        x[r] = qc[r]
    init_covariance(P, x, cfg, heading, bias_var)
    for r in range(3):
        P[IMB + r, IMB + r] = mbv[r]
    if gps_active:
        for r in range(3):
            gv = aux[A_GVEL + r]
            x[IV + r] = gv if gv == gv else 0.0
            gp = aux[A_GPOS + r]
            if gp == gp and not (r == 2 and baro_fresh):
                x[IS + r] = gp
    else:
        for r in range(3):
            x[IV + r] = 0.0
    if heading and aux[A_LASTMAG] == aux[A_LASTMAG]:
        start_earth_field(x, aux[A_LASTMAG] * TESLA_TO_GAUSS, aux[A_LASTMAG + 1] * TESLA_TO_GAUSS,
                          aux[A_LASTMAG + 2] * TESLA_TO_GAUSS, cfg, wk)
