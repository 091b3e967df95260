"""Both kinds, with and without a direct linear part, competing in a run's choice (linear_terms); the search stays
RBF-only (searching with the linear part, ``linear_search``, was measured worse and retired in issue 37)."""

from __future__ import annotations

import numpy as np
import pytest

from streamid.engine import CoEAConfig
from streamid.engine.choice.scores import free_run_scores
from streamid.engine.search.coevolution import Coevolution
from streamid.engine.choice.complexity import criterion, parameter_count
from streamid.engine.choice.selection import _by_criterion, select_model
from streamid.errors import ConfigError


def _narx(n: int, seed: int) -> tuple[np.ndarray, np.ndarray]:
    rng = np.random.default_rng(seed)
    u = rng.uniform(-1, 1, n)
    y = np.zeros(n)
    for t in range(2, n):
        y[t] = 0.6 * y[t - 1] - 0.2 * y[t - 2] + 0.5 * u[t - 1] + 0.3 * np.tanh(2 * u[t - 2]) * y[t - 1]
    return u, y


def test_both_kinds_are_offered_and_the_run_takes_the_lowest_criterion() -> None:
    u, y = _narx(500, 0)
    cfg = CoEAConfig(neurons=6, max_lag_y=3, max_lag_u=3, generations=15, selection="fr_est", fr_candidates=4,
                     linear_terms=True)
    run = Coevolution(u, y, cfg, 0).solve()
    cands = run.candidate_models(4, both=True)
    half = len(cands) // 2
    assert len(cands) == 2 * half and half >= 2
    assert all(m.linear is not None for m in cands[:half]) and all(m.linear is None for m in cands[half:])
    for a, b in zip(cands[:half], cands[half:]):  # the same centres and widths, the weights refitted
        np.testing.assert_array_equal(a.centres, b.centres)
        assert not np.array_equal(a.weights, b.weights)
    ua = u[:, None]
    fr = free_run_scores(cands, ua, y)
    k = _by_criterion(cands, fr, len(y))
    crit = [criterion(s, len(y) - m.max_lag, parameter_count(m)) if e == 0.0 else np.inf
            for m, s, e in zip(cands, fr.scores, fr.excursions)]
    assert k == int(np.argmin(crit)) and np.isfinite(crit[k])
    model, score = select_model(run, ua, y, "fr_est")
    assert score == fr.scores[k] and (model.linear is None) == (cands[k].linear is None)
    # the same rule over equal fits: a plain network (k + 1 fewer weights) beats its linear twin
    twin = free_run_scores([cands[half], cands[0]], ua, y)
    even = type(twin)((0.9, 0.9), (0.0, 0.0))
    assert _by_criterion([cands[0], cands[half]], even, len(y)) == 1


def test_the_search_is_rbf_only_with_or_without_the_linear_part_and_retired_fields_are_refused() -> None:
    u, y = _narx(400, 2)
    base = CoEAConfig(neurons=5, max_lag_y=2, max_lag_u=2, generations=8, selection="fr_est", fr_candidates=3)
    plain = Coevolution(u, y, base, 0).solve()
    cands = plain.candidate_models(3, both=True)  # "both" means nothing without linear_terms
    assert all(m.linear is None for m in cands) and len(cands) == len(plain.candidate_models(3))
    run = Coevolution(u, y, base.replace(linear_terms=True), 0).solve()
    assert run.best_f == plain.best_f  # the same search, bit for bit
    cands = run.candidate_models(3, both=True)
    assert sum(m.linear is not None for m in cands) == len(cands) // 2 == len(plain.candidate_models(3))
    for name in ("linear_search", "weight_decay", "lag_search_generations", "lag_alternation", "hedge_neurons",
                 "range_margin", "refine_above", "screen_rows"):
        with pytest.raises(ConfigError, match=rf"\['{name}'\] were retired in issue 37"):
            CoEAConfig.from_dict({**base.to_dict(), name: 0})
