"""``identify``: one identification, possibly several coevolution runs chosen among.

Strategies (``CoEAConfig.restarts``, ``selection``, ``workers``)
-----------------------------------------------------------------
* ``restarts=1, selection="fitness"`` -- the paper's procedure: one
  :class:`~streamid.engine.coevolution.Coevolution` on all the estimation data,
  the best pair ever evaluated, weights refitted. Runs in this process and
  reports every generation to the callback.
* otherwise ``restarts`` independent runs (seeds drawn from ``rng``; two-stage
  when ``lag_search_neurons > 0``, see :class:`~streamid.engine.settings.CoEAConfig`) in
  ``workers`` processes (spawned, never forked: the caller may hold a Zenoh
  session) or in this process. Each run offers candidates -- its best pair and
  every parameter vector of its final population paired with the best harmony
  (weights refitted) -- and the selection rule picks one per run, then one overall:

  - ``"fr_est"``: highest free-run R^2 on the estimation data, simulated from
    its first samples (the OSA-trained candidates differ most in how their free
    runs hold up; this choice removes the runs whose simulation drifts);
  - ``"holdout_fr"``: the runs search on the first ``1 - holdout_fraction`` of
    the estimation data; highest free-run R^2 over the held-out tail; the chosen
    structure's weights are then refitted on all the estimation data;
  - ``"fitness"``: lowest OSA MSE.

The normalisation is always the min/max of all the estimation data. Validation
data are never looked at.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from concurrent.futures import Executor
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from streamid.engine._blas import one_blas_thread
from streamid.engine.choice import free_run_scores
from streamid.engine.coevolution import CoEAState, Coevolution, Progress, _as_rng
from streamid.engine.fanout import fan_out
from streamid.engine.settings import DEFAULT, CoEAConfig
from streamid.engine.model import Model, free_run
from streamid.engine.parallel import EvalHelper
from streamid.engine.rbf import activations, fit_weights
from streamid.engine.regressors import Normalisation, as_data
from streamid.engine.validation import r2
from streamid.errors import ConfigError, DataError

__all__ = ["Result", "RunSummary", "free_run_r2", "identify", "identify_each", "refit_weights", "select_model"]


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


def refit_weights(model: Model, u: ArrayLike, y: ArrayLike, ridge: float, weight_decay: float = 0.0) -> Model:
    """The same structure with output weights refitted on ``(u, y)`` (model's normalisation).

    The fit uses rows ``t >= max(model.max_lag, start)``; see :func:`~streamid.engine.rbf.fit_weights`.
    """
    ua, ya = as_data(u, y, min_samples=model.max_lag + model.neurons + 1)
    un, yn = model.normalisation.u(ua), model.normalisation.y(ya)
    L, n = model.max_lag, ya.shape[0]
    r = np.empty((n - L, len(model.regressors)))
    for j, reg in enumerate(model.regressors):
        src = yn if reg.signal == "y" else un[:, reg.index]
        r[:, j] = src[L - reg.lag : n - reg.lag]
    with one_blas_thread():
        phi = activations(r, model.centres, model.widths)
        w = fit_weights(phi, yn[L:], ridge, weight_decay)
    if not np.all(np.isfinite(w)):
        raise DataError("refitted weights are not finite (numerically degenerate data)")
    mse = float(np.mean((phi @ w - yn[L:]) ** 2)) * model.normalisation.y_half_range**2
    from dataclasses import replace

    return replace(model, weights=w, metrics={**model.metrics, "fitness": mse})


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
        groups.setdefault((m.regressors, m.normalisation), []).append(i)
    for (regs, norm), idx in groups.items():
        L = max((r.lag for r in regs), default=0)
        first = L if score_from is None else score_from
        if first < L:
            raise DataError(f"free-run scoring from sample {first} needs max_lag = {L} earlier samples")
        us, ys = u[first - L :], y[first - L :]
        sim = free_run(
            regs,
            np.stack([models[i].centres for i in idx]),
            np.stack([models[i].widths for i in idx]),
            np.stack([models[i].weights for i in idx]),
            norm.u(us),
            np.broadcast_to(norm.y(ys[:L]), (len(idx), L)),
        )
        for k, i in enumerate(idx):
            out[i] = r2(ys[L:], norm.y_inverse(sim[k, L:]))
    return out


def select_model(
    run: Coevolution,
    u: NDArray[np.float64],
    y: NDArray[np.float64],
    selection: str,
    *,
    n_search: int | None = None,
    range_margin: float | None = None,
) -> tuple[Model, float]:
    """The model of a finished run by the selection rule, and its score (higher is better).

    The one final-model choice of streamid: :func:`identify` and the online
    updates (:mod:`streamid.online.update`) both call it.

    * ``"fitness"``: the run's best pair (lowest one-step-ahead error, the paper's
      choice); score = -fitness.
    * ``"fr_est"``: of the best pair and the final population, the highest
      free-run R^2 on ``u[:n_search], y[:n_search]`` among the candidates whose
      free run stays in the data's range (:mod:`streamid.engine.choice`).
    * ``"holdout_fr"``: the same, the free run simulated over all the data from
      its start and scored over the held-out tail ``[n_search:]``.

    ``n_search`` defaults to all the data; ``range_margin`` to the run's
    ``config.range_margin``. A run with no candidate in range scores below
    -1e9 (any run with one wins over it); its model says ``admissible: 0``.
    """
    best = run.best_model()
    if selection == "fitness":
        return best, -float(best.metrics["fitness"])
    if selection not in ("fr_est", "holdout_fr"):
        raise ConfigError(f"selection must be one of 'fitness', 'fr_est', 'holdout_fr'; got {selection!r}")
    n = len(y) if n_search is None else int(n_search)
    margin = run.config.range_margin if range_margin is None else float(range_margin)
    cands = [best, *run.population_models(run.config.fr_candidates or None)]
    with one_blas_thread():
        if selection == "fr_est":
            fr = free_run_scores(cands, u[:n], y[:n], range_margin=margin)
        else:
            fr = free_run_scores(cands, u, y, score_from=n, range_margin=margin)
    k = fr.best()
    score = fr.scores[k] if fr.admissible else -1e9 * (1.0 + min(fr.excursions[k], 1e6))  # finite: JSON-able
    return cands[k].with_metrics(free_run_choice=fr.evidence(k)), float(score)


def _stage(
    tick: Callable[[Progress], object] | None, gen0: int, evals0: int
) -> Callable[[Progress], object] | None:
    """A stage's per-generation callback reporting the run's generations and evaluations so far."""
    if tick is None:
        return None
    return lambda p: tick(Progress(gen0 + p.generation, p.generations, p.best_fitness, evals0 + p.evaluations))


def _one_run(job: dict[str, Any], helper: EvalHelper | None = None) -> dict[str, Any]:
    """One coevolution run and its candidate chosen by the selection rule (also a worker's body)."""
    cfg = CoEAConfig.from_dict(job["config"])
    if job.get("neurons", cfg.neurons) != cfg.neurons:  # this restart's complexity (neuron_alternatives)
        cfg = cfg.replace(neurons=int(job["neurons"]))
    norm = Normalisation.from_dict(job["normalisation"])
    warm = CoEAState.from_json(job["warm_start"]) if job.get("warm_start") else None
    u, y, n_search = job["u"], job["y"], job["n_search"]
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
    n_rows = n_search - cfg.max_lag
    if cfg.search_rows and n_rows > cfg.search_rows:  # a large record: the search sees a random sample of rows
        common["rows"] = np.sort(rng.choice(n_rows, cfg.search_rows, replace=False))
    evaluations = 0
    if cfg.lag_search_neurons and warm is None:
        # Two-stage run: a small network's coevolution chooses the lags...
        lag_cfg = cfg.replace(
            neurons=cfg.lag_search_neurons, generations=cfg.lag_search_generations, harmony_stop=1.0
        )
        lag_run = Coevolution(u[:n_search], y[:n_search], lag_cfg, rng, **common).solve(_stage(tick, 0, 0))
        evaluations = lag_run.evaluations
        # ...then DE trains the full network on those lags.
        run = Coevolution(u[:n_search], y[:n_search], cfg, rng, fixed_mask=lag_run.best_h, **common).solve(
            _stage(tick, lag_cfg.generations, evaluations))
    else:
        run = Coevolution(u[:n_search], y[:n_search], cfg, rng, warm_start=warm, **common).solve(_stage(tick, 0, 0))
    evaluations += run.evaluations
    model, score = select_model(run, u, y, cfg.selection, n_search=n_search)
    return {
        "seed": job["seed"],
        "model": model.to_json(indent=None),
        "state": run.state().to_json(),
        "history": list(run.history),
        "evaluations": evaluations,
        "seconds": time.perf_counter() - t0,
        "fitness": float(run.best_f),
        "score": score,
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
        instead of creating one when ``config.workers > 1``.
    helper : EvalHelper, optional
        A started :class:`~streamid.engine.parallel.EvalHelper`: runs made in this
        process evaluate half of every population batch in it (the second core).
        The result is the same with or without it.

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
    gen = _as_rng(rng)
    ua, ya = as_data(u, y)
    names = tuple(input_names) if input_names else tuple(f"u{i}" for i in range(ua.shape[1]))
    win = dict(window) if window else {"n_samples": int(ya.shape[0])}

    n = ya.shape[0]
    n_hold = int(round(cfg.holdout_fraction * n)) if cfg.selection == "holdout_fr" else 0
    n_search = n - n_hold
    need = cfg.max_lag + 2 * max((cfg.neurons, *cfg.neuron_alternatives))
    if n_hold and n_hold < max(cfg.max_lag + 10, 20):
        raise DataError(
            f"the hold-out of {n_hold} samples (holdout_fraction {cfg.holdout_fraction} of {n}) is too short "
            f"to choose by free-run R^2; it needs >= {max(cfg.max_lag + 10, 20)} samples "
            "(more data, a larger holdout_fraction, or another selection)"
        )
    if n_search < need:
        raise DataError(
            f"{n_search} estimation samples are too few (after any hold-out): with max lag {cfg.max_lag} and "
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
        return Result(
            model=model.with_metrics(restarts=1, selection="fitness"),
            state=run.state(),
            fitness_history=np.asarray(run.history),
            evaluations=run.evaluations,
            seconds=time.perf_counter() - t_start,
            runs=(summary,),
            chosen=0,
        )

    seeds = [int(s) for s in gen.integers(0, 2**63 - 1, size=cfg.restarts)]
    sizes = (cfg.neurons, *cfg.neuron_alternatives)
    base = {
        "config": cfg.to_dict(),
        "normalisation": norm.to_dict(),
        "u": ua,
        "y": ya,
        "n_search": n_search,
        "input_names": list(names),
        "output_name": output_name,
        "window": win,
    }
    jobs = [
        {**base, "seed": s, "warm_start": warm_start.to_json() if (warm_start is not None and i == 0) else None,
         "neurons": sizes[i % len(sizes)]}
        for i, s in enumerate(seeds)
    ]
    per_run = cfg.generations + (cfg.lag_search_generations if cfg.lag_search_neurons else 0)
    total_gen = per_run * cfg.restarts
    done: list[dict[str, Any]] = []  # finished runs (in-process progress)
    if callback is not None and executor is None and min(cfg.workers, len(jobs)) <= 1:
        for i, job in enumerate(jobs):  # runs made here report every generation, as the one-run path does
            job["tick"] = lambda p, i=i: callback(Progress(
                i * per_run + p.generation, total_gen, min([p.best_fitness] + [o["fitness"] for o in done]),
                sum(o["evaluations"] for o in done) + p.evaluations))

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

    # Fewer restarts when they agree: with agree_tol > 0 the first two runs are made, and the others only
    # if their scores differ by more than agree_tol (or one has no admissible candidate).
    first = jobs[:2] if cfg.agree_tol > 0 else jobs
    outs = fan_out(_one_run, first, cfg.workers, executor=executor, helper=helper, on_result=report)
    if len(first) < len(jobs):
        sc = [o["score"] for o in outs]
        if not (min(sc) > -1e9 and max(sc) - min(sc) <= cfg.agree_tol):
            made = list(outs)
            outs = made + fan_out(_one_run, jobs[len(first) :], cfg.workers, executor=executor, helper=helper,
                                  on_result=lambda rs: report(made + rs))

    models = [Model.from_json(o["model"]) for o in outs]
    chosen = int(np.argmax([o["score"] for o in outs]))
    final = models[chosen]
    if n_hold:
        final = refit_weights(final, ua, ya, cfg.ridge, cfg.weight_decay)
    final = final.with_metrics(
        restarts=len(outs),
        restarts_max=cfg.restarts,
        run_neurons=[int(j["neurons"]) for j in jobs[: len(outs)]],
        run_scores=[float(o["score"]) for o in outs],
        selection=cfg.selection,
        selection_score=outs[chosen]["score"],
        holdout_samples=n_hold,
        evaluations=int(sum(o["evaluations"] for o in outs)),
    )
    runs = tuple(
        RunSummary(o["seed"], o["fitness"], o["evaluations"], o["seconds"], o["score"], m.lags)
        for o, m in zip(outs, models)
    )
    return Result(
        model=final,
        state=CoEAState.from_json(outs[chosen]["state"]),
        fitness_history=np.asarray(outs[chosen]["history"]),
        evaluations=int(sum(o["evaluations"] for o in outs)),
        seconds=time.perf_counter() - t_start,
        runs=runs,
        chosen=chosen,
    )


def identify_each(
    u: ArrayLike,
    ys: ArrayLike,
    config: CoEAConfig | None = None,
    rng: np.random.Generator | int | None = None,
    *,
    output_names: tuple[str, ...] | None = None,
    **kwargs: Any,
) -> list[Result]:
    """Several outputs: one model per output (each column of ``ys`` identified from ``u``).

    Parameters
    ----------
    u : array_like, shape (N,) or (N, n_inputs)
    ys : array_like, shape (N, n_outputs)
    config, rng :
        As :func:`identify`; the outputs use successive draws of one generator.
    output_names : tuple of str, optional
    **kwargs :
        Passed to :func:`identify` (not ``output_name``).
    """
    ya = np.asarray(ys, dtype=np.float64)
    if ya.ndim == 1:
        ya = ya[:, None]
    if ya.ndim != 2:
        raise DataError(f"ys must have shape (N, n_outputs); got {ya.shape}")
    names = output_names or tuple(f"y{i}" for i in range(ya.shape[1]))
    if len(names) != ya.shape[1]:
        raise ConfigError(f"{len(names)} output names given for {ya.shape[1]} outputs")
    gen = _as_rng(rng)
    return [identify(u, ya[:, i], config, gen, output_name=names[i], **kwargs) for i in range(ya.shape[1])]
