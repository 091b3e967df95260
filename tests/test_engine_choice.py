"""The final choice never takes a free run that leaves the data's range; searching on a sample of rows."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from streamid.engine import PAPER, identify
from streamid.engine.choice.scores import free_run_scores
from streamid.errors import ConfigError
from streamid.sim import simulate_reactor


@pytest.fixture(scope="module")
def reactor() -> tuple[np.ndarray, np.ndarray]:
    _, u, y = simulate_reactor(600, 3)
    return np.asarray(u, dtype=np.float64)[:, None], np.asarray(y, dtype=np.float64)


@pytest.fixture(scope="module")
def good_model(reactor: tuple[np.ndarray, np.ndarray]):  # type: ignore[no-untyped-def]
    u, y = reactor
    return identify(u, y, PAPER.replace(generations=40), 1).model


def test_a_free_run_leaving_the_range_is_never_chosen(reactor, good_model) -> None:  # type: ignore[no-untyped-def]
    u, y = reactor
    wild = replace(good_model, weights=good_model.weights * 4.0)  # same structure, free run far out of range
    fr = free_run_scores([wild, good_model], u, y, range_margin=0.25)
    assert fr.excursions[0] > 0.0 and fr.scores[0] == -np.inf
    assert fr.excursions[1] == 0.0 and fr.scores[1] > 0.9
    assert fr.best() == 1 and fr.admissible == 1
    # Even when the wild model had the better score it would not be chosen: only admissible ones compete.
    ev = fr.evidence(fr.best())
    assert ev["admissible"] == 1 and ev["candidates"] == 2


def test_no_admissible_candidate_falls_back_to_the_smallest_excursion(reactor, good_model) -> None:  # type: ignore[no-untyped-def]
    u, y = reactor
    a = replace(good_model, weights=good_model.weights * 4.0)
    b = replace(good_model, weights=good_model.weights * 2.0)
    fr = free_run_scores([a, b], u, y, range_margin=0.0)
    assert fr.admissible == 0
    assert fr.best() == 1 and fr.excursions[1] < fr.excursions[0]


def test_scoring_a_tail_uses_the_simulation_from_the_start(reactor, good_model) -> None:  # type: ignore[no-untyped-def]
    u, y = reactor
    whole = free_run_scores([good_model], u, y).scores[0]
    tail = free_run_scores([good_model], u, y, score_from=450).scores[0]
    sim = good_model.simulate(u, y[: good_model.max_lag])
    expect = 1 - np.sum((y[450:] - sim[450:]) ** 2) / np.sum((y[450:] - y[450:].mean()) ** 2)
    assert tail == pytest.approx(expect, rel=1e-9, abs=1e-12)
    assert whole != tail


def test_search_on_a_sample_of_rows_is_seeded_and_refits_on_all(reactor) -> None:  # type: ignore[no-untyped-def]
    u, y = reactor
    cfg = PAPER.replace(neurons=8, generations=20, lag_search_neurons=5, restarts=2,
                        selection="fr_est", search_rows=120)
    a = identify(u, y, cfg, 5)
    b = identify(u, y, cfg, 5)
    assert a.model.to_json() == b.model.to_json()  # same seed, same result
    full = identify(u, y, cfg.replace(search_rows=0), 5)
    assert a.model.to_json() != full.model.to_json()  # the sample changed the search
    ch = a.model.metrics["free_run_choice"]
    # Candidates: the best pair and the 20 members of the final population, the best pair counted once
    # (a second stage's best pair is itself a member: DE keeps it).
    assert ch["admissible"] >= 1 and ch["candidates"] == 20 and ch["excursion_spans"] == 0.0
    # The chosen model's free run over the estimation record stays in the widened range.
    sim = a.model.simulate(u, y[: a.model.max_lag])
    span = y.max() - y.min()
    assert sim.max() <= y.max() + 0.25 * span and sim.min() >= y.min() - 0.25 * span


@pytest.mark.parametrize(
    ("field", "value", "text"),
    [("search_rows", -1, "search_rows must be an integer >= 0"), ("search_rows", 5, "search_rows must be 0")],
)
def test_bad_settings_name_the_field_and_the_accepted_form(field: str, value: object, text: str) -> None:
    with pytest.raises(ConfigError, match=text.replace("[", r"\[").replace("]", r"\]")):
        PAPER.replace(**{field: value})


def test_a_model_without_an_input_term_is_not_admissible(reactor, good_model) -> None:  # type: ignore[no-untyped-def]
    import json

    from streamid.model import Model
    from streamid.model.regressors import Regressor

    u, y = reactor
    autonomous = Model(regressors=(Regressor("y", 0, 1),), centres=np.zeros((2, 1)), widths=np.ones(2),
                       weights=np.array([0.1, 0.2]), normalisation=good_model.normalisation)
    fr = free_run_scores([autonomous], u, y)
    assert fr.admissible == 0 and fr.scores[0] == -np.inf and fr.best() == 0
    ev = fr.evidence(0)
    assert ev["excursion_spans"] is None and json.loads(json.dumps(ev, allow_nan=False))["admissible"] == 0
    fr2 = free_run_scores([autonomous, good_model], u, y)
    assert fr2.best() == 1 and fr2.admissible == 1


def test_scores_streamed_in_chunks_are_the_whole_records(reactor, good_model,  # type: ignore[no-untyped-def]
                                                         monkeypatch: pytest.MonkeyPatch) -> None:
    """``keep_paths=False`` simulates a few rows at a time, each chunk from the last outputs of the one before:
    the same free runs (their excursions to the bit, scores to rounding), no paths kept."""
    import streamid.engine.choice.scores as choice

    u, y = reactor
    lin = replace(good_model, linear=np.r_[np.full(len(good_model.regressors), 0.01), 0.02])
    cands = [good_model, replace(good_model, weights=good_model.weights * 4.0), lin,
             replace(good_model, weights=good_model.weights * 1.1)]
    whole = free_run_scores(cands, u, y, range_margin=0.25, score_from=100)
    monkeypatch.setattr(choice, "SCORE_CHUNK_ROWS", 37)  # 600 samples: 17 chunks, none aligned with score_from
    streamed = free_run_scores(cands, u, y, range_margin=0.25, score_from=100, keep_paths=False)
    assert streamed.excursions == whole.excursions and whole.admissible == streamed.admissible >= 2
    assert np.allclose(streamed.scores, whole.scores, rtol=1e-12, atol=0)  # the -inf ones: equal
    assert all(p is None for p in streamed.paths) and all(p is not None for p in whole.paths)
    assert streamed.best() == whole.best()


@pytest.mark.parametrize("linear", [False, True])
def test_a_long_records_final_fit_is_made_in_blocks_with_the_same_weights(  # type: ignore[no-untyped-def]
        reactor, linear: bool, monkeypatch: pytest.MonkeyPatch) -> None:
    """Past ``FIT_BLOCK_ROWS`` rows the chosen pair's activations and regressors are made a block at a time, never
    for every row: the weights of the streamed least squares the whole-record fit takes there, the same to the bit."""
    import streamid.engine.search.candidates as candidates
    import streamid.engine.fit.rbf as rbf
    from streamid.engine.search.coevolution import Coevolution
    from streamid.engine.fit.rbf import activations

    u, y = reactor
    co = Coevolution(u, y, PAPER.replace(neurons=6, generations=4, linear_terms=linear), 3)
    for _ in co:
        pass
    for module in (rbf, candidates):
        monkeypatch.setattr(module, "FIT_BLOCK_ROWS", 64)  # 590 rows: 10 blocks
    mask, x = co.best_h, co.best_x
    blocks = co.model_for(mask, x)
    cols = np.flatnonzero(mask)
    M, D = co.config.neurons, co.D
    whole = co._fitted(cols, x, activations(co.R[:, cols], x[: M * D].reshape(M, D)[:, cols], x[M * D:]),
                       co.R[:, cols], co.target)
    np.testing.assert_array_equal(blocks.weights, whole.weights)
    assert (blocks.linear is None) == (not linear) and (blocks.linear is None or
                                                        np.array_equal(blocks.linear, whole.linear))
    assert blocks.metrics["fitness"] == pytest.approx(whole.metrics["fitness"], rel=1e-12)


def test_a_large_windows_fallback_fits_and_scores_every_candidate_in_blocks(  # type: ignore[no-untyped-def]
        reactor, monkeypatch: pytest.MonkeyPatch) -> None:
    """When the screened choice's refit is not admissible, every candidate is fitted on every row: for a record
    past ``FIT_BLOCK_ROWS`` that is done a block at a time and scored without keeping free runs; the same choice
    as the whole-record way (the weights to an ulp of the activations)."""
    import streamid.engine.search.candidates as candidates
    import streamid.engine.fit.rbf as rbf
    import streamid.engine.choice.selection as selection
    from streamid.engine.search.coevolution import Coevolution

    u, y = reactor
    cfg = PAPER.replace(neurons=6, generations=6, selection="fr_est", linear_terms=True, search_rows=128)
    rows = np.sort(np.random.default_rng(0).choice(len(y) - cfg.max_lag, 128, replace=False))
    co = Coevolution(u, y, cfg, 4, rows=rows)
    for _ in co:
        pass
    whole, score_whole, path = selection.select_model_path(co, u, y, "fr_est")
    for module in (rbf, candidates):
        monkeypatch.setattr(module, "FIT_BLOCK_ROWS", 64)
    monkeypatch.setattr(selection, "_screened", lambda *a: None)  # the screened refit not admissible
    blocks = co.candidate_models(None, both=True, in_blocks=True)
    plain = co.candidate_models(None, both=True)
    assert len(blocks) == len(plain) >= 4
    for a, b in zip(blocks, plain):
        np.testing.assert_allclose(a.weights, b.weights, rtol=1e-7, atol=1e-9)
    chosen, score, none = selection.select_model_path(co, u, y, "fr_est", screen_rows=True)
    assert none is None and path is not None  # no free run kept in blocks
    np.testing.assert_allclose(chosen.weights, whole.weights, rtol=1e-7, atol=1e-9)
    assert score == pytest.approx(score_whole, abs=1e-9)
    assert chosen.metrics["free_run_choice"]["candidates"] == whole.metrics["free_run_choice"]["candidates"]


def test_a_sampled_run_never_makes_every_rows_regressors_for_a_long_record(  # type: ignore[no-untyped-def]
        reactor, monkeypatch: pytest.MonkeyPatch) -> None:
    """A run searched on a sample of rows holds that sample's regressors only; the screened choice of a record past
    ``FIT_BLOCK_ROWS`` fits its chosen one a block at a time: the lag matrix of every row is never made (it is
    made once if asked for, as ``R``), and the model is the one fitted on the whole matrix."""
    import streamid.engine.search.candidates as candidates
    import streamid.engine.fit.rbf as rbf
    from streamid.engine.search.coevolution import Coevolution
    from streamid.engine.fit.lagmatrix import lag_matrix, lag_rows
    from streamid.engine.fit.rbf import activations
    from streamid.engine.choice.selection import select_model

    u, y = reactor
    cfg = PAPER.replace(neurons=6, generations=6, selection="fr_est", linear_terms=True, search_rows=128)
    un, yn = np.random.default_rng(1).uniform(-1, 1, (50, 2)), np.random.default_rng(2).uniform(-1, 1, 50)
    idx = np.array([0, 3, 39])
    np.testing.assert_array_equal(lag_rows(un, yn, 4, 6, idx, min_lag_u=0), lag_matrix(un, yn, 4, 6, min_lag_u=0)[idx])
    rows = np.sort(np.random.default_rng(0).choice(len(y) - cfg.max_lag, 128, replace=False))
    co = Coevolution(u, y, cfg, 4, rows=rows)
    for _ in co:
        pass
    for module in (rbf, candidates):
        monkeypatch.setattr(module, "FIT_BLOCK_ROWS", 64)
    model, _ = select_model(co, u, y, "fr_est", screen_rows=True)
    assert co._R is None  # every row's regressors never made
    full = co.R  # made on demand, once: the same regressors
    assert co._R is full and full.shape == (len(y) - cfg.max_lag, co.D)
    np.testing.assert_array_equal(full[rows], co._search[0])
    cols = np.array([co.candidates.index(r) for r in model.regressors])
    x = np.zeros(co.DX)
    x[: 6 * co.D].reshape(6, co.D)[:, cols] = model.centres
    x[6 * co.D :] = model.widths
    whole = co._fitted(cols, x, activations(full[:, cols], model.centres, model.widths), full[:, cols], co.target)
    np.testing.assert_array_equal(model.weights, whole.weights)  # the chosen one fitted on the whole matrix
    np.testing.assert_array_equal(model.linear, whole.linear)
