"""An output that responds within the sample: u(t) among the candidates (CoEAConfig.direct_terms "on", min_lag_u 0),
decided by a likelihood-ratio test of the direct terms (streamid.engine.search.feedthrough) with direct_terms "test"."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from streamid.engine import DEFAULT, PAPER, CoEAConfig, identify
from streamid.engine.search.coevolution import Coevolution
from streamid.engine.search.feedthrough import THRESHOLD, feedthrough_test
from streamid.model.narx import Model
from streamid.engine.search.populations import CoEAState
from streamid.model.regressors import Normalisation, Regressor, format_lags
from streamid.engine.fit.lagmatrix import candidate_regressors, lag_matrix
from streamid.errors import ConfigError, ModelFormatError


def _plant(n: int, direct: float, seed: int, inputs: int = 1) -> tuple[np.ndarray, np.ndarray]:
    """y(t) = 0.6 y(t-1) + tanh(u_0(t-1)) + 0.4 u_last(t-2) + direct * u_last(t) + noise."""
    rng = np.random.default_rng(seed)
    u = rng.uniform(-1, 1, (n, inputs))
    y = np.zeros(n)
    for t in range(2, n):
        y[t] = 0.6 * y[t - 1] + np.tanh(u[t - 1, 0]) + 0.4 * u[t - 2, -1] + direct * u[t, -1]
    return u, y + rng.normal(0, 0.05, n)


def test_the_statistic_is_the_nested_least_squares_likelihood_ratio() -> None:
    u, y = _plant(1500, 0.5, 1)
    ev = feedthrough_test(u, y, 3)
    rows = len(y) - 3
    lagged = [y[3 - k : -k] for k in (1, 2, 3)] + [u[3 - k : -k, 0] for k in (1, 2, 3)] + [np.ones(rows)]

    def s2(cols: list[np.ndarray]) -> float:  # plain, unscaled least squares: the statistic is scale-free
        X = np.column_stack(cols)
        e = y[3:] - X @ np.linalg.lstsq(X, y[3:], rcond=None)[0]
        return float(e @ e)

    assert ev["order"] == 3 and ev["threshold"] == THRESHOLD == 10.83
    assert ev["lr"][0] == pytest.approx(rows * np.log(s2(lagged) / s2(lagged + [u[3:, 0]])), rel=1e-9)
    assert ev["lr"][0] > 100 and ev["min_lag_u"] == 0


def test_no_direct_term_keeps_the_papers_lags() -> None:
    lrs = [feedthrough_test(*_plant(1500, 0.0, seed), 5)["lr"][0] for seed in range(20)]
    assert sum(lr > THRESHOLD for lr in lrs) == 0  # chi-square(1) under no direct term: p = 0.001 each
    assert 0.2 < float(np.mean(lrs)) < 2.5  # its mean is 1
    assert feedthrough_test(*_plant(1500, 0.0, 3), 5)["min_lag_u"] == 1


def test_each_input_is_tested_and_one_direct_term_is_enough() -> None:
    u, y = _plant(2000, 0.5, 2, inputs=2)  # the direct term on the second input only
    ev = feedthrough_test(u, y, 4)
    assert ev["lr"][0] < THRESHOLD < ev["lr"][1] and ev["min_lag_u"] == 0
    assert feedthrough_test(u[:40], y[:40], 30)["order"] < 30  # a short record: a lower order it can support


def test_direct_terms_are_candidates_with_min_lag_u_0() -> None:
    regs = candidate_regressors(2, 3, 2, min_lag_u=0)
    assert [(r.signal, r.index, r.lag) for r in regs] == [("y", 0, 1), ("y", 0, 2)] + [
        ("u", i, k) for i in (0, 1) for k in (0, 1, 2, 3)]
    assert PAPER.replace(direct_terms="on", max_lag_y=2, max_lag_u=3).n_candidates(2) == len(regs) == 10
    assert PAPER.min_lag_u == 1 and PAPER.replace(direct_terms="on").min_lag_u == 0
    un, yn = np.arange(20.0).reshape(10, 2), np.arange(100.0, 110.0)
    R = lag_matrix(un, yn, 2, 3, min_lag_u=0)
    assert R.shape == (7, 10)
    assert R[0].tolist() == [102.0, 101.0, 6.0, 4.0, 2.0, 0.0, 7.0, 5.0, 3.0, 1.0]  # t = 3: u(t) is row t's own
    assert Regressor("u", 1, 0).label(("force", "volt")) == "volt(t)"
    assert format_lags("a", [1, 2], ["f"], [[0, 1, 2, 5]]) == "a(t-1,t-2) f(t..t-2,t-5)"
    with pytest.raises(ConfigError, match=r"direct_terms must be one of \['off', 'on', 'test'\]; got 'yes'"):
        PAPER.replace(direct_terms="yes")
    with pytest.raises(ConfigError, match=r"min_lag_u was retired in issue 37: use direct_terms"):
        CoEAConfig.from_dict({**PAPER.to_dict(), "min_lag_u": 0})
    with pytest.raises(ModelFormatError, match="'y' \\(index 0\\) with lag >= 1"):
        Model(regressors=(Regressor("y", 0, 0),), centres=np.zeros((1, 1)), widths=np.ones(1), weights=np.ones(1),
              normalisation=Normalisation((-1.0,), (1.0,), -1.0, 1.0))


def test_identify_tests_the_record_and_keeps_the_direct_term() -> None:
    u, y = _plant(900, 0.8, 4)
    cfg = DEFAULT.replace(generations=15, neurons=8, restarts=2, more_restarts=0)
    assert DEFAULT.direct_terms == "test" and PAPER.direct_terms == "off" and PAPER.min_lag_u == 1
    with_test = identify(u, y, cfg, 0)
    m = with_test.model
    ev = m.metrics["feedthrough"]
    assert ev["min_lag_u"] == 0 and ev["lr"][0] > THRESHOLD and ev["order"] == m.config["max_lag_u"]
    assert m.config["direct_terms"] == "on" and 0 in m.lags["u"][0]  # tested, found: the search took u(t)
    again = Model.from_json(m.to_json())
    np.testing.assert_array_equal(again.simulate(u, y[: m.max_lag]), m.simulate(u, y[: m.max_lag]))
    st = CoEAState.from_json(with_test.state.to_json())  # the state says its candidates include u(t)
    assert st.min_lag_u == 0 and json.loads(with_test.state.to_json())["min_lag_u"] == 0
    warm = identify(u, y, PAPER.replace(neurons=st.neurons, max_lag_y=st.max_lag_y, max_lag_u=st.max_lag_u,
                                        generations=3), 1, warm_start=st)  # an update warm-starts from it
    assert warm.model.config["direct_terms"] == "on"
    with pytest.raises(ConfigError, match="min_lag_u\\) must be"):
        Coevolution(u, y, PAPER.replace(neurons=st.neurons, max_lag_y=st.max_lag_y, max_lag_u=st.max_lag_u,
                                        generations=1), 0, warm_start=st)
    off = identify(u, y, cfg.replace(direct_terms="off"), 0).model
    assert "feedthrough" not in off.metrics and off.config["direct_terms"] == "off" and 0 not in off.lags["u"][0]
    assert with_test.model.metrics["selection_score"] > off.metrics["selection_score"]  # the direct term fits better


def test_identify_cli_reports_the_test_and_obeys_direct_terms(tmp_path: Path) -> None:
    u, y = _plant(900, 0.8, 4)
    data = tmp_path / "direct.csv"
    np.savetxt(data, np.column_stack([u[:, 0], y]), delimiter=",", header="volt,pos", comments="", fmt="%.17g")
    mod = tmp_path / "m.json"
    args = [sys.executable, "-m", "streamid", "identify", str(data), "--input", "volt", "--output", "pos", "--generations",
            "5", "--restarts", "2", "--more-restarts", "0", "--workers", "1",
            "--progress", "never", "--model", str(mod)]
    p = subprocess.run(args, capture_output=True, text=True, timeout=120)
    assert p.returncode == 0, p.stderr
    ev = Model.load(mod).metrics["feedthrough"]
    assert ("direct terms u(t) are candidates: the output responds within the sample (likelihood ratio of u(t) in a "
            f"linear ARX model of order {ev['order']}: volt {ev['lr'][0]:.1f}; threshold 10.83)") in p.stdout
    off = subprocess.run(args + ["--direct-terms", "off"], capture_output=True, text=True, timeout=120)
    assert off.returncode == 0 and "direct terms" not in off.stdout
    m = Model.load(mod)
    assert "feedthrough" not in m.metrics and m.config["direct_terms"] == "off" and 0 not in m.lags["u"][0]
    on = subprocess.run(args + ["--direct-terms", "on"], capture_output=True, text=True, timeout=120)
    assert on.returncode == 0 and Model.load(mod).config["direct_terms"] == "on"
    bad = subprocess.run([sys.executable, "-m", "streamid", "identify", str(data), "--input", "volt", "--output", "pos",
                          "--paper", "--direct-terms", "test"], capture_output=True, text=True, timeout=60)
    assert bad.returncode != 0 and "--direct-terms test adds u(t) to the candidate lags; --paper keeps" in bad.stderr
