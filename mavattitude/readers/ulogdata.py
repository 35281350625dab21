"""ULog topics in bulk: the messages ``ulogrecords.frame`` found, decoded as pyulog decodes them.

``frame`` walks the file once (a compiled pass over the data messages) and keeps where each
valid message starts. Here the few other messages (formats, info, parameters, subscriptions,
dropouts) are read in turn, and every data message of a wanted topic is gathered and viewed
through one numpy structured dtype built from its format, flattened as pyulog flattens it:
nested formats as ``outer.inner``, arrays as ``name[i]``, trailing ``_padding`` left out, ``bool``
and ``char`` as int8. The result has the parts of pyulog's ``ULog`` that ``readers.ulog`` uses
(``data_list``, ``initial_parameters``, ``msg_info_dict``, ``dropouts``, ``file_corruption``),
with the same names, dtypes and values (tests/test_ulog_reader.py compares them).

What this does not follow, it hands back as ``Unsupported`` (and the caller reads the file with
pyulog): data appended at given offsets or another incompatible flag bit, a wanted topic whose
format is missing, damaged or of an unknown type, a topic id subscribed twice.
"""
from __future__ import annotations

import struct
from dataclasses import dataclass, field

import numpy as np

from .dfrecords import _gather
from .ulogrecords import FIELD_SIZES, HEADER_SIZE, MAX_NESTING, Framing

# ULog field type -> numpy type, as pyulog's _UNPACK_TYPES
NUMPY_TYPES = {"int8_t": "i1", "uint8_t": "u1", "int16_t": "<i2", "uint16_t": "<u2", "int32_t": "<i4",
               "uint32_t": "<u4", "int64_t": "<i8", "uint64_t": "<u8", "float": "<f4", "double": "<f8",
               "bool": "i1", "char": "i1"}
STRUCT_TYPES = {"int8_t": "b", "uint8_t": "B", "int16_t": "h", "uint16_t": "H", "int32_t": "i",
                "uint32_t": "I", "int64_t": "q", "uint64_t": "Q", "float": "f", "double": "d", "bool": "?",
                "char": "c"}
UNPACK = {kind: struct.Struct("<" + code).unpack for kind, code in STRUCT_TYPES.items()}
DEFINITIONS_END = frozenset(b"ALC")  # pyulog: the first of these starts the data section


class Unsupported(Exception):
    """The file uses something this reader does not follow; the message says what."""


@dataclass
class Topic:
    """One subscription's samples: field name -> array, as pyulog's ``ULog.Data``."""
    name: str
    multi_id: int
    msg_id: int
    data: dict[str, np.ndarray]


@dataclass
class Dropout:
    duration: int  # ms


@dataclass
class LoggedLine:
    """A logged text line, as pyulog's ``MessageLogging`` (damaged text is replaced, not raised)."""
    log_level: int  # '0'-'7' as a byte: emergency .. debug
    timestamp: int  # µs
    message: str


@dataclass
class Topics:
    """What ``readers.ulog`` takes from pyulog's ``ULog``, under the same names."""
    data_list: list[Topic] = field(default_factory=list)
    initial_parameters: dict[str, float | int] = field(default_factory=dict)
    msg_info_dict: dict[str, object] = field(default_factory=dict)
    dropouts: list[Dropout] = field(default_factory=list)
    file_corruption: bool = False
    # the logged text lines, tagged or not (``LoggedLine``)
    logged_messages: list = field(default_factory=list)


def read_topics(data: bytes, framing: Framing, wanted: list[str]) -> Topics:
    """The ``wanted`` topics of a ULog (``data``: the whole file, ``framing``: ``frame(data)``);
    Unsupported for what only pyulog reads."""
    out = Topics()
    subscribed: dict[int, tuple[str, int]] = {}  # id -> (topic, multi_id), wanted topics only
    seen_ids: set[int] = set()
    definitions = True
    buffer = np.frombuffer(data, np.uint8)
    at = np.asarray(framing.other_at, np.int64)
    sizes, kinds = buffer[at] | (buffer[at + 1].astype(np.int64) << 8), buffer[at + 2]
    for pos, size, kind in zip(at.tolist(), sizes.tolist(), kinds.tolist()):
        payload = data[pos + 3:pos + 3 + size]
        definitions = definitions and kind not in DEFINITIONS_END
        if kind == ord("B"):
            _check_flags(payload, pos)
        elif kind == ord("I"):
            key, value = _info(payload)
            out.msg_info_dict[key] = value
        elif kind == ord("P") and definitions:  # later ones are changes in flight (not read)
            key, value = _info(payload)
            out.initial_parameters[key] = value
        elif kind == ord("A"):
            multi_id, msg_id = struct.unpack_from("<BH", payload)
            if msg_id in seen_ids:
                raise Unsupported(f"topic id {msg_id} subscribed twice")
            seen_ids.add(msg_id)
            name = payload[3:].decode("utf-8", "ignore")
            if name in wanted:
                subscribed[msg_id] = (name, multi_id)
        elif kind in (ord("L"), ord("C")) and len(payload) >= (9 if kind == ord("L") else 11):
            # a logged line (tagged: a uint16 tag after the level): level, timestamp, text
            at = 1 if kind == ord("L") else 3
            out.logged_messages.append(LoggedLine(payload[0], struct.unpack_from("<Q", payload, at)[0],
                                                  bytes(payload[at + 8:]).decode("utf-8", "replace")))
        elif kind == ord("O"):
            out.dropouts.append(Dropout(struct.unpack_from("<H", payload)[0]))
        elif kind == ord("D") and struct.unpack_from("<H", payload)[0] in subscribed:
            raise Unsupported("data of a wanted topic whose format is missing or damaged")
    if not subscribed:
        return out
    offsets_of = framing.data_offsets(list(subscribed))
    for msg_id, (name, multi_id) in subscribed.items():
        offsets = offsets_of[msg_id]
        if not len(offsets):
            continue  # pyulog lists only topics with data
        dtype = topic_dtype(framing.formats, name)
        rows = _gather(buffer, offsets, 5, dtype.itemsize).view(dtype)[:, 0]
        out.data_list.append(Topic(name, multi_id, msg_id, {n: rows[n] for n in dtype.names}))
    out.data_list.sort(key=lambda t: (t.name, t.multi_id))  # as pyulog
    return out


def topic_dtype(formats: dict, name: str) -> np.dtype:
    """A topic's data as pyulog's numpy dtype: its format flattened, trailing padding left out."""
    fields: list[tuple[str, str]] = []
    _flatten(formats, name, "", fields, 0)
    while fields and fields[-1][0].startswith("_padding"):
        fields.pop()
    return np.dtype(fields)


def _flatten(formats: dict, name: str, prefix: str, fields: list, depth: int) -> None:
    if name not in formats or depth > MAX_NESTING:
        raise Unsupported(f"format {name!r} is missing or nested too deep")
    for kind, count, field_name in formats[name]:
        if count < 0:
            raise Unsupported(f"format {name!r} has a damaged array size")
        names = [f"{prefix}{field_name}[{i}]" for i in range(count)] if count else [prefix + field_name]
        for one in names:
            if kind in NUMPY_TYPES:
                fields.append((one, NUMPY_TYPES[kind]))
            else:
                _flatten(formats, kind, one + ".", fields, depth + 1)


def _info(payload: bytes) -> tuple[str, object]:
    """An info or parameter message: (key, value) as pyulog gives them (strings for char[n],
    numbers for the plain types, the raw bytes else)."""
    key_len = payload[0]
    kind, _, key = payload[1:1 + key_len].decode("utf-8", "ignore").partition(" ")
    raw = payload[1 + key_len:]
    if kind.startswith("char["):
        return key, raw.decode("utf-8", "ignore")
    if kind in STRUCT_TYPES and len(raw) == FIELD_SIZES[kind]:
        return key, UNPACK[kind](raw)[0]
    if kind in STRUCT_TYPES:
        raise Unsupported(f"info {key!r} is {len(raw)} bytes for a {kind}")
    return key, raw


def _check_flags(payload: bytes, pos: int) -> None:
    """The flag-bits message: appended data or an unknown incompatible flag is pyulog's to read."""
    if pos != HEADER_SIZE:
        raise Unsupported("the flag-bits message is not the first")
    incompat = payload[8:16]
    if any(incompat):
        raise Unsupported("data appended at given offsets" if incompat[0] == 1 and not any(incompat[1:])
                          else "an unknown incompatible flag")
