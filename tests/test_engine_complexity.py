"""Complexity by an information criterion on the estimation free run (streamid.engine.choice.complexity)."""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import pytest

from streamid.engine import DEFAULT, CoEAConfig, identify
from streamid.model import Model
from streamid.engine.settings import FALLBACK_BELOW
from streamid.engine.choice.complexity import choose, criterion, parameter_count
from streamid.model.regressors import Normalisation, Regressor
from streamid.errors import ConfigError


def _net(m: int, linear: bool = False) -> Model:
    regs = (Regressor("y", 0, 1), Regressor("u", 0, 2))
    rng = np.random.default_rng(m)
    return Model(regs, rng.uniform(-1, 1, (m, 2)), np.ones(m), rng.normal(size=m), Normalisation((0.0,), (1.0,), 0.0, 1.0),
                 linear=np.zeros(3) if linear else None)


def test_parameter_count_and_criterion_values() -> None:
    assert parameter_count(_net(30)) == 30 and parameter_count(_net(10, linear=True)) == 13
    assert criterion(0.99, 1000, 30) == pytest.approx(1000 * math.log(0.01) + 60)
    assert criterion(1.0, 1000, 30) == pytest.approx(1000 * math.log(1e-12) + 60)  # a perfect fit: bounded


def test_choose_trades_fit_for_size_and_never_takes_an_inadmissible_run() -> None:
    big, small = _net(30), _net(10)
    # the same free-run fit: the smaller network wins
    k, ev = choose([big, small], [0.95, 0.95], 1000, [10, 10])
    assert k == 1 and ev["neurons"] == 10 and ev["params"] == 10 and ev["rule"] == "aic"
    # a clearly better fit pays for 20 more weights: 1000 log(0.05 / 0.06) = -182 < -40
    assert choose([big, small], [0.95, 0.94], 1000, [10, 10])[0] == 0
    # ...but a slightly better one does not: 1000 log(0.0500 / 0.0505) = -10 > -40
    assert choose([big, small], [0.95, 0.9495], 1000, [10, 10])[0] == 1
    # a run without an admissible candidate is never chosen while one has one
    k, ev = choose([small, big], [-2e9, 0.1], 1000, [10, 30])
    assert k == 1 and ev["candidates"][0]["criterion"] is None and ev["candidates"][0]["r2_fr_est"] is None
    assert [c["lag_space"] for c in ev["candidates"]] == [10, 30]
    # nothing admissible: the highest score (the smallest excursion)
    assert choose([small, big], [-3e9, -2e9], 1000, [10, 10])[0] == 1


def test_the_retired_rule_field_is_refused() -> None:
    with pytest.raises(ConfigError, match=r"\['complexity'\] were retired in issue 37"):
        CoEAConfig.from_dict({**DEFAULT.to_dict(), "complexity": "bic"})
    with pytest.raises(TypeError):
        CoEAConfig(complexity="aic")  # type: ignore[call-arg]


def _narx_record() -> tuple[np.ndarray, np.ndarray]:
    """700 samples of a small nonlinear NARX system driven by uniform noise (seeded)."""
    rng = np.random.default_rng(3)
    u = rng.uniform(-1, 1, 700)
    y = np.zeros(700)
    for t in range(2, 700):
        y[t] = 0.6 * y[t - 1] + np.tanh(u[t - 1]) - 0.2 * u[t - 2] * y[t - 2]
    return u, y


def test_identify_reports_every_candidate_size_and_its_criterion(monkeypatch: pytest.MonkeyPatch) -> None:
    u, y = _narx_record()
    monkeypatch.setattr("streamid.engine.identification.FALLBACK_BELOW", 1.0)  # a fallback run is always made
    cfg = DEFAULT.replace(generations=10, max_lag_cap=0, fallback_neurons=(8,), more_restarts=0,
                          run_ensembles=False)  # the single network's choice (ensembles: test_engine_ensemble.py)
    res = identify(u, y, cfg, 0)
    ev = res.model.metrics["complexity"]
    assert ev["rule"] == "aic" and ev["chosen_run"] == res.chosen and len(ev["candidates"]) == len(res.runs)
    assert [c["neurons"] for c in ev["candidates"]] == [30] * cfg.restarts + [8]  # the fallback run: another size
    assert ev["neurons"] == res.model.neurons
    ok = [c for c in ev["candidates"] if c["criterion"] is not None]
    assert ok and ev["candidates"][res.chosen]["criterion"] == min(c["criterion"] for c in ok)
    for c in ok:  # the criterion is the rule applied to the run's own score and size
        assert c["criterion"] == pytest.approx(criterion(c["r2_fr_est"], 700 - res.extra["run_models"][c["run"]].max_lag,
                                                         c["params"]))


def test_candidates_of_different_sizes_on_the_same_lags_are_scored_together() -> None:
    from streamid.engine.choice.scores import free_run_scores
    from streamid.engine.choice.selection import free_run_r2

    big, small = _net(30), _net(10)
    big = replace(big, weights=big.weights * 0.01)
    small = replace(small, weights=small.weights * 0.01)
    rng = np.random.default_rng(0)
    u, y = rng.uniform(0, 1, (80, 1)), rng.uniform(0, 1, 80)
    fr = free_run_scores([big, small], u, y)  # raised "all input arrays must have the same shape" before
    one = [free_run_scores([m], u, y).scores[0] for m in (big, small)]
    assert fr.scores == pytest.approx(one)
    assert free_run_r2([big, small], u, y) == pytest.approx([free_run_r2([m], u, y)[0] for m in (big, small)])


def test_forward_selection_order_takes_the_explaining_columns_first() -> None:
    from streamid.engine.choice.complexity import ols_order

    rng = np.random.default_rng(1)
    phi = rng.normal(size=(200, 6))
    target = 2.0 * phi[:, 3] + 0.3 * phi[:, 0] + 0.01 * rng.normal(size=200)
    order = ols_order(phi, target)
    assert order[:2] == [3, 0] and sorted(order) == list(range(6))
    dup = np.column_stack([phi[:, :2], phi[:, :1]])  # a column identical to another explains nothing new
    assert ols_order(dup, phi[:, 0])[0] in (0, 2) and sorted(ols_order(dup, phi[:, 0])) == [0, 1, 2]


def test_pruned_networks() -> None:
    from streamid.engine.choice.complexity import pruned

    m = _net(12)
    m = replace(m, weights=m.weights * 0.05, metrics={"fitness": 1.0})
    rng = np.random.default_rng(2)
    u, y = rng.uniform(0, 1, (300, 1)), rng.uniform(0, 1, 300)
    small = pruned(m, u, y, (4, 8, 12, 20), 1e-10)
    assert [s.neurons for s in small] == [4, 8]  # sizes below M only
    for s in small:  # the neurons kept are some of the original ones; the fitness is the refitted network's
        assert all(any(np.array_equal(c, d) for d in m.centres) for c in s.centres)
        assert s.metrics["fitness"] != 1.0 and np.isfinite(s.metrics["fitness"])
    assert small[0].metrics["fitness"] >= small[1].metrics["fitness"]  # nested: more neurons fit no worse


def test_prune_lets_a_smaller_network_compete_and_says_so() -> None:
    u, y = _narx_record()
    cfg = DEFAULT.replace(generations=10, max_lag_cap=0, prune_runs=4, run_ensembles=False)  # the chosen run kept
    res = identify(u, y, cfg, 0)
    assert res.model.metrics["complexity"]["neurons"] == res.model.neurons
    ev = res.model.metrics["neuron_choice"]  # the chosen run's network against its pruned versions
    assert [c["neurons"] for c in ev["candidates"]] == [30, 10, 20] and ev["neurons"] == res.model.neurons
    assert ev["candidates"][0]["r2_fr_est"] == res.runs[res.chosen].score  # the run's own network, before pruning
    assert res.model.metrics["complexity"]["candidates"][res.chosen]["neurons"] == res.model.neurons
    ok = [c["criterion"] for c in ev["candidates"] if c["criterion"] is not None]
    chosen = next(c for c in ev["candidates"] if c["neurons"] == res.model.neurons)
    assert chosen["criterion"] == min(ok)
    plain = identify(u, y, replace(cfg, prune_runs=0), 0)
    assert "neuron_choice" not in plain.model.metrics and plain.model.neurons == 30


def test_fallback_runs_are_made_while_the_best_fit_is_poor(monkeypatch: pytest.MonkeyPatch) -> None:
    rng = np.random.default_rng(5)
    u = rng.uniform(-1, 1, 500)
    y = np.zeros(500)
    for t in range(1, 500):  # mostly noise: no model free-runs well
        y[t] = 0.3 * np.tanh(u[t - 1]) + rng.normal()
    cfg = DEFAULT.replace(generations=5, max_lag_cap=0, restarts=2, prune_runs=0,
                         more_restarts=0)
    poor = identify(u, y, cfg, 0)
    assert max(r.score for r in poor.runs[:2]) <= FALLBACK_BELOW
    assert poor.model.metrics["fallback_runs"] == [15, 8] and len(poor.runs) == 4
    assert poor.model.metrics["run_neurons"][2:] == [15, 8]
    assert identify(u, y, cfg.replace(fallback_neurons=()), 0).model.metrics["fallback_runs"] == []
    monkeypatch.setattr("streamid.engine.identification.FALLBACK_BELOW", -1e9)  # only when no run is admissible
    assert identify(u, y, cfg, 0).model.metrics["fallback_runs"] == []
    with pytest.raises(ConfigError, match="retired"):
        CoEAConfig.from_dict({"fallback_below": 0.5})
