"""Long records offline (issue 53): the correlation tests streamed chunk by chunk equal the whole-record ones, and an
identification beyond one chunk searches on the online rule's stratified sample (a small chunk constant patched)."""

from __future__ import annotations

import numpy as np
import pytest

import streamid.engine.search.rows as rows
import streamid.engine.correlation as correlation
from streamid.engine import identify
from streamid.engine.settings import DEFAULT
from streamid.engine.correlation import ccf, correlation_tests, streamed_ccf


def _whole(e: np.ndarray, u: np.ndarray, L: int) -> list[np.ndarray]:
    """The five tests' values by the whole-record ccf (the computation before streaming)."""
    n = e.size
    pos, nonneg, both = np.arange(1, L + 1), np.arange(0, L + 1), np.arange(-L, L + 1)
    eu = np.zeros(n)
    eu[:-1] = e[1:] * u[1:]
    u2 = u**2 - u.mean() ** 2
    return [ccf(e, e, pos), ccf(u, e, both), ccf(e[:-1], eu[:-1], nonneg), ccf(u2, e, both), ccf(u2, e**2, both)]


@pytest.mark.parametrize("chunk", [7, 64, 333, 10_000])
def test_streamed_ccf_is_the_whole_record_ccf(chunk: int) -> None:
    g = np.random.default_rng(3)
    n = 1000
    a = g.normal(size=n).cumsum() * 0.1 + g.normal(size=n)
    b = np.roll(a, 5) + 0.5 * g.normal(size=n) + 3.0
    lags = np.arange(-25, 26)
    got = streamed_ccf(lambda s, e: a[s:e], lambda s, e: b[s:e], n, lags, chunk)
    np.testing.assert_allclose(got, ccf(a, b, lags), rtol=1e-12, atol=1e-14)
    assert abs(got[lags == 5][0]) > 0.5  # the shift is found (a test that can fail)


def test_correlation_tests_over_several_chunks_equal_the_whole_record(monkeypatch: pytest.MonkeyPatch) -> None:
    g = np.random.default_rng(5)
    n, L = 2_000, 20
    u = g.uniform(-1, 1, n)
    e = 0.3 * np.roll(u, 2) ** 2 + 0.1 * g.normal(size=n)  # a residual the tests should flag
    want = _whole(e, u, L)
    monkeypatch.setattr(correlation, "CHUNK_ROWS", 300)  # seven chunks, the last partial
    rep = correlation_tests(e, u, L)
    assert [t.name for t in rep.tests] == ["ee", "ue", "e_eu", "u2_e", "u2_e2"]
    for t, w in zip(rep.tests, want):
        np.testing.assert_allclose(np.asarray(t.values), w, rtol=1e-12, atol=1e-14)
    assert not rep.passed


def test_one_chunk_or_less_keeps_the_old_sample_and_beyond_it_the_online_rule(monkeypatch: pytest.MonkeyPatch) -> None:
    cfg = DEFAULT
    g = np.random.default_rng(0)
    assert rows.long_record_rows(rows.CHUNK_ROWS, cfg, 1, g) is None  # one chunk: as before (hash-identical)
    assert rows.long_record_rows(10 * rows.CHUNK_ROWS, cfg.replace(search_rows=0), 1, g) is None  # every row, asked
    s = rows.long_record_rows(10 * rows.CHUNK_ROWS, cfg, 1, g)
    assert s is not None
    bound = rows.search_row_bound(cfg.neurons, cfg.max_lag_y, cfg.max_lag_u, 1, {})
    assert s.rows.size == bound == max(rows.SEARCH_ROWS, rows.ROWS_PER_WEIGHT * (cfg.neurons + cfg.max_lag_y + cfg.max_lag_u + 1))
    assert np.all(np.diff(s.rows) > 0) and s.rows[-1] < 10 * rows.CHUNK_ROWS


def test_an_identification_beyond_one_chunk_searches_on_the_stratified_sample(monkeypatch: pytest.MonkeyPatch) -> None:
    from benchmarks.long_records import reactor_record

    u, y = reactor_record(1_500, "uniform", 41)
    monkeypatch.setattr(rows, "CHUNK_ROWS", 600)  # the record is more than two chunks
    monkeypatch.setattr(rows, "SEARCH_ROWS", 300)
    monkeypatch.setattr(rows, "ROWS_PER_WEIGHT", 2)
    cfg = DEFAULT.replace(restarts=1, more_restarts=0, generations=5, lag_search_neurons=0, neurons=8,
                          max_lag_cap=0, max_lag_y=3, max_lag_u=3, fallback_neurons=(), search_rows=300, prune_runs=0,
                          run_ensembles=False, long_linear=0, refine_iterations=0)
    res = identify(u, y, cfg, 0)
    ev = res.model.metrics["search_rows"]
    assert ev == {"rows": 300, "of": 1_500 - 3, "bound": 300, "sampling": "stratified"}
    assert res.model.metrics["free_run_choice"].get("screened_on_rows") == 300 or \
        "screened_on_rows" not in res.model.metrics["free_run_choice"]  # screened, or the full way when refit failed
