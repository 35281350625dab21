"""Ground/air phase detection from baro or GPS height (causal: what a live link can know)."""
from __future__ import annotations

import numpy as np

from mavattitude.flight import BaroSeries, Flight, GpsSeries
from mavattitude.phase import AIR_ABOVE_M, GROUND_BELOW_M, SMOOTH_S, detect_phase, pressure_height
from mavattitude.sim import simulate


def _flight_with_baro(t, height_m):
    p0 = 101325.0 * (1 - 100.0 / 44330.77) ** (1 / 0.190263)  # 100 m above sea level
    h0 = pressure_height(p0)
    # Invert pressure_height for the pressures that give these heights above the start.
    pressure = 101325.0 * (1 - (h0 + np.asarray(height_m)) / 44330.77) ** (1 / 0.190263)
    return Flight("synthetic.bin", "bin", baro=BaroSeries("BARO", np.asarray(t, float), pressure,
                                                          np.full(len(t), np.nan)))


def test_take_off_is_found_where_the_truth_crosses_the_threshold():
    sim = simulate("hover", 40.0, seed=4)
    flight = Flight("sim.bin", "bin", baro=BaroSeries("BARO", sim.baro.t, sim.baro.pressure_pa,
                                                      sim.baro.alt_m))
    phase = detect_phase(flight)
    assert phase.source == "baro height"
    changes = np.flatnonzero(np.diff(phase.in_air)) + 1
    assert len(changes) == 1 and phase.in_air[-1] == 1.0  # one take-off, no flicker
    # The vehicle truly passes AIR_ABOVE_M here (5 m hover, eased climb):
    truth_height = -sim.truth.pos_ned[:, 2]
    t_cross = sim.t[np.argmax(truth_height > AIR_ABOVE_M)]
    # causal: never early, late by at most the smoothing (a trailing median)
    assert t_cross - 0.1 <= phase.t[changes[0]] <= t_cross + SMOOTH_S
    on_imu = phase.on_clock(sim.t)
    assert np.all(on_imu[sim.t < t_cross - 0.5] == 0.0) and np.all(on_imu[sim.t > t_cross + SMOOTH_S] == 1.0)


def test_hysteresis_holds_the_phase_between_the_thresholds():
    t = np.arange(0.0, 60.0, 0.1)
    # Up to 2.5 m (between the thresholds: still ground), then 10 m, then down to 2.5 m (still
    # air), then landed.
    h = np.interp(t, [0, 10, 15, 25, 30, 40, 45, 60], [0, 0, 2.5, 2.5, 10, 10, 2.5, 2.5])
    h[t > 50] = 0.0
    phase = detect_phase(_flight_with_baro(t, h))
    assert GROUND_BELOW_M < 2.5 < AIR_ABOVE_M
    at = lambda s: phase.in_air[np.searchsorted(phase.t, s)]  # noqa: E731
    assert at(20.0) == 0.0 and at(35.0) == 1.0 and at(48.0) == 1.0 and at(55.0) == 0.0


def test_gps_height_when_there_is_no_barometer_and_unknown_without_either():
    t = np.arange(0.0, 30.0, 0.2)
    alt = 50.0 + np.where(t > 10.0, 20.0, 0.0)
    n = len(t)
    gps = GpsSeries("GPS", t, np.full(n, 47.0), np.full(n, 8.0), alt, np.zeros((n, 3)),
                    np.full(n, 3), np.full(n, 10), np.full(n, 1.0))
    phase = detect_phase(Flight("gps.bin", "bin", gps=gps))
    assert phase.source == "GPS height"
    assert phase.in_air[t < 9.0].max() == 0.0 and phase.in_air[t > 12.0].min() == 1.0
    assert detect_phase(Flight("none.bin", "bin")) is None


def test_phase_is_unknown_before_the_first_sample_and_when_stale():
    t = np.arange(10.0, 20.0, 0.1)
    phase = detect_phase(_flight_with_baro(t, np.zeros(len(t))))
    out = phase.on_clock(np.array([5.0, 15.0, 19.95, 30.0]))
    assert np.isnan(out[0]) and out[1] == 0.0 and out[2] == 0.0 and np.isnan(out[3])


def test_the_tracker_fed_in_pieces_equals_fed_whole():
    from mavattitude.phase import PhaseTracker

    t = np.arange(0.0, 60.0, 0.05)
    h = np.interp(t, [0, 10, 15, 40, 45, 60], [0, 0, 10, 10, 0, 0])
    h = h + np.random.default_rng(1).normal(0, 0.5, len(t))
    h[::97] = np.nan
    whole, pieces = PhaseTracker("baro height"), PhaseTracker("baro height")
    whole.add(t, h)
    for chunk in np.array_split(np.arange(len(t)), 211):
        pieces.add(t[chunk], h[chunk])
    a, b = whole.series(), pieces.series()
    np.testing.assert_array_equal(a.t, b.t)
    np.testing.assert_array_equal(a.height_m, b.height_m)
    np.testing.assert_array_equal(a.in_air, b.in_air)


def test_the_median_is_numpys_to_the_bit():
    """phase's own median (quickselect; numba's np.median cost 0.8 s of a first compile) gives
    np.median's value for odd and even counts, ties, sorted and reversed runs, within a longer array."""
    from mavattitude.phase import _median

    rng = np.random.default_rng(1)
    for n in [*range(1, 30), 100, 101]:
        for kind in ("random", "rounded", "sorted", "reversed", "equal"):
            v = rng.normal(size=n + 6)
            v = {"rounded": np.round(v, 1), "sorted": np.sort(v), "reversed": np.sort(v)[::-1].copy(),
                 "equal": np.full_like(v, 1.5)}.get(kind, v)
            lo = int(rng.integers(0, 6))
            assert _median(v[lo:lo + n], np.empty(len(v))) == np.median(v[lo:lo + n]), (n, kind)
