"""How the command stops when it is told to: Ctrl-C (SIGINT), or SIGTERM (``kill``, a service
manager, a batch system's time limit).

The first such signal raises KeyboardInterrupt wherever the program is, so that every ``with``
on the way out cleans up: temporary outputs removed (``outputs.Outputs``), worker processes
ended (``evaluate.Workers``). The command then says so in one line and exits with 128 + the
signal's number, as a shell reports a process killed by it: 130 for Ctrl-C, 143 for SIGTERM.

Raised inside numba's own Python code (which its compiled calls run: typing arguments, boxing
results, loading a kernel), it would leave the call half done; a first signal landing there is
sent again 20 ms later, until it lands in other code.

A second signal while that happens is noted, not raised: a Ctrl-C pressed twice must not cut
the cleanup short (``.partial`` files left), nor end the process by SIGINT, which CPython does
when a KeyboardInterrupt escapes the program. A third ends the process at once
(``os._exit``), should the cleanup hang.

Code that catches everything (pymavlink's ``except: pass`` around an import) can swallow the
KeyboardInterrupt, and Python itself drops one raised where it cannot pass it on (a weakref or
import-lock callback: "Exception ignored", with a traceback). The signal is noted all the same,
the dropped one is not reported (``_unraisable``), and ``check`` raises it again where work
reports progress, before outputs are committed and when the command returns.

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
RESEND_S = 0.02  # s: a first signal that landed in numba's own code is sent again after this
_received: list[int] = []  # the stop signals since ``install``, in order


def _stop(signum, frame) -> None:
    if not _received and _in_numba(frame):
        # Raised there, it would unwind numba's C code halfway through a compiled call: the call
        # came back as a SystemError, or with a half-built result that crashed the process
        # (SIGSEGV, 2 of 50 Ctrl-C at random moments of a replay). Sent again until it lands in
        # other code: at the latest when the call returns (compiled code does not see signals).
        threading.Timer(RESEND_S, os.kill, (os.getpid(), signum)).start()
        return
    _received.append(signum)
    if len(_received) == 1:
        raise KeyboardInterrupt
    if len(_received) >= 3:
        print(SIGNAL_NAMES[_received[0]], file=sys.stderr, flush=True)
        os._exit(exit_code())


def _in_numba(frame) -> bool:
    """Whether ``frame`` is within numba's or llvmlite's own Python code (typing a call's
    arguments, boxing its results, loading or compiling a kernel), itself or a caller of it."""
    while frame is not None:
        parts = frame.f_code.co_filename.split(os.sep)
        if "numba" in parts or "llvmlite" in parts:
            return True
        frame = frame.f_back
    return False


def _unraisable(report) -> None:
    """``sys.unraisablehook`` while installed: a stop's KeyboardInterrupt that Python could not
    pass on is noted already, and raised again by ``check``; anything else is reported as before."""
    if isinstance(report.exc_value, KeyboardInterrupt) and _received:
        return
    _unraisable_before(report)


_unraisable_before = sys.unraisablehook  # the hook ``_unraisable`` hands the rest to


def install() -> dict:
    """Handle SIGINT and SIGTERM as above (from the main thread only: the others get no
    signals), and Python's unraisable exceptions (``_unraisable``); returns the handlers
    replaced, for ``restore``."""
    global _unraisable_before
    if threading.current_thread() is not threading.main_thread():
        return {}
    _received.clear()
    previous = {sig: signal.signal(sig, _stop) for sig in STOP_SIGNALS}
    if sys.unraisablehook is not _unraisable:
        previous["unraisablehook"] = _unraisable_before = sys.unraisablehook
        sys.unraisablehook = _unraisable
    return previous


def check() -> None:
    """Raise KeyboardInterrupt if a stop signal came and the code it landed in swallowed it.
    (pymavlink's ``mavextra`` imports its quaternions inside ``try: ... except: pass``: a
    SIGTERM landing there was lost, and the command went on to the end with exit 0.)"""
    if _received:
        raise KeyboardInterrupt


def restore(previous: dict) -> None:
    """Put back the handlers ``install`` replaced; the signals it saw are forgotten."""
    _received.clear()
    for sig, handler in previous.items():
        if sig == "unraisablehook":
            sys.unraisablehook = handler
        elif handler is not None:  # None: one set outside Python, which Python cannot set again
            signal.signal(sig, handler)


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


@contextmanager
def holding_interrupts():
    """Ctrl-C within code that cannot take it, raised once that code is done: numba's compile,
    where it can land in one of LLVM's callbacks (Python only reports it, "Exception ignored"
    and a traceback, and the compile goes on), and Rerun's import, which turns an exception
    raised while it builds its classes into a warning and goes on. The handler in place (the
    command's) still sees it at once; yields the interrupts seen, so a body that goes on can
    stop early. In the main thread only: the others get no signals."""
    seen: list = []
    if threading.current_thread() is not threading.main_thread():
        yield seen
        return

    def handler(signum, frame):
        seen.append(signum)
        if callable(previous):
            previous(signum, frame)
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
        raise_interrupt(previous)


def raise_interrupt(handler) -> None:
    """Raise KeyboardInterrupt through ``handler``, the program's SIGINT handler, if it is a
    function: the command's counts it as its first stop signal."""
    if callable(handler):
        handler(signal.SIGINT, None)
    raise KeyboardInterrupt


def end_with_parent(parent: int) -> None:
    """In a helper process (an evaluate worker, a compiling process): end it once its parent
    ``parent`` (a pid) is gone, whether that ended by a signal, a crash or SIGKILL, rather
    than let it work on for nobody. A thread checks once a second."""
    def watch() -> None:
        while os.getppid() == parent:  # an orphan is adopted by another process
            time.sleep(1.0)
        os._exit(1)
    threading.Thread(target=watch, name="end-with-parent", daemon=True).start()
