"""Estimator parameters from the command line and from a TOML file.

Every estimator's parameters are a small dataclass with the paper's defaults, each field
declared with ``param(default, valid)``: ``valid`` is the interval of values that mean
something, in interval notation (``"[0, inf)"``, ``"(0, 1]"``); a value outside it is refused
before any work. ``tune`` declares the range ``mavattitude tune`` searches (``"log [0.01, 10]"``:
a scale, log or linear, and an interval inside ``valid``); a field without one is fixed there.
A class may also list pairs of fields that must be strictly ordered
(``ORDERED = (("norm_lo", "norm_hi"),)``: a ramp from ``lo`` to ``hi``). A user
overrides them with ``--params FILE`` (a TOML table per estimator) and ``--set
NAME.FIELD=VALUE`` (applied after the file, so the command line wins). Below both, a log can
supply a default of its own (``log_defaults``, as each estimator's class says: eq-kf's
airspeed from an ArduPlane's cruise airspeed). The declarations (``param``, ``Interval``,
``Search``) live in ``paramspec``, at the bottom of the package where the estimators import
them; they are named here too, where plugins and scripts have always found them::

    [ncs-eskf]
    h_threshold_air = 0.02

    [mahony]
    kp = 0.5
"""
from __future__ import annotations

import re
import sys

from ..errors import InputError, UsageError, check_not_special
from ..paramspec import (  # noqa: F401 - the declarations, also offered here (see the docstring)
    Interval, Search, convert, describe, fail, make, param, search_space, valid_interval)

if sys.version_info >= (3, 11):
    import tomllib
else:  # pragma: no cover - Python 3.10
    import tomli as tomllib


def load_file(path: str) -> dict[str, dict[str, object]]:
    """{estimator: {field: value}} from a TOML file."""
    check_not_special(path)
    try:
        with open(path, "rb") as f:
            data = tomllib.load(f)
    except FileNotFoundError:
        raise InputError(path, "no such file") from None
    except IsADirectoryError:
        raise InputError(path, "is a folder, not a TOML file") from None
    except (tomllib.TOMLDecodeError, UnicodeDecodeError) as exc:
        raise InputError(path, f"not valid TOML: {exc}") from None
    except RecursionError:  # tomllib parses nested arrays and tables recursively
        raise InputError(path, "not a parameter file: its arrays or tables nest too deeply") from None
    for name, table in data.items():
        if not isinstance(table, dict):
            raise InputError(path, f"'{name}' must be a table of parameters, [{name}], not a value")
    return data


def parse_assignment(text: str) -> tuple[str, str, str]:
    """'ncs-eskf.h_threshold_air=0.02' -> ('ncs-eskf', 'h_threshold_air', '0.02')."""
    target, sep, value = text.partition("=")
    name, dot, field = target.strip().rpartition(".")
    if not sep or not dot or not name or not field or not value.strip():
        raise UsageError(f"--set {text!r}: expected ESTIMATOR.PARAMETER=VALUE, "
                         "e.g. --set ncs-eskf.h_threshold_air=0.02")
    return name, field.strip(), value.strip()


def build(names: list[str], file_values: dict | None = None, assignments: list[str] = (),
          source: str = "--params", log_values: dict | None = None) -> dict[str, object]:
    """The parameter dataclass for each estimator in ``names``, defaults overridden: first by
    ``log_values`` (see ``log_defaults``), then the file, then the assignments. Every value is
    checked, a file's tables for estimators not in ``names`` too (one file may serve several
    runs); an assignment to an estimator not in ``names`` would do nothing, and is an error."""
    from ..estimators import ESTIMATORS

    values: dict[str, dict[str, tuple[object, str]]] = {}
    for name, table in (log_values or {}).items():
        for field, value in table.items():
            values.setdefault(name, {})[field] = (value, "log")
    for name, table in (file_values or {}).items():
        for field, value in table.items():
            values.setdefault(name, {})[field] = (value, source)
    for text in assignments:
        name, field, value = parse_assignment(text)
        values.setdefault(name, {})[field] = (value, "--set")
    for name in values:
        if name not in ESTIMATORS:
            fail(values[name][next(iter(values[name]))][1],
                 f"unknown estimator {name!r}; choose from: {', '.join(ESTIMATORS)}")
        if name not in names and any(origin == "--set" for _, origin in values[name].values()):
            fail("--set", f"{name} is not among the estimators run ({', '.join(names)}): "
                          f"--set {name}.… would do nothing")
    params = {name: make(name, ESTIMATORS[name].Params, values.get(name, {}))
              for name in [*names, *(n for n in values if n not in names)]}
    return {name: params[name] for name in names}


def log_default_params(names: list[str]) -> tuple[str, ...]:
    """The autopilot parameters ``log_defaults`` reads for these estimators (each class says
    which: ``Estimator.LOG_PARAMS``); a live session asks its vehicle for them."""
    from ..estimators import ESTIMATORS

    found = [key for name in names if name in ESTIMATORS for key in ESTIMATORS[name].LOG_PARAMS]
    return tuple(dict.fromkeys(found))


def log_defaults(flight, names: list[str], file_values: dict | None = None,
                 assignments: list[str] = ()) -> tuple[dict, list[str]]:
    """Defaults the log itself supplies, for the estimators in ``names`` and the fields the user
    did not set (in ``file_values`` or ``assignments``): ({estimator: {field: value}}, a note
    per value saying where it came from). Pass the first to ``build(log_values=...)``. Each
    estimator says which (``Estimator.log_defaults``: eq-kf's airspeed from an ArduPlane's
    cruise airspeed). ``flight``: a log's, or anything with its ``vehicle`` and ``params`` (a
    live vehicle's ``policy.FlightFacts``)."""
    from ..estimators import ESTIMATORS

    user = {(name, field) for name, table in (file_values or {}).items() for field in table}
    user |= {parse_assignment(text)[:2] for text in assignments}
    values, notes = {}, []
    for name in (n for n in names if n in ESTIMATORS):  # an unknown name: build says so
        for field, (value, said) in ESTIMATORS[name].log_defaults(flight.params, flight.vehicle).items():
            if (name, field) not in user:
                values.setdefault(name, {})[field] = value
                notes.append(f"{name} {field} {value:g} {said}")
    return values, notes


def to_toml(params: dict[str, dict[str, object]], comments: dict[str, str] | None = None) -> str:
    """{estimator: {field: value}} as the TOML ``load_file`` reads (a [NAME] table each), with
    a comment line above a table where ``comments`` has one. Floats are written with ``repr``,
    so they read back to the same bits."""
    lines = []
    for name, table in params.items():
        if comments and comments.get(name):
            lines += [f"# {line}".rstrip() for line in comments[name].splitlines()]
        lines.append(f'["{name}"]' if not re.fullmatch(r"[A-Za-z0-9_-]+", name) else f"[{name}]")
        for field, value in table.items():
            text = ("true" if value else "false") if isinstance(value, bool) else repr(value)
            lines.append(f"{field} = {text}")
        lines.append("")
    return "\n".join(lines)
