"""mavattitude evaluate: the same numbers as replay, resume, failing logs, the summary's
arithmetic, the outputs, and the Dask path on loopback."""
from __future__ import annotations

import csv
import json
import shutil
import signal
import subprocess
import sys
import time
import xml.etree.ElementTree as ET
from pathlib import Path

import pytest

from conftest import SAMPLE_LOGS, SHARED_LOGS, kernel_interrupt, process_group
from mavattitude.commands import evalreport as er
from mavattitude.cli import main
from mavattitude.commands.evaluate import find_logs, record_name

ESTIMATORS = "mahony,ncs-eskf"


@pytest.fixture
def logs(tmp_path):
    """Two sample logs in a folder of their own."""
    folder = tmp_path / "logs"
    folder.mkdir()
    for name in ("figure8.tlog", "static.bin"):
        shutil.copy(SAMPLE_LOGS / name, folder / name)
    return folder


def evaluate(*args) -> int:
    return main(["evaluate", *map(str, args)])


def records(out: Path) -> dict[str, dict]:
    return {Path(r["log"]).name: r for r in (json.loads(p.read_text()) for p in (out / "logs").glob("*.json"))}


def test_each_log_scores_as_replay_does(logs, tmp_path):
    out = tmp_path / "eval"
    assert evaluate(logs, "--estimators", ESTIMATORS, "--out", out, "-j", "1") == 0
    got = records(out)
    assert set(got) == {"figure8.tlog", "static.bin"}
    for name, record in got.items():
        assert record["status"] == "ok", record
        assert main(["replay", str(logs / name), "--estimators", ESTIMATORS, "--no-view",
                     "--json", str(tmp_path / f"{name}.json")]) == 0
        replayed = json.loads((tmp_path / f"{name}.json").read_text())
        assert record["metrics"] == replayed["estimators"]


def test_outputs_are_complete_and_well_formed(logs, tmp_path, capsys):
    out = tmp_path / "eval"
    assert evaluate(logs, "--estimators", ESTIMATORS, "--out", out, "-j", "1") == 0
    assert "ncs-eskf" in capsys.readouterr().out  # the ranking on the terminal
    rows = list(csv.DictReader((out / "results.csv").open()))
    assert len(rows) == 2 * 2 * 3  # logs × estimators × axes
    assert {r["axis"] for r in rows} == {"roll", "pitch", "yaw"}
    assert all(float(r["mae"]) >= 0 for r in rows if r["mae"])
    assert {r["format"] for r in rows} == {"bin", "tlog"}
    assert all(r["imu_source"] and float(r["imu_rate_hz"]) > 0 and float(r["duration_s"]) > 0 for r in rows)
    assert all(float(r["declination_deg"]) == pytest.approx(5.0)  # the simulator's COMPASS_DEC
               and r["declination_source"].startswith("log parameter COMPASS_DEC") for r in rows)
    summary = json.loads((out / "summary.json").read_text())
    assert set(summary["estimators"]) == {"mahony", "ncs-eskf"}
    assert summary["estimators"]["mahony"]["ratio_to_baseline_geomean"] == 1.0
    report = (out / "report.md").read_text()
    assert report.startswith("# Attitude estimators across logs") and "| ncs-eskf |" in report
    svg = ET.parse(out / "tilt_error.svg").getroot()
    assert svg.tag.endswith("svg")
    assert len([e for e in svg.iter() if e.tag.endswith("circle")]) == 2 * 2  # a dot per log and estimator
    if er.has_parquet():
        import pyarrow.parquet as pq
        assert pq.read_table(out / "results.parquet").num_rows == len(rows)


def test_a_stopped_run_resumes_and_force_redoes(logs, tmp_path, capsys):
    out = tmp_path / "eval"
    assert evaluate(logs / "static.bin", "--estimators", ESTIMATORS, "--out", out, "-j", "1") == 0
    first = (out / "logs" / record_name(str(logs / "static.bin"))).stat().st_mtime_ns
    capsys.readouterr()
    # the same options and one more log: only the new one is replayed
    assert evaluate(logs, "--estimators", ESTIMATORS, "--out", out, "-j", "1") == 0
    err = capsys.readouterr().err
    assert "static.bin: already done" in err and "figure8.tlog: ok" in err
    assert (out / "logs" / record_name(str(logs / "static.bin"))).stat().st_mtime_ns == first
    # other options: redone (a record is only reused for what it was computed with)
    assert evaluate(logs, "--estimators", "mahony", "--out", out, "-j", "1") == 0
    assert "already done" not in capsys.readouterr().err
    assert evaluate(logs, "--estimators", "mahony", "--out", out, "-j", "1", "--force") == 0
    assert "already done" not in capsys.readouterr().err


def test_a_failing_log_is_listed_and_the_run_goes_on(logs, tmp_path, capsys):
    bad = logs / "broken.bin"
    bad.write_bytes(b"\xa3\x95\x80" + bytes(200))  # a DataFlash header and nothing readable
    out = tmp_path / "eval"
    assert evaluate(logs, "--estimators", "mahony", "--out", out, "-j", "2") == 0
    assert "broken.bin" in capsys.readouterr().err
    summary = json.loads((out / "summary.json").read_text())
    assert [f["log"] for f in summary["failed"]] == [str(Path(find_logs([str(bad)])[0]))]
    assert summary["scored"] == 2
    assert "## Failed" in (out / "report.md").read_text()
    rows = list(csv.DictReader((out / "results.csv").open()))
    assert [r["status"] for r in rows if r["log"].endswith("broken.bin")] == ["failed"]


def test_folders_are_searched_by_content(logs, tmp_path):
    (logs / "sub").mkdir()
    shutil.copy(SAMPLE_LOGS / "static.bin", logs / "sub" / "UPPER.BIN")
    (logs / "firmware.bin").write_bytes(b"\x00" * 100)  # a .bin that is no log
    (logs / "notes.txt").write_text("not a log")
    found = [Path(p).name for p in find_logs([str(logs)])]
    assert sorted(found) == ["UPPER.BIN", "figure8.tlog", "static.bin"]
    assert [Path(p).name for p in find_logs([str(logs / "*.tlog")])] == ["figure8.tlog"]
    # each log once, however often it is named
    assert len(find_logs([str(logs), str(logs / "static.bin")])) == 3


def test_bad_command_lines(logs, tmp_path, capsys):
    empty = tmp_path / "empty"
    empty.mkdir()
    assert evaluate(empty, "--out", tmp_path / "e") == 1
    assert evaluate(tmp_path / "missing", "--out", tmp_path / "e") == 1
    assert evaluate(tmp_path / "*.nothing", "--out", tmp_path / "e") == 1
    assert evaluate(logs, "--baseline", "nope", "--out", tmp_path / "e") == 2
    assert evaluate(logs, "--ship-logs", "--out", tmp_path / "e") == 2
    assert evaluate(logs, "-j", "0", "--out", tmp_path / "e") == 2
    err = capsys.readouterr().err
    assert "Traceback" not in err


def test_summary_arithmetic():
    def rec(log, **tilt):
        return {"log": log, "status": "ok", "error": None, "facts": {},
                "metrics": {n: {"roll": {"mae": v}, "pitch": {"mae": v}} for n, v in tilt.items()}}

    records = [rec("a", **{"mahony": 2.0, "ekf": 1.0, "eskf": 0.5, "ncs-eskf": 0.4}),
               rec("b", **{"mahony": 1.0, "ekf": 3.0, "eskf": 2.0, "ncs-eskf": 1.0}),
               rec("c", **{"mahony": 4.0, "ekf": 2.0, "eskf": 8.0, "ncs-eskf": 1.0}),
               {"log": "d", "status": "failed", "error": "d: broken", "facts": {}, "metrics": {}}]
    s = er.summarize(records, ["mahony", "ekf", "eskf", "ncs-eskf"], "mahony", "autopilot")
    e = s["estimators"]
    assert e["ekf"]["median"] == 2.0 and e["ekf"]["mean"] == 2.0
    assert e["ekf"]["ratio_to_baseline_geomean"] == round((0.5 * 3.0 * 0.5) ** (1 / 3), 3)
    assert e["ekf"]["logs_at_most_0.8x_baseline"] == 2 and e["ekf"]["logs_over_2x_baseline"] == 1
    assert e["ncs-eskf"]["wins"] == 3 and e["mahony"]["wins"] == 1  # b: a tie for best, both win
    assert e["ncs-eskf"]["mean_rank"] == round((1 + 1.5 + 1) / 3, 3)
    assert e["mahony"]["mean_rank"] == round((4 + 1.5 + 3) / 3, 3)
    assert e["eskf"]["worst_logs"][0] == {"log": "c", "score": 8.0}
    assert s["failed"] == [{"log": "d", "error": "d: broken"}] and s["scored"] == 3
    chain = s["paper_001_ranking"]
    assert chain["logs"] == 3
    assert chain["steps"] == {"ncs-eskf < eskf": 3, "eskf < ekf": 2, "ekf < mahony": 2}
    assert chain["whole_chain"] == 1  # only log a


def test_the_report_lists_spans_not_scored_and_notes_on_a_whole_log():
    def rec(log, suspects=(), notes=()):
        return {"log": log, "status": "ok", "error": None, "facts": {}, "suspects": list(suspects),
                "reference_notes": list(notes), "metrics": {"mahony": {"roll": {"mae": 1.0}, "pitch": {"mae": 1.0}}}}

    span = {"kind": "tilt jump", "start_s": 40.0, "end_s": 45.25, "detail": "ATT's tilt jumped 60°"}
    note = {"kind": "repeated times", "detail": "ATT timestamps repeat 2,442 times; the repeats were dropped"}
    s = er.summarize([rec("a", [span]), rec("b", notes=[note]), rec("c")], ["mahony"], "mahony", "autopilot")
    assert s["reference_suspect"] == [{"log": "a", "spans": [span], "notes": []},
                                      {"log": "b", "spans": [], "notes": [note]}]
    text = er.report_markdown(s, "mavattitude evaluate", "tilt_error.svg")
    assert "- `a`: 40.0-45.2 s: ATT's tilt jumped 60°\n" in text
    assert "- `b`: whole log: ATT timestamps repeat 2,442 times; the repeats were dropped\n" in text


@pytest.mark.slow
def test_dask_cluster_on_loopback_gives_the_local_numbers(logs, tmp_path):
    distributed = pytest.importorskip("distributed")
    local = tmp_path / "local"
    assert evaluate(logs, "--estimators", ESTIMATORS, "--out", local, "-j", "1") == 0
    with distributed.LocalCluster(n_workers=1, threads_per_worker=1, processes=True,
                                  host="127.0.0.1", dashboard_address=":0") as cluster:
        for extra, out in (((), tmp_path / "dask"), (("--ship-logs",), tmp_path / "shipped")):
            assert evaluate(logs, "--estimators", ESTIMATORS, "--out", out,
                            "--scheduler", cluster.scheduler_address, *extra) == 0
            got, want = records(out), records(local)
            assert {k: v["metrics"] for k, v in got.items()} == {k: v["metrics"] for k, v in want.items()}
            assert (out / "summary.json").read_text() == (local / "summary.json").read_text()


def test_no_scheduler_answering_is_one_line(logs, tmp_path, capsys):
    pytest.importorskip("distributed")
    assert evaluate(logs, "--out", tmp_path / "e", "--scheduler", "tcp://127.0.0.1:9") == 1
    err = capsys.readouterr().err
    assert "Traceback" not in err and "127.0.0.1:9" in err


@pytest.mark.slow
def test_shared_logs_all_estimators(tmp_path):
    if not SHARED_LOGS.is_dir():
        pytest.skip(f"real logs not found at {SHARED_LOGS} (they live beside the project, not in it)")
    out = tmp_path / "eval"
    assert evaluate(SHARED_LOGS, "--estimators", "all", "--out", out) == 0
    summary = json.loads((out / "summary.json").read_text())
    assert summary["failed"] == [] and summary["scored"] + len(summary["not_meaningful"]) == summary["logs"] >= 31
    # the telemetry logs whose IMU arrives at 1 and 4 Hz are left out of the ranking
    assert sorted(Path(n["log"]).name for n in summary["not_meaningful"]) == [
        "copter-4.1-flight.tlog", "sitl-quadplane-vtol.tlog"]
    # every log has scores but those no longer than the warm-up (the 6 s PX4 ULog on the ground) and
    # those whose ATT (DCM) is far from their EKF1 all along: the 88° log, the plane roverfolder log (50°)
    got = records(out)
    short = [r for r in got.values() if r["facts"]["duration_s"] <= 10.0]
    disowned = [name for name, r in got.items()
                if any(s["kind"] == "autopilot disagrees" for s in r["suspects"])
                and all(er.tilt_score(m) is None for m in r["metrics"].values())]
    assert sorted(disowned) == ["real-copter-3.3dev-erlepxf-dcm-long-erle-20140923-51.bin",
                                "real-plane-3.0.4b3-erlepxf-dcm-erle-roverfolder-20140802-10.bin"]
    assert summary["paper_001_ranking"]["logs"] == summary["scored"] - len(short) - len(disowned)


# ---------------------------------------------------------------- stop signals


def test_an_interrupt_inside_a_kernel_is_never_a_logs_result(logs, tmp_path, capsys, monkeypatch):
    from mavattitude.commands import evaluate as ev

    monkeypatch.setattr(ev, "_replay", kernel_interrupt)
    with pytest.raises(KeyboardInterrupt):
        ev.evaluate_log(str(logs / "static.bin"), None)
    out = tmp_path / "eval"
    assert evaluate(logs, "--estimators", "mahony", "--out", out, "-j", "1") == 130
    assert capsys.readouterr().err.strip().splitlines()[-1] == "interrupted"
    assert list((out / "logs").iterdir()) == []  # nothing saved for the log


def test_an_internal_error_is_tried_again_on_resume(logs, tmp_path, capsys, monkeypatch):
    from mavattitude.commands import evaluate as ev

    replay = ev._replay

    def bug_on_static(local, path, *args, **kwargs):
        if path.endswith("static.bin"):
            raise RuntimeError("a bug")
        return replay(local, path, *args, **kwargs)
    monkeypatch.setattr(ev, "_replay", bug_on_static)
    out = tmp_path / "eval"
    evaluate(logs, "--estimators", "mahony", "--out", out, "-j", "1")
    assert "internal error (RuntimeError: a bug)" in records(out)["static.bin"]["error"]
    capsys.readouterr()
    monkeypatch.setattr(ev, "_replay", replay)  # the bug fixed, or an interrupt an older version took for one
    assert evaluate(logs, "--estimators", "mahony", "--out", out, "-j", "1") == 0
    err = capsys.readouterr().err
    assert "static.bin: ok" in err and "figure8.tlog: already done" in err
    assert records(out)["static.bin"]["status"] == "ok"


@pytest.mark.slow
@pytest.mark.skipif(not Path("/proc/self/stat").exists(), reason="needs Linux's /proc")
@pytest.mark.parametrize("signum, code", [("SIGTERM", 143), ("SIGINT", 130), ("SIGKILL", -9)])
def test_a_stopped_evaluate_leaves_no_worker_and_no_temporary_file(tmp_path, signum, code):
    """Sent to the parent alone (a service manager, kill), not the whole group as a terminal's
    Ctrl-C is: the workers end too, replaying nothing for nobody; even when the parent is
    killed outright, they notice within a second."""
    if not (SHARED_LOGS / "sitl-copter-4.7-400hz.bin").exists():
        pytest.skip(f"real logs not found at {SHARED_LOGS}")
    logs = [SHARED_LOGS / "sitl-copter-4.7-400hz.bin", *sorted(SHARED_LOGS.glob("*.tlog"))]
    out = tmp_path / "eval"
    proc = subprocess.Popen([sys.executable, "-m", "mavattitude", "evaluate", *map(str, logs), "--estimators", "all",
                             "-j", "2", "--out", str(out)], cwd=tmp_path, text=True, start_new_session=True,
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE)
    deadline = time.monotonic() + 120
    while len(process_group(proc.pid)) < 3:  # the parent and its two workers
        assert proc.poll() is None and time.monotonic() < deadline, proc.communicate()
        time.sleep(0.1)
    time.sleep(2.0)  # replaying
    proc.send_signal(getattr(signal, signum))
    _, err = proc.communicate(timeout=60)
    assert proc.returncode == code, err
    if code > 0:
        assert "Traceback" not in err and err.strip().splitlines()[-1].split()[0] in ("interrupted", "terminated")
        assert not [p.name for p in out.rglob(".*")]  # no .partial output
    deadline = time.monotonic() + 5.0  # not after their logs
    while process_group(proc.pid) and time.monotonic() < deadline:
        time.sleep(0.1)
    assert process_group(proc.pid) == []
