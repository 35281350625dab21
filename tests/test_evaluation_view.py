"""``evaluate --rrd``: one recording for a run, an entity per log, the scores per estimator."""
from __future__ import annotations

import pytest

from mavattitude.outputs import is_kind
from mavattitude.view.evaluation import LogRow, log_evaluation, log_line

from conftest import SAMPLE_LOGS, run


class Rec:
    def __init__(self):
        self.logged, self.columns, self.blueprint = {}, {}, None

    def log(self, path, entity, **k):
        self.logged.setdefault(path, []).append(entity)

    def send_columns(self, path, indexes, columns):
        self.columns[path] = [len(c.as_arrow_array()) for c in columns]

    def send_blueprint(self, bp, **k):
        self.blueprint = bp

    def set_time(self, *a, **k):
        pass


def test_an_entity_per_log_and_a_strip_per_estimator():
    rows = [LogRow("a/one.bin", "ok", {"mahony": 1.2, "ekf": 0.9}, command="mavattitude replay a/one.bin --rrd one.rrd"),
            LogRow("b/two.tlog", "not meaningful", {}, note="IMU at 4 Hz"),
            LogRow("c/three.ulg", "ok", {"mahony": 0.7}),
            LogRow("d/four.bin", "failed", note="no IMU data")]
    rec = Rec()
    log_evaluation(rec, rows, ["mahony", "ekf"], "# report")
    logs = sorted(p for p in rec.logged if p.startswith("logs/"))
    assert logs == ["logs/000_one.bin", "logs/001_two.tlog", "logs/002_three.ulg", "logs/003_four.bin"]
    assert rec.columns["est/mahony/tilt"] == [2] and rec.columns["est/ekf/tilt"] == [1]
    assert "report" in rec.logged and rec.blueprint is not None


def test_a_logs_line_says_its_scores_best_first_and_its_own_recording():
    line = log_line(3, LogRow("x/f.bin", "ok", {"mahony": 1.25, "cpf-ekf": 0.88}, command="mavattitude replay x/f.bin"))
    assert line == "#3 f.bin: ok · cpf-ekf 0.88 · mahony 1.25 | own recording: mavattitude replay x/f.bin"
    assert log_line(0, LogRow("g.bin", "failed", note="no IMU")) == "#0 g.bin: failed (no IMU)"


@pytest.mark.slow
def test_evaluate_writes_the_recording(capsys, tmp_path):
    rrd = tmp_path / "run.rrd"
    code, out, err = run(capsys, "evaluate", SAMPLE_LOGS / "figure8.bin", SAMPLE_LOGS / "hover.tlog",
                         "--estimators", "mahony", "--reference", "truth", "-j", "1", "--out", tmp_path / "ev",
                         "--rrd", rrd, "-q")
    assert code == 0, err
    assert is_kind(rrd, "rrd") and f"the recording {rrd}" in out
