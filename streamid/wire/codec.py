"""Sample-batch wire format: protobuf ``streamid.SampleBatch``, hand-encoded with numpy.

The message (``streamid/data/sample_batch.proto``)::

    message Channel     { string name = 1; repeated double values = 2; }
    message SampleBatch {
      uint32 version = 1;  string stream = 2;  uint64 seq = 3;
      int64 t0_ns = 4;     int64 period_ns = 5;
      repeated sfixed64 t_ns = 6;            // optional per-sample timestamps
      repeated Channel inputs = 7;  repeated Channel outputs = 8;
    }

Packed ``repeated double`` is raw little-endian float64 and packed
``repeated sfixed64`` raw little-endian int64, so the arrays are written and
read with one numpy call each; the few scalars are varints.  :func:`encode`
writes exactly what the official protobuf runtime serializes for the same
message (fields in number order, proto3 defaults omitted), and :func:`decode`
accepts anything a protobuf parser accepts (unknown fields, unpacked repeated
fields, repeated occurrences) and then validates the batch.  The ``protobuf``
package is not needed at run time: :data:`FILE_DESCRIPTOR_SET` holds the
serialized ``FileDescriptorSet`` that MCAP files register as their schema.

:func:`decode` raises :class:`~streamid.errors.CodecError` and nothing else.
"""

from __future__ import annotations

import base64
from collections.abc import Mapping
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import ArrayLike, NDArray

from streamid.errors import CodecError
from streamid.wire.keys import STREAM_NAME_RULE, is_valid_stream_name, samples_key, u_key, y_key
from streamid.wire.names import MAX_NAME_BYTES, NAME_RULE, check_signal_names, name_problem, printable
from streamid.wire.protobuf import U64_MASK, fields, len_field, packed, signed, utf8, varint

__all__ = [
    "FORMAT_VERSION",
    "SCHEMA_NAME",
    "SCHEMA_ENCODING",
    "MESSAGE_ENCODING",
    "FILE_DESCRIPTOR_SET",
    "PROTO_SOURCE",
    "MAX_NAME_BYTES",
    "SampleBatch",
    "encode",
    "decode",
    "with_stream",
    "peek_header",
]

#: Wire-format version written in field 1; decode refuses others.
FORMAT_VERSION = 1
#: Fully-qualified protobuf message name (the MCAP schema name).
SCHEMA_NAME = "streamid.SampleBatch"
#: MCAP schema encoding and message encoding.
SCHEMA_ENCODING = "protobuf"
MESSAGE_ENCODING = "protobuf"

#: The schema source, as shipped in ``streamid/data/sample_batch.proto``.
PROTO_SOURCE = """\
syntax = "proto3";

package streamid;

// One named signal: values[i] is the channel's value at sample i.
message Channel {
  string name = 1;
  repeated double values = 2;  // packed: raw little-endian float64
}

// A batch of consecutive samples of one stream.
message SampleBatch {
  uint32 version = 1;          // wire format version (1)
  string stream = 2;           // stream name: [A-Za-z0-9_.-]{1,128}
  uint64 seq = 3;              // batch sequence number (gaps/reordering detection)
  int64 t0_ns = 4;             // time of sample 0, ns (== t_ns[0] when t_ns is given)
  int64 period_ns = 5;         // sample period, ns (> 0 unless t_ns is given; then 0 or nominal)
  repeated sfixed64 t_ns = 6;  // optional per-sample times, ns, strictly increasing
  repeated Channel inputs = 7; // input channels (u)
  repeated Channel outputs = 8;// output channels (y)
}
"""

#: Serialized ``google.protobuf.FileDescriptorSet`` of ``sample_batch.proto``
#: (checked against the protobuf runtime in the tests).
FILE_DESCRIPTOR_SET: bytes = base64.b64decode(
    "Cs4CChJzYW1wbGVfYmF0Y2gucHJvdG8SCHN0cmVhbWlkIjUKB0NoYW5uZWwSEgoEbmFtZRgBIAEoCVIEbmFt"
    "ZRIWCgZ2YWx1ZXMYAiADKAFSBnZhbHVlcyLuAQoLU2FtcGxlQmF0Y2gSGAoHdmVyc2lvbhgBIAEoDVIHdmVy"
    "c2lvbhIWCgZzdHJlYW0YAiABKAlSBnN0cmVhbRIQCgNzZXEYAyABKARSA3NlcRITCgV0MF9ucxgEIAEoA1IE"
    "dDBOcxIbCglwZXJpb2RfbnMYBSABKANSCHBlcmlvZE5zEhEKBHRfbnMYBiADKBBSA3ROcxIpCgZpbnB1dHMY"
    "ByADKAsyES5zdHJlYW1pZC5DaGFubmVsUgZpbnB1dHMSKwoHb3V0cHV0cxgIIAMoCzIRLnN0cmVhbWlkLkNo"
    "YW5uZWxSB291dHB1dHNiBnByb3RvMw=="
)

_I64_MIN = -(1 << 63)
_I64_MAX = (1 << 63) - 1


# ---------------------------------------------------------------------------
# the batch
# ---------------------------------------------------------------------------
def _check_name(name: object, role: str) -> str:
    problem = name_problem(name)
    if problem is not None:
        shown = f"'{printable(name, 300)}' " if isinstance(name, str) else ""
        raise CodecError(f"{role} channel name {shown}{problem}: channel names are {NAME_RULE}")
    assert isinstance(name, str)
    return name


def _as_values(values: ArrayLike, role: str, name: str) -> NDArray[np.float64]:
    try:
        arr = np.asarray(values, dtype=np.float64)
    except (TypeError, ValueError) as exc:
        raise CodecError(
            f"{role} channel {name!r} values must be numbers convertible to float64; got {exc}"
        ) from exc
    if arr.ndim != 1:
        raise CodecError(
            f"{role} channel {name!r} values must be a 1-D array; got shape {arr.shape}"
        )
    return arr


def _as_i64(value: object, what: str) -> int:
    if isinstance(value, (bool, np.bool_)) or not isinstance(value, (int, np.integer)):
        raise CodecError(f"{what} must be an integer; got {type(value).__name__} {value!r}")
    v = int(value)
    if not _I64_MIN <= v <= _I64_MAX:
        raise CodecError(f"{what} must fit in a signed 64-bit integer; got {v}")
    return v


@dataclass(frozen=True, eq=False)
class SampleBatch:
    """A batch of consecutive samples of one stream.

    Parameters
    ----------
    stream : str
        Stream name (``[A-Za-z0-9_.-]{1,128}``).
    seq : int
        Batch sequence number (unsigned 64-bit), +1 per batch on one key.
    t0_ns : int
        Time of the first sample in integer nanoseconds.
    period_ns : int
        Sample period in ns: > 0 for uniform sampling (``t_ns`` is None); with
        ``t_ns`` given, 0 (irregular) or a nominal period.
    t_ns : ndarray of int64 or None
        Per-sample times in ns, strictly increasing, ``t_ns[0] == t0_ns``.
    inputs, outputs : dict of str to ndarray of float64
        Named channels, each 1-D of the batch length.  A batch on ``.../u``
        carries only inputs, on ``.../y`` only outputs; at least one channel.

    Raises
    ------
    CodecError
        If any rule above is broken (the message names the rule and value).
    """

    stream: str
    seq: int
    t0_ns: int
    period_ns: int
    t_ns: NDArray[np.int64] | None = None
    inputs: Mapping[str, NDArray[np.float64]] = field(default_factory=dict)
    outputs: Mapping[str, NDArray[np.float64]] = field(default_factory=dict)

    def __post_init__(self) -> None:
        if not is_valid_stream_name(self.stream):
            raise CodecError(f"stream name must be {STREAM_NAME_RULE}; got {self.stream!r}")
        if isinstance(self.seq, (bool, np.bool_)) or not isinstance(self.seq, (int, np.integer)):
            raise CodecError(f"seq must be an integer; got {type(self.seq).__name__} {self.seq!r}")
        seq = int(self.seq)
        if not 0 <= seq <= U64_MASK:
            raise CodecError(f"seq must be an integer in [0, 2**64-1]; got {seq}")
        object.__setattr__(self, "seq", seq)
        object.__setattr__(self, "t0_ns", _as_i64(self.t0_ns, "t0_ns"))
        object.__setattr__(self, "period_ns", _as_i64(self.period_ns, "period_ns"))
        if not isinstance(self.inputs, Mapping) or not isinstance(self.outputs, Mapping):
            raise CodecError("inputs and outputs must be mappings of channel name to values")
        n: int | None = None
        chans: dict[str, dict[str, NDArray[np.float64]]] = {}
        for role, mapping in (("input", self.inputs), ("output", self.outputs)):
            out: dict[str, NDArray[np.float64]] = {}
            for name, values in mapping.items():
                _check_name(name, role)
                arr = _as_values(values, role, name)
                if n is None:
                    n = arr.shape[0]
                elif arr.shape[0] != n:
                    raise CodecError(
                        f"every channel must have the same number of samples; {role} channel "
                        f"{name!r} has {arr.shape[0]}, expected {n}"
                    )
                out[name] = arr
            chans[role] = out
        if n is None:
            raise CodecError("a batch must carry at least one input or output channel; got none")
        # the one rule for names: a stream's models (and its FMU) hold these channels' names
        check_signal_names(list(chans["input"]), list(chans["output"]), "sample batch channel", CodecError)
        if n == 0:
            raise CodecError("a batch must carry at least one sample; got 0 samples")
        object.__setattr__(self, "inputs", chans["input"])
        object.__setattr__(self, "outputs", chans["output"])
        if self.t_ns is None:
            if self.period_ns <= 0:
                raise CodecError(
                    f"period_ns must be > 0 when no per-sample t_ns is given; got {self.period_ns}"
                )
            last = self.t0_ns + self.period_ns * (n - 1)
            if last > _I64_MAX:
                raise CodecError(
                    f"sample times must fit in int64 ns; t0_ns + period_ns*(n-1) = {last}"
                )
        else:
            t = np.asarray(self.t_ns)
            if t.dtype.kind not in "iu" or t.ndim != 1:
                raise CodecError(
                    f"t_ns must be a 1-D integer array (int64 ns); got dtype {t.dtype} shape {t.shape}"
                )
            if t.dtype != np.int64:
                if t.size and (int(t.max()) > _I64_MAX or int(t.min()) < _I64_MIN):
                    raise CodecError("t_ns values must fit in a signed 64-bit integer")
                t = t.astype(np.int64)
            if t.shape[0] != n:
                raise CodecError(
                    f"t_ns must have one time per sample; got {t.shape[0]} times for {n} samples"
                )
            if n > 1 and not bool(np.all(t[1:] > t[:-1])):
                i = int(np.argmin(t[1:] > t[:-1]))
                raise CodecError(
                    f"t_ns must be strictly increasing; t_ns[{i + 1}] = {int(t[i + 1])} "
                    f"after t_ns[{i}] = {int(t[i])}"
                )
            if int(t[0]) != self.t0_ns:
                raise CodecError(
                    f"t0_ns must equal t_ns[0] when t_ns is given; got t0_ns = {self.t0_ns}, "
                    f"t_ns[0] = {int(t[0])}"
                )
            if self.period_ns < 0:
                raise CodecError(
                    f"period_ns must be >= 0 (0 = irregular) when t_ns is given; got {self.period_ns}"
                )
            object.__setattr__(self, "t_ns", t)

    def __len__(self) -> int:
        for arr in self.inputs.values():
            return int(arr.shape[0])
        for arr in self.outputs.values():
            return int(arr.shape[0])
        return 0  # pragma: no cover - construction forbids it

    def times_ns(self) -> NDArray[np.int64]:
        """Time of every sample in ns (``t_ns`` or ``t0_ns + i * period_ns``)."""
        if self.t_ns is not None:
            return self.t_ns
        return self.t0_ns + self.period_ns * np.arange(len(self), dtype=np.int64)

    @property
    def end_ns(self) -> int:
        """Time of the last sample in ns."""
        if self.t_ns is not None:
            return int(self.t_ns[-1])
        return self.t0_ns + self.period_ns * (len(self) - 1)

    @property
    def kind(self) -> str:
        """``"samples"`` (inputs and outputs), ``"u"`` (inputs only) or ``"y"`` (outputs only)."""
        if self.inputs and self.outputs:
            return "samples"
        return "u" if self.inputs else "y"

    def key(self) -> str:
        """The natural Zenoh key of this batch: ``streamid/<stream>/<kind>``."""
        return {"samples": samples_key, "u": u_key, "y": y_key}[self.kind](self.stream)

    def __eq__(self, other: object) -> bool:
        if not isinstance(other, SampleBatch):
            return NotImplemented
        if (self.stream, self.seq, self.t0_ns, self.period_ns) != (
            other.stream, other.seq, other.t0_ns, other.period_ns
        ):
            return False
        if (self.t_ns is None) != (other.t_ns is None):
            return False
        if self.t_ns is not None and other.t_ns is not None and not np.array_equal(self.t_ns, other.t_ns):
            return False
        for a, b in ((self.inputs, other.inputs), (self.outputs, other.outputs)):
            if list(a) != list(b):
                return False
            for k in a:  # bitwise equality, NaN payloads included
                if a[k].tobytes() != b[k].tobytes():
                    return False
        return True

    __hash__ = None  # type: ignore[assignment]


# ---------------------------------------------------------------------------
# encoding
# ---------------------------------------------------------------------------


def _channel(name: str, values: NDArray[np.float64]) -> bytes:
    body = len_field(0x0A, name.encode("utf-8"))
    body += len_field(0x12, values.astype("<f8", copy=False).tobytes())
    return body


def encode(batch: SampleBatch) -> bytes:
    """Serialize ``batch`` to protobuf ``streamid.SampleBatch`` bytes.

    The bytes equal the official runtime's ``SerializeToString()`` of the same
    message.
    """
    if not isinstance(batch, SampleBatch):
        raise CodecError(f"encode takes a SampleBatch; got {type(batch).__name__}")
    parts = [b"\x08" + varint(FORMAT_VERSION), len_field(0x12, batch.stream.encode("utf-8"))]
    if batch.seq:
        parts.append(b"\x18" + varint(batch.seq))
    if batch.t0_ns:
        parts.append(b"\x20" + varint(batch.t0_ns))
    if batch.period_ns:
        parts.append(b"\x28" + varint(batch.period_ns))
    if batch.t_ns is not None:
        parts.append(len_field(0x32, batch.t_ns.astype("<i8", copy=False).tobytes()))
    for tag, chans in ((0x3A, batch.inputs), (0x42, batch.outputs)):
        for name, values in chans.items():
            parts.append(len_field(tag, _channel(name, values)))
    return b"".join(parts)


def with_stream(data: bytes, stream: str) -> bytes:
    """Return ``data`` (an encoded batch) with its stream name replaced by ``stream``."""
    b = decode(data)
    return encode(SampleBatch(stream, b.seq, b.t0_ns, b.period_ns, b.t_ns, b.inputs, b.outputs))


# ---------------------------------------------------------------------------
# decoding
# ---------------------------------------------------------------------------


def _decode_channel(buf: bytes, start: int, end: int, role: str) -> tuple[str, NDArray[np.float64]]:
    name = ""
    pieces: list[NDArray[np.float64]] = []
    for fnum, wire, a, b in fields(buf, start, end):
        if fnum == 1 and wire == 2:
            name = utf8(buf, a, b, f"{role} channel name")
        elif fnum == 2 and wire == 2:
            pieces.append(packed(buf, a, b, "<f8", f"{role} channel values"))
        elif fnum == 2 and wire == 1:
            pieces.append(np.frombuffer(buf, dtype="<f8", count=1, offset=a).astype(np.float64))
    if not pieces:
        values = np.empty(0, dtype=np.float64)
    else:
        values = pieces[0] if len(pieces) == 1 else np.concatenate(pieces)
    return name, values


def decode(data: bytes) -> SampleBatch:
    """Parse and validate protobuf ``streamid.SampleBatch`` bytes.

    Raises
    ------
    CodecError
        For anything that is not a valid batch of a known format version; the
        message names the problem.  No other exception escapes.
    """
    if isinstance(data, memoryview):
        data = data.tobytes()
    elif isinstance(data, bytearray):
        data = bytes(data)
    if not isinstance(data, bytes):
        raise CodecError(f"a batch payload must be bytes; got {type(data).__name__}")
    try:
        return _decode(data)
    except CodecError as exc:
        hint = _not_a_batch_hint(data, str(exc))
        if hint:
            raise CodecError(f"{exc} ({hint})") from None
        raise
    except (ValueError, TypeError, IndexError, OverflowError, MemoryError, RecursionError) as exc:
        raise CodecError(f"malformed sample batch ({type(exc).__name__}: {exc})") from exc


def _not_a_batch_hint(data: bytes, message: str) -> str:
    """A hint when a payload fails early and does not even look like a batch (another schema on the key)."""
    if not data or data.startswith(b"\x08\x01") or "wire format version" in message:
        return ""
    if data.lstrip()[:1] in (b"{", b"["):
        return "the payload looks like JSON: samples keys carry protobuf streamid.SampleBatch messages"
    return "the payload does not start with field 1 (version) = 1: is this a streamid.SampleBatch payload?"


def _decode(buf: bytes) -> SampleBatch:
    end = len(buf)
    if end == 0:
        raise CodecError("empty payload: a sample batch has at least a version and a stream name")
    version = 0
    stream: str | None = None
    seq = t0 = period = 0
    times: list[NDArray[np.int64]] = []
    inputs: dict[str, NDArray[np.float64]] = {}
    outputs: dict[str, NDArray[np.float64]] = {}
    for fnum, wire, a, b in fields(buf, 0, end):
        if wire == 0:
            if fnum == 1:
                version = b & 0xFFFFFFFF
            elif fnum == 3:
                seq = b
            elif fnum == 4:
                t0 = signed(b)
            elif fnum == 5:
                period = signed(b)
        elif wire == 2:
            if fnum == 2:
                stream = utf8(buf, a, b, "stream name")
            elif fnum == 6:
                times.append(packed(buf, a, b, "<i8", "t_ns"))
            elif fnum in (7, 8):
                role = "input" if fnum == 7 else "output"
                name, values = _decode_channel(buf, a, b, role)
                target = inputs if fnum == 7 else outputs
                if name in target:
                    raise CodecError(f"{role} channel names must be unique; {name!r} appears twice")
                _check_name(name, role)
                target[name] = values
        elif wire == 1 and fnum == 6:  # unpacked repeated sfixed64
            times.append(np.frombuffer(buf, dtype="<i8", count=1, offset=a).astype(np.int64))
    if version != FORMAT_VERSION:
        raise CodecError(
            f"unknown wire format version {version}; this streamid reads version {FORMAT_VERSION} "
            f"(is this a streamid.SampleBatch payload?)"
        )
    if stream is None:
        raise CodecError("the batch has no stream name (field 2)")
    t_ns = None
    if times:
        t_ns = times[0] if len(times) == 1 else np.concatenate(times)
    return SampleBatch(stream, seq, t0, period, t_ns, inputs, outputs)


def peek_header(data: bytes) -> tuple[int, int] | None:
    """``(seq, t0_ns)`` of an encoded batch without decoding or validating its arrays.

    Returns ``None`` when ``data`` is not a readable version-1 batch.  Used by
    the recorder to stamp MCAP publish times cheaply.
    """
    if not isinstance(data, (bytes, bytearray)):
        return None
    buf = bytes(data)
    version = seq = t0 = 0
    try:
        for fnum, wire, _a, b in fields(buf, 0, len(buf)):
            if wire == 0:
                if fnum == 1:
                    version = b & 0xFFFFFFFF
                elif fnum == 3:
                    seq = b
                elif fnum == 4:
                    t0 = signed(b)
    except CodecError:
        return None
    return (seq, t0) if version == FORMAT_VERSION else None
