#!/usr/bin/env python3
"""How far behind the data live's final scores wait for replay's reference checks, and whether
live's flagged spans are replay's, on .tlog recordings fed to ``LiveEstimation`` a packet at a time.

    python scripts/live_check_lag.py [LOG.tlog ...]     # default: sample_logs/figure8.tlog

Per log: the spans live flags against those replay flags on the same file, and, at each scoring,
the reference's latest time less the time before which the checks have settled (the samples
after it wait: ``running_refcheck``), as median, 95th percentile and maximum.
"""
from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
from pymavlink import mavutil

ROOT = Path(__file__).resolve().parents[1]


def main(paths: list[str]) -> int:
    from mavattitude.commands.replay import run_replay
    from mavattitude.core.policy import RunOptions
    from mavattitude.live.estimation import LiveEstimation
    from mavattitude.readers import read_log

    lags: list[float] = []

    class Watched(LiveEstimation):
        def _check(self, seg, ref, final):
            out = super()._check(seg, ref, final)
            if not final:
                lags.append(float(ref.t[-1]) - out[1])
            return out

    for path in paths:
        lags.clear()
        est = Watched(RunOptions(["mahony"]))
        log = mavutil.mavlink_connection(path, robust_parsing=True)
        n = 0
        while (msg := log.recv_msg()) is not None:
            if msg.get_type() != "BAD_DATA" and msg.get_srcSystem() == 1:
                est.add(msg)
                n += 1
                if n % 7 == 0:
                    est.step()
        est.step(final=True)
        comparisons, seg = est.final_comparisons()
        replay = run_replay(read_log(path), ["mahony"], imu=seg.imu_key)
        same = est.suspects == replay.suspects
        a = np.array(lags)
        print(f"{Path(path).name}: {len(est.suspects)} spans flagged live, {len(replay.suspects)} by replay, "
              f"{'the same' if same else 'DIFFERENT'}; scoring waits {np.median(a):.2f} s median, "
              f"{np.percentile(a, 95):.2f} s 95th percentile, {a.max():.2f} s at most; mahony roll n "
              f"{comparisons['mahony'].axes['roll'].n} live, {replay.comparisons['mahony'].axes['roll'].n} replay")
        for s in est.suspects:
            print(f"  {s.kind} {s.start:.1f}-{s.end:.1f} s: {s.detail}")
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:] or [str(ROOT / "sample_logs" / "figure8.tlog")]))
