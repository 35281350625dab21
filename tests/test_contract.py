"""What every registered estimator promises (``estimators.base``), checked on each: chunked
stepping equals one batch, unit quaternions, a symmetric positive semi-definite covariance,
no NaN on hostile data, the documented diagnostics, ``aiding=None`` accepted, no gyro
integration across a gap, and the static accuracy on simulated truth (a bound per estimator). An estimator added to ``ESTIMATORS`` is checked without a line here.
Each estimator's own file tests what is particular to it."""
from __future__ import annotations

from dataclasses import fields

import numpy as np
import pytest

import simtruth as st
from conftest import estimator_params
from mavattitude import quaternion as quat
from mavattitude.aiding import Aiding, from_sim
from mavattitude.estimators import ESTIMATORS, align, create
from mavattitude.flight import GRAVITY
from mavattitude.core.params import build

NAMES = estimator_params()


def hostile(n: int = 200_000, seed: int = 5, accel_noise: float = 3.0):
    """Noisy inputs with a 5 s gap half-way, accelerometer dropouts (zeros) and NaN, a sparse
    compass, a phase that jumps about, and random GPS and baro."""
    rng = np.random.default_rng(seed)
    t = np.cumsum(rng.uniform(0.001, 0.03, n))
    t[n // 2:] += 5.0
    gyro = rng.normal(0, 0.5, (n, 3))
    gyro[::5000] = rng.normal(0, 8.0, (len(gyro[::5000]), 3))  # spikes
    accel = rng.normal([0, 0, -GRAVITY], accel_noise, (n, 3))
    accel[::1000] = 0.0
    accel[500::2000] = np.nan
    mag = np.where(rng.random((n, 1)) < 0.1, rng.normal([2e-5, 0, 4e-5], 1e-5, (n, 3)), np.nan)
    in_air = rng.choice([0.0, 1.0, np.nan], n)
    aiding = Aiding.empty(n)
    gps = rng.random(n) < 0.02
    aiding.gps_pos[gps] = rng.normal(0, 30.0, (np.count_nonzero(gps), 3))
    aiding.gps_vel[gps] = rng.normal(0, 5.0, (np.count_nonzero(gps), 3))
    baro = rng.random(n) < 0.05
    aiding.baro_height[baro] = rng.normal(10.0, 5.0, np.count_nonzero(baro))
    return t, gyro, accel, mag, in_air, aiding


@pytest.fixture(scope="module")
def noisy():
    return hostile()


class _Reading(dict):
    """Autopilot parameters that note which an estimator reads."""

    def __init__(self, *args):
        super().__init__(*args)
        self.keys_read = set()

    def get(self, key, default=None):
        self.keys_read.add(key)
        return super().get(key, default)

    def __getitem__(self, key):
        self.keys_read.add(key)
        return super().__getitem__(key)

    def __contains__(self, key):
        self.keys_read.add(key)
        return super().__contains__(key)


@pytest.mark.parametrize("name", NAMES)
def test_registered_under_its_name_with_the_interface(name):
    """The registry's name is the class's; a heading reference exactly where the estimator takes
    the compass and one is there, and none once ``--set NAME.use_mag=false``; accel state 0 is
    "used"; our estimators name their numba kernels. After a short update: the attitudes, the
    documented diagnostics with a value per sample and their dtypes, and a covariance that is a
    copy."""
    cls = ESTIMATORS[name]
    assert cls.name == name and cls.Params is not None
    est = create(name)
    assert est.has_heading_reference(True) == cls.uses_mag and not est.has_heading_reference(False)
    if "use_mag" in {f.name for f in fields(cls.Params)}:
        off = build([name], None, [f"{name}.use_mag=false"])[name]
        assert off.use_mag is False and not create(name, off).has_heading_reference(True)
    assert not cls.ACCEL_STATES or cls.ACCEL_STATES[0] == "used"
    assert cls.requires or cls.kernels
    # what it says about itself: marks among its diagnostics, a colour the view can draw, the
    # log's defaults for its own fields only (none from an empty log)
    assert set(cls.MARKS) <= set(cls.DIAGNOSTICS)
    assert cls.color is None or (len(cls.color) == 3 and all(0 <= c <= 255 for c in cls.color))
    assert cls.log_defaults({}, "") == {}
    for vehicle in ("ArduPlane", "ArduCopter", "ArduSub", "PX4"):  # it reads only what it names (live asks for those)
        read = _Reading({key: 10.0 for key in cls.LOG_PARAMS})
        cls.log_defaults(read, vehicle)
        assert read.keys_read <= set(cls.LOG_PARAMS), (vehicle, read.keys_read)
    est.initialize(np.array([1.0, 0.0, 0.0, 0.0]), np.array([0.01, -0.02, 0.003]))
    n = 50
    q = est.update(np.arange(n) * 0.01, np.zeros((n, 3)), np.tile([0.0, 0.0, -9.8], (n, 1)), None)
    assert q.shape == (n, 4)
    assert set(est.diagnostics) == set(cls.DIAGNOSTICS)
    assert all(series.shape == (n,) for series in est.diagnostics.values())
    if "accel_state" in est.diagnostics:
        assert est.diagnostics["accel_state"].dtype == np.int8
    if "cov_trace" in est.diagnostics:
        assert est.diagnostics["cov_trace"].dtype == np.float64
    cov = est.covariance
    if cov is not None:
        cov[0, 0] = 123.0
        assert est.covariance[0, 0] != 123.0  # a copy


@pytest.mark.parametrize("name", NAMES)
def test_invariants_on_hostile_data(name, noisy):
    t, gyro, accel, mag, in_air, aiding = noisy
    cls = ESTIMATORS[name]
    f = create(name, declination=0.2)
    f.initialize(np.array([1.0, 0, 0, 0]), np.zeros(3))
    for s in np.array_split(np.arange(len(t)), 10):
        q = f.update(t[s], gyro[s], accel[s], mag[s], in_air[s], aiding=aiding[s.min():s.max() + 1])
        assert np.isfinite(q).all()
        np.testing.assert_allclose(np.linalg.norm(q, axis=1), 1.0, atol=1e-12)
        P = f.covariance
        if P is not None:
            assert np.isfinite(P).all()
            np.testing.assert_array_equal(P, P.T)
            assert np.linalg.eigvalsh(P).min() >= -1e-9 * max(1.0, np.abs(P).max())
        assert set(f.diagnostics) <= set(cls.DIAGNOSTICS), set(f.diagnostics) - set(cls.DIAGNOSTICS)
        for key, series in f.diagnostics.items():
            assert series.shape == (len(s),), key
        if "cov_trace" in f.diagnostics:
            assert np.isfinite(f.diagnostics["cov_trace"]).all() and (f.diagnostics["cov_trace"] > 0).all()
        if "accel_state" in f.diagnostics:
            assert set(np.unique(f.diagnostics["accel_state"])) <= set(range(len(cls.ACCEL_STATES)))


@pytest.mark.parametrize("name", NAMES)
def test_no_gyro_integration_across_a_gap(name, noisy):
    t, gyro, *_ = noisy
    g = len(t) // 2
    f = create(name)
    f.initialize(np.array([1.0, 0, 0, 0]), np.zeros(3))
    s = slice(g - 10, g + 1)  # no accelerometer, no compass: only the gyro moves it
    q = f.update(t[s], gyro[s], np.full((11, 3), np.nan), None)
    np.testing.assert_array_equal(q[-1], q[-2])


@pytest.fixture(scope="module")
def figure8():
    sim = st.figure8_120()
    t, gyro, accel, mag = st.inputs(sim)
    in_air = np.where(sim.t > 20.0, 1.0, 0.0)
    return sim, t, gyro, accel, mag, in_air, from_sim(sim)


@pytest.mark.parametrize("name", NAMES)
def test_chunked_stepping_equals_one_batch(name, figure8):
    """Live feeds small chunks, replay one big one: the same numbers, bit for bit."""
    sim, t, gyro, accel, mag, in_air, aiding = figure8
    a = align(t, gyro, accel, mag, sim.declination_rad)
    batch = create(name, declination=sim.declination_rad)
    batch.initialize(a.q0, a.gyro_bias)
    q_batch = batch.update(t, gyro, accel, mag, in_air, aiding=aiding)
    live = create(name, declination=sim.declination_rad)
    live.initialize(a.q0, a.gyro_bias)
    cuts = np.sort(np.random.default_rng(0).choice(np.arange(1, len(t)), size=200, replace=False))
    parts, diagnostics = [], []
    for a_, b_ in zip(np.r_[0, cuts], np.r_[cuts, len(t)]):
        s = slice(a_, b_)
        parts.append(live.update(t[s], gyro[s], accel[s], mag[s], in_air[s], aiding=aiding[s]))
        diagnostics.append(live.diagnostics)
    np.testing.assert_array_equal(np.vstack(parts), q_batch)
    for key, series in batch.diagnostics.items():
        np.testing.assert_array_equal(np.concatenate([d[key] for d in diagnostics]), series, err_msg=key)
    if batch.covariance is not None:
        np.testing.assert_array_equal(live.covariance, batch.covariance)


@pytest.mark.parametrize("name", NAMES)
def test_aiding_none_is_accepted(name, figure8):
    sim, t, gyro, accel, mag, in_air, _ = figure8
    outputs = []
    for extra in ({}, {"aiding": None}):
        f = create(name, declination=sim.declination_rad)
        f.initialize(np.array([1.0, 0, 0, 0]), np.zeros(3))
        outputs.append(f.update(t[:500], gyro[:500], accel[:500], mag[:500], in_air[:500], **extra))
    np.testing.assert_array_equal(*outputs)


# Still for 300 s (no accelerometer bias: nothing attitude-only can observe it): the largest roll
# and pitch error after 10 s, per estimator (paper 000 §3.1 claims 0.1° for mahony-ekf). cpf-ekf's
# static claim is paper 003's own test (test_cpf_ekf.py); the rivals are compared with ours in
# test_rivals.py.
STATIC_TILT_DEG = {"mahony": 0.2, "mahony-ekf": 0.1, "ekf": 0.2, "eskf": 0.2, "ncs-eskf": 0.2, "eq-kf": 0.2}


@pytest.mark.parametrize("name", sorted(STATIC_TILT_DEG))
def test_static_roll_pitch_and_heading_on_simulated_truth(name):
    """Roll and pitch within the bound, the heading within 1° where the compass gives one
    (declination applied), the documented diagnostics with their types, and at rest the
    accelerometer used on every sample but a few where the estimator says."""
    sim = st.static_300()
    q, f = st.run(name, sim)
    err = st.errors_deg(sim, q)
    assert err[:, 0].max() < STATIC_TILT_DEG[name] and err[:, 1].max() < STATIC_TILT_DEG[name]
    if f.has_heading_reference(True):
        assert err[:, 2].max() < 1.0
    assert set(f.diagnostics) == set(ESTIMATORS[name].DIAGNOSTICS)
    if "cov_trace" in f.diagnostics:
        assert f.diagnostics["cov_trace"].dtype == np.float64 and np.isfinite(f.diagnostics["cov_trace"]).all()
    if "accel_state" in f.diagnostics:
        assert f.diagnostics["accel_state"].dtype == np.int8
        assert np.mean(np.isin(f.diagnostics["accel_state"], USED_AT_REST.get(name, (0,)))) > 0.99


# The accel_state codes that mean "used": ncs-eskf takes the low-passed reading where it is the
# closer of the two to the predicted gravity (code 4), at rest much of the time.
USED_AT_REST = {"ncs-eskf": (0, 4)}


# Started 30° off in roll or in yaw on the static flight: [(seconds after the start, which errors,
# bound in degrees)] per estimator and axis; "axis" is the one set off, "tilt" roll and pitch.
# ncs-eskf's own test tells it the start is uncertain; cpf-ekf's runs on its circling flight.
OFFSET_30 = {
    ("mahony", "roll"): [(40.0, "axis", 0.5)],  # ~8 time constants at Kp = 0.2; what remains is
    ("mahony", "yaw"): [(40.0, "axis", 1.0)],   # the integral term's wind-up, decaying slowly
    ("mahony-ekf", "roll"): [(10.0, "axis", 1.0), (100.0, "axis", 0.4)],  # the wind-up unwinds over Kp/Ki
    ("mahony-ekf", "yaw"): [(10.0, "axis", 1.0), (100.0, "axis", 0.4)],
    ("ekf", "roll"): [(2.0, "axis", 0.2)],  # P0 = I: the first updates take it in
    ("ekf", "yaw"): [(2.0, "axis", 1.0)],
    ("eskf", "roll"): [(10.0, "tilt", 0.3)],
    ("eq-kf", "roll"): [(30.0, "tilt", 0.2), (30.0, "yaw", 1.0)],
    ("eq-kf", "yaw"): [(30.0, "tilt", 0.2), (30.0, "yaw", 1.0)],
}


@pytest.mark.parametrize("name,axis", sorted(OFFSET_30))
def test_converges_from_a_30_degree_offset(name, axis):
    sim = st.static_300()
    i = {"roll": 0, "yaw": 2}[axis]
    start = quat.to_euler(sim.truth.q[0])
    start[i] += np.radians(30.0)
    q, _ = st.run(name, sim, q0=quat.from_euler(*start))
    err = st.errors_deg(sim, q, after_s=0.0)
    assert err[0, i] == pytest.approx(30.0, abs=0.5)
    for after_s, which, bound in OFFSET_30[name, axis]:
        columns = {"axis": [i], "tilt": [0, 1], "yaw": [2]}[which]
        assert err[sim.t >= sim.t[0] + after_s][:, columns].max() < bound, (after_s, which)


def test_the_static_flight_is_aligned_from_its_still_start_with_a_heading():
    sim = st.static_300()
    t, gyro, accel, mag = st.inputs(sim)
    a = align(t, gyro, accel, mag, sim.declination_rad)
    assert a.still_span is not None and a.heading_from_mag


@pytest.mark.slow
def test_a_second_process_loads_the_compiled_kernels_from_the_cache(tmp_path, first_run):
    """``cache=True`` works: on an empty cache needs_compile names what a first run compiles;
    after one (conftest's ``first_run``: replay with mahony and eskf, which said it compiled
    them), the next process loads every kernel without compiling one."""
    import os
    import subprocess
    import sys

    done, cache = first_run
    assert done.returncode == 0 and "compiling log reader, mahony, eskf" in done.stderr, done.stderr
    probe = ("import sys; from mavattitude.estimators import ESTIMATORS, needs_compile; from mavattitude.core.warmup import compile_kernels; "
             "names = ['mahony', 'eskf']; print(needs_compile(names)); sys.argv[1:] and compile_kernels(names); "
             "misses = sum(sum(k.stats.cache_misses.values()) for n in names for k in ESTIMATORS[n].kernels); "
             "print(misses)")
    runs = [subprocess.run([sys.executable, "-c", probe, *args], env={**os.environ, "NUMBA_CACHE_DIR": str(where)},
                           capture_output=True, text=True, timeout=300)
            for where, args in ((tmp_path, []), (cache, ["compile"]))]
    first, second = (r.stdout.split("\n") for r in runs)
    assert first[0] == "['mahony', 'eskf']", runs[0].stderr
    assert second[0] == "[]" and int(second[1]) == 0, runs[1].stderr
