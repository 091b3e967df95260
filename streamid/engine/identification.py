"""``identify``: one identification, possibly several coevolution runs chosen among.

Strategies (``CoEAConfig.restarts`` and ``selection``; ``identify``'s ``workers``)
------------------------------------------------------------------------------
* ``restarts=1, selection="fitness"`` -- the paper's procedure: one :class:`~streamid.engine.search.coevolution.Coevolution`
  on all the estimation data, the best pair ever evaluated, weights refitted. Runs in this process and reports
  every generation to the callback.
* otherwise ``restarts`` independent runs (on a record beyond one chunk with ``run_ensembles``, at most
  :data:`~streamid.engine.choice.robust.LONG_RUNS`: the others feed only the median, not made there;
  ``metrics.restarts_made``; seeds drawn from ``rng``; two-stage when ``lag_search_neurons > 0``,
  see :class:`~streamid.engine.settings.CoEAConfig`) in ``workers`` processes (spawned, never forked: the caller
  may hold a Zenoh session) or in this process. Each run offers candidates -- its best pair and every parameter
  vector of its final population paired with the best harmony (weights refitted) -- and the selection rule picks
  one per run, then one overall:

  - ``"fr_est"``: highest free-run R^2 on the estimation data, simulated from its first samples (the OSA-trained
    candidates differ most in how their free runs hold up; this choice removes the runs whose simulation drifts);
  - ``"fitness"``: lowest OSA MSE.

Before the runs, with ``max_lag_cap > 0``, the candidate lags ``1..L`` are chosen from the estimation data
(:mod:`streamid.engine.search.lagspace`; evidence in ``metrics.max_lag_choice``); when ``L`` is at least twice the floor
the odd restarts keep ``1..floor`` (restart 1 of every 4 with ``lag_search_neurons`` neurons when > 0: the
paper's size by default). A two-stage run's second stage always trains on a lag set with an input term. After the runs,
if no run has an admissible candidate, one more run is made with each of ``fallback_neurons`` in turn until one
has (``metrics.fallback_runs``; also while the best run's score is at most ``settings.FALLBACK_BELOW``, 0.5). Before
those, with ``more_restarts``, that many more runs when the best run's score lies in ``(0, settings.MORE_BELOW)``
(:mod:`streamid.engine.restarts`; ``metrics.more_restarts``).

With ``selection="fr_est"`` the run kept is chosen by AIC (:mod:`streamid.engine.choice.complexity`: the lowest ``n log(1 - R2_fr) + 2 p`` over the runs' admissible candidates, ``p`` the weights fitted;
``metrics.complexity``), after the ``prune_runs`` best runs have offered their networks pruned to ``M // 3`` and
``2 M // 3`` neurons (``metrics.neuron_choice``); with ``run_ensembles`` the means of the best runs' networks
compete by the same criterion (:mod:`streamid.engine.choice.ensemble_choice`); with ``refine_iterations`` the kept
model's weights are then fitted to its free run (:mod:`streamid.engine.choice.refine`, ``metrics.refinement``).

The normalisation is always the min/max of all the estimation data. Validation data are never looked at.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from concurrent.futures import Executor
from dataclasses import dataclass, field
from functools import partial
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from streamid.engine.search.coevolution import CoEAState, Coevolution, Progress, _as_rng
from streamid.engine.choice.scores import RANGE_MARGIN
from streamid.engine.choice.complexity import choose as choose_complexity
from streamid.engine.choice.calibration import with_interval
from streamid.engine.choice.ensemble_choice import KEEP_PATHS_ROWS, choose_ensemble, one_step_mse
from streamid.engine.choice.refine import ABOVE as REFINE_ABOVE, refine_judged
from streamid.engine.choice.robust import LONG_RUNS, LONG_RUNS_REASON, ROBUST_BEYOND, robust_choice
from streamid.engine.restarts import report_after, wants_more
from streamid.engine.search.fanout import fan_out
from streamid.engine.search.feedthrough import direct_terms
from streamid.engine.search.lagspace import memory_lag, with_input_term
from streamid.engine.search.rows import long_record_rows
from streamid.model.limits import CHUNK_ROWS
from streamid.engine.choice.longlinear import long_linear_choice
from streamid.model.narx import Model
from streamid.engine.search.parallel import EvalHelper
from streamid.model.regressors import Normalisation, as_data
from streamid.engine.choice.selection import free_run_r2, pruned_choice, refit_weights, select_model, select_model_path
from streamid.engine.settings import DEFAULT, FALLBACK_BELOW, MORE_BELOW, RIDGE, CoEAConfig
from streamid.errors import ConfigError, DataError

__all__ = ["Result", "RunSummary", "free_run_r2", "identify", "refit_weights", "select_model"]


@dataclass(frozen=True)
class RunSummary:
    """One coevolution run of an identification."""

    seed: int | None
    fitness: float
    evaluations: int
    seconds: float
    score: float
    lags: dict[str, Any]

    def to_dict(self) -> dict[str, Any]:
        return {
            "seed": self.seed,
            "fitness": self.fitness,
            "evaluations": self.evaluations,
            "seconds": self.seconds,
            "score": self.score,
            "lags": self.lags,
        }


@dataclass(frozen=True, eq=False)
class Result:
    """What :func:`identify` returns.

    Attributes
    ----------
    model : Model
        The identified model (weights fitted on all the estimation data).
    state : CoEAState
        State of the chosen run (warm-start a later run with it).
    fitness_history : ndarray
        Best fitness after each generation of the chosen run (output units squared).
    evaluations : int
        Fitness evaluations over all runs.
    seconds : float
        Wall time of the identification.
    runs : tuple of RunSummary
        Every run, in seed order.
    chosen : int
        Index of the chosen run in ``runs``.
    extra : dict
        ``run_models``: each run's chosen model, in run order (several runs only); ``osa_predictions_est``: the
        model's one-step predictions over the estimation record (length N, the first ``max_lag`` not predicted) when the
        identification made them for its ``metrics.fitness`` (a record of up to ``KEEP_PATHS_ROWS`` rows):
        :func:`~streamid.engine.validation.validate`'s ``osa_predictions_est``.
    """

    model: Model
    state: CoEAState
    fitness_history: NDArray[np.float64]
    evaluations: int
    seconds: float
    runs: tuple[RunSummary, ...] = ()
    chosen: int = 0
    extra: dict[str, Any] = field(default_factory=dict)

    @property
    def fitness(self) -> float:
        """OSA MSE of the final model on the estimation data (output units squared)."""
        return float(self.model.metrics["fitness"])


def _stage(
    tick: Callable[[Progress], object] | None, gen0: int, evals0: int
) -> Callable[[Progress], object] | None:
    """A stage's per-generation callback reporting the run's generations and evaluations so far."""
    if tick is None:
        return None
    return lambda p: tick(Progress(gen0 + p.generation, p.generations, p.best_fitness, evals0 + p.evaluations))


def _threads(helper: EvalHelper | None) -> int:
    """Threads for the numerics between search batches: 2 with a helper (its core is ours, and idle while a run's
    candidates are fitted and simulated or the kept model refined), else 1. The results are the same either way."""
    return 2 if helper is not None else 1


def _settled(model: Model, u: NDArray[np.float64], y: NDArray[np.float64], threads: int,
             keep_osa: dict[str, Any] | None = None) -> Model:
    """``model`` with its ``metrics.fitness`` made where :func:`choose_ensemble` left it None (the same value it
    would have made there); ``keep_osa`` as :func:`~streamid.engine.choice.refine.refine_weights`' (the one-step
    predictions that value is made of, kept for the validation)."""
    if "fitness" in model.metrics and model.metrics["fitness"] is None:
        settled = model.with_metrics(fitness=one_step_mse(model, u, y, threads, keep_osa))
        if keep_osa is not None:
            keep_osa["of"] = settled
        return settled
    return model


def _one_run(job: dict[str, Any], helper: EvalHelper | None = None) -> dict[str, Any]:
    """One coevolution run and its candidate chosen by the selection rule (also a worker's body)."""
    cfg = CoEAConfig.from_dict(job["config"])
    if job.get("neurons", cfg.neurons) != cfg.neurons:  # this restart's size (the hedge's, fallback_neurons)
        cfg = cfg.replace(neurons=int(job["neurons"]))
    if job.get("max_lag", cfg.max_lag) != cfg.max_lag:  # this restart's lag space (max_lag_cap)
        cfg = cfg.replace(max_lag_y=int(job["max_lag"]), max_lag_u=int(job["max_lag"]), max_lag_cap=0)
    norm = Normalisation.from_dict(job["normalisation"])
    warm = CoEAState.from_json(job["warm_start"]) if job.get("warm_start") else None
    u, y = job["u"], job["y"]
    tick = job.get("tick")  # in-process runs only (a callable is never sent to a worker): tick(Progress) per generation
    t0 = time.perf_counter()
    rng = np.random.default_rng(job["seed"])
    common: dict[str, Any] = {
        "input_names": tuple(job["input_names"]),
        "output_name": job["output_name"],
        "window": job["window"],
        "normalisation": norm,
        "helper": helper,
    }
    sample = long_record_rows(len(y) - cfg.max_lag, cfg, u.shape[1], rng)  # beyond one chunk: the online rule
    if sample is not None:
        common["rows"] = sample.rows
    elif cfg.search_rows and len(y) - cfg.max_lag > cfg.search_rows:  # the search sees a random sample of rows
        common["rows"] = np.sort(rng.choice(len(y) - cfg.max_lag, cfg.search_rows, replace=False))
    evaluations, lag_rule = 0, "search"
    if cfg.lag_search_neurons and warm is None:
        # Two-stage run: a small network's coevolution chooses the lags...
        lag_cfg = cfg.replace(neurons=cfg.lag_search_neurons)  # RBF-only, as every search; its lags evolve throughout
        lag_run = Coevolution(u, y, lag_cfg, rng, harmony_stop=1.0, **common).solve(_stage(tick, 0, 0))
        evaluations = lag_run.evaluations
        # ...(always with an input term: streamid.engine.search.lagspace)...
        R, target = (lag_run.R, lag_run.target) if sample is None else lag_run.searched  # beyond one chunk:
        mask, lag_rule = with_input_term(lag_run.best_h, lag_run.H, lag_run.fh, lag_run.candidates,  # the sample's
                                         R, target)  # rows, never every row's candidate lags at once
        del lag_run, R, target  # its copies of the record go before the second stage makes its own
        # ...then DE trains the full network on those lags.
        run = Coevolution(u, y, cfg, rng, fixed_mask=mask, **common).solve(
            _stage(tick, lag_cfg.generations, evaluations))
    else:
        run = Coevolution(u, y, cfg, rng, warm_start=warm, **common).solve(_stage(tick, 0, 0))
    evaluations += run.evaluations
    # beyond one chunk the candidates are screened on the search's rows and only the chosen one fitted on every row
    model, score, path = select_model_path(run, u, y, cfg.selection, threads=_threads(helper),
                                           screen_rows=sample is not None, keep_path_rows=KEEP_PATHS_ROWS)
    if sample is not None:
        model = model.with_metrics(search_rows=sample.evidence())
    return {
        "seed": job["seed"],
        # A run made in this process hands back its objects; a worker's go back as JSON.
        "model": model if job.get("in_process") else model.to_json(indent=None),
        "state": run.state() if job.get("in_process") else run.state().to_json(),
        "history": list(run.history),
        "evaluations": evaluations,
        "seconds": time.perf_counter() - t0,
        "fitness": float(run.best_f),
        "score": score,
        "path": path,  # the model's estimation free run (output units) when the choice made one
        "lag_rule": lag_rule,
        "search_rows": None if sample is None else sample.evidence(),
        "neurons": cfg.neurons,
        "max_lag": cfg.max_lag,
    }


def identify(
    u: ArrayLike,
    y: ArrayLike,
    config: CoEAConfig | None = None,
    rng: np.random.Generator | int | None = None,
    *,
    warm_start: CoEAState | None = None,
    callback: Callable[[Progress], object] | None = None,
    input_names: tuple[str, ...] | None = None,
    output_name: str = "y",
    window: dict[str, Any] | None = None,
    executor: Executor | None = None,
    helper: EvalHelper | None = None,
    workers: int = 1,
) -> Result:
    """Identify an RBF-NARX model of ``y`` from ``u`` (one output).

    Parameters
    ----------
    u : array_like, shape (N,) or (N, n_inputs)
        Estimation inputs.
    y : array_like, shape (N,)
        Estimation output (identify several outputs one at a time).
    config : CoEAConfig, optional
        Settings; default :data:`~streamid.engine.settings.DEFAULT`.
    rng : numpy.random.Generator or int, optional
        Source of all randomness (an int seeds ``default_rng``; None = seed 0).
    warm_start : CoEAState, optional
        Start (the first run) from an exported state; re-evaluated on this data.
    callback : callable, optional
        ``callback(Progress)``: after every generation of an in-process run, or
        after every finished run when runs go to worker processes. A truthy
        return stops an in-process run early.
    input_names, output_name, window : optional
        Recorded in the model.
    executor : concurrent.futures.Executor, optional
        Run the restarts on this executor (e.g. a long-lived process pool)
        instead of creating one when ``workers > 1``.
    helper : EvalHelper, optional
        A started :class:`~streamid.engine.search.parallel.EvalHelper`: runs made in this
        process evaluate half of every population batch in it (the second core).
        The result is the same with or without it.
    workers : int
        Processes for the restarts (spawned); 1 = in this process. The result is the same whatever the number
        (a run's seed is drawn from ``rng`` before any is made); not a setting of the method, so not in ``config``.

    Returns
    -------
    Result

    Raises
    ------
    DataError, ConfigError
    """
    t_start = time.perf_counter()
    cfg = DEFAULT if config is None else config
    if not isinstance(cfg, CoEAConfig):
        raise ConfigError(f"config must be a CoEAConfig; got {type(cfg).__name__}")
    if not (isinstance(workers, int) and not isinstance(workers, bool) and 1 <= workers <= 1024):
        raise ConfigError(f"workers must be an integer in [1, 1024] (processes for the restarts); got {workers!r}")
    gen = _as_rng(rng)
    ua, ya = as_data(u, y, copy=False)  # read only (a test passes read-only arrays): no copy of a long record
    names = tuple(input_names) if input_names else tuple(f"u{i}" for i in range(ua.shape[1]))
    win = dict(window) if window else {"n_samples": int(ya.shape[0])}

    n = ya.shape[0]
    lag_evidence: dict[str, int] | None = None
    floor = cfg.max_lag
    if cfg.max_lag_cap and warm_start is None and (cfg.restarts > 1 or cfg.lag_search_neurons):
        lag, lag_evidence = memory_lag(ua, ya, cfg.max_lag, cfg.max_lag_cap)
        lag = min(lag, max(cfg.max_lag, (n - 2 * cfg.neurons) // 2))
        lag_evidence["max_lag"] = lag
        cfg = cfg.replace(max_lag_y=lag, max_lag_u=lag, max_lag_cap=max(lag, cfg.max_lag_cap))
    elif warm_start is not None and cfg.max_lag_cap:  # the lag space (and size) of the state warm-started from
        st = warm_start
        cfg = cfg.replace(max_lag_y=st.max_lag_y, max_lag_u=st.max_lag_u, neurons=st.neurons,
                          max_lag_cap=max(st.max_lag_y, st.max_lag_u, cfg.max_lag_cap))
    # u(t) a candidate? A warm start's state says; else the test on the record (streamid.engine.search.feedthrough)
    cfg, feed = direct_terms(cfg, ua, ya, warm_start, test=cfg.restarts > 1 or bool(cfg.lag_search_neurons))
    need = cfg.max_lag + 2 * cfg.neurons
    if n < need:
        raise DataError(
            f"{n} estimation samples are too few: with max lag {cfg.max_lag} and "
            f"{cfg.neurons} neurons at least max_lag + 2 * neurons = {need} are needed"
        )
    norm = Normalisation.fit(ua, ya)

    if cfg.restarts == 1 and cfg.selection == "fitness" and not cfg.lag_search_neurons:
        # The paper's procedure: one run, the best pair ever evaluated (in this process, steppable).
        run = Coevolution(
            ua, ya, cfg, gen, warm_start=warm_start, input_names=names, output_name=output_name, window=win,
            normalisation=norm, helper=helper,
        ).solve(callback)
        model = run.best_model()
        summary = RunSummary(None, float(run.best_f), run.evaluations, run.seconds, -float(model.metrics["fitness"]), model.lags)
        return Result(  # the paper's model, with its free-run interval (calibrated on a held-out half: no change)
            model=with_interval(model, ua, ya, RIDGE).with_metrics(restarts=1, selection="fitness"),
            state=run.state(),
            fitness_history=np.asarray(run.history),
            evaluations=run.evaluations,
            seconds=time.perf_counter() - t_start,
            runs=(summary,),
            chosen=0,
        )

    # beyond one chunk the median is not made (ROBUST_BEYOND), and the restarts past LONG_RUNS only feed it (the
    # median is made with selection "fr_est" only: with "fitness" every restart is made, at any length)
    no_median_here = cfg.run_ensembles and cfg.selection == "fr_est" and n > CHUNK_ROWS
    made_restarts = min(cfg.restarts, LONG_RUNS) if no_median_here else cfg.restarts
    seeds = [int(s) for s in gen.integers(0, 2**63 - 1, size=made_restarts)]
    # A long lag space chosen from the data (>= twice the floor) is hedged: the odd restarts use the floor's.
    hedge = lag_evidence is not None and cfg.max_lag >= 2 * floor
    base = {
        "config": cfg.to_dict(),
        "normalisation": norm.to_dict(),
        "u": ua,
        "y": ya,
        "input_names": list(names),
        "output_name": output_name,
        "window": win,
    }
    per_run = cfg.generations * (2 if cfg.lag_search_neurons else 1)
    total_gen = per_run * made_restarts  # (grows when more_restarts are made)
    done: list[dict[str, Any]] = []  # finished runs (in-process progress)

    def restart(i: int, s: int, n_jobs: int) -> dict[str, Any]:  # restart i's job: the pattern repeats every 4
        job = {**base, "seed": s, "warm_start": warm_start.to_json() if (warm_start is not None and i == 0) else None,
               "neurons": (cfg.lag_search_neurons or cfg.neurons) if (hedge and i % 4 == 1) else cfg.neurons,
               "max_lag": floor if (hedge and i % 2 == 1) else cfg.max_lag, "in_process": executor is None and workers <= 1}
        if callback is not None and executor is None and min(workers, n_jobs) <= 1:
            job["tick"] = lambda p: callback(Progress(  # runs made here report every generation, as one run does
                i * per_run + p.generation, total_gen, min([p.best_fitness] + [o["fitness"] for o in done]),
                sum(o["evaluations"] for o in done) + p.evaluations))
        return job

    jobs = [restart(i, s, len(seeds)) for i, s in enumerate(seeds)]

    def report(outs: list[dict[str, Any]]) -> None:
        done[:] = outs
        if callback is not None:
            callback(
                Progress(
                    len(outs) * per_run,
                    total_gen,
                    min(o["fitness"] for o in outs),
                    sum(o["evaluations"] for o in outs),
                )
            )

    outs = fan_out(_one_run, jobs, workers, executor=executor, helper=helper, on_result=report)
    more_made = 0  # more runs where the record is half explained (restarts.wants_more)
    if wants_more(outs, cfg):
        more_seeds = [int(s) for s in gen.integers(0, 2**63 - 1, size=cfg.more_restarts)]
        total_gen = per_run * (made_restarts + cfg.more_restarts)
        more = [restart(made_restarts + j, s, len(more_seeds)) for j, s in enumerate(more_seeds)]
        made = list(outs)
        outs = made + fan_out(_one_run, more, workers, executor=executor, helper=helper,
                              on_result=partial(report_after, report, made))
        jobs, more_made = jobs + more, len(more)

    # No run admissible (every candidate's free run leaves the data's range or ignores the input): smaller
    # networks, one run each in the order of fallback_neurons, until one has an admissible candidate.
    fallback_made: list[int] = []
    for m in cfg.fallback_neurons:
        if max(o["score"] for o in outs) > FALLBACK_BELOW:
            break
        made = list(outs)
        job = {**base, "seed": int(gen.integers(0, 2**63 - 1)), "warm_start": None, "neurons": m, "max_lag": floor,
               "in_process": True}
        jobs.append(job)
        fallback_made.append(m)
        outs = made + fan_out(_one_run, [job], 1, executor=None, helper=helper,
                              on_result=partial(report_after, report, made))

    # threads of the work after the restarts: a helper's core is idle then, but beyond one chunk a second thread
    # holds a second allocator arena of temporaries for little: 1,000,000 samples, the refinement and the
    # calibration in two threads (a chunk's temporaries each): 0.1 s saved, peak RSS 374 -> 482 MiB (stagemem)
    post = 1 if n > CHUNK_ROWS else _threads(helper)
    if callback is not None:  # the search is done: what follows is the kept model's choice (a stage of its own)
        callback(Progress(total_gen, total_gen, min(o["fitness"] for o in outs), sum(o["evaluations"] for o in outs),
                          "choice"))
    models = [o["model"] if isinstance(o["model"], Model) else Model.from_json(o["model"]) for o in outs]
    scores, paths = [float(o["score"]) for o in outs], [o.get("path") for o in outs]  # paths: estimation free runs
    complexity: dict[str, Any] | None = None
    spaces = [int(o.get("max_lag", cfg.max_lag)) for o in outs]
    if cfg.selection == "fr_est":  # the network size among the runs' candidates (streamid.engine.choice.complexity)
        chosen, complexity = choose_complexity(models, scores, n, spaces)
        if cfg.prune_runs:  # the best runs' pruned networks compete too (CoEAConfig.prune_runs)
            ranked = sorted((c for c in complexity["candidates"] if c["criterion"] is not None),
                            key=lambda c: (c["criterion"], c["run"]))[: cfg.prune_runs]
            for c in ranked:
                i = int(c["run"])
                models[i], scores[i], paths[i] = pruned_choice(cfg, models[i], scores[i], ua, ya, RANGE_MARGIN, paths[i],
                                                               KEEP_PATHS_ROWS)
            chosen, complexity = choose_complexity(models, scores, n, spaces)
    else:
        chosen = int(np.argmax(scores))
    final, score = models[chosen], float(outs[chosen]["score"])
    if cfg.run_ensembles and complexity is not None:  # means of the best runs compete (streamid.engine.choice.ensemble_choice)
        # a mean's one-step MSE (metrics.fitness) is made only if it stays (_settled): the refinement or the median
        # replaces it otherwise (a pass of every member's one-step prediction over the record saved)
        ens, members, complexity["ensembles"] = choose_ensemble(models, paths, complexity, ua, ya, RANGE_MARGIN, post,
                                                                fitness=False)
        if ens is not None:  # the state and history are the best member's run's (a warm start is one run's)
            final, chosen, score = ens, members[0], float(ens.metrics["ensemble"]["r2_fr_est"])
    del paths  # the runs' estimation free runs: read by the choices above only
    for o in outs:
        o.pop("path", None)
    own = scores[chosen] if final is models[chosen] else score
    if cfg.long_linear and complexity is not None and own < MORE_BELOW:  # a dense linear ARX part competes
        final = _settled(final, ua, ya, post)
        offered = [(int(c["run"]), models[int(c["run"])]) for c in complexity["candidates"] if c["criterion"] is not None]
        ll, complexity["long_linear"] = long_linear_choice(final, own, cfg.long_linear, ua, ya,
                                                           RANGE_MARGIN, RIDGE, offered, chosen)
        if ll is not None:  # the state and history are the run's whose network it keeps
            final, score, chosen = ll, float(complexity["long_linear"]["r2_fr_est"]), int(complexity["long_linear"]["run"])
    robust: Model | None = None
    if no_median_here and complexity is not None:  # its cost grows with the record: not made
        fewer = f"; {made_restarts} of the {cfg.restarts} restarts made (the others feed only the median)"
        complexity["robust"] = {"combine": "median", "taken": False,
                                "reason": ROBUST_BEYOND + (fewer if made_restarts < cfg.restarts else "")}
    elif cfg.run_ensembles and complexity is not None:  # the finished runs' median (streamid.engine.choice.robust)
        robust, complexity["robust"] = robust_choice(final, models, [float(o["score"]) for o in outs], cfg, ua, ya,
                                                     post)
        if robust is not None:  # its members each refined already; the state and history stay the chosen run's
            final, score = robust, complexity["robust"]["r2_fr_est"]
    # the kept model's one-step predictions over the record, where the refinement or _settled make them (its
    # metrics.fitness): handed to the validation (Result.extra["osa_predictions_est"]), which need not make them
    # again; kept up to KEEP_PATHS_ROWS rows (8 MiB)
    osa: dict[str, Any] | None = {} if n <= KEEP_PATHS_ROWS else None
    if cfg.refine_iterations and robust is None:  # the weights fitted to the free run (streamid.engine.choice.refine)
        final, refined = refine_judged(final, ua, ya, cfg.refine_iterations, REFINE_ABOVE, RANGE_MARGIN,
                                       threads=post, keep_osa=osa)
        follows = osa is not None and osa.get("of") is final  # the refined model's predictions: they follow it to its metrics
        final = final.with_metrics(refinement=refined, **({"fitness": refined["osa_mse_est"]} if refined["taken"] else {}))
        if follows and osa is not None:
            osa["of"] = final
    final = _settled(final, ua, ya, post, osa)  # a mean's one-step MSE where the refinement did not replace it
    osa_est = osa["osa"] if osa and osa["of"] is final else None  # the predictions of this very model only
    final = with_interval(final, ua, ya, RIDGE, post)  # its free-run interval, calibrated on a held-out half
    final = final.with_metrics(
        restarts=len(outs),
        restarts_max=cfg.restarts,
        **({"restarts_made": {"runs": made_restarts, "reason": LONG_RUNS_REASON}}
           if made_restarts < cfg.restarts else {}),
        more_restarts=more_made,
        run_neurons=[int(o.get("neurons", cfg.neurons)) for o in outs],
        fallback_runs=fallback_made,
        run_max_lags=[int(o.get("max_lag", cfg.max_lag)) for o in outs],
        run_scores=[float(o["score"]) for o in outs],
        run_lag_rules=[str(o.get("lag_rule", "search")) for o in outs],
        selection=cfg.selection,
        selection_score=score,
        evaluations=int(sum(o["evaluations"] for o in outs)),
        max_lag_choice=lag_evidence,
        **({"feedthrough": feed} if feed is not None else {}),
        **({"search_rows": outs[chosen]["search_rows"]} if outs[chosen].get("search_rows") else {}),
        complexity=complexity,
    )
    runs = tuple(
        RunSummary(o["seed"], o["fitness"], o["evaluations"], o["seconds"], o["score"], m.lags)
        for o, m in zip(outs, models)
    )
    return Result(
        model=final,
        state=st if isinstance(st := outs[chosen]["state"], CoEAState) else CoEAState.from_json(st),
        fitness_history=np.asarray(outs[chosen]["history"]),
        evaluations=int(sum(o["evaluations"] for o in outs)),
        seconds=time.perf_counter() - t_start,
        runs=runs,
        chosen=chosen,
        extra={"run_models": tuple(models), **({"osa_predictions_est": osa_est} if osa_est is not None else {})},
    )
