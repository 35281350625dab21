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
import time

from .. import signals
from ..estimators import ESTIMATORS, create, needs_compile, plugin_paths
from ..estimators.base import DEFAULT_COMPILE_S


def compile_seconds(name: str) -> float:
    """How long estimator ``name``'s kernels take to compile the first time, one core, as its
    class says (``Estimator.compile_seconds``; unsaid: ``DEFAULT_COMPILE_S``): to share the
    work out fairly between processes."""
    seconds = ESTIMATORS[name].compile_seconds
    return DEFAULT_COMPILE_S if seconds is None else float(seconds)


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
            with signals.holding_interrupts() as interrupted:
                if self.progress is not None or self.processes:
                    warm_up([])  # the estimation core's own kernels, here, meanwhile
                    self.done(CORE)
                self._follow_processes(interrupted)
                processes, self.processes = self.processes, []
                for p in processes:
                    p.wait()
                if any(p.returncode == -signal.SIGINT for p in processes):
                    signals.raise_interrupt(signal.getsignal(signal.SIGINT))  # Ctrl-C at a terminal reaches the workers too
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
    took (an estimator alone, or on one core) or a failed process left. An estimator
    registered at run time is registered in the processes too, from its module
    (``estimators.plugin_paths``); one that no module holds (defined in ``__main__``) is
    compiled here. ``progress``, ``also``: see ``Compiling``."""
    pending = needs_compile(names)
    if not pending and not also:
        return Compiling()
    workers = min(len(pending), os.cpu_count() or 1)
    if workers < 2:
        return Compiling(pending=pending, progress=progress, also=also)
    plugins = plugin_paths(pending)
    here = [n for n, path in plugins.items() if path is None]  # no module holds it: compiled in wait()
    paths = [path for path in plugins.values() if path is not None]
    dealt = shares([n for n in pending if n not in here], workers)
    return Compiling((compiling_process(share, paths) for share in dealt), pending, progress, also)


def compiling_process(names: list[str], plugins: list[str] = ()):
    """A process that compiles the kernels of ``names`` (``compile_kernels``), saying "NAME TIME"
    on its stdout as each is done. It imports from this process's path and registers
    ``plugins`` ("module:Class", ``estimators.plugin_paths``) first, so it knows the estimators
    registered here at run time; it ends with this process (a SIGTERM may end this one before
    it waits for it)."""
    import json
    import subprocess

    code = ("import sys, json; sys.path[:] = json.loads(sys.argv[2]); "
            "from mavattitude.signals import end_with_parent; end_with_parent(int(sys.argv[1])); "
            "from mavattitude.estimators import register_from; register_from(json.loads(sys.argv[3])); "
            "from mavattitude.core.warmup import compile_kernels; compile_kernels(sys.argv[4:], report=sys.stdout)")
    return subprocess.Popen([sys.executable, "-c", code, str(os.getpid()), json.dumps([str(p) for p in sys.path]),
                             json.dumps(list(plugins)), *names], stdout=subprocess.PIPE, stderr=subprocess.DEVNULL)


def shares(names: list[str], workers: int) -> list[list[str]]:
    """``names`` dealt out to ``workers`` processes by their compile time, longest first, each
    to the process with the least so far (the last to finish ends soonest)."""
    out: list[list[str]] = [[] for _ in range(workers)]
    loads = [0.0] * workers
    for name in sorted(names, key=lambda n: -compile_seconds(n)):
        k = loads.index(min(loads))
        out[k].append(name)
        loads[k] += compile_seconds(name)
    return [share for share in out if share]


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
    with signals.holding_interrupts():
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
