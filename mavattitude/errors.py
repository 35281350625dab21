"""Errors the CLI turns into one line on stderr and a non-zero exit, and how an interrupt looks
when numba's compiled code returns it."""
from __future__ import annotations

import os
import stat

SPECIAL_FILES = ((stat.S_ISFIFO, "a FIFO"), (stat.S_ISSOCK, "a socket"), (stat.S_ISCHR, "a character device"),
                 (stat.S_ISBLK, "a block device"))


class InputError(Exception):
    """A log (or other input) we cannot use. The message names the file and the problem."""

    def __init__(self, path, problem: str):
        self.path = str(path)
        self.problem = problem
        super().__init__(f"{self.path}: {problem}")


class UsageError(Exception):
    """The command line asks for something that cannot be done (exit 2)."""


def special_file(path) -> str | None:
    """'a FIFO', 'a socket', 'a character device' or 'a block device' for such a file (the link
    followed), None for a regular file, a folder or nothing."""
    try:
        mode = os.stat(path).st_mode
    except OSError:
        return None
    return next((name for test, name in SPECIAL_FILES if test(mode)), None)


def check_not_special(path) -> None:
    """InputError for an input that is no regular file: opening a FIFO waits for a writer, and
    reading a device may never end."""
    kind = special_file(path)
    if kind:
        raise InputError(path, f"not a regular file ({kind})")


def is_interrupt(exc: BaseException | None) -> bool:
    """Whether ``exc`` is a stop signal's KeyboardInterrupt, also as numba's compiled code
    returns it: a signal handled while a kernel runs leaves the exception set under its
    result, and CPython reports a SystemError ("returned a result with an exception set")
    caused by the KeyboardInterrupt."""
    if isinstance(exc, KeyboardInterrupt):
        return True
    return isinstance(exc, SystemError) and is_interrupt(exc.__cause__ or exc.__context__)


def reraise_interrupt(exc: BaseException) -> None:
    """For a catch-all (``except Exception``) around compiled code: raise KeyboardInterrupt if
    ``exc`` is an interrupt, so that a Ctrl-C is never taken for a log's fault or result."""
    if is_interrupt(exc):
        raise KeyboardInterrupt from exc
