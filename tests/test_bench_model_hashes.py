"""benchmarks.model_hashes: the before/after check that a change leaves the engine's models as they were."""

from __future__ import annotations

import json

from benchmarks.model_hashes import CASES, model_hash
from benchmarks.suite import targets
from streamid.engine import identify
from streamid.engine.settings import PAPER


def test_the_hash_is_the_models_and_not_its_settings_or_metrics() -> None:
    t = targets(("reactor_sim",))[0]
    res = identify(t.u_est, t.y_est, PAPER.replace(generations=6, neurons=4), 0)
    doc = json.loads(res.model.to_json())
    r2 = res.model.metrics.get("r2_fr_est")
    h = model_hash(json.dumps(doc), r2)
    assert len(h) == 16 and int(h, 16) >= 0
    renamed = {**doc, "config": {"a field retired": 1}, "metrics": {**doc["metrics"], "seconds": -1.0}}
    assert model_hash(json.dumps(renamed), r2) == h  # the settings' names and the run's timings do not count
    moved = {**doc, "weights": [w + 1e-12 for w in doc["weights"]]}
    assert model_hash(json.dumps(moved), r2) != h  # a weight moved by 1e-12 does
    assert model_hash(json.dumps(doc), 0.5) != h  # and so does the estimation fit


def test_the_cases_name_suite_targets() -> None:
    names = {t.name for t in targets(("piezo_sim", "f16", "mr_damper", "reactor_sim"))}
    assert {name for name, _, _ in CASES} <= names
    assert {settings for _, settings, _ in CASES} == {"defaults", "paper"}
