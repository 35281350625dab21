"""Values an adversarial tester gave the command line, parameters and outputs (issue 23,
point 8, "values" and "messages"): each is one line and its exit status, or works."""
from __future__ import annotations

import argparse

import pytest

from conftest import SAMPLE_LOGS
from mavattitude.cli import build_parser, main

LOG = SAMPLE_LOGS / "static.bin"
POSITIONALS = {"info": [LOG], "replay": [LOG], "evaluate": [LOG], "tune": [LOG, "--estimator", "mahony"]}


def run(capsys, *args):
    code = main([str(a) for a in args])
    out, err = capsys.readouterr()
    return code, out, err


def one_line(err: str) -> str:
    lines = err.strip().splitlines()
    assert len(lines) == 1 and "Traceback" not in err, err
    return lines[0]


def options_with_values():
    """(command, action) for every option of every subcommand that takes a value."""
    parser = build_parser()
    commands = next(a for a in parser._actions if isinstance(a, argparse._SubParsersAction)).choices
    return [(command, action) for command, sub in commands.items() for action in sub._actions
            if action.option_strings and action.nargs is None and not isinstance(
                action, (argparse._StoreConstAction, argparse._HelpAction, argparse._VersionAction))]


def numeric_options():
    return [pytest.param(c, a, id=f"{c} {a.option_strings[-1]}") for c, a in options_with_values()
            if getattr(a.type, "__name__", "") == "number"]


def test_every_numeric_option_is_found():
    assert len(numeric_options()) >= 31  # the tester's count; new ones join by themselves


@pytest.mark.parametrize("command, action", numeric_options())
def test_a_dash_dash_value_is_checked_like_any_other(capsys, command, action):
    """argparse (before Python 3.12.7) took '--' after '=' for the separator and skipped the
    option's type: bench --seed=-- started a full benchmark."""
    option = action.option_strings[-1]
    code, _, err = run(capsys, command, *POSITIONALS.get(command, []), f"{option}=--")
    line = one_line(err)
    assert code == 2 and f"argument {'/'.join(action.option_strings)}: expected" in line and "'--'" in line


def test_no_option_is_left_without_a_value():
    """Every option given '--' holds '--' (then checked as any string) or is refused."""
    parser = build_parser()
    for command, action in options_with_values():
        option = action.option_strings[-1]
        try:
            args = parser.parse_args([command, *map(str, POSITIONALS.get(command, [])), f"{option}=--"])
        except SystemExit as exc:
            assert exc.code == 2
            continue
        value = getattr(args, action.dest)
        assert value == "--" or value == ["--"], f"{command} {option}: {value!r}"
