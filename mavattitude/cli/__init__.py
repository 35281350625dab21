"""The ``mavattitude`` command: a module per command, each a thin layer over the readers, the
commands (replay, evaluate, tune, bench, info), their reports and the view.

Exit status (one rule for every command; the README lists it):

- 0 success;
- 1 a file, folder, device or endpoint named on the command line cannot be used: a log that
  cannot be read or lacks what was asked of it (an IMU source, a clock segment, ground
  truth), a parameter file with bad TOML or a bad value, an output that would write over an
  input or another kind of file or cannot be created, a viewer or link that fails. One line
  on stderr names it and says what is wrong;
- 2 the command line itself is wrong, whatever the files hold: an unknown option, estimator
  or parameter, a value out of its range, options that exclude each other, a malformed URL;
- 130 interrupted (Ctrl-C); 141 the reader of our output went away (``| head``).
"""
from __future__ import annotations

import argparse
import gc
import os
import sys

from .. import __version__, signals
from ..errors import InputError, UsageError, is_interrupt
from . import bench, estimators, evaluate, info, live, replay, simulate, tune
from .args import Parser
from .common import warn

DESCRIPTION = """\
Replay flight logs (ArduPilot .bin DataFlash, MAVLink .tlog telemetry, PX4 .ulg ULog) through
attitude estimators and compare each estimate with the autopilot's own attitude (ATT /
ATTITUDE / vehicle_attitude) or, where the log has it, simulator ground truth (SIM / SIMSTATE /
vehicle_attitude_groundtruth)."""

EPILOG = """\
examples:
  mavattitude info flight.bin
  mavattitude replay flight.bin --estimators mahony --rrd flight.rrd --json metrics.json
  mavattitude replay sitl.tlog --reference truth --export out/
  mavattitude replay flight.bin --estimators all --set ncs-eskf.h_threshold_air=0.02
  mavattitude evaluate ../logs --estimators all -j 4 --out evaluation/
  mavattitude tune ../logs --estimator mahony -o tuned.toml
  mavattitude estimators
  mavattitude simulate --scenario figure8 --duration 120 -o figure8.tlog
  mavattitude live udpin:0.0.0.0:14550 --estimators all --spawn
  mavattitude simulate --live udpout:127.0.0.1:14550   # a simulated vehicle for 'live'
  mavattitude bench --json bench.json
"""

COMMANDS = (info, replay, evaluate, tune, estimators, simulate, live, bench)  # in --help's order


def build_parser() -> argparse.ArgumentParser:
    parser = Parser(prog="mavattitude", description=DESCRIPTION, epilog=EPILOG,
                    formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--version", action="version", version=f"mavattitude {__version__}")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    for command in COMMANDS:
        command.add_parser(sub)
    return parser


def main(argv=None) -> int:
    program = argv is None  # the process's own command line, not a caller's (a test, a script)
    previous = signals.install()  # first: a stop signal during the imports below is one line too
    try:
        code = _main(argv)
    except KeyboardInterrupt:  # before the command started, or as it ended
        code = _interrupted()
    finally:
        if program:
            signals.ignore()  # done: the interpreter's exit is not cut short
        else:
            signals.restore(previous)  # a caller's own handlers back
    if program and code == signals.exit_code():
        # stopped wherever it was (an import, LLVM mid-compile, Rerun's start): the interpreter's
        # exit can crash on what was left half done (SIGSEGV seen); end here, everything closed
        _release_pool_semaphores()
        sys.stdout.flush()
        sys.stderr.flush()
        os._exit(code)
    if program:
        # the interpreter's exit collects every object once more, numba's by the hundred thousand:
        # 0.4 s of a 1.6 s replay; frozen, they are left to the end of the process (exit handlers
        # still run: Rerun's, multiprocessing's)
        gc.freeze()
    return code


def _release_pool_semaphores() -> None:
    """Unlink the named semaphores of a process pool stopped mid-run, as the interpreter's exit
    would (their multiprocessing finalizers): os._exit skips that, and multiprocessing's
    resource tracker then printed a warning about leaked semaphores after 'interrupted'."""
    if "multiprocessing" in sys.modules:
        from multiprocessing import util

        util._run_finalizers(0)  # only those of priority >= 0: the semaphores, not joining processes


def _main(argv) -> int:
    # Rerun's own log lines would repeat, in Rust's format, what our one-line errors say.
    os.environ.setdefault("RUST_LOG", "off")
    parser = build_parser()
    try:
        args = parser.parse_args(argv)
    except SystemExit as exc:  # --help (0) or a usage error argparse has printed (2)
        return exc.code
    if not getattr(args, "func", None):
        parser.print_help()
        return 2
    from ..estimators import load_plugins
    for problem in load_plugins():
        warn(problem)
    code = _run(args)
    # Only a command that opened a viewer has one to close: importing the view here would import
    # Rerun, perhaps half imported when a Ctrl-C cut its import short (a traceback after "interrupted")
    sink = sys.modules.get("mavattitude.view.sink")
    try:
        closed = sink is None or sink.shutdown()
    except KeyboardInterrupt:
        closed = False
    if not closed:
        print("mavattitude: the Rerun viewer stopped answering; closed without it", file=sys.stderr)
        # Rerun's exit handler would wait for that viewer forever: end here, everything written and closed
        sys.stdout.flush()
        sys.stderr.flush()
        os._exit(code)
    return code


def _interrupted() -> int:
    """A stop signal's one line ('interrupted') and exit status (130; 143 for SIGTERM)."""
    print(signals.message(), file=sys.stderr)
    return signals.exit_code()


def _run(args) -> int:
    """Run the command; every error becomes one line on stderr and its exit status."""
    try:
        try:
            code = args.func(args)
            signals.check()  # a stop that something swallowed on the way still ends it as a stop
            return code
        except (SystemError, InputError, UsageError, OSError) as exc:
            # a Ctrl-C inside a compiled kernel comes back as a SystemError; and once told to
            # stop, whatever ends the command is the stop's doing
            if signals.received() is not None or is_interrupt(exc):
                raise KeyboardInterrupt from exc
            raise  # a SystemError that is no interrupt: a bug, whose traceback is the report
    except InputError as exc:
        print(f"mavattitude: error: {exc}", file=sys.stderr)
        return 1
    except UsageError as exc:
        print(f"mavattitude: error: {exc}", file=sys.stderr)
        return 2
    except BrokenPipeError:  # our reader went away (`| head`): stop quietly, as Unix tools do
        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
        return 141
    except OSError as exc:  # an output we cannot write, a port in use
        name = f"{exc.filename}: " if exc.filename else ""
        print(f"mavattitude: error: {name}{exc.strerror or exc}", file=sys.stderr)
        return 1
    except KeyboardInterrupt:
        return _interrupted()


if __name__ == "__main__":
    sys.exit(main())
