"""A received model run sample by sample (streamid.Predictor): the model's own computations, bounded, and honest."""

from __future__ import annotations

import numpy as np
import pytest

from streamid import CoEAConfig, Model, Predictor, identify
from streamid.model.predictor import MIN_HISTORY, has_direct_terms
from streamid.model.regressors import Normalisation, Regressor
from streamid.errors import DataError
from streamid.sim import simulate_reactor


@pytest.fixture(scope="module")
def reactor() -> tuple[Model, np.ndarray, np.ndarray]:
    _, u, y = simulate_reactor(1500, np.random.default_rng(1))
    model = identify(u[:480], y[:480], CoEAConfig(neurons=6, generations=40), np.random.default_rng(0)).model
    return model, np.asarray(u, dtype=float), np.asarray(y, dtype=float)


def _hand_model(lags: list[tuple[str, int]], n_inputs: int = 1) -> Model:
    """A small network over the given (signal, lag) regressors (input 0), with fixed, non-trivial parameters."""
    k = len(lags)
    rng = np.random.default_rng(7)
    return Model(regressors=tuple(Regressor(s, 0, lag) for s, lag in lags), centres=rng.uniform(-0.5, 0.5, (3, k)),
                 widths=np.array([0.8, 1.1, 1.5]), weights=np.array([0.4, -0.3, 0.2]),
                 normalisation=Normalisation((-2.0,) * n_inputs, (2.0,) * n_inputs, -1.0, 1.0),
                 linear=np.r_[np.full(k, 0.1), 0.05])


def test_one_step_and_forecasts_are_the_models_own_computations(reactor: tuple[Model, np.ndarray, np.ndarray]) -> None:
    model, u, y = reactor
    L = model.max_lag
    osa = model.predict_osa(u, y)
    p = Predictor(model)
    checked = 0
    for t in range(u.shape[0] - 1):  # 1,500 samples: the buffer (2 x 256) wraps several times
        # a float (checked in Python) or any other form (checked by numpy) every other sample: the same values
        p.learn_one(float(u[t]), float(y[t])) if t % 2 else p.learn_one([u[t]], np.array(y[t]))
        if t + 1 < L:
            assert not p.ready
            with pytest.raises(DataError, match=f"needs the newest {L} samples"):
                p.predict_one()
            continue
        assert p.predict_one() == pytest.approx(osa[t + 1], rel=1e-12, abs=1e-12)
        if t % 97 == 0 and t + 51 <= u.shape[0]:
            want = model.simulate(u[t + 1 - L : t + 51], y[t + 1 - L : t + 1])[L:]
            got = p.forecast(u[t + 1 : t + 51])
            assert got.shape == (50,) and np.allclose(got, want, rtol=1e-12, atol=1e-12)
            plans = np.stack([u[t + 1 : t + 51] * g for g in (1.0, 0.5, -0.8)])  # candidate plans, at once
            many = p.forecast_many(plans)
            assert many.shape == (3, 50) and np.allclose(many[0], want, rtol=1e-12, atol=1e-12)
            assert all(np.allclose(many[k], p.forecast(plans[k]), rtol=1e-12, atol=1e-12) for k in (1, 2))
            checked += 1
    assert checked >= 10



def _net(regs: list[tuple[str, int, int]], *, linear: str = "", seed: int = 0, scale: float = 2.0) -> Model:
    """A network over (signal, input index, lag) regressors of 2 inputs; ``linear``: "" none, "own" on its
    regressors, "long" a long linear part of its own; ``scale``: the normalisation's half range."""
    k = len(regs)
    rng = np.random.default_rng(seed)
    long_regs = tuple(Regressor(s, i, lag) for s, i, lag in (("y", 0, 1), ("y", 0, 7), ("u", 1, 4), ("u", 0, 12)))
    lin = {"": None, "own": rng.normal(0, 0.1, k + 1), "long": rng.normal(0, 0.1, len(long_regs) + 1)}[linear]
    return Model(regressors=tuple(Regressor(s, i, lag) for s, i, lag in regs), centres=rng.uniform(-0.6, 0.6, (5, k)),
                 widths=rng.uniform(0.6, 1.4, 5), weights=rng.normal(0, 0.5, 5),
                 normalisation=Normalisation((-scale, -1.0), (scale, 3.0), -1.5 * scale, scale), linear=lin,
                 linear_regressors=long_regs if linear == "long" else None)


def test_every_kind_of_model_predicts_its_own_one_step_across_swaps_and_wraps() -> None:
    """Networks with and without a linear part (on their regressors, or long: its own), of two inputs, an
    ensemble of them, and a direct term: ``predict_one`` is ``predict_osa``'s last value at every sample,
    including right after a swap to a model of another normalisation and across the buffer's wraps."""
    from streamid.model.ensemble import ensemble_of

    a = _net([("y", 0, 1), ("u", 0, 1), ("u", 1, 3), ("y", 0, 2)])
    b = _net([("u", 1, 2), ("y", 0, 3), ("u", 0, 5)], linear="own", seed=1, scale=3.0)
    c = _net([("y", 0, 1), ("u", 0, 2)], linear="long", seed=2, scale=1.0)
    e = ensemble_of([a, b, c])
    d = _net([("y", 0, 1), ("u", 0, 0), ("u", 1, 1)], linear="own", seed=3)  # u0(t): a direct term
    rng = np.random.default_rng(5)
    n = 1400
    u, y = rng.uniform(-1.5, 1.5, (n, 2)), rng.uniform(-1.0, 1.0, n)
    plan = [(0, a), (200, b), (330, c), (600, e), (1000, d), (1200, a)]
    p = Predictor(a)
    served, checked = a, 0
    for t in range(n - 1):
        for at, m in plan:
            if t == at and m is not served:
                p.swap(m)
                served = m
        p.learn_one(u[t], y[t])
        if not p.ready:
            continue
        want = served.predict_osa(u[: t + 2], np.r_[y[: t + 1], 0.0])[-1]
        got = p.predict_one(u_next=u[t + 1]) if has_direct_terms(served) else p.predict_one()
        assert got == pytest.approx(want, rel=1e-12, abs=1e-12), (t, served)
        checked += 1
        if t in (300, 700, 1100):  # the free runs too: two plans at once, each the model's own simulate
            L = served.max_lag
            plans = np.stack([u[t + 1 : t + 41], -u[t + 1 : t + 41]])
            many = p.forecast_many(plans)
            for k in range(2):
                want_run = served.simulate(np.vstack([u[t + 1 - L : t + 1], plans[k]]), y[t + 1 - L : t + 1])[L:]
                assert np.allclose(many[k], want_run, rtol=1e-12, atol=1e-12), (t, k, served)
    assert checked > n - 30 and p._n <= 2 * MIN_HISTORY  # noqa: SLF001 - the buffer wrapped, still bounded

def test_the_buffer_is_bounded_and_reset_forgets(reactor: tuple[Model, np.ndarray, np.ndarray]) -> None:
    model, u, y = reactor
    p = Predictor(model)
    for t in range(20_000):
        p.learn_one(u[t % 1000], y[t % 1000])
    # noqa: SLF001 - the bound is the point: 2 x 256 samples, raw and normalised, and one slot for u_next
    assert p._u.shape[0] == p._y.shape[0] == p._un.shape[0] == p._yn.shape[0] == 2 * MIN_HISTORY + 1
    assert MIN_HISTORY <= p.held <= 2 * MIN_HISTORY
    p.reset()
    assert p.held == 0 and not p.ready


def test_a_swapped_model_keeps_the_samples_and_a_longer_memory_waits_for_enough() -> None:
    short, long_ = _hand_model([("y", 1), ("u", 1)]), _hand_model([("y", 1), ("u", 300)])
    rng = np.random.default_rng(3)
    u, y = rng.uniform(-1, 1, 400), rng.uniform(-0.5, 0.5, 400)
    p = Predictor(short)
    for t in range(280):
        p.learn_one(u[t], y[t])
    assert p.predict_one() == pytest.approx(short.predict_osa(u[:281], y[:281])[-1], rel=1e-12)
    p.swap(long_)
    assert p.model is long_ and p.held == 280 and not p.ready  # 280 of the 300 samples it needs
    for t in range(280, 300):
        p.learn_one(u[t], y[t])
    assert p.ready
    assert p.predict_one() == pytest.approx(long_.predict_osa(u[:301], y[:301])[-1], rel=1e-12)
    with pytest.raises(DataError, match=r"the new model takes 2 input\(s\)"):
        p.swap(_hand_model([("y", 1), ("u", 1)], n_inputs=2))
    with pytest.raises(DataError, match="serves a streamid Model"):
        p.swap({"format": "streamid.model/1"})  # type: ignore[arg-type]


def test_direct_terms_need_the_input_at_the_predicted_instant() -> None:
    m = _hand_model([("y", 1), ("u", 0), ("u", 2)])
    assert has_direct_terms(m) and not has_direct_terms(_hand_model([("y", 1), ("u", 1)]))
    rng = np.random.default_rng(4)
    u, y = rng.uniform(-1, 1, 50), rng.uniform(-0.5, 0.5, 50)
    p = Predictor(m)
    for t in range(40):
        p.learn_one(u[t], y[t])
    with pytest.raises(DataError, match=r"direct terms .*pass u_next"):
        p.predict_one()
    assert p.predict_one(u_next=u[40]) == pytest.approx(m.predict_osa(u[:41], y[:41])[-1], rel=1e-12)
    got = p.forecast(u[40:50])  # u(t+1) is used at the first step
    assert np.allclose(got, m.simulate(u[38:50], y[38:40])[2:], rtol=1e-12)


def test_bad_samples_are_refused_naming_the_value_and_nothing_is_added(
        reactor: tuple[Model, np.ndarray, np.ndarray]) -> None:
    model, u, y = reactor
    p = Predictor(model)
    for t in range(10):
        p.learn_one(u[t], y[t])
    before = (p.held, p.predict_one())
    for args, match in (((np.nan, 1.0), r"u must contain only finite numbers \(no NaN or inf\); got nan"),
                        ((0.1, float("inf")), "y must contain only finite numbers .*; got inf"),
                        (([0.1, 0.2], 1.0), r"u must be a number; got shape \(2,\)"),
                        (("fast", 1.0), "u must be numbers; got 'fast'")):
        with pytest.raises(DataError, match=match):
            p.learn_one(*args)
    with pytest.raises(DataError, match=r"u_plan must be an array of shape \(H,\) or \(H, 1\)"):
        p.forecast(np.zeros((0,)))
    with pytest.raises(DataError, match="u_plan must contain only finite numbers .*; got nan at sample 1"):
        p.forecast([0.1, np.nan])
    with pytest.raises(DataError, match=r"u_plans\[1\] must contain only finite numbers .*; got inf at sample 0"):
        p.forecast_many([[0.1, 0.2], [np.inf, 0.0]])
    with pytest.raises(DataError, match=r"u_plans must be an array of shape \(P, H\) or \(P, H, 1\), .*got shape \(2,\)"):
        p.forecast_many([0.1, 0.2])
    assert (p.held, p.predict_one()) == before


def test_beyond_range_names_the_signals_a_prediction_leans_on() -> None:
    m = _hand_model([("y", 1), ("u", 2)])  # estimated on u in [-2, 2], y in [-1, 1]
    p = Predictor(m)
    for _ in range(3):
        p.learn_one(0.5, 0.2)
    assert p.beyond_range() == ()
    assert p.beyond_range(u_plan=[0.0, 3.5]) == ("u0",)  # 1.5 beyond a span of 4: more than a quarter
    assert p.beyond_range(u_plan=[0.0, 2.9]) == ()  # 0.9 beyond: within the quarter the guard allows
    p.learn_one(0.0, 1.8)
    assert p.beyond_range() == ("y",)
    p.learn_one(-3.5, 0.0)
    p.learn_one(0.0, 0.0)
    assert p.beyond_range() == ("u0",)  # the output sample at 1.8 is no longer among the newest max_lag


def test_an_online_champion_with_direct_terms_predicts_from_the_input_at_the_predicted_instant() -> None:
    """OnlineIdentifier.predict_one used to put the last input in place of u(t+1) for such a champion."""
    from streamid import OnlineIdentifier, StreamConfig

    rng = np.random.default_rng(0)
    n = 3000
    u = rng.uniform(-1, 1, n)
    y = np.zeros(n)
    for t in range(1, n):  # the output responds within the sample: u(t) is a regressor of its model
        y[t] = 0.6 * y[t - 1] + np.tanh(2 * u[t]) + 0.2 * u[t - 1]
    t_ns = np.arange(n, dtype=np.int64) * 10_000_000
    ident = OnlineIdentifier(StreamConfig(window_samples=1000, update_every_samples=500,
                                          engine=(("direct_terms", "test"),)), stream="f")
    for k in range(0, n, 100):
        ident.learn_many(t_ns[k : k + 100], u[k : k + 100, None], y[k : k + 100, None], inputs=["u"], outputs=["y"])
        ident.update_all()
    m = ident.model
    assert m is not None and has_direct_terms(m), m
    with pytest.raises(DataError, match="pass u_next"):
        ident.predict_one()
    want = m.predict_osa(np.r_[u, 0.3], np.r_[y, 0.0])[-1]
    assert ident.predict_one(u_next=0.3) == pytest.approx(want, rel=1e-12)
    assert ident.predict_one(u_next=-0.3) != pytest.approx(want, rel=1e-3)  # u(t+1) is used, not the last input
