"""Log readers: a file in, a :class:`~mavattitude.flight.Flight` out (SI units, autopilot clock).

``read_log(path)`` picks the format from the file's first bytes, decodes it (``dataflash``:
in bulk, ``dfrecords``; ``tlog``: in bulk, ``tlogrecords``; ``ulog``: in bulk, ``ulogdata``, pyulog where that one
cannot), follows the clock (``collect``) and builds the
flight's series (``series``): one clock segment (the longest, unless asked), each sample newer
than the one before it, plausible values. ``sources`` chooses the IMU and compass.
"""
from __future__ import annotations

import contextlib
import io
import os
import sys
import tempfile
import warnings as py_warnings

from ..errors import InputError, check_not_special
from ..flight import Flight
from ..kernel_cache import cached
from .broad import HDF5_SIGNATURE, looks_like_broad, read_broad
from .dataflash import read_dataflash
from .logevents import fill_events
from .series import IMU_LIMITS, MAG_LIMITS, earth_field_power, fill_series
from .sources import (IMU_PREFERENCE, best_imu_source, enum_name, identify_vehicle, imu_rate, mag_for_imu,
                      pick_imu, pick_mag)
from .tlog import TLOG_SEARCH_BYTES, read_tlog, tlog_start
from .ulog import read_ulog
from .ulogrecords import looks_like_ulog

__all__ = ["IMU_LIMITS", "IMU_PREFERENCE", "MAG_LIMITS", "best_imu_source", "earth_field_power", "enum_name",
           "identify_vehicle", "imu_rate", "mag_for_imu", "pick_imu", "pick_mag", "read_log", "reader_needs_compile",
           "sniff_format"]

DATAFLASH_MAGIC = b"\xa3\x95"


def sniff_format(path: str) -> str:
    """'bin', 'tlog', 'ulg' or 'broad' from the file's content; InputError if it is none of them."""
    if not os.path.exists(path):
        raise InputError(path, "no such file")
    if os.path.isdir(path):
        raise InputError(path, "is a folder, not a log file")
    check_not_special(path)
    with open(path, "rb") as f:
        head = f.read(TLOG_SEARCH_BYTES)
    if not head:
        raise InputError(path, "empty file")
    if head[:2] == DATAFLASH_MAGIC:
        return "bin"
    if looks_like_ulog(head):  # a damaged magic byte is said by the reader
        return "ulg"
    if looks_like_broad(path, head):
        return "broad"
    if tlog_start(head) is not None:
        return "tlog"
    ext = os.path.splitext(path)[1].lower()
    if head.startswith(HDF5_SIGNATURE):
        raise InputError(path, "an HDF5 file, but not a BROAD trial (it lacks imu_gyr, imu_acc, imu_mag, "
                               "opt_quat or movement)")
    kind = {".bin": "DataFlash .bin", ".tlog": "telemetry .tlog", ".ulg": "PX4 ULog", ".hdf5": "BROAD HDF5",
            ".h5": "BROAD HDF5"}.get(ext, "flight log")
    raise InputError(path, f"not a {kind} file (it starts with bytes {head[:10].hex(' ')}; "
                           "expected a DataFlash header a3 95, a tlog record, the ULog header 'ULog' "
                           "or an HDF5 signature)")


@contextlib.contextmanager
def _captured_output():
    """Capture what pymavlink prints while it decodes, Python and C alike (its Cython
    indexer writes to the process's stdout and stderr directly); yields a function that
    returns the captured lines. The progress display is let through: it writes after.
    Python warnings are the decoder's only when raised in its own files: any other (numpy's,
    from our code) is issued again afterwards, as itself, not as "corrupt data"."""
    sys.stdout.flush()
    sys.stderr.flush()
    with tempfile.TemporaryFile(mode="w+b") as sink:
        saved = [os.dup(1), os.dup(2)]
        lines: list[str] = []
        caught: list = []
        try:
            os.dup2(sink.fileno(), 1)
            os.dup2(sink.fileno(), 2)
            with contextlib.redirect_stdout(io.StringIO()) as out, \
                    contextlib.redirect_stderr(io.StringIO()) as err, \
                    py_warnings.catch_warnings(record=True) as caught:  # the filters stay as they are
                yield lambda: lines
        finally:
            sys.stdout.flush()
            sys.stderr.flush()
            os.dup2(saved[0], 1)
            os.dup2(saved[1], 2)
            for fd in saved:
                os.close(fd)
            sink.seek(0)
            lines += sink.read().decode(errors="replace").splitlines()
            lines += out.getvalue().splitlines() + err.getvalue().splitlines()
            for warning in caught:
                if _in_decoder(warning.filename):
                    lines.append(f"{warning.category.__name__}: {warning.message}")
                else:  # on the restored stderr
                    py_warnings.warn_explicit(warning.message, warning.category, warning.filename, warning.lineno,
                                              source=warning.source)


def _in_decoder(filename: str) -> bool:
    """Whether code in this file is pymavlink's or pyulog's."""
    import pymavlink
    import pyulog

    return any(os.path.abspath(filename).startswith(os.path.dirname(os.path.abspath(package.__file__)) + os.sep)
               for package in (pymavlink, pyulog))


def reader_needs_compile(path: str) -> bool:
    """Whether reading this log compiles its reader's kernels first (numba's cache has not
    got them yet): a first run's reading is slow. False for a file that is no log."""
    from . import collect, dfrecords, tlogrecords, ulogrecords

    try:
        fmt = sniff_format(path)
    except (InputError, OSError):
        return False  # read_log says what is wrong with it
    if fmt == "broad":
        return False  # h5py reads it, nothing to compile
    kernels = {"bin": (dfrecords._scan, dfrecords._gather_words), "tlog": (tlogrecords._scan, tlogrecords._gather),
               "ulg": (ulogrecords._pass, dfrecords._gather_words)}[fmt]  # those every read of the format runs
    return not all(cached(kernel) for kernel in (collect._track, *kernels))


def read_log(path: str, segment: int | None = None, progress=None) -> Flight:
    """Read a .bin, .tlog, .ulg or BROAD trial (.hdf5). ``segment``: which clock segment to keep when the autopilot
    rebooted during the log (0-based); default the longest."""
    path = str(path)
    fmt = sniff_format(path)
    if fmt == "broad":  # one clock, one IMU: none of the logs' decoding
        if segment not in (None, 0):
            raise InputError(path, f"has 1 clock segment(s); segment {segment} does not exist")
        flight = read_broad(path)
        if progress is not None:
            progress(1.0)
        return flight
    reader = {"bin": read_dataflash, "tlog": read_tlog, "ulg": read_ulog}[fmt]
    with _captured_output() as chatter:  # pymavlink's (or pyulog's) complaints about corrupt data
        decoded = reader(path, progress)
    col, notes, warnings = decoded.collector, decoded.notes, decoded.warnings
    col.finish()
    complaints = [line for line in chatter() if line.strip()]
    if col.outliers:
        warnings.append(f"dropped {col.outliers} samples whose time fits neither the clock before them nor "
                        "after (corrupt records)")
    decoder = "pyulog" if fmt == "ulg" else "pymavlink"
    if complaints:
        warnings.append(f"{decoder} skipped corrupt data ({len(complaints)} reports; first: {complaints[0]})")
    if progress is not None:
        progress(1.0)
    segments = col.segments
    if not segments:
        why = f" ({decoder}: {complaints[0]})" if complaints else ""
        raise InputError(path, f"no time-stamped sensor or attitude messages found{why}")
    if segment is None:
        segment = col.longest_segment()
    elif not 0 <= segment < len(segments):
        raise InputError(path, f"has {len(segments)} clock segment(s); segment {segment} does not exist")
    if len(segments) > 1:
        spans = ", ".join(f"#{i}: {a:.1f}-{b:.1f} s" for i, (a, b) in enumerate(segments))
        warnings.append(f"the autopilot clock went back (reboot): {len(segments)} segments ({spans}); "
                        f"using segment {segment} (--segment N for another)")
    flight = Flight(path=path, format=fmt, params=decoded.params, message_counts=decoded.counts,
                    segments=segments, segment_index=segment, notes=notes, warnings=warnings, utc_s=decoded.utc_s)
    unusable = fill_series(flight, col, segment)
    flight.vehicle, flight.firmware = decoded.identity or identify_vehicle(decoded.texts)
    fill_events(flight, col, segment, flight.vehicle or decoded.build)  # (the vehicle names a .bin's modes)
    if not flight.imu and unusable:
        raise InputError(path, "IMU data present but none usable: " + "; ".join(unusable))
    if not flight.imu:
        damage = f"; the log is damaged: {'; '.join(warnings)}" if warnings else ""
        raise InputError(path, "no IMU data (looked for IMU/IMU2/IMU3, GYR/ACC and IMT in .bin; RAW_IMU, "
                               "SCALED_IMU/2/3 and HIGHRES_IMU in .tlog; sensor_combined and vehicle_imu in "
                               f".ulg){damage}")
    return flight


