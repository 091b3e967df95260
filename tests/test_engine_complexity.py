"""Complexity by an information criterion on the estimation free run (streamid.engine.complexity)."""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import pytest

from streamid.engine import DEFAULT, CoEAConfig, Model, identify
from streamid.engine.complexity import choose, criterion, parameter_count
from streamid.engine.regressors import Normalisation, Regressor
from streamid.errors import ConfigError


def _net(m: int, linear: bool = False) -> Model:
    regs = (Regressor("y", 0, 1), Regressor("u", 0, 2))
    rng = np.random.default_rng(m)
    return Model(regs, rng.uniform(-1, 1, (m, 2)), np.ones(m), rng.normal(size=m), Normalisation((0.0,), (1.0,), 0.0, 1.0),
                 linear=np.zeros(3) if linear else None)


def test_parameter_count_and_criterion_values() -> None:
    assert parameter_count(_net(30)) == 30 and parameter_count(_net(10, linear=True)) == 13
    assert criterion("aic", 0.99, 1000, 30) == pytest.approx(1000 * math.log(0.01) + 60)
    assert criterion("bic", 0.99, 1000, 30) == pytest.approx(1000 * math.log(0.01) + math.log(1000) * 30)
    assert criterion("score", 0.5, 1000, 30) == -0.5
    with pytest.raises(ValueError, match="'aic'"):
        criterion("aicc", 0.5, 10, 1)


def test_choose_trades_fit_for_size_and_never_takes_an_inadmissible_run() -> None:
    big, small = _net(30), _net(10)
    # the same free-run fit: the smaller network wins under AIC, the first under "score"
    k, ev = choose("aic", [big, small], [0.95, 0.95], 1000, [10, 10])
    assert k == 1 and ev["neurons"] == 10 and ev["params"] == 10
    assert choose("score", [big, small], [0.95, 0.95], 1000, [10, 10])[0] == 0
    # a clearly better fit pays for 20 more weights: 1000 log(0.05 / 0.06) = -182 < -40
    assert choose("aic", [big, small], [0.95, 0.94], 1000, [10, 10])[0] == 0
    # ...but a slightly better one does not: 1000 log(0.0500 / 0.0505) = -10 > -40
    assert choose("aic", [big, small], [0.95, 0.9495], 1000, [10, 10])[0] == 1
    # a run without an admissible candidate is never chosen while one has one
    k, ev = choose("aic", [small, big], [-2e9, 0.1], 1000, [10, 30])
    assert k == 1 and ev["candidates"][0]["criterion"] is None and ev["candidates"][0]["r2_fr_est"] is None
    assert [c["lag_space"] for c in ev["candidates"]] == [10, 30]
    # nothing admissible: the highest score (the smallest excursion)
    assert choose("aic", [small, big], [-3e9, -2e9], 1000, [10, 10])[0] == 1


def test_config_rule_is_checked() -> None:
    with pytest.raises(ConfigError, match="complexity must be one of"):
        CoEAConfig(complexity="fpe")
    assert DEFAULT.complexity == "aic" and CoEAConfig().complexity == "score"


def test_identify_reports_every_candidate_size_and_its_criterion() -> None:
    rng = np.random.default_rng(3)
    u = rng.uniform(-1, 1, 700)
    y = np.zeros(700)
    for t in range(2, 700):
        y[t] = 0.6 * y[t - 1] + np.tanh(u[t - 1]) - 0.2 * u[t - 2] * y[t - 2]
    cfg = DEFAULT.replace(generations=10, lag_search_generations=10, max_lag_cap=0, neuron_alternatives=(8,))
    res = identify(u, y, cfg, 0)
    ev = res.model.metrics["complexity"]
    assert ev["rule"] == "aic" and ev["chosen_run"] == res.chosen and len(ev["candidates"]) == len(res.runs)
    assert [c["neurons"] for c in ev["candidates"]][:2] == [30, 8]
    assert ev["neurons"] == res.model.neurons
    ok = [c for c in ev["candidates"] if c["criterion"] is not None]
    assert ok and ev["candidates"][res.chosen]["criterion"] == min(c["criterion"] for c in ok)
    for c in ok:  # the criterion is the rule applied to the run's own score and size
        assert c["criterion"] == pytest.approx(criterion("aic", c["r2_fr_est"], 700 - res.extra["run_models"][c["run"]].max_lag,
                                                         c["params"]))
    # the rule "score" keeps the highest estimation free-run R^2 (round 2's choice)
    plain = identify(u, y, replace(cfg, complexity="score"), 0)
    sc = [r.score for r in plain.runs]
    assert plain.chosen == int(np.argmax(sc))
