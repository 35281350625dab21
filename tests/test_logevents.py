"""The log's own flight modes, arming and text lines (readers.logevents): a simulated log read
back exactly in every format, the collector's placing of untimed rows, and the shared real logs."""
from __future__ import annotations

import numpy as np
import pytest

from mavattitude.readers import read_log
from mavattitude.readers.collect import Collector
from mavattitude.readers.logevents import err_text
from mavattitude.sim import simulate, write_log

from conftest import SHARED_LOGS, read_shared


@pytest.fixture(scope="module")
def hover():
    return simulate("hover", 30.0, seed=1, imu_rate=100.0)


@pytest.mark.parametrize("suffix", [".bin", ".tlog", ".ulg"])
def test_simulated_log_read_back(hover, suffix, tmp_path):
    script = hover.script
    assert len(script.modes) == 2 and script.armed_at is not None and script.messages  # the script has each
    flight = read_log(str(write_log(hover, tmp_path / f"s{suffix}")))
    names = [m[4] if suffix == ".ulg" else m[3] for m in script.modes]
    numbers = [m[2] if suffix == ".ulg" else m[1] for m in script.modes]
    assert flight.modes.label == names and flight.modes.value.tolist() == numbers
    arming = flight.arming
    assert arming.label[-1] == "armed" and arming.value[-1] == 1
    texts = [text for _, text in script.messages]
    assert [x for x in flight.messages.label if x in texts] == texts
    t_text = flight.messages.t[[x in texts for x in flight.messages.label]]
    want_modes = np.array([m[0] for m in script.modes])
    want_texts = np.array([t for t, _ in script.messages])
    if suffix == ".tlog":  # a heartbeat has no time: it takes the IMU tick's before it
        step = 1.0 / hover.rates.imu
        assert np.all((flight.modes.t <= want_modes + 1e-6) & (flight.modes.t >= want_modes - step - 1e-6))
        assert script.armed_at - step - 1e-6 <= arming.t[-1] <= script.armed_at + 1e-6
        np.testing.assert_allclose(t_text, want_texts, atol=1e-6)  # written after its tick
    else:
        np.testing.assert_allclose(flight.modes.t, want_modes, atol=1e-6)
        assert arming.t[-1] == pytest.approx(script.armed_at, abs=1e-6)
        np.testing.assert_allclose(t_text, want_texts, atol=1e-6)


def test_info_lists_the_modes_the_armed_span_and_the_errors(tmp_path):
    """``mavattitude info``: the simulated script's modes and armed span, its text lines counted,
    and a log's errors listed one by one (copter 3.3's ERR records)."""
    from mavattitude.commands.info import render, summarize

    hover = simulate("hover", 30.0, seed=1, imu_rate=100.0)
    flight = read_log(str(write_log(hover, tmp_path / "s.bin")))
    info = summarize(flight)
    events, end = info["events"], info["end_s"]
    assert [m["name"] for m in events["modes"]] == [m[3] for m in hover.script.modes]
    assert events["modes"][-1]["end_s"] == end
    assert events["armed"] == [{"start_s": pytest.approx(hover.script.armed_at, abs=1e-3), "end_s": end}]
    assert events["messages"]["by_severity"] == {"info": len(flight.messages.t)}  # the script's and the version's
    assert events["messages"]["warnings"] == []
    text = render(info)
    assert f"  armed     {hover.script.armed_at:.1f}-{end:.1f} s" in text.splitlines()
    if SHARED_LOGS.is_dir():
        text = render(summarize(read_shared("copter-3.3-loiter-rtl.bin")))
        assert "error     ERR: CRASH_CHECK 1" in text and "more (--json lists them all)" in text  # 9 modes


def test_untimed_rows_take_the_clock_before_them():
    col = Collector()
    t = np.arange(10) * 0.1 + 5.0
    col.add_columns("imu", "IMU[0]", np.arange(10) * 10, t, np.zeros((10, 6)))
    # before every sample, between two, and two lines in the same microsecond
    col.add_events("text", "MSG", [-1, 35, 71, 72], [np.nan, np.nan, 5.7, 5.7], [6, 6, 3, 3], ["a", "b", "c", "c"])
    col.finish()
    times, values, labels = col.events("text", "MSG", 0)
    assert times.tolist() == [5.0, 5.3, 5.7, 5.7] and labels == ["a", "b", "c", "c"]
    assert values.tolist() == [6, 6, 3, 3]


def test_a_row_far_from_the_clock_is_dropped():
    col = Collector()
    col.add_columns("imu", "IMU[0]", np.arange(10), np.arange(10) * 0.1, np.zeros((10, 6)))
    col.add_events("mode", "MODE", [5, 6], [0.5, 500.0], [1, 2])
    col.finish()
    assert col.events("mode", "MODE", 0)[1].tolist() == [1]


def test_err_text():
    assert err_text(12, 1) == "ERR: CRASH_CHECK 1"
    assert err_text(11, 0) == "ERR: GPS 0 (resolved)"
    assert err_text(99, 4) == "ERR: subsystem 99 4"


def test_copter_33_modes_and_errors():
    flight = read_shared("copter-3.3-loiter-rtl.bin")  # MODE, EV, ERR, MSG without a time of their own
    assert flight.modes.label[:3] == ["ALT_HOLD", "LOITER", "LAND"]
    assert np.all(np.diff(flight.modes.t) >= 0) and flight.modes.t[0] > 0
    assert flight.arming.label[0] == "armed"
    assert "ERR: CRASH_CHECK 1" in flight.messages.label
    assert flight.messages.label[0].startswith("ArduCopter V3.3")


@pytest.mark.skipif(not (SHARED_LOGS / "ulog").is_dir(), reason=f"real ULog not found at {SHARED_LOGS / 'ulog'}")
def test_px4_modes_arming_and_messages():
    flight = read_log(str(SHARED_LOGS / "ulog" / "px4-sitl-events-31s.ulg"))
    assert flight.modes.label == ["AUTO_LOITER", "AUTO_TAKEOFF", "AUTO_LOITER", "AUTO_RTL", "AUTO_LOITER"]
    assert flight.arming.label == ["disarmed", "armed", "disarmed"]
    assert any(x.startswith("[commander]") for x in flight.messages.label)


def test_tlog_modes_from_heartbeats():
    flight = read_shared("sitl-copter-4.7-50hz.tlog")
    assert flight.modes.label == ["STABILIZE", "GUIDED", "RTL"]
    assert flight.arming.label == ["disarmed", "armed", "disarmed"]


@pytest.mark.slow
@pytest.mark.skipif(not SHARED_LOGS.is_dir(), reason=f"real logs not found at {SHARED_LOGS}")
def test_every_shared_log_reads_its_events():
    paths = sorted(p for folder in (SHARED_LOGS, SHARED_LOGS / "corpus", SHARED_LOGS / "ulog")
                   for p in folder.iterdir() if p.suffix in (".bin", ".tlog", ".ulg"))
    with_modes = 0
    for path in paths:
        flight = read_log(str(path))
        for series in (flight.modes, flight.arming, flight.messages):
            if series is not None:
                assert len(series.t) == len(series.value) == len(series.label) > 0, path.name
                assert np.isfinite(series.t).all(), path.name
        if flight.modes is not None:
            with_modes += 1
            # named by pymavlink's tables (a number they lack, as ArduSub's 20, stays "mode 20")
            named = [not x.startswith(("mode ", "nav_state ")) for x in flight.modes.label]
            assert sum(named) > len(named) / 2, (path.name, flight.modes.label)
    assert with_modes >= len(paths) - 5
