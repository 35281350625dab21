"""Estimator parameters from the command line and from a TOML file.

Every estimator's parameters are a small dataclass with the paper's defaults. A user
overrides them with ``--params FILE`` (a TOML table per estimator) and ``--set
NAME.FIELD=VALUE`` (applied after the file, so the command line wins). Below both, a log can
supply a default of its own (``log_defaults``: eq-kf's airspeed from an ArduPlane's cruise
airspeed)::

    [ncs-eskf]
    h_threshold_air = 0.02

    [mahony]
    kp = 0.5
"""
from __future__ import annotations

import dataclasses
import inspect
import re
import sys

from .errors import InputError, UsageError

if sys.version_info >= (3, 11):
    import tomllib
else:  # pragma: no cover - Python 3.10
    import tomli as tomllib


def load_file(path: str) -> dict[str, dict[str, object]]:
    """{estimator: {field: value}} from a TOML file."""
    try:
        with open(path, "rb") as f:
            data = tomllib.load(f)
    except FileNotFoundError:
        raise InputError(path, "no such file") from None
    except IsADirectoryError:
        raise InputError(path, "is a folder, not a TOML file") from None
    except (tomllib.TOMLDecodeError, UnicodeDecodeError) as exc:
        raise InputError(path, f"not valid TOML: {exc}") from None
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
    ``log_values`` (see ``log_defaults``), then the file, then the assignments."""
    from .estimators import ESTIMATORS

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
            raise UsageError(f"{values[name][next(iter(values[name]))][1]}: unknown estimator {name!r}; "
                             f"choose from: {', '.join(ESTIMATORS)}")
    params = {}
    for name in names:
        defaults = ESTIMATORS[name].Params()
        changes = {}
        known = {f.name: f for f in dataclasses.fields(defaults)}
        for field, (value, origin) in values.get(name, {}).items():
            if field not in known:
                raise UsageError(f"{origin}: {name} has no parameter {field!r}; it has: "
                                 f"{', '.join(known)} (see 'mavattitude estimators')")
            changes[field] = convert(value, getattr(defaults, field), f"{origin}: {name}.{field}")
        params[name] = dataclasses.replace(defaults, **changes)
    return params


def log_defaults(flight, names: list[str], file_values: dict | None = None,
                 assignments: list[str] = ()) -> tuple[dict, list[str]]:
    """Defaults the log itself supplies, for the estimators in ``names`` and the fields the user
    did not set (in ``file_values`` or ``assignments``): ({estimator: {field: value}}, a note
    per value saying where it came from). Pass the first to ``build(log_values=...)``.

    - eq-kf ``airspeed`` (turn compensation) on an ArduPlane log: a plane flies at about its
      cruise airspeed, TRIM_ARSPD_CM (cm/s; AIRSPEED_CRUISE, m/s, from Plane 4.5 on).
    """
    found: dict[str, dict[str, tuple[object, str]]] = {}
    if flight.vehicle == "ArduPlane":
        for key, scale in (("TRIM_ARSPD_CM", 0.01), ("AIRSPEED_CRUISE", 1.0)):
            value = flight.params.get(key)
            if value is not None and value == value and 0.0 < value * scale < 200.0:
                found.setdefault("eq-kf", {})["airspeed"] = (float(value) * scale, key)
                break
    user = {(name, field) for name, table in (file_values or {}).items() for field in table}
    user |= {parse_assignment(text)[:2] for text in assignments}
    values, notes = {}, []
    for name, table in found.items():
        for field, (value, key) in table.items():
            if name in names and (name, field) not in user:
                values.setdefault(name, {})[field] = value
                notes.append(f"{name} {field} {value:g} m/s from {key} (the plane's cruise airspeed)")
    return values, notes


def convert(value, default, where: str):
    """``value`` (a string from --set, or a TOML value) as the type of ``default``."""
    if isinstance(default, bool):
        if isinstance(value, bool):
            return value
        text = str(value).strip().lower()
        if text in ("true", "yes", "on", "1"):
            return True
        if text in ("false", "no", "off", "0"):
            return False
        raise UsageError(f"{where}: expected true or false, got {value!r}")
    if isinstance(default, (int, float)):
        try:
            number = float(value) if not isinstance(value, bool) else None
        except (TypeError, ValueError):
            number = None
        if number is None or number != number or number in (float("inf"), float("-inf")):
            raise UsageError(f"{where}: expected a number, got {value!r}")
        if isinstance(default, int):
            if number != int(number):
                raise UsageError(f"{where}: expected a whole number, got {value!r}")
            return int(number)
        return number
    raise UsageError(f"{where}: this parameter cannot be set")


def describe(params_class) -> list[tuple[str, object, str]]:
    """(field, default, comment) for each parameter of a params dataclass; the comment is the
    one written after the field in its source, so the code stays the one place it is said."""
    comments = {}
    try:
        source = inspect.getsource(params_class)
    except (OSError, TypeError):
        source = ""
    for line in source.splitlines():
        m = re.match(r"\s*(\w+)\s*:[^#]*#\s*(.*)", line)
        if m:
            comments[m.group(1)] = m.group(2).strip()
    defaults = params_class()
    return [(f.name, getattr(defaults, f.name), comments.get(f.name, ""))
            for f in dataclasses.fields(defaults)]
