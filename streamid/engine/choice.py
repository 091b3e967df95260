"""The final choice among candidate models: free-run scores with a range guard.

The rule (the one place it is applied; :func:`~streamid.engine.identification.select_model`
and through it :func:`~streamid.engine.identification.identify` and the online updates use it)
------------------------------------------------------------------------------------------
Every candidate is simulated in free run over the **whole estimation record**, from
its first ``max_lag`` measured outputs. A candidate is *admissible* when that free
run is finite and stays, at every sample, within the estimation output's range
widened by ``range_margin`` of its span on both sides
(``[min - m * span, max + m * span]``). The measured output never leaves
``[min, max]`` on that record, so a free run that does is unstable or on its way
to a wrong equilibrium; such a model is never chosen while an admissible one exists.

Score of an admissible candidate: R^2 of that same free run over the scored part
of the record (``score_from`` onwards: the held-out tail with
``selection="holdout_fr"``, everything after the initial lags with ``"fr_est"``).
One simulation gives both the guard and the score, and a held-out tail is scored
after the drift accumulated over the whole search part (stricter than a simulation
restarted just before the tail).

A candidate with no input term is not admissible either: its free run ignores the
input (an autonomous oscillator can fit an estimation record and says nothing of
another). Nor is one whose linear part has an unstable autoregression
(:mod:`streamid.engine.stability`: only a stable one bounds the free run on every input). If no candidate is admissible, the choice falls back to the candidate with the
smallest excursion beyond the widened range (the report says ``admissible: 0``).
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np
from numpy.typing import NDArray

from streamid.engine.ensemble import EnsembleModel, members_of
from streamid.engine.model import Model, free_run
from streamid.engine.rbf import activations, fit_weights
from streamid.engine.stability import is_bounded
from streamid.engine.validation import r2
from streamid.errors import DataError, ModelFormatError

__all__ = ["FreeRunScores", "blocked_cv_scores", "free_run_scores", "group_free_run", "path_score"]


def group_free_run(models: list[Model], u: NDArray[np.float64], y_init: NDArray[np.float64],
                   threads: int = 1) -> NDArray[np.float64]:
    """Free runs (normalised units, one row per model) of models sharing their regressors and normalisation,
    simulated together from the same measured initial outputs ``y_init`` (``max_lag`` of them); ``threads``:
    :func:`~streamid.engine.freerun.free_run`'s (the same result).
    Ensembles are refused (their members have their own regressors: use ``model.simulate``)."""
    if any(isinstance(m, EnsembleModel) for m in models):
        raise ModelFormatError("group_free_run simulates single networks sharing their regressors; got an ensemble "
                               "(simulate it with model.simulate, which runs each member)")
    m0 = models[0]
    if any(m.linear_regressors != m0.linear_regressors for m in models):
        raise ModelFormatError("group_free_run simulates networks sharing their regressors; got different long linear parts")
    L = m0.max_lag
    return free_run(
        m0.regressors,
        np.stack([m.centres for m in models]),
        np.stack([m.widths for m in models]),
        np.stack([m.weights for m in models]),
        m0.normalisation.u(u),
        np.broadcast_to(m0.normalisation.y(y_init[:L]), (len(models), L)),
        _linear_parts(models),
        threads=threads,
        linear_regressors=m0.linear_regressors,
    )


def _linear_parts(models: list[Model]) -> NDArray[np.float64] | None:
    """The networks' linear parts stacked (zeros for a network without one); None when none has one."""
    if all(m.linear is None for m in models):
        return None
    regs = models[0].regressors if models[0].linear_regressors is None else models[0].linear_regressors
    k = len(regs) + 1
    return np.stack([np.zeros(k) if m.linear is None else m.linear for m in models])


@dataclass(frozen=True)
class FreeRunScores:
    """Per candidate: score (R^2 over the scored part, -inf when not admissible) and excursion."""

    scores: tuple[float, ...]
    excursions: tuple[float, ...]  # largest distance beyond the widened range, in spans (0 = admissible)
    range_margin: float = 0.25
    #: Each candidate's free run over the record in output units (first ``max_lag`` measured; None: not finite).
    paths: tuple[NDArray[np.float64] | None, ...] = field(default=(), compare=False, repr=False)

    @property
    def admissible(self) -> int:
        return sum(1 for e in self.excursions if e == 0.0)

    def best(self) -> int:
        """Index of the chosen candidate (see the module docstring)."""
        if self.admissible:
            return int(np.argmax(self.scores))
        return int(np.argmin(self.excursions))

    def evidence(self, k: int) -> dict[str, Any]:
        """JSON-able: candidates, how many were admissible, the chosen one's score and excursion (None: not finite)."""

        def finite(v: float) -> float | None:
            return v if np.isfinite(v) else None

        return {
            "candidates": len(self.scores),
            "admissible": self.admissible,
            "score": finite(self.scores[k]),
            "excursion_spans": finite(self.excursions[k]),
            "range_margin": self.range_margin,
        }


def free_run_scores(
    models: list[Model],
    u: NDArray[np.float64],
    y: NDArray[np.float64],
    *,
    score_from: int | None = None,
    range_margin: float = 0.25,
    threads: int = 1,
) -> FreeRunScores:
    """Free-run scores and range guard of ``models`` on ``(u, y)`` (``u`` of shape (N, n_inputs)).

    Models sharing regressors and normalisation are simulated together (one recursion; in ``threads``
    groups at once, the same result).
    """
    if not models:
        raise DataError("no candidate models to choose from")
    lo, hi = float(np.min(y)), float(np.max(y))
    span = hi - lo
    if not span > 0:
        raise DataError(f"the output is constant over the estimation record (all values {lo!r}); nothing to score")
    scores = [-np.inf] * len(models)
    exc = [np.inf] * len(models)
    paths: list[NDArray[np.float64] | None] = [None] * len(models)
    groups: dict[tuple[Any, ...], list[int]] = {}
    for i, m in enumerate(models):
        key = (("ensemble", i) if isinstance(m, EnsembleModel)
               else (m.regressors, m.normalisation, m.neurons, m.linear_regressors))
        groups.setdefault(key, []).append(i)
    for key, idx in groups.items():
        m0 = models[idx[0]]
        L = m0.max_lag
        first = L if score_from is None else max(int(score_from), L)
        if first >= len(y) - 1:
            raise DataError(f"free-run scoring from sample {first} leaves fewer than 2 of {len(y)} samples")
        with np.errstate(over="ignore", invalid="ignore"):
            if isinstance(m0, EnsembleModel):  # each member on its own past outputs, averaged
                ys = m0.simulate(u, y[:L])[None]
            else:
                ys = m0.normalisation.y_inverse(group_free_run([models[i] for i in idx], u, y[:L], threads))
        drives = all(any(r.signal == "u" for r in mm.regressors) for mm in members_of(m0))
        for k, i in enumerate(idx):
            if not np.all(np.isfinite(ys[k, L:])):
                continue
            paths[i] = ys[k]
            if drives and is_bounded(models[i]):
                scores[i], exc[i] = path_score(ys[k], y, L, first, lo, hi, range_margin)
    return FreeRunScores(tuple(float(s) for s in scores), tuple(float(e) for e in exc), float(range_margin), tuple(paths))


def path_score(path: NDArray[np.float64], y: NDArray[np.float64], L: int, first: int, lo: float, hi: float,
               range_margin: float) -> tuple[float, float]:
    """The range guard and score of one finite free run ``path`` (output units) of ``y``: (R^2 over
    ``first:``, or -inf when not admissible; excursion beyond the widened range ``[lo, hi]`` in spans)."""
    span = hi - lo
    run = path[L:]
    beyond = max(float(run.max()) - hi, lo - float(run.min()), 0.0) / span
    e = max(beyond - range_margin, 0.0)
    return (r2(y[first:], path[first:]) if e == 0.0 else -np.inf), e


def blocked_cv_scores(
    models: list[Model],
    u: NDArray[np.float64],
    y: NDArray[np.float64],
    *,
    folds: int = 2,
    ridge: float = 1e-10,
    weight_decay: float = 0.0,
) -> list[float]:
    """Blocked cross-validated free-run R^2 of each model's structure (lags, centres, widths).

    The record is cut into ``folds`` consecutive blocks; for each block the output
    weights are refitted on the other blocks (joined end to end; the rows that would
    straddle a join are dropped) and the block is simulated in free run from its own
    first ``max_lag`` measured outputs. The score is the mean R^2 over the blocks
    (-inf when a refit or a free run is not finite): how well the structure predicts
    data its weights have not seen. It ranks complexity: a network with too many
    neurons fits its own estimation record and loses on the held-out block.
    """
    n = len(y)
    edges = [round(k * n / folds) for k in range(folds + 1)]
    total = [0.0] * len(models)
    for b in range(folds):
        a, z = edges[b], edges[b + 1]
        refits: list[Model] = []
        keep: list[int] = []
        for i, m in enumerate(models):
            if not np.isfinite(total[i]):
                continue
            parts = [(edges[k], edges[k + 1]) for k in range(folds) if k != b]
            # One least squares over the rows of every training block.
            rs, ts = [], []
            ok = True
            for lo, hi in parts:
                f = _refit_rows(m, u[lo:hi], y[lo:hi])
                if f is None:
                    ok = False
                    break
                rs.append(f[0])
                ts.append(f[1])
            w = fit_weights(np.vstack(rs), np.concatenate(ts), ridge, weight_decay) if ok else None
            if w is None or not np.all(np.isfinite(w)) or z - a <= m.max_lag + 1:
                total[i] = -np.inf
                continue
            assert w is not None
            M = m.neurons
            refits.append(replace(m, weights=w[:M], linear=None if m.linear is None else w[M:]))
            keep.append(i)
        if not refits:
            continue
        fr = _fr_r2(refits, u[a:z], y[a:z])
        for i, v in zip(keep, fr):
            total[i] = total[i] + v / folds if np.isfinite(v) else -np.inf
    return total


def _refit_rows(model: Model, u: NDArray[np.float64], y: NDArray[np.float64]) -> tuple[NDArray[np.float64], NDArray[np.float64]] | None:
    """Activations and normalised targets of ``model`` on ``(u, y)`` (rows ``t >= max_lag``)."""
    if len(y) - model.max_lag < 2:
        return None
    r, target = model.regressor_rows(u, y)
    phi = activations(r, model.centres, model.widths)
    if model.linear is not None:  # the linear part is refitted in the same least squares
        rl = r if model.linear_regressors is None else model.linear_rows(u, y)
        phi = np.hstack([phi, rl, np.ones((phi.shape[0], 1))])
    return phi, target


def _fr_r2(models: list[Model], u: NDArray[np.float64], y: NDArray[np.float64]) -> list[float]:
    """Free-run R^2 of each model over ``(u, y)`` from its first ``max_lag`` outputs (-inf: not finite)."""
    out = [-np.inf] * len(models)
    groups: dict[tuple[Any, ...], list[int]] = {}
    for i, m in enumerate(models):
        groups.setdefault((m.regressors, m.normalisation, m.neurons, m.linear_regressors), []).append(i)
    for (regs, norm, _, lregs), idx in groups.items():
        L = models[idx[0]].max_lag
        with np.errstate(over="ignore", invalid="ignore"):
            sim = norm.y_inverse(free_run(
                regs, np.stack([models[i].centres for i in idx]), np.stack([models[i].widths for i in idx]),
                np.stack([models[i].weights for i in idx]), norm.u(u), np.broadcast_to(norm.y(y[:L]), (len(idx), L)),
                _linear_parts([models[i] for i in idx]), linear_regressors=lregs))
        for k, i in enumerate(idx):
            if np.all(np.isfinite(sim[k, L:])):
                out[i] = r2(y[L:], sim[k, L:])
    return out
