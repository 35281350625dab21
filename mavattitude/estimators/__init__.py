"""The attitude estimators, by CLI name. Each module holds one, with its paper in the docstring.

``create`` makes one to run on your own arrays; ``register`` adds your own estimator class
(a subclass of ``Estimator``) so that the command lists and runs it too, as does a package
that names it in the entry point group ``mavattitude.estimators``.
"""
from __future__ import annotations

from .. import kernel_cache as _kernel_cache
from ..paramspec import make
from .alignment import Alignment, align
from .base import Estimator
from .base import needs_compile as _needs_compile
from .cpf_ekf import CpfEkf
from .ekf import Ekf
from .eq_kf import EqKf
from .eskf import Eskf
from .mahony import Mahony
from .mahony_ekf import MahonyEkf
from .ncs_eskf import NcsEskf
from .rivals import Imufusion, Vqf

__all__ = ["ESTIMATORS", "Alignment", "Estimator", "align", "all_names", "available", "create", "load_plugins", "needs_compile",
           "plugin_paths", "register", "register_from", "summary"]

ESTIMATORS: dict[str, type[Estimator]] = {
    Mahony.name: Mahony,
    MahonyEkf.name: MahonyEkf,
    Ekf.name: Ekf,
    Eskf.name: Eskf,
    NcsEskf.name: NcsEskf,
    EqKf.name: EqKf,
    CpfEkf.name: CpfEkf,
    Vqf.name: Vqf,  # the filters people use instead, for comparison: optional packages, not in 'all'
    Imufusion.name: Imufusion,
}

BUILT_IN = dict(ESTIMATORS)  # what every process has on import; the rest is registered at run time
_kernel_cache.refresh(Mahony.kernels[0])  # no stale kernel from older sources (see kernel_cache)


def summary(cls) -> str:
    """The first line of an estimator's module docstring (a filter from another project: its
    class docstring): what it is and which paper."""
    import sys
    doc = (cls.__doc__ if cls.requires else sys.modules[cls.__module__].__doc__) or cls.__doc__ or ""
    return doc.strip().splitlines()[0].rstrip(".") if doc.strip() else cls.name


ENTRY_POINT_GROUP = "mavattitude.estimators"


def all_names() -> list[str]:
    """What '--estimators all' runs: every registered estimator but the filters from other
    projects (``Estimator.in_all``), which are named explicitly."""
    return [name for name, cls in ESTIMATORS.items() if cls.in_all]


def available(name: str) -> str | None:
    """None when estimator ``name`` can run here; else why not, in a line with the pip command."""
    from .rivals import missing
    return missing(ESTIMATORS[name])


def create(name: str, params=None, declination: float = 0.0, **values) -> Estimator:
    """An estimator by name: with ``params`` (its parameter dataclass), or with parameter
    values by keyword (``create("mahony", kp=0.5)``), each checked against its valid range.
    ``declination``: rad, east positive. Call ``initialize(q0, gyro_bias)``, then ``update``."""
    if name not in ESTIMATORS:
        raise KeyError(f"unknown estimator {name!r}; choose from: {', '.join(ESTIMATORS)}")
    if values:
        params = make(name, ESTIMATORS[name].Params, {k: (v, "create()") for k, v in values.items()})
    return ESTIMATORS[name](params=params, declination=declination)


def register(cls: type[Estimator]) -> type[Estimator]:
    """Add an estimator class under its ``name`` (usable as a decorator). It needs ``name``,
    ``Params`` (a dataclass, fields declared with ``paramspec.param``) and ``initialize`` and
    ``update`` as ``Estimator`` describes them."""
    if not (isinstance(cls, type) and issubclass(cls, Estimator) and cls.name and cls.Params is not None):
        raise TypeError(f"{cls!r}: an estimator is an Estimator subclass with a name and a Params dataclass")
    if cls.name in ("autopilot", "all"):
        raise ValueError(f"{cls.name!r} is a reserved name")
    ESTIMATORS[cls.name] = cls
    return cls


def load_plugins() -> list[str]:
    """Register the estimators that installed packages name in the entry point group
    ``mavattitude.estimators``; returns what could not be loaded, a line each."""
    from importlib.metadata import entry_points

    problems = []
    for point in entry_points(group=ENTRY_POINT_GROUP):
        try:
            register(point.load())
        except Exception as exc:  # a broken plugin must not stop the command
            problems.append(f"estimator plugin {point.name} ({point.value}): {exc}")
    return problems


def plugin_paths(names) -> dict[str, str | None]:
    """Where each of these estimators that was registered at run time (a plugin, ``register``)
    lives, as "module:Class": what another process imports to register it too
    (``register_from``: evaluate's workers, the compiling processes). None for a class that no
    module holds (defined in ``__main__`` or in a function)."""
    out = {}
    for name in names:
        cls = ESTIMATORS[name]
        if BUILT_IN.get(name) is not cls:
            importable = cls.__module__ != "__main__" and "<locals>" not in cls.__qualname__
            out[name] = f"{cls.__module__}:{cls.__qualname__}" if importable else None
    return out


def register_from(paths) -> list[str]:
    """Register the estimator class at each "module:Class" (``plugin_paths``), importing its
    module: another process's plugins, here. Returns what could not be, a line each."""
    import importlib

    problems = []
    for path in paths:
        module, _, qualname = path.partition(":")
        try:
            cls = importlib.import_module(module)
            for part in qualname.split("."):
                cls = getattr(cls, part)
            register(cls)
        except Exception as exc:  # its logs fail naming the estimator; the others run
            problems.append(f"estimator {path}: {exc}")
    return problems


def needs_compile(names: list[str]) -> list[str]:
    """Which of these estimators will compile on first use (numba cache empty)."""
    return _needs_compile([ESTIMATORS[n] for n in names])
