"""What each IMU family (``--imu-source``) is worth, on simulated truth.

    python scripts/imu_source_gain.py [--duration 300] [--estimators all]

Simulated flights (figure8 and circle, 50 and 400 Hz) are written as .bin with IMT delta angles
and velocities (``simulate --imt``) and replayed from the main-loop samples (``imu``) and from
the deltas (``delta``); where ../shared/logs/sitl-copter-4.7-400hz.bin is present (ArduPilot
SITL with sensor-rate GYR/ACC), ``imu`` and ``raw`` are replayed on it. Prints, per estimator,
the tilt error (mean of roll and pitch MAE) and the yaw MAE against the truth, in degrees.
"""
from __future__ import annotations

import argparse
import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
SITL = ROOT.parent / "shared" / "logs" / "sitl-copter-4.7-400hz.bin"


def scores(flight, names, family) -> dict[str, tuple[float, float]]:
    import mavattitude

    result = mavattitude.replay(flight, names, reference="truth", imu_source=family)
    rows = result.metrics["estimators"]
    return {n: ((rows[n]["roll"]["mae"] + rows[n]["pitch"]["mae"]) / 2, rows[n]["yaw"]["mae"]) for n in names}


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--duration", type=float, default=300.0)
    ap.add_argument("--estimators", default="all")
    args = ap.parse_args()
    import mavattitude
    from mavattitude.estimators import ESTIMATORS
    from mavattitude.sim import simulate, write_log

    names = list(ESTIMATORS) if args.estimators == "all" else args.estimators.split(",")
    cases = []
    with tempfile.TemporaryDirectory() as tmp:
        for scenario in ("figure8", "circle"):
            for rate in (50.0, 400.0):
                path = write_log(simulate(scenario, args.duration, seed=1, imu_rate=rate),
                                 Path(tmp) / f"{scenario}-{rate:g}.bin", imt=True)
                cases.append((f"{scenario} {rate:g} Hz", mavattitude.load(path), ("imu", "delta")))
        if SITL.exists():
            cases.append(("SITL 4.7 (IMU 400 Hz, GYR 1.2 kHz)", mavattitude.load(SITL), ("imu", "raw")))
        print("tilt / yaw MAE against the truth, degrees")
        print(f"{'flight':38s} {'source':6s} " + " ".join(f"{n:>15s}" for n in names))
        for label, flight, families in cases:
            for family in families:
                row = scores(flight, names, family)
                print(f"{label:38s} {family:6s} " + " ".join(f"{row[n][0]:7.3f}/{row[n][1]:<7.2f}" for n in names),
                      flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
