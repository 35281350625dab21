"""Numba kernels compiled before they are needed: a first run's (``precompile``), shared out
between cores, in another process from the start and here once the log is read; and here, over
synthetic samples, before a live link's first samples arrive (``warm_up``).

Above the estimators and the estimation core (it runs both); the registry
(``estimators/__init__.py``) says only which estimators need compiling (``needs_compile``).
"""
from __future__ import annotations

import gc
import os
import signal
import sys
import threading
import time
from contextlib import contextmanager

from .. import signals
from ..estimators import ESTIMATORS, create, needs_compile, plugin_paths
from ..estimators.base import DEFAULT_COMPILE_S


def compile_seconds(name: str) -> float:
    """How long estimator ``name``'s kernels take to compile the first time, one core, as its
    class says (``Estimator.compile_seconds``; unsaid: ``DEFAULT_COMPILE_S``): the longest are
    handed out first, so that the processes end close together."""
    seconds = ESTIMATORS[name].compile_seconds
    return DEFAULT_COMPILE_S if seconds is None else float(seconds)


CORE = "estimation core"  # the runner's own kernels: a step of every first compile


class Compiling:
    """Kernels compiling in other processes and here (``precompile``); ``wait`` before using them.
    ``pending``: every estimator that was to compile; ``queue``: those not yet handed out,
    longest first, each to the first of the processes or this one that is free; ``progress``:
    told as each is done (``progress.StepsLine``), or None; ``also``: other steps it counts,
    which the caller says are ``done`` (the log reader's kernels)."""

    def __init__(self, processes=(), pending=(), progress=None, also=(), queue=()):
        self.processes = list(processes)
        self.pending = list(pending)
        self.queue = list(queue)
        self.progress = progress
        self.steps_left = {*pending, *also, CORE}
        if progress is not None:
            progress.total = len(self.steps_left)
        self.started = time.time()  # the processes say when each estimator was done on this clock

    def wait(self) -> None:
        """Until every pending estimator is compiled: the processes' own, those compiled here
        meanwhile (in a thread, so that a stop signal ends the command at once rather than
        after the compile), and here, one by one, what a failed process left."""
        try:
            with signals.holding_interrupts() as interrupted, collector_off():
                if self.progress is not None or self.processes:
                    warm_up([])  # the estimation core's own kernels, here, first
                    self.done(CORE)
                self._share_out(interrupted)
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

    def _share_out(self, interrupted: list) -> None:
        """Hand the queue out, an estimator at a time, to a thread here and to each process as
        it says "NAME TIME" (``compile_kernels(report=)``) for the last, the thread loading
        what the processes compiled once the queue is empty; until all is compiled and loaded
        and the processes end (or an interrupt came), ticking the progress line meanwhile."""
        import selectors

        selector = selectors.DefaultSelector()
        for p in self.processes:
            if p.stdout is not None:
                selector.register(p.stdout, selectors.EVENT_READ, [b"", p])
        here, theirs = None, []  # theirs: what the processes compiled, for the thread to load meanwhile
        while (selector.get_map() or here or self.queue or theirs) and not interrupted:
            if here is None and (self.queue or theirs):  # loaded now, not after the last is compiled
                here = _Here(self.queue.pop(0) if self.queue else theirs.pop(0))
            for key, _ in selector.select(timeout=0.05 if here else 0.5):
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
                        continue  # not a report (something the process printed): its estimators are said at the end
                    if name in ESTIMATORS:
                        theirs.append(name)
                    _hand(key.data[1], self.queue.pop(0) if self.queue else None)
            if here is not None and not here.thread.is_alive():
                if here.compiled:
                    self.done(here.name)
                here = None  # one that failed stays pending: compiled again below, where its error is raised
            if self.progress is not None:
                self.progress.tick()
        selector.close()
        for p in self.processes:  # nothing more for them (an interrupt came): each ends after its estimator
            _hand(p, None)


class _Here:
    """An estimator compiling in a thread of this process (``compile_kernels``)."""

    def __init__(self, name: str):
        self.name, self.compiled = name, False
        self.thread = threading.Thread(target=self._compile, name=f"compiling {name}", daemon=True)
        self.thread.start()

    def _compile(self) -> None:
        try:
            compile_kernels([self.name])
            self.compiled = True
        except BaseException:  # noqa: BLE001 - said where it is compiled again, in the main thread
            pass


def _hand(process, name: str | None) -> None:
    """Give ``process`` (``compiling_process``) ``name`` to compile next; None: nothing more, it ends."""
    if process.stdin is None:
        return
    try:
        if name is None:
            process.stdin.close()
        else:
            process.stdin.write(f"{name}\n".encode())
            process.stdin.flush()
    except (BrokenPipeError, ValueError):  # it ended: what it had is compiled here
        pass


def precompile(names: list[str], progress=None, also=()) -> Compiling:
    """Start compiling the kernels of ``names`` that are not cached yet, here and in one more
    process per further core, the longest first, each to the first free: a first run then waits
    for about the sum shared by the cores rather than the sum (all seven: 37 s in one process).
    Returns at once, a process compiling; the caller reads its log meanwhile and calls
    ``wait``, which compiles here what the processes have not taken (an estimator alone, or on
    one core, all) or a failed process left. An estimator registered at run time is
    registered in the processes too, from its module (``estimators.plugin_paths``); one that no
    module holds (defined in ``__main__``) is compiled here. ``progress``, ``also``: see
    ``Compiling``."""
    pending = needs_compile(names)
    if not pending and not also:
        return Compiling()
    plugins = plugin_paths(pending)
    # one that no module holds (None) is left to wait()
    queue = longest_first([n for n in pending if plugins.get(n, "") is not None])
    paths = [path for path in plugins.values() if path is not None]
    extra = min(len(queue), os.cpu_count() or 1) - 1  # this process is one of the compiling ones
    if extra < 1:
        return Compiling(pending=pending, progress=progress, also=also)
    processes = [compiling_process([queue.pop(0)], paths) for _ in range(extra)]
    return Compiling(processes, pending, progress, also, queue)


def compiling_process(names: list[str], plugins: list[str] = ()):
    """A process that compiles the kernels of ``names``, then of each name written to its stdin
    (a line each) until that is closed (``compile_kernels``), saying "NAME TIME" on its stdout as
    each is done. It imports from this process's path and registers ``plugins`` ("module:Class",
    ``estimators.plugin_paths``) first, so it knows the estimators registered here at run time;
    it ends with this process (a SIGTERM may end this one before it waits for it)."""
    import json
    import subprocess

    code = ("import sys, json; sys.path[:] = json.loads(sys.argv[2]); "
            "from mavattitude.signals import end_with_parent; end_with_parent(int(sys.argv[1])); "
            "from mavattitude.estimators import register_from; register_from(json.loads(sys.argv[3])); "
            "from mavattitude.core.warmup import compile_kernels; "
            "[compile_kernels([n.strip()], report=sys.stdout) for n in iter(sys.stdin.readline, '') if n.strip()]; "
            "import os; os._exit(0)")  # all said and cached: no teardown for the command to wait for (0.6 s)
    process = subprocess.Popen([sys.executable, "-c", code, str(os.getpid()), json.dumps([str(p) for p in sys.path]),
                                json.dumps(list(plugins))], stdin=subprocess.PIPE, stdout=subprocess.PIPE,
                               stderr=subprocess.DEVNULL)
    for name in names:
        _hand(process, name)
    return process


def longest_first(names: list[str]) -> list[str]:
    """``names`` by their compile time, longest first: handed out in this order, each to the
    first process free, the last to finish ends soonest."""
    return sorted(names, key=lambda n: -compile_seconds(n))


def compile_kernels(names: list[str], report=None) -> None:
    """Run each estimator alone over a few synthetic samples: its kernels compile (or load).
    ``report``: a stream told "NAME TIME" (``time.time()``) as each is done."""
    import numpy as np

    from ..aiding import Aiding
    n = 5
    t = np.arange(n) * 0.01
    for name in names:
        with collector_off():
            e = create(name)
            e.initialize(np.array([1.0, 0.0, 0.0, 0.0]), np.zeros(3))
            e.update(t, np.zeros((n, 3)), np.tile([0.0, 0.0, -9.80665], (n, 1)),
                     np.tile([2e-5, 0.0, 4e-5], (n, 1)), np.zeros(n), aiding=Aiding.empty(n))
        if report is not None:
            print(name, time.time(), file=report, flush=True)


@contextmanager
def collector_off():
    """Python's cycle collector off within: numba's compile makes objects by the hundred
    thousand, and a first compile spent 12-16 % of its CPU in collections at Python's
    thresholds, 4-5 % at a fourteenth as often (1.3-1.7 s of 30-37 for the seven estimators in
    one process; their peak 420 MB, 607 MB with it off). Back on after, where it was on; what
    the compile left is collected then, as it would have been."""
    if not gc.isenabled():  # within another one (a thread compiling inside ``Compiling.wait``)
        yield
        return
    gc.disable()
    try:
        yield
    finally:
        gc.enable()


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
