"""The evidence for ``imucheck``'s thresholds: what the IMU's rate does to every estimator, and
what the shared logs' accelerometers read at rest.

    python scripts/imu_rate_sweep.py rate [LOG ...] [--rates 400,100,50,25,20,10,5,2,1]
    python scripts/imu_rate_sweep.py accel [LOG ...]

``rate``: each log's chosen IMU point-sampled at lower rates (every k-th sample, as a telemetry
stream sends it), every estimator replayed against the simulator's truth; prints per rate the
tilt error (mean of roll and pitch MAE) / yaw MAE in degrees. Default logs: the SITL logs with
truth in ../shared/logs (sitl-copter-4.7-400hz.bin, sitl-plane-4.7-circuit.tlog).
``accel``: per log, the chosen IMU's median rate and its accelerometer's reading of g
(``imucheck.accel_at_rest``). Default: every log in ../shared/logs, its corpus/ and ulog/.
"""
from __future__ import annotations

import argparse
import sys
from dataclasses import replace
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
SHARED = ROOT.parent / "shared" / "logs"


def rate_sweep(paths: list[Path], rates: list[float]) -> None:
    import mavattitude
    from mavattitude.estimators import ESTIMATORS
    from mavattitude.flight import ImuSeries
    from mavattitude.readers import best_imu_source, imu_rate

    names = list(ESTIMATORS)
    for path in paths:
        flight = mavattitude.load(path)
        source = best_imu_source(flight)
        imu = flight.imu[source]
        print(f"{path.name}: {source} at {imu_rate(imu):.1f} Hz; tilt / yaw MAE (°) against the truth", flush=True)
        for rate in rates:
            every = slice(None, None, max(1, round(imu_rate(imu) / rate)))
            sampled = ImuSeries(imu.source, imu.t[every], imu.gyro[every], imu.accel[every],
                                None if imu.arrival is None else imu.arrival[every])
            result = mavattitude.replay(replace(flight, imu={source: sampled}), names, reference="truth", imu=source)
            cells = []
            for name in names:
                axes = result.comparisons[name].axes
                cells.append(f"{name} -" if axes["roll"] is None else
                             f"{name} {(axes['roll'].mae + axes['pitch'].mae) / 2:.2f}/{axes['yaw'].mae:.1f}")
            print(f"{imu_rate(sampled):6.1f} Hz  " + "  ".join(cells), flush=True)


def accel_readings(paths: list[Path]) -> None:
    import mavattitude
    from mavattitude.flight import GRAVITY
    from mavattitude.scoring.imucheck import accel_at_rest
    from mavattitude.readers import best_imu_source, imu_rate

    for path in paths:
        flight = mavattitude.load(path)
        imu = flight.imu[best_imu_source(flight)]
        g, at_rest = accel_at_rest(imu.t, imu.gyro, imu.accel)
        reading = "-" if g is None else f"{g:.3f} m/s² ({100 * (g / GRAVITY - 1):+.1f} %)"
        print(f"{path.name[:60]:60s} {imu.source:15s} {imu_rate(imu):6.1f} Hz  {reading} "
              f"{'at rest' if at_rest else 'whole log'}", flush=True)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("what", choices=("rate", "accel"))
    ap.add_argument("logs", nargs="*", type=Path)
    ap.add_argument("--rates", default="400,100,50,25,20,10,5,2,1", help="Hz, for rate")
    args = ap.parse_args()
    if args.what == "rate":
        rate_sweep(args.logs or [SHARED / "sitl-copter-4.7-400hz.bin", SHARED / "sitl-plane-4.7-circuit.tlog"],
                   [float(r) for r in args.rates.split(",")])
    else:
        accel_readings(args.logs or sorted(p for folder in (SHARED, SHARED / "corpus", SHARED / "ulog")
                                           for p in folder.glob("*") if p.suffix in (".bin", ".tlog", ".ulg")))
    return 0


if __name__ == "__main__":
    sys.exit(main())
