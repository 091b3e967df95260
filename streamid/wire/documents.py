"""The daemon's messages on Zenoh: model updates and stream status (JSON, never NaN).

``streamid/<stream>/model`` carries a *model update*::

    {"format": "streamid.model-update/1", "stream": "bench1", "version": 7,
     "model": { ... the engine's streamid.model/1 document ... },
     "window": {"t0_ns": ..., "t_end_ns": ..., "period_ns": ..., "n_samples": ...,
                "n_estimation": ..., "n_validation": ..., "number": ...},
     "metrics": {"r2_osa_val": ..., "r2_fr_val": ..., "r2_osa_est": ..., "r2_fr_est": ..., ...},
     "warm": true, "generations": 30, "identification_s": 0.21,
     "window_closed_unix_ns": ..., "published_unix_ns": ...}

``version`` increases by one with every published model of the stream, across
daemon restarts that keep their ``--state-dir``.  The same document answers
queries on the model key.  ``streamid/<stream>/status`` carries a
``streamid.status/1`` document of counters (see :func:`status_message`).
"""

from __future__ import annotations

import json
import math
from typing import Any, TypedDict

from streamid.errors import ModelFormatError

__all__ = [
    "MODEL_UPDATE_FORMAT",
    "STATUS_FORMAT",
    "ModelUpdateFields",
    "encode_json",
    "model_update_message",
    "parse_model_update_fields",
    "parse_status",
]

MODEL_UPDATE_FORMAT = "streamid.model-update/1"
STATUS_FORMAT = "streamid.status/1"


def encode_json(doc: dict[str, Any]) -> bytes:
    """Compact UTF-8 JSON; raises ``ValueError`` on NaN or infinity (never published)."""
    return json.dumps(doc, allow_nan=False, separators=(",", ":")).encode("utf-8")


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
) -> dict[str, Any]:
    """The model update document (see the module docstring)."""
    return {
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


def _doc(payload: bytes | str, fmt: str, what: str) -> dict[str, Any]:
    try:
        doc = json.loads(payload)
    except (json.JSONDecodeError, UnicodeDecodeError, TypeError, RecursionError) as exc:
        raise ModelFormatError(f"a {what} must be UTF-8 JSON; parsing failed: {exc}") from None
    if not isinstance(doc, dict) or doc.get("format") != fmt:
        got = doc.get("format") if isinstance(doc, dict) else type(doc).__name__
        raise ModelFormatError(f"a {what} must be a JSON object with format {fmt!r}; got {got!r}")
    return doc


class ModelUpdateFields(TypedDict):
    """The fields of a checked model update; ``model`` is still the engine's JSON document."""

    stream: str
    version: int
    model: dict[str, Any]
    window: dict[str, Any]
    metrics: dict[str, Any]
    warm: bool
    generations: int
    identification_s: float
    published_unix_ns: int
    window_closed_unix_ns: int
    document: dict[str, Any]


def parse_model_update_fields(payload: bytes | str) -> ModelUpdateFields:
    """Parse and check a ``streamid.model-update/1`` payload, all but its model.

    ``model`` is only checked to be a JSON object: rebuilding the engine's model from
    it is the reader's job (:func:`streamid.transport.updates.parse_model_update`), so
    the wire format does not depend on the engine.

    Raises
    ------
    ModelFormatError
        If the payload is not such a document.
    """
    doc = _doc(payload, MODEL_UPDATE_FORMAT, "model update")
    try:
        version = doc["version"]
        if isinstance(version, bool) or not isinstance(version, int) or version < 1:
            raise ModelFormatError(f"model update 'version' must be an integer >= 1; got {version!r}")
        model = doc["model"]
        if not isinstance(model, dict):
            raise ModelFormatError(f"model update 'model' must be a JSON object; got {type(model).__name__}")
        metrics = doc.get("metrics", {})
        for k, v in metrics.items():
            if isinstance(v, float) and not math.isfinite(v):
                raise ModelFormatError(f"model update metric {k!r} must be finite; got {v!r}")
        return ModelUpdateFields(
            stream=str(doc["stream"]),
            version=version,
            model=model,
            window=dict(doc.get("window", {})),
            metrics=dict(metrics),
            warm=bool(doc.get("warm", False)),
            generations=int(doc.get("generations", 0)),
            identification_s=float(doc.get("identification_s", 0.0)),
            published_unix_ns=int(doc.get("published_unix_ns", 0)),
            window_closed_unix_ns=int(doc.get("window_closed_unix_ns", 0)),
            document=doc,
        )
    except ModelFormatError:
        raise
    except (KeyError, TypeError, ValueError, AttributeError) as exc:
        raise ModelFormatError(f"model update is missing or has a malformed field ({type(exc).__name__}: {exc})") from None


def parse_status(payload: bytes | str) -> dict[str, Any]:
    """Parse a ``streamid.status/1`` payload into a dict.

    Raises
    ------
    ModelFormatError
        If the payload is not such a document.
    """
    return _doc(payload, STATUS_FORMAT, "status message")
