"""MAVLink telemetry logs (.tlog) in bulk: find the packets, then decode each message type at once.

A .tlog is a stream of records: a big-endian UNIX time in µs (8 bytes, the ground station's
receive time), then one MAVLink 1 or 2 packet. pymavlink decodes it packet by packet in Python
(about 15 µs a packet); here one compiled pass (``scan``) walks the records, checks each packet's
CRC and keeps where the packets of the wanted message ids are, and ``decode`` views all packets of
one id through one numpy structured dtype made from pymavlink's own message definition. The
header is only peeked at: a message we do not use is never decoded.

A packet counts when its CRC (with the message's CRC_EXTRA) is right. A packet whose CRC is
wrong, or whose id the dialect does not know, is skipped whole when the next record starts right
after it; otherwise the scan steps forward a byte at a time until packets line up again, and
counts the bytes it skipped.

Values come out as pymavlink gives them (its tests compare field by field): MAVLink 2's
truncated payloads zero-padded to the message's full length, integers as integers, floats
widened to float64.
"""
from __future__ import annotations

import re
from dataclasses import dataclass

import numpy as np

from ..kernel_cache import kernel
from pymavlink.dialects.v20 import ardupilotmega as dialect

MAGIC_V1, MAGIC_V2 = 0xFE, 0xFD
TIME_BYTES = 8  # the record's receive time, before the packet
SIGNATURE_BYTES = 13  # MAVLink 2, when incompat_flags has bit 0
STRUCT_TO_NUMPY = {"Q": "<u8", "q": "<i8", "I": "<u4", "i": "<i4", "H": "<u2", "h": "<i2", "B": "u1",
                   "b": "i1", "f": "<f4", "d": "<f8", "c": "S1", "s": "S"}


def _crc_extras() -> np.ndarray:
    """CRC_EXTRA by message id; -1 where the dialect has no such message."""
    extras = np.full(max(dialect.mavlink_map) + 1, -1, np.int64)
    for msgid, cls in dialect.mavlink_map.items():
        extras[msgid] = cls.crc_extra
    return extras


CRC_EXTRAS = _crc_extras()


@kernel
def _crc_ok(data, start, end, extra, crc):
    """MAVLink's X.25 CRC over data[start:end] and the message's CRC_EXTRA, against ``crc``."""
    acc = 0xFFFF
    for k in range(start, end + 1):
        b = data[k] if k < end else extra
        tmp = (b ^ (acc & 0xFF)) & 0xFF
        tmp = (tmp ^ (tmp << 4)) & 0xFF
        acc = ((acc >> 8) ^ (tmp << 8) ^ (tmp << 3) ^ (tmp >> 4)) & 0xFFFF
    return acc == crc


@kernel
def _packet_end(data, p):
    """Where the packet starting at ``p`` ends (its signature included), or -1 if not a packet
    start. Returns (end, header length)."""
    magic = data[p]
    if magic == MAGIC_V1:
        return p + 6 + data[p + 1] + 2, 6
    if magic == MAGIC_V2:
        signed = SIGNATURE_BYTES if data[p + 2] & 1 else 0
        return p + 10 + data[p + 1] + 2 + signed, 10
    return -1, 0


@kernel
def _scan(data, start, crc_extras, wanted):
    """One pass over the records from ``start``. Returns (packet offsets, message ids, system
    ids, payload starts, payload lengths) of the wanted packets, the count of every good
    packet by id, and (corrupt packets, unknown packets, skipped bytes, tail bytes)."""
    n = len(data)
    cap = max(n // 32, 16)
    offsets = np.empty(cap, np.int64)
    msgids = np.empty(cap, np.int64)
    sysids = np.empty(cap, np.int64)
    pstart = np.empty(cap, np.int64)
    plen = np.empty(cap, np.int64)
    counts = np.zeros(len(crc_extras), np.int64)
    kept = corrupt = unknown = skipped = 0
    ofs = start
    while ofs + TIME_BYTES + 8 <= n:  # the shortest packet: MAVLink 1, no payload
        p = ofs + TIME_BYTES
        end, hlen = _packet_end(data, p)
        if end < 0 or end > n:
            skipped += 1
            ofs += 1
            continue
        if hlen == 6:
            msgid = np.int64(data[p + 5])
            sysid = data[p + 3]
        else:
            msgid = np.int64(data[p + 7]) | (np.int64(data[p + 8]) << 8) | (np.int64(data[p + 9]) << 16)
            sysid = data[p + 5]
        length = data[p + 1]
        crc_at = p + hlen + length
        good = False
        if msgid < len(crc_extras) and crc_extras[msgid] >= 0:
            crc = np.int64(data[crc_at]) | (np.int64(data[crc_at + 1]) << 8)
            good = _crc_ok(data, p + 1, crc_at, crc_extras[msgid], crc)
        if not good:
            # skipped whole only when the next record lines up behind it
            nxt = end + TIME_BYTES
            if end == n or (nxt < n and (data[nxt] == MAGIC_V1 or data[nxt] == MAGIC_V2)):
                if msgid < len(crc_extras) and crc_extras[msgid] >= 0:
                    corrupt += 1
                else:
                    unknown += 1
                ofs = end
            else:
                skipped += 1
                ofs += 1
            continue
        counts[msgid] += 1
        if wanted[msgid]:
            if kept == len(offsets):
                offsets = np.concatenate((offsets, np.empty(len(offsets), np.int64)))
                msgids = np.concatenate((msgids, np.empty(len(msgids), np.int64)))
                sysids = np.concatenate((sysids, np.empty(len(sysids), np.int64)))
                pstart = np.concatenate((pstart, np.empty(len(pstart), np.int64)))
                plen = np.concatenate((plen, np.empty(len(plen), np.int64)))
            offsets[kept] = ofs
            msgids[kept] = msgid
            sysids[kept] = sysid
            pstart[kept] = p + hlen
            plen[kept] = length
            kept += 1
        ofs = end
    return (offsets[:kept], msgids[:kept], sysids[:kept], pstart[:kept], plen[:kept], counts,
            corrupt, unknown, skipped, n - ofs)


@dataclass
class Packets:
    """What ``scan`` found: the wanted packets in file order, and what it could not use."""
    offsets: np.ndarray  # each record's offset in the file
    msgids: np.ndarray
    sysids: np.ndarray
    payload_start: np.ndarray
    payload_length: np.ndarray
    counts: dict[str, int]  # message name -> good packets, every id
    corrupt: int  # packets of a known id with a wrong CRC
    unknown: int  # packets of an id the dialect does not know
    skipped_bytes: int  # bytes that were no packet
    tail_bytes: int  # after the last record (a record cut off)


def msgid(name: str) -> int:
    return getattr(dialect, f"MAVLINK_MSG_ID_{name}")


def scan(data: np.ndarray, start: int, wanted: list[str]) -> Packets:
    """The packets of the ``wanted`` message names in a .tlog's bytes, from ``start``."""
    want = np.zeros(len(CRC_EXTRAS), np.bool_)
    for name in wanted:
        want[msgid(name)] = True
    (offsets, ids, sysids, pstart, plen, counts, corrupt, unknown, skipped, tail) = _scan(
        data, start, CRC_EXTRAS, want)
    names = {int(i): dialect.mavlink_map[int(i)].msgname for i in np.flatnonzero(counts)}
    return Packets(offsets, ids, sysids, pstart, plen, {names[i]: int(counts[i]) for i in names},
                   int(corrupt), int(unknown), int(skipped), int(tail))


def _dtype(cls) -> np.dtype:
    """A message's payload, in wire order, as a numpy structured type (from its struct format)."""
    tokens = re.findall(r"(\d*)([a-zA-Z])", cls.unpacker.format)
    formats = []
    for count, char in tokens:
        count = int(count or 1)
        if char == "s":
            formats.append(f"S{count}")
        else:
            formats.append((STRUCT_TO_NUMPY[char], (count,)) if count > 1 else STRUCT_TO_NUMPY[char])
    return np.dtype({"names": list(cls.ordered_fieldnames), "formats": formats})


@kernel
def _gather(data, starts, lengths, size):
    """Each payload, zero-padded or cut to ``size`` bytes, as MAVLink 2 and pymavlink do."""
    out = np.zeros((len(starts), size), np.uint8)
    for i in range(len(starts)):
        m = min(lengths[i], size)
        out[i, :m] = data[starts[i]:starts[i] + m]
    return out


def decode(data: np.ndarray, packets: Packets, name: str, rows: np.ndarray) -> dict[str, np.ndarray]:
    """The ``rows`` (indices into ``packets``) of message ``name``: field -> array, numbers as
    pymavlink gives them (float fields widened to float64)."""
    cls = dialect.mavlink_map[msgid(name)]
    dtype = _dtype(cls)
    raw = _gather(data, packets.payload_start[rows], packets.payload_length[rows], dtype.itemsize)
    records = raw.view(dtype).reshape(-1)
    out = {}
    for field in dtype.names:
        values = records[field]
        out[field] = values.astype(np.float64) if values.dtype.kind == "f" else values
    return out


def packet_bytes(data: np.ndarray, packets: Packets, i: int) -> bytearray:
    """Packet ``i`` as it was sent, for pymavlink to decode (text and rare messages)."""
    p = packets.payload_start[i] - (6 if data[packets.offsets[i] + TIME_BYTES] == MAGIC_V1 else 10)
    end, _ = _packet_end(data, p)
    return bytearray(data[p:end].tobytes())
