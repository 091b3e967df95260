"""Predictor.step: the model run as a simulator sample by sample (an FMU's doStep), its band and its domain flag
equal to what Model.simulate(..., interval=level) and the domain module compute over the whole run."""

from __future__ import annotations

from dataclasses import FrozenInstanceError, replace

import numpy as np
import pytest

from streamid.engine import DEFAULT, identify
from streamid.errors import DataError
from streamid.model import Model, Predictor
from streamid.model.domain import outside, signal_excess, signal_outside, value_excess, value_outside
from streamid.model.ensemble import ensemble_of, members_of
from streamid.model.predictor import Step, has_direct_terms
from streamid.model.uncertainty import BEYOND, LEVELS, Interval
from streamid.sim import simulate_mr_damper
from test_predictor import _net

INTERVAL = Interval(LEVELS, (0.5, 1.0, 1.5, 2.0, 3.0), 0.1, 100, beyond=BEYOND)


@pytest.fixture(scope="module")
def damper() -> tuple[list[Model], np.ndarray, np.ndarray]:
    """Three networks the engine identified on a simulated MR damper (seeds 0-2: each with a calibrated interval,
    two with a linear part, memories of 7 and 10 samples), and another record of the same excitation to run them on."""
    est, val = simulate_mr_damper(3000, 1), simulate_mr_damper(1200, 2)
    cfg = DEFAULT.replace(generations=15, restarts=2, neurons=10, lag_search_neurons=0, more_restarts=0)
    nets = [identify(est.u, est.y, cfg, s).model for s in range(3)]
    assert all(m.interval is not None for m in nets) and any(m.linear is not None for m in nets)
    assert len({m.max_lag for m in nets}) > 1  # an ensemble's shorter members free-run over measured samples too
    return nets, val.u.reshape(-1, 1).astype(float), val.y.astype(float)


def _stepped(model: Model, u: np.ndarray, y: np.ndarray, start: int, stop: int,
             level: float | None = 0.9) -> tuple[Predictor, list[Step]]:
    """A predictor that learnt samples ..start-1, then stepped the instants start..stop-1 (a one-input model's
    input given as a float every other instant: the loop's fast path, the same values)."""
    p = Predictor(model)
    for t in range(start):
        p.learn_one(u[t], y[t])
    return p, [p.step(float(u[t, 0]) if t % 2 and u.shape[1] == 1 else u[t], interval=level) for t in range(start, stop)]


def _check_equal_to_simulate(model: Model, u: np.ndarray, y: np.ndarray, start: int, steps: list[Step]) -> np.ndarray:
    """The steps against ``simulate`` from the newest max_lag measured samples before ``start`` (y, lower, upper to
    1e-9 relative) and against :func:`outside` on that run (in_domain); returns the domain flags."""
    L = model.max_lag
    stop = start + len(steps)
    whole = model.simulate(u[start - L : stop], y[start - L : start], interval=0.9)
    tol = 1e-12 * model.normalisation.y_half_range
    for name in ("y", "lower", "upper"):
        got = np.array([getattr(s, name) for s in steps])
        np.testing.assert_allclose(got, getattr(whole, name)[L:], rtol=1e-9, atol=tol, err_msg=name)
    regs = sorted({r for m in members_of(model) for r in (*m.regressors, *(m.linear_regressors or ()))},
                  key=lambda r: (r.signal, r.index, r.lag))
    flags = ~outside(model.normalisation, regs, u[start - L : stop], whole.y)[L:]
    assert [s.in_domain for s in steps] == flags.tolist()
    return flags


def test_steps_of_engine_models_and_their_ensembles_are_simulate_with_its_band(
        damper: tuple[list[Model], np.ndarray, np.ndarray]) -> None:
    nets, u, y = damper
    u = u.copy()
    u[700:760] *= 1.6  # the input leaves its estimation range: the band grows, in_domain says so
    models = [nets[0], replace(ensemble_of(nets), interval=nets[0].interval),
              replace(ensemble_of(nets, combine="median"), interval=nets[0].interval)]
    for model in models:
        p, steps = _stepped(model, u, y, 300, 1000)
        flags = _check_equal_to_simulate(model, u, y, 300, steps)
        assert flags.any() and not flags.all(), model  # some instants in the domain, some outside
        band = p.forecast(u[1000:1100], interval=0.9)  # forecast is unaffected by the steps (measured samples)
        L = model.max_lag
        whole = model.simulate(u[300 - L : 400], y[300 - L : 300], interval=0.9)
        assert p.stepped == 700 and not np.allclose(band.y[:100], whole.y[L:])  # another start: another run


def test_every_kind_of_network_steps_as_it_simulates() -> None:
    """Two inputs, a linear part on the regressors and a long one of its own, a direct term (lag 0), members of
    different memories in mean and median ensembles; inputs that leave the domain."""
    a = _net([("y", 0, 1), ("u", 0, 1), ("u", 1, 3), ("y", 0, 2)])
    b = _net([("u", 1, 2), ("y", 0, 3), ("u", 0, 5)], linear="own", seed=1, scale=3.0)
    c = _net([("y", 0, 1), ("u", 0, 2)], linear="long", seed=2, scale=1.0)
    d = _net([("y", 0, 1), ("u", 0, 0), ("u", 1, 1)], linear="own", seed=3)  # u0(t): a direct term
    rng = np.random.default_rng(5)
    u, y = rng.uniform(-1.5, 1.5, (600, 2)), rng.uniform(-1.0, 1.0, 600)
    u[:, 0] *= 1.5  # input 0's range is -2 .. 2 (-1 .. 1 for c): sometimes beyond
    u[:, 1] += 0.9  # input 1's range is -1 .. 3: inside
    models = [replace(m, interval=INTERVAL) for m in (a, b, c, d)]
    models += [replace(ensemble_of([a, b, c], combine=k), interval=INTERVAL) for k in ("mean", "median")]
    models.append(replace(ensemble_of([a, d]), interval=INTERVAL))
    models.append(replace(_net([("u", 0, 0), ("u", 1, 0)], linear="own", seed=4), interval=INTERVAL))  # max_lag 0
    for model in models:
        _, steps = _stepped(model, u, y, 50, 400)
        flags = _check_equal_to_simulate(model, u, y, 50, steps)
        assert flags.any() and not flags.all(), model
    assert has_direct_terms(models[3]) and has_direct_terms(models[-1])


def test_a_direct_term_reads_the_input_of_its_own_instant_and_others_from_the_next() -> None:
    plain = replace(_net([("y", 0, 1), ("u", 0, 1), ("u", 1, 2)]), interval=INTERVAL)
    direct = replace(_net([("y", 0, 1), ("u", 0, 0), ("u", 1, 1)], linear="own", seed=3), interval=INTERVAL)
    rng = np.random.default_rng(2)
    u, y = rng.uniform(-1.0, 1.0, (40, 2)), rng.uniform(-1.0, 1.0, 40)
    for model, moves in ((plain, False), (direct, True)):
        p, q = _stepped(model, u, y, 20, 20)[0], _stepped(model, u, y, 20, 20)[0]
        first_p, first_q = p.step(u[20]), q.step(u[20] + 0.5)
        assert (first_p.y != first_q.y) is moves
        assert p.step(u[21]).y != q.step(u[21]).y  # the first input matters from the next instant on anyway


def test_a_measurement_restarts_the_run_and_steps_never_touch_the_measured_samples(
        damper: tuple[list[Model], np.ndarray, np.ndarray]) -> None:
    nets, u, y = damper
    model = replace(ensemble_of(nets, combine="median"), interval=nets[0].interval)
    p, _ = _stepped(model, u, y, 200, 260)
    one_step = Predictor(model)
    for t in range(200):
        one_step.learn_one(u[t], y[t])
    assert p.predict_one() == one_step.predict_one()  # the measured samples are those learnt, not the run's
    p.learn_one(u[200], y[200])  # the sensor's sample of instant 200: the run starts again from it
    assert p.stepped == 0
    steps = [p.step(u[t]) for t in range(201, 300)]
    assert p.stepped == 99
    _check_equal_to_simulate(model, u, y, 201, steps)


def test_a_swap_restarts_the_run_from_the_measured_samples(damper: tuple[list[Model], np.ndarray, np.ndarray]) -> None:
    nets, u, y = damper
    p, _ = _stepped(nets[0], u, y, 200, 250)
    new = replace(ensemble_of(nets), interval=nets[0].interval)
    p.swap(new)
    assert p.stepped == 0
    steps = [p.step(u[t]) for t in range(200, 320)]
    _check_equal_to_simulate(new, u, y, 200, steps)  # from the samples measured before 200, not the old run's
    p.reset()
    with pytest.raises(DataError, match=f"needs the newest {new.max_lag} samples"):
        p.step(u[320])


def test_without_an_interval_the_band_is_none_and_the_output_the_same(
        damper: tuple[list[Model], np.ndarray, np.ndarray]) -> None:
    nets, u, y = damper
    bare = replace(nets[0], interval=None)
    _, steps = _stepped(bare, u, y, 100, 160)
    _, none_asked = _stepped(nets[0], u, y, 100, 160, level=None)
    _, banded = _stepped(nets[0], u, y, 100, 160, level=0.5)
    want = bare.simulate(u[100 - bare.max_lag : 160], y[100 - bare.max_lag : 100])[bare.max_lag :]
    for run in (steps, none_asked):
        assert all(s.lower is None and s.upper is None for s in run)
        np.testing.assert_allclose([s.y for s in run], want, rtol=1e-9, atol=1e-12 * bare.normalisation.y_half_range)
    assert [s.y for s in banded] == [s.y for s in none_asked]
    assert all(s.lower is not None and s.upper is not None and s.lower < s.y < s.upper for s in banded)
    with pytest.raises(FrozenInstanceError):
        steps[0].y = 0.0  # type: ignore[misc]


def test_bad_calls_are_refused_naming_the_value_and_change_nothing() -> None:
    model = replace(_net([("y", 0, 1), ("u", 0, 1), ("u", 1, 3), ("y", 0, 2)]), interval=INTERVAL)
    rng = np.random.default_rng(9)
    u, y = rng.uniform(-1.0, 1.0, (80, 2)), rng.uniform(-1.0, 1.0, 80)
    p = Predictor(model)
    p.learn_one(u[0], y[0])
    with pytest.raises(DataError, match="needs the newest 3 samples .* 1 held"):
        p.step(u[1])
    for t in range(1, 10):
        p.learn_one(u[t], y[t])
    first = [p.step(u[t]) for t in range(10, 15)]
    bad = [([np.nan, 0.0], r"u must contain only finite numbers \(no NaN or inf\); got nan"),
           ([0.0, np.inf], r"u must contain only finite numbers \(no NaN or inf\); got inf"),
           (0.5, r"u must be a sequence of 2 numbers \(one per input\); got shape \(\)"),
           ([[0.0, 1.0]], r"u must be a sequence of 2 numbers \(one per input\); got shape \(1, 2\)"),
           ("fast", "u must be numbers; got 'fast'")]
    for value, msg in bad:
        with pytest.raises(DataError, match=msg):
            p.step(value)
    for level, msg in ((0.77, r"interval level must be one of 0.5, 0.8, 0.9, 0.95, 0.99 .*; got 0.77"),
                       ("90%", r"interval must be a number, one of 0.5, .* or None; got '90%'")):
        with pytest.raises(DataError, match=msg):
            p.step(u[15], interval=level)  # type: ignore[arg-type]
    assert p.stepped == 5
    rest = [p.step(u[t]) for t in range(15, 60)]  # the refused calls took no instant
    _check_equal_to_simulate(model, u, y, 10, first + rest)


def test_the_run_is_bounded_however_long_it_steps(damper: tuple[list[Model], np.ndarray, np.ndarray]) -> None:
    nets, u, y = damper
    model = replace(ensemble_of(nets), interval=nets[0].interval)
    L = model.max_lag
    p, steps = _stepped(model, u, y, 50, u.shape[0])  # 1,150 instants: the rings of 2 (max_lag + 1) rows wrap often
    run = p._run  # noqa: SLF001 - the bound is the point
    assert run is not None and run._un.shape[0] == run._ynk.shape[1] == 2 * (L + 1)  # noqa: SLF001
    _check_equal_to_simulate(model, u, y, 50, steps)


def test_one_values_domain_tests_are_the_records() -> None:
    """The step judges one sample at a time (domain.value_excess / value_outside): the same numbers as the record's
    (signal_excess / signal_outside, behind excess, outside and the band), edges, non-finite values and a zero
    span included."""
    x = np.array([-3.0, -2.0 - 5e-9, -2.0 - 3e-9, -2.0, 0.0, 2.0, 2.0 + 3e-9, 2.0 + 5e-9, 7.5, np.nan, np.inf, -np.inf,
                  1e308, -1e308])
    for lo, hi in ((-2.0, 2.0), (1.0, 1.0), (-1e-60, 1e-60)):
        ex, out = signal_excess(x, lo, hi), signal_outside(x, lo, hi)
        assert [value_excess(float(v), lo, hi) for v in x] == ex.tolist()
        assert [value_outside(float(v), lo, hi) for v in x] == out.tolist()
    assert signal_outside(x, -2.0, 2.0).tolist()[1:8] == [True, False, False, False, False, False, True]
