"""Files a command writes: checked before any work, never written over a user's log.

A command names its outputs (``--rrd``, ``--json``, ``--export``, ``-o``) on the command line;
``Outputs`` checks every one of them before the log is read, so a bad option costs a second,
not a replay:

- an output is never the same file as an input (a log, a parameter file), not even with
  ``--force``;
- an existing file of another kind (a log where a ``.rrd`` is asked for) is not written over
  unless ``--force``; an empty file, or one of the output's own kind, is. A JSON, SVG, TOML,
  CSV, Markdown or Parquet file is of our kind only when mavattitude wrote it (``is_kind``
  knows ours by content: a first key ``written_by`` in our JSON, a first comment in our SVG,
  our CSV headers): a user's ``summary.json`` is someone else's file;
- a flight log the simulator did not write is never replaced by ``simulate -o``, not even with
  ``--force``: a log is a flight that cannot be flown again;
- ``--export`` writes into a folder only when it is empty or holds nothing but our CSV files
  (unless ``--force``), and ``--study`` into an SQLite database only when it is Optuna's alone;
- a missing folder is created; a path through a regular file, a folder where a file is asked
  for, or a place nothing can be created in (``/proc``) is refused;
- a regular file is written under a temporary name beside it and renamed at the end
  (``commit``), so a run that fails or is interrupted leaves the old file as it was; a
  character device (``/dev/null``) is written directly, and its errors (``/dev/full``) surface
  as one line. A FIFO, a socket or a block device is refused (a FIFO nobody reads blocks the
  command for ever, after all its work), except the command's own stdout or stderr
  (``--json /dev/stdout | jq``).
"""
from __future__ import annotations

import contextlib
import json
import os
import re
import secrets
import sqlite3
import sys
import tempfile
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path

from . import signals
from ._version import __version__
from .errors import InputError, special_file

if sys.version_info >= (3, 11):
    import tomllib
else:  # pragma: no cover - Python 3.10
    import tomli as tomllib

KIND_NAMES = {"rrd": "Rerun recording", "json": "JSON file written by mavattitude",
              "csv": "CSV file written by mavattitude", "sim": "log written by the simulator",
              "md": "report of mavattitude evaluate", "svg": "figure of mavattitude evaluate",
              "parquet": "Parquet file written by mavattitude", "toml": "TOML file written by mavattitude tune",
              "study": "study of mavattitude tune (SQLite)"}
CSV_HEADER_STARTS = (b"time_s,roll_deg,pitch_deg,yaw_deg\n", b"log,status,error,")  # replay --export's, evaluate's
REPORT_START = b"# Attitude estimators across logs"
SQLITE_MAGIC = b"SQLite format 3\x00"
NAME_MAX = 255  # bytes in one file name (Linux, macOS)
SIM_MARK = b"mavattitude-sim"  # in the firmware text of every simulated log, near its start
PARTIAL_TOKEN_BYTES = 4
PARTIAL_NAME = re.compile(r"\..+\.[0-9a-f]{8}\.partial")  # an output being written: ".name.<token>.partial"
WRITTEN_BY = "mavattitude"  # what our JSON, SVG and Parquet files say they were written by
JSON_MARK = re.compile(rb'\s*\{\s*"written_by"\s*:\s*"mavattitude[ "]')
SVG_MARK = b"<!-- written by mavattitude"
TOML_MARK = b"# written by: mavattitude"  # tune's comment above its table
# The tables of an Optuna study (optuna.storages._rdb.models, and its schema migrations'); a
# database with others belongs to another program.
OPTUNA_TABLES = {"studies", "version_info", "study_directions", "study_user_attributes", "study_system_attributes",
                 "trials", "trial_user_attributes", "trial_system_attributes", "trial_params", "trial_values",
                 "trial_intermediate_values", "trial_heartbeats", "alembic_version"}


def json_text(data: dict, indent: int = 2, **options) -> str:
    """``data`` as our JSON files hold it: after a first key saying who wrote it (how
    ``is_kind`` tells our files from a user's)."""
    return json.dumps({"written_by": f"{WRITTEN_BY} {__version__}", **data}, indent=indent, **options) + "\n"


def is_kind(path: Path, kind: str) -> bool:
    """Whether an existing file looks like an output of ``kind`` (by content, not name)."""
    with open(path, "rb") as f:
        head = f.read(1 << 16)
    if kind == "rrd":
        return head.startswith(b"RRF")  # Rerun's file magic (RRF2 today)
    if kind == "json":
        return JSON_MARK.match(head) is not None
    if kind == "csv":
        return head.startswith(CSV_HEADER_STARTS)
    if kind == "md":
        return head.startswith(REPORT_START)
    if kind == "svg":
        return head.startswith(SVG_MARK)
    if kind == "parquet":  # the schema's metadata is in the footer, at the end
        with open(path, "rb") as f:
            f.seek(max(os.path.getsize(path) - (1 << 16), 0))
            tail = f.read()
        return head.startswith(b"PAR1") and b"written_by" in tail and WRITTEN_BY.encode() in tail
    if kind == "toml":
        try:
            tomllib.loads(head.decode())
        except (UnicodeDecodeError, tomllib.TOMLDecodeError, RecursionError):  # deep nesting: no parameter file
            return False
        return TOML_MARK in head
    if kind == "study":
        return head.startswith(SQLITE_MAGIC)
    if kind == "sim":  # a user's flight log is never "of the simulator's kind"
        return SIM_MARK in head
    raise ValueError(f"unknown output kind {kind!r}")


def _ours(entry: Path, kind: str) -> bool:
    """Whether a file in an output folder is one we wrote: of ``kind``, or the temporary file
    of a run that was killed."""
    if PARTIAL_NAME.fullmatch(entry.name):
        return True
    return entry.is_file() and not entry.is_symlink() and special_file(entry) is None and is_kind(entry, kind)


def _is_flight_log(path: Path) -> bool:
    """Whether ``path`` is a .bin, .tlog or .ulg by its content (``readers.sniff_format``)."""
    from .readers import sniff_format

    try:
        sniff_format(str(path))
    except InputError:
        return False
    return True


def _refuse_special(path: Path, option: str, allowed: tuple[str, ...]) -> None:
    """InputError for a FIFO, socket or device output, but for the ``allowed`` kinds and the
    command's own stdout and stderr."""
    kind = special_file(path)
    if kind is None or kind in allowed or _our_stream(path):
        return
    raise InputError(path, f"{option}: not a regular file ({kind}); name a file, or /dev/stdout")


def _our_stream(path: Path) -> bool:
    """Whether ``path`` is this process's stdout or stderr (a pipe to ``jq``, say)."""
    try:
        st = os.stat(path)
        return any(os.path.samestat(st, os.fstat(fd)) for fd in (1, 2))
    except OSError:
        return False


def _foreign_tables(path: Path, option: str) -> list[str]:
    """The tables of an SQLite database that are not an Optuna study's (read only, as SQLite
    says; its own sqlite_* tables left out); InputError for a database SQLite cannot read."""
    try:
        uri = path.resolve().as_uri() + "?mode=ro"
        with contextlib.closing(sqlite3.connect(uri, uri=True)) as db:
            names = [row[0] for row in db.execute("SELECT name FROM sqlite_master WHERE type = 'table'")]
    except sqlite3.DatabaseError as exc:
        raise InputError(path, f"{option}: not a readable SQLite database ({exc})") from None
    return sorted(n for n in names if n not in OPTUNA_TABLES and not n.startswith("sqlite_"))


def temporary_name(name: str, name_max: int = NAME_MAX) -> str:
    """A new hidden name beside ``name`` for writing it: ``.NAME.RANDOM.partial``, with NAME
    cut short where the whole would pass ``name_max`` bytes, so that every name the user may
    give can be written (238 to 255 bytes were refused)."""
    suffix = f".{secrets.token_hex(PARTIAL_TOKEN_BYTES)}.partial"
    room = name_max - 1 - len(suffix)
    kept = name.encode("utf-8", "surrogateescape")[:room].decode("utf-8", "ignore")  # whole characters
    return f".{kept}{suffix}"


def same_file(a: Path, b: Path) -> bool:
    try:
        return a.exists() and b.exists() and os.path.samefile(a, b)
    except OSError:
        return False


@dataclass
class Output:
    """One output file: ``write_path`` is where to write it, ``commit`` puts it in place."""
    path: Path  # what the user asked for
    option: str  # the option that named it, for messages
    write_path: Path  # a temporary file beside ``path``, or ``path`` itself for a device
    committed: bool = False

    @contextmanager
    def writing(self):
        """``with out.writing() as path: ...`` writes the file at ``path``; a failed write (a
        full disk) is an InputError naming the output. It is put in place (``commit``) with
        the command's other outputs once the whole command has succeeded."""
        try:
            yield self.write_path
        except OSError as exc:
            raise InputError(self.path, f"{self.option}: cannot write ({exc.strerror or exc})") from None

    def commit(self) -> None:
        if self.committed:
            return
        self.committed = True
        if self.write_path != self.path:
            os.replace(self.write_path, self.path)

    def discard(self) -> None:
        if not self.committed and self.write_path != self.path:
            try:
                os.unlink(self.write_path)
            except FileNotFoundError:
                pass
        self.committed = True


class Outputs:
    """The outputs of one command. As a context manager: on success every file is committed,
    together at the end (an interrupted replay has replaced no --json while its --rrd was being
    written); on an error, Ctrl-C or any exception that ends the command (SIGTERM made one),
    every temporary file is removed."""

    def __init__(self, inputs=(), force: bool = False):
        self.inputs = [Path(p) for p in inputs if p]
        self.force = force
        self.files: list[Output] = []
        self.taken: list[tuple[Path, str]] = []  # (path, option) of every output claimed

    def __enter__(self) -> Outputs:
        return self

    def __exit__(self, exc_type, exc, tb) -> None:
        try:
            if exc_type is None:
                signals.check()  # a stop that something swallowed: nothing put in place
                for out in self.files:
                    out.commit()
        finally:  # what is not in place (an error, or Ctrl-C during the renames) is removed
            for out in self.files:
                out.discard()

    def file(self, path, option: str, kind: str) -> Output | None:
        """Check ``path`` as an output of ``kind`` and reserve its temporary file; None if no path."""
        if not path:
            return None
        path = self._unclaimed(path, option)
        if path.exists() or path.is_symlink():
            if path.is_dir():
                raise InputError(path, f"{option} names a folder; give a file name, "
                                       f"e.g. {path / ('out.' + kind)}")
            if not path.is_file() or _our_stream(path):  # a device, or /dev/stdout: written as it is
                _refuse_special(path, option, allowed=("a character device",))
                if not os.access(path, os.W_OK):
                    raise InputError(path, f"{option}: not writable")
                out = Output(path, option, path)
                self.files.append(out)
                return out
            if kind == "sim" and path.stat().st_size and not is_kind(path, "sim") and _is_flight_log(path):
                raise InputError(path, f"is a flight log the simulator did not write: {option} never writes "
                                       "over one, even with --force (choose another name)")
            if path.stat().st_size and not self.force and not is_kind(path, kind):
                raise InputError(path, f"exists and is not a {KIND_NAMES[kind]}: {option} will not write "
                                       "over it (choose another name, or --force)")
        folder = self._make_folder(path.parent, option)
        temp = folder / temporary_name(path.name)
        try:  # created as any new file is (the umask applies), and only if it is new
            os.close(os.open(temp, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o666))
        except OSError as exc:
            raise InputError(folder, f"{option}: cannot create a file here ({exc.strerror})") from None
        out = Output(path, option, temp)
        self.files.append(out)
        return out

    def new_file(self, path, option: str) -> Path | None:
        """Check ``path`` as a file to create, written as the command goes (a live recording):
        it must not exist at all, whatever ``--force`` says. Its folder is made."""
        if not path:
            return None
        path = self._unclaimed(path, option)
        if path.exists() or path.is_symlink():
            raise InputError(path, f"exists: {option} never writes over a file; choose another name")
        self._make_folder(path.parent, option)
        self.taken.append((path, option))
        return path

    def database(self, path, option: str) -> Path | None:
        """Check ``path`` as an SQLite database the command opens and updates in place (a
        study that a later run resumes): new, empty, or an Optuna study already, which we may
        write; its folder is made."""
        if not path:
            return None
        path = self._unclaimed(path, option)
        if path.is_dir():
            raise InputError(path, f"{option} names a folder; give a file name, e.g. {path / 'study.db'}")
        _refuse_special(path, option, allowed=())
        if path.is_file() and path.stat().st_size:
            if not is_kind(path, "study"):
                raise InputError(path, f"exists and is not an SQLite database: {option} will not write into it "
                                       "(choose another name)")
            others = _foreign_tables(path, option)
            if others:
                raise InputError(path, f"{option}: a database of another program (its tables "
                                       f"{', '.join(others[:3])}{', ...' if len(others) > 3 else ''} are not "
                                       "Optuna's): tune will not write into it (choose another name)")
            if not os.access(path, os.W_OK):
                raise InputError(path, f"{option}: not writable")
        folder = self._make_folder(path.parent, option)
        if not os.access(folder, os.W_OK):  # SQLite writes its journal beside the database
            raise InputError(folder, f"{option}: cannot create files here (permission denied)")
        self.taken.append((path, option))
        return path

    def folder(self, path, option: str, only: str | None = None) -> Path | None:
        """Check ``path`` as a folder the command writes files into (each then claimed with
        ``file``). ``only``: the kind of file it writes there, the only kind an existing folder
        may hold (unless ``--force``): no folder of someone's files is written into."""
        if not path:
            return None
        folder = self._make_folder(self._unclaimed(path, option), option)
        if only and not self.force:
            foreign = next((entry for entry in sorted(folder.iterdir()) if not _ours(entry, only)), None)
            if foreign is not None:
                kind = special_file(foreign)
                raise InputError(folder, f"{option}: the folder holds files mavattitude did not write "
                                         f"({foreign.name}{', ' + kind if kind else ''}); choose an empty or "
                                         "new folder, or --force")
        try:
            with tempfile.TemporaryFile(dir=folder):
                pass
        except OSError as exc:
            raise InputError(folder, f"{option}: cannot create files here ({exc.strerror})") from None
        return folder

    def _unclaimed(self, path, option: str) -> Path:
        """``path``, once sure it is no input and no other output of this command, and a name
        the file system can hold (found now, not when the finished file is renamed to it)."""
        path = Path(path)
        if len(os.fsencode(path.name)) > NAME_MAX:
            raise InputError(path, f"{option}: the file name is {len(os.fsencode(path.name))} bytes long; "
                                   f"a name has at most {NAME_MAX}")
        for source in self.inputs:
            if same_file(path, source) or path.resolve() == source.resolve():
                raise InputError(path, f"{option} would write over the input {source}; choose another name")
        for other, other_option in self.taken + [(o.path, o.option) for o in self.files]:
            if other.resolve() == path.resolve():
                raise InputError(path, f"named by both {other_option} and {option}; give each its own file")
        return path

    @staticmethod
    def _make_folder(folder: Path, option: str) -> Path:
        folder = folder if str(folder) else Path(".")
        try:
            folder.mkdir(parents=True, exist_ok=True)
        except (FileExistsError, NotADirectoryError):
            raise InputError(folder, f"{option}: not a folder (a file is in the way)") from None
        except OSError as exc:
            raise InputError(folder, f"{option}: cannot create this folder ({exc.strerror})") from None
        if not folder.is_dir():
            raise InputError(folder, f"{option}: not a folder")
        return folder
