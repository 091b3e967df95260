"""Model updates: the wire layer checks the envelope, the client rebuilds the engine's model."""

from __future__ import annotations

import json

import numpy as np
import pytest

from streamid.model import Model
from streamid.model.regressors import Normalisation, Regressor
from streamid.errors import ModelFormatError
from streamid.transport.updates import ModelUpdate, parse_model_update
from streamid.wire.documents import encode_json, model_update_message, parse_model_update_fields


def _payload(**change: object) -> bytes:
    model = Model(
        regressors=(Regressor("y", 0, 1), Regressor("u", 0, 2)),
        centres=np.zeros((2, 2)),
        widths=np.ones(2),
        weights=np.array([0.5, -0.25]),
        normalisation=Normalisation((0.0,), (1.0,), 0.0, 1.0),
    )
    doc = model_update_message(
        stream="bench1",
        version=3,
        model=model.to_dict(),
        window={"n_samples": 100},
        metrics={"r2_osa_val": 0.9},
        warm=True,
        generations=30,
        identification_s=0.2,
        window_closed_unix_ns=5,
        published_unix_ns=7,
    )
    doc.update(change)
    return encode_json(doc)


def test_a_model_update_round_trips_with_the_model_rebuilt() -> None:
    up = parse_model_update(_payload())
    assert isinstance(up, ModelUpdate) and isinstance(up.model, Model)
    assert (up.stream, up.version, up.warm, up.generations) == ("bench1", 3, True, 30)
    assert up.model.lags == Model.from_dict(up.document["model"]).lags
    assert up.metrics == {"r2_osa_val": 0.9} and up.window == {"n_samples": 100}
    assert (up.published_unix_ns, up.window_closed_unix_ns) == (7, 5)


def test_the_wire_layer_leaves_the_model_as_json() -> None:
    fields = parse_model_update_fields(_payload())
    assert fields["model"]["format"] == "streamid.model/1" and fields["version"] == 3


@pytest.mark.parametrize(
    ("change", "match"),
    [
        ({"version": 0}, "version"),
        ({"version": True}, "version"),
        ({"model": [1, 2]}, "JSON object"),
        ({"generations": "many"}, "malformed"),
        ({"format": "other/1"}, "format"),
    ],
)
def test_a_bad_envelope_is_a_model_format_error(change: dict[str, object], match: str) -> None:
    with pytest.raises(ModelFormatError, match=match):
        parse_model_update(_payload(**change))


def test_a_bad_model_is_a_model_format_error() -> None:
    doc = json.loads(_payload())
    del doc["model"]["weights"]
    with pytest.raises(ModelFormatError, match="weights"):
        parse_model_update(json.dumps(doc))
    parse_model_update_fields(json.dumps(doc))  # the envelope alone is fine
