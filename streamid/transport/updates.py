"""Model updates as a client receives them: the wire document with the engine's model rebuilt.

:mod:`streamid.wire.documents` checks the ``streamid.model-update/1`` envelope without
depending on the engine; this module turns its ``model`` into a
:class:`~streamid.engine.Model`.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

from streamid.engine.model import Model
from streamid.wire.documents import parse_model_update_fields

__all__ = ["ModelUpdate", "parse_model_update"]


@dataclass(frozen=True, eq=False)
class ModelUpdate:
    """A parsed model update.

    Attributes
    ----------
    stream, version
        Which stream, which model version.
    model
        The engine's :class:`~streamid.engine.Model` rebuilt from the JSON.
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


def parse_model_update(payload: bytes | str) -> ModelUpdate:
    """Parse a ``streamid.model-update/1`` payload (the model is rebuilt and checked).

    Raises
    ------
    ModelFormatError
        If the payload is not such a document or its model is invalid.
    """
    fields = parse_model_update_fields(payload)
    return ModelUpdate(
        stream=fields["stream"],
        version=fields["version"],
        model=Model.from_dict(fields["model"]),
        window=fields["window"],
        metrics=fields["metrics"],
        warm=fields["warm"],
        generations=fields["generations"],
        identification_s=fields["identification_s"],
        published_unix_ns=fields["published_unix_ns"],
        window_closed_unix_ns=fields["window_closed_unix_ns"],
        document=fields["document"],
    )
