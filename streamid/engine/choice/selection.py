"""Scoring and choosing finished runs' models: refits, batched free runs, the selection rule.

:func:`select_model` is the one final-model choice of streamid (:func:`~streamid.engine.identification.identify`
and the online updates use it); the rule itself is in :mod:`streamid.engine.choice.scores`.
"""

from __future__ import annotations

from dataclasses import replace
from typing import TYPE_CHECKING, Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from streamid.engine.fit.blas import one_blas_thread
from streamid.threads import thread_map
from streamid.engine.choice.scores import (RANGE_MARGIN, FreeRunScores, free_run_scores, group_free_run, segment_scores,
                                          segments)
from streamid.engine.choice.complexity import RULE, criterion, parameter_count, pruned
from streamid.model.ensemble import EnsembleModel
from streamid.model.narx import Model
from streamid.engine.choice.longlinear import long_linear_fit
from streamid.engine.fit.rbf import activations, fit_in_blocks, fit_linear_rbf, fit_weights
from streamid.model.limits import CHUNK_ROWS
from streamid.engine.search.rows import spaced_rows
from streamid.model.regressors import as_data, regressors_at
from streamid.engine.settings import RIDGE
from streamid.engine.validation import r2
from streamid.errors import ConfigError, DataError

if TYPE_CHECKING:
    from streamid.engine.search.coevolution import Coevolution
    from streamid.engine.settings import CoEAConfig

__all__ = ["free_run_r2", "pruned_choice", "refit_weights", "select_model", "select_model_path"]


def refit_weights(model: Model, u: ArrayLike, y: ArrayLike, ridge: float,
                  samples: NDArray[np.intp] | None = None, threads: int = 1, fitness: bool = True) -> Model:
    """The same structure with output weights refitted on ``(u, y)`` (model's normalisation).

    A model with a linear part has it refitted in the same least squares. The fit uses rows ``t >= max(model.max_lag, start)``; see :func:`~streamid.engine.fit.rbf.fit_weights`.
    An ensemble has every member refitted (each on its own regressors); its ``fitness`` is then the mean's.
    ``samples`` (sorted sample indices, each at least the model's ``max_lag``): the fit and the fitness on those
    samples' rows only (a record beyond one chunk: :func:`~streamid.engine.search.rows.spaced_rows`; the time and
    memory those rows', not the record's). ``threads``: an ensemble's members refitted in that many threads (the
    same weights: each member's least squares is its own); ``fitness`` False: an ensemble's ``metrics.fitness`` is
    left as it was (for a caller that reads only the weights: the calibration's half-model).
    """
    if isinstance(model, EnsembleModel):
        with one_blas_thread():  # around the threads too: each member's own limit then restores this one
            members = thread_map(lambda m: refit_weights(m, u, y, ridge, samples), model.members, threads)
        ens = replace(model, members=tuple(members))
        if not fitness:
            return ens
        ua, ya = as_data(u, y, min_samples=ens.max_lag + 2)
        L = ens.max_lag
        if samples is not None:
            at = np.array([_rows_at(m, ua, ya, samples)[2] for m in ens.members])  # each member's OSA there
            err = ens.combine_rows(at) - ya[samples]
            return ens.with_metrics(fitness=float(np.mean(err**2)))
        return ens.with_metrics(fitness=float(np.mean((ens.predict_osa(ua, ya)[L:] - ya[L:]) ** 2)))
    ua, ya = as_data(u, y, min_samples=model.max_lag + model.neurons + 1)
    L = model.max_lag
    if samples is not None:
        if samples.size < model.neurons + 1 or int(samples[0]) < L:
            raise DataError(f"a refit on samples needs at least neurons + 1 = {model.neurons + 1} of them, each >= "
                            f"max_lag {L}; got {samples.size} from {int(samples[0]) if samples.size else None}")
        r, rl, _ = _rows_at(model, ua, ya, samples)
        target = model.normalisation.y(ya[samples])
    elif ya.shape[0] - L > CHUNK_ROWS and model.linear_regressors is None:  # beyond one chunk: streamed in blocks
        return _refit_in_blocks(model, ua, ya, ridge)
    else:
        r, target = model.regressor_rows(ua, ya)  # target: the normalised outputs of rows t >= L
        rl = r if model.linear_regressors is None else model.linear_rows(ua, ya)
    with one_blas_thread():
        phi = activations(r, model.centres, model.widths)
        lin = None
        if model.linear is None:
            w = fit_weights(phi, target, ridge)
            fit = phi @ w
        else:
            if model.linear_regressors is None:
                w, lin = fit_linear_rbf(phi, rl, target, ridge)
            else:  # a long linear part: fitted as it was built (streamid.engine.choice.longlinear)
                w, lin = long_linear_fit(model.linear_regressors, phi, rl, target, ridge)
            fit = phi @ w + rl @ lin[:-1] + lin[-1]
    if not np.all(np.isfinite(w)) or (lin is not None and not np.all(np.isfinite(lin))):
        raise DataError("refitted weights are not finite (numerically degenerate data)")
    mse = float(np.mean((fit - target) ** 2)) * model.normalisation.y_half_range**2
    return replace(model, weights=w, linear=lin, metrics={**model.metrics, "fitness": mse})


def _rows_at(model: Model, u: NDArray[np.float64], y: NDArray[np.float64],
             samples: NDArray[np.intp]) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]]:
    """A network's normalised regressors at ``samples`` (one row each), its linear part's, and its one-step
    prediction there (output units): what :meth:`Model.predict_osa` computes at those samples."""
    norm = model.normalisation
    r = regressors_at(norm, model.regressors, u, y, samples)
    rl = r if model.linear_regressors is None else regressors_at(norm, model.linear_regressors, u, y, samples)
    yn_hat = activations(r, model.centres, model.widths) @ model.weights
    if model.linear is not None:
        yn_hat = yn_hat + rl @ model.linear[:-1] + model.linear[-1]
    return r, rl, model.normalisation.y_inverse(yn_hat)


def _refit_in_blocks(model: Model, u: NDArray[np.float64], y: NDArray[np.float64], ridge: float) -> Model:
    """:func:`refit_weights` of a network (its linear part on its own regressors, if any) on a record beyond one
    chunk: the least squares streamed over blocks of rows (:func:`~streamid.engine.fit.rbf.fit_in_blocks`: the same
    weights to rounding), never every row's activations at once."""
    L = model.max_lag
    target = model.normalisation.y(y)[L:]
    with one_blas_thread():
        w, lin, sse = fit_in_blocks(lambda a, b: model.regressor_rows(u[a : b + L], y[a : b + L])[0], target,
                                    model.centres, model.widths, ridge, model.linear is not None)
    if not np.all(np.isfinite(w)) or (lin is not None and not np.all(np.isfinite(lin))):
        raise DataError("refitted weights are not finite (numerically degenerate data)")
    mse = sse / target.shape[0] * model.normalisation.y_half_range**2
    return replace(model, weights=w, linear=lin, metrics={**model.metrics, "fitness": float(mse)})


def free_run_r2(
    models: list[Model], u: NDArray[np.float64], y: NDArray[np.float64], score_from: int | None = None
) -> list[float]:
    """Free-run R^2 of several models (batched: models sharing their regressors run together).

    Parameters
    ----------
    models : list of Model
    u, y : ndarray
        Data (``u`` of shape (N, n_inputs)).
    score_from : int, optional
        First sample scored; each model's simulation starts ``max_lag`` samples
        earlier from the measured outputs. Default: each model's own ``max_lag``
        (simulation from the start of the data).
    """
    out = [0.0] * len(models)
    groups: dict[tuple[Any, ...], list[int]] = {}
    for i, m in enumerate(models):
        if isinstance(m, EnsembleModel):  # each member on its own past outputs, averaged (model.simulate)
            first = m.max_lag if score_from is None else score_from
            if first < m.max_lag:
                raise DataError(f"free-run scoring from sample {first} needs max_lag = {m.max_lag} earlier samples")
            sim = m.simulate(u[first - m.max_lag :], y[first - m.max_lag : first])
            out[i] = r2(y[first:], sim[m.max_lag :])
            continue
        groups.setdefault((m.regressors, m.normalisation, m.neurons), []).append(i)
    for (regs, norm, _), idx in groups.items():
        L = max((r.lag for r in regs), default=0)
        first = L if score_from is None else score_from
        if first < L:
            raise DataError(f"free-run scoring from sample {first} needs max_lag = {L} earlier samples")
        us, ys = u[first - L :], y[first - L :]
        sim = group_free_run([models[i] for i in idx], us, ys[:L])
        for k, i in enumerate(idx):
            out[i] = r2(ys[L:], norm.y_inverse(sim[k, L:]))
    return out


def select_model(
    run: Coevolution,
    u: NDArray[np.float64],
    y: NDArray[np.float64],
    selection: str,
    *,
    range_margin: float | None = None,
    screen_rows: bool = False,
) -> tuple[Model, float]:
    """The model of a finished run by the selection rule, and its score (higher is better).

    See :func:`select_model_path` (the same choice, with the chosen model's estimation free run).
    """
    model, score, _ = select_model_path(run, u, y, selection, range_margin=range_margin, screen_rows=screen_rows)
    return model, score


def select_model_path(
    run: Coevolution,
    u: NDArray[np.float64],
    y: NDArray[np.float64],
    selection: str,
    *,
    range_margin: float | None = None,
    threads: int = 1,
    screen_rows: bool = False,
    keep_path_rows: int = 0,
) -> tuple[Model, float, NDArray[np.float64] | None]:
    """The model of a finished run by the selection rule, its score (higher is better) and, with
    ``"fr_est"``, its free run over the estimation record in output units when the choice made
    one (None otherwise: the final choice's ensembles then simulate it again).

    The one final-model choice of streamid: :func:`identify` and the online
    updates (:mod:`streamid.online.update`) both call it.

    * ``"fitness"``: the run's best pair (lowest one-step-ahead error, the paper's
      choice); score = -fitness.
    * ``"fr_est"``: of the best pair and the final population, the highest
      free-run R^2 on ``u, y`` among the admissible candidates: their free run stays in the data's range and
      they are bounded by construction (:mod:`streamid.engine.choice.scores`, :mod:`streamid.engine.choice.stability`).

    With ``config.linear_terms`` and ``"fr_est"``, every candidate is offered with its linear part and
    without it (the same centres and widths, weights refitted); the run's model is the admissible one of
    the lowest AIC (:func:`_by_criterion`).

    ``screen_rows`` (a run searched on a sample of its rows, the online updates): the candidates are fitted on
    the search's rows only for the free-run choice, and the chosen one is refitted on all rows and scored again
    (the full way if that refit is not admissible: then each candidate fitted and simulated a block of rows at a
    time, :meth:`~streamid.engine.search.coevolution.Coevolution.models_for`'s ``in_blocks`` and
    :func:`~streamid.engine.choice.scores.free_run_scores`'s ``keep_paths=False``, so that a window's memory does not
    grow with every candidate's activations and free run; no path is returned); otherwise every candidate is
    fitted on all rows. Beyond one chunk of rows the screen's free runs are made on segments of the record and
    there is no full way (:func:`_screened`); its chosen model's free run is then returned only for a record of
    at most ``keep_path_rows`` rows (the identification's ensembles read it instead of simulating it again:
    :data:`~streamid.engine.choice.ensemble_choice.KEEP_PATHS_ROWS`; 0, the online updates: never).
    ``range_margin`` defaults to :data:`~streamid.engine.choice.scores.RANGE_MARGIN`. ``threads`` > 1: the candidates are fitted
    and simulated in that many threads (for a caller with a core to spare; the same result). A run with no
    candidate in range scores below -1e9 (any run with one wins over it); its model says ``admissible: 0``.
    """
    if selection == "fitness":
        best = run.best_model()
        return best, -float(best.metrics["fitness"]), None
    if selection != "fr_est":
        raise ConfigError(f"selection must be one of 'fitness', 'fr_est'; got {selection!r}")
    n = len(y)
    margin = RANGE_MARGIN if range_margin is None else float(range_margin)
    bounded = False  # a large record's fallback: every candidate on every row, in blocks, no paths kept
    if screen_rows and run.search_rows < len(run.target):
        screened = _screened(run, u, y, margin, keep_path_rows)
        if screened is not None:
            return screened
        bounded = True
    both = run.config.linear_terms  # both kinds compete (_by_criterion)
    cands = run.candidate_models(run.config.fr_candidates or None, both=both, threads=threads,
                                 in_blocks=bounded)  # the best pair first
    with one_blas_thread():
        fr = free_run_scores(cands, u, y, range_margin=margin, threads=threads, keep_paths=not bounded)
    k = _by_criterion(cands, fr, n) if both and fr.admissible else fr.best()
    score = fr.scores[k] if fr.admissible else -1e9 * (1.0 + min(fr.excursions[k], 1e6))  # finite: JSON-able
    chosen = cands[k].with_metrics(free_run_choice=fr.evidence(k))
    return chosen, float(score), fr.paths[k] if fr.admissible and not bounded else None


def _by_criterion(cands: list[Model], fr: FreeRunScores, n: int) -> int:
    """The admissible candidate of the lowest AIC (:func:`~streamid.engine.choice.complexity.criterion`) (ties: the first). With both kinds of
    candidate (with and without a linear part, the same centres and widths) this is the best of each kind by
    free-run R^2, then the kind by the criterion: ``p`` counts the linear part's ``k + 1`` weights."""
    crit = [criterion(s, n - m.max_lag, parameter_count(m)) if e == 0.0 else np.inf
            for m, s, e in zip(cands, fr.scores, fr.excursions)]
    return int(np.argmin(crit))


def pruned_choice(cfg: CoEAConfig, model: Model, score: float, u: NDArray[np.float64], y: NDArray[np.float64],
                   margin: float, path: NDArray[np.float64] | None = None, keep_path_rows: int = 0,
                   ) -> tuple[Model, float, NDArray[np.float64] | None]:
    """A chosen model or one of its pruned networks (``M // 3``, ``2 M // 3`` neurons kept in
    forward-selection order, :func:`~streamid.engine.choice.complexity.pruned`), by the complexity rule on the
    estimation free run (range guard included), with the chosen one's estimation free run (``path``: the
    model's; beyond one chunk a pruned one's only for a record of at most ``keep_path_rows`` rows).
    Evidence in ``metrics.neuron_choice``."""
    M = model.neurons
    with one_blas_thread():
        smaller = pruned(model, u, y, (M // 3, 2 * M // 3), RIDGE,
                         spaced_rows(len(y) - model.max_lag))  # beyond one chunk: fitted on evenly spaced rows
        if not smaller:
            return model, score, path
        long = len(y) - model.max_lag > CHUNK_ROWS  # beyond one chunk: scored a chunk at a time, no path kept...
        # each at its own size (not padded with zero-weight neurons to share one recursion: the same values, as
        # a zero weight adds +0.0, at about half the work)
        fr = free_run_scores(list(smaller), u, y, range_margin=margin, keep_paths=not long,
                             streamed_paths=long and len(y) <= keep_path_rows)  # ...but written out up to this
    rows = [(model, score, 0.0), *zip(smaller, fr.scores, fr.excursions)]
    crit = [criterion(s, len(y) - m.max_lag, parameter_count(m)) if e == 0.0 else np.inf
            for m, s, e in rows]
    k = int(np.argmin(crit))  # ties: the unpruned network (first)
    ev = {"rule": RULE, "neurons": rows[k][0].neurons,
          "candidates": [{"neurons": m.neurons, "r2_fr_est": s if e == 0.0 else None,
                          "criterion": c if np.isfinite(c) else None} for (m, s, e), c in zip(rows, crit)]}
    # a pruned network's path: None beyond keep_path_rows (the ensembles' choice simulates it again if it needs it)
    return rows[k][0].with_metrics(neuron_choice=ev), float(rows[k][1]), path if k == 0 else fr.paths[k - 1]


#: Beyond the screen (:func:`_screened`): the admissible candidates refitted on every row, best first, at most this many.
REFITS_TRIED = 3


def _screened(run: Coevolution, u: NDArray[np.float64], y: NDArray[np.float64], margin: float,
              keep_path_rows: int = 0) -> tuple[Model, float, NDArray[np.float64] | None] | None:
    """``"fr_est"`` on a large record with candidates fitted on the search's rows only, the chosen one refitted on
    all rows and scored again; None (choose the full way) when that refit is not admissible and the record is one
    chunk or less.

    Beyond one chunk (:func:`~streamid.engine.choice.scores.segments`) the candidates' free runs are made on the
    record's segments, and the choice stays bounded whatever happens: the admissible candidates are refitted on
    :func:`~streamid.engine.search.rows.spaced_rows` in turn, best first (at most :data:`REFITS_TRIED`), the first
    whose free run over every row is admissible kept; when none is (a free run that holds on 2,048-sample segments
    and drifts over the whole record), the full way's rule with bounded fits: every candidate fitted on those rows
    and free-run over every row, streamed (the online rule's fallback, its least squares on 65,536 rows)."""
    pairs = run.candidate_pairs(run.config.fr_candidates or None)
    cands = [run.model_for(h, x, search_rows=True) for h, x in pairs]
    parts = segments(0, len(y), max(m.max_lag for m in cands))
    with one_blas_thread():
        fr = (free_run_scores(cands, u, y, range_margin=margin, keep_paths=False) if parts is None  # bounded memory
              else segment_scores(cands, u, y, parts, margin))
        if parts is None and not fr.admissible:
            return None
        order = [int(k) for k in np.argsort(-np.asarray(fr.scores), kind="stable") if fr.excursions[k] == 0.0]
        spaced = None if parts is None else spaced_rows(len(run.target))

        def refit(k: int) -> Model:  # on every row; beyond one chunk on CHUNK_ROWS evenly spaced rows
            return run.model_for(*pairs[k]) if spaced is None else run.model_on_rows(*pairs[k], spaced)

        tried: list[tuple[float, Model, FreeRunScores]] = []
        for k in order[: 1 if parts is None else REFITS_TRIED]:
            final = refit(k)
            # beyond one chunk scored a chunk at a time; its path written out as the pieces pass only for a record
            # of at most keep_path_rows rows (the ensembles' choice reads it; beyond, it makes its own)
            again = free_run_scores([final], u, y, range_margin=margin, keep_paths=parts is None,
                                    streamed_paths=parts is not None and len(y) <= keep_path_rows)
            if again.admissible:
                ev = {**again.evidence(0), "candidates": len(cands), "admissible": fr.admissible,
                      "screened_on_rows": run.search_rows}
                if parts is not None:
                    ev["screened_on_segments"] = {"count": len(parts), "rows": int(sum(b - a for a, b in parts))}
                return final.with_metrics(free_run_choice=ev), float(again.scores[0]), again.paths[0]
            tried.append((again.excursions[0], final, again))
        if parts is None:
            return None
        # the fallback, bounded: every candidate fitted on the spaced rows, free-run over every row (streamed, no paths)
        both = run.config.linear_terms  # both kinds compete, as in the full way (_by_criterion)
        full = [run.model_on_rows(*pairs[k], spaced, linear=kind) for kind in ((None, False) if both else (None,))
                for k in range(len(pairs))] if spaced is not None else [refit(k) for k in range(len(pairs))]
        fb = free_run_scores(full, u, y, range_margin=margin, keep_paths=False)
    k = _by_criterion(full, fb, len(y)) if both and fb.admissible else fb.best()
    score = fb.scores[k] if fb.admissible else -1e9 * (1.0 + min(fb.excursions[k], 1e6))  # finite: JSON-able
    ev = {**fb.evidence(k), "screened_on_rows": run.search_rows, "admissible_on_segments": fr.admissible,
          "refitted_first": len(tried), "fallback": "every candidate on spaced rows, free run over every row"}
    return full[k].with_metrics(free_run_choice=ev), float(score), None
