"""Regenerate sample_logs/: small simulated logs with ground truth, for demos and tests.

    python scripts/make_sample_logs.py

Deterministic: fixed scenarios, durations, rates and seeds give byte-identical files.
"""
from __future__ import annotations

import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))  # run from a checkout without installing

from mavattitude.sim import simulate, write_log  # noqa: E402

OUT = ROOT / "sample_logs"

# file name, scenario, duration s, IMU rate Hz, seed
SAMPLES = (
    ("figure8.tlog", "figure8", 100.0, 50.0, 1),
    ("figure8.bin", "figure8", 100.0, 100.0, 2),
    ("hover.tlog", "hover", 60.0, 50.0, 3),
    ("static.bin", "static", 60.0, 100.0, 4),
)


def main() -> None:
    OUT.mkdir(exist_ok=True)
    total = 0
    for name, scenario, duration, imu_rate, seed in SAMPLES:
        path = write_log(simulate(scenario, duration, seed=seed, imu_rate=imu_rate), OUT / name)
        size = path.stat().st_size
        total += size
        print(f"{path.relative_to(ROOT)}: {scenario}, {duration:g} s, IMU {imu_rate:g} Hz, "
              f"seed {seed}, {size / 1e6:.2f} MB")
    print(f"total {total / 1e6:.2f} MB")


if __name__ == "__main__":
    main()
