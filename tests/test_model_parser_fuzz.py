"""The model-update and status parsers raise ModelFormatError and nothing else; names are shown escaped.

Property-based (hypothesis): random JSON values, real documents with one field replaced
by a random value, huge numbers, deep nesting, damaged bytes.  Plus the exact messages of
the attacks of issue 11 (``"published_unix_ns": 1e400`` made ``int()`` raise OverflowError
in every client), the ordering rule and the display helpers.
"""

from __future__ import annotations

import copy
import dataclasses
import json
import re
from dataclasses import replace
from typing import Any

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from streamid.commands.watch import decision_text, format_update
from streamid.model import EnsembleModel, Model
from streamid.model.regressors import Normalisation, Regressor
from streamid.errors import CodecError, ModelFormatError
from streamid.transport.updates import ModelUpdate, is_newer, parse_model_update, recency
from streamid.wire.codec import SampleBatch, decode
from streamid.wire.documents import (
    MAX_DOCUMENT_BYTES, Champion, Decision, Origin, encode_json, model_update_message, parse_status,
)
from streamid.wire.names import printable, unsafe_char
from streamid.wire.protobuf import len_field, varint

FUZZ = settings(max_examples=300, deadline=None)


def _model(output: str = "force_N", inputs: tuple[str, ...] = ("v",)) -> Model:
    return Model(
        regressors=(Regressor("y", 0, 1), Regressor("u", 0, 2)),
        centres=np.zeros((2, 2)), widths=np.ones(2), weights=np.array([0.5, -0.25]),
        normalisation=Normalisation((0.0,), (1.0,), 0.0, 1.0), input_names=inputs, output_name=output,
    )


def _doc(version: int = 3, *, accepted: bool = True, output: str = "force_N", **extra: Any) -> dict[str, Any]:
    doc = model_update_message(
        stream="bench1", version=version, model=_model(output).to_dict(), output=output, accepted=accepted,
        window={"t0_ns": 1, "t_end_ns": 2, "period_ns": 1, "n_samples": 100, "number": 4},
        metrics={"r2_osa_val": 0.99, "r2_fr_val": 0.95}, warm=True, generations=30, identification_s=0.2,
        window_closed_unix_ns=5, published_unix_ns=7,
        decision={"accepted": accepted, "code": "better" if accepted else "not_better", "reason": "FR R² ...",
                  "margin": 0.01, "champion": {"version": 2, "r2_fr_val": 0.937, "r2_osa_val": None}},
        origin={"daemon": "5f0c1a2b3c4d5e6f", "epoch_ns": 1_700_000_000_000_000_000},
    )
    doc.update(extra)
    return doc


REAL = _doc()
json_values = st.recursive(
    st.none() | st.booleans() | st.integers(-(2**70), 2**70) | st.floats(allow_nan=False, allow_infinity=False)
    | st.text(max_size=20),
    lambda kids: st.lists(kids, max_size=4) | st.dictionaries(st.text(max_size=8), kids, max_size=4),
    max_leaves=12,
)


def _paths(doc: Any, prefix: tuple[Any, ...] = ()) -> list[tuple[Any, ...]]:
    out = [prefix] if prefix else []
    if isinstance(doc, dict):
        for k, v in doc.items():
            out += _paths(v, (*prefix, k))
    elif isinstance(doc, list):
        for i, v in enumerate(doc):
            out += _paths(v, (*prefix, i))
    return out


PATHS = _paths(REAL)
#: A model with a long linear part (streamid.model/4): its own fields fuzzed too.
REAL4 = _doc(model=dataclasses.replace(
    _model(), linear=np.array([0.1, -0.2, 0.3, 0.05, 0.0]),
    linear_regressors=(Regressor("y", 0, 1), Regressor("y", 0, 2), Regressor("u", 0, 0), Regressor("u", 0, 1)),
).to_dict())
#: A mean of networks with long linear parts (streamid.model/5): its members' fields fuzzed too.
REAL5 = _doc(model=EnsembleModel.of([Model.from_dict(REAL4["model"]), dataclasses.replace(
    _model(), weights=np.array([0.3, -0.1]), linear=np.array([0.2, 0.1, 0.0]),
    linear_regressors=(Regressor("y", 0, 3), Regressor("u", 0, 2)))]).to_dict())
DOC_PATHS = ([(REAL, p) for p in PATHS] + [(REAL4, p) for p in _paths(REAL4) if p[:1] == ("model",)]
             + [(REAL5, p) for p in _paths(REAL5) if p[:2] == ("model", "members")])


def _only_model_format_error(payload: bytes | str) -> ModelUpdate | None:
    try:
        return parse_model_update(payload)
    except ModelFormatError as exc:
        assert str(exc)  # a message, always
        return None


@FUZZ
@given(json_values)
def test_random_json_values_raise_only_model_format_error(value: Any) -> None:
    _only_model_format_error(json.dumps(value))
    with_format = value if isinstance(value, dict) else {"v": value}
    _only_model_format_error(json.dumps({**with_format, "format": "streamid.model-update/1"}))
    try:
        parse_status(json.dumps({**with_format, "format": "streamid.status/1"}))
    except ModelFormatError:
        pass


@FUZZ
@given(st.sampled_from(DOC_PATHS), json_values | st.sampled_from(["1e400", "-1e400", "NaN", "Infinity", "1" * 5000]),
       st.booleans())
def test_real_documents_with_one_field_replaced_or_removed(where: tuple[dict[str, Any], tuple[Any, ...]], value: Any,
                                                           delete: bool) -> None:
    real, path = where
    doc = copy.deepcopy(real)
    parent = doc
    for p in path[:-1]:
        parent = parent[p]
    raw_token = value if isinstance(value, str) and value in ("1e400", "-1e400", "NaN", "Infinity") or (
        isinstance(value, str) and value.isdigit()) else None
    if delete and isinstance(parent, dict):
        del parent[path[-1]]
        text = json.dumps(doc)
    elif raw_token is not None:  # a number token json.dumps cannot write: splice it into the text
        parent[path[-1]] = "@@TOKEN@@"
        text = json.dumps(doc).replace('"@@TOKEN@@"', raw_token)
    else:
        parent[path[-1]] = value
        text = json.dumps(doc)
    up = _only_model_format_error(text)
    if up is not None:  # what is accepted is consistent
        assert up.accepted is (up.decision.accepted if up.decision else True)
        assert up.version >= (1 if up.accepted else 0) and up.output


@FUZZ
@given(st.binary(max_size=300) | st.text(max_size=300))
def test_arbitrary_bytes_and_text_raise_only_model_format_error(data: bytes | str) -> None:
    _only_model_format_error(data)
    try:
        parse_status(data)
    except ModelFormatError:
        pass


@FUZZ
@given(st.data())
def test_damaged_real_payloads_raise_only_model_format_error(data: st.DataObject) -> None:
    raw = bytearray(encode_json(REAL))
    for _ in range(data.draw(st.integers(1, 4))):
        i = data.draw(st.integers(0, len(raw) - 1))
        action = data.draw(st.sampled_from(["flip", "insert", "delete"]))
        if action == "flip":
            raw[i] ^= 1 << data.draw(st.integers(0, 7))
        elif action == "insert":
            raw[i:i] = data.draw(st.sampled_from([b"9" * 30, b"e400", b"[" * 50, b'"', b"{", b"\xe2\x80\xae", b"-"]))
        else:
            del raw[i : i + data.draw(st.integers(1, 8))]
    _only_model_format_error(bytes(raw))


@pytest.mark.parametrize(
    ("field", "token", "match"),
    [
        ("published_unix_ns", "1e400", "1e400"),  # issue 11.4: int(inf) raised OverflowError in every client
        ("published_unix_ns", "-1e400", "finite"),
        ("identification_s", "NaN", "NaN"),
        ("identification_s", "Infinity", "Infinity"),
        ("version", "1" * 5000, "64 bits"),  # int() of 5000 digits raises ValueError in Python 3.11
        ("version", str(2**64), "64 bits"),
        ("version", str(2**63), "version"),
        ("window_closed_unix_ns", "-5", "window_closed_unix_ns"),
        ("generations", "2.5", "generations"),
        ("warm", '"yes"', "warm"),
        ("stream", '"a/b"', "stream"),
        ("stream", "7", "stream"),
        ("output", '"y\\u202e1v"', "U\\+202E"),
        ("output", '""', "output"),
        ("output", '"other"', "differs from its model's output"),
        ("metrics", '{"r2_fr_val": "high"}', "r2_fr_val"),
        ("metrics", "[]", "metrics"),
        ("window", '{"t0_ns": 1.5}', "t0_ns"),
        ("accepted", '"true"', "accepted"),
        ("decision", '{"accepted": false, "code": "x"}', "decision"),
        ("decision", '{"accepted": true, "code": "a b"}', "code"),
        ("decision", '{"accepted": true, "code": "x", "reason": 3}', "reason"),
        ("decision", '{"accepted": true, "code": "x", "champion": {"version": 0}}', "champion"),
        ("decision", '{"accepted": true, "code": "x", "margin": "big"}', "margin"),
        ("origin", '{"daemon": "d", "epoch_ns": -1}', "epoch_ns"),
        ("origin", '{"daemon": "", "epoch_ns": 1}', "daemon"),
        ("origin", "[1]", "origin"),
        ("model", '{"format": "streamid.model/1", "output": "force_N", "regressors": 3}', "model"),
        ("model", "null", "model"),
    ],
)
def test_each_bad_field_is_a_clear_model_format_error(field: str, token: str, match: str) -> None:
    doc = copy.deepcopy(REAL)
    doc[field] = "@@TOKEN@@"
    text = json.dumps(doc).replace('"@@TOKEN@@"', token)
    with pytest.raises(ModelFormatError, match=match) as info:
        parse_model_update(text)
    assert "\u202e" not in str(info.value)  # the offending value is shown escaped


def test_size_nesting_and_missing_fields() -> None:
    with pytest.raises(ModelFormatError, match=f"at most {MAX_DOCUMENT_BYTES} bytes"):
        parse_model_update(b" " * (MAX_DOCUMENT_BYTES + 1))
    with pytest.raises(ModelFormatError, match="UTF-8 JSON"):
        parse_model_update("[" * 200_000 + "]" * 200_000)
    for field in ("stream", "version", "model"):
        doc = copy.deepcopy(REAL)
        del doc[field]
        with pytest.raises(ModelFormatError, match=f"'{field}'"):
            parse_model_update(json.dumps(doc))
    with pytest.raises(ModelFormatError, match="degraded"):
        parse_status('{"format": "streamid.status/1", "degraded": "yes"}')
    with pytest.raises(ModelFormatError, match="finite"):
        parse_status('{"format": "streamid.status/1", "unix_ns": 1e400}')


def test_older_documents_are_accepted_models_of_their_models_output() -> None:
    old = model_update_message(
        stream="bench1", version=4, model=_model("um").to_dict(), window={}, metrics={}, warm=False,
        generations=1, identification_s=0.0, window_closed_unix_ns=0, published_unix_ns=0,
    )
    assert set(old) >= {"stream", "version"} and not {"output", "accepted", "decision", "origin"} & set(old)
    up = parse_model_update(encode_json(old))
    assert (up.output, up.accepted, up.decision, up.origin) == ("um", True, None, None)


def test_a_long_linear_model_arrives_whole() -> None:
    up = parse_model_update(encode_json(REAL4))
    assert up.model.linear_regressors == (Regressor("y", 0, 1), Regressor("y", 0, 2), Regressor("u", 0, 0),
                                          Regressor("u", 0, 1)) and up.model.max_lag == 2


def test_new_fields_round_trip_and_rejected_may_carry_version_0() -> None:
    up = parse_model_update(encode_json(REAL))
    assert (up.output, up.accepted) == ("force_N", True)
    assert up.decision == Decision(True, "better", "FR R² ...", 0.01, Champion(2, 0.937, None))
    assert up.origin == Origin("5f0c1a2b3c4d5e6f", 1_700_000_000_000_000_000)
    rej = parse_model_update(encode_json(_doc(0, accepted=False, decision=None)))
    assert not rej.accepted and rej.version == 0 and rej.decision is None
    with pytest.raises(ModelFormatError, match="version"):
        parse_model_update(encode_json(_doc(0)))  # an accepted model has a version >= 1


def _up(version: int, epoch: int | None = None, daemon: str = "d1") -> ModelUpdate:
    origin = None if epoch is None else {"daemon": daemon, "epoch_ns": epoch}
    return parse_model_update(encode_json(_doc(version, origin=origin)))


def test_ordering_by_version_or_a_later_daemon_life() -> None:
    assert is_newer(_up(1), None)
    assert is_newer(_up(5, 100), _up(4, 100)) and not is_newer(_up(4, 100), _up(4, 100))
    assert not is_newer(_up(3, 100), _up(4, 100))  # an older version of the same life
    assert is_newer(_up(1, 200), _up(7, 100))  # a restarted daemon (new epoch, version 1) is recognised
    assert is_newer(_up(1, 200, "d2"), _up(7, 100))  # another owner that started later
    assert not is_newer(_up(1, 50, "d2"), _up(7, 100))  # an origin that began earlier is not
    assert is_newer(_up(1, 1), _up(7))  # a daemon with an origin after one without
    assert not is_newer(_up(1), _up(7, 100))
    assert max([_up(9, 100), _up(1, 200), _up(3, 150)], key=recency).version == 1


def test_printable_escapes_unsafe_characters_and_keeps_every_script() -> None:
    assert printable("f\u202e") == "f\\u202e"
    assert printable("a\nb\x1b[31m") == "a\\x0ab\\x1b[31m"
    assert printable("x\u200by\u2028z\ue000") == "x\\u200by\\u2028z\\ue000"
    assert printable("C:\\u202e") == "C:\\\\u202e"  # a literal backslash never looks like an escape
    assert printable("force_N Weg_µm 温度 R²") == "force_N Weg_µm 温度 R²"
    assert printable("\U000e0041") == "\\U000e0041"  # tag character (Cf)
    assert printable("x" * 50, 10) == "xxxxxxx..."
    assert unsafe_char("ab\u202ec") == (2, "\u202e") and unsafe_char("温度") is None


@FUZZ
@given(st.text(max_size=40))
def test_printable_output_holds_no_unsafe_character(text: str) -> None:
    out = printable(text)
    assert unsafe_char(out) is None and "\n" not in out
    unescaped = re.sub(r"\\(\\|x[0-9a-f]{2}|u[0-9a-f]{4}|U[0-9a-f]{8})",
                       lambda m: "\\" if m[1] == "\\" else chr(int(m[1][1:], 16)), out)
    assert unescaped == text  # unambiguous: two different names never print alike


def _batch_with_channel(name: str) -> bytes:
    chan = len_field(0x0A, name.encode("utf-8")) + len_field(0x12, np.ones(3).tobytes())
    return (b"\x08\x01" + len_field(0x12, b"s") + b"\x28" + varint(5) + len_field(0x3A, chan)
            + len_field(0x42, len_field(0x0A, b"y") + len_field(0x12, np.ones(3).tobytes())))


@pytest.mark.parametrize("name", ["f\u202e", "f\u200b", "f\u2028", "f\ue000", "f\x85", "f\u2066x", "\u061c"])
def test_codec_refuses_channel_names_with_control_format_or_bidi_characters(name: str) -> None:
    with pytest.raises(CodecError) as info:
        decode(_batch_with_channel(name))
    msg = str(info.value)
    assert f"'{printable(name)}'" in msg and "Cc, Cf, Zl, Zp, Co, Cs" in msg and "input channel name" in msg
    assert unsafe_char(msg) is None  # the message itself is safe to print
    with pytest.raises(CodecError, match="U\\+"):
        SampleBatch("s", 0, 0, 5, None, {"v": np.ones(3)}, {name: np.ones(3)})
    assert decode(_batch_with_channel("Weg_µm 温度")).inputs.keys() == {"Weg_µm 温度"}


def test_watch_lines_say_why_and_escape_what_came_from_the_network() -> None:
    up = parse_model_update(encode_json(_doc(13, metrics={"r2_osa_val": 0.99, "r2_fr_val": 0.95})))
    line = format_update(up, now_ns=7 + 2 * 10**9)
    assert line.startswith("bench1 v13 warm G=30 force_N(t) = F[") and "age 2.0s" in line
    assert line.endswith("; accepted: better than v2 (FR R2 0.9370 on the same data) by 0.013")
    rej = parse_model_update(encode_json(_doc(12, accepted=False)))
    assert decision_text(rej) == "rejected: not better than v2 (FR R2 0.9370 on the same data): +0.013, margin 0.01"
    assert format_update(rej).startswith("bench1 challenger rejected (serving v12) ")
    doc = _doc(4, model=_model("force_N", inputs=("v\u202e",)).to_dict())
    with pytest.raises(ModelFormatError, match=r"'inputs'\[0\] 'v\\u202e' holds U\+202E at position 1"):
        parse_model_update(encode_json(doc))  # a name breaking the one rule for names (streamid.wire.names)
    doc = _doc(4, model=_model("force_N", inputs=("v",)).to_dict())
    doc["decision"] = {"accepted": True, "code": "odd", "reason": "line\nbreak \u202eevil", "margin": None}
    doc["origin"] = {"daemon": "d1", "epoch_ns": 5}
    line = format_update(parse_model_update(encode_json(doc)))
    assert "v(t-" in line and "accepted (odd): line\\x0abreak \\u202eevil" in line
    assert unsafe_char(line) is None and "\n" not in line
    # a model with a long linear part (online, where its network explains less than 95 %) says so
    from streamid.engine.choice.longlinear import dense_regressors
    net = _model("force_N")
    lregs = dense_regressors(24, net.n_inputs, direct=False)
    ll = replace(net, linear=np.zeros(len(lregs) + 1), linear_regressors=lregs)
    line = format_update(parse_model_update(encode_json(_doc(14, model=ll.to_dict()))))
    assert f"force_N(t) = F[{net.lags_text()}] + linear ARX part of order 24 R2 val" in line, line
    # a refined model says so, with the held-out half's figures that let it (and nothing odd from the network breaks it)
    held = {"samples": 2100, "r2_fr_before": 0.9352, "r2_fr_after": 0.9438}
    refined = replace(net, metrics={**net.metrics, "refinement": {"taken": True, "held_out": held}})
    line = format_update(parse_model_update(encode_json(_doc(15, model=refined.to_dict()))))
    assert line.startswith("bench1 v15 warm G=30 refined (held out FR 0.9352 -> 0.9438) force_N(t) = F["), line
    for odd in ({"taken": "yes"}, {"taken": True, "held_out": [1]}, "refined", {"taken": False}):
        m = replace(net, metrics={**net.metrics, "refinement": odd})
        line = format_update(parse_model_update(encode_json(_doc(16, model=m.to_dict()))))
        assert ("refined (held out FR n/a -> n/a)" in line) == (odd == {"taken": True, "held_out": [1]}), (odd, line)
