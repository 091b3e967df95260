"""Coevolution: structure recovery, reproducibility, stepping, exported state and warm starts."""

from __future__ import annotations

import numpy as np
import pytest

from streamid.engine import CoEAConfig, CoEAState, Coevolution
from streamid.engine.identification import identify
from streamid.engine.validation import prediction_r2
from streamid.errors import ConfigError, ModelFormatError

SMALL = CoEAConfig(neurons=8, max_lag_y=4, max_lag_u=4, generations=40)


def narx(n: int, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """y(t) = 0.5 y(t-1) + sin(2 u(t-2)) - 0.3 u(t-1) y(t-1): true lags y1, u1, u2."""
    u = rng.uniform(-1, 1, n)
    y = np.zeros(n)
    for t in range(3, n):
        y[t] = 0.5 * y[t - 1] + np.sin(2 * u[t - 2]) - 0.3 * u[t - 1] * y[t - 1]
    return u, y


def miso(n: int, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """Two inputs: y(t) = 0.5 y(t-1) + sin(2 u0(t-1)) + 0.5 u1(t-2)^2."""
    u = rng.uniform(-1, 1, (n, 2))
    y = np.zeros(n)
    for t in range(2, n):
        y[t] = 0.5 * y[t - 1] + np.sin(2 * u[t - 1, 0]) + 0.5 * u[t - 2, 1] ** 2
    return u, y


@pytest.mark.parametrize("seed", range(4))
def test_recovers_true_lags_of_synthetic_narx(seed: int) -> None:
    u, y = narx(400, np.random.default_rng(100 + seed))
    run = Coevolution(u, y, SMALL, seed).solve()
    m = run.best_model()
    assert m.lags == {"y": [1], "u": [[1, 2]]}
    assert run.evaluations == SMALL.evaluations_per_run() == 20 * 42
    uv, yv = narx(300, np.random.default_rng(999))
    osa, fr, _ = prediction_r2(m, uv, yv)
    assert osa > 0.95 and fr > 0.9  # 40 generations of M = 8: a usable model, not a polished one


def test_miso_recovers_lags_of_each_input() -> None:
    u, y = miso(400, np.random.default_rng(7))
    m = Coevolution(u, y, SMALL.replace(generations=60), 1).solve().best_model()
    assert m.lags == {"y": [1], "u": [[1], [2]]}
    assert m.n_inputs == 2


def test_same_seed_same_result_and_global_rng_has_no_effect() -> None:
    u, y = narx(300, np.random.default_rng(1))
    np.random.seed(1)
    a = Coevolution(u, y, SMALL.replace(generations=15), 42).solve()
    np.random.seed(12345)
    _ = np.random.random(100)
    b = Coevolution(u, y, SMALL.replace(generations=15), np.random.default_rng(42)).solve()
    assert a.history == b.history
    assert a.best_model().to_json() == b.best_model().to_json()
    np.testing.assert_array_equal(a.state().params, b.state().params)
    c = Coevolution(u, y, SMALL.replace(generations=15), 43).solve()
    assert c.best_model().to_json() != a.best_model().to_json()


def test_identify_reproducible_with_restarts_in_process() -> None:
    u, y = narx(300, np.random.default_rng(2))
    cfg = SMALL.replace(generations=10, restarts=3, selection="fr_est")
    r1 = identify(u, y, cfg, 5)
    r2 = identify(u, y, cfg, 5)
    assert r1.model.to_json() == r2.model.to_json()
    assert len(r1.runs) == 3 and r1.evaluations == 3 * cfg.evaluations_per_run()
    assert r1.model.metrics["selection"] == "fr_est"
    # the chosen run is the one with the best free-run R^2 on the estimation data
    assert r1.runs[r1.chosen].score == max(r.score for r in r1.runs)


def test_stepping_and_history() -> None:
    u, y = narx(300, np.random.default_rng(3))
    run = Coevolution(u, y, SMALL.replace(generations=6), 0)
    assert run.evaluations == 40 and not run.done
    progress = [next(run) for _ in range(3)]
    assert [p.generation for p in progress] == [1, 2, 3]
    assert run.evaluations == 40 + 3 * 20
    rest = list(run)
    assert len(rest) == 3 and run.done
    with pytest.raises(StopIteration):
        next(run)
    h = run.history
    assert len(h) == 6 and all(b <= a for a, b in zip(h, h[1:]))  # best-so-far never worsens


def test_callback_can_stop_early() -> None:
    u, y = narx(300, np.random.default_rng(3))
    seen = []
    run = Coevolution(u, y, SMALL.replace(generations=50), 0).solve(lambda p: seen.append(p.generation) or p.generation >= 5)
    assert seen == [1, 2, 3, 4, 5] and run.g == 5


def test_best_pair_consistent_with_populations() -> None:
    u, y = narx(300, np.random.default_rng(4))
    run = Coevolution(u, y, SMALL.replace(generations=30), 0).solve()
    st = run.state()
    assert st.best_fitness == pytest.approx(min(st.param_fitness.min(), st.harmony_fitness.min()))
    # the refitted model reproduces the search's fitness (same regularised least squares, computed by SVD)
    m = run.best_model()
    assert m.metrics["fitness"] == pytest.approx(run.best_f, rel=1e-6)


def test_state_json_and_npz_round_trip(tmp_path) -> None:
    u, y = narx(300, np.random.default_rng(5))
    st = Coevolution(u, y, SMALL.replace(generations=5), 0).solve().state()
    st2 = CoEAState.from_json(st.to_json())
    path = tmp_path / "state.npz"
    st.save_npz(path)
    st3 = CoEAState.load_npz(path)
    for other in (st2, st3):
        np.testing.assert_array_equal(other.harmonies, st.harmonies)
        np.testing.assert_array_equal(other.params, st.params)
        np.testing.assert_array_equal(other.param_fitness, st.param_fitness)
        assert other.best_fitness == st.best_fitness and other.normalisation == st.normalisation
    with pytest.raises(ModelFormatError):
        CoEAState.from_json('{"format": "something else"}')
    (tmp_path / "bad.npz").write_bytes(b"not a zip")
    with pytest.raises(ModelFormatError):
        CoEAState.load_npz(tmp_path / "bad.npz")


def test_warm_start_on_new_data() -> None:
    rng = np.random.default_rng(6)
    u, y = narx(900, rng)
    a_u, a_y, b_u, b_y = u[:450], y[:450], u[450:], y[450:]
    first = Coevolution(a_u, a_y, SMALL.replace(generations=40), 0).solve()
    state = CoEAState.from_json(first.state().to_json())  # exported and imported, as the daemon does
    cfg = SMALL.replace(generations=10)
    warm = Coevolution(b_u, b_y, cfg, 1, warm_start=state)
    # the previous populations were re-evaluated on the new data: X with the old best harmony
    cols = np.flatnonzero(state.best_mask)
    m0 = warm.model_for(state.best_mask, warm.X[0])
    assert warm.fx[0] == pytest.approx(m0.metrics["fitness"], rel=1e-6)
    assert np.array_equal(warm.H, state.harmonies)
    assert warm.evaluations == 2 * cfg.population
    assert cols.size and warm.best_f <= warm.fx.min() + 1e-12
    warm.solve()
    cold = Coevolution(b_u, b_y, cfg, 1).solve()
    assert warm.best_f < cold.best_f  # ten generations from a good start beat ten from scratch
    assert warm.best_model().lags == {"y": [1], "u": [[1, 2]]}


def test_warm_start_must_fit_the_configuration() -> None:
    u, y = narx(300, np.random.default_rng(8))
    st = Coevolution(u, y, SMALL.replace(generations=2), 0).solve().state()
    with pytest.raises(ConfigError, match="does not fit"):
        Coevolution(u, y, SMALL.replace(neurons=5), 0, warm_start=st)
    with pytest.raises(ConfigError, match="does not fit"):
        Coevolution(np.column_stack([u, u]), y, SMALL, 0, warm_start=st)


@pytest.mark.parametrize("seed", [0, 1])
def test_reactor_with_the_papers_settings(seed: int) -> None:
    """Paper eq. (17), 480 + 480 samples, G=400, M=10, L=10: the lags of the literature and FR R^2 >= 0.9999."""
    from benchmarks.engine_cases import REACTOR_CONFIG, reactor_data, reactor_lags_ok

    ue, ye, uv, yv = reactor_data(seed)
    res = identify(ue, ye, REACTOR_CONFIG, seed)
    assert res.evaluations == 8040
    assert reactor_lags_ok(res.model.lags)
    osa, fr, _ = prediction_r2(res.model, uv, yv)
    assert fr >= 0.9999 and osa >= 0.9999


def test_mr_damper_with_streamids_defaults() -> None:
    """The real MR damper (bundled log), 2000 estimation / 1499 validation samples, default identify()."""
    from benchmarks.engine_cases import mr_damper_data

    ue, ye, uv, yv = mr_damper_data()
    res = identify(ue, ye, None, 0)
    from streamid.model.ensemble import members_of

    nets = members_of(res.model)  # issue 51: the median of the eight finished runs' networks of 30 neurons
    assert len(res.runs) == 8 and len(nets) == 8 and all(m.neurons == 30 for m in nets)
    assert getattr(res.model, "combine", None) == "median"
    osa, fr, _ = prediction_r2(res.model, uv, yv)
    assert osa >= 0.996 and fr >= 0.97


@pytest.mark.parametrize("block", [1, 3, 7])
def test_result_does_not_depend_on_random_block_size(monkeypatch: pytest.MonkeyPatch, block: int) -> None:
    """Uniforms drawn for blocks of generations: the same stream as one draw per generation."""
    from streamid.engine.search import coevolution

    u, y = narx(300, np.random.default_rng(6))
    cfg = SMALL.replace(generations=17)
    ref = Coevolution(u, y, cfg, 3).solve()
    monkeypatch.setattr(coevolution, "_BLOCK", block)
    run = Coevolution(u, y, cfg, 3)
    assert run._trials.block == block
    run.solve()
    assert run.history == ref.history
    np.testing.assert_array_equal(run.state().params, ref.state().params)
    np.testing.assert_array_equal(run.state().harmonies, ref.state().harmonies)
