"""The linear part in the search's fitness and both kinds competing in a run's choice (linear_terms)."""

from __future__ import annotations

import numpy as np
import pytest

from streamid.engine import CoEAConfig
from streamid.engine.choice import free_run_scores
from streamid.engine.coevolution import Coevolution
from streamid.engine.complexity import criterion, parameter_count
from streamid.engine.batch import BatchEvaluator
from streamid.engine.rbf import activations, fit_linear_rbf
from streamid.engine.selection import _by_criterion, select_model
from streamid.errors import ConfigError


def _members(seed: int, n: int = 400, D: int = 8, M: int = 6, P: int = 5):
    rng = np.random.default_rng(seed)
    R = rng.uniform(-1, 1, (n, D))
    y = np.sin(2 * R[:, 0]) + 0.5 * R[:, 1] + 0.3 * R[:, 2] - 0.2
    masks = rng.random((P, D)) < 0.5
    masks[:, 0] = True
    return R, y, masks, rng.uniform(-1, 1, (P, M, D)), rng.uniform(0.3, 2.0, (P, M))


def _direct_mse(R, y, mask, c, s) -> float:
    cols = np.flatnonzero(mask)
    phi = activations(R[:, cols], c[:, cols], s)
    w, lin = fit_linear_rbf(phi, R[:, cols], y, 1e-10)
    return float(np.mean((phi @ w + R[:, cols] @ lin[:-1] + lin[-1] - y) ** 2))


def test_linear_fitness_is_the_joint_least_squares_of_each_member() -> None:
    R, y, masks, C, S = _members(1)
    ev = BatchEvaluator(R, y, C.shape[1], masks.shape[0], linear=True)
    plain = BatchEvaluator(R, y, C.shape[1], masks.shape[0]).evaluate(masks, C, S)
    for shared_masks in (masks, np.tile(masks[2], (masks.shape[0], 1))):  # per-member masks, then one mask
        mse = ev.evaluate(shared_masks, C, S)
        direct = [_direct_mse(R, y, shared_masks[i], C[i], S[i]) for i in range(len(mse))]
        np.testing.assert_allclose(mse, direct, rtol=1e-9)
    # the per-member call after a shared one rewrites the linear rows (no stale regressors)
    again = ev.evaluate(masks, C, S)
    np.testing.assert_allclose(again, [_direct_mse(R, y, masks[i], C[i], S[i]) for i in range(len(again))], rtol=1e-9)
    # the linear part can only help on the same centres and widths (the target has a linear part here)
    assert np.all(again < plain)


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
                     linear_terms=True, complexity="aic")
    run = Coevolution(u, y, cfg, 0).solve()
    assert run.evaluator.linear and run.linear_search
    cands = run.candidate_models(4, both=True)
    half = len(cands) // 2
    assert len(cands) == 2 * half and half >= 2
    assert all(m.linear is not None for m in cands[:half]) and all(m.linear is None for m in cands[half:])
    for a, b in zip(cands[:half], cands[half:]):  # the same centres and widths, the weights refitted
        np.testing.assert_array_equal(a.centres, b.centres)
        assert not np.array_equal(a.weights, b.weights)
    ua = u[:, None]
    fr = free_run_scores(cands, ua, y)
    k = _by_criterion("aic", cands, fr, len(y))
    crit = [criterion("aic", s, len(y) - m.max_lag, parameter_count(m)) if e == 0.0 else np.inf
            for m, s, e in zip(cands, fr.scores, fr.excursions)]
    assert k == int(np.argmin(crit)) and np.isfinite(crit[k])
    model, score = select_model(run, ua, y, "fr_est")
    assert score == fr.scores[k] and (model.linear is None) == (cands[k].linear is None)
    # the same rule over equal fits: a plain network (k + 1 fewer weights) beats its linear twin
    twin = free_run_scores([cands[half], cands[0]], ua, y)
    even = type(twin)((0.9, 0.9), (0.0, 0.0))
    assert _by_criterion("aic", [cands[0], cands[half]], even, len(y)) == 1


def test_linear_terms_off_keeps_the_rbf_only_search_and_one_kind() -> None:
    u, y = _narx(400, 1)
    cfg = CoEAConfig(neurons=5, max_lag_y=2, max_lag_u=2, generations=5, selection="fr_est", fr_candidates=3)
    run = Coevolution(u, y, cfg, 0).solve()
    assert not run.evaluator.linear
    cands = run.candidate_models(3, both=True)  # "both" means nothing without linear_terms
    assert all(m.linear is None for m in cands) and len(cands) == len(run.candidate_models(3))
    # a caller can keep the search RBF-only with linear_terms on (the lag search of a two-stage run)
    lag = Coevolution(u, y, cfg.replace(linear_terms=True), 0, linear_search=False).solve()
    assert not lag.evaluator.linear and lag.best_f == run.best_f


def test_linear_search_false_searches_rbf_only_and_still_offers_both_kinds() -> None:
    u, y = _narx(400, 2)
    base = CoEAConfig(neurons=5, max_lag_y=2, max_lag_u=2, generations=8, selection="fr_est", fr_candidates=3)
    plain = Coevolution(u, y, base, 0).solve()
    run = Coevolution(u, y, base.replace(linear_terms=True, linear_search=False), 0).solve()
    assert not run.evaluator.linear and run.best_f == plain.best_f  # the same search, bit for bit
    cands = run.candidate_models(3, both=True)
    assert sum(m.linear is not None for m in cands) == len(cands) // 2 == len(plain.candidate_models(3))
    with pytest.raises(ConfigError, match="linear_search must be true or false; got 'yes'"):
        CoEAConfig(linear_search="yes")  # type: ignore[arg-type]
