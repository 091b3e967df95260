"""The restarts' finished models combined by their per-sample median: one run that leaves the next waveform moves
the median little (docs/engine-results.md, issue 37 round 3: nothing on the estimation record tells which run will).

Each admissible run's network is given the final stage as if it were the kept model: a long linear part where the
networks explain the record in part (:func:`~streamid.engine.choice.longlinear.long_linear_choice`), then the
free-run refinement judged out of sample (:func:`~streamid.engine.choice.refine.refine_judged`). Their median is a
``streamid.model/6`` :class:`~streamid.model.ensemble.EnsembleModel` (``combine="median"``).

:func:`robust_choice` is the identification's last choice (issue 51, "robust by default"): the median replaces the
kept model unless that one carries a long linear part (offered only where the networks alone free-run the
estimation record below ``MORE_BELOW``: the F-16's, where the median of networks lost 0.047 of a real record's
median R^2). Measured on the saved models of the suite before it was the rule (docs/benchmarks.md, "A rule scored on
the saved models").
"""

from __future__ import annotations

from typing import Any

import numpy as np
from numpy.typing import NDArray

from streamid.engine.choice.longlinear import long_linear_choice
from streamid.engine.choice.refine import ABOVE as REFINE_ABOVE, refine_judged
from streamid.engine.choice.scores import RANGE_MARGIN
from streamid.engine.settings import MORE_BELOW, RIDGE, CoEAConfig
from streamid.model.ensemble import MAX_MEMBERS, ensemble_of, members_of
from streamid.model.freerun import chunked_runs
from streamid.model.limits import CHUNK_ROWS
from streamid.model.narx import Model

__all__ = ["ADMISSIBLE_ABOVE", "LONG_RUNS", "LONG_RUNS_REASON", "MIN_RUNS", "ROBUST_BEYOND", "carries_long_linear",
           "finish", "median_of_finished", "robust_choice"]

#: Why a record beyond one chunk keeps the chosen model (streamid.engine.identification): every run finished, and
#: the median's free run and one-step prediction over every row, took 9,000,000 samples 49.5 -> 94.7 s (issue 53's
#: bound 60 s; 1,000,000: 19.1 s against 12-14 s without it), and no long record has measured what the median earns.
ROBUST_BEYOND = "a record beyond one chunk (65,536 rows): the median's cost grows with the record; the chosen model kept"

#: Most restarts made on a record beyond one chunk when ``run_ensembles`` would make the median up to one chunk: the
#: restarts past these feed the median (eight finished networks reach FROLS on the Bouc-Wen benchmark's multisine
#: where four did not: docs/benchmarks.md, issue 51), which is not made there (:data:`ROBUST_BEYOND`), and each costs
#: a sampled search (1,000,000 samples: 16.9 s with eight runs against 9.4-9.9 s with four; issue 53's bound 10 s).
LONG_RUNS = 4
#: What ``metrics.restarts_made`` says when fewer than ``restarts`` runs were made for that reason.
LONG_RUNS_REASON = (f"a record beyond one chunk (65,536 rows): the restarts past {LONG_RUNS} feed the median of the "
                    "finished restarts, which is not made there")

#: Fewest finished runs a median is made of (two: the median is their mean; fewer: the kept model stands).
MIN_RUNS = 3
#: A run is admissible when its score (estimation free-run R^2 of its chosen candidate) is above this (the search
#: scores a run with no admissible candidate -1e9).
ADMISSIBLE_ABOVE = -1e8


def finish(model: Model, score: float, cfg: CoEAConfig, u: NDArray[np.float64], y: NDArray[np.float64],
           threads: int = 1) -> tuple[Model, dict[str, Any]]:
    """``model`` (one run's network) given the final stage: a long linear part when it explains the record in part,
    then the refinement; the evidence of each step."""
    ev: dict[str, Any] = {}
    if cfg.long_linear and score < MORE_BELOW:
        ll, ev["long_linear"] = long_linear_choice(model, score, cfg.long_linear, u, y, RANGE_MARGIN, RIDGE)
        if ll is not None:
            model = ll
    if cfg.refine_iterations:
        model, ev["refinement"] = refine_judged(model, u, y, cfg.refine_iterations, REFINE_ABOVE, RANGE_MARGIN,
                                                threads=threads)
    return model, ev


def median_of_finished(models: list[Model], scores: list[float], cfg: CoEAConfig, u: NDArray[np.float64],
                       y: NDArray[np.float64], threads: int = 1) -> tuple[Model | None, dict[str, Any]]:
    """The median of the admissible runs' finished networks (None: fewer than :data:`MIN_RUNS` are admissible),
    and the evidence (``metrics.robust``: the runs taken and what their final stage did)."""
    runs = [i for i, s in enumerate(scores) if s > ADMISSIBLE_ABOVE]
    ev: dict[str, Any] = {"combine": "median", "runs": runs, "min_runs": MIN_RUNS}
    if len(runs) < MIN_RUNS:
        return None, {**ev, "reason": f"{len(runs)} admissible run(s); a median needs {MIN_RUNS}"}
    finished: list[Model] = []
    steps: list[dict[str, Any]] = []
    for i in runs:
        m, step = finish(members_of(models[i])[0], scores[i], cfg, u, y, threads)
        finished.extend(members_of(m))
        steps.append({"run": i, "long_linear": bool((step.get("long_linear") or {}).get("taken")),
                      "refined": bool((step.get("refinement") or {}).get("taken"))})
    finished = finished[:MAX_MEMBERS]
    base, first = finished[0], models[runs[0]]  # the document's config and window: the identification's
    return ensemble_of(finished, combine="median", normalisation=base.normalisation, input_names=base.input_names,
                       output_name=base.output_name, config=first.config, window=first.window), {**ev, "finished": steps}


def carries_long_linear(model: Model) -> bool:
    """Whether ``model`` (a network or an ensemble) has a long linear part (:mod:`~streamid.engine.choice.longlinear`)."""
    return any(m.linear_regressors is not None for m in members_of(model))


def robust_choice(kept: Model, models: list[Model], scores: list[float], cfg: CoEAConfig, u: NDArray[np.float64],
                  y: NDArray[np.float64], threads: int = 1) -> tuple[Model | None, dict[str, Any]]:
    """The model that replaces ``kept`` (the choice among the runs, its ensemble or long linear part), or None, and
    the evidence (``metrics.robust``): the median of the finished runs (:func:`median_of_finished`) unless ``kept``
    carries a long linear part or fewer than :data:`MIN_RUNS` runs are admissible. The median comes with its free-run
    R^2 on the estimation record (``r2_fr_est``, None when it left the numbers) and its one-step MSE (``fitness``),
    both made a chunk at a time."""
    if carries_long_linear(kept):
        return None, {"combine": "median", "taken": False, "reason": "the kept model carries a long linear part"}
    med, ev = median_of_finished(models, scores, cfg, u, y, threads)
    if med is None:
        return None, {**ev, "taken": False}
    L = med.max_lag
    sse = ss = sse_osa = 0.0
    mean = float(np.mean(y[L:]))
    finite = True
    for a, _, centre, _ in chunked_runs(med, u, y[:L], CHUNK_ROWS, threads, far=False):
        b, s = a + centre.shape[0], max(a, L)
        if s >= b:
            continue
        with np.errstate(over="ignore", invalid="ignore"):
            fr = centre[s - a :]
            finite = finite and bool(np.all(np.isfinite(fr)))
            sse += float(np.sum((y[s:b] - fr) ** 2)) if finite else 0.0
        ss += float(np.sum((y[s:b] - mean) ** 2))
        osa = med.predict_osa(u[s - L : b], y[s - L : b], threads=threads)[L:]
        sse_osa += float(np.sum((osa - y[s:b]) ** 2))
    if not (finite and ss > 0):
        return None, {**ev, "taken": False, "reason": "the median's free run left the numbers on the estimation record"}
    ev = {**ev, "taken": True, "r2_fr_est": 1.0 - sse / ss}
    steps = ev["finished"]
    refined = {"gate": None, "iterations": 0, "taken": False,  # what the kept model's own step says, for every reader
               "reason": f"not as a whole: each of its {len(steps)} networks was finished on its own, "
                         f"{sum(1 for st in steps if st['refined'])} of them refined (metrics.robust)"}
    return med.with_metrics(fitness=sse_osa / max(1, len(y) - L), robust=ev, refinement=refined), ev
