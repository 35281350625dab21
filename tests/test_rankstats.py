"""evaluate's rankings that say when they mean something (rankstats, evalreport): made-up records
with a known answer."""
from __future__ import annotations

import json

import pytest

from mavattitude.commands import evalreport as er
from mavattitude.scoring.rankstats import (against_baseline, bootstrap_median_interval, counted_wins, reference_family,
                                   sign_test_p)


def record(log, scores, algorithm="DCM", spread=None, **extra):
    """A record as evaluate writes it, its tilt score per estimator split evenly over roll and pitch."""
    return {"log": log, "status": "ok", "error": None, "facts": {}, "suspects": [],
            "metrics": {n: {"roll": {"mae": v}, "pitch": {"mae": v}, "yaw": {"mae": 1.0}} for n, v in scores.items()},
            "reference_stream": "ATT", "reference_algorithm": algorithm, "reference_spread_deg": spread, **extra}


def test_sign_test_exact():
    assert sign_test_p(10, 0) == pytest.approx(2 * 0.5 ** 10)
    assert sign_test_p(0, 10) == pytest.approx(2 * 0.5 ** 10)
    assert sign_test_p(5, 5) == 1.0 and sign_test_p(0, 0) == 1.0
    assert sign_test_p(8, 2) == pytest.approx(2 * (1 + 10 + 45) / 1024)  # P(X <= 2) of Binomial(10, 1/2), twice


def test_an_estimator_better_on_every_log():
    by_log = {f"log{i}": {"mahony": 2.0 + i, "ekf": 0.5 * (2.0 + i) * (1 + 0.01 * i)} for i in range(10)}
    v = against_baseline(by_log, "ekf", "mahony")
    assert v["logs"] == 10 and v["lower"] == 10 and v["higher"] == 0
    assert v["p"] == pytest.approx(2 * 0.5 ** 10, rel=1e-3)
    assert v["median_ratio"] == pytest.approx(0.5 * (1 + 0.045), abs=1e-3)  # the median of 0.5·(1 + 0.01 i)
    low, high = v["interval"]
    assert 0.5 <= low <= v["median_ratio"] <= high <= 0.5 * 1.09 + 1e-9


def test_identical_estimators_show_no_difference():
    by_log = {f"log{i}": {"mahony": 1.0 + i, "copy": 1.0 + i} for i in range(10)}
    v = against_baseline(by_log, "copy", "mahony")
    assert v["median_ratio"] == 1.0 and v["interval"] == [1.0, 1.0] and v["p"] == 1.0 and v["ties"] == 10


def test_bootstrap_interval_is_seeded_and_covers_the_median():
    values = [0.6, 0.7, 0.8, 0.85, 0.9, 1.0, 1.1, 1.2, 0.75, 0.95, 1.3]
    first, again = bootstrap_median_interval(values), bootstrap_median_interval(values)
    assert first == again  # the same records, the same interval
    assert first[0] < 0.9 < first[1] and first[0] >= 0.6 and first[1] <= 1.3


@pytest.mark.parametrize("algorithm, reference, family", [
    ("DCM", "autopilot", "DCM"), ("EKF1", "autopilot", "EKF"), ("EKF2 core 0", "autopilot", "EKF"),
    ("EKF3", "autopilot", "EKF"), ("EKF", "autopilot", "EKF"), ("PX4 EKF2", "autopilot", "EKF"),
    ("PX4 EKF2 instance 1", "autopilot", "EKF"), ("SITL", "autopilot", "truth"), ("DCM", "truth", "truth"),
    ("PX4 Q", "autopilot", "other"), ("unknown", "autopilot", "other"),
])
def test_reference_family(algorithm, reference, family):
    assert reference_family(algorithm, reference) == family


def test_wins_only_above_the_spread():
    by_log = {"a": {"mahony": 1.0, "ekf": 1.5},  # lead 0.5 > spread 0.3: mahony wins
              "b": {"mahony": 1.0, "ekf": 1.2},  # lead 0.2 < spread 0.3: nobody
              "c": {"mahony": 2.0, "ekf": 1.9},  # no spread: ekf, counted apart
              "d": {"mahony": 2.0, "ekf": 2.0}}  # no spread, no lead: nobody
    wins = counted_wins(by_log, {"a": 0.3, "b": 0.3, "c": None, "d": None}, ["mahony", "ekf"])
    assert wins["estimators"] == {"mahony": {"over_spread": 1, "no_spread": 0},
                                  "ekf": {"over_spread": 0, "no_spread": 1}}
    assert wins["within_spread"] == 1 and wins["logs_with_spread"] == 2 and wins["logs_without_spread"] == 2


def summary_of(records, names=("mahony", "cpf-ekf")):
    return er.summarize(records, list(names), "mahony", "autopilot")


def test_logs_grouped_by_reference_algorithm():
    records = ([record(f"dcm{i}", {"mahony": 1.0, "cpf-ekf": 1.5}, "DCM", 0.2) for i in range(3)]
               + [record(f"ekf{i}", {"mahony": 1.0, "cpf-ekf": 0.5}, alg, 0.2)
                  for i, alg in enumerate(["EKF3", "EKF2 core 0", "PX4 EKF2", "EKF1"])]
               + [{k: v for k, v in record("old", {"mahony": 1.0, "cpf-ekf": 0.9}).items()
                   if not k.startswith("reference_")}])  # a record from before the reference was named
    groups = summary_of(records)["by_reference"]
    assert list(groups) == ["all", "DCM", "EKF", "other"]
    assert [groups[g]["logs"] for g in groups] == [8, 3, 4, 1]
    assert groups["DCM"]["estimators"]["mahony"]["wins"]["over_spread"] == 3
    assert groups["EKF"]["estimators"]["cpf-ekf"]["wins"]["over_spread"] == 4
    assert groups["EKF"]["estimators"]["cpf-ekf"]["vs_baseline"]["median_ratio"] == 0.5
    assert groups["DCM"]["estimators"]["cpf-ekf"]["vs_baseline"]["median_ratio"] == 1.5
    assert groups["other"]["estimators"]["cpf-ekf"]["wins"] == {"over_spread": 0, "no_spread": 1}
    json.loads(er.summary_json(summary_of(records)))  # summary.json holds it


def test_the_report_says_what_the_data_supports_and_what_not():
    lower = [record(f"l{i}", {"mahony": 2.0, "cpf-ekf": 1.6 + 0.01 * i}, "EKF3", 0.1) for i in range(12)]
    mixed = [record(f"m{i}", {"mahony": 2.0, "cpf-ekf": 2.0 + (0.3 if i % 2 else -0.3)}, "DCM", 1.0)
             for i in range(10)]
    summary = summary_of(lower + mixed)
    text = er.report_markdown(summary, "mavattitude evaluate", None)
    assert "## Rankings per reference algorithm" in text and "### EKF-reference logs" in text
    ekf = summary["by_reference"]["EKF"]["plain"]
    assert ekf[0].startswith("cpf-ekf is lower than mahony on 12 of 12 logs, median ratio 0.83 [")
    assert f"p = {2 * 0.5 ** 12:.1e}" in ekf[0] and "lower than mahony on these logs (the interval excludes 1" in ekf[0]
    dcm = summary["by_reference"]["DCM"]["plain"]
    assert dcm[0].startswith("cpf-ekf is lower than mahony on 5 of 10 logs") and "p = 1.000" in dcm[0]
    assert dcm[0].endswith("the interval includes 1: no difference shown")
    # a 0.3° lead inside a 1° spread wins nothing, and the report says how wins are counted
    assert dcm[-1] == ("A win is counted where the best estimator leads the second best by more than the log's "
                       "reference spread (10 logs have one; on 10 of them the lead is inside it and nobody wins).")
    for line in ekf + dcm:
        assert f"- {line}" in text
    assert "EKF-reference logs (EKF1, EKF2, EKF3, PX4 EKF2) (12 logs):" in er.ranking_text(summary)


def test_few_logs_and_logs_without_a_spread_are_said_plainly():
    records = [record(f"x{i}", {"mahony": 2.0, "cpf-ekf": 1.0}, "DCM", None) for i in range(4)]
    plain = summary_of(records)["by_reference"]["all"]["plain"]
    assert plain[0].endswith("too few logs for the sign test to show anything (with 4 untied logs p cannot fall "
                             "below 0.05)")
    assert plain[-1].endswith("on the 4 logs with no reference spread (no other autopilot estimate) any lead > 0 "
                              "wins, counted apart.")


def test_a_shown_difference_inside_the_autopilots_spread_says_so():
    records = [record(f"s{i}", {"mahony": 2.0, "cpf-ekf": 1.95 - 0.001 * i}, "EKF3", 1.0) for i in range(10)]
    group = summary_of(records)["by_reference"]["EKF"]
    assert group["median_spread_deg"] == 1.0
    assert group["plain"][0].endswith("lower than mahony on these logs (the interval excludes 1, p < 0.05), by a "
                                      "median 0.05°, inside the autopilot's own spread on these logs (median 1.00°)")
    text = er.report_markdown(summary_of(records), "mavattitude evaluate", None)
    assert "### EKF-reference logs (EKF1, EKF2, EKF3, PX4 EKF2): 10 logs; the autopilot's own spread: median 1.00° " \
           "over 10 of them" in text
