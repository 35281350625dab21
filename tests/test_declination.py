"""The declination: the World Magnetic Model against IGRF (ppigrf, another model and another
implementation), on a real log whose autopilot computed it (COMPASS_AUTODEC=1), and the policy's
order on simulated logs, where it is said (info, the table, the JSON) and --home."""
from __future__ import annotations

import datetime
import json
import math

import numpy as np
import pytest

from conftest import SAMPLE_LOGS, shared_log
from mavattitude import declination as decl
from mavattitude.cli import main
from mavattitude.readers import read_log
from mavattitude.sim.world import EPOCH_UNIX_AT_BOOT, Home

UTC = datetime.timezone.utc
HOME = Home()  # where the simulator flies: 47.397742° N, 8.545594° E


def igrf_declination_deg(lat: float, lon: float, alt_m: float, when: datetime.datetime) -> float:
    """The oracle: IGRF's declination (ppigrf), degrees east."""
    ppigrf = pytest.importorskip("ppigrf", reason="ppigrf (the test extra) checks the declination")
    east, north, _ = ppigrf.igrf(lon, lat, alt_m / 1000.0, when.replace(tzinfo=None))
    return float(np.degrees(np.arctan2(east, north)).item())


@pytest.mark.parametrize("lat, lon, alt_m, when", [
    (-35.36, 149.17, 600.0, datetime.datetime(2012, 3, 1, tzinfo=UTC)),  # Canberra, WMM-2010
    (42.85, -2.69, 500.0, datetime.datetime(2014, 11, 6, tzinfo=UTC)),  # Vitoria, near zero
    (-38.01, -58.07, 10.0, datetime.datetime(2017, 6, 3, tzinfo=UTC)),  # South Atlantic anomaly, WMM-2015v2
    (63.42, 10.41, 50.0, datetime.datetime(2021, 4, 21, tzinfo=UTC)),  # Trondheim, WMM-2020
    (30.93, -104.04, 1500.0, datetime.datetime(2025, 3, 1, tzinfo=UTC)),  # West Texas, WMM-2025
    (61.2, -149.9, 40.0, datetime.datetime(2026, 11, 1, tzinfo=UTC)),  # Anchorage: large, east
])
def test_the_model_agrees_with_igrf(lat, lon, alt_m, when):
    ours = math.degrees(decl.model_declination(lat, lon, alt_m, when))
    assert ours == pytest.approx(igrf_declination_deg(lat, lon, alt_m, when), abs=0.5)


def _first_fix_by_pymavlink(path) -> tuple[float, float, float, datetime.datetime]:
    """The first GPS record with a 3D fix and 6 satellites, read by pymavlink, not our reader;
    its time from the GPS week and milliseconds (GWk/GMS, old logs Week/TimeMS), UTC."""
    from pymavlink import DFReader

    log = DFReader.DFReader_binary(str(path))
    while (m := log.recv_match(type="GPS")) is not None:
        if m.Status >= 3 and m.NSats >= 6:
            week, ms = (m.GWk, m.GMS) if hasattr(m, "GWk") else (m.Week, m.TimeMS)
            gps_epoch = datetime.datetime(1980, 1, 6, tzinfo=UTC)
            return m.Lat, m.Lng, m.Alt, gps_epoch + datetime.timedelta(weeks=week, milliseconds=ms)
    raise AssertionError(f"{path}: no 3D fix")


@pytest.mark.parametrize("name", ["copter-3.3-loiter-rtl.bin",  # ArduCopter 3.3, GPS Week/TimeMS
                                  "corpus/real-copter-4.5.7-pixhawk6x-mag-anomaly-quiver090.bin"])  # GWk/GMS
def test_a_real_log_that_computed_its_declination_gets_igrf_s_at_its_first_fix(name):
    """COMPASS_AUTODEC=1: the autopilot computed the declination at its first fix; so do we."""
    path = shared_log(name)
    flight = read_log(str(path))
    assert flight.params["COMPASS_AUTODEC"] == 1
    lat, lon, alt, when = _first_fix_by_pymavlink(path)
    assert flight.utc_s == pytest.approx(when.timestamp(), abs=30.0)  # the leap seconds apart
    chosen = decl.for_flight(flight)
    assert chosen.kind == "model"
    assert chosen.source.startswith("WMM-20") and f"at the first GPS fix {lat:.4f},{lon:.4f} on {when:%Y-%m-%d}" \
        in chosen.source and chosen.source.endswith("COMPASS_AUTODEC=1")
    assert chosen.deg == pytest.approx(igrf_declination_deg(lat, lon, alt, when), abs=0.5)


def test_each_reader_keeps_the_log_s_date():
    """.bin from the GPS week/ms, .tlog from SYSTEM_TIME (1 Hz): the simulator's boot epoch plus its clock."""
    for name in ("static.bin", "figure8.tlog"):
        flight = read_log(str(SAMPLE_LOGS / name))
        assert flight.utc_s == pytest.approx(EPOCH_UNIX_AT_BOOT + flight.gps.t[0], abs=1.0), name


def _static(**params):
    """The simulator's static.bin (COMPASS_DEC 5°, no COMPASS_AUTODEC, a fix at home on
    2024-06-01) with parameters changed (None: removed)."""
    flight = read_log(str(SAMPLE_LOGS / "static.bin"))
    for name, value in params.items():
        if value is None:
            flight.params.pop(name, None)
        else:
            flight.params[name] = value
    return flight


def test_the_order_of_the_sources_on_a_simulated_log():
    home = decl.Fix(-35.36, 149.17)
    at_home = decl.model_declination(HOME.lat_deg, HOME.lon_deg, HOME.alt_m, datetime.datetime(2024, 6, 1, tzinfo=UTC))
    fix_text = f"WMM-2020 at the first GPS fix {HOME.lat_deg:.4f},{HOME.lon_deg:.4f} on 2024-06-01"

    # 1. --declination wins over everything
    chosen = decl.for_flight(_static(COMPASS_AUTODEC=1), 10.0, home)
    assert (chosen.deg, chosen.source, chosen.kind) == (pytest.approx(10.0), "--declination", "option")
    # 2. a declination set by hand: the log's, --home or not
    chosen = decl.for_flight(_static())
    assert chosen.deg == pytest.approx(5.0, abs=1e-4)
    assert chosen.source == "log parameter COMPASS_DEC, no COMPASS_AUTODEC: set by hand"
    chosen = decl.for_flight(_static(COMPASS_AUTODEC=0), home=home)
    assert chosen.deg == pytest.approx(5.0, abs=1e-4)
    assert chosen.source == "log parameter COMPASS_DEC, COMPASS_AUTODEC=0: set by hand; --home not used"
    # 3. computed by the autopilot: the model, at --home, else at the first good fix
    chosen = decl.for_flight(_static(COMPASS_AUTODEC=1))
    assert chosen.rad == pytest.approx(at_home, abs=1e-4) and chosen.kind == "model"  # noon, not midnight
    assert chosen.source == fix_text + "; COMPASS_AUTODEC=1"
    chosen = decl.for_flight(_static(COMPASS_AUTODEC=1), home=home)
    assert chosen.source == "WMM-2020 at --home -35.3600,149.1700 on 2024-06-01; COMPASS_AUTODEC=1"
    assert chosen.deg == pytest.approx(igrf_declination_deg(-35.36, 149.17, 0.0, datetime.datetime(2024, 6, 1)),
                                       abs=0.5)
    assert decl.for_flight(_static(COMPASS_DEC=None)).source == fix_text  # no parameter at all
    # 4. computed by the autopilot, but nowhere to compute it at: the value it held
    flight = _static(COMPASS_AUTODEC=1)
    flight.gps = None
    chosen = decl.for_flight(flight)
    assert chosen.deg == pytest.approx(5.0, abs=1e-4) and chosen.kind == "held"
    assert chosen.source == ("log parameter COMPASS_DEC, COMPASS_AUTODEC=1 but no GPS fix and no --home: "
                             "the value the autopilot held")
    # 5. nothing: 0, not known
    flight = _static(COMPASS_DEC=None)
    flight.gps = None
    chosen = decl.for_flight(flight)
    assert (chosen.rad, chosen.source, chosen.known) == (0.0, "none (0)", False)


def test_a_fix_too_poor_to_place_the_vehicle_is_passed_over():
    flight = _static(COMPASS_AUTODEC=1)
    gps = flight.gps
    poor = slice(0, 10)
    gps.fix_type[poor], gps.lat_deg[poor] = 2, 10.0  # a 2D fix somewhere else first
    gps.num_sats[10:20], gps.lat_deg[10:20] = 4, 20.0  # then too few satellites
    fix = decl.first_good_fix(gps)
    assert (fix.lat_deg, fix.lon_deg) == (pytest.approx(gps.lat_deg[20]), pytest.approx(gps.lon_deg[20]))


def test_a_log_without_a_date_or_outside_the_models_says_so():
    flight = _static(COMPASS_AUTODEC=1)
    flight.utc_s = None
    chosen = decl.for_flight(flight)
    assert chosen.source.startswith("WMM-2025 at the first GPS fix")
    assert "date unknown: at the model's epoch 2025.0" in chosen.source
    old = decl.choose({}, decl.Fix(60.0, -150.0), datetime.datetime(2005, 1, 1, tzinfo=UTC))
    assert old.source.endswith("extrapolated outside its 2010-2015 span")
    assert old.deg == pytest.approx(igrf_declination_deg(60.0, -150.0, 0.0, datetime.datetime(2005, 1, 1)), abs=0.5)


def test_px4_s_automatic_declination_is_bit_0_of_ekf2_decl_type():
    fix, when = decl.Fix(47.4, 8.5), datetime.datetime(2019, 5, 13, tzinfo=UTC)
    looked_up = decl.choose({"EKF2_MAG_DECL": 9.0, "EKF2_DECL_TYPE": 7}, fix, when)
    assert looked_up.kind == "model" and looked_up.source.endswith("EKF2_DECL_TYPE=7")
    by_hand = decl.choose({"EKF2_MAG_DECL": 9.0, "EKF2_DECL_TYPE": 6}, fix, when)
    assert by_hand.deg == pytest.approx(9.0) and by_hand.source == "log parameter EKF2_MAG_DECL, EKF2_DECL_TYPE=6: set by hand"


def test_the_warning_for_no_declination_is_said_once_with_one_wording(tmp_path, capsys):
    from mavattitude.commands.replay import run_replay

    flight = _static(COMPASS_DEC=None)
    flight.gps = None
    result = run_replay(flight, ["mahony"])
    assert [e.text for e in result.events if e.level == "warn" and "declination" in e.text] == [decl.NO_DECLINATION]
    from mavattitude.commands.info import summarize
    assert summarize(flight)["warnings"].count(decl.NO_DECLINATION) == 1
    assert summarize(flight)["declination_deg"] is None


@pytest.mark.parametrize("value, wrong", [
    ("91,8", "latitude 91 is outside -90 to 90"),
    ("47,181", "longitude 181 is outside -180 to 180"),
    ("47", "expected LAT,LON in degrees"),
    ("47,8,1,2", "expected LAT,LON in degrees"),
    ("north,8", "expected numbers LAT,LON"),
    ("nan,8", "expected finite numbers"),
])
def test_a_bad_home_is_a_usage_error(capsys, value, wrong):
    code = main(["replay", str(SAMPLE_LOGS / "static.bin"), "--no-view", "--home", value])
    err = capsys.readouterr().err
    assert code == 2 and f"argument --home: {wrong}" in err and len(err.strip().splitlines()) == 1


def test_home_parses_with_and_without_altitude():
    assert decl.parse_home(" -35.36, 149.17 ") == decl.Fix(-35.36, 149.17, 0.0)
    assert decl.parse_home("-35.36,149.17,584") == decl.Fix(-35.36, 149.17, 584.0)


def test_info_and_replay_say_the_declination_and_its_source(tmp_path, capsys):
    from mavattitude.sim import simulate, write_log

    sim = simulate("static", 15.0, seed=5, imu_rate=50.0)
    sim.extra_params["COMPASS_AUTODEC"] = 1.0  # the autopilot computes it: COMPASS_DEC is ignored
    path = write_log(sim, tmp_path / "autodec.bin")
    assert main(["info", str(path), "--json", "-q"]) == 0
    info = json.loads(capsys.readouterr().out)
    when = datetime.datetime.fromtimestamp(EPOCH_UNIX_AT_BOOT + sim.gps.t[0], UTC)
    expected = math.degrees(decl.model_declination(HOME.lat_deg, HOME.lon_deg, HOME.alt_m, when))
    assert info["date_utc"].startswith("2024-06-01T12:00")
    assert info["declination_deg"] == pytest.approx(expected, abs=1e-3)
    assert info["declination_source"].startswith("WMM-2020 at the first GPS fix 47.3977,8.5456 on 2024-06-01")
    assert main(["info", str(path), "-q"]) == 0
    assert f"declination {expected:.2f}° (WMM-2020 at the first GPS fix" in capsys.readouterr().out
    assert main(["replay", str(path), "--no-view", "-q", "--warmup", "2", "--home", "-35.36,149.17",
                 "--json", str(tmp_path / "m.json")]) == 0
    out = capsys.readouterr().out
    assert "declination 1" in out and "(WMM-2020 at --home -35.3600,149.1700 on 2024-06-01" in out
    metrics = json.loads((tmp_path / "m.json").read_text())
    assert metrics["declination_deg"] == pytest.approx(igrf_declination_deg(-35.36, 149.17, 0.0, when), abs=0.5)
    assert metrics["declination_source"] == "WMM-2020 at --home -35.3600,149.1700 on 2024-06-01; COMPASS_AUTODEC=1"


@pytest.mark.slow  # a session stepped packet by packet
def test_a_live_session_uses_the_same_policy_and_says_when_a_fix_comes_later(tmp_path):
    from pymavlink import mavutil

    from mavattitude.live.estimation import LiveEstimation
    from mavattitude.sim import simulate, write_log

    sim = simulate("static", 20.0, seed=6, imu_rate=50.0)
    sim.extra_params["COMPASS_AUTODEC"] = 1.0
    path = write_log(sim, tmp_path / "autodec.tlog")

    def feed(est, no_fix_before_s=0.0):
        log = mavutil.mavlink_connection(str(path))
        n = 0
        while (msg := log.recv_msg()) is not None:
            if msg.get_type() == "GPS_RAW_INT" and msg.time_usec * 1e-6 < no_fix_before_s:
                msg.fix_type = 1
            est.add(msg)
            n += 1
            if n % 7 == 0:
                est.step()
        est.step(final=True)
        return [e.text for e in est.events if "declination" in e.text]

    texts = feed(LiveEstimation(["mahony"], expect_declination=True))
    # the vehicle's date (SYSTEM_TIME), as the replay of the recording takes it
    assert texts == ["declination 3.47° (WMM-2020 at the first GPS fix 47.3977,8.5456 on 2024-06-01; "
                     "COMPASS_AUTODEC=1)"]
    texts = feed(LiveEstimation(["mahony"], expect_declination=True), no_fix_before_s=12.0)
    assert texts[0] == ("declination 5.00° (vehicle parameter COMPASS_DEC, COMPASS_AUTODEC=1 but no GPS fix and "
                        "no --home: the value the autopilot held)")
    assert texts[1].startswith("GPS fix: the declination there is ") and "keeps its 5.00°" in texts[1]
    texts = feed(LiveEstimation(["mahony"], home=decl.Fix(-35.36, 149.17)), no_fix_before_s=12.0)
    assert "(WMM-20" in texts[0] and "at --home -35.3600,149.1700" in texts[0] and len(texts) == 1
