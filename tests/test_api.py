"""The Python API: every snippet of the README's "Use from Python" runs, and does what it says;
estimator plugins from the entry point group reach the command."""
from __future__ import annotations

import re
from importlib.metadata import EntryPoint
from pathlib import Path

import numpy as np
import pytest

import mavattitude
from mavattitude.cli import main
from mavattitude.estimators import ESTIMATORS, create

ROOT = Path(__file__).resolve().parents[1]


def readme_snippets() -> list[str]:
    text = (ROOT / "README.md").read_text()
    section = text.split("## Use from Python", 1)[1].split("\n## ", 1)[0]
    return re.findall(r"```python\n(.*?)```", section, re.S)


@pytest.fixture
def scratch(tmp_path, monkeypatch):
    """A working folder with the sample logs in reach, and the estimator registry restored."""
    (tmp_path / "sample_logs").symlink_to(ROOT / "sample_logs")
    monkeypatch.chdir(tmp_path)
    before = dict(ESTIMATORS)
    yield tmp_path
    ESTIMATORS.clear()
    ESTIMATORS.update(before)


def test_the_readme_snippets_run(scratch):
    snippets = readme_snippets()
    assert len(snippets) == 3
    namespace: dict = {}
    for code in snippets:
        exec(compile(code, "README.md", "exec"), namespace)
    assert (scratch / "out" / "metrics.json").read_text().startswith("{")
    assert (scratch / "out" / "csv" / "ekf.csv").exists() and (scratch / "out" / "figure8.rrd").exists()
    assert namespace["q"].shape == (1000, 4) and np.allclose(namespace["q"][-1], [1, 0, 0, 0], atol=1e-9)
    scored = namespace["baseline"].metrics["estimators"]
    assert set(scored) == {"gyro-only", "mahony", "autopilot"} and all(0 < row["roll"]["mae"] < 10 for row in scored.values())


def test_replay_takes_a_path_or_a_flight_and_checks_parameters():
    a = mavattitude.replay(ROOT / "sample_logs" / "static.bin")
    b = mavattitude.replay(mavattitude.load(ROOT / "sample_logs" / "static.bin"))
    np.testing.assert_array_equal(a.estimates["mahony"].q, b.estimates["mahony"].q)
    assert a.metrics == b.metrics
    with pytest.raises(Exception, match="outside its valid range"):
        mavattitude.replay(ROOT / "sample_logs" / "static.bin", params={"mahony": {"kp": -1}})
    with pytest.raises(Exception, match="outside its valid range"):
        create("ekf", r_accel=0.0)
    with pytest.raises(KeyError, match="unknown estimator"):
        create("nope")


def test_an_estimator_plugin_reaches_the_command(scratch, monkeypatch, capsys):
    snippet = readme_snippets()[2].split("\n\nbaseline =")[0]  # the class, not its use
    (scratch / "my_plugin.py").write_text("import numpy as np\n" + snippet.replace("@register\n", ""))
    monkeypatch.syspath_prepend(str(scratch))
    point = EntryPoint("gyro-only", "my_plugin:GyroOnly", "mavattitude.estimators")
    broken = EntryPoint("broken", "no_such_module:Nothing", "mavattitude.estimators")
    monkeypatch.setattr("importlib.metadata.entry_points",
                        lambda group=None: [point, broken] if group == "mavattitude.estimators" else [])
    code = main(["replay", "sample_logs/static.bin", "--estimators", "gyro-only,mahony", "--no-view"])
    out, err = capsys.readouterr()
    assert code == 0 and "gyro-only" in out
    assert "estimator plugin broken" in err  # one line, and the command goes on
    assert main(["estimators"]) == 0 and "gyro-only: Gyro integration alone" in capsys.readouterr().out


def test_replay_takes_the_logs_own_defaults_as_the_command_does(tmp_path):
    """A plane's cruise airspeed reaches eq-kf from the API as from `replay` (params.log_defaults)."""
    from conftest import shared_log

    log = shared_log("plane-3.1-flight-329.bin")
    assert main(["replay", str(log), "--estimators", "eq-kf", "--no-view", "--json", str(tmp_path / "m.json")]) == 0
    import json
    cli = json.loads((tmp_path / "m.json").read_text())["estimators"]
    api = mavattitude.replay(log, estimators=["eq-kf"]).metrics["estimators"]
    assert api == cli
    assert api["eq-kf"]["params"]["airspeed"] > 0
