"""The Rerun view, on a synthetic replay (the pipeline is not needed).

Run as a script to write the synthetic recording for a look in a viewer:
    python tests/test_view.py /tmp/synthetic.rrd [--duration 120]
"""
from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import rerun as rr

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from mavattitude import quaternion as quat  # noqa: E402
from mavattitude import view  # noqa: E402
from mavattitude.flight import AttitudeSeries, Flight, GpsSeries, ImuSeries  # noqa: E402
from mavattitude.scoring.metrics import AXES, AxisMetrics, Comparison  # noqa: E402
from mavattitude.events import Event  # noqa: E402
from mavattitude.commands.replay import ReplayResult  # noqa: E402
from mavattitude.outputs import Outputs  # noqa: E402
from mavattitude.view.sink import close_sink, open_sink, plan_sink  # noqa: E402
from conftest import RERUN_CLI as RERUN  # noqa: E402  (the rerun CLI, or None)

# ---------------------------------------------------------------- synthetic replay


def _true_euler(t):
    """A flight that rolls, pitches and turns through north-south (yaw crosses ±180°)."""
    roll = np.radians(25.0) * np.sin(2 * np.pi * t / 17.0) * np.clip(t / 10.0, 0, 1)
    pitch = np.radians(12.0) * np.sin(2 * np.pi * t / 11.0 + 0.7)
    yaw = np.radians(140.0) + np.radians(2.5) * (t - 30.0) + np.radians(20.0) * np.sin(t / 7.0)
    return roll, pitch, quat.wrap_pi(yaw)


def _estimate(t, rng, bias_deg, noise_deg, start_err_deg, tau):
    roll, pitch, yaw = _true_euler(t)
    decay = np.exp(-(t - t[0]) / tau)
    e = [np.radians(bias_deg[k] + start_err_deg[k] * decay) + np.radians(noise_deg)
         * rng.standard_normal(len(t)) for k in range(3)]
    return quat.from_euler(roll + e[0], pitch + e[1], yaw + e[2])


def _axis_metrics(err):
    a = np.abs(err)
    if len(a) == 0:
        return None
    hist = np.histogram(a, bins=[0, 0.5, 1.0, 2.0, np.inf])[0] / len(a)
    return AxisMetrics(n=len(a), mae=float(a.mean()), rmse=float(np.sqrt((a ** 2).mean())),
                       mse=float((a ** 2).mean()), r2=0.99, max=float(a.max()),
                       sigma1=float(np.quantile(a, 0.6826)),
                       sigma3=float(np.quantile(a, 0.9973)), buckets=tuple(hist))


def _compare(name, est: AttitudeSeries, ref: AttitudeSeries, warmup_s=10.0):
    inside = (ref.t >= est.t[0]) & (ref.t <= est.t[-1])
    t = ref.t[inside]
    q_est = quat.interpolate(est.t, est.q, t)
    err = quat.wrap_deg(np.degrees(quat.to_euler(q_est) - quat.to_euler(ref.q[inside])))
    scored = t >= est.t[0] + warmup_s
    axes = {axis: _axis_metrics(err[scored, k]) for k, axis in enumerate(AXES)}
    return Comparison(estimator=name, reference=ref.source, t=t, error_deg=err, scored=scored,
                      axes=axes, warmup_s=warmup_s)


def make_replay(duration=120.0, imu_hz=400.0, att_hz=25.0, truth_hz=50.0,
                reference="truth", gps=True, t0=30.0, seed=1) -> ReplayResult:
    rng = np.random.default_rng(seed)
    t_imu = t0 + np.arange(0.0, duration, 1.0 / imu_hz)
    n = len(t_imu)
    imu = ImuSeries("IMU[0]", t_imu, np.zeros((n, 3)),
                    np.tile([0.0, 0.0, -9.80665], (n, 1)))
    t_att = t0 + np.arange(0.0, duration, 1.0 / att_hz)
    t_truth = t0 + np.arange(0.0, duration, 1.0 / truth_hz)
    truth = AttitudeSeries("SIM", t_truth, quat.from_euler(*_true_euler(t_truth)))
    att = AttitudeSeries("ATT", t_att, _estimate(t_att, rng, (0.3, -0.2, 1.0), 0.1,
                                                 (0, 0, 0), 1.0))
    fl = Flight(path="synthetic.bin", format="bin", imu={"IMU[0]": imu}, attitude=att,
                truth=truth if reference == "truth" else None, vehicle="ArduPlane",
                firmware="ArduPlane V4.5.0 (synthetic)", segments=[(t0, t0 + duration)],
                notes=["synthetic flight for the view tests"])
    if gps:
        t_gps = t0 + np.arange(0.0, duration, 0.2)
        ang = 2 * np.pi * (t_gps - t0) / duration
        lat = -35.363261 + 0.004 * np.sin(ang)
        lon = 149.165230 + 0.006 * (1 - np.cos(ang))
        m = len(t_gps)
        fl.gps = GpsSeries("GPS[0]", t_gps, lat, lon, np.full(m, 600.0), np.zeros((m, 3)),
                           np.full(m, 3), np.full(m, 12), np.full(m, 1.5))
    estimates = {
        "mahony": AttitudeSeries("mahony", t_imu, _estimate(t_imu, rng, (0.5, 0.8, -2.0), 0.3,
                                                            (20, -15, 60), 2.5)),
        "ncs-eskf": AttitudeSeries("ncs-eskf", t_imu, _estimate(t_imu, rng, (-0.2, 0.1, 0.8),
                                                                0.15, (-10, 8, -40), 1.5)),
    }
    ref = truth if reference == "truth" else att
    comparisons = {name: _compare(name, s, ref) for name, s in estimates.items()}
    if reference == "truth":
        comparisons["autopilot"] = _compare("autopilot", att, truth)
    events = [Event(t0, "info", "replay started on IMU[0]"),
              Event(t0 + 10.0, "info", "warm-up over: scoring starts"),
              Event(t0 + 0.45 * duration, "warn", "mahony: accelerometer rejected for 1.2 s"),
              Event(t0 + 0.7 * duration, "info", "mode change: AUTO")]
    return ReplayResult(flight=fl, imu_source="IMU[0]", reference=ref, estimates=estimates,
                        comparisons=comparisons, events=events)


def write_rrd(result: ReplayResult, path) -> None:
    with Outputs() as outputs:
        sink = plan_sink("rrd", path, outputs)
        rec = open_sink(sink, "mavattitude", "synthetic replay")
        view.log_replay(result, rec)
        close_sink(rec, sink)


# ---------------------------------------------------------------- helpers


def _rrd_text(path) -> str:
    out = subprocess.run([RERUN, "rrd", "print", "-v", str(path)], capture_output=True,
                         text=True, timeout=120)
    assert out.returncode == 0, out.stderr
    return out.stdout + out.stderr


@pytest.fixture(scope="module")
def truth_rrd(tmp_path_factory):
    path = tmp_path_factory.mktemp("view") / "truth.rrd"
    write_rrd(make_replay(duration=60.0), path)
    return path


# ---------------------------------------------------------------- tests


@pytest.mark.skipif(RERUN is None, reason="rerun CLI not found")
def test_rrd_verifies(truth_rrd):
    out = subprocess.run([RERUN, "rrd", "verify", str(truth_rrd)], capture_output=True,
                         text=True, timeout=120)
    assert out.returncode == 0, out.stdout + out.stderr


@pytest.mark.skipif(RERUN is None, reason="rerun CLI not found")
def test_entity_paths_present(truth_rrd):
    text = _rrd_text(truth_rrd)
    expected = ["/summary", "/events", "/map/track", "/map/position",
                "/ref/truth/box/body", "/ref/autopilot/box/body", "/est/mahony/box/body",
                "/est/ncs-eskf/box/body", "/est/mahony/box/reference",
                "/ref/autopilot/box/reference"]
    for axis in AXES:
        expected += [f"/ref/{s}/attitude/{axis}" for s in ("truth", "autopilot")]
        expected += [f"/est/{s}/attitude/{axis}" for s in ("mahony", "ncs-eskf")]
        expected += [f"/est/{s}/error/{axis}" for s in ("mahony", "ncs-eskf")]
        expected += [f"/ref/autopilot/error/{axis}", f"/est/mahony/warmup/{axis}"]
    missing = [p for p in expected if p not in text]
    assert not missing, missing
    assert "/ref/truth/box/reference" not in text  # the reference has no ghost of itself


def test_no_per_sample_log_calls(tmp_path, monkeypatch):
    calls = {"log": 0, "send_columns": 0}
    orig_log, orig_cols = rr.RecordingStream.log, rr.RecordingStream.send_columns

    def counting_log(self, *a, **k):
        calls["log"] += 1
        return orig_log(self, *a, **k)

    def counting_cols(self, *a, **k):
        calls["send_columns"] += 1
        return orig_cols(self, *a, **k)

    def forbidden(*a, **k):
        raise AssertionError("use the recording passed in, not the global rr.log")

    monkeypatch.setattr(rr.RecordingStream, "log", counting_log)
    monkeypatch.setattr(rr.RecordingStream, "send_columns", counting_cols)
    monkeypatch.setattr(rr, "log", forbidden)
    monkeypatch.setattr(rr, "send_columns", forbidden)

    counts = []
    for duration in (20.0, 80.0):
        calls.update(log=0, send_columns=0)
        result = make_replay(duration=duration)
        write_rrd(result, tmp_path / f"d{duration:g}.rrd")
        counts.append(dict(calls))
    samples = sum(len(s.t) for s in make_replay(duration=20.0).estimates.values())
    assert counts[0] == counts[1], counts  # independent of the number of samples
    # static styling only: about a dozen calls per series, whatever the length
    assert counts[0]["log"] < 150 and counts[0]["log"] < samples / 50, counts


def test_decimation_rules():
    t = np.arange(0.0, 10.0, 1 / 400)
    idx = view._bin_first(t, 50.0)
    assert 495 <= len(idx) <= 505
    assert len(view._bin_first(t[::4], 200.0)) == len(t[::4])  # 100 Hz kept whole
    y = np.zeros_like(t)
    y[1234] = 42.0
    y[2345] = -17.0
    idx = view._bin_minmax(t, y, 200.0)
    assert len(idx) <= 2 * 10 * 100 + 2 and 1234 in idx and 2345 in idx
    assert np.all(np.diff(idx) > 0)
    assert view.scalar_rate_for(60.0) == view.SCALAR_MAX_HZ
    assert view.scalar_rate_for(3600.0) == pytest.approx(view.SCALAR_MAX_POINTS / 3600.0)
    assert view.transform_rate_for(600.0) == view.TRANSFORM_MAX_HZ
    assert view.transform_rate_for(3600.0) == pytest.approx(view.TRANSFORM_MAX_POINTS / 3600.0)


def test_min_max_binning_in_runs_of_bins_picks_what_it_picks_whole(monkeypatch):
    """_bin_minmax cuts a long series at bin ends: the same picks as binning it whole (NaNs,
    ties, a gap, a backward step)."""
    rng = np.random.default_rng(7)
    t = np.cumsum(rng.uniform(0.0005, 0.01, 20_000))
    t[5000:] += 4.0
    y = np.round(rng.normal(size=len(t)), 1)
    y[rng.random(len(t)) < 0.05] = np.nan
    whole = view._bin_minmax(t, y, 37.0)
    for rows in (1, 7, 999):
        monkeypatch.setattr(view.decimation, "MINMAX_ROWS", rows)
        assert np.array_equal(view._bin_minmax(t, y, 37.0), whole)
        back = t.copy()
        back[100] = back[50]  # time stepping back: the first sample of each bin instead
        assert np.array_equal(view._bin_minmax(back, y, 37.0), view._bin_first(back, 37.0))


def test_reference_autopilot_without_truth_or_gps(tmp_path):
    result = make_replay(duration=30.0, reference="autopilot", gps=False)
    path = tmp_path / "att.rrd"
    write_rrd(result, path)
    if RERUN:
        text = _rrd_text(path)
        assert "/ref/autopilot/box/body" in text and "/est/mahony/box/reference" in text
        assert "/map/" not in text and "/ref/truth/" not in text


def test_no_reference_nothing_scored(tmp_path):
    """A log without an attitude reference: estimates shown, no errors, no ghosts."""
    result = make_replay(duration=20.0, reference="autopilot", gps=False)
    result.flight.attitude = None
    result.reference = None
    result.comparisons = {}
    assert "Nothing was scored" in view.summary_markdown(result)
    path = tmp_path / "noref.rrd"
    write_rrd(result, path)
    if RERUN:
        text = _rrd_text(path)
        assert "/est/mahony/box/body" in text and "/est/ncs-eskf/attitude/yaw" in text
        assert "/error/" not in text and "/reference" not in text and "/ref/" not in text


def test_colors_fixed_and_distinct():
    c = view.assign_colors(["truth", "autopilot", "mahony", "ncs-eskf", "mystery", "other"])
    assert c["truth"] == view.TRUTH_COLOR and c["autopilot"] == view.AUTOPILOT_COLOR
    assert len(set(c.values())) == len(c)
    assert view.assign_colors(["mahony"])["mahony"] == c["mahony"]


class _Capture:
    """Stands in for a RecordingStream: keeps what send_columns was given."""

    def __init__(self):
        self.sent = {}

    def send_columns(self, path, indexes, columns):
        times = indexes[0].as_arrow_array().cast("int64").to_pylist()  # ns
        values = {c.component_descriptor().component: c.as_arrow_array().to_pylist()
                  for c in columns}
        self.sent.setdefault(path, []).append((times, values))


def test_transform_columns_are_xyzw_body_to_ned():
    q = quat.from_euler(np.radians([10.0, -20.0]), np.radians([5.0, 0.0]),
                        np.radians([30.0, 170.0]))
    cap = _Capture()
    view.log_transform_columns(cap, "world/x/body", [1.0, 2.0], q)
    (times, values), = cap.sent["world/x/body"]
    got = np.array([v[0] for v in values["Transform3D:quaternion"]])
    assert np.allclose(got, q[:, [1, 2, 3, 0]], atol=1e-6)


def test_euler_columns_in_degrees_and_wraps_broken():
    t = np.arange(0.0, 1.0, 0.1)
    yaw = np.radians(np.linspace(170.0, 190.0, len(t)))  # crosses +180 -> -180
    cap = _Capture()
    view.log_euler_columns(cap, "mahony", t, quat.from_euler(np.zeros_like(t),
                                                             np.zeros_like(t), yaw))
    (times, values), = cap.sent["est/mahony/attitude/yaw"]
    y = np.array([v[0] for v in values["Scalars:scalars"]], dtype=float)
    assert len(y) == len(t) + 1 and np.isnan(y).sum() == 1  # one break at the wrap
    assert np.nanmax(y) == pytest.approx(178.89, abs=0.01) and np.nanmin(y) < -170
    (_, roll), = cap.sent["est/mahony/attitude/roll"]
    assert np.allclose([v[0] for v in roll["Scalars:scalars"]], 0.0, atol=1e-9)


def test_chunks_log_like_the_whole():
    """Live use: the same series sent in chunks lands on the same paths, same samples."""
    t = np.arange(0.0, 20.0, 1 / 400)
    q = quat.from_euler(0.3 * np.sin(t), 0.1 * np.cos(t), np.zeros_like(t))
    whole, parts = _Capture(), _Capture()
    view.log_attitude_columns(whole, "ekf", t, q, scalar_max_hz=200.0)
    for sl in (slice(0, 3001), slice(3001, 8000)):
        view.log_attitude_columns(parts, "ekf", t[sl], q[sl], scalar_max_hz=200.0)
    assert set(whole.sent) == set(parts.sent)
    for path in whole.sent:
        a = [x for times, _ in whole.sent[path] for x in times]
        b = [x for times, _ in parts.sent[path] for x in times]
        assert a == b, path


@pytest.mark.slow
def test_an_hour_long_log_makes_a_modest_file(tmp_path):
    """An hour at 400 Hz with two estimators: decimated to what a screen shows (its time is
    measured by scripts/rrd_size.py and bench --read, not tested)."""
    result = make_replay(duration=3600.0, att_hz=10.0, truth_hz=50.0)
    write_rrd(result, tmp_path / "hour.rrd")
    size_mb = (tmp_path / "hour.rrd").stat().st_size / 1e6
    assert size_mb < 200, size_mb


if __name__ == "__main__":
    import argparse

    ap = argparse.ArgumentParser(description="write the synthetic replay as an .rrd")
    ap.add_argument("out")
    ap.add_argument("--duration", type=float, default=120.0)
    ap.add_argument("--reference", default="truth", choices=["truth", "autopilot"])
    args = ap.parse_args()
    write_rrd(make_replay(duration=args.duration, reference=args.reference), args.out)
    print(args.out)


def test_an_estimate_without_heading_is_shown_as_it_is_scored():
    """The yaw plot and the box of an estimator with no heading reference carry the offset its
    yaw error had removed, span by span (restarts), so value and error plots agree."""
    from mavattitude.scoring.metrics import compare
    from mavattitude.view import shown_estimate

    t = np.arange(0.0, 60.0, 0.02)
    roll, pitch, yaw = 0.2 * np.sin(t), 0.1 * np.cos(t), 0.05 * t
    ref = AttitudeSeries("ATT", t, quat.from_euler(roll, pitch, yaw))
    drift = np.where(t < 30.0, np.radians(40.0), np.radians(-100.0))  # a new arbitrary yaw after the restart
    est = AttitudeSeries("eskf", t, quat.from_euler(roll, pitch, yaw + drift))
    c = compare(ref, est, warmup_s=5.0, align_yaw=True, restarts=[30.0])
    shown = shown_estimate(est, c, [30.0])
    assert [round(o) for _, o in c.yaw_offsets_deg] == [40, -100]
    assert np.allclose(quat.to_euler(shown.q), quat.to_euler(ref.q), atol=1e-9)  # the shown yaw is the scored one
    assert shown_estimate(est, compare(ref, est, warmup_s=5.0), [30.0]) is est  # with a heading: as it is


def test_a_replay_kept_at_the_rows_drawn_is_drawn_as_one_kept_whole(monkeypatch):
    """``compact``: each estimate kept only at ``drawn_rows`` (not finite rows counted as
    estimated); the recording receives the same columns as from the whole estimates."""
    from mavattitude.commands.replay import replay_flight
    from mavattitude.core.policy import RunOptions
    from mavattitude.readers import read_log
    from conftest import SAMPLE_LOGS

    sent = []

    def spy(self, path, indexes, columns, **kwargs):
        sent.append((path, [str(i.as_arrow_array()) for i in indexes],
                     [str(c.as_arrow_array()) for c in columns]))

    monkeypatch.setattr(rr.RecordingStream, "send_columns", spy)
    monkeypatch.setattr(view.decimation, "SCALAR_MAX_HZ", 17.0)  # rates that do not nest, as an hour's
    monkeypatch.setattr(view.decimation, "TRANSFORM_MAX_HZ", 12.5)
    options = RunOptions.of(["mahony", "vqf"])
    whole, _ = replay_flight(read_log(SAMPLE_LOGS / "figure8.bin"), options, compact=False)
    kept, _ = replay_flight(read_log(SAMPLE_LOGS / "figure8.bin"), options, compact=True)
    assert kept.shown_rows is not None and len(kept.estimates["mahony"].t) <= len(whole.estimates["mahony"].t) / 2
    assert kept.nonfinite == whole.nonfinite
    # as kept whole for the view before: in float32 (the sample log has no board trim)
    assert whole.trim is None
    whole.estimates = {n: AttitudeSeries(n, s.t, s.q.astype(np.float32)) for n, s in whole.estimates.items()}
    drawn = []
    for result in (whole, kept):
        sent.clear()
        view.log_replay(result, rr.RecordingStream("test"), blueprint=False)
        drawn.append(list(sent))
    assert drawn[0] == drawn[1] and len(drawn[0]) > 20
