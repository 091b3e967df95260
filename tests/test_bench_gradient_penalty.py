"""benchmarks.gradient_penalty: the slope penalty of issue 37's round 8, checked against finite differences."""

from __future__ import annotations

import numpy as np

from benchmarks.gradient_penalty import free_run_mse, gradient_gram, penalised_refit
from streamid.engine import identify
from streamid.engine.fit.rbf import activations
from streamid.engine.choice.selection import refit_weights
from streamid.engine.settings import DEFAULT, RIDGE
from streamid.sim import simulate_reactor


def test_the_gram_gives_the_sum_of_squared_slopes() -> None:
    rng = np.random.default_rng(0)
    r, c, s, w = rng.normal(size=(50, 3)), rng.normal(size=(4, 3)), rng.uniform(0.3, 2.0, 4), rng.normal(size=4)
    h = 1e-6
    for cols in ([0, 2], [0, 1, 2]):
        slopes = np.zeros(50)
        for j in cols:
            d = np.zeros(3)
            d[j] = h
            g = (activations(r + d, c, s) - activations(r - d, c, s)) @ w / (2 * h)
            slopes += g**2
        assert abs(w @ gradient_gram(r, c, s, cols) @ w - slopes.sum()) < 1e-6 * slopes.sum()


def test_no_penalty_is_the_least_squares_and_a_penalty_flattens_the_network() -> None:
    tr = simulate_reactor(480, 0)
    u, y = np.asarray(tr.u, dtype=float).reshape(-1, 1), np.asarray(tr.y, dtype=float)
    model = identify(u, y, DEFAULT.replace(neurons=6, generations=8, restarts=1, selection="fitness", linear_terms=False,
                                           long_linear=0, refine_iterations=0), 1).model
    plain = refit_weights(model, u, y, RIDGE)
    same = penalised_refit(model, u, y, 0.0, "all")
    assert same is not None  # the least squares (the engine scales its ridge per column: the same fit's error)
    mse = [float(np.mean((m.predict_osa(u, y) - y)[m.max_lag:] ** 2)) for m in (same, plain)]
    assert abs(mse[0] - mse[1]) < 1e-3 * mse[1]
    r, _ = model.regressor_rows(u, y)
    cols = list(range(len(model.regressors)))
    g = gradient_gram(r, model.centres, model.widths, cols)
    flat = penalised_refit(model, u, y, 10 * free_run_mse(model, u, y), "all")
    assert flat is not None
    assert flat.weights @ g @ flat.weights < plain.weights @ g @ plain.weights


def test_the_summary_counts_targets_and_keeps_the_model_where_a_refit_is_refused() -> None:
    from benchmarks.gradient_penalty import summarise

    rows = [{"row": "rlc [id->test]", "seed": s, "base": 0.97, "refit": None, "y": 0.5, "all": 0.96,
             "held_base": 0.9, "held_y": 0.95, "held_all": 0.8} for s in range(5)]
    lines, met = summarise(rows)
    assert met["defaults"] == 1 and met["refit"] == 1  # refused: the kept model's 0.97 (FROLS 0.9412)
    assert met["y"] == 0 and met["y judged"] == 0  # 0.5, taken: its half held out better
    assert met["all"] == 1 and met["all judged"] == 1  # 0.96 not taken (its half held out worse): 0.97
    assert lines[0].startswith("| rlc [id->test] | 0.9700 / 0.97 *")
