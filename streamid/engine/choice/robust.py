"""The restarts' finished models combined by their per-sample median: one run that leaves the next waveform moves
the median little (docs/engine-results.md, issue 37 round 3: nothing on the estimation record tells which run will).

Each admissible run's network is given the final stage as if it were the kept model: a long linear part where the
networks explain the record in part (:func:`~streamid.engine.choice.longlinear.long_linear_choice`), then the
free-run refinement judged out of sample (:func:`~streamid.engine.choice.refine.refine_judged`). Their median is a
``streamid.model/6`` :class:`~streamid.model.ensemble.EnsembleModel` (``combine="median"``).
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
from streamid.model.narx import Model

__all__ = ["ADMISSIBLE_ABOVE", "MIN_RUNS", "finish", "median_of_finished"]

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
    base = finished[0]
    return ensemble_of(finished, combine="median", normalisation=base.normalisation, input_names=base.input_names,
                       output_name=base.output_name), {**ev, "finished": steps}
