"""Shared fixtures: the real logs in ../shared/logs (skipped where absent) and simulated flights."""
from __future__ import annotations

import math
import shutil
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
SHARED_LOGS = ROOT.parent / "shared" / "logs"
SAMPLE_LOGS = ROOT / "sample_logs"
# the rerun-sdk's CLI beside this Python (a venv not activated has it off the PATH), else the PATH's; None: neither
RERUN_CLI = next((str(p) for p in [Path(sys.executable).with_name("rerun")] if p.exists()), shutil.which("rerun"))


def installed_estimators() -> list[str]:
    """Every registered estimator whose package is installed (vqf and imufusion are optional)."""
    from mavattitude.estimators import ESTIMATORS, available
    return [name for name in ESTIMATORS if not available(name)]


def estimator_params() -> list:
    """Every registered estimator as a test parameter, skipped with the pip command where its
    package is not installed."""
    from mavattitude.estimators import ESTIMATORS, available
    return [pytest.param(name, marks=pytest.mark.skipif(bool(available(name)), reason=available(name) or ""))
            for name in ESTIMATORS]


def shared_log_paths() -> list[Path]:
    if not SHARED_LOGS.is_dir():
        return []
    return sorted(p for p in SHARED_LOGS.iterdir() if p.suffix in (".bin", ".tlog"))


def shared_log_params(corpus: bool = False, suffix: str | None = None, slow_above_mb: float = math.inf):
    """pytest params for every shared log (``corpus``: its corpus/ folder too; ``suffix``: of
    one kind); one skipped param when the folder is absent. Logs larger than ``slow_above_mb``
    are marked slow."""
    paths = shared_log_paths()
    if corpus and paths:
        paths += sorted(p for p in (SHARED_LOGS / "corpus").iterdir() if p.suffix in (".bin", ".tlog"))
    paths = [p for p in paths if suffix in (None, p.suffix)]
    if not paths:
        return [pytest.param(None, marks=pytest.mark.skip(
            reason=f"real logs not found at {SHARED_LOGS} (they live beside the project, not in it)"))]
    return [pytest.param(p, id=p.name, marks=[pytest.mark.slow] if p.stat().st_size > slow_above_mb * 1e6 else [])
            for p in paths]


def shared_log(name: str) -> Path:
    path = SHARED_LOGS / name
    if not path.exists():
        pytest.skip(f"real log {name} not found in {SHARED_LOGS}")
    return path


def kernel_interrupt(*args, **kwargs):
    """Raise what numba's dispatcher returns when a Ctrl-C is handled while it calls a kernel: a
    SystemError caused by the KeyboardInterrupt (a stand-in for replay_flight and the like)."""
    try:
        raise KeyboardInterrupt
    except KeyboardInterrupt as exc:
        raise SystemError("CPUDispatcher(<function mahony_run>) returned a result with an exception set") from exc


def process_group(pgid: int) -> list[int]:
    """The live processes of a process group (Linux's /proc)."""
    pids = []
    for entry in Path("/proc").iterdir():
        try:
            fields = (entry / "stat").read_text().rsplit(")", 1)[1].split()
        except (OSError, IndexError):
            continue
        if int(fields[2]) == pgid and fields[0] != "Z":
            pids.append(int(entry.name))
    return pids


def run(capsys, *args):
    """The command in this process: (exit status, stdout, stderr)."""
    from mavattitude.cli import main

    code = main([str(a) for a in args])
    out, err = capsys.readouterr()
    return code, out, err


def one_line(err: str) -> str:
    """The one line a problem is told in (no traceback, nothing else)."""
    lines = err.strip().splitlines()
    assert len(lines) == 1 and "Traceback" not in err, err
    return lines[0]


_flights = {}


def read_shared(name: str):
    """A shared log, read once per test session."""
    from mavattitude.readers import read_log

    if name not in _flights:
        _flights[name] = read_log(str(shared_log(name)))
    return _flights[name]


@pytest.fixture(scope="session")
def sim_logs(tmp_path_factory):
    """Small simulated logs with known truth, written once per session: {name: (SimFlight, path)}."""
    from mavattitude.sim import simulate, write_log

    out = tmp_path_factory.mktemp("sim")
    logs = {}
    for scenario, duration, suffix, rate in [("static", 40.0, ".bin", 100.0),
                                             ("figure8", 90.0, ".tlog", 50.0),
                                             ("figure8", 90.0, ".bin", 100.0)]:
        sim = simulate(scenario, duration, seed=3, imu_rate=rate)
        name = f"{scenario}{suffix}"
        logs[name] = (sim, write_log(sim, out / name))
    return logs


@pytest.fixture(scope="session")
def first_run(tmp_path_factory):
    """``replay`` of static.bin with mahony and eskf on an empty kernel cache (a NUMBA_CACHE_DIR
    of its own), run once for the tests of a first run and of the cache it leaves: (the
    finished process, that cache folder). A test that runs more in it works on a copy."""
    import os
    import subprocess
    import sys

    cache = tmp_path_factory.mktemp("cold-cache")
    done = subprocess.run([sys.executable, "-m", "mavattitude", "replay", str(SAMPLE_LOGS / "static.bin"),
                           "--estimators", "mahony,eskf", "--no-view"], env=dict(os.environ, NUMBA_CACHE_DIR=str(cache)),
                          cwd=cache.parent, capture_output=True, text=True, timeout=600)
    return done, cache
