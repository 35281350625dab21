"""Files a command writes: checked before any work, never written over a user's log.

A command names its outputs (``--rrd``, ``--json``, ``--export``, ``-o``) on the command line;
``Outputs`` checks every one of them before the log is read, so a bad option costs a second,
not a replay:

- an output is never the same file as an input (a log, a parameter file), not even with
  ``--force``;
- an existing file of another kind (a log where a ``.rrd`` is asked for) is not written over
  unless ``--force``; an empty file, or one of the output's own kind, is;
- a missing folder is created; a path through a regular file, a folder where a file is asked
  for, or a place nothing can be created in (``/proc``) is refused;
- a regular file is written under a temporary name beside it and renamed at the end
  (``commit``), so a run that fails or is interrupted leaves the old file as it was; a device
  (``/dev/null``) is written directly, and its errors (``/dev/full``) surface as one line.
"""
from __future__ import annotations

import os
import secrets
import sys
import tempfile
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path

from .errors import InputError

if sys.version_info >= (3, 11):
    import tomllib
else:  # pragma: no cover - Python 3.10
    import tomli as tomllib

KIND_NAMES = {"rrd": "Rerun recording", "json": "JSON file", "csv": "CSV file",
              "sim": "log written by the simulator", "md": "report of mavattitude evaluate",
              "svg": "SVG image", "parquet": "Parquet file", "toml": "TOML parameter file",
              "study": "study of mavattitude tune (SQLite)"}
CSV_HEADER_STARTS = (b"time_s,", b"log,status,")  # replay --export's, evaluate's results
REPORT_START = b"# Attitude estimators across logs"
SQLITE_MAGIC = b"SQLite format 3\x00"
NAME_MAX = 255  # bytes in one file name (Linux, macOS)
SIM_MARK = b"mavattitude-sim"  # in the firmware text of every simulated log, near its start


def is_kind(path: Path, kind: str) -> bool:
    """Whether an existing file looks like an output of ``kind`` (by content, not name)."""
    with open(path, "rb") as f:
        head = f.read(1 << 16)
    if kind == "rrd":
        return head.startswith(b"RRF")  # Rerun's file magic (RRF2 today)
    if kind == "json":
        return head.lstrip()[:1] in (b"{", b"[")
    if kind == "csv":
        return head.startswith(CSV_HEADER_STARTS)
    if kind == "md":
        return head.startswith(REPORT_START)
    if kind == "svg":
        return head.lstrip().startswith((b"<svg", b"<?xml"))
    if kind == "parquet":
        return head.startswith(b"PAR1")
    if kind == "toml":
        try:
            tomllib.loads(head.decode())
        except (UnicodeDecodeError, tomllib.TOMLDecodeError, RecursionError):  # deep nesting: no parameter file
            return False
        return True
    if kind == "study":
        return head.startswith(SQLITE_MAGIC)
    if kind == "sim":  # a user's flight log is never "of the simulator's kind"
        return SIM_MARK in head
    raise ValueError(f"unknown output kind {kind!r}")


def temporary_name(name: str, name_max: int = NAME_MAX) -> str:
    """A new hidden name beside ``name`` for writing it: ``.NAME.RANDOM.partial``, with NAME
    cut short where the whole would pass ``name_max`` bytes, so that every name the user may
    give can be written (238 to 255 bytes were refused)."""
    suffix = f".{secrets.token_hex(4)}.partial"
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
        """``with out.writing() as path: ...`` writes the file at ``path`` and commits it; a
        failed write (a full disk) is an InputError naming the output."""
        try:
            yield self.write_path
        except OSError as exc:
            raise InputError(self.path, f"{self.option}: cannot write ({exc.strerror or exc})") from None
        self.commit()

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
    on an error or Ctrl-C every temporary file is removed."""

    def __init__(self, inputs=(), force: bool = False):
        self.inputs = [Path(p) for p in inputs if p]
        self.force = force
        self.files: list[Output] = []
        self.taken: list[tuple[Path, str]] = []  # (path, option) of every output claimed

    def __enter__(self) -> Outputs:
        return self

    def __exit__(self, exc_type, exc, tb) -> None:
        for out in self.files:
            if exc_type is None:
                out.commit()
            else:
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
            if not path.is_file():  # a device or a pipe: written as it is
                if not os.access(path, os.W_OK):
                    raise InputError(path, f"{option}: not writable")
                out = Output(path, option, path)
                self.files.append(out)
                return out
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
        study that a later run resumes): new, empty, or a database already; its folder is made."""
        if not path:
            return None
        path = self._unclaimed(path, option)
        if path.is_dir():
            raise InputError(path, f"{option} names a folder; give a file name, e.g. {path / 'study.db'}")
        if path.is_file() and path.stat().st_size and not is_kind(path, "study"):
            raise InputError(path, f"exists and is not an SQLite database: {option} will not write into it "
                                   "(choose another name)")
        self._make_folder(path.parent, option)
        self.taken.append((path, option))
        return path

    def folder(self, path, option: str, names: list[str], kind: str) -> Path | None:
        """Check ``path`` as a folder the command writes ``names`` (files of ``kind``) into."""
        if not path:
            return None
        folder = self._make_folder(self._unclaimed(path, option), option)
        for name in names:
            target = self._unclaimed(folder / name, option)
            if target.is_dir():
                raise InputError(target, f"{option}: is a folder where a {KIND_NAMES[kind]} goes")
            if (target.is_file() and target.stat().st_size and not self.force
                    and not is_kind(target, kind)):
                raise InputError(target, f"exists and is not a {KIND_NAMES[kind]}: {option} will not "
                                         "write over it (choose another folder, or --force)")
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
