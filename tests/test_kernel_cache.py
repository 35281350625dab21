"""numba's cache is emptied of our kernels when any kernel source changed (kernel_cache); a first
compile says each estimator as it is done."""
from __future__ import annotations

from types import SimpleNamespace

import pytest

from mavattitude import kernel_cache
from mavattitude.estimators.mahony import mahony_run


def fake_kernel(cache_dir):
    """A kernel of estimators/mahony.py whose cache lives in ``cache_dir`` (a NUMBA_CACHE_DIR mirror)."""
    return SimpleNamespace(_cache=SimpleNamespace(_cache_path=str(cache_dir)), py_func=mahony_run.py_func)


def test_a_changed_source_empties_the_cache_once(tmp_path, monkeypatch):
    mirror = tmp_path / "mavattitude"
    (mirror / "estimators").mkdir(parents=True)
    kernel = fake_kernel(mirror / "estimators")
    assert kernel_cache.cache_root(kernel) == mirror
    old = [mirror / "estimators" / "eq_kf.eqkf_run-1.py311.nbi", mirror / "quaternion.rotate-2.py311.1.nbc"]
    for path in old:
        path.write_bytes(b"x")
    keep = mirror / "notes.txt"
    keep.write_text("not a kernel")
    assert kernel_cache.refresh(kernel)  # no stamp yet: whatever is there may be stale
    assert not any(p.exists() for p in old) and keep.exists()
    old[0].write_bytes(b"x")
    assert not kernel_cache.refresh(kernel) and old[0].exists()  # same sources: kept
    monkeypatch.setattr(kernel_cache, "sources_stamp", lambda: "changed")
    assert kernel_cache.refresh(kernel) and not old[0].exists()


def test_the_stamp_covers_the_inlined_helpers():
    """quaternion.py and estimators/consistency.py are compiled into other modules' kernels."""
    import hashlib

    stamp = kernel_cache.sources_stamp()
    assert len(stamp) == 40 and stamp == kernel_cache.sources_stamp()
    files = {str(p.relative_to(kernel_cache.PACKAGE)) for p in kernel_cache.PACKAGE.rglob("*.py")
             if kernel_cache.holds_kernels(p.read_bytes())}
    assert {"quaternion.py", "estimators/consistency.py", "estimators/mahony.py"} <= files
    assert hashlib.sha1(b"").hexdigest() != stamp


def test_a_first_compile_says_each_estimator_and_the_time_so_far(monkeypatch):
    """Processes that compile say when each estimator is done; what none took is compiled here,
    one by one; each is named on the progress line with its time (the compile itself faked)."""
    import io
    import subprocess
    import sys
    import time

    import mavattitude.core.warmup as est
    from mavattitude.progress import StepsLine

    compiled_here = []
    monkeypatch.setattr(est, "warm_up", lambda names: None)
    monkeypatch.setattr(est, "compile_kernels", lambda names: compiled_here.extend(names))
    now = time.time()
    worker = ("import sys, time; [print(n, float(sys.argv[1]) + 3.0 * k, flush=True) or time.sleep(0.05) "
              "for k, n in enumerate(sys.argv[2:], 1)]")
    processes = [subprocess.Popen([sys.executable, "-c", worker, str(now), *share], stdout=subprocess.PIPE)
                 for share in (["cpf-ekf"], ["ekf", "eskf"])]
    stream = io.StringIO()
    compiling = est.Compiling(processes, ["cpf-ekf", "ekf", "eskf", "mahony"], StepsLine("compiling", 0, stream=stream),
                              also=["log reader"])
    compiling.started = now
    compiling.done("log reader", now + 1.0)  # said by the caller, once its log is read
    compiling.done("the reader of another format")  # not counted: not said
    compiling.wait()
    lines = stream.getvalue().splitlines()
    assert lines[:2] == ["compiling: log reader done at 1 s (1/6)", "compiling: estimation core done at 0 s (2/6)"]
    # the processes' lines in whichever order they came, each with its own time
    assert sorted(line.rsplit(" (", 1)[0] for line in lines[2:5]) == [
        "compiling: cpf-ekf done at 3 s", "compiling: ekf done at 3 s", "compiling: eskf done at 6 s"]
    assert [line.rsplit(" (", 1)[1] for line in lines[2:5]] == ["3/6)", "4/6)", "5/6)"]
    assert lines[5].startswith("compiling: mahony done at ") and lines[5].endswith("(6/6)")
    assert lines[6].startswith("compiling: 6/6 done in ") and len(lines) == 7
    # the processes' estimators loaded here meanwhile (the compile faked: run here); mahony, which
    # no process had, compiled here after
    assert sorted(compiled_here[:3]) == ["cpf-ekf", "ekf", "eskf"] and compiled_here[3:] == ["mahony"]
    assert all(p.returncode == 0 for p in processes)


@pytest.mark.slow
def test_a_real_first_run_names_each_estimator_as_it_is_compiled(first_run):
    """An empty cache (its own NUMBA_CACHE_DIR): replay says what it compiles, then the log
    reader, each estimator and the estimation core as they are done, with the time, and the
    total. (The run: conftest's ``first_run``, whose cache test_contract loads again.)"""
    import re

    done, _ = first_run
    assert done.returncode == 0, done.stderr
    lines = done.stderr.splitlines()
    assert lines[0].startswith("compiling log reader, mahony, eskf (first run on this machine only")
    steps = [re.fullmatch(r"compiling \(first run only\): (\S.*) done at (\d+) s \((\d)/4\)", line) for line in lines[1:5]]
    assert all(steps), lines
    assert steps[0][1] == "log reader"  # as soon as the log is read
    assert sorted(m[1] for m in steps[1:]) == ["eskf", "estimation core", "mahony"]
    assert re.fullmatch(r"compiling \(first run only\): 4/4 done in \d+ s", lines[5])


def test_a_log_whose_reader_is_cached_needs_no_compile(tmp_path):
    from conftest import SAMPLE_LOGS
    from mavattitude.readers import read_log, reader_needs_compile

    for name in ("static.bin", "figure8.tlog"):
        read_log(str(SAMPLE_LOGS / name))  # compiles its reader if it must, and caches it
        assert not reader_needs_compile(str(SAMPLE_LOGS / name))
    (tmp_path / "notes.bin").write_text("not a log")
    assert not reader_needs_compile(str(tmp_path / "notes.bin")) and not reader_needs_compile(str(tmp_path / "none"))


def test_every_kernel_of_the_package_is_compiled_as_kernel_says():
    """Cached, and without numba's C-callable wrapper: a kernel decorated with numba's own njit
    would compile slower on a first run, or not be cached at all."""
    import importlib
    import pkgutil

    from numba.core.caching import NullCache
    from numba.core.registry import CPUDispatcher

    import mavattitude

    kernels = {}
    for info in pkgutil.walk_packages(mavattitude.__path__, "mavattitude."):
        if info.name.endswith("__main__") or ".view" in info.name or ".sim" in info.name:
            continue  # the command line itself; no kernels in the view or the simulator (Rerun's import is slow)
        module = importlib.import_module(info.name)
        for name, value in vars(module).items():
            if isinstance(value, CPUDispatcher) and value.py_func.__module__ == info.name:
                kernels[f"{info.name}.{name}"] = value
    assert len(kernels) > 100
    for name, dispatcher in kernels.items():
        assert dispatcher.targetoptions.get("no_cfunc_wrapper") is True, name
        assert not isinstance(dispatcher._cache, NullCache), name
