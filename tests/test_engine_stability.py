"""Bounded by construction (issue 37): a kept model's linear part has a stable autoregression.

The rule of :mod:`streamid.engine.choice.stability`, checked on hand-built parts (the radius, the refusal in the final
choice, the refit with the linear part's own autoregression) and end to end: on a record where the network and its
linear part fitted together have an unstable autoregression, ``identify`` keeps a model whose free run stays bounded
on inputs far beyond the record's, and from a far-off initial state.
"""

from __future__ import annotations

import json

import numpy as np

from streamid.engine import identify
from streamid.engine.choice.scores import free_run_scores
from streamid.model.narx import Model
from streamid.model.regressors import Regressor
from streamid.engine.settings import DEFAULT
from streamid.engine.choice.longlinear import _LinearBlock
from streamid.engine.choice.stability import ar_radius, is_bounded, radius

Y1, Y2, U1 = Regressor("y", 0, 1), Regressor("y", 0, 2), Regressor("u", 0, 1)


def model(a1: float, a2: float = 0.0) -> Model:
    """``yn(t) = a1 yn(t-1) + a2 yn(t-2) + 0.2 un(t-1)`` beside one Gaussian of weight 0.1."""
    doc = {
        "format": "streamid.model/2", "inputs": ["u"], "output": "y",
        "regressors": [{"signal": "y", "index": 0, "lag": 1}, {"signal": "y", "index": 0, "lag": 2},
                       {"signal": "u", "index": 0, "lag": 1}],
        "normalisation": {"u_low": [-1.0], "u_high": [1.0], "y_low": -1.0, "y_high": 1.0},
        "centres": [[0.0, 0.0, 0.0]], "widths": [1.0], "weights": [0.1], "linear": [a1, a2, 0.2, 0.0],
        "metrics": {}, "window": {},
    }
    return Model.from_json(json.dumps(doc))


def test_radius_is_the_largest_root_of_the_autoregression() -> None:
    # 1 - 1.5 z^-1 + 0.56 z^-2 = (1 - 0.7 z^-1)(1 - 0.8 z^-1): radius 0.8
    assert abs(ar_radius(model(1.5, -0.56)) - 0.8) < 1e-12
    assert is_bounded(model(1.5, -0.56))
    # (1 - 1.1 z^-1)(1 - 0.5 z^-1) = 1 - 1.6 z^-1 + 0.55 z^-2: radius 1.1
    assert abs(radius((Y1, Y2, U1), np.array([1.6, -0.55, 0.3])) - 1.1) < 1e-12
    assert not is_bounded(model(1.6, -0.55))
    assert not is_bounded(model(1.0))  # on the unit circle: an integrator, not bounded
    assert radius((U1,), np.array([5.0])) == 0.0  # no output term: nothing to be unstable


def test_the_final_choice_refuses_an_unstable_linear_part_however_well_it_fits() -> None:
    rng = np.random.default_rng(0)
    u = rng.uniform(-1, 1, (400, 1))
    stable, unstable = model(0.5), model(1.02)
    y = stable.simulate(u, np.zeros(2))
    # The unstable model's free run over this short record stays in range (1.02 ** 400 is ~2.8e3 of a small start)
    fr = free_run_scores([unstable, stable], u, y, range_margin=1e9)
    assert fr.scores[0] == -np.inf and fr.excursions[0] == np.inf  # refused whatever its fit
    assert fr.best() == 1 and fr.scores[1] > 0.999


def test_a_long_linear_part_keeps_the_autoregression_of_the_linear_part_fitted_alone() -> None:
    # The refit of streamid.engine.choice.longlinear (step 3b) when the network and the linear part fitted together have an
    # unstable autoregression: the output terms are the linear part's own least squares, the rest refitted on them.
    rng = np.random.default_rng(1)
    n = 2000
    lin_cols = rng.uniform(-1, 1, (n, 2))  # columns: y(t-1), u(t-1)
    Z = np.column_stack([np.ones(n), lin_cols])
    A = np.exp(-((lin_cols[:, :1] - 1.0) ** 2) / 0.8)  # one Gaussian rising with y(t-1)
    target = 1.3 * lin_cols[:, 0] + 0.4 * lin_cols[:, 1] - 1.2 * A[:, 0]  # fitted exactly by an unstable joint fit
    block = _LinearBlock(Z, target, 1e-12)
    w, c = block.solve(A, 3)
    assert abs(c[1] - 1.3) < 1e-4  # the joint fit: an unstable autoregression
    is_y = np.array([False, True, False])
    w2, c2 = block.with_autoregression(Z, A, 3, is_y)
    alone = np.linalg.lstsq(Z, target, rcond=None)[0]
    assert abs(c2[1] - alone[1]) < 1e-6 and abs(c2[1]) < 1.0  # the linear part's own, stable here
    fit = A @ w2 + Z @ c2
    # the network, the input term and the constant refitted on what that autoregression leaves: better than alone
    assert np.mean((fit - target) ** 2) < np.mean((Z @ alone - target) ** 2)


def test_identify_keeps_a_model_that_stays_bounded_far_from_its_record() -> None:
    # A saturating plant driven by band-limited noise: where the defaults' networks and linear parts fit together,
    # their autoregressions were unstable (issue 37's simulators); the kept model must be bounded on any input.
    rng = np.random.default_rng(3)
    n = 1500
    u = np.convolve(rng.standard_normal(n + 20), np.ones(20) / 20, mode="valid")[:n]
    y = np.zeros(n)
    for t in range(2, n):
        y[t] = 1.2 * y[t - 1] - 0.45 * y[t - 2] + 0.5 * np.tanh(2.0 * u[t - 1])
    res = identify(u, y, DEFAULT.replace(restarts=2, more_restarts=0, generations=20), 0)
    kept = res.model
    assert is_bounded(kept)
    span = float(np.ptp(y))
    far = np.concatenate([np.full(300, 10 * np.max(np.abs(u))), np.full(300, -10 * np.max(np.abs(u)))])
    with np.errstate(over="ignore", invalid="ignore"):
        run = kept.simulate(far[:, None], np.full(kept.max_lag, float(np.max(y)) + 5 * span))
    assert np.all(np.isfinite(run))


def test_a_neuron_where_no_row_is_gets_weight_zero_beside_a_long_linear_part() -> None:
    # Seen on a 20,000-sample online window: a weight of 2.8e78 on a neuron whose activations had a norm of 9e-82.
    rng = np.random.default_rng(2)
    n = 500
    Z = np.column_stack([np.ones(n), rng.uniform(-1, 1, (n, 2))])
    A = np.column_stack([np.exp(-((Z[:, 1] - 0.3) ** 2) / 0.5), np.full(n, 1e-82)])  # a live and a dead neuron
    target = Z @ np.array([0.1, 0.5, -0.2]) + 0.7 * A[:, 0]
    block = _LinearBlock(Z, target, 1e-12)
    w, c = block.solve(A, 3)
    assert w[1] == 0.0 and abs(w[0] - 0.7) < 1e-6 and np.allclose(c, [0.1, 0.5, -0.2], atol=1e-6)
    w2, _ = block.with_autoregression(Z, A, 3, np.array([False, True, False]))
    assert w2[1] == 0.0 and np.all(np.isfinite(w2))
