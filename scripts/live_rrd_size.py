"""How large a live session's `--rrd` recording grows: MB per hour of 1 kHz data.

The simulated autopilot of `mavattitude bench --live` streams RAW_IMU at 1 kHz and ATTITUDE at
50 Hz, ``--speed`` times real time for ``--seconds`` of wall time, to a live session writing a
Rerun recording (what `mavattitude live --rrd FILE` does); the recording's size is then
scaled to an hour of data. A file gets the plots, 3D boxes and diagnostics at the rates of
``live.display.FILE`` whatever the IMU rate, so the size per hour does not depend much on it.
Stream in real time (``--speed 1``): a file gets a chunk per entity every ``FILE.flush_s`` of
wall time, so a faster stream makes fewer, larger chunks than a real session would.

    python scripts/live_rrd_size.py --estimators all
"""
from __future__ import annotations

import argparse
import json
import tempfile
from pathlib import Path


def main() -> None:
    from mavattitude.commands.bench_live import LIVE_IMU_HZ, _probe_sender, _session_against
    from mavattitude.estimators import ESTIMATORS
    from mavattitude.view.live import FILE
    from mavattitude.view.sink import plan_sink
    from mavattitude.core.warmup import warm_up

    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--estimators", default="all", help="comma-separated names, or all")
    parser.add_argument("--speed", type=float, default=1.0, help="times real time (default 1)")
    parser.add_argument("--seconds", type=float, default=120.0, help="wall seconds of streaming (default 120)")
    args = parser.parse_args()
    names = list(ESTIMATORS) if args.estimators == "all" else args.estimators.split(",")
    warm_up(names)
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "live.rrd"
        sink = plan_sink("rrd", str(path))
        result = _session_against(_probe_sender, (args.speed, args.seconds * args.speed, str(Path(tmp) / "s.json")),
                                     names, record=None, request=False, sink=sink,
                                     duration=args.seconds + 120.0)
        sink.file.commit()
        sent = json.loads((Path(tmp) / "s.json").read_text())["sent"]
        mb = path.stat().st_size / 1e6
    hours = result.estimation.samples / LIVE_IMU_HZ / 3600
    print(f"{len(names)} estimators, {result.estimation.samples:,} IMU samples at {LIVE_IMU_HZ:g} Hz "
          f"({hours * 60:.1f} min of data; {sent:,} packets sent, {result.monitor.packets:,} received) "
          f"-> {mb:.1f} MB recording: {mb / hours:.0f} MB per hour "
          f"(plots in {FILE.scalar_hz:g} Hz bins, 3D at {FILE.transform_hz:g} Hz, diagnostics in "
          f"{FILE.diagnostic_hz:g} Hz bins)")


if __name__ == "__main__":
    main()
