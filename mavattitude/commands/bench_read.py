"""The reading figures of ``mavattitude bench --read``: how fast logs are read, and what an
hour-long replay costs end to end.

- ``.bin``: our reader (``readers.dataflash.read_dataflash``: every message type replay uses,
  decoded into SI columns) against pymavlink's type-filtered read of the same types
  (``DFReader_binary`` then ``recv_match(type=...)`` until the end), in CPU seconds, in the
  same run: on a simulated 1-hour 400 Hz log the simulator writes, and on any ``--log`` given.
- ``.tlog``: our reader (``readers.tlog.read_tlog``) against pymavlink's ``mavmmaplog`` with
  ``recv_match(type=...)`` of the types replay uses, on any ``--log`` given.
- ``.ulg``: our reader (``readers.ulog.read_ulog``: the topics replay uses, into SI columns)
  against pyulog's read of the same topics (``ULog(path, message_name_filter_list=TOPICS)``), on
  the simulated log written as a ULog too, and on any ``--log`` given.
- ``load()``: ``mavattitude.load`` end to end, timed as the ``readers.read_log`` it calls (the
  reader, then the clock, the checks and the series of a ``Flight``) against the same reference read (``x_pymavlink_load``, ``x_pyulog_load``), per log.
- End to end: ``mavattitude replay LOG --estimators all --rrd`` on the 1-hour log, in a child
  process (kernels compiled beforehand): wall time and peak RSS (the replay's own, as the
  kernel counts it: ``ru_maxrss``, in MB of 10^6 bytes), next to the size of the arrays the
  reader decoded (MB likewise). ``scripts/replay_memory.py`` says which phase the peak is in.
  The replay is started by a small process of its own (``LAUNCH``): a process started from this
  one starts its ``ru_maxrss`` at this one's peak (Linux takes the peak of the memory it leaves
  at ``exec``: this process's, shared until then), and this one has read the hour with pymavlink
  (some 700 MB).

Ours: best of ``repeat`` runs (the first compiles or loads the scan kernels); pymavlink's: one
run (it takes seconds to minutes), pyulog's likewise. With ``repeat`` above 1, a read shorter than
that is run again until ``MIN_TIMED_S`` of CPU is spent, ours and the reference alike, and the
best run counts (``--repeat 1``: one run each, for a quick look): a read of
a few milliseconds moves by half with the heap from one run to the next (the 4 MB ``.ulg`` read
8-14x pyulog in single runs).

Targets: ``.bin`` decode at least ``MIN_X_PYMAVLINK`` times pymavlink's, ``load()`` of a ``.bin`` at
least ``MIN_X_LOAD`` times; ``.ulg`` at least ``MIN_X_PYULOG`` times pyulog's; the hour through all
seven estimators, metrics and recording within ``MAX_END_TO_END_S`` (a shorter simulated log:
its share of it); its peak RSS is reported
against ``MAX_RSS_X_DECODED`` times the decoded arrays.
"""
from __future__ import annotations

import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

MIN_X_PYMAVLINK = 15.0
MIN_X_LOAD = 10.0  # load() does more than decode: the clock, the checks, the Flight's series
MIN_X_PYULOG = 10.0
MAX_END_TO_END_S = 30.0
MAX_RSS_X_DECODED = 3.0
MIN_TIMED_S = 1.0  # CPU s: a short read is repeated until this much is spent, its best run counts
MAX_RUNS = 500


def _cpu(fn, repeat: int, at_least_s: float) -> float:
    """The best CPU time of at least ``repeat`` calls of ``fn``, and of more while they have
    taken less than ``at_least_s`` together (at most ``MAX_RUNS``)."""
    best, spent, runs = float("inf"), 0.0, 0
    while runs < repeat or (spent < at_least_s and runs < MAX_RUNS):
        start = time.process_time()
        fn()
        took = time.process_time() - start
        best, spent, runs = min(best, took), spent + took, runs + 1
    return best


def _pymavlink_bin(path: str) -> int:
    from pymavlink import DFReader

    from ..readers.dataflash import WANTED

    log = DFReader.DFReader_binary(path, zero_time_base=True)
    n = 0
    while log.recv_match(type=WANTED) is not None:
        n += 1
    return n


def _pymavlink_tlog(path: str) -> int:
    from pymavlink import mavutil

    from ..readers.tlog import OTHER_MESSAGES, SAMPLE_MESSAGES, STREAM_MESSAGES

    mavutil.set_dialect("ardupilotmega")
    log = mavutil.mavmmaplog(path)
    n = 0
    while log.recv_match(type=list(SAMPLE_MESSAGES + STREAM_MESSAGES + OTHER_MESSAGES)) is not None:
        n += 1
    return n


def _pyulog(path: str) -> int:
    from pyulog import ULog

    from ..readers.ulog import TOPICS

    return len(ULog(path, message_name_filter_list=TOPICS, disable_str_exceptions=True).data_list)


def read_figures(path: str, repeat: int = 3) -> dict:
    """Our reader and the reference one (pymavlink's, or pyulog for a ULog) on one log: CPU
    seconds, MB/s and the ratio, under keys that name the reference (``x_pymavlink``, ``x_pyulog``)."""
    from ..readers import read_log, sniff_format
    from ..readers.dataflash import read_dataflash
    from ..readers.tlog import read_tlog
    from ..readers.ulog import read_ulog

    kind = sniff_format(path)
    reader, reference, theirs_fn = {"bin": (read_dataflash, "pymavlink", _pymavlink_bin),
                                    "tlog": (read_tlog, "pymavlink", _pymavlink_tlog),
                                    "ulg": (read_ulog, "pyulog", _pyulog)}[kind]
    at_least_s = MIN_TIMED_S if repeat > 1 else 0.0
    ours = _cpu(lambda: reader(path), repeat, at_least_s)
    loaded = _cpu(lambda: read_log(path), repeat, at_least_s)
    theirs = _cpu(lambda: theirs_fn(path), 1, at_least_s)
    mb = os.path.getsize(path) / 1e6
    return {"log": path, "format": kind, "mb": round(mb, 2), "reference": reference, "ours_s": round(ours, 6),
            f"{reference}_s": round(theirs, 6), "ours_mb_s": round(mb / ours, 1),
            f"{reference}_mb_s": round(mb / theirs, 1), f"x_{reference}": round(theirs / ours, 1),
            "load_s": round(loaded, 6), f"x_{reference}_load": round(theirs / loaded, 1)}


def decoded_mb(path: str) -> float:
    """The size of the arrays the reader hands over for a log (every series of the flight)."""
    import numpy as np

    from ..readers import read_log

    flight = read_log(path)
    series = [*flight.imu.values(), *flight.mag.values(), flight.gps, flight.baro, flight.attitude, flight.truth]
    return sum(v.nbytes for s in series if s is not None for v in vars(s).values()
               if isinstance(v, np.ndarray)) / 1e6


# Runs a command and prints its exit code, ru_maxrss and wall seconds (see the module docstring).
LAUNCH = ("import os, subprocess, sys, time; start = time.perf_counter(); "
          "child = subprocess.Popen(sys.argv[1:], stdout=subprocess.DEVNULL); "
          "_, status, usage = os.wait4(child.pid, 0); "
          "print(os.waitstatus_to_exitcode(status), usage.ru_maxrss, time.perf_counter() - start)")


def end_to_end(path: str, out_dir: str) -> dict:
    """``replay --estimators all --rrd`` on ``path`` in a child process: wall s and peak RSS."""
    command = [sys.executable, "-m", "mavattitude", "replay", path, "--estimators", "all",
               "--rrd", str(Path(out_dir) / "replay.rrd")]
    errors = Path(out_dir) / "replay.err"  # a file, not a pipe: a full pipe would stall the child
    with open(errors, "w") as err:
        # pymavlink's import sets MAVLINK_DIALECT=all in this process's environment when unset;
        # a replay given it would load that larger dialect (13 MB) rather than its own
        env = {k: v for k, v in os.environ.items() if k != "MAVLINK_DIALECT"}
        said = subprocess.run([sys.executable, "-c", LAUNCH, *command], stdout=subprocess.PIPE, stderr=err,
                              text=True, env=env).stdout.split()
    if len(said) != 3 or said[0] != "0":
        raise RuntimeError(f"replay failed: {errors.read_text(errors='replace').strip()}")
    # in MB of 10^6 bytes, as decoded_mb: macOS counts bytes, Linux KiB
    peak_mb = int(said[1]) * (1 if sys.platform == "darwin" else 1024) / 1e6
    wall = float(said[2])
    return {"wall_s": round(wall, 2), "peak_rss_mb": round(peak_mb, 1),
            "rrd_mb": round((Path(out_dir) / "replay.rrd").stat().st_size / 1e6, 1)}


def run_read_bench(logs: list[str], scenario: str = "figure8", duration: float = 3600.0,
                   imu_rate: float = 400.0, repeat: int = 3, say=print) -> dict:
    """Every figure (see the module docstring); ``logs``: real logs to read besides the
    simulated one (``duration`` s of ``scenario`` at ``imu_rate``: by default, the hour)."""
    from ..estimators import ESTIMATORS, needs_compile
    from ..core.warmup import precompile
    from ..readers import read_log

    precompile(needs_compile(list(ESTIMATORS))).wait()
    with tempfile.TemporaryDirectory(prefix="mavattitude-bench-") as tmp:
        hour, hour_ulog = str(Path(tmp) / "simulated.bin"), str(Path(tmp) / "simulated.ulg")
        label = f"simulated {scenario} {duration / 60:g} min at {imu_rate:g} Hz"
        say(f"{label}: writing it (.bin and .ulg) ...")
        for path in (hour, hour_ulog):
            subprocess.run([sys.executable, "-m", "mavattitude", "simulate", "--scenario", scenario,
                            "--duration", str(duration), "--imu-rate", str(imu_rate), "-o", path],
                           check=True, stdout=subprocess.DEVNULL)
        say(f"{label}: replaying it with every estimator ...")
        read_log(hour)  # the reader's kernels compiled (a first run) here, not in the timed replay
        e2e = end_to_end(hour, tmp)
        reads = []
        for path in [*logs, hour_ulog, hour]:
            say(f"reading {path} (ours, then the reference reader's) ...")
            reads.append(read_figures(path, repeat))
        reads[-2]["log"] = f"{label} (.ulg)"
        reads[-1]["log"] = label
        os.remove(hour_ulog)
        e2e["decoded_mb"] = round(decoded_mb(hour), 1)
    e2e["rss_x_decoded"] = round(e2e["peak_rss_mb"] / e2e["decoded_mb"], 2)
    bins = [r for r in reads if r["format"] == "bin"]
    ulogs = [r for r in reads if r["format"] == "ulg"]
    # the target is for an hour at 400 Hz; a shorter log gets its share
    end_to_end_s = MAX_END_TO_END_S * (duration * imu_rate) / (3600.0 * 400.0)
    return {"reads": reads, "end_to_end": e2e, "targets": {
        "bin_x_pymavlink": MIN_X_PYMAVLINK, "x_pymavlink_load": MIN_X_LOAD, "ulg_x_pyulog": MIN_X_PYULOG,
        "end_to_end_s": round(end_to_end_s, 4), "rss_x_decoded": MAX_RSS_X_DECODED},
        "met": {"bin_x_pymavlink": all(r["x_pymavlink"] >= MIN_X_PYMAVLINK for r in bins),
                "x_pymavlink_load": all(r["x_pymavlink_load"] >= MIN_X_LOAD for r in bins),
                "ulg_x_pyulog": all(r["x_pyulog"] >= MIN_X_PYULOG for r in ulogs),
                "end_to_end_s": e2e["wall_s"] <= end_to_end_s,
                "rss_x_decoded": e2e["rss_x_decoded"] <= MAX_RSS_X_DECODED}}


def format_read(result: dict) -> str:
    def met(key):
        return "yes" if result["met"][key] else "NO"
    lines = ["", "Reading the message types replay uses (CPU s, each reader's best run; a read under 1 s "
                 "repeated for 1 s; reference: pymavlink, pyulog for .ulg)",
             f"{'log':58s} {'MB':>7s} {'ours s':>8s} {'MB/s':>7s} {'reference':>9s} {'s':>8s} {'MB/s':>6s} {'x':>6s}"
             f" {'load() s':>9s} {'x':>6s}"]
    for r in result["reads"]:
        name = r["log"] if len(r["log"]) <= 58 else "..." + r["log"][-55:]
        ref = r["reference"]
        lines.append(f"{name:58s} {r['mb']:7.1f} {r['ours_s']:8.3f} {r['ours_mb_s']:7.0f} {ref:>9s} "
                     f"{r[ref + '_s']:8.2f} {r[ref + '_mb_s']:6.0f} {r['x_' + ref]:5.1f}x"
                     f" {r['load_s']:9.3f} {r['x_' + ref + '_load']:5.1f}x")
    e = result["end_to_end"]
    t = result["targets"]
    lines += ["", f"End to end: replay --estimators all --rrd on the {result['reads'][-1]['log']} (a child process)",
              f"  wall {e['wall_s']:.1f} s, peak RSS {e['peak_rss_mb']:.0f} MB = {e['rss_x_decoded']:.1f}x the "
              f"{e['decoded_mb']:.0f} MB of decoded arrays, recording {e['rrd_mb']:.0f} MB",
              f"targets: .bin read >= {t['bin_x_pymavlink']:g}x pymavlink: {met('bin_x_pymavlink')}; "
              f".bin load() >= {t['x_pymavlink_load']:g}x pymavlink: {met('x_pymavlink_load')}; "
              f".ulg read >= {t['ulg_x_pyulog']:g}x pyulog: {met('ulg_x_pyulog')}; "
              f"replay <= {t['end_to_end_s']:g} s ({MAX_END_TO_END_S:g} s for 1 h at 400 Hz): {met('end_to_end_s')}; "
              f"peak RSS <= {t['rss_x_decoded']:g}x decoded: {met('rss_x_decoded')}"]
    return "\n".join(lines) + "\n"
