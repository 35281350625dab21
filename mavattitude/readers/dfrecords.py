"""DataFlash records in bulk: find them, then decode each message type at once.

A DataFlash log (.bin) is a stream of records: ``A3 95``, a type byte, then a body whose
layout the log itself defines in FMT records (type 128: Type, Length, Name, Format, Columns).
pymavlink reads it record by record in Python; here one compiled pass (``scan``) walks the
records and keeps the offsets of the wanted types, and ``decode`` views all records of a type
through one numpy structured dtype, as pyulog does for ULog.

Damage: a record counts only if its type has a usable FMT (format characters, a printable
name) and it is followed by another record's header or by the end of the file. Anything else
is corrupt: the scan steps forward a byte at a time until records line up again, and counts
what it skipped. pymavlink, by contrast, stops at the first record of an unknown type, so a
flipped type byte loses the rest of the log. A damaged FMT record of a wanted message is
repaired when one flipped bit explains it and the records of its type line up with the repair
(``_recover``); else its records are skipped as corrupt, and counted.

Values come out exactly as pymavlink gives them (its tests compare field by field): integers
as integers, ``f``/``d``/``g`` floats widened to float64, the scaled types (``c C e E L``)
divided as pymavlink divides (by ``1 / multiplier``), strings cut at their first NUL. FMTU's
multipliers are not applied (pymavlink does not either): units stay as logged.
"""
from __future__ import annotations

import mmap
import re
import sys
from collections import Counter
from collections.abc import Mapping
from dataclasses import dataclass, field

import numpy as np

from ..kernel_cache import kernel

HEAD1, HEAD2 = 0xA3, 0x95
FMT_TYPE = 0x80
FMT_LENGTH = 89  # 3 header bytes + B Type, B Length, 4s Name, 16s Format, 64s Columns
HEADER = 3

# format character -> (numpy type, pymavlink's multiplier or None); as pymavlink's FORMAT_TO_STRUCT
FORMAT_TYPES = {
    "a": ("<i2", 32, None), "b": ("i1", 1, None), "B": ("u1", 1, None), "g": ("<f2", 1, None),
    "h": ("<i2", 1, None), "H": ("<u2", 1, None), "i": ("<i4", 1, None), "I": ("<u4", 1, None),
    "f": ("<f4", 1, None), "n": ("S4", 1, None), "N": ("S16", 1, None), "Z": ("S64", 1, None),
    "c": ("<i2", 1, 0.01), "C": ("<u2", 1, 0.01), "e": ("<i4", 1, 0.01), "E": ("<u4", 1, 0.01),
    "L": ("<i4", 1, 1e-7), "d": ("<f8", 1, None), "M": ("i1", 1, None), "q": ("<i8", 1, None),
    "Q": ("<u8", 1, None),
}


def _char_sizes() -> np.ndarray:
    sizes = np.zeros(256, np.int64)  # 0: not a format character
    for char, (dtype, count, _) in FORMAT_TYPES.items():
        sizes[ord(char)] = np.dtype(dtype).itemsize * count
    return sizes


CHAR_SIZES = _char_sizes()


@dataclass
class Format:
    type: int
    name: str
    length: int  # record length, header included
    format: str
    columns: list[str]

    def named_fields(self) -> dict[str, int]:
        """Column name -> field index. As pymavlink: a field beyond the column names has no
        name, and of two columns of one name the later wins."""
        return {column: i for i, column in enumerate(self.columns[:len(self.format)])}

    def dtype(self) -> np.dtype:
        """The record body as a numpy structured type; unnamed fields are ``_<index>``."""
        by_index = {i: column for column, i in self.named_fields().items()}
        names, types = [], []
        for i, char in enumerate(self.format):
            dtype, count, _ = FORMAT_TYPES[char]
            names.append(by_index.get(i, f"_{i}"))
            types.append((dtype, (count,)) if count > 1 else dtype)
        return np.dtype({"names": names, "formats": types})


@dataclass
class Scan:
    """What ``scan_log`` found: the wanted records, and what it could not use."""
    formats: dict[int, Format]
    offsets: dict[str, np.ndarray]  # message name -> offsets of its records, in file order
    counts: dict[str, int]  # message name -> records of every defined type (FMT excluded)
    skipped_bytes: int = 0  # bytes not part of any valid record
    skipped_stretches: int = 0
    first_skip: int = -1  # offset of the first skipped byte
    bad_formats: int = 0  # FMT records not used: characters that are no format, a name not printable
    tail_bytes: int = 0  # after the last record: a record cut off, unused log space
    recovered_formats: list[str] = field(default_factory=list)  # "IMU (its Length)": damaged FMTs repaired


    def format_of(self, name: str) -> "Format":
        """The format of the records of message ``name``."""
        return next(f for f in self.formats.values() if f.name == name)

    def has_text(self, name: str) -> bool:
        """Whether message ``name`` has a text field ('n': ``decode`` judges it over the records asked for)."""
        return "n" in self.format_of(name).format


# What the scan made of each FMT record it met
USED, UNUSABLE, IGNORED, BAD_HEADER = 0, 1, 2, 3  # IGNORED: its type defined before; BAD_HEADER: not a record


@kernel(inline="always")
def _append(values, n, value):
    """``values`` with ``value`` at ``n``, twice as long when full."""
    if n == len(values):
        values = np.concatenate((values, np.empty_like(values)))
    values[n] = value
    return values


@kernel
def _scan(data, wanted_names, char_sizes, fix_at, fix_types, fix_lengths):
    """One pass over the records. ``wanted_names``: (K, 4) uint8, the names whose records are
    kept. ``fix_at``: offsets (ascending) of damaged FMT records to take as defining the wanted
    types ``fix_types`` of ``fix_lengths`` (what ``_recover`` made of them). Returns (offsets,
    types, type counts, FMT offsets, what became of each FMT (USED ...), skipped bytes,
    stretches, first skip, tail bytes)."""
    n = len(data)
    lengths = np.zeros(256, np.int64)
    lengths[FMT_TYPE] = FMT_LENGTH
    wanted = np.zeros(256, np.bool_)
    counts = np.zeros(256, np.int64)
    offsets = np.empty(max(n // 16, 16), np.int64)
    types = np.empty(len(offsets), np.uint8)
    fmt_offsets = np.empty(256, np.int64)
    fmt_status = np.empty(256, np.uint8)
    n_kept = 0
    n_fmt = 0
    k_fix = 0
    skipped = 0
    stretches = 0
    first_skip = -1
    in_skip = False
    skip_start = 0
    ofs = 0
    next_fix = fix_at[0] if len(fix_at) else n
    while ofs + HEADER <= n:
        while ofs > next_fix:  # a fix inside damage: passed by
            k_fix += 1
            next_fix = fix_at[k_fix] if k_fix < len(fix_at) else n
        fixed = ofs == next_fix
        t = FMT_TYPE if fixed else data[ofs + 2]
        length = lengths[t]
        ok = (fixed or (data[ofs] == HEAD1 and data[ofs + 1] == HEAD2)) and length > 0 and ofs + length <= n
        if ok:
            nxt = ofs + length
            # the next record must start right after this one (or the file end)
            ok = nxt + 2 > n or (data[nxt] == HEAD1 and data[nxt + 1] == HEAD2) or nxt == next_fix
        if not ok:
            # one bit off an FMT header, and a record after it: an FMT for ``_recover`` to look at
            x = (data[ofs] ^ HEAD1) | ((data[ofs + 1] ^ HEAD2) << 8) | ((data[ofs + 2] ^ FMT_TYPE) << 16)
            nxt = ofs + FMT_LENGTH
            if x and x & (x - 1) == 0 and nxt + 2 <= n and data[nxt] == HEAD1 and data[nxt + 1] == HEAD2:
                fmt_offsets = _append(fmt_offsets, n_fmt, ofs)
                fmt_status = _append(fmt_status, n_fmt, BAD_HEADER)
                n_fmt += 1
            if not in_skip:
                stretches += 1
                in_skip = True
                skip_start = ofs
                if first_skip < 0:
                    first_skip = ofs
            skipped += 1
            ofs += 1
            continue
        in_skip = False
        if t == FMT_TYPE:
            if fixed:
                ftype, flen, valid = fix_types[k_fix], fix_lengths[k_fix], True
                k_fix += 1
                next_fix = fix_at[k_fix] if k_fix < len(fix_at) else n
            else:
                ftype, flen = np.int64(data[ofs + 3]), np.int64(data[ofs + 4])
                valid = data[ofs + 5] != 0  # a name: printable characters, then NULs
                for j in range(4):
                    c = data[ofs + 5 + j]
                    if c == 0:
                        break
                    if c < 0x21 or c > 0x7E:
                        valid = False
                for j in range(16):
                    c = data[ofs + 9 + j]
                    if c == 0:
                        break
                    if char_sizes[c] == 0:
                        valid = False
            # Framing trusts Length, as the firmware and pymavlink do; a Length that disagrees
            # with the Format (a firmware quirk: BAR3 33 for 29 bytes in Copter 3.4) only stops
            # that message from being decoded (see ``decode``).
            status = UNUSABLE
            if valid:
                status = USED if flen >= HEADER and ftype != FMT_TYPE and lengths[ftype] == 0 else IGNORED
            if status == USED:
                lengths[ftype] = flen  # the first definition stands
                wanted[ftype] = fixed
                for k in range(wanted_names.shape[0]):
                    same = True
                    for j in range(4):
                        if data[ofs + 5 + j] != wanted_names[k, j]:
                            same = False
                            break
                    if same:
                        wanted[ftype] = True
            fmt_offsets = _append(fmt_offsets, n_fmt, ofs)
            fmt_status = _append(fmt_status, n_fmt, status)
            n_fmt += 1
        counts[t] += 1
        if wanted[t]:
            if n_kept == len(offsets):
                offsets = np.concatenate((offsets, np.empty_like(offsets)))
                types = np.concatenate((types, np.empty_like(types)))
            offsets[n_kept] = ofs
            types[n_kept] = t
            n_kept += 1
        ofs += length
    # What the file ends with after its last record (a record cut off by a power loss, unused
    # log space) is its tail, not damage.
    tail = n - (skip_start if in_skip else ofs)
    if in_skip:
        skipped -= ofs - skip_start
        stretches -= 1
        if first_skip == skip_start:
            first_skip = -1
    return (offsets[:n_kept], types[:n_kept], counts, fmt_offsets[:n_fmt], fmt_status[:n_fmt], skipped,
            stretches, first_skip, tail)


@kernel
def _line_up(data, starts, types, lengths):
    """For each candidate k: the headers ``A3 95 types[k]`` from ``starts[k]`` on, and how
    many of them have another header (or the file end) ``lengths[k]`` bytes further."""
    n = len(data)
    candidate = np.zeros(256, np.bool_)
    for t in types:
        candidate[t] = True
    seen = np.zeros(len(types), np.int64)
    lined = np.zeros(len(types), np.int64)
    for i in range(starts.min(), n - 2):
        if data[i] != HEAD1 or data[i + 1] != HEAD2 or not candidate[data[i + 2]]:
            continue
        for k in range(len(types)):
            if data[i + 2] == types[k] and i >= starts[k]:
                seen[k] += 1
                end = i + lengths[k]
                if end == n or (end + 2 <= n and data[end] == HEAD1 and data[end + 1] == HEAD2):
                    lined[k] += 1
    return seen, lined


def _name(raw: bytes) -> str:
    """A FMT text field, as pymavlink's null_term: undecodable bytes escaped, cut at a NUL."""
    return raw.decode(errors="backslashreplace").split("\0", 1)[0]


def _text(raw: bytes) -> str:
    """A string field, as pymavlink's DFMessage gives it: UTF-8 (else Latin-1), cut at a NUL."""
    try:
        text = raw.decode("utf-8")
    except UnicodeDecodeError:
        text = raw.decode("ISO-8859-1")
    return text.split("\0", 1)[0]


def _mostly_text(values: np.ndarray) -> bool:
    """Whether most of a 4-character field's values (64 of them at most) are ASCII text."""
    sample = [v.split(b"\0", 1)[0] for v in values[::max(1, len(values) // 64)].tolist()]
    return 2 * sum(v != b"" and all(0x20 <= c < 0x7F for c in v) for v in sample) >= len(sample)


def open_log(path: str) -> np.ndarray:
    """The file's bytes as a read-only uint8 array (memory-mapped, not read into memory)."""
    with open(path, "rb") as f:
        try:
            mapped = mmap.mmap(f.fileno(), 0, access=mmap.ACCESS_READ)
        except ValueError:  # an empty file cannot be mapped
            return np.zeros(0, np.uint8)
    return np.frombuffer(mapped, dtype=np.uint8)


def release_pages(data: np.ndarray, end: int | None = None) -> None:
    """Let go of the pages of a mapped log (``open_log``) read so far (those wholly before byte
    ``end``, or all): they count in the process's memory while mapped (an hour at 400 Hz is
    166 MB), and the page cache keeps them for the next read. The array stays valid; what is
    read again is mapped again."""
    mapped = data.base.obj if isinstance(data.base, memoryview) else data.base  # (numpy keeps a memoryview of it)
    if isinstance(mapped, mmap.mmap) and hasattr(mmap, "MADV_DONTNEED"):
        if end is None:
            mapped.madvise(mmap.MADV_DONTNEED)
        elif end >= mmap.PAGESIZE:
            mapped.madvise(mmap.MADV_DONTNEED, 0, end - end % mmap.PAGESIZE)


COLUMN = re.compile(rb"[A-Za-z0-9_]+")
FMT_FIELDS = (("Type", 0, 1), ("Length", 1, 2), ("Name", 2, 6), ("Format", 6, 22), ("Columns", 22, 86))
MAX_SUSPECTS = 32  # damaged FMT records looked at per log: a log this damaged is read as it is


def _name_of(body: bytes) -> bytes:
    return body[2:6].split(b"\0", 1)[0]


def _printable(name: bytes) -> bool:
    """A message name, as the scan takes it: printable ASCII, then NULs."""
    name = name.split(b"\0", 1)[0]
    return bool(name) and all(0x21 <= c <= 0x7E for c in name)


def _sound(body: bytes) -> Format | None:
    """A FMT record's body (its header left out) as a Format if every field is sound: a
    printable name, format characters that add up to its Length, one column name per field
    (letters, digits, _), no two alike. Else None."""
    name, chars, cols = (body[a:b].split(b"\0", 1)[0] for _, a, b in FMT_FIELDS[2:])
    columns = cols.split(b",")
    if not (_printable(name) and chars and all(CHAR_SIZES[c] for c in chars)
            and body[1] == HEADER + sum(CHAR_SIZES[c] for c in chars) and len(columns) == len(chars)
            and len(set(columns)) == len(columns) and all(COLUMN.fullmatch(c) for c in columns)):
        return None
    return Format(body[0], name.decode(), body[1], chars.decode(), [c.decode() for c in columns])


def _recover(data: np.ndarray, found: tuple, wanted: list[str]) -> dict[int, tuple[Format, str]]:
    """Damaged FMT records of wanted messages, repaired: {offset: (format, what was damaged)}.

    An FMT record is damaged when the scan could not use it, or it is unsound (``_sound``), or
    (in a log with damage) nothing of its type follows it. A repair puts back one flipped bit
    (for a damaged header: takes the record as it is) and must give a sound FMT of a wanted
    message, of a type and name no other FMT record claims. It is made only when it is the one
    repair of that record, and the records of its type after it line up at its Length (each
    followed by another record's header): 90 % of them, one at least. Otherwise the record
    stays ignored and its type's records are skipped as corrupt, as before.
    """
    _, _, counts, fmt_offsets, fmt_status, skipped = found[:6]
    bodies = [data[o + HEADER:o + FMT_LENGTH].tobytes() for o in fmt_offsets]
    used = {b[0]: b for b, st in zip(bodies, fmt_status) if st == USED}
    # the types and names each FMT record claims, damaged or not: a repair takes none of another's
    claims = Counter(b[0] for b in bodies) + Counter(_name_of(b) for b in bodies)
    layouts = Counter(b[1:2] + b[6:] for b in bodies)  # Length, Format, Columns
    wanted_names = {name.encode() for name in wanted}
    candidates = []  # (offset, format, repaired body)
    suspects = 0
    for ofs, body, st in zip(fmt_offsets.tolist(), bodies, fmt_status):
        is_wanted = _name_of(body) in wanted_names
        if st == USED:  # unsound, or (in a damaged log) its type was one bit off
            damaged = is_wanted and (_sound(body) is None or (skipped and not counts[body[0]]))
        elif st == IGNORED:  # a type one bit off, onto a defined one
            damaged = is_wanted and used.get(body[0]) != body
        else:  # only a bit of the name can make the others wanted
            damaged = is_wanted or (st == UNUSABLE and not _printable(body[2:6]))
        if not damaged:
            continue
        suspects += 1
        if suspects > MAX_SUSPECTS:
            break
        if st == BAD_HEADER:
            repairs = [body]
        else:
            where = range(len(body)) if is_wanted else range(2, 6)
            repairs = [body[:i] + bytes([body[i] ^ (1 << bit)]) + body[i + 1:] for i in where for bit in range(8)]
        for fixed in repairs:
            fmt = _sound(fixed)
            if not fmt or fmt.name not in wanted or fmt.type == FMT_TYPE:
                continue
            others = (claims[fmt.type] - (fmt.type == body[0])
                      + claims[_name_of(fixed)] - (_name_of(fixed) == _name_of(body)))
            # records of another type may fit another FMT just as well (IMU, IMU2 in old logs)
            twins = fmt.type != body[0] and layouts[fixed[1:2] + fixed[6:]] > 1
            if not others and not twins:
                candidates.append((ofs, fmt, fixed))
    if not candidates:
        return {}
    seen, lined = _line_up(data, np.array([c[0] + FMT_LENGTH for c in candidates], np.int64),
                           np.array([c[1].type for c in candidates], np.int64),
                           np.array([c[1].length for c in candidates], np.int64))
    verified: dict[int, list] = {}
    for (ofs, fmt, fixed), s, k in zip(candidates, seen, lined):
        if k and k >= 0.9 * s:
            verified.setdefault(ofs, []).append((fmt, fixed))
    fixes: dict[int, tuple[Format, str]] = {}
    for ofs, repairs in verified.items():
        fmt, fixed = repairs[0]
        taken = {(f.type, f.name) for f, _ in fixes.values()}
        if len(repairs) > 1 or any(fmt.type == t or fmt.name == name for t, name in taken):
            continue  # more than one way to read it: none
        body = data[ofs + HEADER:ofs + FMT_LENGTH].tobytes()
        what = next((f"its {field}" for field, a, b in FMT_FIELDS if body[a:b] != fixed[a:b]), "its header")
        fixes[ofs] = (fmt, what)
    return fixes


def scan_log(data: np.ndarray, wanted: list[str]) -> Scan:
    """Find the records of the ``wanted`` message names (FMT always) in a log's bytes."""
    names = np.zeros((len(wanted), 4), np.uint8)
    for k, name in enumerate(wanted):
        raw = name.encode()[:4]
        names[k, :len(raw)] = np.frombuffer(raw, np.uint8)
    none = np.zeros(0, np.int64)
    found = _scan(data, names, CHAR_SIZES, none, none, none)
    fixes = _recover(data, found, wanted)
    if fixes:  # again, each repaired FMT in place of the damaged one
        at = np.array(sorted(fixes), np.int64)
        found = _scan(data, names, CHAR_SIZES, at, np.array([fixes[o][0].type for o in at], np.int64),
                      np.array([fixes[o][0].length for o in at], np.int64))
    offsets, types, counts, fmt_offsets, fmt_status, skipped, stretches, first_skip, tail = found
    formats: dict[int, Format] = {}
    for ofs in fmt_offsets[fmt_status == USED]:
        if int(ofs) in fixes:
            formats[fixes[int(ofs)][0].type] = fixes[int(ofs)][0]
            continue
        body = data[ofs + HEADER:ofs + FMT_LENGTH].tobytes()
        ftype = body[0]
        if ftype in formats:
            continue
        columns = _name(body[22:86]).split(",") if body[22] else []
        formats[ftype] = Format(ftype, _name(body[2:6]), body[1], _name(body[6:22]), columns)
    first = {}  # name -> the type of its first FMT (damage can give two types one name)
    for ftype, f in formats.items():
        first.setdefault(f.name, ftype)
    by_name: dict[str, np.ndarray] = {}
    for ftype in np.unique(types):
        name = formats[int(ftype)].name
        if first[name] == ftype:
            by_name[name] = offsets[types == ftype]
    record_counts = {f.name: int(counts[t]) for t, f in formats.items() if counts[t]}
    return Scan(formats, by_name, record_counts, int(skipped), int(stretches), int(first_skip),
                int(np.count_nonzero(fmt_status == UNUSABLE)), int(tail),
                [f"{fmt.name} ({what})" for fmt, what in fixes.values()])


def _gather(data: np.ndarray, offsets: np.ndarray, start: int, size: int) -> np.ndarray:
    """The ``size`` bytes at ``offsets + start`` of ``data``, one row each ((rows, size); the
    rows ``size`` rounded up to 8 bytes apart). Copied a word at a time, each put together from
    the two aligned words it straddles, into an array numpy allocates (numpy asks for huge
    pages; numba's own allocation took twice as long in page faults): 2.5x the byte-by-byte copy."""
    n_words = (size + 7) // 8
    out = np.empty((len(offsets), n_words), np.uint64)
    rows = out.view(np.uint8)
    words = np.frombuffer(data, np.uint64, count=len(data) // 8)
    if sys.byteorder == "little":
        _gather_words(words, offsets, start, out)
    # a row whose last word straddles the file's end (the last few bytes), or a big-endian
    # machine: byte by byte
    slow = np.flatnonzero((offsets + start) // 8 + n_words >= len(words)) if sys.byteorder == "little" \
        else range(len(offsets))
    for i in slow:
        rows[i, :size] = data[offsets[i] + start:offsets[i] + start + size]
    return rows[:, :size]


@kernel
def _gather_words(words, offsets, start, out):
    """``_gather``'s copy (words: the file as aligned uint64), but for rows that run into its
    last word."""
    n_words = out.shape[1]
    for i in range(len(offsets)):
        at = offsets[i] + start
        word = at >> 3
        if word + n_words >= len(words):
            continue
        shift = (at & 7) * 8
        if shift == 0:
            for j in range(n_words):
                out[i, j] = words[word + j]
        else:
            low = words[word]
            for j in range(n_words):
                high = words[word + j + 1]
                out[i, j] = (low >> shift) | (high << (64 - shift))
                low = high


def decode(data: np.ndarray, scan: Scan, name: str, rows: slice = slice(None)) -> Mapping[str, np.ndarray]:
    """Every record of message ``name`` (or the ``rows`` of them): column -> array (len =
    records), values as pymavlink gives them, each column converted when first asked for (an
    hour of IMU has 15 columns; a reader uses 8). ValueError when the format's Length
    disagrees with its Format (pymavlink cannot decode those records either)."""
    offsets = scan.offsets[name][rows]
    fmt = scan.format_of(name)
    dtype = fmt.dtype()
    if len(fmt.columns) != len(fmt.format):  # a column name split or two joined: the names after it are off
        raise ValueError(f"its {len(fmt.columns)} column names do not fit its {len(fmt.format)} fields")
    if dtype.itemsize != fmt.length - HEADER:
        raise ValueError(f"its format {fmt.format!r} is {dtype.itemsize} bytes, its records {fmt.length - HEADER}")
    records = _gather(data, offsets, HEADER, dtype.itemsize).view(dtype).reshape(-1)
    for i, char in enumerate(fmt.format):  # a float read as text: 'f' and 'n' (char[4]) are a bit apart
        if char == "n" and not _mostly_text(records[dtype.names[i]]):
            raise ValueError(f"its field {dtype.names[i]} ('n', 4 characters) holds no text")
    return RecordColumns(fmt, records)


class RecordColumns(Mapping):
    """The columns of one message type's records, converted as pymavlink converts them."""

    def __init__(self, fmt: Format, records: np.ndarray):
        self._fmt, self._records, self._fields = fmt, records, fmt.named_fields()
        self._done: dict[str, np.ndarray] = {}

    def __getitem__(self, column: str) -> np.ndarray:
        if column not in self._done:
            if column not in self._fields:
                raise KeyError(column)
            values = self._records[column]
            multiplier = FORMAT_TYPES[self._fmt.format[self._fields[column]]][2]
            with np.errstate(invalid="ignore"):  # a corrupt float may be a signalling NaN: NaN it stays
                if multiplier is not None:
                    values = values.astype(np.float64) / (1.0 / multiplier)  # pymavlink divides, for accuracy
                elif values.dtype.kind == "f":
                    values = values.astype(np.float64)
                elif values.dtype.kind == "S":
                    values = np.array([_text(v) for v in values.tolist()], dtype=object)
            self._done[column] = values
        return self._done[column]

    def __contains__(self, column) -> bool:
        return column in self._fields

    def __iter__(self):
        return iter(self._fields)

    def __len__(self) -> int:
        return len(self._fields)
