"""Large records fast (issue 13, item 4): candidates fitted together, the best pair counted once, the lag search on
fewer rows, fewer restarts of one configuration when they agree (an option)."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from streamid.engine import PAPER, identify
from streamid.engine.settings import DEFAULT, MORE_BELOW
from streamid.engine.search.coevolution import Coevolution
from streamid.engine.restarts import wants_more
from streamid.model.narx import Model
from streamid.errors import ConfigError
from streamid.sim import simulate_reactor


@pytest.fixture(scope="module")
def reactor() -> tuple[np.ndarray, np.ndarray]:
    _, u, y = simulate_reactor(900, 4)
    return np.asarray(u, dtype=np.float64)[:, None], np.asarray(y, dtype=np.float64)


@pytest.fixture(scope="module")
def second_stage(reactor: tuple[np.ndarray, np.ndarray]) -> Coevolution:
    u, y = reactor
    cfg = PAPER.replace(neurons=12, generations=15)
    mask = np.zeros(cfg.n_candidates(1), dtype=bool)
    mask[[0, 10, 11]] = True  # y(t-1), u(t-1), u(t-2)
    return Coevolution(u, y, cfg, 3, fixed_mask=mask).solve()


def test_models_fitted_together_are_the_models_fitted_one_by_one(second_stage: Coevolution) -> None:
    run = second_stage
    b = int(np.argmin(run.fh))
    xs = [run.X[i] for i in range(5)]
    together = run.models_for(run.H[b], xs)
    for x, m in zip(xs, together):
        one = run.model_for(run.H[b], x)
        assert m.regressors == one.regressors
        np.testing.assert_array_equal(m.centres, one.centres)
        np.testing.assert_array_equal(m.widths, one.widths)
        np.testing.assert_allclose(m.weights, one.weights, rtol=1e-7, atol=1e-9 * np.abs(one.weights).max())
        assert m.metrics["fitness"] == pytest.approx(one.metrics["fitness"], rel=1e-9)
    assert run.models_for(run.H[b], []) == []


def test_the_best_pair_is_a_candidate_once(second_stage: Coevolution) -> None:
    run = second_stage
    members = [i for i in range(run.X.shape[0]) if np.array_equal(run.X[i], run.best_x)]
    assert len(members) == 1  # DE keeps the best trial: the best pair is a member of the final population
    cands = run.candidate_models()
    assert len(cands) == run.X.shape[0]  # the best pair, then the other members (not P + 1)
    np.testing.assert_array_equal(cands[0].centres, run.model_for(run.best_h, run.best_x).centres)
    assert len({m.centres.tobytes() + m.widths.tobytes() for m in cands}) == len(cands)
    assert len(run.candidate_models(5)) == 5  # the 5 fittest include the best member: 1 + 4


def _out(score: float, neurons: int = 30, max_lag: int = 10) -> dict[str, object]:
    return {"score": score, "neurons": neurons, "max_lag": max_lag}


def test_more_runs_only_where_the_record_is_half_explained() -> None:
    cfg = PAPER.replace(more_restarts=4, selection="fr_est")
    assert MORE_BELOW == 0.95
    assert wants_more([_out(0.3), _out(0.92)], cfg)  # the heat exchanger's and the F-16's band
    assert not wants_more([_out(0.3), _out(0.97)], cfg)  # one run explains most of the record
    assert not wants_more([_out(-1e9), _out(-0.8)], cfg)  # none explains anything: the fallback runs' case
    assert not wants_more([_out(0.0)], cfg) and not wants_more([_out(0.95)], cfg)  # the band is open
    assert not wants_more([_out(0.5)], cfg.replace(more_restarts=0))  # off
    assert not wants_more([], cfg)
    assert not wants_more([_out(0.5)], cfg.replace(selection="fitness"))  # its scores are not R^2


def test_more_restarts_add_runs_after_the_same_first_ones(reactor: tuple[np.ndarray, np.ndarray],
                                                         monkeypatch: pytest.MonkeyPatch) -> None:
    u, y = reactor
    cfg = PAPER.replace(neurons=8, generations=10, lag_search_neurons=4, restarts=2,
                        selection="fr_est", more_restarts=2)
    monkeypatch.setattr("streamid.engine.restarts.MORE_BELOW", 0.5)
    plain = identify(u, y, cfg, 6)  # the reactor's runs fit above 0.5: none added
    monkeypatch.setattr("streamid.engine.restarts.MORE_BELOW", 1.0)
    seen: list[tuple[int, int]] = []
    more = identify(u, y, cfg, 6, callback=lambda p: seen.append((p.generation, p.generations)))
    assert min(r.score for r in plain.runs) > 0.5
    assert plain.model.metrics["more_restarts"] == 0 and len(plain.runs) == 2
    assert more.model.metrics["more_restarts"] == 2 and len(more.runs) == 4
    assert [r.score for r in more.runs[:2]] == [r.score for r in plain.runs]  # the same first runs, then new seeds
    assert len({r.seed for r in more.runs}) == 4
    again = identify(u, y, cfg, 6)
    assert again.model.to_json() == more.model.to_json()  # same seed, same result
    per_run = 20
    assert seen[-1] == (4 * per_run, 4 * per_run)  # the bar's total grew with the runs added
    assert all(g <= total for g, total in seen) and [g for g, _ in seen] == sorted(g for g, _ in seen)


@pytest.mark.parametrize("field, value", [("more_restarts", -1), ("more_restarts", 1.5)])
def test_more_restarts_settings_are_checked(field: str, value: object) -> None:
    with pytest.raises(ConfigError, match=f"CoEAConfig.{field} must be"):
        PAPER.replace(**{field: value})


def test_identify_cli_reports_the_runs_added(tmp_path: Path) -> None:
    rng = np.random.default_rng(5)
    u = rng.uniform(-1, 1, 800)
    y = np.zeros(800)
    for t in range(2, 800):  # half signal, half noise: the runs explain part of the record
        y[t] = 0.5 * y[t - 1] + np.tanh(2 * u[t - 1]) + 0.6 * rng.normal()
    data = tmp_path / "half.csv"
    np.savetxt(data, np.column_stack([u, y]), delimiter=",", header="volt,pos", comments="", fmt="%.17g")
    mod = tmp_path / "m.json"
    args = [sys.executable, "-m", "streamid", "identify", str(data), "--input", "volt", "--output", "pos",
            "--generations", "5", "--workers", "1", "--progress", "never"]
    p = subprocess.run(args + ["--more-restarts", "2", "--model", str(mod)], capture_output=True, text=True, timeout=120)
    assert p.returncode == 0, p.stderr
    m = Model.load(mod).metrics
    k = DEFAULT.restarts  # the CLI's
    assert m["more_restarts"] == 2 and len(m["run_scores"]) == k + 2 and 0 < max(m["run_scores"][:k]) < 0.95
    assert (f"runs made: {k} + 2 more (the best of those fit the estimation record at FR R2 "
            f"{max(m['run_scores'][:k]):.5f}, in (0, 0.95))") in p.stdout
    off = subprocess.run(args + ["--more-restarts", "0", "--model", str(mod)], capture_output=True, text=True, timeout=120)
    assert off.returncode == 0 and "runs made" not in off.stdout and Model.load(mod).metrics["more_restarts"] == 0
    bad = subprocess.run(args + ["--more-restarts", "-1"], capture_output=True, text=True, timeout=60)
    assert bad.returncode != 0 and "more_restarts must be an integer in [0, 100]; got -1" in bad.stderr
