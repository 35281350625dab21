"""``mavattitude bench`` end to end (short flights, no timed assertions), and the
allocation-free mahony kernel against the vector formulation it replaced."""
from __future__ import annotations

import json
import sys
from dataclasses import dataclass

import numpy as np
import pytest

from mavattitude import quaternion as quat
from mavattitude.cli import main
from mavattitude.estimators import ESTIMATORS, Estimator, all_names, available
from mavattitude.estimators.base import MAX_STEP_S
from mavattitude.estimators.mahony import Mahony, MahonyParams
from mavattitude.flight import MagSeries
from mavattitude.core.runner import held_magnetometer
from mavattitude.sim import simulate

SHORT = ["bench", "--duration", "20", "--imu-rate", "100", "--repeat", "1"]


def _bench(capsys, tmp_path, *extra):
    path = tmp_path / "bench.json"
    rc = main(SHORT + ["--json", str(path), *extra])
    out, err = capsys.readouterr()
    return rc, out, err, json.loads(path.read_text())


def test_bench_runs_every_estimator(capsys, tmp_path):
    rc, out, err, result = _bench(capsys, tmp_path, "--imufusion-samples", "500")
    assert rc == 0, err
    assert "simulating figure8" in err and "simulated in" in err
    d = result["data"]
    assert d["samples"] == 2000 and d["imu_rate_hz"] == 100.0 and d["duration_s"] == 20.0
    assert d["mag_samples"] == 200  # 10 Hz compass over 20 s
    assert result["repeat"] == 1
    assert result["targets"] == {"min_x_imufusion": 5.0, "estimators": {  # as the classes state them
        "mahony": {"min_samples_per_s": 1e6}, "cpf-ekf": {"min_x_imufusion": 1.0}}}
    assert "imufusion in the same mode, cpf-ekf ≥ 1×; mahony ≥ 1.00 M samples/s" in out
    rows = result["results"]
    for name in all_names():  # 'all': ours
        cls = ESTIMATORS[name]
        modes = sorted(r["mag"] for r in rows if r["estimator"] == name)
        assert modes == ([False, True] if cls.uses_mag else [False]), name
        assert name in out
    fusion = result["imufusion"]
    for row in rows:
        assert "error" not in row, row
        assert row["samples_per_s"] > 0 and row["best_s"] > 0 and row["samples"] == 2000
        # without imufusion (it is the optional 'bench' extra) only mahony has a target of its own
        judged = fusion["available"] or row["estimator"] == "mahony"
        assert row["target_met"] in ((True, False) if judged else (None,)), row
        assert row["x_imufusion"] is None or row["x_imufusion"] > 0
    if fusion["available"]:
        assert fusion["samples"] == 500 and fusion["version"]
        assert set(fusion["samples_per_s"]) == {"mag", "no_mag"}
        assert all(v > 0 for v in fusion["samples_per_s"].values())
        assert fusion["settings"]["convention"] == "NED" and fusion["settings"]["gain"] == 0.5
        assert all(r["x_imufusion"] > 0 for r in rows)
        assert "imufusion.Ahrs" in out
    assert "samples/s" in out and "target met" in out


@pytest.mark.skipif(bool(available("vqf") or available("imufusion")), reason="needs vqf and imufusion")
def test_bench_times_the_rivals_beside_ours_without_targets(capsys, tmp_path):
    rc, out, err, result = _bench(capsys, tmp_path, "--estimators", "mahony,vqf,imufusion",
                                  "--imufusion-samples", "500")
    assert rc == 0, err
    rows = {(r["estimator"], r["mag"]): r for r in result["results"]}
    assert set(rows) == {(n, m) for n in ("mahony", "vqf", "imufusion") for m in (True, False)}
    for name in ("vqf", "imufusion"):
        for mag in (True, False):
            row = rows[name, mag]
            assert row["samples_per_s"] > 0 and row["x_imufusion"] > 0 and row["target_met"] is None
    assert rows["mahony", True]["target_met"] in (True, False)
    assert [line.split()[0] for line in out.splitlines() if line.startswith(("vqf ", "imufusion "))] == \
        ["vqf", "vqf", "imufusion", "imufusion"]


def test_bench_without_imufusion(capsys, tmp_path, monkeypatch):
    monkeypatch.setitem(sys.modules, "imufusion", None)  # import imufusion raises ImportError
    rc, out, err, result = _bench(capsys, tmp_path, "--estimators", "mahony")
    assert rc == 0, err
    assert "imufusion is not installed" in err and "pip install" in err
    assert result["imufusion"]["available"] is False
    assert result["imufusion"]["samples_per_s"] == {}
    rows = result["results"]
    assert [(r["estimator"], r["mag"]) for r in rows] == [("mahony", True), ("mahony", False)]
    for row in rows:
        assert row["samples_per_s"] > 0 and row["x_imufusion"] is None
        assert row["target_met"] in (True, False)  # mahony's own target still applies
    assert "imufusion.Ahrs" not in out and "imufusion not installed" in out


@dataclass
class _NoParams:
    pass


class _Broken(Estimator):
    name = "broken"
    Params = _NoParams

    def initialize(self, q0, gyro_bias):
        self.initialized = True

    def update(self, t, gyro, accel, mag, in_air=None):
        raise RuntimeError("kernel exploded")


def test_a_failing_estimator_is_reported_not_fatal(capsys, tmp_path, monkeypatch):
    monkeypatch.setitem(sys.modules, "imufusion", None)
    monkeypatch.setitem(ESTIMATORS, "broken", _Broken)
    rc, out, err, result = _bench(capsys, tmp_path, "--estimators", "broken,mahony")
    assert rc == 1
    assert "broken failed: RuntimeError: kernel exploded" in err
    assert result["results"][0] == {"estimator": "broken", "mag": None,
                                     "error": "RuntimeError: kernel exploded"}
    assert [r["estimator"] for r in result["results"][1:]] == ["mahony", "mahony"]
    assert "kernel exploded" in out


@pytest.mark.parametrize("args", [["--duration", "0"], ["--repeat", "0"], ["--scenario", "nope"],
                                  ["--estimators", "nope"], ["--duration", "0.1"]])
def test_bench_usage_errors(capsys, args):
    assert main(["bench", *args]) == 2
    assert "error" in capsys.readouterr().err


# ---------------------------------------------------------------- the allocation-free mahony


def test_integrate_gyro_scalar_equals_integrate_gyro():
    rng = np.random.default_rng(1)
    for k in range(500):
        q = quat.normalize(rng.normal(size=4))
        w = rng.normal(0, 2.0, 3) * (1e-14 if k % 10 == 0 else 1.0)  # some below the small-angle cut
        dt = rng.uniform(1e-4, 0.1)
        assert quat.integrate_gyro_scalar(*q, *w, dt) == tuple(quat.integrate_gyro(q, w, dt))


def _mahony_reference(t, gyro, accel, mag, q0, bias, params, declination):
    """The filter as it was written before the loop was made allocation-free: per-sample
    arrays, C(q) as a matrix, the vector helpers of ``quaternion``."""
    q = np.array(q0, dtype=float)
    bias_correction = -np.array(bias, dtype=float)
    north = np.array([np.cos(declination), np.sin(declination)])
    t_prev, gyro_prev = np.nan, np.zeros(3)
    out = np.empty((len(t), 4))
    for i in range(len(t)):
        dt = t[i] - t_prev if t_prev == t_prev else 0.0
        t_prev = t[i]
        rate = 0.5 * (gyro[i] + gyro_prev) if dt > 0.0 else gyro[i]
        gyro_prev = gyro[i].copy()
        c = quat.qdcm(q)
        e = np.zeros(3)
        a_norm = np.linalg.norm(accel[i])
        if a_norm > 0.0:
            e += quat.cross(accel[i] / a_norm, -c[2, :])
        m = mag[i]
        if params.use_mag and m[0] == m[0]:
            m_n = c @ m
            if np.hypot(m_n[0], m_n[1]) > 0.0:
                gamma = np.arctan2(m_n[0] * north[1] - m_n[1] * north[0],
                                   m_n[0] * north[0] + m_n[1] * north[1])
                e += gamma * c[2, :]
        if 0.0 < dt <= MAX_STEP_S:
            bias_correction += params.ki * e * dt
            q = quat.integrate_gyro(q, rate + params.kp * e + bias_correction, dt)
        out[i] = q
    return out


@pytest.mark.parametrize("use_mag", [True, False])
def test_mahony_kernel_matches_the_vector_formulation(use_mag):
    sim = simulate("figure8", 30.0, seed=4, imu_rate=200.0)
    t, gyro, accel = sim.t.copy(), sim.imu[0].gyro.copy(), sim.imu[0].accel.copy()
    mag = held_magnetometer(t, MagSeries("mag", sim.mag.t, sim.mag.field))
    t[3000:] += 3.0  # a gap, not integrated over
    accel[::500] = 0.0  # accelerometer dropouts
    # large gains: the terms matter; the accelerometer as it reads (the pre-step has its own test)
    params = MahonyParams(kp=1.0, ki=0.05, use_mag=use_mag, accel_tau=0.0)
    q0, bias = quat.from_euler(0.3, -0.2, 1.0), np.array([0.01, -0.02, 0.005])
    f = Mahony(params, declination=0.2)
    f.initialize(q0, bias)
    q = f.update(t, gyro, accel, mag)
    ref = _mahony_reference(t, gyro, accel, mag, q0, bias, params, 0.2)
    np.testing.assert_allclose(q, ref, rtol=0, atol=1e-12)


@pytest.mark.slow
def test_live_figure_runs_and_reports(capsys):
    """``bench --live`` end to end on a short stream (the figures are not judged here: speed
    targets live in the benchmark, not in tests)."""
    from mavattitude.commands.bench_live import format_live, run_live_bench

    # the simulated vehicle sits still for its first seconds: estimates begin when it moves (some
    # 6 s into the stream); 7 s and the 3 s of settling leave ~4 s measured, the fade at ~5 s
    figures = run_live_bench(["mahony"], seconds=7.0, say=lambda line: None, probe_seconds=2.0)
    assert figures["packets_sent"] > 9000 and figures["packets_received"] > 0
    assert 2.0 < figures["alignment_wait_s"] < 10.0
    assert figures["imu_samples_measured"] > 1000
    assert any("SET_MESSAGE_INTERVAL RAW_IMU 1000 us" in r for r in figures["requests"])
    lat = figures["latency_ms"]
    assert 0 < lat["p50"] <= lat["p99"] <= lat["max"]
    assert figures["target_met"] in (True, False)
    # 10 s of 1 kHz: one 200-packet burst lost on purpose, its IMU samples seen by the clock
    assert figures["faded_packets"] == 200 and figures["faded_imu_samples"] > 100
    assert abs(figures["imu_samples_lost_by_clock"] - figures["faded_imu_samples"]) <= 2
    assert figures["lost_by_sequence"] < 128  # what the sequence number saw of it
    probe = figures["rate_probe"]  # 2 s at 20x real time
    assert probe["sent"] > 30_000 and probe["received"] <= probe["sent"] and probe["held"] in (True, False)
    assert probe["imu_samples"] > 20_000 and probe["mb_per_hour_at_1khz"] is not None
    assert probe["rss_mb"]["start"] > 0 and probe["rss_mb"]["end"] > 0
    text = format_live(figures)
    assert "packet-to-estimate latency" in text and "dropped" in text and "by the autopilot's clock" in text
    assert "packets/s for 2 s" in text


def test_rss_growth_is_the_slope_of_the_second_half():
    """A session that fills its history, then stays flat, grows 0 MB an hour; one that keeps
    growing is extrapolated from its slope (10 min of 1 kHz data in 30 s here)."""
    from mavattitude.commands.bench_live import _rss_figures

    t = np.arange(0.0, 30.0, 0.25) + 100.0
    flat = np.minimum(300.0 + 10.0 * (t - 100.0), 350.0) + np.where(np.arange(len(t)) % 2, 3.0, -3.0)
    got = _rss_figures(list(zip(t, flat)), 100.0, 130.0, 600_000)
    assert abs(got["mb_per_hour_at_1khz"]) < 5 and got["rss_mb"]["start"] < got["rss_mb"]["end"] == 350.0
    growing = 300.0 + 0.5 * (t - 100.0)  # 15 MB per 10 min of data: 90 MB an hour
    assert _rss_figures(list(zip(t, growing)), 100.0, 130.0, 600_000)["mb_per_hour_at_1khz"] == pytest.approx(90.0)


@pytest.mark.slow  # times pymavlink reading a log
def test_read_figures_run_and_report(capsys, tmp_path):
    """``bench --read`` on a short simulated log and a sample .tlog: every figure present and
    consistent (no timed assertion: the speeds are whatever this machine gives)."""
    from conftest import SAMPLE_LOGS

    path = tmp_path / "read.json"
    rc = main(["bench", "--read", "--duration", "30", "--imu-rate", "100", "--repeat", "1",
               "--log", str(SAMPLE_LOGS / "figure8.tlog"), "--json", str(path)])
    out, err = capsys.readouterr()
    result = json.loads(path.read_text())
    assert rc == 0, err  # whatever the speeds: a missed target is printed, not an exit status
    reads = {r["format"]: r for r in result["reads"]}
    assert set(reads) == {"bin", "tlog", "ulg"} and reads["bin"]["log"].startswith("simulated figure8")
    assert reads["ulg"]["log"].endswith("(.ulg)") and reads["ulg"]["reference"] == "pyulog"
    for r in reads.values():
        # (rounded to 0.1: a cold compile inside the timed run makes a small x)
        ref = r["reference"]
        assert r[f"x_{ref}"] == pytest.approx(r[f"{ref}_s"] / r["ours_s"], rel=0.05, abs=0.05)
        assert r[f"x_{ref}_load"] == pytest.approx(r[f"{ref}_s"] / r["load_s"], rel=0.05, abs=0.05)
        assert r["load_s"] > 0
    e2e = result["end_to_end"]
    assert e2e["wall_s"] > 0 and e2e["peak_rss_mb"] > e2e["decoded_mb"] > 0 and e2e["rrd_mb"] > 0
    assert result["targets"]["end_to_end_s"] == pytest.approx(30.0 * 30 * 100 / (3600 * 400))
    assert "Reading the message types replay uses" in out and "End to end" in out
    assert "targets:" in out and set(result["met"]) >= {"bin_x_pymavlink", "x_pymavlink_load", "ulg_x_pyulog",
                                                         "end_to_end_s"}
    assert result["targets"]["x_pymavlink_load"] == 10.0 and "load() >= 10x pymavlink" in out
    assert ".ulg read >= 10x pyulog" in out


def test_log_without_read_is_a_usage_error(capsys):
    assert main(["bench", "--log", "x.bin"]) == 2
    assert "--log is for --read" in capsys.readouterr().err


@pytest.mark.slow  # three processes, one of them at 300 MB: kept out of the quick loop
@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="Linux's accounting of a child's peak memory")
def test_the_end_to_end_peak_is_the_replays_own_not_the_benchs():
    """A process started from this one begins its ru_maxrss at this one's peak (Linux keeps the
    peak of the memory a process leaves at exec: its parent's, under vfork): ``bench --read``
    starts the replay from a small process of its own (``LAUNCH``), as pymavlink's read of the
    hour takes the bench to some 700 MB, above the replay's own peak."""
    import os
    import subprocess

    from mavattitude.commands.bench_read import LAUNCH

    big = np.ones(300_000_000 // 8)  # this process at 300 MB and more, for a moment
    del big
    child = subprocess.Popen([sys.executable, "-c", "pass"])
    direct = os.wait4(child.pid, 0)[2].ru_maxrss * 1024 / 1e6
    code, peak, wall = subprocess.run([sys.executable, "-c", LAUNCH, sys.executable, "-c", "pass"],
                                      capture_output=True, text=True, check=True).stdout.split()
    assert direct > 300 and code == "0" and int(peak) * 1024 / 1e6 < 100 and float(wall) > 0
