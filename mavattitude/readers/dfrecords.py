"""DataFlash records in bulk: find them, then decode each message type at once.

A DataFlash log (.bin) is a stream of records: ``A3 95``, a type byte, then a body whose
layout the log itself defines in FMT records (type 128: Type, Length, Name, Format, Columns).
pymavlink reads it record by record in Python; here one compiled pass (``scan``) walks the
records and keeps the offsets of the wanted types, and ``decode`` views all records of a type
through one numpy structured dtype, as pyulog does for ULog.

Damage: a record counts only if its type has a valid FMT (its Length agrees with its Format)
and it is followed by another record's header or by the end of the file. Anything else is
corrupt: the scan steps forward a byte at a time until records line up again, and counts what
it skipped. pymavlink, by contrast, stops at the first record of an unknown type, so a
flipped type byte loses the rest of the log.

Values come out exactly as pymavlink gives them (its tests compare field by field): integers
as integers, ``f``/``d``/``g`` floats widened to float64, the scaled types (``c C e E L``)
divided as pymavlink divides (by ``1 / multiplier``), strings cut at their first NUL. FMTU's
multipliers are not applied (pymavlink does not either): units stay as logged.
"""
from __future__ import annotations

import mmap
from dataclasses import dataclass

import numpy as np
from numba import njit

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
    bad_formats: int = 0  # FMT records with characters that are no format
    tail_bytes: int = 0  # after the last record: a record cut off, unused log space


@njit(cache=True)
def _scan(data, wanted_names, char_sizes):
    """One pass over the records. ``wanted_names``: (K, 4) uint8, the names whose records are
    kept. Returns (offsets, types, type counts, FMT offsets, skipped bytes, stretches, first
    skip, unusable FMTs, tail bytes)."""
    n = len(data)
    lengths = np.zeros(256, np.int64)
    lengths[FMT_TYPE] = FMT_LENGTH
    wanted = np.zeros(256, np.bool_)
    counts = np.zeros(256, np.int64)
    offsets = np.empty(max(n // 16, 16), np.int64)
    types = np.empty(len(offsets), np.uint8)
    fmt_offsets = np.empty(256, np.int64)
    n_kept = 0
    n_fmt = 0
    skipped = 0
    stretches = 0
    first_skip = -1
    bad_formats = 0
    in_skip = False
    skip_start = 0
    ofs = 0
    while ofs + HEADER <= n:
        t = data[ofs + 2]
        length = lengths[t]
        ok = data[ofs] == HEAD1 and data[ofs + 1] == HEAD2 and length > 0 and ofs + length <= n
        if ok:
            nxt = ofs + length
            # the next record must start right after this one (or the file end)
            ok = nxt + 2 > n or (data[nxt] == HEAD1 and data[nxt + 1] == HEAD2)
        if not ok:
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
            ftype = data[ofs + 3]
            flen = data[ofs + 4]
            size = HEADER
            valid = True
            for j in range(16):
                c = data[ofs + 9 + j]
                if c == 0:
                    break
                if char_sizes[c] == 0:
                    valid = False
                size += char_sizes[c]
            # Framing trusts Length, as the firmware and pymavlink do; a Length that disagrees
            # with the Format (a firmware quirk: BAR3 33 for 29 bytes in Copter 3.4) only stops
            # that message from being decoded (see ``decode``).
            if valid and flen >= HEADER and ftype != FMT_TYPE and lengths[ftype] == 0:
                lengths[ftype] = flen  # the first definition stands
                for k in range(wanted_names.shape[0]):
                    same = True
                    for j in range(4):
                        if data[ofs + 5 + j] != wanted_names[k, j]:
                            same = False
                            break
                    if same:
                        wanted[ftype] = True
                if n_fmt == len(fmt_offsets):
                    fmt_offsets = np.concatenate((fmt_offsets, np.empty(len(fmt_offsets), np.int64)))
                fmt_offsets[n_fmt] = ofs
                n_fmt += 1
            elif not valid:
                bad_formats += 1
        counts[t] += 1
        if wanted[t]:
            if n_kept == len(offsets):
                offsets = np.concatenate((offsets, np.empty(len(offsets), np.int64)))
                types = np.concatenate((types, np.empty(len(types), np.uint8)))
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
    return (offsets[:n_kept], types[:n_kept], counts, fmt_offsets[:n_fmt], skipped, stretches,
            first_skip, bad_formats, tail)


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


def open_log(path: str) -> np.ndarray:
    """The file's bytes as a read-only uint8 array (memory-mapped, not read into memory)."""
    with open(path, "rb") as f:
        try:
            mapped = mmap.mmap(f.fileno(), 0, access=mmap.ACCESS_READ)
        except ValueError:  # an empty file cannot be mapped
            return np.zeros(0, np.uint8)
    return np.frombuffer(mapped, dtype=np.uint8)


def scan_log(data: np.ndarray, wanted: list[str]) -> Scan:
    """Find the records of the ``wanted`` message names (FMT always) in a log's bytes."""
    names = np.zeros((len(wanted), 4), np.uint8)
    for k, name in enumerate(wanted):
        raw = name.encode()[:4]
        names[k, :len(raw)] = np.frombuffer(raw, np.uint8)
    offsets, types, counts, fmt_offsets, skipped, stretches, first_skip, bad, tail = _scan(data, names, CHAR_SIZES)
    formats: dict[int, Format] = {}
    for ofs in fmt_offsets:
        body = data[ofs + HEADER:ofs + FMT_LENGTH].tobytes()
        ftype = body[0]
        if ftype in formats:
            continue
        columns = _name(body[22:86]).split(",") if body[22] else []
        formats[ftype] = Format(ftype, _name(body[2:6]), body[1], _name(body[6:22]), columns)
    by_name: dict[str, np.ndarray] = {}
    for ftype in np.unique(types):
        by_name[formats[int(ftype)].name] = offsets[types == ftype]
    record_counts = {f.name: int(counts[t]) for t, f in formats.items() if counts[t]}
    return Scan(formats, by_name, record_counts, int(skipped), int(stretches), int(first_skip), int(bad),
                int(tail))


@njit(cache=True)
def _gather(data, offsets, start, size):
    out = np.empty((len(offsets), size), np.uint8)
    for i in range(len(offsets)):
        out[i, :] = data[offsets[i] + start:offsets[i] + start + size]
    return out


def decode(data: np.ndarray, scan: Scan, name: str) -> dict[str, np.ndarray]:
    """Every record of message ``name``: column -> array (len = records), values as pymavlink
    gives them. ValueError when the format's Length disagrees with its Format (pymavlink
    cannot decode those records either)."""
    offsets = scan.offsets[name]
    fmt = next(f for f in scan.formats.values() if f.name == name)
    dtype = fmt.dtype()
    if dtype.itemsize != fmt.length - HEADER:
        raise ValueError(f"its format {fmt.format!r} is {dtype.itemsize} bytes, its records {fmt.length - HEADER}")
    records = _gather(data, offsets, HEADER, dtype.itemsize).view(dtype).reshape(-1)
    out = {}
    with np.errstate(invalid="ignore"):  # a corrupt float may be a signalling NaN: NaN it stays
        for column, i in fmt.named_fields().items():
            values = records[column]
            multiplier = FORMAT_TYPES[fmt.format[i]][2]
            if multiplier is not None:
                values = values.astype(np.float64) / (1.0 / multiplier)  # pymavlink divides, for accuracy
            elif values.dtype.kind == "f":
                values = values.astype(np.float64)
            elif values.dtype.kind == "S":
                values = np.array([_text(v) for v in values.tolist()], dtype=object)
            out[column] = values
    return out
