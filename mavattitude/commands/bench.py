"""``mavattitude bench``: how fast each estimator runs, against imufusion called from Python.

One simulated flight (default: figure8, 1 h at 400 Hz = 1.44 M IMU samples) feeds every
estimator. Each is run once on a short slice first, which compiles its kernels (or loads them
from numba's cache), then ``update()`` over the whole flight is timed, best of ``repeat``
runs, with and without the magnetometer. The yardstick is the ``imufusion`` estimator
(``estimators.rivals``: the Python package of x-io's Fusion, a C complementary filter, whose
``Ahrs`` is called per sample from a Python loop, as a user of that package would), timed the
same way on the first ``imufusion_samples`` samples of the same data. The filters from other
projects (``vqf``, ``imufusion``) can be named too (``--estimators mahony,vqf,imufusion``):
their rows have no target.

What is timed: one ``update()`` over the whole chunk (input checks, the filter, the output
array). For imufusion that is its inputs converted to its units (°/s, g, µT) in one go, then
per sample ``update(...)`` or ``update_no_magnetometer(...)`` and ``get_quaternion()``.

The magnetometer reaches the estimators as in ``replay`` (``runner.held_magnetometer``, the
interface of ``estimators.base``): the latest compass sample held at every IMU time (a new
one every 40th sample at 400 Hz with a 10 Hz compass). imufusion likewise gets ``update``
with the latest compass sample on every sample, as its documentation calls it. An estimator
that takes aiding (``cpf-ekf``) also gets the simulated GPS and baro on the IMU clock
(``aiding.from_sim``, as ``replay`` builds them from a log), in both modes.

Targets: every estimator of ours at least ``MIN_X_IMUFUSION`` times imufusion's rate in the same mode
(``MIN_X_IMUFUSION_FOR`` where an estimator's own target differs),
and mahony at least ``MAHONY_MIN_RATE`` samples/s.
"""
from __future__ import annotations

import os
import platform
import sys
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from .._version import __version__
from ..errors import UsageError, reraise_interrupt
from ..flight import MagSeries
from ..outputs import json_text

MIN_X_IMUFUSION = 5.0  # every estimator: at least this many times imufusion's samples/s
# ... except these, whose work per sample is of another order: cpf-ekf propagates a 20×20
# covariance and runs a complementary filter alongside (its target: at least imufusion's rate).
MIN_X_IMUFUSION_FOR = {"cpf-ekf": 1.0}
MAHONY_MIN_RATE = 1e6  # samples/s
AIR_ABOVE_M = 3.0  # m above home: in the air (the in_air input, from the simulated truth)
WARM_SAMPLES = 2000  # the compile/warm run's slice
INSTALL_HINT = 'pip install "mavattitude[bench]"  (or: pip install "imufusion>=1.3,<2")'
MODES = (("mag", True), ("no mag", False))


@dataclass
class BenchData:
    scenario: str
    seed: int
    duration: float  # s
    imu_rate: float  # Hz
    t: np.ndarray  # (N,) s
    gyro: np.ndarray  # (N, 3) rad/s
    accel: np.ndarray  # (N, 3) m/s²
    mag: np.ndarray  # (N, 3) T, the latest compass sample held at each IMU time
    in_air: np.ndarray  # (N,) 1.0 / 0.0
    declination: float  # rad
    q0: np.ndarray
    gyro_bias: np.ndarray
    simulate_s: float  # how long the simulation took
    compass_samples: int  # compass samples in the flight (the rest of the mag rows repeat one)
    aiding: object = None  # aiding.Aiding: GPS and baro on the IMU clock, for estimators that use them

    @property
    def n(self) -> int:
        return len(self.t)

    @property
    def mag_samples(self) -> int:
        return self.compass_samples


def _say(text: str) -> None:
    print(text, file=sys.stderr, flush=True)


def make_data(scenario: str = "figure8", duration: float = 3600.0, imu_rate: float = 400.0,
              seed: int = 0) -> BenchData:
    """Simulate the flight and prepare the estimators' inputs and starting point."""
    from ..aiding import from_sim
    from ..estimators import align
    from ..core.runner import held_magnetometer
    from ..sim import simulate

    _say(f"simulating {scenario}, {duration:g} s at {imu_rate:g} Hz "
         f"({int(round(duration * imu_rate)):,} IMU samples) ...")
    start = time.perf_counter()
    try:
        sim = simulate(scenario, duration, seed=seed, imu_rate=imu_rate)
    except ValueError as exc:  # too short for two samples of every sensor
        raise UsageError(str(exc)) from None
    simulate_s = time.perf_counter() - start
    _say(f"simulated in {simulate_s:.1f} s")
    imu = sim.imu[0]
    mag = held_magnetometer(sim.t, MagSeries("mag", sim.mag.t, sim.mag.field))
    in_air = (-sim.truth.pos_ned[:, 2] > AIR_ABOVE_M).astype(np.float64)
    a = align(sim.t, imu.gyro, imu.accel, mag, sim.declination_rad)
    return BenchData(scenario, seed, float(duration), float(imu_rate), sim.t, imu.gyro, imu.accel,
                     mag, in_air, sim.declination_rad, a.q0, a.gyro_bias, simulate_s,
                     int(np.count_nonzero((sim.mag.t >= sim.t[0]) & (sim.mag.t <= sim.t[-1]))),
                     from_sim(sim))


# ---------------------------------------------------------------- our estimators


def _run_once(name: str, data: BenchData, use_mag: bool, n: int) -> float:
    from ..estimators import create

    estimator = create(name, declination=data.declination)
    estimator.initialize(data.q0.copy(), data.gyro_bias.copy())
    args = (data.t[:n], data.gyro[:n], data.accel[:n], data.mag[:n] if use_mag else None)
    in_air = data.in_air[:n]
    extra = {"aiding": data.aiding[:n]} if estimator.uses_aiding and data.aiding is not None else {}
    start = time.perf_counter()
    q = estimator.update(*args, in_air=in_air, **extra)
    seconds = time.perf_counter() - start
    if q.shape != (n, 4) or not np.isfinite(q[-1]).all():
        raise RuntimeError(f"{name}: update returned {q.shape} with a non-finite last attitude")
    return seconds


def warm(name: str, data: BenchData) -> float:
    """One short run in each mode: compiles the kernels or loads them from the cache."""
    n = min(data.n, WARM_SAMPLES)
    return sum(_run_once(name, data, use_mag, n) for _, use_mag in MODES)


def time_estimator(name: str, data: BenchData, use_mag: bool, repeat: int) -> float:
    """Best of ``repeat`` timings of one ``update()`` over the whole flight, seconds."""
    return min(_run_once(name, data, use_mag, data.n) for _ in range(repeat))


# ---------------------------------------------------------------- imufusion


def imufusion_available() -> bool:
    """Whether the imufusion estimator (``estimators.rivals``) can run; if not, says how to install it."""
    from ..estimators import available

    if available("imufusion"):
        _say(f"imufusion is not installed, so there is no comparison with it: {INSTALL_HINT}")
        return False
    return True


def time_imufusion(data: BenchData, use_mag: bool, n: int, repeat: int) -> float:
    """Best of ``repeat`` timings of the ``imufusion`` estimator (Fusion's Ahrs per sample in a
    Python loop, its defaults) over the first ``n`` samples, seconds."""
    return min(_run_once("imufusion", data, use_mag, n) for _ in range(repeat))


# ---------------------------------------------------------------- the whole bench


def _verdict(name: str, rate: float, x_imufusion: float | None) -> tuple[bool | None, list[str]]:
    """Whether the row meets its targets (None: nothing to check), and what it misses."""
    checks = []
    if x_imufusion is not None:
        target = MIN_X_IMUFUSION_FOR.get(name, MIN_X_IMUFUSION)
        checks.append((x_imufusion >= target, f"{x_imufusion:.1f}× < {target:g}× imufusion"))
    if name == "mahony":
        checks.append((rate >= MAHONY_MIN_RATE, f"{_rate(rate)}/s < {_rate(MAHONY_MIN_RATE)}/s"))
    if not checks:
        return None, []
    return all(ok for ok, _ in checks), [why for ok, why in checks if not ok]


def run_bench(names: list[str], scenario: str = "figure8", duration: float = 3600.0,
              imu_rate: float = 400.0, seed: int = 0, repeat: int = 3,
              imufusion_samples: int = 200_000) -> dict:
    """Simulate, time every named estimator and imufusion; the result as a JSON-ready dict."""
    from ..estimators import ESTIMATORS, needs_compile

    data = make_data(scenario, duration, imu_rate, seed)
    has_imufusion = imufusion_available()
    reference = {}
    n_fusion = min(imufusion_samples, data.n)
    if has_imufusion:
        for label, use_mag in MODES:
            _say(f"timing imufusion.Ahrs ({label}) on {n_fusion:,} samples ...")
            reference[label] = n_fusion / time_imufusion(data, use_mag, n_fusion, repeat)
    pending = needs_compile(names)
    if pending:
        _say(f"compiling {', '.join(pending)} (first run on this machine only; cached afterwards) ...")
    rows = []
    for name in names:
        cls = ESTIMATORS[name]
        try:
            warm_s = warm(name, data)
        except Exception as exc:  # one broken estimator must not hide the others' numbers
            reraise_interrupt(exc)  # a Ctrl-C in its kernel is no fault of it
            _say(f"warning: {name} failed: {type(exc).__name__}: {exc}")
            rows.append(dict(estimator=name, mag=None, error=f"{type(exc).__name__}: {exc}"))
            continue
        for label, use_mag in MODES:
            if use_mag and not cls.uses_mag:
                continue
            _say(f"timing {name} ({label}) on {data.n:,} samples, best of {repeat} ...")
            try:
                seconds = time_estimator(name, data, use_mag, repeat)
            except Exception as exc:
                reraise_interrupt(exc)
                _say(f"warning: {name} ({label}) failed: {type(exc).__name__}: {exc}")
                rows.append(dict(estimator=name, mag=use_mag, error=f"{type(exc).__name__}: {exc}"))
                continue
            rate = data.n / seconds
            x = rate / reference[label] if label in reference else None
            met, misses = _verdict(name, rate, x if cls.in_all else None)  # targets are ours, not the rivals'
            rows.append(dict(estimator=name, mag=use_mag, samples=data.n, best_s=seconds,
                             samples_per_s=rate, x_imufusion=x, target_met=met, misses=misses,
                             warm_s=warm_s))
    return {
        "mavattitude": __version__,
        "machine": {"python": platform.python_version(), "numpy": np.__version__,
                    "numba": _version("numba"), "platform": platform.platform(),
                    "cpus": os.cpu_count()},
        "data": {"scenario": data.scenario, "seed": data.seed, "duration_s": data.duration,
                 "imu_rate_hz": data.imu_rate, "samples": data.n, "mag_samples": data.mag_samples,
                 "simulate_s": data.simulate_s},
        "repeat": repeat,
        "targets": {"min_x_imufusion": MIN_X_IMUFUSION, "mahony_min_samples_per_s": MAHONY_MIN_RATE},
        "imufusion": {
            "available": has_imufusion,
            "version": _version("imufusion") if has_imufusion else None,
            "samples": n_fusion if has_imufusion else 0,
            "samples_per_s": {("mag" if k == "mag" else "no_mag"): v for k, v in reference.items()},
            "settings": _settings_json() if has_imufusion else None,
        },
        "results": rows,
    }


def _settings_json() -> dict:
    """The yardstick's settings: the imufusion estimator's defaults, in its NED convention."""
    from dataclasses import asdict

    from ..estimators.rivals import ImufusionParams
    return {"convention": "NED", **asdict(ImufusionParams())}


def _version(package: str) -> str | None:
    from importlib.metadata import PackageNotFoundError, version

    try:
        return version(package)
    except PackageNotFoundError:
        return None


# ---------------------------------------------------------------- table


def _rate(r: float) -> str:
    if r >= 1e6:
        return f"{r / 1e6:.2f} M"
    if r >= 1e3:
        return f"{r / 1e3:.0f} k"
    return f"{r:.0f}"


def format_table(result: dict) -> str:
    d = result["data"]
    fusion = result["imufusion"]
    lines = [f"{d['scenario']}, {d['duration_s']:g} s at {d['imu_rate_hz']:g} Hz: {d['samples']:,} IMU "
             f"samples, {d['mag_samples']:,} magnetometer samples; best of {result['repeat']}"]
    header = f"{'estimator':<16}  {'mag':<6}  {'samples/s':>10}  {'× imufusion':>11}  target met"
    lines += [header, "-" * len(header)]
    for row in result["results"]:
        mode = "" if row["mag"] is None else ("mag" if row["mag"] else "no mag")
        if "error" in row:
            lines.append(f"{row['estimator']:<16}  {mode:<6}  {'failed':>10}  {'':>11}  {row['error']}")
            continue
        x = "n/a" if row["x_imufusion"] is None else f"{row['x_imufusion']:.1f}"
        met = {True: "yes", False: "NO: " + "; ".join(row["misses"]), None: "n/a"}[row["target_met"]]
        lines.append(f"{row['estimator']:<16}  {mode:<6}  {_rate(row['samples_per_s']):>10}  {x:>11}  {met}")
    if fusion["available"]:
        for key, label in (("mag", "mag"), ("no_mag", "no mag")):
            rate = fusion["samples_per_s"][key]
            lines.append(f"{'imufusion.Ahrs':<16}  {label:<6}  {_rate(rate):>10}  {'1.0':>11}  "
                         f"(reference: Python loop, {fusion['samples']:,} samples)")
    others = "".join(f", {name} ≥ {x:g}×" for name, x in MIN_X_IMUFUSION_FOR.items())
    lines.append(f"targets: every estimator ≥ {MIN_X_IMUFUSION:g}× imufusion in the same mode{others}; "
                 f"mahony ≥ {_rate(MAHONY_MIN_RATE)} samples/s")
    if not fusion["available"]:
        lines.append(f"imufusion not installed: no × imufusion column ({INSTALL_HINT})")
    return "\n".join(lines) + "\n"


def run(names: list[str], scenario: str, duration: float, imu_rate: float, seed: int,
        repeat: int, imufusion_samples: int, json_out=None,
        live_seconds: float | None = None) -> int:
    """The ``bench`` command: checks its options, runs, prints the table, writes the JSON.
    ``live_seconds``: also the live figure (``bench_live``), streaming that long."""
    from ..sim import SCENARIOS

    if scenario not in SCENARIOS:
        raise UsageError(f"unknown scenario {scenario!r}; choose from: {', '.join(SCENARIOS)}")
    if not (duration > 0 and imu_rate > 0 and repeat >= 1 and imufusion_samples >= 1
            and (live_seconds is None or live_seconds > 0)):
        raise ValueError("durations, rates and counts must be positive")  # the CLI's types check them
    result = run_bench(names, scenario, duration, imu_rate, seed, repeat, imufusion_samples)
    print(format_table(result), end="")
    if live_seconds is not None:
        from .bench_live import format_live, run_live_bench
        result["live"] = run_live_bench(names, live_seconds, say=_say)
        print(format_live(result["live"]), end="")
    if json_out is not None:  # an outputs.Output
        with json_out.writing() as path:
            Path(path).write_text(json_text(result))
    # 1 when an estimator could not be timed; a missed speed target is a finding, printed and in the JSON
    return 1 if any("error" in row for row in result["results"]) else 0
