"""The attitude estimators, by CLI name. Each module holds one, with its paper in the docstring."""
from __future__ import annotations

from .alignment import Alignment, align
from .base import Estimator, params_table
from .base import needs_compile as _needs_compile
from .cpf_ekf import CpfEkf
from .ekf import Ekf
from .eq_kf import EqKf
from .eskf import Eskf
from .mahony import Mahony
from .mahony_ekf import MahonyEkf
from .ncs_eskf import NcsEskf

ESTIMATORS: dict[str, type[Estimator]] = {
    Mahony.name: Mahony,
    MahonyEkf.name: MahonyEkf,
    Ekf.name: Ekf,
    Eskf.name: Eskf,
    NcsEskf.name: NcsEskf,
    EqKf.name: EqKf,
    CpfEkf.name: CpfEkf,
}


def summary(cls) -> str:
    """The first line of an estimator's module docstring: what it is and which paper."""
    import sys
    doc = sys.modules[cls.__module__].__doc__ or cls.__doc__ or ""
    return doc.strip().splitlines()[0].rstrip(".") if doc.strip() else cls.name


def create(name: str, params=None, declination: float = 0.0) -> Estimator:
    return ESTIMATORS[name](params=params, declination=declination)


def needs_compile(names: list[str]) -> list[str]:
    """Which of these estimators will compile on first use (numba cache empty)."""
    return _needs_compile([ESTIMATORS[n] for n in names])
