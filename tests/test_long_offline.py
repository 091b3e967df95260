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


def test_one_chunk_or_less_keeps_the_old_sample_and_beyond_it_the_online_rule() -> None:
    cfg = DEFAULT
    g = np.random.default_rng(0)
    assert rows.long_record_rows(rows.CHUNK_ROWS, cfg, 1, g) is None  # one chunk: as before (hash-identical)
    assert rows.long_record_rows(10 * rows.CHUNK_ROWS, cfg.replace(search_rows=0), 1, g) is None  # every row, asked
    bound = rows.search_row_bound(cfg.neurons, cfg.max_lag_y, cfg.max_lag_u, 1, {})
    assert bound == max(rows.SEARCH_ROWS, rows.ROWS_PER_WEIGHT * (cfg.neurons + cfg.max_lag_y + cfg.max_lag_u + 1))
    for n in (rows.CHUNK_ROWS + 1, 10 * rows.CHUNK_ROWS, 150 * rows.CHUNK_ROWS):  # the search's cost: not the record's
        s = rows.long_record_rows(n, cfg, 1, g)
        assert s is not None and s.rows.size == s.bound == bound and s.of == n
        assert np.all(np.diff(s.rows) > 0) and s.rows[-1] < n
        strata = (np.arange(bound + 1) * n) // bound  # one row in each stratum
        assert np.array_equal(np.searchsorted(strata, s.rows, side="right") - 1, np.arange(bound))


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


# --- beyond one chunk: free runs on contiguous segments (refinement, the candidates' screen) -------------------------

def _plant(n: int = 600, seed: int = 3) -> tuple[np.ndarray, np.ndarray]:
    """A nonlinear plant with output feedback (its free run differs from its one-step prediction)."""
    g = np.random.default_rng(seed)
    u = g.uniform(-1, 1, n)
    y = np.zeros(n)
    for t in range(2, n):
        y[t] = 0.7 * y[t - 1] - 0.2 * y[t - 2] + np.tanh(1.5 * u[t - 1]) + 0.3 * u[t - 2] ** 2
    return u, y + g.normal(0, 0.02, n)


def _osa_net(u: np.ndarray, y: np.ndarray, lags: tuple[tuple[str, int], ...], m: int, seed: int) -> "Model":
    """A network with random centres and widths, its weights the one-step least squares (as the search's)."""
    from dataclasses import replace

    from streamid.model.narx import Model
    from streamid.model.regressors import Normalisation, Regressor

    regs = tuple(Regressor(s, 0, lag) for s, lag in lags)
    g = np.random.default_rng(seed)
    net = Model(regressors=regs, centres=g.uniform(-1, 1, (m, len(regs))), widths=g.uniform(0.4, 1.2, m),
                weights=np.zeros(m), normalisation=Normalisation((-1.0,), (1.0,), -3.0, 3.0))
    r, target = net.regressor_rows(u[:, None], y)
    return replace(net, weights=np.linalg.lstsq(net._phi(r), target, rcond=None)[0])


def test_segments_are_none_within_one_chunk_and_evenly_spaced_beyond(monkeypatch: pytest.MonkeyPatch) -> None:
    from streamid.engine.choice import scores

    monkeypatch.setattr(scores, "CHUNK_ROWS", 1000)
    monkeypatch.setattr(scores, "SEGMENT_ROWS", 400)  # 8 segments of 50 scored rows
    assert scores.segments(0, 1003, 3) is None  # one chunk of rows after the first L: one free run, as always
    parts = scores.segments(0, 10_000, 3)
    assert parts is not None and len(parts) == scores.SEGMENTS == 8
    assert parts[0][0] == 0 and parts[-1][1] == 10_000
    assert all(b - a == 3 + 50 for a, b in parts) and all(b <= a2 for (_, b), (a2, _) in zip(parts, parts[1:]))
    assert scores.segments(4_000, 10_000, 3)[0][0] == 4_000  # type: ignore[index]


def test_refinement_on_segments_that_repeat_one_record_is_that_record_s_refinement() -> None:
    """Four copies of one record, each copy a segment: every free run, Jacobian and error is four times one copy's,
    so the refinement is the one made on one copy (a test of the segments' bookkeeping: a piece started from the
    wrong outputs, or rows scored twice or not at all, would not give it)."""
    from streamid.engine.choice.refine import refine_weights
    from streamid.model.ensemble import ensemble_of, members_of

    u, y = _plant()
    net = _osa_net(u, y, (("y", 1), ("y", 2), ("u", 1), ("u", 2)), 7, 2)
    ens = ensemble_of([_osa_net(u, y, (("y", 1), ("y", 2), ("u", 1)), 6, 3), _osa_net(u, y, (("y", 1), ("u", 1)), 5, 4)])
    n, k = len(y), 4
    U, Y = np.tile(u, k)[:, None], np.tile(y, k)
    for model in (net, ens):
        want, ev_want = refine_weights(model, u[:, None], y, 10, 0.0, 0.25)
        got, ev = refine_weights(model, U, Y, 10, 0.0, 0.25, segments=[(i * n, (i + 1) * n) for i in range(k)])
        assert ev_want["taken"] is True and ev["taken"] is True and ev["iterations"] == ev_want["iterations"] >= 2
        assert ev["segments"] == {"count": k, "rows": k * n, "of": k * n}
        assert ev["r2_fr_est_after"] == pytest.approx(ev_want["r2_fr_est_after"], abs=1e-9)
        for a, b in zip(members_of(got), members_of(want)):
            np.testing.assert_allclose(a.weights, b.weights, rtol=1e-7, atol=1e-10)


def test_a_refinement_beyond_one_chunk_is_made_and_judged_on_segments(monkeypatch: pytest.MonkeyPatch) -> None:
    from streamid.engine.choice import scores
    from streamid.engine.choice.refine import refine_judged

    u, y = _plant(4_000, seed=5)
    net = _osa_net(u, y, (("y", 1), ("y", 2), ("u", 1), ("u", 2)), 7, 2)
    monkeypatch.setattr(scores, "CHUNK_ROWS", 500)
    monkeypatch.setattr(scores, "SEGMENT_ROWS", 800)  # 8 segments of 100 scored rows: 800 of 4,000
    kept: dict[str, object] = {}
    out, ev = refine_judged(net, u[:, None], y, 10, 0.0, 0.25, keep_osa=kept)
    assert ev["held_out"]["segments"] == 8 and ev["held_out"]["samples"] == 2_000
    assert ev["taken"] is True and ev["segments"] == {"count": 8, "rows": 8 * 102, "of": 4_000}
    assert out is not net and ev["r2_fr_est_after"] > ev["r2_fr_est_before"]
    # the refined model's one-step predictions over the whole record, kept for the validation (made once)
    pred = out.predict_osa(u[:, None], y)
    assert kept["of"] is out and np.array_equal(kept["osa"], pred)  # type: ignore[arg-type]
    assert ev["osa_mse_est"] == float(np.mean((pred[out.max_lag:] - y[out.max_lag:]) ** 2))


def test_segment_scores_on_one_segment_are_the_free_run_scores() -> None:
    from streamid.engine.choice.scores import free_run_scores, segment_scores

    u, y = _plant(800, seed=7)
    nets = [_osa_net(u, y, (("y", 1), ("y", 2), ("u", 1), ("u", 2)), 6, s) for s in (1, 2, 3)]
    nets.append(_osa_net(u, y, (("y", 1), ("y", 2)), 4, 9))  # no input term: never admissible
    want = free_run_scores(nets, u[:, None], y)
    got = segment_scores(nets, u[:, None], y, [(0, len(y))])
    assert got.excursions == pytest.approx(want.excursions) and want.admissible >= 1
    np.testing.assert_allclose(got.scores, want.scores, rtol=1e-10)
    assert got.scores[-1] == -np.inf
    two = segment_scores(nets, u[:, None], y, [(0, 400), (400, 800)])  # two free runs: rows 400-401 given, not scored
    assert two.admissible == want.admissible and two.scores != got.scores


def test_the_direct_term_test_beyond_one_chunk_fits_on_evenly_spaced_rows(monkeypatch: pytest.MonkeyPatch) -> None:
    from streamid.engine.search.feedthrough import feedthrough_test

    g = np.random.default_rng(11)
    n = 6_000
    u = g.uniform(-1, 1, n)
    y_direct, y_lagged = np.zeros(n), np.zeros(n)
    for t in range(1, n):
        y_direct[t] = 0.5 * y_direct[t - 1] + u[t] + 0.3 * u[t - 1]
        y_lagged[t] = 0.5 * y_lagged[t - 1] + u[t - 1]
    y_direct += 0.05 * g.normal(size=n)
    y_lagged += 0.05 * g.normal(size=n)
    whole = [feedthrough_test(u[:, None], y, 3) for y in (y_direct, y_lagged)]
    monkeypatch.setattr(rows, "CHUNK_ROWS", 700)  # 5,997 rows: 700 evenly spaced
    assert rows.spaced_rows(699) is None and np.array_equal(rows.spaced_rows(1400), np.arange(0, 1400, 2))
    spaced = [feedthrough_test(u[:, None], y, 3) for y in (y_direct, y_lagged)]
    assert [w["min_lag_u"] for w in whole] == [s["min_lag_u"] for s in spaced] == [0, 1]
    assert spaced[0]["lr"][0] < whole[0]["lr"][0]  # n in LR is the rows fitted: fewer, a smaller statistic


def test_a_refit_beyond_one_chunk_is_streamed_and_the_same_least_squares(monkeypatch: pytest.MonkeyPatch) -> None:
    from dataclasses import replace

    import streamid.engine.choice.selection as selection

    u, y = _plant(3_000, seed=13)
    net = _osa_net(u, y, (("y", 1), ("y", 2), ("u", 1), ("u", 2)), 6, 4)
    lin = replace(net, linear=np.zeros(5))
    want = [selection.refit_weights(m, u, y, 1e-8) for m in (net, lin)]
    monkeypatch.setattr(selection, "CHUNK_ROWS", 500)
    calls: list[int] = []
    real = selection.fit_in_blocks
    monkeypatch.setattr(selection, "fit_in_blocks", lambda *a, **k: calls.append(1) or real(*a, **k))
    got = [selection.refit_weights(m, u, y, 1e-8) for m in (net, lin)]
    assert len(calls) == 2  # both streamed
    for g, w in zip(got, want):
        np.testing.assert_allclose(g.weights, w.weights, rtol=1e-8, atol=1e-10)
        assert g.metrics["fitness"] == pytest.approx(w.metrics["fitness"], rel=1e-9)
    np.testing.assert_allclose(got[1].linear, want[1].linear, rtol=1e-8, atol=1e-10)


def test_a_candidate_fitted_on_given_rows_is_model_for_s_fit_on_those_rows() -> None:
    from benchmarks.long_records import reactor_record
    from streamid.engine.search.coevolution import Coevolution

    u, y = reactor_record(900, "uniform", 41)
    cfg = DEFAULT.replace(restarts=1, generations=4, lag_search_neurons=0, neurons=6, max_lag_cap=0, max_lag_y=2,
                          max_lag_u=2, search_rows=200)
    run = Coevolution(u[:, None], y, cfg, 0, rows=np.sort(np.random.default_rng(1).choice(898, 200, replace=False)))
    run.solve()
    h, x = run.candidate_pairs(None)[0]
    every = run.model_for(h, x)
    same = run.model_on_rows(h, x, np.arange(len(run.target)))
    np.testing.assert_allclose(same.weights, every.weights, rtol=1e-9, atol=1e-12)
    half = run.model_on_rows(h, x, np.arange(0, len(run.target), 2))
    assert not np.allclose(half.weights, every.weights, rtol=1e-9)  # other rows, another least squares
    assert half.centres.tolist() == every.centres.tolist() and half.lags == every.lags


def test_a_refit_on_samples_is_the_least_squares_of_those_rows_and_the_calibration_uses_it(
        monkeypatch: pytest.MonkeyPatch) -> None:
    """``refit_weights(..., samples)``: every sample is the full refit (networks with and without a linear part,
    and their ensemble, whose fitness is then the mean's one-step error there); half of them another fit. Beyond
    one chunk the interval's calibration refits its half-model on that many evenly spaced samples and says so."""
    from dataclasses import replace

    import streamid.engine.choice.calibration as calibration
    import streamid.engine.choice.selection as selection
    from streamid.model.ensemble import ensemble_of

    u, y = _plant(3_000, seed=13)
    net = _osa_net(u, y, (("y", 1), ("y", 2), ("u", 1), ("u", 2)), 6, 4)
    lin = replace(_osa_net(u, y, (("y", 1), ("u", 1), ("u", 3)), 5, 5), linear=np.zeros(4))
    ens = ensemble_of([net, lin])
    for m in (net, lin, ens):
        L = m.max_lag
        got = selection.refit_weights(m, u, y, 1e-8, np.arange(L, len(y)))
        # each member on the rows t >= L (the ensemble's), i.e. its own full refit of the record from L - its lag
        want = [selection.refit_weights(k, u[L - k.max_lag:], y[L - k.max_lag:], 1e-8) for k in
                getattr(m, "members", (m,))]
        for a, b in zip(getattr(got, "members", (got,)), want):
            np.testing.assert_allclose(a.weights, b.weights, rtol=1e-8, atol=1e-10)
            if b.linear is not None:
                np.testing.assert_allclose(a.linear, b.linear, rtol=1e-8, atol=1e-10)
        mean = ensemble_of(want) if len(want) > 1 else want[0]
        fitness = float(np.mean((mean.predict_osa(u, y)[L:] - y[L:]) ** 2))
        assert got.metrics["fitness"] == pytest.approx(fitness, rel=1e-9)
        half = selection.refit_weights(m, u, y, 1e-8, np.arange(L, len(y), 2))
        assert not np.allclose(getattr(half, "members", (half,))[0].weights, want[0].weights, rtol=1e-6)
    with pytest.raises(Exception, match="at least neurons"):
        selection.refit_weights(net, u, y, 1e-8, np.arange(2, 5))
    whole, ev = calibration.calibrate(ens, u, y, 1e-8)
    assert whole is not None and "fit_rows" not in ev  # one chunk: every row of the first half, as always
    monkeypatch.setattr(rows, "CHUNK_ROWS", 400)  # the first half (1,500 samples) is beyond one chunk
    spaced, ev = calibration.calibrate(ens, u, y, 1e-8)
    assert spaced is not None and ev["fit_rows"] == 400 and ev["held_out"] is True
    assert spaced.scale != whole.scale  # another fit (a test that can fail), of the same order
    assert 0.5 < spaced.scale / whole.scale < 2.0


def test_an_ensemble_s_one_step_prediction_beyond_one_chunk_is_made_a_chunk_at_a_time(
        monkeypatch: pytest.MonkeyPatch) -> None:
    import streamid.model.ensemble as ensemble
    from streamid.model.ensemble import ensemble_of

    u, y = _plant(3_000, seed=13)
    ens = ensemble_of([_osa_net(u, y, (("y", 1), ("y", 2), ("u", 1), ("u", 2)), 6, 4),
                       _osa_net(u, y, (("y", 1), ("u", 1), ("u", 3)), 5, 5)])
    want = ens.predict_osa(u, y)
    monkeypatch.setattr(ensemble, "CHUNK_ROWS", 700)  # five chunks, the last partial
    seen: list[int] = []
    real = type(ens.members[0]).predict_osa
    monkeypatch.setattr(type(ens.members[0]), "predict_osa",
                        lambda self, uu, yy, threads=1: seen.append(len(yy)) or real(self, uu, yy, threads))
    for threads in (1, 2):
        np.testing.assert_allclose(ens.predict_osa(u, y, threads=threads), want, rtol=1e-12, atol=1e-12)
    assert max(seen) <= 700 + ens.max_lag and len(seen) == 2 * 2 * 5  # members x thread counts x chunks


def test_a_record_judged_a_chunk_at_a_time_gives_the_whole_record_s_report(monkeypatch: pytest.MonkeyPatch) -> None:
    """``assess`` beyond one chunk: the free run cut in pieces is the whole one to the bit (each network carries its
    last outputs), the figures the whole record's to rounding (sums added piece by piece), the band's coverage and
    width the same, the domain's excess reading back across a piece's start; ``keep=False`` holds no prediction."""
    from dataclasses import replace

    import streamid.engine.validation as validation
    from streamid.model.ensemble import ensemble_of
    from streamid.model.freerun import chunked_paths
    from streamid.model.uncertainty import BEYOND, LEVELS, Interval

    u, y = _plant(5_000, seed=13)
    ens = ensemble_of([_osa_net(u, y, (("y", 1), ("y", 2), ("u", 1), ("u", 2)), 6, 4),
                       _osa_net(u, y, (("y", 1), ("u", 1), ("u", 3)), 5, 5)])
    ens = replace(ens, interval=Interval(LEVELS, (0.5, 1.0, 1.5, 2.0, 3.0), 0.02, 100, beyond=BEYOND))
    uu = u.copy()
    uu[2_780:2_820] *= 1.6  # leaves the estimation range across a piece's start (2,800 below): the band grows
    whole = validation.assess(ens, uu, y)
    pieces = list(chunked_paths(ens, uu[:, None], y, 700))
    assert [a for a, _ in pieces] == list(range(0, 5_000, 700))
    assert np.array_equal(np.concatenate([p for _, p in pieces], axis=1), ens.member_paths(uu, y[:3]))
    monkeypatch.setattr(validation, "CHUNK_ROWS", 700)  # eight pieces, the last partial
    cut = validation.assess(ens, uu, y)
    assert np.array_equal(cut.predictions["fr"], whole.predictions["fr"])
    np.testing.assert_allclose(cut.predictions["osa"], whole.predictions["osa"], rtol=1e-13, atol=1e-13)
    for k in ("osa", "fr", "rmse_osa", "rmse_fr", "outside_domain"):
        assert getattr(cut, k) == pytest.approx(getattr(whole, k), rel=1e-12), k
    assert cut.interval is not None and whole.interval is not None and 0.0 < whole.outside_domain
    assert cut.interval["coverage"] == whole.interval["coverage"]
    assert cut.interval["width"] == pytest.approx(whole.interval["width"], rel=1e-12)
    for t, w in zip(cut.correlation.tests, whole.correlation.tests):
        np.testing.assert_allclose(t.values, w.values, rtol=1e-9, atol=1e-12)
    bare = validation.assess(ens, uu, y, keep=False)
    assert bare.predictions == {} and bare.to_dict() == cut.to_dict()


def _beyond_one_chunk(monkeypatch: pytest.MonkeyPatch) -> None:
    """Every step's own chunk threshold and the search's sample made small, so that a 1,500-sample record is beyond
    one chunk for all of them (600 rows; segments of 400; a 300-row search sample)."""
    import importlib

    for name in ("streamid.engine.search.rows", "streamid.engine.choice.scores", "streamid.engine.choice.selection",
                 "streamid.engine.choice.calibration", "streamid.engine.identification", "streamid.engine.validation",
                 "streamid.model.ensemble"):
        monkeypatch.setattr(importlib.import_module(name), "CHUNK_ROWS", 600)
    monkeypatch.setattr(importlib.import_module("streamid.engine.choice.scores"), "SEGMENT_ROWS", 400)  # 8 x 50
    monkeypatch.setattr(rows, "SEARCH_ROWS", 300)
    monkeypatch.setattr(rows, "ROWS_PER_WEIGHT", 2)


def test_identify_and_assess_never_write_the_caller_s_arrays(monkeypatch: pytest.MonkeyPatch) -> None:
    """A long record is read, not copied (``as_data(copy=False)``): so every step must only read it. Read-only
    arrays through the whole of an identification beyond one chunk (search sample, screen, pruning, ensembles,
    refinement, interval) and through a report raise on any write."""
    from benchmarks.long_records import reactor_record
    from streamid.engine.validation import assess

    u, y = reactor_record(1_500, "uniform", 41)
    u.flags.writeable = False
    y.flags.writeable = False
    _beyond_one_chunk(monkeypatch)
    cfg = DEFAULT.replace(restarts=2, more_restarts=0, generations=4, lag_search_neurons=4, neurons=6,
                          max_lag_cap=0, max_lag_y=3, max_lag_u=3, search_rows=300)
    res = identify(u, y, cfg, 0)
    rep = assess(res.model, u, y)
    assert rep.fr is not None and res.model.interval is not None


def test_ensembles_beyond_one_chunk_are_scored_a_chunk_at_a_time_as_their_whole_mean(
        monkeypatch: pytest.MonkeyPatch) -> None:
    """Beyond one chunk the runs keep no free run; the ensembles offered are scored in one pass a chunk at a time
    (``ensemble_choice._chunked_scores``): the score and range guard of the whole mean path, to rounding."""
    import streamid.engine.choice.ensemble_choice as ensemble_choice
    from streamid.engine.choice.scores import path_score

    u, y = _plant(5_000, seed=13)
    nets = [_osa_net(u, y, (("y", 1), ("y", 2), ("u", 1), ("u", 2)), 6, 4),
            _osa_net(u, y, (("y", 1), ("u", 1), ("u", 3)), 5, 5), _osa_net(u, y, (("y", 1), ("u", 1)), 4, 6)]
    lo, hi = float(y.min()), float(y.max())
    offered = [[0, 1], [0, 1, 2], [2, 0]]
    want = []
    for m in offered:
        L = max(nets[i].max_lag for i in m)
        mean = np.mean([nets[i].simulate(u, y[: nets[i].max_lag]) for i in m], axis=0)
        want.append(path_score(mean, y, L, L, lo, hi, 0.25))
    monkeypatch.setattr(ensemble_choice, "CHUNK_ROWS", 700)  # eight pieces, the last partial
    got = ensemble_choice._chunked_scores(nets, offered, u[:, None], y, lo, hi, 0.25)
    for g, w in zip(got, want):
        assert g is not None and g[1] == w[1] == 0.0
        assert g[0] == pytest.approx(w[0], rel=1e-12, abs=1e-14)
    tight = ensemble_choice._chunked_scores(nets, offered, u[:, None], y, lo, hi, -0.45)  # a narrow range: guarded
    assert [t[1] > 0 and t[0] == -np.inf for t in tight if t is not None] == [True] * 3


def test_runs_paths_written_out_as_their_scores_stream_give_the_ensembles_the_same_scores_to_the_bit(
        monkeypatch: pytest.MonkeyPatch) -> None:
    """A run's estimation free run written out while its score is streamed (``free_run_scores(...,
    keep_paths=False, streamed_paths=True)``, what the identification keeps up to ``KEEP_PATHS_ROWS``) is the
    network's own free run from row ``max_lag`` on, and ``_chunked_scores`` reading it scores every ensemble exactly
    as when it simulates that member again (some members given, some made: the same bits)."""
    import streamid.engine.choice.ensemble_choice as ensemble_choice
    import streamid.engine.choice.scores as scores

    u, y = _plant(5_000, seed=13)
    nets = [_osa_net(u, y, (("y", 1), ("y", 2), ("u", 1), ("u", 2)), 6, 4),
            _osa_net(u, y, (("y", 1), ("u", 1), ("u", 3)), 5, 5), _osa_net(u, y, (("y", 1), ("u", 1)), 4, 6)]
    lo, hi = float(y.min()), float(y.max())
    offered = [[0, 1], [0, 1, 2], [2, 0]]
    monkeypatch.setattr(scores, "SCORE_CHUNK_ROWS", 900)  # the score's pieces other than the ensembles' (700)
    monkeypatch.setattr(ensemble_choice, "CHUNK_ROWS", 700)
    ua = u[:, None]
    paths = []
    for m in nets:
        fr = scores.free_run_scores([m], ua, y, keep_paths=False, streamed_paths=True)
        plain = scores.free_run_scores([m], ua, y, keep_paths=False)
        assert fr.scores == plain.scores and fr.excursions == plain.excursions and plain.paths == (None,)
        p = fr.paths[0]
        assert p is not None and p.shape == y.shape
        np.testing.assert_array_equal(p[m.max_lag :], m.simulate(u, y[: m.max_lag])[m.max_lag :])
        paths.append(p)
    made = ensemble_choice._chunked_scores(nets, offered, ua, y, lo, hi, 0.25)
    for given in ([paths[0], None, paths[2]], paths, [None, paths[1], None]):
        assert ensemble_choice._chunked_scores(nets, offered, ua, y, lo, hi, 0.25, given) == made


def test_the_identification_hands_its_one_step_predictions_to_the_validation_which_gives_the_same_report() -> None:
    """The kept model's one-step predictions, made once for its ``metrics.fitness`` (here a mean of two runs'), reach
    the validation (``Result.extra["osa_predictions_est"]``): the same report to the bit as predicting again; the given
    predictions are what it reads (one changed, another report); a wrong length is a one-line error naming both."""
    from streamid.engine.validation import validate
    from streamid.errors import DataError

    u, y = _plant(1_500, seed=5)
    ue, ye, uv, yv = u[:1_000], y[:1_000], u[1_000:], y[1_000:]
    cfg = DEFAULT.replace(restarts=2, more_restarts=0, generations=5, lag_search_neurons=0, neurons=6, max_lag_cap=0,
                          max_lag_y=2, max_lag_u=2, fallback_neurons=(), prune_runs=0, long_linear=0)
    res = identify(ue, ye, cfg, 1)  # seed 1: the two runs' mean is kept (two runs: no median), its fitness made last
    m, L = res.model, res.model.max_lag
    assert m.metrics["ensemble"]["members"] == [0, 1] or m.metrics["ensemble"]["members"] == [1, 0]
    osa = res.extra["osa_predictions_est"]
    assert osa.shape == ye.shape and np.array_equal(osa[L:], m.predict_osa(ue[:, None], ye)[L:])
    assert m.metrics["fitness"] == float(np.mean((osa[L:] - ye[L:]) ** 2))
    plain = validate(m, ue, ye, uv, yv, keep=False)
    given = validate(m, ue, ye, uv, yv, keep=False, osa_predictions_est=osa)
    assert given.r2_dict() == plain.r2_dict() and given.correlation_est.to_dict() == plain.correlation_est.to_dict()
    changed = osa.copy()
    changed[L + 5] += 1.0
    assert validate(m, ue, ye, uv, yv, keep=False, osa_predictions_est=changed).osa_est < plain.osa_est
    with pytest.raises(DataError, match=r"osa_predictions_est must be .* shape \(1000,\); got shape \(999,\)"):
        validate(m, ue, ye, uv, yv, osa_predictions_est=osa[1:])
    single = identify(ue, ye, cfg, 0)  # seed 0: one run's network is kept, its fitness its run's: no prediction made
    assert not hasattr(single.model, "members") and "osa_predictions_est" not in single.extra


def test_beyond_one_chunk_the_calibration_s_held_out_free_run_starts_at_the_second_half(
        monkeypatch: pytest.MonkeyPatch) -> None:
    """Up to one chunk the half-model's free run starts at the record's first measured outputs (as always); beyond
    it at the second half's own (the first half's free run is never scored: not made). A stable model forgets its
    start: the two agree after its first samples."""
    import streamid.engine.choice.calibration as calibration
    from streamid.model.ensemble import ensemble_of

    u, y = _plant(3_000, seed=13)
    ens = ensemble_of([_osa_net(u, y, (("y", 1), ("y", 2), ("u", 1), ("u", 2)), 6, 4),
                       _osa_net(u, y, (("y", 1), ("u", 1), ("u", 3)), 5, 5)])
    L, h, ua = ens.max_lag, 1_500, u[:, None]
    err0, terms0 = calibration._held_out(ens, ua, y, h, 1)
    np.testing.assert_array_equal(err0, y[h:] - ens.simulate(ua, y[:L])[h:])
    monkeypatch.setattr(calibration, "CHUNK_ROWS", 400)
    err, terms = calibration._held_out(ens, ua, y, h, 1)
    np.testing.assert_allclose(err, y[h:] - ens.simulate(ua[h - L:], y[h - L:h])[L:], rtol=0, atol=1e-12)
    assert not np.array_equal(err[:5], err0[:5])  # another start: a test that can fail
    np.testing.assert_allclose(err[200:], err0[200:], rtol=0, atol=1e-9)
    np.testing.assert_allclose(terms[200:], terms0[200:], rtol=0, atol=1e-9)


def test_beyond_one_chunk_only_long_runs_restarts_are_made_where_the_median_would_be(
        monkeypatch: pytest.MonkeyPatch) -> None:
    """The restarts past ``LONG_RUNS`` feed the median of the finished restarts, which a record beyond one chunk
    never makes: there only ``LONG_RUNS`` runs are made (the first seeds drawn, as the same config up to a chunk
    makes them), and the model says so; with ``run_ensembles`` off, with selection "fitness" (no median at any
    length), or up to one chunk, every restart is made."""
    from benchmarks.long_records import reactor_record
    import streamid.engine.identification as identification

    u, y = reactor_record(1_500, "uniform", 41)
    _beyond_one_chunk(monkeypatch)
    monkeypatch.setattr(identification, "LONG_RUNS", 2)
    cfg = DEFAULT.replace(restarts=3, more_restarts=0, generations=3, lag_search_neurons=4, neurons=6, max_lag_cap=0,
                          max_lag_y=3, max_lag_u=3, search_rows=300, fallback_neurons=())
    long = identify(u, y, cfg, 0)
    m = long.model.metrics
    assert len(long.runs) == 2 and m["restarts"] == 2 and m["restarts_max"] == 3
    assert m["restarts_made"]["runs"] == 2 and "feed the median" in m["restarts_made"]["reason"]
    assert m["complexity"]["robust"]["reason"].endswith("; 2 of the 3 restarts made (the others feed only the median)")
    every = identify(u, y, cfg.replace(run_ensembles=False), 0)  # no median anywhere: every restart is made
    assert len(every.runs) == 3 and "restarts_made" not in every.model.metrics
    assert [r.seed for r in every.runs[:2]] == [r.seed for r in long.runs]  # the same first seeds
    fitness = identify(u, y, cfg.replace(selection="fitness"), 0)  # no median at any length: every restart is made
    assert len(fitness.runs) == 3 and "restarts_made" not in fitness.model.metrics
    monkeypatch.undo()  # up to one chunk (the record's 1,500 rows): every restart is made
    monkeypatch.setattr(identification, "LONG_RUNS", 2)
    short = identify(u, y, cfg, 0)
    assert len(short.runs) == 3 and "restarts_made" not in short.model.metrics
