"""The project's flight simulator: known truth, realistic sensors, genuine ArduPilot logs.

    sim = simulate("figure8", 120.0, seed=1, imu_rate=400)
    write_log(sim, "figure8.bin")   # or .tlog, .ulg

``simulate`` returns a ``SimFlight`` (truth and sensor arrays, SI); ``write_log`` writes it as a
DataFlash .bin or a MAVLink 2 .tlog that pymavlink, and so our readers, read like a real log,
or as a PX4 ULog that pyulog reads. Files: ``trajectory`` (scenarios, true motion), ``sensors``
(error models), ``world`` (home, field, clocks; the ellipsoid and the atmosphere are the
package's ``earth``), ``simflight`` (``simulate``), ``tlog``, ``dataflash`` and ``ulog`` (writers).
"""
from __future__ import annotations

from pathlib import Path

from .dataflash import write_bin
from .sensors import Rates, SensorParams
from .simflight import SimFlight, simulate
from .tlog import write_tlog
from .trajectory import REGISTRY
from .ulog import write_ulog

SCENARIOS: dict[str, str] = {name: s.description for name, s in REGISTRY.items()}

_WRITERS = {".tlog": write_tlog, ".bin": write_bin, ".ulg": write_ulog}


def write_log(sim: SimFlight, path, suffix: str | None = None, imt: bool = False) -> Path:
    """Write ``sim`` as a .tlog, .bin or .ulg, chosen by ``suffix`` (default: that of ``path``);
    ``imt``: a .bin with delta angles and velocities too. Returns the path."""
    path = Path(path)
    writer = _WRITERS.get((suffix or path.suffix).lower())
    if writer is None:
        raise ValueError(f"{path}: cannot write a {path.suffix or 'suffix-less'} log; "
                         f"use a .tlog, .bin or .ulg file name")
    if imt:
        if writer is not write_bin:
            raise ValueError(f"{path}: delta angles (IMT) are DataFlash records; write a .bin")
        writer(sim, path, imt=True)
    else:
        writer(sim, path)
    return path


__all__ = ["SCENARIOS", "Rates", "SensorParams", "SimFlight", "simulate", "write_log"]
