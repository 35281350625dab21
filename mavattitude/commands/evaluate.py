"""``mavattitude evaluate``: replay a collection of logs, as ``replay`` does each one, and rank
the estimators across them.

One record per log (``--out``/logs/<name>.json: the log's facts and its metrics, or why it
failed) is written as soon as the log is done, so a run stopped half-way resumes where it
stopped. The logs run in a local process pool, or on a Dask cluster (``--scheduler``); the
records are the same either way. ``summarize`` turns the records into the tables of
``evalreport``.
"""
from __future__ import annotations

import glob
import hashlib
import json
import os
import secrets
import sys
import tempfile
import time
from dataclasses import asdict
from pathlib import Path

import numpy as np

from ..errors import InputError, UsageError, check_not_special, reraise_interrupt, special_file
from ..core.policy import RunOptions
from .replay import NoReference
from ..progress import clock

LOG_SUFFIXES = (".bin", ".tlog", ".ulg", ".hdf5", ".h5")  # .hdf5/.h5: BROAD trials
RECORD_VERSION = 2  # 2: the reference as an object, its stream, algorithm and spread, the autopilot's streams
INTERNAL_ERROR = "internal error"  # a record's error that is our fault, not the log's: redone on resume


# ---------------------------------------------------------------- which logs


def find_logs(paths: list[str], passed: list[str] | None = None) -> list[str]:
    """The logs named by ``paths``: files as given, folders searched recursively for .bin,
    .tlog, .ulg and .hdf5/.h5 (BROAD) files (any case) that are logs by their content, and glob patterns. In order,
    each once; InputError for a path that names nothing, or a file named that is no regular file.
    A FIFO or device a folder or pattern holds is passed by, and its path added to ``passed``."""
    from ..readers import sniff_format
    from ..readers.broad import NEEDS_H5PY

    found: list[str] = []
    for path in paths:
        if os.path.isdir(path):
            for root, dirs, files in os.walk(path):
                dirs.sort()
                for name in sorted(files):
                    if name.lower().endswith(LOG_SUFFIXES):
                        candidate = os.path.join(root, name)
                        if special_file(candidate):  # opening a FIFO would wait for a writer forever
                            if passed is not None:
                                passed.append(f"{candidate} ({special_file(candidate)})")
                            continue
                        try:
                            sniff_format(candidate)
                        except InputError as exc:
                            if exc.problem != NEEDS_H5PY:  # a BROAD trial without h5py fails, saying why
                                continue  # a .bin that is no log (firmware, say) is not ours to replay
                        found.append(candidate)
        elif os.path.exists(path):
            check_not_special(path)
            found.append(path)  # named on purpose: replayed, and failing with its reason if it must
        elif glob.has_magic(path):
            matches = sorted(glob.glob(path, recursive=True))
            if not matches:
                raise InputError(path, "the pattern matches no file")
            if passed is not None:
                passed += [f"{m} ({special_file(m)})" for m in matches if special_file(m)]
            found += find_logs([m for m in matches if not special_file(m)], passed)
        else:
            raise InputError(path, "no such file or folder")
    unique = list(dict.fromkeys(os.path.abspath(p) for p in found))
    return [os.path.relpath(p) if not os.path.relpath(p).startswith("..") else p for p in unique]


def record_name(path: str) -> str:
    """The log's record file name in --out: its own name and a hash of its absolute path (two
    folders may each hold a flight.bin)."""
    digest = hashlib.sha1(os.path.abspath(path).encode()).hexdigest()[:10]
    stem = "".join(c if c.isalnum() or c in "-_." else "_" for c in os.path.basename(path))
    return f"{stem}-{digest}.json"


def settings_key(settings: RunOptions) -> str:
    """What a record was computed with, the settings and the code: a record made with other
    settings, or by another version of mavattitude, is redone."""
    from ..kernel_cache import sources_stamp

    options = json.dumps(asdict(settings), sort_keys=True, default=str)
    return hashlib.sha1((options + sources_stamp(kernels_only=False)).encode()).hexdigest()[:16]


# ---------------------------------------------------------------- one log


def evaluate_log(path: str, settings: RunOptions, data: bytes | None = None, keep: bool = False) -> dict:
    """Replay one log as ``replay`` does (``commands.replay.replay_flight``) and return its record:
    ``status`` ("ok", "failed" or "skipped"), ``facts``, ``metrics`` (``replay --json``'s
    estimators), ``error``. ``data``: the log's bytes, for a worker that cannot see ``path``.
    ``keep``: keep the decoded log in this process for the next replay of it (``tune`` replays
    the same logs once per trial). Never raises for a bad log: its error is the record."""
    record = {"version": RECORD_VERSION, "log": path, "status": "failed", "facts": {}, "metrics": {},
              "error": None, "seconds": 0.0}
    start = time.perf_counter()
    local = path
    try:
        if keep and (path, settings.segment) in _kept:
            record.update(_replay(path, path, settings, _kept[path, settings.segment]))
        elif data is None:
            record.update(_replay(path, path, settings, keep=keep))
        else:
            with tempfile.TemporaryDirectory() as tmp:
                local = os.path.join(tmp, os.path.basename(path))
                with open(local, "wb") as f:
                    f.write(data)
                record.update(_replay(local, path, settings, keep=keep))
    except (InputError, UsageError) as exc:
        record["error"] = str(exc).replace(local, path)
    except MemoryError:
        record["error"] = f"{path}: out of memory"
    except Exception as exc:  # noqa: BLE001 - one log's fault must not stop a thousand others
        reraise_interrupt(exc)  # a Ctrl-C inside a compiled kernel is no result of the log
        record["error"] = f"{path}: {INTERNAL_ERROR} ({type(exc).__name__}: {exc}); please report it"
    record["seconds"] = round(time.perf_counter() - start, 3)
    return record


_kept: dict = {}  # (log path, segment) -> its Flight, in a process replaying logs with keep=True


def _replay(local: str, path: str, settings: RunOptions, flight=None, keep: bool = False) -> dict:
    from .replay import choose_imu, replay_flight
    from ..readers import read_log

    if flight is None:
        flight = read_log(local, segment=settings.segment)
        if keep:
            _kept[path, settings.segment] = flight
    facts = log_facts(flight, choose_imu(flight, settings.imu, settings.imu_family))
    if settings.reference.lower() == "truth" and flight.truth is None:
        return {"status": "skipped", "facts": facts, "error": "no ground truth (SIM / SIMSTATE / vehicle_attitude_groundtruth)"}
    if settings.reference.lower() == "autopilot" and flight.attitude is None:
        return {"status": "skipped", "facts": facts, "error": "no attitude reference (ATT / ATTITUDE / vehicle_attitude)"}
    try:
        result, _ = replay_flight(flight, settings)
    except NoReference as exc:  # --reference ekf (or a stream) the log has not
        return {"status": "skipped", "facts": facts, "error": exc.problem}
    facts["imu_source"] = result.imu_source
    metrics = result.metrics
    facts["board_trim"] = metrics["scoring"]["board_trim"]
    facts["not_meaningful"] = metrics["scoring"]["why"]  # left out of the rankings when set
    facts["accel_scale_error"] = metrics["scoring"]["accel_g_reading"]["scale_error"]
    facts["reference_suspect"] = len(metrics["scoring"]["reference_suspect"])
    facts["declination_deg"], facts["declination_source"] = metrics["declination_deg"], metrics["declination_source"]
    spread = metrics["reference_spread_deg"]
    return {"status": "ok", "facts": facts, "metrics": metrics["estimators"], "reference": metrics["reference"],
            "reference_stream": metrics["reference"]["stream"],
            "reference_algorithm": metrics["reference"]["algorithm"],
            "reference_spread_deg": None if spread is None else spread["tilt"],
            "autopilot_streams": metrics["autopilot_streams"],
            "suspects": metrics["scoring"]["reference_suspect"], "reference_notes": metrics["scoring"]["reference_notes"]}


def write_recording(path, records: list[dict], names: list[str], reference: str, report_md: str) -> None:
    """``evaluate --rrd``: the run as one Rerun recording (``view.evaluation``): each log's tilt
    error per estimator, a line per log with the ``replay`` command that writes its own
    recording beside this one, and the report."""
    import shlex

    import rerun as rr

    from . import evalreport as er
    from ..view.evaluation import LogRow, log_evaluation

    by_log = er.scores(records)
    rows = []
    for r in records:
        why = er.not_meaningful(r) if r["status"] == "ok" else r.get("error")
        status = "not meaningful" if r["status"] == "ok" and why else r["status"]
        own = Path(path).parent / (Path(r["log"]).stem + ".rrd")
        command = (f"mavattitude replay {shlex.quote(r['log'])} --estimators {','.join(names)} "
                   f"--reference {shlex.quote(reference)} --rrd {shlex.quote(str(own))}")
        rows.append(LogRow(r["log"], status, by_log.get(r["log"], {}), why or "", command))
    rec = rr.RecordingStream("mavattitude-evaluate")
    rec.save(str(path))
    log_evaluation(rec, rows, names, report_md)
    rec.flush()
    rec.disconnect()


def log_facts(flight, source: str) -> dict:
    """What kind of log it is, for the results table (``source``: the IMU estimated from)."""
    from ..readers import imu_rate
    from ..core.runner import REINIT_GAP_S

    t = flight.imu[source].t
    return {"format": flight.format, "vehicle": flight.vehicle, "firmware": flight.firmware,
            "imu_source": source, "imu_rate_hz": round(imu_rate(flight.imu[source]), 2),
            "duration_s": round(float(t[-1] - t[0]), 3) if len(t) else 0.0,
            "gps": flight.gps is not None, "compass": bool(flight.mag), "baro": flight.baro is not None,
            "clock_segments": len(flight.segments),
            "gaps": int(np.count_nonzero(np.diff(t) > REINIT_GAP_S)) if len(t) else 0}


# ---------------------------------------------------------------- many logs


class Progress:
    """Logs done, failures and the time left, on stderr: a line redrawn on a terminal, else
    a line per log."""

    def __init__(self, total: int, stream=None, quiet: bool = False):
        self.total, self.done, self.failed = total, 0, 0
        self.start = time.monotonic()
        self.stream = stream or sys.stderr
        self.tty = self.stream.isatty()
        self.quiet = quiet  # failures only

    def add(self, record: dict, reused: bool = False) -> None:
        self.done += 1
        self.failed += record["status"] == "failed"
        if self.quiet:
            if record["status"] == "failed":
                print(f"failed: {record['error']}", file=self.stream, flush=True)
            return
        elapsed = time.monotonic() - self.start
        left = (elapsed / self.done * (self.total - self.done)) if self.done else 0.0
        bar = (f"evaluate: {self.done}/{self.total} logs, {self.failed} failed, "
               f"{clock(elapsed)} elapsed, about {clock(left)} left")
        if self.tty:
            print(f"\r{bar}   ", end="", file=self.stream, flush=True)
            if record["status"] == "failed":
                print(f"\rfailed: {record['error']}" + " " * 10, file=self.stream, flush=True)
        else:
            status = "already done" if reused else record["status"]
            detail = f": {record['error']}" if record["status"] != "ok" else ""
            print(f"[{self.done}/{self.total}] {record['log']}: {status}{detail} "
                  f"({record['seconds']:.1f} s; about {clock(left)} left)", file=self.stream, flush=True)

    def close(self) -> None:
        if self.tty and not self.quiet:
            print(file=self.stream, flush=True)


def load_records(folder: Path, settings: RunOptions) -> dict[str, dict]:
    """The records in ``folder`` computed with these settings, by log path; internal errors are
    left out, to be tried again."""
    key = settings_key(settings)
    records = {}
    for path in sorted(folder.glob("*.json")):
        try:
            record = json.loads(path.read_text())
        except (OSError, ValueError):
            continue  # a record cut off mid-write: the log is redone
        if (isinstance(record, dict) and record.get("settings") == key and record.get("version") == RECORD_VERSION
                and not is_internal_error(record)):
            records[record["log"]] = record
    return records


def is_internal_error(record: dict) -> bool:
    """A record of a failure of ours, not of the log (a bug, or an interrupt an older version
    took for one): tried again by the next run rather than kept as the log's result."""
    return record.get("status") == "failed" and f": {INTERNAL_ERROR} (" in str(record.get("error"))


def save_record(folder: Path, record: dict) -> None:
    """Write a record under a temporary name, then rename: a killed run leaves none half-written."""
    target = folder / record_name(record["log"])
    tmp = target.with_suffix(".part")
    tmp.write_text(json.dumps(record, indent=1))
    os.replace(tmp, target)


def run_logs(logs: list[str], settings: RunOptions, records_dir: Path, jobs: int,
             scheduler: str | None = None, ship_logs: bool = False, force: bool = False,
             progress: Progress | None = None) -> list[dict]:
    """Every log's record, in the order of ``logs``: reused from ``records_dir`` when it was
    computed with the same settings (unless ``force``), else computed here, in a pool of
    ``jobs`` processes or on the Dask cluster at ``scheduler``, and saved as it arrives."""
    key = settings_key(settings)
    known = {} if force else load_records(records_dir, settings)
    results: dict[str, dict] = {}
    for log in logs:
        if log in known:
            results[log] = known[log]
            if progress:
                progress.add(known[log], reused=True)
    todo = [log for log in logs if log not in results]

    def finished(record: dict) -> None:
        record["settings"] = key
        save_record(records_dir, record)
        results[record["log"]] = record
        if progress:
            progress.add(record)

    with Workers(min(jobs, len(todo)), scheduler, ship_logs) as workers:
        workers.run(todo, settings, finished)
    return [results[log] for log in logs]


class Workers:
    """Where logs are replayed (``evaluate_log``): in this process (``jobs`` 1), in a pool of
    ``jobs`` local processes, or on the Dask cluster at ``scheduler``. Open (a context
    manager) for as many ``run``s as needed: ``tune`` runs the same logs once per trial, and
    with ``keep`` each worker keeps the logs it has read."""

    def __init__(self, jobs: int, scheduler: str | None = None, ship_logs: bool = False, keep: bool = False):
        self.jobs, self.scheduler, self.ship_logs, self.keep = jobs, scheduler, ship_logs, keep
        self._pool = self._client = None
        self._plugins: dict[str, str | None] = {}  # estimators registered at run time: where the workers find them
        self._runs = 0
        self._token = secrets.token_hex(4)  # task keys are the cluster's: unique to this run

    def __enter__(self) -> Workers:
        if self.scheduler:
            try:
                from distributed import Client
            except ImportError:
                raise UsageError("--scheduler needs Dask distributed: pip install 'mavattitude[cluster]'") from None
            try:
                self._client = Client(self.scheduler, timeout="10s")
            except (OSError, TimeoutError) as exc:
                raise InputError(self.scheduler, f"no Dask scheduler answers ({exc})") from None
        elif self.jobs > 1:
            import multiprocessing
            from concurrent.futures import ProcessPoolExecutor

            from ..estimators import ESTIMATORS, plugin_paths

            # spawn: a fresh interpreter per worker (no forked numba or pymavlink state); each
            # loads the compiled kernels from the cache once, and registers the estimators
            # registered here at run time (plugins) from their modules, on this process's path
            self._plugins = plugin_paths(list(ESTIMATORS))
            self._pool = ProcessPoolExecutor(max_workers=self.jobs, mp_context=multiprocessing.get_context("spawn"),
                                             initializer=_start_worker,
                                             initargs=(os.getpid(), [p for p in self._plugins.values() if p]))
        return self

    def __exit__(self, exc_type, exc, tb) -> None:
        if self._pool is not None:
            if exc_type is not None:  # stopped (Ctrl-C, SIGTERM) or failed: the logs under way are not waited for
                _end_workers(self._pool)
            self._pool.shutdown(cancel_futures=True)
        if self._client is not None:
            self._client.close()

    def run(self, logs: list[str], settings: RunOptions, finished) -> None:
        """``finished(record)`` for each log, in the order they finish."""
        self._runs += 1
        if self._client is not None:
            from distributed import as_completed

            from ..estimators import plugin_paths

            plugins = [path for path in plugin_paths(settings.names).values() if path]
            futures = []
            for log in logs:
                data = Path(log).read_bytes() if self.ship_logs else None
                futures.append(self._client.submit(_evaluate_on_worker, plugins, log, settings, data, self.keep,
                                                   pure=False,
                                                   key=f"evaluate-{self._token}-{self._runs}-{record_name(log)}"))
            for future in as_completed(futures):
                finished(future.result())
        elif self._pool is not None and len(logs) > 1:
            from concurrent.futures import as_completed

            for name in settings.names:
                if name in self._plugins and self._plugins[name] is None:
                    raise UsageError(f"estimator {name} is defined in __main__ (or in a function), where the worker "
                                     "processes cannot import it: define it in a module, or run with -j 1")
            futures = [self._pool.submit(evaluate_log, log, settings, None, self.keep) for log in logs]
            try:
                for future in as_completed(futures):
                    finished(future.result())
            except BaseException:
                for future in futures:
                    future.cancel()
                raise
        else:
            for log in logs:
                finished(evaluate_log(log, settings, keep=self.keep))


def _evaluate_on_worker(plugins: list[str], path: str, settings: RunOptions, data: bytes | None,
                        keep: bool) -> dict:
    """``evaluate_log`` on a Dask worker, which first registers the estimators this process
    registered at run time (``plugins``, "module:Class" each: the worker must be able to import
    their modules; one it cannot leaves its logs failed, naming the estimator)."""
    from ..estimators import register_from

    register_from(plugins)
    return evaluate_log(path, settings, data, keep)


def _start_worker(parent: int, plugins: list[str] = ()) -> None:
    """In each pool process, first. Ctrl-C at a terminal reaches the whole process group: the
    parent alone acts on it (and ends the pool), so no worker takes it for a log's failure.
    A worker whose parent died without ending it (SIGKILL, a crash) ends as well. ``plugins``:
    the parent's estimators registered at run time, "module:Class" each, registered here too."""
    import signal

    from ..estimators import register_from
    from ..signals import end_with_parent

    signal.signal(signal.SIGINT, signal.SIG_IGN)
    end_with_parent(parent)
    for problem in register_from(plugins):
        print(f"warning: {problem}", file=sys.stderr)


def _end_workers(pool) -> None:
    """Terminate a ProcessPoolExecutor's processes (Python 3.14 has terminate_workers; before it
    the processes are only in a private attribute)."""
    terminate = getattr(pool, "terminate_workers", None)
    if terminate is not None:
        terminate()
        return
    for process in list((getattr(pool, "_processes", None) or {}).values()):
        process.terminate()


def check_scheduler(address: str) -> None:
    """A refused or unreachable TCP scheduler address fails at once, not after Dask's timeout."""
    import socket
    from urllib.parse import urlsplit

    parts = urlsplit(address if "://" in address else f"tcp://{address}")
    if parts.scheme != "tcp":
        return  # tls://, inproc://: Dask's own checks
    try:
        port = parts.port or 8786
    except ValueError:
        raise UsageError(f"--scheduler {address}: not a TCP address (tcp://HOST:PORT)") from None
    try:
        socket.create_connection((parts.hostname or "127.0.0.1", port), timeout=5.0).close()
    except OSError as exc:
        raise InputError(address, f"no Dask scheduler answers ({exc.strerror or exc})") from None
