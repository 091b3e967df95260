"""R^2 and the five correlation tests against direct implementations of the paper's formulas."""

from __future__ import annotations

import numpy as np
import pytest

from streamid.engine.validation import PASS_FRACTION, ccf, correlation_tests, r2
from streamid.errors import DataError


def _phi_direct(a: np.ndarray, b: np.ndarray, tau: int) -> float:
    """Eq. (6) of the paper written out with loops (1-based sums as printed)."""
    n = len(a)
    ma, mb = sum(a) / n, sum(b) / n
    num = 0.0
    for t in range(1, n - tau + 1):  # t = 1 .. N - tau
        num += (a[t - 1] - ma) * (b[t + tau - 1] - mb)
    den = (sum((x - ma) ** 2 for x in a) * sum((x - mb) ** 2 for x in b)) ** 0.5
    return num / den


def test_r2_formula() -> None:
    y = np.array([1.0, 2.0, 3.0, 4.0])
    yhat = np.array([1.1, 1.9, 3.2, 3.9])
    expected = 1 - (0.01 + 0.01 + 0.04 + 0.01) / 5.0
    assert r2(y, yhat) == pytest.approx(expected)
    assert r2(y, y) == 1.0
    assert r2(y, np.full(4, y.mean())) == pytest.approx(0.0)
    import warnings

    with warnings.catch_warnings():
        warnings.simplefilter("error")  # a diverged free run (finite, huge) scores -inf without a numpy warning
        assert r2(y, np.array([1.0, 2.0, 3.0, 1e300])) == -np.inf


def test_r2_errors() -> None:
    with pytest.raises(DataError, match="constant"):
        r2(np.ones(5), np.zeros(5))
    with pytest.raises(DataError, match="same length"):
        r2(np.ones(5), np.zeros(4))
    with pytest.raises(DataError, match="finite"):
        r2(np.array([1.0, np.nan, 2.0]), np.zeros(3))


def test_ccf_matches_equation_6() -> None:
    rng = np.random.default_rng(0)
    a = rng.normal(size=60)
    b = 0.5 * np.roll(a, 3) + rng.normal(size=60)
    lags = np.arange(-7, 8)
    got = ccf(a, b, lags)
    for tau, g in zip(lags, got):
        ref = _phi_direct(a, b, tau) if tau >= 0 else _phi_direct(b, a, -tau)
        assert g == pytest.approx(ref, abs=1e-12)
    assert ccf(a, a, np.array([0]))[0] == pytest.approx(1.0)
    assert ccf(a, np.ones(60), np.array([0, 1]))[0] == 0.0  # constant sequence: no correlation


def test_tests_on_white_residual_pass_and_values_match_direct() -> None:
    rng = np.random.default_rng(1)
    n = 2000
    u = rng.uniform(-1, 1, n)
    e = rng.normal(size=n)
    rep = correlation_tests(e, u, max_lag=20)
    assert rep.band == pytest.approx(1.96 / np.sqrt(n))
    assert {t.name for t in rep.tests} == {"ee", "ue", "e_eu", "u2_e", "u2_e2"}
    for t in rep.tests:
        assert t.fraction_inside >= PASS_FRACTION - 0.05  # white noise: ~5 % outside by chance
        assert t.max_abs < t.strict_band * 1.2
    ee = rep["ee"]
    assert ee.lags == tuple(range(1, 21))
    assert ee.values[4] == pytest.approx(_phi_direct(e, e, 5), abs=1e-12)
    ue = rep["ue"]
    assert ue.lags == tuple(range(-20, 21))
    assert ue.values[20 + 3] == pytest.approx(_phi_direct(u, e, 3), abs=1e-12)
    assert ue.values[20 - 3] == pytest.approx(_phi_direct(e, u, 3), abs=1e-12)
    eu = e[1:] * u[1:]  # (eu)(t) = e(t+1) u(t+1)
    assert rep["e_eu"].values[2] == pytest.approx(_phi_direct(e[:-1], eu, 2), abs=1e-12)
    u2 = u**2 - u.mean() ** 2
    assert rep["u2_e"].values[20 + 1] == pytest.approx(_phi_direct(u2, e, 1), abs=1e-12)
    assert rep["u2_e2"].values[20] == pytest.approx(_phi_direct(u2, e**2, 0), abs=1e-12)


def test_tests_detect_unmodelled_dynamics() -> None:
    rng = np.random.default_rng(2)
    n = 1000
    u = rng.uniform(-1, 1, n)
    w = rng.normal(size=n)
    e = w + 0.8 * np.roll(w, 1)  # coloured residual
    assert not correlation_tests(e, u)["ee"].passed
    e2 = rng.normal(size=n) * 0.1 + np.roll(u, 2) ** 2  # a missed input term u(t-2)^2
    rep = correlation_tests(e2, u)
    assert not rep["u2_e"].passed
    assert not rep.passed
    e3 = rng.normal(size=n) * 0.1 + 0.5 * np.roll(u, 1)  # a missed linear term
    assert not correlation_tests(e3, u)["ue"].passed


def test_miso_tests_per_input_and_dict() -> None:
    rng = np.random.default_rng(3)
    u = rng.uniform(-1, 1, (500, 2))
    rep = correlation_tests(rng.normal(size=500), u, max_lag=5, input_names=("volt", "temp"))
    names = [t.name for t in rep.tests]
    assert names == ["ee", "ue[volt]", "e_eu[volt]", "u2_e[volt]", "u2_e2[volt]", "ue[temp]", "e_eu[temp]", "u2_e[temp]", "u2_e2[temp]"]
    assert [t.name for t in correlation_tests(rng.normal(size=500), u, max_lag=5).tests][1] == "ue[u0]"
    d = rep.to_dict()
    assert set(d["tests"]) == set(names)
    t = d["tests"]["ue[temp]"]
    assert len(t["lags"]) == len(t["values"]) == 11 and isinstance(t["passed"], bool)


def test_a_failed_test_names_the_lag_the_value_and_the_band() -> None:
    rng = np.random.default_rng(2)
    n = 1000
    u = rng.uniform(-1, 1, n)
    e = rng.normal(size=n) * 0.1 + 0.5 * np.roll(u, 1)  # a missed linear term u(t-1)
    ue = correlation_tests(e, u)["ue"]
    lag, value = ue.worst()
    assert lag == 1 and value > 0.5
    assert ue.verdict() == f"ue FAIL: lag 1 value {value:.3g} outside ±{ue.strict_band:.3g} (99.9 % band)"
    assert ue.to_dict()["reason"] == ue.reason != ""
    r0 = np.random.default_rng(0)  # a white residual that passes (about one seed in four fails by chance)
    ok = correlation_tests(r0.normal(size=n), r0.uniform(-1, 1, n))["ee"]
    assert ok.passed and ok.reason == "" and ok.verdict().startswith("ee pass (")
    # a failure by the 5 % rule alone names how many lags left the 95 % band
    band = 1.96 / np.sqrt(n)
    from streamid.engine.validation import CorrelationTest

    t = CorrelationTest("ee", "φ_ee(τ) = δ(τ)", tuple(range(1, 11)), tuple([1.2 * band] * 2 + [0.0] * 8), band)
    assert not t.passed and t.reason.startswith("2 of 10 lags outside ±")


def test_correlation_test_names_are_the_documented_ones() -> None:
    from pathlib import Path

    from streamid.engine.validation import TESTS, correlation_test_name

    doc = (Path(__file__).resolve().parents[1] / "docs" / "method.md").read_text(encoding="utf-8")
    for name, (formula, _) in TESTS.items():
        assert f"`{name}`" in doc and formula in doc, name
    with pytest.raises(DataError, match="must be one of"):
        correlation_test_name("xixi")


def test_fit_percent_is_the_nrmse_fit() -> None:
    from streamid.engine.validation import fit_percent

    rng = np.random.default_rng(1)
    y = rng.normal(size=200)
    yhat = y + 0.3 * rng.normal(size=200)
    direct = 100 * (1 - np.linalg.norm(y - yhat) / np.linalg.norm(y - y.mean()))
    assert fit_percent(r2(y, yhat)) == pytest.approx(direct, abs=1e-9)
    assert fit_percent(0.99) == pytest.approx(90.0) and fit_percent(0.75) == pytest.approx(50.0)
    assert fit_percent(-3.0) == pytest.approx(-100.0) and np.isnan(fit_percent(float("nan")))
    assert fit_percent(-np.inf) != fit_percent(-np.inf)  # a diverged run: nan, not a number to rank


def _toy_model() -> object:
    from streamid.engine import CoEAConfig, identify

    rng = np.random.default_rng(0)
    u = rng.uniform(-1, 1, 700)
    y = np.zeros(700)
    for t in range(2, 700):
        y[t] = 0.6 * y[t - 1] + np.tanh(1.5 * u[t - 1])
    cfg = CoEAConfig.paper(neurons=5, generations=15, max_lag_y=2, max_lag_u=2)
    return identify(u[:400], y[:400], cfg, 0).model, u, y


def test_assess_is_validate_on_one_record() -> None:
    """The record's figures equal validate()'s validation part; its RMSE is the free run's own."""
    from streamid.engine import assess, validate

    model, u, y = _toy_model()
    full = validate(model, u[:400], y[:400], u[400:], y[400:])
    rec = assess(model, u[400:], y[400:])
    assert rec.fr == full.fr_val and rec.osa == full.osa_val and rec.n == 300  # type: ignore[attr-defined]
    assert rec.n_scored == 300 - model.max_lag  # type: ignore[attr-defined]
    assert rec.correlation.to_dict() == full.correlation_val.to_dict()
    L = model.max_lag  # type: ignore[attr-defined]
    fr = model.simulate(u[400:], y[400:400 + L])  # type: ignore[attr-defined]
    assert rec.rmse_fr == pytest.approx(float(np.sqrt(np.mean((y[400 + L:] - fr[L:]) ** 2))), rel=1e-12)
    assert np.array_equal(rec.predictions["fr"], fr)
    with pytest.raises(DataError, match=r"the model has 1 input\(s\) \['u0'\]; the data give 2"):
        assess(model, np.column_stack([u, u])[400:], y[400:])


def test_record_caveats_read_the_range_from_the_model() -> None:
    from streamid.engine.choice.caveats import record_caveats

    model, u, y = _toy_model()
    inside = record_caveats(model, 0.99, 0.9, u[400:], y[400:])
    assert inside == []
    wide = record_caveats(model, 0.99, 0.9, 2.5 * u[400:], y[400:])
    assert len(wide) == 1 and wide[0].startswith("the validation input u0 spans") and "beyond the estimation range" in wide[0]
    drifting = record_caveats(model, 0.95, -2.0, u[400:], np.cumsum(np.abs(u[400:])))
    assert any(c.startswith("a one-step predictor, not a simulator") and "pole at |z| =" in c for c in drifting), drifting

