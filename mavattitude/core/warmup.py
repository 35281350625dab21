"""Numba kernels compiled before they are needed: in other processes while a log is read
(``precompile``, a first run's 33 s of compiling shared out between cores), and here, over
synthetic samples, before a live link's first samples arrive (``warm_up``).

Above the estimators and the estimation core (it runs both); the registry
(``estimators/__init__.py``) says only which estimators need compiling (``needs_compile``).
"""
from __future__ import annotations

import os
import signal
import sys
import threading
import time
from contextlib import contextmanager

from ..estimators import create, needs_compile

# Seconds each estimator's kernels take to compile the first time (measured here, one core,
# with ``warm_up``), to share the work out fairly between processes.
COMPILE_SECONDS = {"mahony": 2.0, "mahony-ekf": 4.0, "ekf": 4.0, "eskf": 2.5, "ncs-eskf": 5.0, "eq-kf": 4.5,
                   "cpf-ekf": 9.5}


@contextmanager
def _noticing_interrupts():
    """A Ctrl-C while numba compiles can land in one of LLVM's callbacks, where Python can only
    report it ("Exception ignored", a traceback) and numba goes on compiling: take it quietly,
    and raise it once the compile is over (in the main thread; others get no signals)."""
    seen: list = []  # yielded: a body that goes on compiling can stop early
    if threading.current_thread() is not threading.main_thread():
        yield seen
        return

    def handler(signum, frame):
        seen.append(signum)
        if callable(previous):
            previous(signum, frame)  # the program's own handling (the command's: see signals.py)
        else:
            raise KeyboardInterrupt

    def unraisable(report):
        if isinstance(report.exc_value, KeyboardInterrupt):
            seen.append(report)
        else:
            previous_hook(report)
    previous, previous_hook = signal.signal(signal.SIGINT, handler), sys.unraisablehook
    sys.unraisablehook = unraisable
    try:
        yield seen
    finally:
        signal.signal(signal.SIGINT, previous)
        sys.unraisablehook = previous_hook
    if seen:
        _raise_interrupt(previous)


def _raise_interrupt(handler) -> None:
    """Raise KeyboardInterrupt through ``handler``, the program's SIGINT handler, if it is a
    function: the command's counts it as its first stop signal (see signals.py)."""
    if callable(handler):
        handler(signal.SIGINT, None)
    raise KeyboardInterrupt


CORE = "estimation core"  # the runner's own kernels: a step of every first compile


class Compiling:
    """Kernels compiling in other processes (``precompile``); ``wait`` before using them.
    ``pending``: every estimator that was to compile, those the processes have and the rest;
    ``progress``: told as each is done (``progress.StepsLine``), or None; ``also``: other
    steps it counts, which the caller says are ``done`` (the log reader's kernels)."""

    def __init__(self, processes=(), pending=(), progress=None, also=()):
        self.processes = list(processes)
        self.pending = list(pending)
        self.progress = progress
        self.steps_left = {*pending, *also, CORE}
        if progress is not None:
            progress.total = len(self.steps_left)
        self.started = time.time()  # the processes say when each estimator was done on this clock

    def wait(self) -> None:
        """Until every pending estimator is compiled: the processes' own, and here, one by one,
        what no process took (or one that failed left)."""
        try:
            with _noticing_interrupts() as interrupted:
                if self.progress is not None or self.processes:
                    warm_up([])  # the estimation core's own kernels, here, meanwhile
                    self.done(CORE)
                self._follow_processes(interrupted)
                processes, self.processes = self.processes, []
                for p in processes:
                    p.wait()
                if any(p.returncode == -signal.SIGINT for p in processes):
                    _raise_interrupt(signal.getsignal(signal.SIGINT))  # Ctrl-C at a terminal reaches the workers too
                for name in list(self.pending):
                    if interrupted:
                        break
                    compile_kernels([name])
                    self.done(name)
        finally:
            if self.progress is not None:
                self.progress.close()

    def done(self, name: str, at: float | None = None) -> None:
        """``name`` is compiled, at ``at`` (``time.time()``; default now). A step not counted
        (the log reader when it was cached) is let pass."""
        if name not in self.steps_left:
            return
        self.steps_left.remove(name)
        if name in self.pending:
            self.pending.remove(name)
        if self.progress is not None:
            self.progress.step(name, None if at is None else at - self.started)

    def _follow_processes(self, interrupted: list) -> None:
        """Read each process's "NAME TIME" lines (``compile_kernels(report=)``) until all end
        (or an interrupt came), ticking the progress line meanwhile."""
        import selectors

        selector = selectors.DefaultSelector()
        for p in self.processes:
            if p.stdout is not None:
                selector.register(p.stdout, selectors.EVENT_READ, [b""])
        while selector.get_map() and not interrupted:
            for key, _ in selector.select(timeout=0.5):
                chunk = os.read(key.fd, 4096)
                if not chunk:
                    selector.unregister(key.fileobj)
                    key.fileobj.close()
                    continue
                *lines, key.data[0] = (key.data[0] + chunk).split(b"\n")
                for line in lines:
                    name, _, at = line.decode(errors="replace").rpartition(" ")
                    try:
                        self.done(name, float(at))
                    except ValueError:
                        pass  # not a report (something the process printed): its estimators are said at the end
            if self.progress is not None:
                self.progress.tick()
        selector.close()


def precompile(names: list[str], progress=None, also=()) -> Compiling:
    """Start compiling the kernels of ``names`` that are not cached yet, in one process per
    core, each with a fair share: a first run then waits for the longest share rather than
    the sum (here, all seven: 33 s in one process). Returns at once; the caller reads its log
    meanwhile and calls ``wait`` before it estimates, which compiles here what no process
    took (an estimator alone, or on one core) or a failed process left. Estimators registered
    at run time (not importable by a new process) compile on first use instead.
    ``progress``, ``also``: see ``Compiling``."""
    import subprocess

    pending = [n for n in needs_compile(names) if n in COMPILE_SECONDS]
    if not pending and not also:
        return Compiling()
    workers = min(len(pending), os.cpu_count() or 1)
    if workers < 2:
        return Compiling(pending=pending, progress=progress, also=also)
    shares: list[list[str]] = [[] for _ in range(workers)]
    loads = [0.0] * workers
    for name in sorted(pending, key=lambda n: -COMPILE_SECONDS[n]):  # longest first, to the lightest
        k = loads.index(min(loads))
        shares[k].append(name)
        loads[k] += COMPILE_SECONDS[name]
    # a compiling process ends with its parent (a SIGTERM may end that before it waits for them)
    code = ("import sys; from mavattitude.signals import end_with_parent; end_with_parent(int(sys.argv[1])); "
            "from mavattitude.core.warmup import compile_kernels; compile_kernels(sys.argv[2:], report=sys.stdout)")
    return Compiling((subprocess.Popen([sys.executable, "-c", code, str(os.getpid()), *share], stdout=subprocess.PIPE,
                                       stderr=subprocess.DEVNULL) for share in shares), pending, progress, also)


def compile_kernels(names: list[str], report=None) -> None:
    """Run each estimator alone over a few synthetic samples: its kernels compile (or load).
    ``report``: a stream told "NAME TIME" (``time.time()``) as each is done."""
    import numpy as np

    from ..aiding import Aiding
    n = 5
    t = np.arange(n) * 0.01
    for name in names:
        e = create(name)
        e.initialize(np.array([1.0, 0.0, 0.0, 0.0]), np.zeros(3))
        e.update(t, np.zeros((n, 3)), np.tile([0.0, 0.0, -9.80665], (n, 1)), np.tile([2e-5, 0.0, 4e-5], (n, 1)),
                 np.zeros(n), aiding=Aiding.empty(n))
        if report is not None:
            print(name, time.time(), file=report, flush=True)


def warm_up(names: list[str], params: dict | None = None) -> None:
    """Run the estimation core over a second of synthetic samples (compass, GPS and baro
    included), so every compiled kernel is loaded (or compiled) now rather than on the first
    samples of a live link."""
    with _noticing_interrupts():
        _warm_up(names, params)


def _warm_up(names: list[str], params: dict | None) -> None:
    import numpy as np

    from .runner import Runner
    n = 100
    t = np.arange(n) * 0.01
    arrival = np.arange(n) * 4.0
    runner = Runner(names, params, imu_source="warm-up", mag_source="warm-up")
    runner.add_imu(t, np.zeros((n, 3)), np.tile([0.0, 0.0, -9.80665], (n, 1)), arrival)
    runner.add_mag(t, np.tile([2e-5, 0.0, 4e-5], (n, 1)), arrival + 1)
    fix = [[47.0, 8.0, 500.0, 0.0, 0.0, 0.0, 3, 10, 1.0, 2.0]] * (n // 10)
    runner.add_gps(np.column_stack([t[::10], fix, arrival[::10] + 2]))
    runner.add_baro(np.column_stack([t, np.full(n, 95_000.0), arrival + 3]))
    runner.step(final=True)
