"""How the command stops when it is told to: Ctrl-C (SIGINT), or SIGTERM (``kill``, a service
manager, a batch system's time limit).

The first such signal raises KeyboardInterrupt wherever the program is, so that every ``with``
on the way out cleans up: temporary outputs removed (``outputs.Outputs``), worker processes
ended (``evaluate.Workers``). The command then says so in one line and exits with 128 + the
signal's number, as a shell reports a process killed by it: 130 for Ctrl-C, 143 for SIGTERM.

A second signal while that happens is noted, not raised: a Ctrl-C pressed twice must not cut
the cleanup short (``.partial`` files left), nor end the process by SIGINT, which CPython does
when a KeyboardInterrupt escapes the program. A third ends the process at once
(``os._exit``), should the cleanup hang.

Once the command is done, they are ignored while the interpreter exits (``ignore``).

``live`` handles the same signals itself while its session runs (a signal ends the session,
its metrics printed, exit 0), and puts these back after.
"""
from __future__ import annotations

import os
import signal
import sys
import threading
import time
from contextlib import contextmanager

STOP_SIGNALS = (signal.SIGINT, signal.SIGTERM)
SIGNAL_NAMES = {signal.SIGINT: "interrupted", signal.SIGTERM: "terminated (SIGTERM)"}
_received: list[int] = []  # the stop signals since ``install``, in order
_holding = 0  # ``held`` blocks running
_due = False  # a first signal came during a ``held`` block: raised as it ends


def _stop(signum, frame) -> None:
    global _due
    _received.append(signum)
    if len(_received) >= 3:
        print(SIGNAL_NAMES[_received[0]], file=sys.stderr, flush=True)
        os._exit(exit_code())
    if len(_received) == 1:
        if _holding:
            _due = True
        else:
            raise KeyboardInterrupt


def install() -> dict:
    """Handle SIGINT and SIGTERM as above (from the main thread only: the others get no
    signals); returns the handlers replaced, for ``restore``."""
    global _due
    if threading.current_thread() is not threading.main_thread():
        return {}
    _received.clear()
    _due = False
    return {sig: signal.signal(sig, _stop) for sig in STOP_SIGNALS}


def restore(previous: dict) -> None:
    for sig, handler in previous.items():
        if handler is not None:  # None: one set outside Python, which Python cannot set again
            signal.signal(sig, handler)


@contextmanager
def held():
    """A first stop signal waits till the block is done, then raises. For short native work that
    must not be left half done: numba linking a cached kernel into LLVM, stopped there, crashed
    the process (SIGSEGV, 2 of 50 Ctrl-C at random moments of a replay)."""
    global _holding, _due
    _holding += 1
    try:
        yield
    finally:
        _holding -= 1
        if _due and not _holding:
            _due = False
            raise KeyboardInterrupt  # the stop comes first, whatever the block raised


def hold_during_kernel_loads() -> None:
    """Load every cached numba kernel ``held`` (numba loads each on its first call, in the middle
    of a replay): for the command only, a library user's process is left as it is."""
    from numba.core.caching import Cache

    load = Cache.load_overload
    if getattr(load, "held", False):
        return

    def load_held(self, sig, target_context):
        with held():
            return load(self, sig, target_context)
    load_held.held = True
    Cache.load_overload = load_held


def ignore() -> None:
    """The program's work is done: a stop signal while the interpreter exits is ignored. (Its
    exit puts back the default handlers, and a Ctrl-C landing then would end the process by
    SIGINT, not 130, its work done.)"""
    for sig in STOP_SIGNALS:
        signal.signal(sig, signal.SIG_IGN)


def received() -> int | None:
    """The first stop signal since ``install``, if any."""
    return _received[0] if _received else None


def rearm() -> None:
    """After a command took the first signal as its own (Ctrl-C ends ``--web``'s serving and the
    command goes on): the next one stops the command again."""
    _received.clear()


def exit_code() -> int:
    """128 + the first stop signal's number (130 when a KeyboardInterrupt came without one)."""
    return 128 + (received() or signal.SIGINT)


def message() -> str:
    """The one line a stopped command prints: 'interrupted' or 'terminated (SIGTERM)'."""
    return SIGNAL_NAMES[received() or signal.SIGINT]


def end_with_parent(parent: int) -> None:
    """In a helper process (an evaluate worker, a compiling process): end it once its parent
    ``parent`` (a pid) is gone, whether that ended by a signal, a crash or SIGKILL, rather
    than let it work on for nobody. A thread checks once a second."""
    def watch() -> None:
        while os.getppid() == parent:  # an orphan is adopted by another process
            time.sleep(1.0)
        os._exit(1)
    threading.Thread(target=watch, name="end-with-parent", daemon=True).start()
