"""Model updates as a client receives them: the wire document with the engine's model rebuilt.

:mod:`streamid.wire.documents` checks the ``streamid.model-update/1`` envelope without
depending on the engine; this module turns its ``model`` into a
:class:`~streamid.model.Model`, and says which of two updates of one (stream, output)
is the newer (:func:`is_newer`).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

from streamid.model.narx import Model
from streamid.errors import ModelFormatError
from streamid.wire.documents import Champion, Decision, Origin, parse_model_update_fields
from streamid.wire.names import printable

__all__ = ["Champion", "Decision", "ModelUpdate", "Origin", "is_newer", "parse_model_update", "recency"]


@dataclass(frozen=True, eq=False)
class ModelUpdate:
    """A parsed model update.

    Attributes
    ----------
    stream, version
        Which stream, which model version (one counter per stream, over all its outputs;
        for a rejected challenger, the version still served, 0 if none).
    output
        The output signal the model predicts (one update per output of a MIMO stream).
    accepted
        True for a model the daemon serves; False for a rejected challenger.
    decision
        Why it was accepted or rejected (:class:`~streamid.wire.documents.Decision`;
        None from daemons older than the field).
    origin
        Which daemon published it and when that daemon's life began
        (:class:`~streamid.wire.documents.Origin`; None from older daemons).
    model
        The engine's :class:`~streamid.model.Model` rebuilt from the JSON.
    window, metrics
        The window the model was fitted on and its validation figures.
    warm, generations, identification_s
        How it was identified.
    published_unix_ns, window_closed_unix_ns
        When (wall clock).
    document
        The whole JSON document.
    """

    stream: str
    version: int
    model: Model
    window: dict[str, Any]
    metrics: dict[str, Any]
    warm: bool
    generations: int
    identification_s: float
    published_unix_ns: int
    window_closed_unix_ns: int
    document: dict[str, Any]
    output: str = "y"
    accepted: bool = True
    decision: Decision | None = None
    origin: Origin | None = None


def parse_model_update(payload: bytes | str) -> ModelUpdate:
    """Parse a ``streamid.model-update/1`` payload (the model is rebuilt and checked).

    Raises
    ------
    ModelFormatError
        If the payload is not such a document or its model is invalid (and nothing else).
    """
    fields = parse_model_update_fields(payload)
    try:
        model = Model.from_dict(fields["model"])
    except ModelFormatError as exc:
        raise ModelFormatError(f"model update 'model' is not a valid model: {exc}") from None
    except (ValueError, TypeError, KeyError, IndexError, AttributeError, OverflowError, MemoryError,
            RecursionError) as exc:
        raise ModelFormatError(
            f"model update 'model' is not a valid streamid.model/1 document ({type(exc).__name__}: "
            f"{printable(exc, 200)})"
        ) from None
    return ModelUpdate(
        stream=fields["stream"],
        version=fields["version"],
        model=model,
        window=fields["window"],
        metrics=fields["metrics"],
        warm=fields["warm"],
        generations=fields["generations"],
        identification_s=fields["identification_s"],
        published_unix_ns=fields["published_unix_ns"],
        window_closed_unix_ns=fields["window_closed_unix_ns"],
        document=fields["document"],
        output=fields["output"],
        accepted=fields["accepted"],
        decision=fields["decision"],
        origin=fields["origin"],
    )


def _epoch_ns(up: ModelUpdate) -> int:
    return -1 if up.origin is None else up.origin.epoch_ns


def is_newer(up: ModelUpdate, prev: ModelUpdate | None) -> bool:
    """Whether ``up`` supersedes ``prev``, the last update seen of the same (stream, output).

    Newer means a higher version, or another origin (a restarted daemon, another owner)
    whose life began later: a daemon restarted without its state starts again at version 1
    and is recognised, not ignored forever.  A document without an origin counts as the
    earliest life.  This orders a daemon's honest documents; it is no defence against a
    publisher with write access to the model key (see docs/security.md).
    """
    if prev is None:
        return True
    if up.version > prev.version:
        return True
    return up.origin != prev.origin and _epoch_ns(up) > _epoch_ns(prev)


def recency(up: ModelUpdate) -> tuple[int, int]:
    """Sort key of simultaneous answers (e.g. query replies): the latest daemon life, then the highest version."""
    return (_epoch_ns(up), up.version)
