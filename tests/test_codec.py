"""Wire format: round trips, interop with the official protobuf runtime, golden bytes, validation."""

from __future__ import annotations

import struct
from pathlib import Path

import numpy as np
import pytest

from streamid.wire import codec

from streamid.wire import protobuf as protowire
from streamid.wire.codec import CodecError, SampleBatch, decode, encode

DATA = Path(__file__).parent / "data"

pb = pytest.importorskip("google.protobuf")
from google.protobuf import descriptor_pb2, descriptor_pool, message_factory  # noqa: E402


def _message_class():
    fds = descriptor_pb2.FileDescriptorSet.FromString(codec.FILE_DESCRIPTOR_SET)
    pool = descriptor_pool.DescriptorPool()
    for f in fds.file:
        pool.Add(f)
    return message_factory.GetMessageClass(pool.FindMessageTypeByName(codec.SCHEMA_NAME))


Msg = _message_class()


def _batch(n: int = 5, **kw) -> SampleBatch:
    rng = np.random.default_rng(n)
    args = dict(stream="dev1", seq=3, t0_ns=1_000, period_ns=50_000, t_ns=None,
                inputs={"u": rng.standard_normal(n)}, outputs={"y": rng.standard_normal(n)})
    args.update(kw)
    return SampleBatch(**args)


# -- round trips -------------------------------------------------------------
@pytest.mark.parametrize(
    "batch",
    [
        _batch(),
        _batch(1),
        _batch(1000, seq=2**64 - 1, t0_ns=-(2**62)),
        _batch(4, inputs={"a": [1, 2, 3, 4], "b": [5, 6, 7, 8]}, outputs={}),
        _batch(3, inputs={}, outputs={"y1": [np.nan, np.inf, -0.0], "y2": [1e308, 5e-324, -1]}),
        _batch(3, t_ns=np.array([10, 20, 35]), t0_ns=10, period_ns=0),
        _batch(3, t_ns=np.array([-5, 0, 7]), t0_ns=-5, period_ns=10),
        _batch(2, inputs={"température °C": [1.0, 2.0]}, outputs={"力": [3.0, 4.0]}),
    ],
)
def test_round_trip_and_runtime_agree(batch: SampleBatch) -> None:
    data = encode(batch)
    back = decode(data)
    assert back == batch
    assert back.times_ns().tolist() == batch.times_ns().tolist()
    # the official runtime parses our bytes to the same fields ...
    m = Msg.FromString(data)
    assert m.version == codec.FORMAT_VERSION and m.stream == batch.stream and m.seq == batch.seq
    assert m.t0_ns == batch.t0_ns and m.period_ns == batch.period_ns
    assert list(m.t_ns) == ([] if batch.t_ns is None else batch.t_ns.tolist())
    assert [c.name for c in m.inputs] == list(batch.inputs)
    for c in m.outputs:
        assert np.asarray(c.values).tobytes() == batch.outputs[c.name].tobytes()
    # ... and serializes exactly our bytes (deterministic, field-number order)
    assert m.SerializeToString(deterministic=True) == data


def test_runtime_encoded_message_decodes() -> None:
    m = Msg(version=1, stream="s", seq=9, t0_ns=100, period_ns=5)
    c = m.inputs.add(name="u")
    c.values.extend([1.0, 2.0, 3.0])
    c = m.outputs.add(name="y")
    c.values.extend([4.0, 5.0, 6.0])
    b = decode(m.SerializeToString())
    assert (b.stream, b.seq, b.t0_ns, b.period_ns) == ("s", 9, 100, 5)
    assert b.inputs["u"].tolist() == [1.0, 2.0, 3.0] and b.outputs["y"].tolist() == [4.0, 5.0, 6.0]
    assert b.times_ns().tolist() == [100, 105, 110]


def _tag(field: int, wire: int) -> bytes:
    return protowire.varint((field << 3) | wire)


def test_unknown_fields_unpacked_and_split_fields_are_tolerated() -> None:
    """What protobuf parsers accept: unknown fields of every wire type, unpacked repeated
    fields, a packed field split in two, fields out of order."""
    chan_u = (_tag(1, 2) + b"\x01u" + _tag(2, 1) + struct.pack("<d", 1.5)
              + _tag(2, 1) + struct.pack("<d", 2.5) + _tag(99, 0) + b"\x05")
    vals = struct.pack("<3d", 7.0, 8.0, 9.0)
    chan_y = _tag(2, 2) + b"\x08" + vals[:8] + _tag(1, 2) + b"\x01y" + _tag(2, 2) + b"\x10" + vals[8:]
    t_unpacked = b"".join(_tag(6, 1) + struct.pack("<q", t) for t in (5, 6))
    t_packed = _tag(6, 2) + b"\x08" + struct.pack("<q", 9)
    data = (
        _tag(50, 5) + b"abcd"                      # unknown fixed32
        + _tag(8, 2) + bytes([len(chan_y)]) + chan_y
        + _tag(1, 0) + b"\x01"
        + _tag(51, 1) + b"12345678"                # unknown fixed64
        + _tag(2, 2) + b"\x02ab"
        + _tag(52, 3) + _tag(1, 0) + b"\x01" + _tag(52, 4)   # unknown group
        + t_unpacked + t_packed
        + _tag(4, 0) + b"\x05"
        + _tag(7, 2) + bytes([len(chan_u)]) + chan_u
        + _tag(53, 2) + b"\x03xyz"                 # unknown length-delimited
    )
    # only 2 input values vs 3 outputs -> invalid; add a third input value
    chan_u2 = chan_u + _tag(2, 2) + b"\x08" + struct.pack("<d", 3.5)
    data = data.replace(_tag(7, 2) + bytes([len(chan_u)]) + chan_u,
                        _tag(7, 2) + bytes([len(chan_u2)]) + chan_u2)
    b = decode(data)
    assert b.stream == "ab" and b.t0_ns == 5 and b.t_ns.tolist() == [5, 6, 9]
    assert b.inputs["u"].tolist() == [1.5, 2.5, 3.5] and b.outputs["y"].tolist() == [7.0, 8.0, 9.0]
    m = Msg.FromString(data)  # the runtime agrees on the same bytes
    assert list(m.t_ns) == [5, 6, 9] and list(m.inputs[0].values) == [1.5, 2.5, 3.5]


# -- schema ------------------------------------------------------------------
def test_descriptor_constant_matches_schema_built_with_runtime() -> None:
    F = descriptor_pb2.FieldDescriptorProto
    fp = descriptor_pb2.FileDescriptorProto(name="sample_batch.proto", package="streamid", syntax="proto3")
    ch = fp.message_type.add(name="Channel")
    ch.field.add(name="name", number=1, label=F.LABEL_OPTIONAL, type=F.TYPE_STRING, json_name="name")
    ch.field.add(name="values", number=2, label=F.LABEL_REPEATED, type=F.TYPE_DOUBLE, json_name="values")
    sb = fp.message_type.add(name="SampleBatch")
    for name, num, lab, typ, jn in [
        ("version", 1, F.LABEL_OPTIONAL, F.TYPE_UINT32, "version"),
        ("stream", 2, F.LABEL_OPTIONAL, F.TYPE_STRING, "stream"),
        ("seq", 3, F.LABEL_OPTIONAL, F.TYPE_UINT64, "seq"),
        ("t0_ns", 4, F.LABEL_OPTIONAL, F.TYPE_INT64, "t0Ns"),
        ("period_ns", 5, F.LABEL_OPTIONAL, F.TYPE_INT64, "periodNs"),
        ("t_ns", 6, F.LABEL_REPEATED, F.TYPE_SFIXED64, "tNs"),
        ("inputs", 7, F.LABEL_REPEATED, F.TYPE_MESSAGE, "inputs"),
        ("outputs", 8, F.LABEL_REPEATED, F.TYPE_MESSAGE, "outputs"),
    ]:
        f = sb.field.add(name=name, number=num, label=lab, type=typ, json_name=jn)
        if typ == F.TYPE_MESSAGE:
            f.type_name = ".streamid.Channel"
    expected = descriptor_pb2.FileDescriptorSet(file=[fp])
    assert descriptor_pb2.FileDescriptorSet.FromString(codec.FILE_DESCRIPTOR_SET) == expected


def test_shipped_proto_file_is_the_schema_text() -> None:
    import re
    from importlib import resources

    text = (resources.files("streamid") / "data" / "sample_batch.proto").read_text(encoding="utf-8")
    assert text == codec.PROTO_SOURCE
    fds = descriptor_pb2.FileDescriptorSet.FromString(codec.FILE_DESCRIPTOR_SET)
    for msg in fds.file[0].message_type:  # every field of the descriptor is declared in the text
        for f in msg.field:
            assert re.search(rf"\b{f.name} = {f.number};", text), (msg.name, f.name)


# -- golden bytes ------------------------------------------------------------
def test_golden_files() -> None:
    b = decode((DATA / "golden_batch_v1.bin").read_bytes())
    assert (b.stream, b.seq, b.t0_ns, b.period_ns, b.t_ns) == ("golden", 7, 1_700_000_000_000_000_000, 50_000, None)
    assert b.inputs["voltage_V"].tolist() == [0.0, 1.5, -2.25]
    assert b.outputs["deflection_um"].tobytes() == np.array([0.125, -0.0, 1e-300]).tobytes()
    assert encode(b) == (DATA / "golden_batch_v1.bin").read_bytes()
    golden = (DATA / "golden_batch_v1.bin").read_bytes()
    assert Msg.FromString(golden).SerializeToString(deterministic=True) == golden
    b2 = decode((DATA / "golden_batch_v1_tns.bin").read_bytes())
    assert b2.t_ns.tolist() == [-3, 0, 1_000_000_007] and b2.t0_ns == -3 and b2.kind == "y"
    assert b2.outputs["y"].tolist() == [np.inf, -1.0, 2.0]
    assert encode(b2) == (DATA / "golden_batch_v1_tns.bin").read_bytes()


# -- validation --------------------------------------------------------------
def _raw(**fields) -> bytes:
    """A message built with the runtime, bypassing SampleBatch's checks."""
    m = Msg(version=fields.pop("version", 1), stream=fields.pop("stream", "s"))
    for name in ("seq", "t0_ns", "period_ns"):
        if name in fields:
            setattr(m, name, fields.pop(name))
    m.t_ns.extend(fields.pop("t_ns", []))
    for role in ("inputs", "outputs"):
        for name, values in fields.pop(role, {}).items():
            c = getattr(m, role).add(name=name)
            c.values.extend(values)
    assert not fields
    return m.SerializeToString()


@pytest.mark.parametrize(
    ("data", "message"),
    [
        (b"", "empty payload"),
        (_raw(version=2, period_ns=1, inputs={"u": [1.0]}), "unknown wire format version 2"),
        (_raw(version=0, period_ns=1, inputs={"u": [1.0]}), "unknown wire format version 0"),
        (_raw(period_ns=1), "at least one input or output channel"),
        (_raw(period_ns=1, inputs={"u": []}), "at least one sample"),
        (_raw(period_ns=1, inputs={"u": [1.0, 2.0]}, outputs={"y": [1.0]}), "same number of samples"),
        (_raw(period_ns=0, inputs={"u": [1.0]}), "period_ns must be > 0"),
        (_raw(period_ns=-5, inputs={"u": [1.0]}), "period_ns must be > 0"),
        (_raw(t0_ns=1, t_ns=[1, 1], inputs={"u": [1.0, 2.0]}), "strictly increasing"),
        (_raw(t0_ns=2, t_ns=[2, 1], inputs={"u": [1.0, 2.0]}), "strictly increasing"),
        (_raw(t0_ns=0, t_ns=[1, 2], inputs={"u": [1.0, 2.0]}), "t0_ns must equal t_ns[0]"),
        (_raw(t0_ns=1, t_ns=[1, 2, 3], inputs={"u": [1.0, 2.0]}), "one time per sample"),
        (_raw(stream="", period_ns=1, inputs={"u": [1.0]}), "stream name"),
        (_raw(stream="a/b", period_ns=1, inputs={"u": [1.0]}), "stream name"),
        (_raw(period_ns=1, inputs={"": [1.0]}), "channel name"),
        (_raw(period_ns=1, outputs={"a\nb": [1.0]}), "control characters"),
        (_raw(t0_ns=2**62, period_ns=2**62, inputs={"u": [1.0, 2.0, 3.0]}), "fit in int64"),
        (b"\x08\x01\x12\x02\xff\xfe", "valid UTF-8"),
        (b"\x08\x01\x12\x05ab", "truncated field 2"),
        (b"\x08", "truncated varint"),
        (b"\x08" + b"\xff" * 11, "longer than 10 bytes"),
        (b"\x0f", "invalid protobuf wire type 7"),
        (b"\x00\x01", "invalid field number 0"),
        (b"\x08\x01\x32\x03abc", "multiple of 8"),
        (b"\x08\x01\x0c", "end-group"),
    ],
)
def test_invalid_payloads_raise_codec_error_naming_the_problem(data: bytes, message: str) -> None:
    with pytest.raises(CodecError, match=message.replace("[", r"\[").replace("]", r"\]")):
        decode(data)


def test_duplicate_channel_names_are_refused() -> None:
    data = _raw(period_ns=1, inputs={"u": [1.0]})
    chan = _tag(1, 2) + b"\x01u" + _tag(2, 2) + b"\x08" + struct.pack("<d", 2.0)
    with pytest.raises(CodecError, match="unique"):
        decode(data + _tag(7, 2) + bytes([len(chan)]) + chan)


def test_decode_refuses_non_bytes() -> None:
    with pytest.raises(CodecError, match="must be bytes"):
        decode("text")  # type: ignore[arg-type]
    assert decode(bytearray(encode(_batch()))) == _batch()
    assert decode(memoryview(encode(_batch()))) == _batch()


@pytest.mark.parametrize(
    ("kwargs", "message"),
    [
        ({"stream": "x y"}, "stream name"),
        ({"seq": -1}, "seq must be"),
        ({"seq": 2**64}, "seq must be"),
        ({"seq": 1.0}, "seq must be an integer"),
        ({"t0_ns": 2**63}, "signed 64-bit"),
        ({"period_ns": 1.5}, "period_ns must be an integer"),
        ({"inputs": {"u": [[1.0]]}}, "1-D"),
        ({"inputs": {"u": ["a"]}}, "float64"),
        ({"t_ns": np.array([1.0, 2.0, 3.0, 4.0, 5.0])}, "integer array"),
    ],
)
def test_batch_construction_validates(kwargs: dict, message: str) -> None:
    with pytest.raises(CodecError, match=message):
        _batch(**kwargs)


def test_batch_helpers() -> None:
    b = _batch(4, t0_ns=100, period_ns=10)
    assert len(b) == 4 and b.end_ns == 130 and b.times_ns().tolist() == [100, 110, 120, 130]
    assert b.kind == "samples" and b.key() == "streamid/dev1/samples"
    assert _batch(inputs={}).key() == "streamid/dev1/y" and _batch(outputs={}).key() == "streamid/dev1/u"
    assert codec.peek_header(encode(b)) == (3, 100)
    assert codec.peek_header(b"\x00garbage") is None
    renamed = decode(codec.with_stream(encode(b), "other"))
    assert renamed.stream == "other" and renamed.inputs["u"].tolist() == b.inputs["u"].tolist()
    assert b != _batch(4, t0_ns=100, period_ns=11)
