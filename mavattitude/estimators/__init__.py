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


def warm_up(names: list[str], params: dict | None = None) -> None:
    """Run each estimator over a few synthetic samples, so its compiled kernel is loaded (or
    compiled) now rather than on the first samples of a live link."""
    import numpy as np

    from ..aiding import Aiding
    n = 5
    t = np.arange(n) * 0.01
    gyro = np.zeros((n, 3))
    accel = np.tile([0.0, 0.0, -9.80665], (n, 1))
    mag = np.tile([2e-5, 0.0, 4e-5], (n, 1))
    for name in names:
        e = create(name, (params or {}).get(name))
        e.initialize(np.array([1.0, 0.0, 0.0, 0.0]), np.zeros(3))
        extra = {"aiding": Aiding.empty(n)} if e.uses_aiding else {}
        e.update(t, gyro, accel, mag, np.zeros(n), **extra)
