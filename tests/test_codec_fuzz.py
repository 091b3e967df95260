"""Property-based tests of the codec: arbitrary bytes never raise anything but CodecError."""

from __future__ import annotations

import numpy as np
from hypothesis import assume, given, settings
from hypothesis import strategies as st
from hypothesis.extra import numpy as hnp

from streamid.wire import codec
from streamid.errors import ModelFormatError
from streamid.wire.codec import CodecError, SampleBatch, decode, encode
from streamid.wire.names import check_signal_names, name_problem

FUZZ = settings(max_examples=400, deadline=None)

names = st.text(
    alphabet=st.characters(min_codepoint=32, blacklist_categories=("Cs", "Cc", "Cf", "Zl", "Zp", "Co")),
    min_size=1, max_size=12,
).filter(lambda s: name_problem(s) is None)  # the one rule for names (noncharacters such as U+FFFE refused too)
streams = st.from_regex(r"[A-Za-z0-9_.\-]{1,20}", fullmatch=True).filter(lambda s: s not in (".", ".."))


@st.composite
def batches(draw: st.DrawFn) -> SampleBatch:
    n = draw(st.integers(1, 40))
    floats = hnp.arrays(np.float64, n, elements=st.floats(allow_nan=True, allow_infinity=True))
    ins = draw(st.dictionaries(names, floats, max_size=3))
    outs = draw(st.dictionaries(names, floats, min_size=0 if ins else 1, max_size=3))
    try:  # names distinct across roles, none an added name (initial_<output>, ...): else refused, as tested below
        check_signal_names(list(ins), list(outs))
    except ModelFormatError:
        assume(False)
    seq = draw(st.integers(0, 2**64 - 1))
    if draw(st.booleans()):
        steps = draw(hnp.arrays(np.int64, n - 1, elements=st.integers(1, 10**9)))
        t0 = draw(st.integers(-(2**60), 2**60))
        t = t0 + np.concatenate([[0], np.cumsum(steps)]).astype(np.int64)
        return SampleBatch(draw(streams), seq, t0, draw(st.integers(0, 10**9)), t, ins, outs)
    period = draw(st.integers(1, 10**9))
    t0 = draw(st.integers(-(2**62), 2**62 - period * n))
    return SampleBatch(draw(streams), seq, t0, period, None, ins, outs)


@FUZZ
@given(st.binary(max_size=300))
def test_arbitrary_bytes_raise_only_codec_error(data: bytes) -> None:
    try:
        b = decode(data)
    except CodecError:
        return
    assert isinstance(b, SampleBatch) and len(b) >= 1  # the rare valid batch is a real one


@FUZZ
@given(batches())
def test_round_trip(batch: SampleBatch) -> None:
    data = encode(batch)
    assert decode(data) == batch
    assert encode(decode(data)) == data


@FUZZ
@given(batches(), st.data())
def test_damaged_valid_payloads_raise_only_codec_error(batch: SampleBatch, data: st.DataObject) -> None:
    raw = bytearray(encode(batch))
    action = data.draw(st.sampled_from(["truncate", "flip", "insert", "delete"]))
    if action == "truncate":
        raw = raw[: data.draw(st.integers(0, len(raw) - 1))]
    elif action == "flip":
        for _ in range(data.draw(st.integers(1, 4))):
            i = data.draw(st.integers(0, len(raw) - 1))
            raw[i] ^= 1 << data.draw(st.integers(0, 7))
    elif action == "insert":
        i = data.draw(st.integers(0, len(raw)))
        raw[i:i] = data.draw(st.binary(min_size=1, max_size=8))
    else:
        i = data.draw(st.integers(0, len(raw) - 1))
        del raw[i : i + data.draw(st.integers(1, 8))]
    try:
        decode(bytes(raw))
    except CodecError:
        pass
    assert codec.peek_header(bytes(raw)) is None or isinstance(codec.peek_header(bytes(raw)), tuple)
