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
import math
import re
import sys
from dataclasses import dataclass

from .errors import InputError, UsageError, check_not_special

if sys.version_info >= (3, 11):
    import tomllib
else:  # pragma: no cover - Python 3.10
    import tomli as tomllib


@dataclass(frozen=True)
class Interval:
    """The values a parameter may take: from ``lo`` to ``hi``, each end closed or open."""
    lo: float
    hi: float
    lo_closed: bool
    hi_closed: bool

    @classmethod
    def parse(cls, text: str) -> Interval:
        m = re.fullmatch(r"\s*([\[(])\s*([^,\s]+)\s*,\s*([^\])\s]+)\s*([\])])\s*", text)
        if not m:
            raise ValueError(f"not an interval: {text!r} (write e.g. '[0, inf)' or '(0, 1]')")
        return cls(float(m.group(2)), float(m.group(3)), m.group(1) == "[", m.group(4) == "]")

    def __contains__(self, x: float) -> bool:
        above = x >= self.lo if self.lo_closed else x > self.lo
        below = x <= self.hi if self.hi_closed else x < self.hi
        return above and below

    def __str__(self) -> str:
        def end(v):  # 1e6 and 1e-12, as they are declared, not 1e+06 and 1e-12
            return "inf" if v == math.inf else "-inf" if v == -math.inf else re.sub(r"e\+?(-?)0*(\d)", r"e\1\2", f"{v:g}")
        return f"{'[' if self.lo_closed else '('}{end(self.lo)}, {end(self.hi)}{']' if self.hi_closed else ')'}"


@dataclass(frozen=True)
class Search:
    """The range ``tune`` searches for a parameter: from ``lo`` to ``hi``, on a log or linear
    scale, whole numbers when the default is one."""
    lo: float
    hi: float
    log: bool
    integer: bool

    @classmethod
    def parse(cls, text: str, default) -> Search:
        scale, _, interval = text.strip().partition(" ")
        if scale not in ("log", "linear"):
            raise ValueError(f"a search range starts with 'log' or 'linear', not {text!r}")
        span = Interval.parse(interval)
        search = cls(span.lo, span.hi, scale == "log", isinstance(default, int))
        if not (span.lo_closed and span.hi_closed and span.lo < span.hi):
            raise ValueError(f"a search range is closed and not empty, e.g. 'log [0.01, 10]', not {text!r}")
        if search.log and span.lo <= 0:
            raise ValueError(f"a log-scale search range starts above 0, not {text!r}")
        return search

    def __str__(self) -> str:
        return f"{'log' if self.log else 'linear'} [{self.lo:g}, {self.hi:g}]"


def param(default, valid: str | None = None, tune: str | None = None):
    """A parameter field: its default and, for numbers, the interval of values that mean
    something (``valid``, e.g. ``"(0, inf)"`` for a noise density) and the range ``tune``
    searches (``tune``, e.g. ``"log [1e-4, 0.1]"``; None: fixed when tuning)."""
    if valid is None and not isinstance(default, bool):
        raise ValueError("a numeric parameter declares its valid interval")
    interval = Interval.parse(valid) if valid is not None else None
    if interval is not None and default not in interval:
        raise ValueError(f"default {default!r} is outside its own valid interval {interval}")
    search = None
    if tune is not None:
        if interval is None:
            raise ValueError("a flag is not tuned")
        search = Search.parse(tune, default)
        if search.lo not in interval or search.hi not in interval:
            raise ValueError(f"search range {search} leaves the valid interval {interval}")
        if not search.lo <= default <= search.hi:
            raise ValueError(f"default {default!r} is outside its own search range {search}")
    return dataclasses.field(default=default, metadata={"valid": interval, "search": search})


def valid_interval(params_class, name: str) -> Interval | None:
    """The valid interval ``param`` declared for a field (None for a flag)."""
    return {f.name: f.metadata.get("valid") for f in dataclasses.fields(params_class)}[name]


def search_space(params_class) -> dict[str, Search]:
    """{field: the range ``tune`` searches} for the fields ``param`` gave one, in field order."""
    return {f.name: f.metadata["search"] for f in dataclasses.fields(params_class) if f.metadata.get("search")}


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
            _fail(values[name][next(iter(values[name]))][1],
                  f"unknown estimator {name!r}; choose from: {', '.join(ESTIMATORS)}")
        if name not in names and any(origin == "--set" for _, origin in values[name].values()):
            _fail("--set", f"{name} is not among the estimators run ({', '.join(names)}): "
                           f"--set {name}.… would do nothing")
    params = {}
    for name in [*names, *(n for n in values if n not in names)]:
        cls = ESTIMATORS[name].Params
        defaults = cls()
        changes, origins = {}, {}
        known = {f.name: f for f in dataclasses.fields(defaults)}
        for field, (value, origin) in values.get(name, {}).items():
            if field not in known:
                _fail(origin, f"{name} has no parameter {field!r}; it has: "
                              f"{', '.join(known)} (see 'mavattitude estimators')")
            where = f"{name}.{field}"
            changes[field] = convert(value, getattr(defaults, field), where, origin)
            interval = known[field].metadata.get("valid")
            if interval is not None and changes[field] not in interval:
                _fail(origin, f"{where} = {changes[field]:g} is outside its valid range {interval}")
            origins[field] = origin
        chosen = dataclasses.replace(defaults, **changes)
        for lo, hi in getattr(cls, "ORDERED", ()):
            if not getattr(chosen, lo) < getattr(chosen, hi):
                _fail(origins.get(lo, origins.get(hi, "--set")),
                      f"{name}.{lo} ({getattr(chosen, lo):g}) must be below {name}.{hi} ({getattr(chosen, hi):g})")
        params[name] = chosen
    return {name: params[name] for name in names}


def _fail(origin: str, problem: str):
    """A bad value from the command line is a usage error (exit 2); from a file, an error in
    that file (exit 1), named."""
    if origin in ("--set", "log"):
        raise UsageError(f"{origin}: {problem}")
    raise InputError(origin, problem)


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


def convert(value, default, where: str, origin: str = "--set"):
    """``value`` (a string from --set, or a TOML value) as the type of ``default``."""
    if isinstance(default, bool):
        if isinstance(value, bool):
            return value
        text = str(value).strip().lower()
        if text in ("true", "yes", "on", "1"):
            return True
        if text in ("false", "no", "off", "0"):
            return False
        _fail(origin, f"{where}: expected true or false, got {value!r}")
    if isinstance(default, (int, float)):
        try:
            number = float(value) if not isinstance(value, bool) else None
        except (TypeError, ValueError):
            number = None
        if number is None or not math.isfinite(number):
            _fail(origin, f"{where}: expected a finite number, got {value!r}")
        if isinstance(default, int):
            if number != int(number):
                _fail(origin, f"{where}: expected a whole number, got {value!r}")
            return int(number)
        return number
    _fail(origin, f"{where}: this parameter cannot be set")


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


def describe(params_class) -> list[tuple[str, object, Interval | None, str]]:
    """(field, default, valid interval, comment) for each parameter of a params dataclass; the
    comment is the one written after the field in its source, so the code stays the one place
    it is said."""
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
    return [(f.name, getattr(defaults, f.name), f.metadata.get("valid"), comments.get(f.name, ""))
            for f in dataclasses.fields(defaults)]
