"""MAVLink packet framing without pymavlink's per-byte parser: header parsing, CRC, payload layout.

Used by the tlog fast path and, for the same frames, by the live link: a packet's bytes go
through :func:`split_packet` and :class:`PayloadLayout` whichever way they arrived.
"""
from __future__ import annotations

import re
import struct
from dataclasses import dataclass

from fastcrc.crc16 import mcrf4xx

from gcs_pdm.mavlink.dialect import CRC_EXTRA, MESSAGE_CLASSES

MAGIC_V1 = 0xFE
MAGIC_V2 = 0xFD
HEADER_LEN_V1 = 6  # magic len seq sysid compid msgid
HEADER_LEN_V2 = 10  # magic len incompat compat seq sysid compid msgid(3)
SEQ_AT_V1, SEQ_AT_V2 = 2, 4  # the sender's packet counter's byte in each header
SIGNATURE_LEN = 13
MAVLINK_IFLAG_SIGNED = 0x01

# One-byte strings of each message's CRC_EXTRA, so the CRC can be finished without building a
# concatenated copy of the packet.
CRC_EXTRA_BYTES: dict[int, bytes] = {msgid: bytes((extra,)) for msgid, extra in CRC_EXTRA.items()}


def crc_ok(packet: memoryview | bytes, header_len: int, payload_len: int, msgid: int) -> bool | None:
    """True/False for a packet whose CRC_EXTRA is known; None when the message id is unknown."""
    extra = CRC_EXTRA_BYTES.get(msgid)
    if extra is None:
        return None
    end = header_len + payload_len
    crc = mcrf4xx(extra, mcrf4xx(packet[1:end]))
    return crc == (packet[end] | (packet[end + 1] << 8))


@dataclass(frozen=True, slots=True)
class Packet:
    """One MAVLink packet split into the parts the mapping needs."""

    msgid: int
    sysid: int
    compid: int
    payload: bytes
    version: int
    seq: int  # the sender's packet counter, modulo 256 (gcs_pdm.mavlink.sequence)


def split_packet(buf: bytes) -> Packet | None:
    """Header fields and payload of one complete packet (as pymavlink's ``get_msgbuf()`` gives)."""
    if len(buf) < 8:
        return None
    if buf[0] == MAGIC_V2:
        plen = buf[1]
        return Packet(buf[7] | (buf[8] << 8) | (buf[9] << 16), buf[5], buf[6],
                      bytes(buf[HEADER_LEN_V2:HEADER_LEN_V2 + plen]), 2, buf[SEQ_AT_V2])
    if buf[0] == MAGIC_V1:
        plen = buf[1]
        return Packet(buf[5], buf[3], buf[4], bytes(buf[HEADER_LEN_V1:HEADER_LEN_V1 + plen]), 1, buf[SEQ_AT_V1])
    return None


_FORMAT_TOKEN = re.compile(r"(\d*)([a-zA-Z?])")


class PayloadLayout:
    """Where each field of one message sits in the tuple that its precompiled ``struct`` returns.

    MAVLink 2 drops trailing zero bytes of a payload and MAVLink 1 carries no extension fields,
    so :meth:`unpack` pads short payloads with zeros (which is what the dropped bytes were).
    """

    __slots__ = ("msgid", "name", "struct", "size", "index", "count", "codes", "_fields", "_as_dict", "_dtype")

    def __init__(self, msgid: int):
        cls = MESSAGE_CLASSES[msgid]
        self.msgid = msgid
        self.name: str = cls.msgname
        self.struct = struct.Struct(cls.unpacker.format)
        self.size = self.struct.size
        self.index: dict[str, int] = {}
        self.count: dict[str, int] = {}
        self.codes: dict[str, tuple[str, str]] = {}  # name -> (struct code, repeat), in wire order
        tokens = _FORMAT_TOKEN.findall(cls.unpacker.format.lstrip("<"))
        position = 0
        for name, (repeat, code) in zip(cls.ordered_fieldnames, tokens):
            n = 1 if code == "s" or not repeat else int(repeat)
            self.index[name] = position
            self.count[name] = n
            self.codes[name] = (code, repeat)
            position += n
        self._dtype = None
        # (name, position, count, is text) in the message's field order, for :meth:`as_dict`
        text = {name for name, (_r, code) in zip(cls.ordered_fieldnames, tokens) if code == "s"}
        self._fields = tuple((name, self.index[name], self.count[name], name in text) for name in cls.fieldnames)
        self._as_dict = self._compile_as_dict()

    def _compile_as_dict(self):
        """``as_dict`` over the unpacked tuple as one dict display compiled from source (one call a
        message, not a loop over the fields)."""
        items = []
        for name, pos, count, text in self._fields:
            if text:
                items.append(f"{name!r}: v[{pos}].split(b'\\0', 1)[0].decode(errors='backslashreplace')")
            elif count == 1:
                items.append(f"{name!r}: v[{pos}]")
            else:
                items.append(f"{name!r}: list(v[{pos}:{pos + count}])")
        namespace: dict = {}
        exec(f"def as_dict(v):\n    return {{{', '.join(items)}}}\n", namespace)  # noqa: S102 - our own source
        return namespace["as_dict"]

    def unpack(self, payload: bytes | memoryview) -> tuple:
        if len(payload) != self.size:
            payload = bytes(payload)[: self.size].ljust(self.size, b"\0")
        return self.struct.unpack(payload)

    def as_dict(self, payload: bytes | memoryview) -> dict:
        """The fields by name as pymavlink's ``msg.to_dict()`` gives them (arrays as lists, text
        decoded up to its NUL padding), without building a pymavlink message."""
        return self._as_dict(self.unpack(payload))

    def field_at(self, position: int) -> tuple[str, int | None, str]:
        """The field behind a position of the unpacked tuple: (name, element of an array field or
        None, struct code)."""
        for name, start in self.index.items():
            if start <= position < start + self.count[name]:
                code, repeat = self.codes[name]
                return name, (position - start if repeat and code != "s" else None), code
        raise IndexError(f"{self.name} has {sum(self.count.values())} values, not {position + 1}")

    @property
    def dtype(self):
        """The payload as a numpy structured dtype (little-endian, packed: one record a payload;
        array fields as sub-arrays, char[] as bytes)."""
        if self._dtype is None:
            import numpy as np

            self._dtype = np.dtype([(name, f"S{repeat or 1}") if code == "s" else
                                    ((name, "<" + _NUMPY_CODES[code], (int(repeat),)) if repeat else
                                     (name, "<" + _NUMPY_CODES[code]))
                                    for name, (code, repeat) in self.codes.items()])
            assert self._dtype.itemsize == self.size, self.name
        return self._dtype

    def unpack_many(self, raw, start, end):
        """The payloads ``raw[start[i]:end[i]]`` (``raw``: the bytes as a numpy uint8 array; ``start``,
        ``end``: int64 arrays) as one structured array of :attr:`dtype`, all at once: what
        :meth:`unpack` gives each of them (short payloads padded with zeros, longer ones cut)."""
        import numpy as np

        size = self.size
        length = np.minimum(end - start, size)
        if start.size and int(start.max()) + size > raw.size:  # a payload near the end of the data
            raw = np.concatenate((raw, np.zeros(size, dtype=np.uint8)))
        rows = np.lib.stride_tricks.sliding_window_view(raw, size)[start]  # one copy of each payload
        short = length < size
        if short.any():
            rows[np.arange(size) >= length[:, None]] = 0
        return rows.view(self.dtype).reshape(-1)


#: struct code -> numpy type code (little-endian is added where used)
_NUMPY_CODES = {"b": "i1", "B": "u1", "h": "i2", "H": "u2", "i": "i4", "I": "u4", "q": "i8", "Q": "u8",
                "f": "f4", "d": "f8", "c": "S1", "?": "?"}

_LAYOUTS: dict[int, PayloadLayout] = {}


def layout(msgid: int) -> PayloadLayout:
    found = _LAYOUTS.get(msgid)
    if found is None:
        found = _LAYOUTS[msgid] = PayloadLayout(msgid)
    return found


# msgid -> byte offset of a ``time_boot_ms`` (uint32) field, for every message that carries one.
TIME_BOOT_MS_OFFSET: dict[int, int] = {}
for _msgid, _cls in MESSAGE_CLASSES.items():
    if "time_boot_ms" in _cls.ordered_fieldnames:
        _fmt = _cls.unpacker.format
        _names = _cls.ordered_fieldnames
        _tokens = _FORMAT_TOKEN.findall(_fmt.lstrip("<"))
        _offset = 0
        for _name, (_rep, _code) in zip(_names, _tokens):
            if _name == "time_boot_ms":
                if _code in "Ii":
                    TIME_BOOT_MS_OFFSET[_msgid] = _offset
                break
            _offset += struct.calcsize("<" + _rep + _code)
