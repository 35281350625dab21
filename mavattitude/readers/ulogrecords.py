"""ULog framing: where each message lies, and the stretches of damage between them.

A ULog is a 16-byte header (magic 'ULog' 01 12 35, a version byte, the start time) and then
messages, each a 3-byte header (uint16 payload size, uint8 type) and its payload. pyulog reads
them in turn; meeting damage, it may stop for good without a word (16 zeroed bytes in a data
message end its read, and half a real log is lost: issue 23). So, as ``dfrecords`` does for
DataFlash, ``frame`` walks the messages itself first. A message is valid when its type is one
ULog defines, its payload is not empty and ends inside the file, and a data message ('D') names
a subscribed id ('A') with the payload size of that topic's format ('F'), the size pyulog
accepts. Past damage, reading resumes where ``RESYNC_CHAIN`` valid messages follow each other.
``repaired`` is the file without its damage (the header mended), for pyulog to read.
The walk keeps where each valid message starts (``data_at`` with ``data_ids``, ``other_at``)
for ``ulogdata`` to decode; the data messages of a known size, nearly all of a log, are passed
by one compiled loop (``_pass``), with the messages that need no learning.
"""
from __future__ import annotations

import re
import struct
from dataclasses import dataclass, field

import numpy as np

from ..kernel_cache import kernel

MAGIC = b"ULog\x01\x12\x35"
VERSION = 1
HEADER_SIZE = 16
TYPES = frozenset(b"BFIMPQARDLCOS")  # every message type of the ULog format
DATA = ord("D")
DATA_HEADER = struct.Struct("<HBH")  # a data message's size, type and topic id
TYPE_BYTE = re.compile(b"[" + re.escape(bytes(sorted(TYPES))) + b"]")
RESYNC_CHAIN = 4  # valid messages in a row that mark the end of a damaged stretch
FIELD_SIZES = {"int8_t": 1, "uint8_t": 1, "int16_t": 2, "uint16_t": 2, "int32_t": 4, "uint32_t": 4,
               "int64_t": 8, "uint64_t": 8, "float": 4, "double": 8, "bool": 1, "char": 1}
MAX_NESTING = 8  # formats inside formats; deeper is a damaged format
FLAG_BITS_OFFSETS = 3 + 16  # in the flag-bits message: after its header, compat and incompat flags
APPENDED_DATA = 1  # incompat flag bit: the file has data appended at the offsets given


def header_damage(head: bytes) -> list[str] | None:
    """What is wrong with a ULog header: [] for a sound one, None for no ULog header at all
    (more than one magic byte wrong, or too short)."""
    wrong = [i for i in range(len(MAGIC)) if i >= len(head) or head[i] != MAGIC[i]]
    if len(head) < HEADER_SIZE or len(wrong) > 1:
        return None
    problems = [f"magic byte {i} is 0x{head[i]:02x}, not 0x{MAGIC[i]:02x}" for i in wrong]
    if head[len(MAGIC)] > VERSION:  # version 0 is an older PX4's, and pyulog reads it
        problems.append(f"version byte is {head[len(MAGIC)]}, not {VERSION}")
    return problems


def looks_like_ulog(head: bytes) -> bool:
    """A ULog header, sound or with one magic byte or the version byte damaged."""
    return header_damage(head) is not None


@dataclass
class Framing:
    """The result of ``frame``: the runs of valid messages and the damage between them."""
    size: int  # of the file
    header: list[str]  # what is wrong with the header (``header_damage``)
    runs: list[tuple[int, int]] = field(default_factory=list)  # (start, end) of valid messages
    damage: list[tuple[int, int]] = field(default_factory=list)  # (start, end) of skipped bytes
    # the log's clock (s) at the last data before each damaged stretch and the first after it
    # (None where not known, or nothing follows)
    times: list[tuple[float | None, float | None]] = field(default_factory=list)
    # where the valid messages start: data ('D') of a known size, and every other one (in order)
    data_at: np.ndarray = field(default_factory=lambda: np.empty(0, np.int64))
    data_ids: np.ndarray = field(default_factory=lambda: np.empty(0, np.uint16))  # the topic id of each
    other_at: list[int] = field(default_factory=list)
    formats: dict[str, list[tuple[str, int, str]]] = field(default_factory=dict)  # name -> (type, count, field)

    @property
    def skipped(self) -> int:
        return sum(end - start for start, end in self.damage)

    def data_offsets(self, ids: list[int]) -> dict[int, np.ndarray]:
        """Where the data messages of each topic id in ``ids`` start, in file order (one pass
        over them all: a comparison and a mask per id took 3 ms each on an hour at 400 Hz)."""
        counts = np.bincount(self.data_ids, minlength=max(ids, default=0) + 1)  # (ids are few and small)
        wanted = np.zeros(len(counts), np.bool_)
        wanted[list(ids)] = True
        counts *= wanted
        starts = np.concatenate([[0], np.cumsum(counts)])
        out = np.empty(starts[-1], np.int64)
        _split_by_id(self.data_ids, self.data_at, wanted, starts[:-1].copy(), out)
        return {i: out[starts[i]:starts[i + 1]] for i in ids}

    def notes(self) -> list[str]:
        """The damage, said plainly (nothing for a sound file)."""
        notes = []
        if self.header:
            notes.append(f"the ULog header is damaged ({'; '.join(self.header)}); read as a ULog all the same")
        if self.damage:
            last_start, last_end = self.damage[-1]
            lost_tail = (f"nothing readable follows byte {last_start:,}: the last "
                         f"{100.0 * (self.size - last_start) / self.size:.2g} % of the file is lost")
            ends = self.times[-1][0]
            if ends is not None:
                lost_tail += f" (the data ends at {ends:.1f} s on the log's clock)"
            gaps = [max(b - a, 0.0) for a, b in self.times if a is not None and b is not None]
            lost_s = "less than 0.01" if sum(gaps) < 0.01 else f"{sum(gaps):.2g}"
            resumed = "messages resumed after each" + (
                f" ({lost_s} s of data lost)" if gaps and len(gaps) == len(self.times) else "")
            after = lost_tail if last_end == self.size else resumed
            notes.append(
                f"skipped {self.skipped:,} bytes of corrupt data ({100.0 * self.skipped / max(self.size, 1):.2g} % "
                f"of the file) in {len(self.damage)} stretch{'es' if len(self.damage) != 1 else ''}, the first at "
                f"byte {self.damage[0][0]:,}: {after}")
        return notes

    def repaired(self, data: bytes) -> bytes:
        """The file with its damage cut out and its header mended, for pyulog."""
        version = min(data[len(MAGIC)], VERSION)
        head = bytearray(MAGIC + bytes([version]) + data[len(MAGIC) + 1:HEADER_SIZE])
        body = bytearray(b"".join(data[start:end] for start, end in self.runs))
        self._shift_appended_offsets(body)
        return bytes(head + body)

    def _shift_appended_offsets(self, body: bytearray) -> None:
        """The flag-bits message (first, when there is one) gives the file offsets of appended
        data: moved back by the bytes cut before each."""
        if len(body) < FLAG_BITS_OFFSETS + 24 or body[2] != ord("B") or not body[3 + 8] & APPENDED_DATA:
            return
        for k in range(3):
            at = FLAG_BITS_OFFSETS + 8 * k
            offset, = struct.unpack_from("<Q", body, at)
            if offset:
                cut = sum(min(end, offset) - start for start, end in self.damage if start < offset)
                struct.pack_into("<Q", body, at, max(offset - cut, 0))


def frame(data: bytes) -> Framing:
    """Walk the messages of a ULog (``data``: the whole file, whose header ``looks_like_ulog``)."""
    framing = Framing(len(data), header_damage(data[:HEADER_SIZE]) or [])
    walk = _Walk(data)
    pos = run_start = HEADER_SIZE
    buffer = np.frombuffer(data, np.uint8)
    # subscribed id -> its data payload size, -1 where not known: the compiled pass takes the
    # data messages of a known size (nearly all) and the messages that teach nothing (PASSED),
    # ``message`` the rest
    sizes = np.full(1 << 16, -1, np.int64)
    data_at = np.empty(len(data) // 32 + 16, np.int64)  # doubled when full (IMU samples take ~50 bytes)
    data_ids = np.empty(len(data_at), np.uint16)
    other_at = np.empty(256, np.int64)  # likewise (a log has hundreds of parameters)
    n_data = n_other = 0
    while pos < len(data):
        if data[pos + 2:pos + 3] not in (b"F", b"A"):  # (a compiled call costs microseconds: not for each definition)
            pos, n_data, n_other = _pass(buffer, pos, sizes, data_at, data_ids, n_data, other_at, n_other)
        if n_data == len(data_at) or n_other == len(other_at):
            data_at, data_ids = (np.concatenate([data_at, data_at]), np.concatenate([data_ids, data_ids])) \
                if n_data == len(data_at) else (data_at, data_ids)
            other_at = np.concatenate([other_at, other_at]) if n_other == len(other_at) else other_at
            continue
        if pos >= len(data):
            break
        end = walk.message(pos, learn=True)
        if end > 0:
            other_at[n_other] = pos
            n_other += 1
            if data[pos + 2] == ord("A") and end - pos > 6:
                msg_id, = struct.unpack_from("<H", data, pos + 4)
                known = walk.data_sizes.get(msg_id)
                sizes[msg_id] = -1 if known is None else known
            pos = end
            continue
        if end == _CUT:  # the last message cut short: where a log stopped, not damage
            break
        framing.runs.append((run_start, pos))
        resume = walk.resync(pos + 1)
        framing.damage.append((pos, resume))
        framing.times.append((walk.time_of(_last_data(walk, data_at, n_data)), walk.first_time(resume)))
        pos = run_start = resume
    framing.runs.append((run_start, min(pos, len(data))))
    framing.data_at, framing.data_ids = data_at[:n_data].copy(), data_ids[:n_data].copy()
    framing.other_at = other_at[:n_other].tolist()
    framing.formats = walk.formats
    return framing


def _last_data(walk: "_Walk", data_at: np.ndarray, n_data: int) -> int:
    """Where the last valid data message seen starts (either pass), -1 if none."""
    return max(walk.last_data, int(data_at[n_data - 1]) if n_data else -1)


# the message types the compiled pass steps over (besides data of a known size): those that
# teach the walk nothing (formats 'F' and subscriptions 'A' do)
PASSED = np.array([k in TYPES and k not in b"FAD" for k in range(256)])


@kernel
def _pass(data, pos, sizes, data_at, data_ids, n_data, other_at, n_other):
    """Step over valid messages from ``pos``: data messages of their topic's known size (kept in
    ``data_at`` with their topic id) and those of a PASSED type (kept in ``other_at``); returns
    where it stopped (any other message, damage, the end, or an array full) and the counts kept."""
    n = len(data)
    while pos + 3 <= n and n_data < len(data_at) and n_other < len(other_at):
        size = data[pos] | (data[pos + 1] << 8)
        kind = data[pos + 2]
        if pos + 3 + size > n:
            break
        if kind == DATA:
            if size < 2:
                break
            msg_id = data[pos + 3] | (data[pos + 4] << 8)
            if sizes[msg_id] != size - 2:
                break
            data_at[n_data] = pos
            data_ids[n_data] = msg_id
            n_data += 1
        elif PASSED[kind] and size > 0:
            other_at[n_other] = pos
            n_other += 1
        else:
            break
        pos += 3 + size
    return pos, n_data, n_other


@kernel
def _split_by_id(data_ids, data_at, wanted, next_at, out):
    for i in range(len(data_ids)):
        msg_id = data_ids[i]
        if wanted[msg_id]:
            out[next_at[msg_id]] = data_at[i]
            next_at[msg_id] += 1


_INVALID, _CUT = -1, -2


class _Walk:
    """The state of a walk: the formats and subscriptions seen so far."""

    def __init__(self, data: bytes):
        self.data = data
        self.formats: dict[str, list[tuple[str, int, str]]] = {}
        self.data_sizes: dict[int, int | None] = {}  # subscribed id -> its data payload size (None: unknown)
        self.time_offsets: dict[int, int | None] = {}  # subscribed id -> where its timestamp is in the data
        self.last_data = -1  # where the last valid data message seen starts
        self._sizes: dict[tuple[str, int], int | None] = {}  # _format_size's answers, until a format is learned

    def message(self, pos: int, learn: bool) -> int:
        """The end of the valid message at ``pos``, _INVALID, or _CUT (it runs past the end)."""
        data = self.data
        if pos + 3 > len(data):
            return _CUT
        size, kind = struct.unpack_from("<HB", data, pos)
        if kind not in TYPES or size == 0:
            return _INVALID
        end = pos + 3 + size
        if end > len(data):
            return _CUT
        if kind == ord("D"):
            if size < 2:
                return _INVALID
            msg_id, = struct.unpack_from("<H", data, pos + 3)
            if msg_id not in self.data_sizes:
                return _INVALID
            expected = self.data_sizes[msg_id]
            if expected is not None and size - 2 != expected:
                return _INVALID
            if learn:
                self.last_data = pos
        elif learn and kind == ord("F"):
            self._learn_format(data[pos + 3:end])
        elif learn and kind == ord("A") and size > 3:
            msg_id, = struct.unpack_from("<H", data, pos + 4)
            name = data[pos + 6:end].decode("latin-1")
            self.data_sizes[msg_id] = self._format_size(name)
            self.time_offsets[msg_id] = self._timestamp_offset(name)
        return end

    def time_of(self, pos: int) -> float | None:
        """The timestamp (s) of the valid data message at ``pos``, if its topic has one."""
        if pos < 0:
            return None
        msg_id, = struct.unpack_from("<H", self.data, pos + 3)
        offset = self.time_offsets.get(msg_id)
        if offset is None:
            return None
        return struct.unpack_from("<Q", self.data, pos + 5 + offset)[0] * 1e-6

    def first_time(self, pos: int, look: int = 64) -> float | None:
        """The timestamp (s) of the first data message among the ``look`` from ``pos``."""
        for _ in range(look):
            end = self.message(pos, learn=False)
            if end < 0:
                return None
            if self.data[pos + 2] == ord("D"):
                return self.time_of(pos)
            pos = end
        return None

    def resync(self, start: int) -> int:
        """The first offset from ``start`` where RESYNC_CHAIN valid messages (or the rest of the
        file) follow each other; the file's end if there is none."""
        data, n = self.data, len(self.data)
        pos = start
        while True:
            found = TYPE_BYTE.search(data, pos + 2)  # the next byte that can be a type (C speed over zeros)
            if found is None:
                return n
            pos = at = found.start() - 2
            for _ in range(RESYNC_CHAIN):
                end = self.message(at, learn=False)
                if end < 0:
                    break
                at = end
                if at == n:
                    return pos
            else:
                return pos
            pos += 1

    def _learn_format(self, payload: bytes) -> None:
        name, _, body = payload.decode("latin-1").partition(":")
        fields = []
        for item in body.split(";"):
            kind, _, field_name = item.partition(" ")
            if not item:
                continue
            count = 0
            if "[" in kind:
                kind, _, n = kind.partition("[")
                digits = n[:-1]
                count = int(digits) if n[-1:] == "]" and digits.isascii() and digits.isdigit() else -1  # -1: damaged
            fields.append((kind, count, field_name))
        self.formats[name] = fields
        self._sizes.clear()

    def _timestamp_offset(self, name: str) -> int | None:
        """Where a topic's ``timestamp`` (uint64, µs) lies in its data, None if it has none."""
        offset = 0
        for kind, count, field_name in self.formats.get(name, []):
            if field_name == "timestamp":
                return offset if kind == "uint64_t" and count == 0 else None
            one = FIELD_SIZES.get(kind) or self._format_size(kind, 1)
            if one is None or count < 0:
                return None
            offset += one * max(count, 1)
        return None

    def _format_size(self, name: str, depth: int = 0) -> int | None:
        """Bytes of a topic's data as pyulog takes them (the trailing padding left out), None
        when a format is missing or damaged: its data messages are then taken at any size."""
        if (name, depth) not in self._sizes:
            self._sizes[(name, depth)] = self._count_size(name, depth)
        return self._sizes[(name, depth)]

    def _count_size(self, name: str, depth: int) -> int | None:
        fields = self.formats.get(name)
        if fields is None or depth > MAX_NESTING:
            return None
        if depth == 0:
            while fields and fields[-1][2].startswith("_padding"):
                fields = fields[:-1]
        total = 0
        for kind, count, _ in fields:
            one = FIELD_SIZES.get(kind)
            if one is None:
                one = self._format_size(kind, depth + 1)
            if one is None or count < 0:
                return None
            total += one * max(count, 1)
        return total
