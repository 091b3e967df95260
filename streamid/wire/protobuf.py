"""Protocol-buffers wire primitives used by :mod:`streamid.wire.codec`.

Varints, tags and field iteration over a ``bytes`` buffer, plus packed
fixed-width arrays read with numpy.  Every malformation raises
:class:`~streamid.errors.CodecError` naming the byte position.
"""

from __future__ import annotations

from collections.abc import Iterator
from typing import Any

import numpy as np
from numpy.typing import NDArray

from streamid.errors import CodecError

__all__ = ["U64_MASK", "varint", "len_field", "read_varint", "skip", "fields", "utf8", "packed", "signed"]

U64_MASK = (1 << 64) - 1
_MAX_DEPTH = 64  # nesting depth for skipping unknown groups


def varint(value: int) -> bytes:
    """Encode ``value`` (taken modulo 2**64, two's complement for negatives) as a base-128 varint."""
    value &= U64_MASK
    out = bytearray()
    while value > 0x7F:
        out.append((value & 0x7F) | 0x80)
        value >>= 7
    out.append(value)
    return bytes(out)


def len_field(tag: int, payload: bytes) -> bytes:
    """A length-delimited field: tag varint, length varint, ``payload``."""
    return varint(tag) + varint(len(payload)) + payload


def read_varint(buf: bytes, pos: int, end: int) -> tuple[int, int]:
    """Read a varint at ``pos`` (before ``end``); return ``(value mod 2**64, next position)``."""
    result = 0
    shift = 0
    while True:
        if pos >= end:
            raise CodecError(f"truncated varint at byte {pos}: the payload ends inside a number")
        byte = buf[pos]
        pos += 1
        result |= (byte & 0x7F) << shift
        if byte < 0x80:
            return result & U64_MASK, pos
        shift += 7
        if shift >= 70:
            raise CodecError(f"malformed varint ending at byte {pos}: longer than 10 bytes")


def skip(buf: bytes, pos: int, end: int, wire: int, fnum: int, depth: int) -> int:
    """Skip one field's value of wire type ``wire``; return the position after it."""
    if wire == 0:
        return read_varint(buf, pos, end)[1]
    if wire == 1:
        pos += 8
    elif wire == 5:
        pos += 4
    elif wire == 2:
        length, pos = read_varint(buf, pos, end)
        pos += length
    elif wire == 3:  # deprecated group: skip until the matching end-group tag
        if depth >= _MAX_DEPTH:
            raise CodecError(f"groups nested deeper than {_MAX_DEPTH} at byte {pos}")
        while True:
            tag, pos = read_varint(buf, pos, end)
            if tag & 7 == 4:
                if tag >> 3 != fnum:
                    raise CodecError(f"unmatched end-group tag for field {tag >> 3} at byte {pos}")
                return pos
            if tag >> 3 == 0:
                raise CodecError(f"invalid field number 0 at byte {pos}")
            pos = skip(buf, pos, end, tag & 7, tag >> 3, depth + 1)
    else:
        raise CodecError(f"invalid protobuf wire type {wire} for field {fnum} at byte {pos}")
    if pos > end:
        raise CodecError(
            f"truncated field {fnum} (wire type {wire}): it ends at byte {pos}, past the end {end}"
        )
    return pos


def fields(buf: bytes, pos: int, end: int) -> Iterator[tuple[int, int, int, int]]:
    """Yield ``(field_number, wire_type, value_start, value_end_or_varint)``."""
    while pos < end:
        tag, pos = read_varint(buf, pos, end)
        fnum, wire = tag >> 3, tag & 7
        if fnum == 0:
            raise CodecError(f"invalid field number 0 at byte {pos}")
        if wire == 4:
            raise CodecError(f"unexpected end-group tag for field {fnum} at byte {pos}")
        start = pos
        if wire == 0:
            value, pos = read_varint(buf, pos, end)
            yield fnum, wire, start, value
            continue
        if wire == 2:
            length, start = read_varint(buf, pos, end)
            pos = start + length
            if pos > end:
                raise CodecError(
                    f"truncated field {fnum}: length {length} at byte {start} runs past the "
                    f"end of its message at byte {end}"
                )
            yield fnum, wire, start, pos
            continue
        pos = skip(buf, pos, end, wire, fnum, 0)
        yield fnum, wire, start, pos


def utf8(buf: bytes, start: int, stop: int, what: str) -> str:
    """Decode ``buf[start:stop]`` as UTF-8 (``what`` names the field in the error)."""
    try:
        return bytes(buf[start:stop]).decode("utf-8")
    except UnicodeDecodeError as exc:
        raise CodecError(f"{what} must be valid UTF-8; got {bytes(buf[start:stop])!r:.80}") from exc


def packed(buf: bytes, start: int, stop: int, dtype: str, what: str) -> NDArray[Any]:
    """A packed little-endian 8-byte array (``"<f8"`` or ``"<i8"``) as an aligned native copy."""
    if (stop - start) % 8:
        raise CodecError(
            f"{what} packed field length must be a multiple of 8 bytes; got {stop - start}"
        )
    arr = np.frombuffer(buf, dtype=dtype, count=(stop - start) // 8, offset=start)
    return arr.astype(dtype[1:], copy=True)  # aligned, native, owns its memory


def signed(v: int) -> int:
    """Reinterpret an unsigned 64-bit value as two's-complement signed (int64 fields)."""
    return v - (1 << 64) if v >= (1 << 63) else v
