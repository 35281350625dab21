"""The view's layout on a messy flight: one subtree per series (one action hides it
everywhere), a palette whose colours stay apart, and the ranges the plots open on (the flight,
not a crash at its end; errors from their spread, not one diverging estimator)."""
from __future__ import annotations

import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from mavattitude import quaternion as quat  # noqa: E402
from mavattitude import view  # noqa: E402
from mavattitude.flight import AttitudeSeries  # noqa: E402
from mavattitude.scoring.metrics import AXES  # noqa: E402
from test_view import make_replay  # noqa: E402


def srgb_to_lab(rgb):
    c = np.asarray(rgb, dtype=float) / 255.0
    c = np.where(c <= 0.04045, c / 12.92, ((c + 0.055) / 1.055) ** 2.4)
    m = np.array([[0.4124564, 0.3575761, 0.1804375], [0.2126729, 0.7151522, 0.0721750], [0.0193339, 0.1191920, 0.9503041]])
    xyz = c @ m.T / np.array([0.95047, 1.0, 1.08883])
    f = np.where(xyz > (6 / 29) ** 3, np.cbrt(xyz), xyz / (3 * (6 / 29) ** 2) + 4 / 29)
    return np.stack([116 * f[..., 1] - 16, 500 * (f[..., 0] - f[..., 1]), 200 * (f[..., 1] - f[..., 2])], axis=-1)

def ciede2000(lab1, lab2):
    L1, a1, b1 = np.moveaxis(np.asarray(lab1, float), -1, 0)
    L2, a2, b2 = np.moveaxis(np.asarray(lab2, float), -1, 0)
    C1, C2 = np.hypot(a1, b1), np.hypot(a2, b2)
    Cb = (C1 + C2) / 2
    G = 0.5 * (1 - np.sqrt(Cb**7 / (Cb**7 + 25.0**7)))
    a1p, a2p = (1 + G) * a1, (1 + G) * a2
    C1p, C2p = np.hypot(a1p, b1), np.hypot(a2p, b2)
    h1p = np.degrees(np.arctan2(b1, a1p)) % 360
    h2p = np.degrees(np.arctan2(b2, a2p)) % 360
    dLp, dCp = L2 - L1, C2p - C1p
    dh = h2p - h1p
    dh = np.where(C1p * C2p == 0, 0, np.where(dh > 180, dh - 360, np.where(dh < -180, dh + 360, dh)))
    dHp = 2 * np.sqrt(C1p * C2p) * np.sin(np.radians(dh / 2))
    Lbp, Cbp = (L1 + L2) / 2, (C1p + C2p) / 2
    hs = h1p + h2p
    hbp = np.where(C1p * C2p == 0, hs, np.where(np.abs(h1p - h2p) <= 180, hs / 2, np.where(hs < 360, (hs + 360) / 2, (hs - 360) / 2)))
    T = 1 - 0.17 * np.cos(np.radians(hbp - 30)) + 0.24 * np.cos(np.radians(2 * hbp)) + 0.32 * np.cos(np.radians(3 * hbp + 6)) - 0.20 * np.cos(np.radians(4 * hbp - 63))
    dtheta = 30 * np.exp(-(((hbp - 275) / 25) ** 2))
    Rc = 2 * np.sqrt(Cbp**7 / (Cbp**7 + 25.0**7))
    Sl = 1 + 0.015 * (Lbp - 50) ** 2 / np.sqrt(20 + (Lbp - 50) ** 2)
    Sc, Sh = 1 + 0.045 * Cbp, 1 + 0.015 * Cbp * T
    Rt = -np.sin(np.radians(2 * dtheta)) * Rc
    return np.sqrt((dLp / Sl) ** 2 + (dCp / Sc) ** 2 + (dHp / Sh) ** 2 + Rt * (dCp / Sc) * (dHp / Sh))


def test_ciede2000_against_sharma_table():
    """Pairs 1, 7 and 17 of Sharma, Wu and Dalal (2005), the formula's published test data."""
    assert abs(ciede2000([50, 2.6772, -79.7751], [50, 0, -82.7485]) - 2.0425) < 1e-4
    assert abs(ciede2000([50, 0, 0], [50, -1, 2]) - 2.3669) < 1e-4
    assert abs(ciede2000([50, 2.5, 0], [73, 25, -18]) - 27.1492) < 1e-4


def test_palette_separates_every_line_a_replay_can_show():
    names = ["mahony", "mahony-ekf", "ekf", "eskf", "ncs-eskf", "eq-kf", "cpf-ekf", "vqf", "imufusion",
             "autopilot", "truth", "reference"] + [f"autopilot:EKF{k} (EKF{k})" for k in range(1, 5)]
    colors = view.assign_colors(names)
    lab = srgb_to_lab(np.array([colors[n] for n in names]))
    d = ciede2000(lab[:, None], lab[None])
    np.fill_diagonal(d, np.inf)
    i, j = np.unravel_index(np.argmin(d), d.shape)
    assert d[i, j] > 19.0, (names[i], names[j], d[i, j])  # was 13.8 (ekf / imufusion)
    assert np.all((lab[:, 0] > 38) & (lab[:, 0] < 75))  # mid luminance: both themes


def _paths(result, tmp_path):
    """Every entity path the recording of ``result`` writes, and the blueprint's view filters."""
    logged = []

    class Rec:
        def log(self, path, *a, **k):
            logged.append(path.lstrip("/"))

        def send_columns(self, path, *a, **k):
            logged.append(path.lstrip("/"))

        def send_blueprint(self, bp, **k):
            logged.append(("blueprint", bp))

    view.log_replay(result, Rec())
    bp = next(x[1] for x in logged if isinstance(x, tuple))
    return [p for p in logged if isinstance(p, str)], bp


def _views(container):
    for c in container.contents:
        if hasattr(c, "origin"):
            yield c
        else:
            yield from _views(c)


def test_each_series_draws_under_its_own_root_and_every_view_lists_that_root(tmp_path):
    result = make_replay(duration=30.0)
    paths, bp = _paths(result, tmp_path)
    for name in ("mahony", "ncs-eskf", "autopilot", "truth"):
        root = view.series_root(name)
        mine = [p for p in paths if p.startswith(root + "/")]
        # its attitude lines, its error lines (the truth is the reference: none), its box
        assert {f"{root}/attitude/{a}" for a in AXES} <= set(mine), name
        assert f"{root}/box/body" in mine, name
        if name != "truth":
            assert {f"{root}/error/{a}" for a in AXES} <= set(mine), name
    # nothing of a series outside its subtree: the old per-plot trees are gone
    assert not [p for p in paths if p.split("/")[0] in ("attitude", "error", "world", "diagnostics")]
    # every view that draws part of a series also lists the series' root entity, so the
    # blueprint panel's "Hide in all views" on that root reaches each of them
    drawn = 0
    for v in _views(bp.root_container):
        rules = [str(r) for r in (getattr(v, "contents", None) or [])]
        for name in ("mahony", "ncs-eskf"):
            root = view.series_root(name)
            if any(r.startswith(f"+ /{root}/") for r in rules):
                drawn += 1
                assert f"+ /{root}" in rules, (v.name, rules)
    assert drawn >= 2 * (3 + 3 + 1 + 1)  # attitude, error, legend, 3D for each


def _tumbling(t, start):
    """Level flight, then upside down from ``start`` to the end (a crash the log records)."""
    roll = np.where(t < start, np.radians(10.0) * np.sin(t), np.radians(175.0))
    return quat.from_euler(roll, np.radians(5.0) * np.cos(t), np.zeros_like(t))


def test_an_upset_at_the_end_does_not_set_the_ranges():
    result = make_replay(duration=120.0, reference="autopilot", gps=False)
    t = result.reference.t
    result.reference = AttitudeSeries("ATT", t, _tumbling(t, t[0] + 100.0))
    a, b = view.open_span(result)
    assert b <= t[0] + 100.0 - view.UPSET_MARGIN_S + 1e-9 and b > t[0] + 90.0
    lo, hi = view.attitude_ranges(result, (a, b))["roll"]
    assert -20.0 < lo and hi < 20.0  # the flight's ±10°, not the ±180° of the tumble


def test_a_flip_is_not_an_upset():
    t = np.arange(0.0, 60.0, 0.02)
    roll = np.where((t > 30.0) & (t < 30.6), np.radians(360.0) * (t - 30.0) / 0.6, 0.0)
    q = quat.from_euler(roll, np.zeros_like(t), np.zeros_like(t))
    assert view.upset_start(t, q) is None
    q_end = quat.from_euler(np.where(t > 59.5, np.radians(120.0), 0.0), np.zeros_like(t), np.zeros_like(t))
    assert abs(view.upset_start(t, q_end) - t[t > 59.5][0]) < 1e-9  # tilted as the log ends


def test_error_range_from_the_spread_not_one_diverging_estimator():
    result = make_replay(duration=60.0)
    base = view.error_ranges(result.comparisons, (0.0, 1e9))
    c = result.comparisons["mahony"]
    c.error_deg = c.error_deg.copy()
    c.error_deg[c.scored.nonzero()[0][-50:], 0] = 170.0  # a tumble in the last second of one
    assert view.error_ranges(result.comparisons, (0.0, 1e9))["roll"] < 2 * base["roll"] + 1.0


def test_an_upset_before_take_off_leaves_the_flight_open():
    result = make_replay(duration=120.0, reference="autopilot", gps=False)
    t = result.reference.t
    on_side = (t > t[0] + 15.0) & (t < t[0] + 18.0)  # carried on its side, 3 s, then flown
    q = quat.from_euler(np.where(on_side, np.radians(90.0), np.radians(5.0) * np.sin(t)), np.zeros_like(t),
                        np.zeros_like(t))
    result.reference = AttitudeSeries("ATT", t, q)
    a, b = view.open_span(result)
    assert a == t[on_side][-1] + view.UPSET_MARGIN_S and b == view.scored_span(result)[1]


def test_a_log_that_ends_tumbling_opens_before_the_tumble():
    t = np.arange(0.0, 60.0, 0.1)
    burst = ((t > 56.5) & (t < 57.5)) | ((t > 58.0) & (t < 58.8))  # through 65° twice, level at the end
    q = quat.from_euler(np.where(burst, np.radians(100.0), 0.0), np.zeros_like(t), np.zeros_like(t))
    assert view.upset_runs(t, q) == [(t[burst][0], t[-1])]


def test_the_logs_modes_arming_and_lines_in_a_band_and_the_events_tab(tmp_path):
    from mavattitude.flight import LabelSeries
    from mavattitude.view.flightlog import MAX_NAMED_LINES, flight_events

    result = make_replay(duration=30.0)
    fl = result.flight
    fl.modes = LabelSeries("MODE", np.array([30.0, 40.0, 50.0]), np.array([0, 5, 0]), ["MANUAL", "LOITER", "MANUAL"])
    fl.arming = LabelSeries("EV", np.array([35.0, 55.0]), np.array([1, 0]), ["armed", "disarmed"])
    n = MAX_NAMED_LINES + 5
    fl.messages = LabelSeries("MSG+ERR", 30.0 + np.arange(n) * 0.5, np.array([3] + [6] * (n - 1)),
                              ["ERR: CRASH_CHECK 1"] + [f"line {i}" for i in range(1, n)])
    paths, bp = _paths(result, tmp_path)
    # one bar entity per mode (MANUAL's two spans share one), the armed bar, a dot per line up to the cap
    assert {p for p in paths if p.startswith("log/modes/")} == {"log/modes/00", "log/modes/01"}
    assert "log/armed" in paths
    assert len({p for p in paths if p.startswith("log/lines/")}) == MAX_NAMED_LINES + 1  # the rest share one
    band = [v for v in _views(bp.root_container) if str(v.name).startswith("the log's")]
    assert len(band) == 2 and all(any("/log/**" in str(r) for r in v.contents) for v in band)  # atop each column
    legend = next(v for v in _views(bp.root_container) if str(v.name) == "flight modes")
    assert any("/log/modes/**" in str(r) for r in legend.contents)
    events = flight_events(fl)
    assert [e.text for e in events[:3]] == ["mode MANUAL (log)", "mode LOITER (log)", "mode MANUAL (log)"]
    assert next(e for e in events if "CRASH_CHECK" in e.text).level == "error"


def test_no_band_without_the_logs_events(tmp_path):
    _, bp = _paths(make_replay(duration=30.0), tmp_path)
    assert not [v for v in _views(bp.root_container) if str(v.name).startswith(("the log's", "flight modes"))]


def test_accel_state_codes_as_named_spans():
    sent = {}

    class Rec:
        def log(self, path, entity, **k):
            sent.setdefault(path, {})["style"] = entity

        def send_columns(self, path, indexes, columns):
            sent.setdefault(path, {})["n"] = sum(len(c.as_arrow_array()) for c in columns)

    t = np.arange(0.0, 10.0, 0.01)  # 100 Hz
    codes = np.zeros(len(t), np.int8)
    codes[100:150] = 2  # one run
    codes[300:302] = 1
    codes[305:307] = 1  # two runs 0.03 s apart: one bar
    codes[800:810] = 1  # another bar
    view.log_state_spans(Rec(), "ncs-eskf", t, codes, ("used", "skipped", "down-weighted"))
    root = view.series_root("ncs-eskf")
    assert set(sent) == {f"{root}/diagnostics/accel_states/1", f"{root}/diagnostics/accel_states/2"}
    assert sent[f"{root}/diagnostics/accel_states/1"]["n"] == 2 * 3  # two bars, three points each
    assert sent[f"{root}/diagnostics/accel_states/2"]["n"] == 3


def test_state_labels_fit_a_legend():
    assert view.state_label(1, "skipped") == "1 skipped"
    label = view.state_label(4, "used the low-passed reading (the closer of the two; accel_tau)")
    assert label == "4 used the low-passed rea…" and len(label) == 26
