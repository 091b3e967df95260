"""Complexity chosen by the data: an information criterion on the estimation free run.

The rule (every choice among candidates of ``selection="fr_est"``; applied by :func:`~streamid.engine.identification.identify`
to the runs' chosen candidates, each a network of its own size and lag space)
--------------------------------------------------------------------------------------------
Every run offers one candidate (its best by the selection rule, range guard included).
Its network size -- the number of neurons ``M`` (30 on the lags ``1..L`` chosen from
the data, 10 or 30 on ``1..10`` for the hedged restarts, 15 then 8 for the fallback
runs), the lag space and whether it has a linear part -- is then chosen among the
admissible candidates by AIC::

    AIC = n log(1 - R2_fr) + 2 p,       p = M (+ k + 1 with a linear part)

with ``R2_fr`` the candidate's free-run R^2 over the ``n`` scored samples of the
estimation record (the same simulation the range guard judged) and ``p`` the
parameters fitted by least squares on that record: one output weight per neuron,
plus the linear part's ``k`` coefficients and constant. A candidate that is not admissible is never chosen while one is.

Why ``p = M`` (and not the centres and widths too), and what the pruning measured: docs/method.md ("Complexity by an
information criterion", "Pruned networks compete") and docs/engine-results.md.

Pruned networks (``CoEAConfig.prune_runs = K``, 2 by default): the ``K`` best runs by the
criterion also offer their networks of ``M // 3`` and ``2 M // 3`` neurons, the neurons
taken in forward-selection order (:func:`ols_order`: orthogonal least squares on the
estimation data, the classical way of choosing an RBF network's centres) and the
weights refitted. Each competes with its parent by the same criterion on the estimation
free run, range guard included (``metrics.neuron_choice``), then the runs as above.

Every candidate's size, lag space, ``p``, ``R2_fr`` and criterion value are in the
model's ``metrics.complexity`` and the ``streamid identify`` report.
"""

from __future__ import annotations

import math
from dataclasses import replace
from typing import Any

import numpy as np
from numpy.typing import NDArray

from streamid.model.ensemble import members_of
from streamid.model.narx import Model
from streamid.model.regressors import as_data, regressors_at
from streamid.engine.fit.rbf import activations, fit_linear_rbf, fit_weights
from streamid.errors import ModelFormatError

__all__ = ["RULE", "choose", "criterion", "ols_order", "parameter_count", "pruned"]

#: The criterion's name in the evidence (``metrics.complexity.rule``) and the report.
RULE = "aic"

_ADMISSIBLE = -1e9  # a run's score at or below this has no admissible candidate (streamid.engine.choice.selection)


def parameter_count(model: Model) -> float:
    """Parameters fitted by least squares on the estimation record: ``M`` weights (+ the linear part's
    coefficients); of an ensemble, the mean of its members' counts: each member's weights are a least squares on
    the same record, and the mean of least-squares fits has the mean of their degrees of freedom (the trace of
    the mean of their hat matrices; docs/engine-results.md, round 14)."""
    counts = [m.neurons + (0 if m.linear is None else int(m.linear.shape[0])) for m in members_of(model)]
    return counts[0] if len(counts) == 1 else sum(counts) / len(counts)


def criterion(r2_fr: float, n_scored: int, params: float) -> float:
    """AIC (lower is better) of a candidate of free-run R^2 ``r2_fr`` over ``n_scored`` samples and ``params``
    weights fitted: ``n log(1 - R2_fr) + 2 p``."""
    err = max(1.0 - r2_fr, 1e-12)  # relative free-run error (an R^2 of 1 to rounding: bounded)
    return n_scored * math.log(err) + 2.0 * params


def choose(models: list[Model], scores: list[float], n: int, lag_spaces: list[int]) -> tuple[int, dict[str, Any]]:
    """Index of the chosen candidate among the runs' and the evidence (JSON-able).

    ``scores``: each run's selection score (free-run R^2 on the estimation record;
    <= -1e9: no admissible candidate); ``n``: estimation samples; ``lag_spaces``:
    each run's largest candidate lag.
    """
    ok = [i for i, s in enumerate(scores) if s > _ADMISSIBLE]
    rows: list[dict[str, Any]] = []
    for i, (m, s) in enumerate(zip(models, scores)):
        p = parameter_count(m)
        ns = n - m.max_lag
        value = criterion(s, ns, p) if i in ok else None
        rows.append({"run": i, "neurons": m.neurons, "lag_space": int(lag_spaces[i]), "terms": len(m.regressors),
                     "linear": m.linear is not None, "params": p,
                     "r2_fr_est": float(s) if i in ok else None, "criterion": value})
    if ok:
        k = min(ok, key=lambda i: (rows[i]["criterion"], i))
    else:  # nothing admissible: the run whose candidate leaves the range least (the highest score)
        k = max(range(len(scores)), key=lambda i: (scores[i], -i))
    ev = {"rule": RULE, "chosen_run": k, "neurons": models[k].neurons, "params": rows[k]["params"],
          "candidates": rows}
    return k, ev


def ols_order(phi: NDArray[np.float64], target: NDArray[np.float64]) -> list[int]:
    """Columns of ``phi`` in forward-selection order (orthogonal least squares, Chen, Cowan & Grant 1991).

    Each step takes the column whose part orthogonal to those already taken explains
    the most of what is left of ``target`` (the largest error reduction). Computed on
    the Gram matrix (``phi' phi``, ``phi' target``; each step a Schur complement), so its
    cost does not grow with the rows beyond one product. Columns with nothing left
    (below 1e-10 of their own norm) come last, in index order.
    """
    G = phi.T @ phi
    b = phi.T @ target
    scale = np.maximum(np.diag(G).copy(), 1e-300)
    order: list[int] = []
    free = np.ones(G.shape[0], dtype=bool)
    for _ in range(G.shape[0]):
        d = np.diag(G)
        live = free & (d > 1e-10 * scale)
        if not live.any():
            break
        gain = np.where(live, b * b / np.where(live, d, 1.0), -1.0)
        j = int(np.argmax(gain))
        order.append(j)
        free[j] = False
        g = G[:, j] / G[j, j]
        b = b - g * b[j]
        G = G - np.outer(g, G[j, :])
    return order + [int(j) for j in np.flatnonzero(free)]


def pruned(model: Model, u: NDArray[np.float64], y: NDArray[np.float64], sizes: tuple[int, ...],
           ridge: float, rows: NDArray[np.intp] | None = None) -> list[Model]:
    """Smaller networks made of ``model``'s first neurons in :func:`ols_order` on ``(u, y)``, weights refitted.

    One network per size in ``sizes`` below ``model.neurons`` (same regressors, centres
    and widths of the neurons kept; a linear part, if any, refitted with the weights). ``rows``: the order and the
    fits on those regressor rows only (a record beyond one chunk: :func:`~streamid.engine.search.rows.spaced_rows`).
    """
    _single("pruned", model)
    if model.linear_regressors is not None:
        raise ModelFormatError("pruned takes networks whose linear part (if any) is on their own regressors; "
                               "got one with a long linear part")
    if rows is None:
        r, target = model.regressor_rows(u, y)
    else:  # only those rows' regressors (not every row's, then a few: a long record's memory)
        ua, ya = as_data(u, y, copy=False)
        samples = np.asarray(rows, dtype=np.intp) + model.max_lag
        r, target = regressors_at(model.normalisation, model.regressors, ua, ya, samples), model.normalisation.y(ya[samples])
    phi = activations(r, model.centres, model.widths)
    order = ols_order(phi, target)
    out: list[Model] = []
    for m in sorted({s for s in sizes if 1 <= s < model.neurons}):
        keep = np.sort(np.asarray(order[:m], dtype=np.intp))
        lin = None
        if model.linear is None:
            w = fit_weights(phi[:, keep], target, ridge)
        else:
            w, lin = fit_linear_rbf(phi[:, keep], r, target, ridge)
        fit = phi[:, keep] @ w + (0.0 if lin is None else r @ lin[:-1] + lin[-1])
        mse = float(np.mean((fit - target) ** 2)) * model.normalisation.y_half_range**2
        if np.all(np.isfinite(w)) and (lin is None or np.all(np.isfinite(lin))) and math.isfinite(mse):
            out.append(replace(model, centres=model.centres[keep], widths=model.widths[keep], weights=w, linear=lin,
                               metrics={**model.metrics, "fitness": mse}))
    return out


def _single(what: str, model: Model) -> None:
    """Refuse an ensemble where one network's neurons are worked on."""
    if len(members_of(model)) > 1:
        raise ModelFormatError(f"{what}() works on one network; got an ensemble of {len(members_of(model))} "
                               "(apply it to model.members[i])")
