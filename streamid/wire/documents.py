"""The daemon's messages on Zenoh: model updates and stream status (JSON, never NaN).

``streamid/<stream>/model`` carries accepted *model updates*, ``streamid/<stream>/rejected``
the challengers that were not accepted::

    {"format": "streamid.model-update/1", "stream": "bench1", "version": 7, "output": "force_N",
     "accepted": true,
     "decision": {"accepted": true, "code": "better", "reason": "...", "margin": 0.01,
                  "champion": {"version": 6, "r2_fr_val": 0.93, "r2_osa_val": 0.99}},
     "origin": {"daemon": "...", "epoch_ns": ...},
     "model": { ... the engine's streamid.model/1 document ... },
     "window": {"t0_ns": ..., "t_end_ns": ..., "period_ns": ..., "n_samples": ...,
                "n_estimation": ..., "n_validation": ..., "number": ...},
     "metrics": {"r2_osa_val": ..., "r2_fr_val": ..., "r2_osa_est": ..., "r2_fr_est": ..., ...},
     "warm": true, "generations": 30, "identification_s": 0.21,
     "window_closed_unix_ns": ..., "published_unix_ns": ...}

``version`` is one counter per stream: every accepted model of any output takes the next
one, across daemon restarts that keep their ``--state-dir``; a rejected challenger carries
the version still served (0: none yet).  ``output``, ``accepted``, ``decision`` and
``origin`` were added later: a document without them is an accepted model of its model's
output.  The same document answers queries on the model key (one reply per output).
``streamid/<stream>/status`` carries a ``streamid.status/1`` document of counters.

:func:`parse_model_update_fields` and :func:`parse_status` check every field they read
and raise :class:`~streamid.errors.ModelFormatError` and nothing else (fuzzed), naming
the field, its accepted form and the value.  See docs/wire-format.md.
"""

from __future__ import annotations

import json
import math
import re
from dataclasses import dataclass
from typing import Any, TypedDict

from streamid.errors import ModelFormatError
from streamid.wire.keys import STREAM_NAME_RULE, is_valid_stream_name
from streamid.wire.names import MAX_NAME_BYTES, UNSAFE_RULE, printable, unsafe_char

__all__ = [
    "MAX_VERSION",
    "MODEL_UPDATE_FORMAT",
    "STATUS_FORMAT",
    "MAX_DOCUMENT_BYTES",
    "Champion",
    "Decision",
    "Origin",
    "ModelUpdateFields",
    "encode_json",
    "model_update_message",
    "parse_model_update_fields",
    "parse_status",
]

MODEL_UPDATE_FORMAT = "streamid.model-update/1"
STATUS_FORMAT = "streamid.status/1"
#: Longest model update or status payload a client parses (a larger one is refused unread).
MAX_DOCUMENT_BYTES = 8 * 1024 * 1024
#: Longest decision reason, in characters.
MAX_REASON_CHARS = 4096
#: Highest version a document may carry (2**53, the largest integer every JSON reader keeps exactly): the daemon
#: never numbers above it and reads no version above it, from a file, a handed-over state or the network.
MAX_VERSION = 2**53
_I64_MAX = (1 << 63) - 1
_CODE_RE = re.compile(r"[A-Za-z0-9_.\-]{1,64}")
_WINDOW_INTS = ("t0_ns", "t_end_ns", "period_ns", "n_samples", "n_estimation", "n_validation", "number")


def encode_json(doc: dict[str, Any]) -> bytes:
    """Compact UTF-8 JSON; raises ``ValueError`` on NaN or infinity (never published)."""
    return json.dumps(doc, allow_nan=False, separators=(",", ":")).encode("utf-8")


@dataclass(frozen=True)
class Champion:
    """The model served when a challenger was judged, and its figures on the challenger's held-out data."""

    version: int
    r2_fr_val: float | None = None
    r2_osa_val: float | None = None


@dataclass(frozen=True)
class Decision:
    """Why a model was accepted or rejected: ``code`` (``first``, ``better``, ``not_better``, ...), in words."""

    accepted: bool
    code: str
    reason: str
    margin: float | None = None
    champion: Champion | None = None


@dataclass(frozen=True)
class Origin:
    """Which daemon published a document and when (wall clock, ns) that daemon's life began."""

    daemon: str
    epoch_ns: int


def model_update_message(
    *,
    stream: str,
    version: int,
    model: dict[str, Any],
    window: dict[str, Any],
    metrics: dict[str, float],
    warm: bool,
    generations: int,
    identification_s: float,
    window_closed_unix_ns: int,
    published_unix_ns: int,
    output: str | None = None,
    accepted: bool | None = None,
    decision: dict[str, Any] | None = None,
    origin: dict[str, Any] | None = None,
) -> dict[str, Any]:
    """The model update document (see the module docstring); the optional fields only when given."""
    doc: dict[str, Any] = {
        "format": MODEL_UPDATE_FORMAT,
        "stream": stream,
        "version": int(version),
        "model": model,
        "window": window,
        "metrics": metrics,
        "warm": bool(warm),
        "generations": int(generations),
        "identification_s": float(identification_s),
        "window_closed_unix_ns": int(window_closed_unix_ns),
        "published_unix_ns": int(published_unix_ns),
    }
    extra = {"output": output, "accepted": None if accepted is None else bool(accepted),
             "decision": decision, "origin": origin}
    doc.update({k: v for k, v in extra.items() if v is not None})
    return doc


# ---------------------------------------------------------------------------
# parsing: every field checked, ModelFormatError and nothing else
# ---------------------------------------------------------------------------
def _shown(value: object) -> str:
    """A value for an error message: its repr, escaped and cut."""
    try:
        text = repr(value)
    except (ValueError, RecursionError):  # e.g. an int too long for repr
        text = f"<{type(value).__name__}>"
    return printable(text, 120)


def _refuse_constant(token: str) -> Any:
    raise ModelFormatError(f"JSON numbers must be finite; got {token} (NaN and infinities are not JSON)")


def _parse_float(token: str) -> float:
    v = float(token)
    if not math.isfinite(v):
        raise ModelFormatError(f"JSON numbers must be finite float64 values (|x| < 1.8e308); got {printable(token, 60)}")
    return v


def _parse_int(token: str) -> int:
    if len(token) > 21:
        raise ModelFormatError(f"JSON integers must fit in 64 bits; got one of {len(token)} digits ({token[:24]}...)")
    v = int(token)
    if not -(1 << 63) <= v < (1 << 64):
        raise ModelFormatError(f"JSON integers must fit in 64 bits; got {v}")
    return v


def _doc(payload: bytes | bytearray | memoryview | str, fmt: str, what: str) -> dict[str, Any]:
    if isinstance(payload, (bytearray, memoryview)):
        payload = bytes(payload)
    if not isinstance(payload, (bytes, str)):
        raise ModelFormatError(f"a {what} payload must be bytes or str (UTF-8 JSON); got {type(payload).__name__}")
    if len(payload) > MAX_DOCUMENT_BYTES:
        raise ModelFormatError(f"a {what} must be at most {MAX_DOCUMENT_BYTES} bytes; got {len(payload)} bytes")
    try:
        doc = json.loads(payload, parse_constant=_refuse_constant, parse_float=_parse_float, parse_int=_parse_int)
    except ModelFormatError as exc:
        raise ModelFormatError(f"a {what} must be UTF-8 JSON with finite numbers: {exc}") from None
    except (ValueError, TypeError, RecursionError, MemoryError) as exc:
        # ValueError covers JSONDecodeError and UnicodeDecodeError; RecursionError: nesting too deep
        raise ModelFormatError(f"a {what} must be UTF-8 JSON; parsing failed: {_shown(exc)}") from None
    if not isinstance(doc, dict) or doc.get("format") != fmt:
        got = doc.get("format") if isinstance(doc, dict) else type(doc).__name__
        raise ModelFormatError(f"a {what} must be a JSON object with format {fmt!r}; got {_shown(got)}")
    return doc


_MISSING: Any = object()


def _get(doc: dict[str, Any], key: str, what: str, default: Any) -> Any:
    v = doc.get(key, _MISSING)
    if v is _MISSING:
        if default is _MISSING:
            raise ModelFormatError(f"{what} must have the field {key!r}; it is missing")
        return default
    return v


def _int(doc: dict[str, Any], key: str, what: str, lo: int = 0, hi: int = _I64_MAX, default: Any = _MISSING) -> int:
    v = _get(doc, key, what, default)
    if isinstance(v, bool) or not isinstance(v, int) or not lo <= v <= hi:
        raise ModelFormatError(f"{what} {key!r} is malformed: it must be an integer in [{lo}, {hi}]; got {_shown(v)}")
    return v


def _num(doc: dict[str, Any], key: str, what: str, *, nullable: bool = False, lo: float | None = None,
         default: Any = _MISSING) -> float | None:
    v = _get(doc, key, what, default)
    if v is None and nullable:
        return None
    if isinstance(v, bool) or not isinstance(v, (int, float)) or (lo is not None and not v >= lo):
        form = "a finite number" + (f" >= {lo:g}" if lo is not None else "") + (" or null" if nullable else "")
        raise ModelFormatError(f"{what} {key!r} is malformed: it must be {form}; got {_shown(v)}")
    return float(v)


def _bool(doc: dict[str, Any], key: str, what: str, default: Any = _MISSING) -> bool:
    v = _get(doc, key, what, default)
    if not isinstance(v, bool):
        raise ModelFormatError(f"{what} {key!r} is malformed: it must be true or false; got {_shown(v)}")
    return v


def _obj(doc: dict[str, Any], key: str, what: str, default: Any = _MISSING) -> dict[str, Any]:
    v = _get(doc, key, what, default)
    if not isinstance(v, dict):
        raise ModelFormatError(f"{what} {key!r} is malformed: it must be a JSON object; got {type(v).__name__} {_shown(v)}")
    return v


def _name(v: object, what: str) -> str:
    """A name shown to people (output, daemon): 1-256 UTF-8 bytes, no control/format/bidi characters."""
    if not isinstance(v, str) or not 1 <= len(v.encode("utf-8", "surrogatepass")) <= MAX_NAME_BYTES:
        raise ModelFormatError(f"{what} must be a string of 1 to {MAX_NAME_BYTES} UTF-8 bytes; got {_shown(v)}")
    bad = unsafe_char(v)
    if bad is not None:
        raise ModelFormatError(
            f"{what} '{printable(v, 300)}' holds U+{ord(bad[1]):04X} at position {bad[0]}: {what} must have {UNSAFE_RULE}"
        )
    return v


def _decision(v: object, accepted: bool) -> Decision:
    what = "model update decision"
    if not isinstance(v, dict):
        raise ModelFormatError(f"model update 'decision' must be a JSON object or absent; got {_shown(v)}")
    acc = _bool(v, "accepted", what)
    if acc != accepted:
        raise ModelFormatError(f"model update 'decision' says accepted={acc} but the document says accepted={accepted}")
    code = _get(v, "code", what, _MISSING)
    if not isinstance(code, str) or _CODE_RE.fullmatch(code) is None:
        raise ModelFormatError(f"{what} 'code' must be 1 to 64 characters from A-Z a-z 0-9 _ - .; got {_shown(code)}")
    reason = _get(v, "reason", what, "")
    if not isinstance(reason, str) or len(reason) > MAX_REASON_CHARS:
        raise ModelFormatError(f"{what} 'reason' must be a string of at most {MAX_REASON_CHARS} characters; "
                               f"got {type(reason).__name__} of length {len(reason) if isinstance(reason, str) else '-'}")
    margin = _num(v, "margin", what, nullable=True, default=None)
    champ = v.get("champion")
    champion = None
    if champ is not None:
        cw = "model update decision champion"
        if not isinstance(champ, dict):
            raise ModelFormatError(f"{what} 'champion' must be a JSON object or null; got {_shown(champ)}")
        champion = Champion(version=_int(champ, "version", cw, lo=1, hi=MAX_VERSION),
                            r2_fr_val=_num(champ, "r2_fr_val", cw, nullable=True, default=None),
                            r2_osa_val=_num(champ, "r2_osa_val", cw, nullable=True, default=None))
    return Decision(accepted=acc, code=code, reason=reason, margin=margin, champion=champion)


def _origin(v: object) -> Origin | None:
    if v is None:
        return None
    if not isinstance(v, dict):
        raise ModelFormatError(f"model update 'origin' must be a JSON object or absent; got {_shown(v)}")
    return Origin(daemon=_name(v.get("daemon"), "model update origin 'daemon'"),
                  epoch_ns=_int(v, "epoch_ns", "model update origin"))


class ModelUpdateFields(TypedDict):
    """The fields of a checked model update; ``model`` is still the engine's JSON document."""

    stream: str
    version: int
    output: str
    accepted: bool
    decision: Decision | None
    origin: Origin | None
    model: dict[str, Any]
    window: dict[str, Any]
    metrics: dict[str, float | None]
    warm: bool
    generations: int
    identification_s: float
    published_unix_ns: int
    window_closed_unix_ns: int
    document: dict[str, Any]


def parse_model_update_fields(payload: bytes | str) -> ModelUpdateFields:
    """Parse and check a ``streamid.model-update/1`` payload, all but its model.

    ``model`` is only checked to be a JSON object (and to name the same output):
    rebuilding the engine's model from it is the reader's job
    (:func:`streamid.transport.updates.parse_model_update`), so the wire format does not
    depend on the engine.  Every number must be finite JSON and every integer fit in 64 bits.

    Raises
    ------
    ModelFormatError
        If the payload is not such a document (and nothing else): the message names the
        field, its accepted form and the value.
    """
    doc = _doc(payload, MODEL_UPDATE_FORMAT, "model update")
    what = "model update"
    stream = _get(doc, "stream", what, _MISSING)
    if not is_valid_stream_name(stream):
        raise ModelFormatError(f"model update 'stream' must be a stream name, {STREAM_NAME_RULE}; got {_shown(stream)}")
    accepted = _bool(doc, "accepted", what, default=True)
    version = _int(doc, "version", what, lo=1 if accepted else 0, hi=MAX_VERSION)
    model = _obj(doc, "model", what)
    model_output = model.get("output")
    output = _name(_get(doc, "output", what, model_output if model_output is not None else "y"),
                   "model update 'output'")
    if model_output is not None and model_output != output:
        raise ModelFormatError(f"model update 'output' {printable(repr(output), 80)} differs from its model's output "
                               f"{_shown(model_output)}: they must be the same signal")
    window = _obj(doc, "window", what, default={})
    for k in _WINDOW_INTS:
        if k in window:
            _int(window, k, "model update window", lo=-(1 << 63))
    metrics = _obj(doc, "metrics", what, default={})
    checked: dict[str, float | None] = {}
    for k in metrics:
        checked[k] = _num(metrics, k, "model update metric", nullable=True)
    raw_decision = doc.get("decision")
    return ModelUpdateFields(
        stream=stream,
        version=version,
        output=output,
        accepted=accepted,
        decision=None if raw_decision is None else _decision(raw_decision, accepted),
        origin=_origin(doc.get("origin")),
        model=model,
        window=dict(window),
        metrics=checked,
        warm=_bool(doc, "warm", what, default=False),
        generations=_int(doc, "generations", what, default=0),
        identification_s=float(_num(doc, "identification_s", what, lo=0.0, default=0.0) or 0.0),
        published_unix_ns=_int(doc, "published_unix_ns", what, default=0),
        window_closed_unix_ns=_int(doc, "window_closed_unix_ns", what, default=0),
        document=doc,
    )


def parse_status(payload: bytes | str) -> dict[str, Any]:
    """Parse a ``streamid.status/1`` payload into a dict.

    The fields a client shows are checked (``stream``, ``version``, ``degraded``,
    ``degraded_reason``); the counters are left as they are (finite JSON numbers).

    Raises
    ------
    ModelFormatError
        If the payload is not such a document (and nothing else).
    """
    doc = _doc(payload, STATUS_FORMAT, "status message")
    what = "status message"
    if "stream" in doc and not is_valid_stream_name(doc["stream"]):
        raise ModelFormatError(f"status message 'stream' must be a stream name, {STREAM_NAME_RULE}; "
                               f"got {_shown(doc['stream'])}")
    if "version" in doc:
        _int(doc, "version", what, hi=MAX_VERSION)
    if "degraded" in doc:
        _bool(doc, "degraded", what)
    reason = doc.get("degraded_reason", "")
    if not isinstance(reason, str) or len(reason) > MAX_REASON_CHARS:
        raise ModelFormatError(f"status message 'degraded_reason' must be a string of at most {MAX_REASON_CHARS} "
                               f"characters; got {type(reason).__name__}")
    return doc
