"""What an estimator parameter is: its default, the interval of values that mean something,
and the range ``tune`` searches (``param``), and how a value is checked against that.

At the bottom of the package (it imports only ``errors``), so every estimator module can declare
its parameters here without importing the registry or anything that runs estimators;
``params`` builds the parameter sets of a run from these declarations (``--params``, ``--set``
and the log's defaults). See ``params`` for the notation.
"""
from __future__ import annotations

import dataclasses
import inspect
import math
import re
from dataclasses import dataclass

from .errors import InputError, UsageError


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


def make(name: str, params_class, values: dict[str, tuple[object, str]]):
    """An instance of ``params_class`` (estimator ``name``'s) with ``values`` ({field: (value,
    where it came from)}) over its defaults: each converted to the field's type and checked
    against its valid interval, and the class's ``ORDERED`` pairs checked; an error names the
    value's origin (``fail``)."""
    defaults = params_class()
    changes, origins = {}, {}
    known = {f.name: f for f in dataclasses.fields(defaults)}
    for field, (value, origin) in values.items():
        if field not in known:
            fail(origin, f"{name} has no parameter {field!r}; it has: "
                         f"{', '.join(known)} (see 'mavattitude estimators')")
        where = f"{name}.{field}"
        changes[field] = convert(value, getattr(defaults, field), where, origin)
        interval = known[field].metadata.get("valid")
        if interval is not None and changes[field] not in interval:
            fail(origin, f"{where} = {changes[field]:g} is outside its valid range {interval}")
        origins[field] = origin
    chosen = dataclasses.replace(defaults, **changes)
    for lo, hi in getattr(params_class, "ORDERED", ()):
        if not getattr(chosen, lo) < getattr(chosen, hi):
            fail(origins.get(lo, origins.get(hi, "--set")),
                 f"{name}.{lo} ({getattr(chosen, lo):g}) must be below {name}.{hi} ({getattr(chosen, hi):g})")
    return chosen


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
        fail(origin, f"{where}: expected true or false, got {value!r}")
    if isinstance(default, (int, float)):
        try:
            number = float(value) if not isinstance(value, bool) else None
        except (TypeError, ValueError):
            number = None
        if number is None or not math.isfinite(number):
            fail(origin, f"{where}: expected a finite number, got {value!r}")
        if isinstance(default, int):
            if number != int(number):
                fail(origin, f"{where}: expected a whole number, got {value!r}")
            return int(number)
        return number
    fail(origin, f"{where}: this parameter cannot be set")


def fail(origin: str, problem: str):
    """A bad value from the command line is a usage error (exit 2); from a file, an error in
    that file (exit 1), named."""
    if origin in ("--set", "log"):
        raise UsageError(f"{origin}: {problem}")
    raise InputError(origin, problem)


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
