"""Where a Rerun recording goes: a file, a spawned viewer, a running viewer or the web viewer.

``plan_sink`` checks the choice before any work is done (the file can be created, a display
exists for a viewer, a viewer answers at the URL, the web ports are free), so a bad option
costs a second rather than a replay. ``open_sink`` and ``close_sink`` turn what can still fail
later (a disk that fills up, a viewer that dies) into an ``InputError``: one line, exit 1.
Every wait on Rerun is bounded and leaves Ctrl-C working: its flush blocks in native code,
so it is waited for in short steps. A network sink (spawn, connect, web) is closed by
``shutdown``, which a program calls last: Rerun's own exit handler waits forever on a viewer
that stopped answering, so when closing takes longer than a few seconds the program should end
without it (the CLI does, with ``os._exit``).
"""
from __future__ import annotations

import os
import shutil
import socket
import sys
import threading
import time
from dataclasses import dataclass
from urllib.parse import quote, urlsplit

from ..errors import InputError, UsageError
from ..outputs import Output, Outputs

KINDS = ("rrd", "spawn", "connect", "web")
RERUN_SCHEMES = {"rerun": 9876, "rerun+http": 9876, "rerun+https": 443}
CONNECT_TIMEOUT_S = 3.0  # to find a viewer at --connect before the work starts
# How long the last data may take to reach a viewer before we give up on it. Rerun's own
# flush waits forever on a viewer that is gone.
FLUSH_TIMEOUT_S = 30.0
DEFAULT_WEB_PORT = 9090  # Rerun's defaults
DEFAULT_GRPC_PORT = 9876
PORT_SEARCH = 20  # ports tried above a default that is in use
SHUTDOWN_TIMEOUT_S = 5.0

_network_streams: list = []  # recording streams to a viewer, closed by ``shutdown``


@dataclass
class Sink:
    kind: str  # one of KINDS
    file: Output | None = None  # rrd: the file being written
    url: str | None = None  # connect: the viewer's URL
    web_port: int = DEFAULT_WEB_PORT  # web: where the viewer page and the data are served
    grpc_port: int = DEFAULT_GRPC_PORT
    open_browser: bool = True

    @property
    def where(self) -> str:
        return {"rrd": f"--rrd {self.file.path if self.file else ''}", "spawn": "--spawn",
                "connect": f"--connect {self.url}", "web": "--web"}[self.kind]


def plan_sink(kind: str, value, outputs: Outputs | None = None, *, open_browser: bool = True) -> Sink:
    """A checked sink. ``value``: the file for rrd, the URL for connect, ignored otherwise.
    ``outputs`` reserves the rrd file (and refuses to write it over an input)."""
    if kind == "rrd":
        outputs = outputs or Outputs()
        return Sink("rrd", file=outputs.file(value, "--rrd", "rrd"))
    if kind == "spawn":
        _check_display()
        return Sink("spawn")
    if kind == "connect":
        return Sink("connect", url=_check_viewer(value))
    if kind == "web":
        web = _free_port(DEFAULT_WEB_PORT)
        grpc = _free_port(DEFAULT_GRPC_PORT, avoid=web)
        return Sink("web", web_port=web, grpc_port=grpc, open_browser=open_browser)
    raise ValueError(f"unknown sink {kind!r}")


def _check_display() -> None:
    if shutil.which("rerun") is None:
        raise InputError("--spawn", "the Rerun viewer ('rerun') is not on PATH; use --web, or --rrd FILE")
    if sys.platform.startswith("linux") and not (os.environ.get("DISPLAY") or os.environ.get("WAYLAND_DISPLAY")):
        raise InputError("--spawn", "no display to open a viewer on (DISPLAY and WAYLAND_DISPLAY are unset); "
                                    "use --web, or --rrd FILE and open it where there is a screen")


def _check_viewer(url: str) -> str:
    """The URL, once a viewer answers there. A malformed URL is a usage error."""
    parts = urlsplit(url or "")
    if parts.scheme not in RERUN_SCHEMES or not parts.hostname:
        raise UsageError(f"--connect {url!r}: expected a Rerun URL such as "
                         "rerun+http://127.0.0.1:9876/proxy")
    try:
        port = parts.port or RERUN_SCHEMES[parts.scheme]
    except ValueError:
        raise UsageError(f"--connect {url!r}: the port is not a number from 0 to 65535") from None
    try:
        socket.create_connection((parts.hostname, port), timeout=CONNECT_TIMEOUT_S).close()
    except OSError as exc:
        why = exc.strerror or ("no answer" if isinstance(exc, TimeoutError) else str(exc))
        raise InputError(url, f"no Rerun viewer answers there ({why.lower()}); start one with 'rerun', "
                              "or use --spawn, --web or --rrd FILE") from None
    return url


def _free_port(preferred: int, avoid: int | None = None) -> int:
    """``preferred`` if nothing listens on it, else the next free port above it."""
    for port in range(preferred, preferred + PORT_SEARCH + 1):
        if port == avoid:
            continue
        with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as s:
            try:
                s.bind(("0.0.0.0", port))
            except OSError:
                continue
        if port != preferred:
            print(f"port {preferred} is in use (another viewer or --web session?): using {port}",
                  file=sys.stderr)
        return port
    raise InputError("--web", f"ports {preferred}-{preferred + PORT_SEARCH} are all in use")


def open_sink(sink: Sink, app_id: str, recording_name: str):
    """A new recording stream writing to ``sink``."""
    from . import import_rerun
    rr = import_rerun()

    rec = rr.RecordingStream(app_id)
    try:
        if sink.kind == "rrd":
            rec.save(str(sink.file.write_path))
        elif sink.kind == "spawn":
            rec.spawn(port=sink.grpc_port)
            _check_spawned(sink.grpc_port)
        elif sink.kind == "connect":
            rec.connect_grpc(sink.url)
        else:
            url = rec.serve_grpc(grpc_port=sink.grpc_port)
            rr.serve_web_viewer(web_port=sink.web_port, open_browser=sink.open_browser, connect_to=url)
            print(f"Rerun web viewer: http://localhost:{sink.web_port}/?url={quote(url, safe='')}",
                  file=sys.stderr)
        rec.send_recording_name(recording_name)
    except RuntimeError as exc:
        raise _sink_error(sink, exc) from None
    if sink.kind != "rrd":
        _network_streams.append(rec)
    return rec


def _check_spawned(port: int) -> None:
    """Rerun's spawn carries on, silently, when the viewer dies at start (no usable display):
    the data would then wait forever. It waits for the viewer to listen first, so a port that
    refuses now means a viewer that is not there."""
    try:
        socket.create_connection(("127.0.0.1", port), timeout=CONNECT_TIMEOUT_S).close()
    except OSError:
        raise InputError("--spawn", "the Rerun viewer did not start (its own message, if any, is "
                                    "above); use --web, or --rrd FILE") from None


def close_sink(rec, sink: Sink, timeout_s: float | None = None) -> None:
    """Send what is left, waiting at most ``timeout_s`` (in 1 s steps, so Ctrl-C is heard).
    A file is then closed, complete with its footer; a viewer's connection is closed by
    ``shutdown``. ``timeout_s`` defaults to ``FLUSH_TIMEOUT_S``."""
    timeout_s = FLUSH_TIMEOUT_S if timeout_s is None else timeout_s
    deadline = time.monotonic() + timeout_s
    try:
        while True:
            try:
                rec.flush(timeout_sec=1.0)
                break
            except RuntimeError as exc:
                if "timed out" not in str(exc):
                    raise
                if time.monotonic() > deadline:
                    what = "the file" if sink.kind == "rrd" else "the viewer"
                    raise InputError(sink.where, f"{what} did not take the recording within "
                                                 f"{timeout_s:g} s; gave up") from None
        if sink.kind == "rrd":
            rec.disconnect()
    except RuntimeError as exc:
        raise _sink_error(sink, exc) from None


def shutdown(timeout_s: float | None = None) -> bool:
    """Close every viewer connection this process opened, and Rerun itself, waiting at most
    ``timeout_s``. False when that was not enough: a viewer stopped answering, and Rerun's
    exit handler would then wait forever (end the process with ``os._exit``). ``timeout_s``
    defaults to ``SHUTDOWN_TIMEOUT_S``."""
    timeout_s = SHUTDOWN_TIMEOUT_S if timeout_s is None else timeout_s
    if not _network_streams:
        return True
    import rerun as rr

    def close_all():
        while _network_streams:
            _network_streams.pop().disconnect()
        rr.rerun_shutdown()

    worker = threading.Thread(target=close_all, daemon=True)
    worker.start()
    worker.join(timeout_s)
    if worker.is_alive():
        return False
    rr.unregister_shutdown()  # done already
    return True


def _sink_error(sink: Sink, exc: Exception) -> InputError:
    text = str(exc).split(", path:")[0].replace("Failed to encode LogMsg: ", "")
    if sink.kind == "rrd":
        return InputError(sink.file.path, f"cannot write the recording: {text}")
    return InputError(sink.where, f"Rerun failed: {text}")
