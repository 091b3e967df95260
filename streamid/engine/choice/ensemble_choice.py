"""Ensembles of the restarts' networks competing in the final choice (``CoEAConfig.run_ensembles``).

The rule (applied by :func:`~streamid.engine.identification.identify` after the complexity choice)
--------------------------------------------------------------------------------------------
The runs' candidates after pruning are ranked by AIC (on the
estimation free run, :mod:`streamid.engine.choice.complexity`; ties by run order), the admissible
ones only. The means of the top 2, the top 3 and all of them (each formed once: with 3
admissible runs "top 3" and "all" are the same) are candidates too, each scored like a
single network on the estimation record:

* its free run is the mean of its members' free runs, each member simulating on its own
  past outputs from the measured initial outputs (:mod:`streamid.model.ensemble`); the
  members' free runs made by the choice are reused (no new simulation) when at hand;
* the range guard of :mod:`streamid.engine.choice.scores` is applied to that mean, scored from the
  largest member lag ``L`` (``n - L`` samples);
* ``p`` is the mean of the members' fitted weights (:func:`~streamid.engine.choice.complexity.parameter_count` says why),
  and the criterion is the complexity rule's, ``n log(1 - R2_fr) + 2 p`` for AIC.

An ensemble is taken when its criterion is strictly below the single choice's (the lowest
of the ensembles' when several are). Measured in round 5 of issue 13 (docs/engine-results.md):
heat exchanger worst seed 0.541 -> 0.597, F-16 accel2 worst -1.61 -> -0.12, Bouc-Wen
0.9841 / 0.9822 -> 0.9906 / 0.9868, MR damper ten seeds' min 0.9668 -> 0.9746; no system worse.
The evidence (each ensemble's members, R^2, p, criterion, whether taken) goes to
``metrics.complexity["ensembles"]``.
"""

from __future__ import annotations

from collections.abc import Iterator, Sequence
from types import SimpleNamespace
from typing import Any

import numpy as np
from numpy.typing import NDArray

from streamid.engine.choice.scores import _excursion, path_score
from streamid.engine.choice.complexity import criterion, parameter_count
from streamid.model.ensemble import MAX_MEMBERS, ensemble_of
from streamid.model.freerun import chunked_paths
from streamid.model.limits import CHUNK_ROWS
from streamid.model.narx import Model

__all__ = ["ENSEMBLE_SIZES", "KEEP_PATHS_ROWS", "choose_ensemble", "one_step_mse"]

#: The ensembles offered: the mean of the top 2, the top 3 and all admissible runs (0 = all; at most
#: :data:`~streamid.model.ensemble.MAX_MEMBERS`, the top ones).
ENSEMBLE_SIZES = (2, 3, 0)
#: Beyond one chunk a run's estimation free run is written out as its score is streamed, and read here instead of
#: being simulated again, for a record of at most this many rows (8 MiB a run; the restarts, the extra runs and the
#: fallback runs together at most 10: 80 MiB). Beyond it every member is simulated again a chunk at a time.
#: Measured: ``streamid bench --only long`` (1,000,000 samples) in docs/benchmarks.md, "Long records offline".
KEEP_PATHS_ROWS = 1 << 20


def choose_ensemble(
    models: Sequence[Model],
    paths: Sequence[NDArray[np.float64] | None],
    complexity: dict[str, Any],
    u: NDArray[np.float64],
    y: NDArray[np.float64],
    range_margin: float,
    threads: int = 1,
    fitness: bool = True,
) -> tuple[Model | None, list[int], list[dict[str, Any]]]:
    """The ensemble taken (None: the single choice stands), its members' runs (best first) and the evidence.

    ``models``: each run's candidate after pruning; ``paths``: each one's estimation free run in output
    units (None: simulated here once); ``complexity``: the single choice's evidence
    (:func:`~streamid.engine.choice.complexity.choose`); ``u``, ``y``: the estimation record; ``threads``: the
    taken ensemble's members predicted in that many threads (the same result to the bit); ``fitness`` False: the
    taken ensemble's ``metrics.fitness`` (its one-step MSE over the record) is left None, in its place, for a
    caller that may replace it (:func:`one_step_mse` makes it).
    """
    rows = complexity["candidates"]
    ranked = [int(c["run"]) for c in sorted((c for c in rows if c["criterion"] is not None),
                                            key=lambda c: (c["criterion"], c["run"]))]
    if len(ranked) < 2:
        return None, [], []
    single = float(rows[int(complexity["chosen_run"])]["criterion"])
    lo, hi = float(np.min(y)), float(np.max(y))
    runs: dict[int, NDArray[np.float64] | None] = {}
    evidence: list[dict[str, Any]] = []
    best: tuple[float, Model | None, list[int]] = (single, None, [])
    seen: set[int] = set()
    # beyond one chunk the runs keep no free run (their memory): every ensemble offered is scored in one pass over
    # the record a chunk at a time (_chunked_scores), its members' paths made once
    offered = [ranked[: (min(len(ranked), MAX_MEMBERS) if size == 0 else size)] for size in ENSEMBLE_SIZES]
    offered = [m for k, m in enumerate(offered) if len(m) >= 2 and m not in offered[:k]]
    chunked = _chunked_scores(models, offered, u, y, lo, hi, range_margin, paths) if len(y) > CHUNK_ROWS else None
    for size in ENSEMBLE_SIZES:
        k = min(len(ranked), MAX_MEMBERS) if size == 0 else size
        if k > len(ranked) or k in seen:
            continue
        seen.add(k)
        members = ranked[:k]
        for i in members:
            if i not in runs and chunked is None:
                runs[i] = paths[i] if paths[i] is not None else _simulate(models[i], u, y)
        row: dict[str, Any] = {"name": "all" if size == 0 else f"top{size}", "members": members,
                               "neurons": [models[i].neurons for i in members], "r2_fr_est": None,
                               "params": sum(parameter_count(models[i]) for i in members) / k, "criterion": None,
                               "taken": False}
        evidence.append(row)
        L = max(models[i].max_lag for i in members)
        if chunked is not None:
            got_score = chunked[offered.index(members)]
            if got_score is None:  # not finite
                continue
            score, excursion = got_score
        else:
            got = [runs[i] for i in members]
            if any(p is None for p in got):
                continue
            with np.errstate(over="ignore", invalid="ignore"):  # np.mean(axis=0)'s sum, row after row: no (k, N) copy
                ps = [p for p in got if p is not None]
                mean = np.array(ps[0], dtype=np.float64)
                for p in ps[1:]:
                    mean += p
                mean /= len(ps)
            if not np.all(np.isfinite(mean[L:])):
                continue
            score, excursion = path_score(mean, y, L, L, lo, hi, range_margin)
        if excursion > 0.0:
            row["excursion_spans"] = excursion
            continue
        value = criterion(score, len(y) - L, float(row["params"]))
        row.update(r2_fr_est=float(score), criterion=float(value))
        if value < best[0]:
            best = (value, None, members)
    if not best[2]:
        return None, [], evidence
    members = best[2]
    taken: dict[str, Any] = {}
    for row in evidence:
        row["taken"] = row["members"] == members
        taken = row if row["taken"] else taken
    first = models[members[0]]  # the document's config and window: the identification's (as a single network's)
    ens = ensemble_of([models[i] for i in members], config=first.config, window=first.window)
    mse = one_step_mse(ens, u, y, threads) if fitness else None
    choice = {"candidates": len(evidence), "admissible": sum(1 for e in evidence if e["criterion"] is not None),
              "score": taken["r2_fr_est"], "excursion_spans": 0.0, "range_margin": float(range_margin),
              "run_ensemble": len(members)}  # the mean's free run on the estimation record, as a single model's
    return ens.with_metrics(fitness=mse, free_run_choice=choice, ensemble={
        k: taken[k] for k in ("name", "members", "neurons", "r2_fr_est", "params", "criterion")}), members, evidence


def one_step_mse(model: Model, u: NDArray[np.float64], y: NDArray[np.float64], threads: int = 1,
                 keep: dict[str, Any] | None = None) -> float:
    """``model``'s one-step-ahead mean squared error over the record from its ``max_lag``-th sample (output units
    squared): an ensemble's ``metrics.fitness``; ``keep`` given receives the predictions it is made of (``"osa"``)."""
    L = model.max_lag
    pred = model.predict_osa(u, y, threads=threads)
    if keep is not None:
        keep["osa"] = pred
    return float(np.mean((pred[L:] - y[L:]) ** 2))


def _chunked_scores(models: Sequence[Model], offered: list[list[int]], u: NDArray[np.float64], y: NDArray[np.float64],
                    lo: float, hi: float, range_margin: float,
                    paths: Sequence[NDArray[np.float64] | None] = ()) -> list[tuple[float, float] | None]:
    """:func:`~streamid.engine.choice.scores.path_score` of the mean free run of each ensemble ``offered`` (lists of
    run indices), its members' free runs made together a chunk at a time (:func:`~streamid.model.freerun.
    chunked_paths`, each from its own measured outputs: the same values as whole runs) or read from ``paths``
    where a member's is given (the run's own streamed free run: the same values), the means summed in the
    members' order as the whole-record way does; the sums of the score added chunk by chunk (equal to rounding).
    None where a mean is not finite. Memory: a chunk of every member's path, whatever the record's length (and
    the paths given)."""
    union = sorted({i for m in offered for i in m})
    row = {i: k for k, i in enumerate(union)}
    given = {i: p for i in union if i < len(paths) and (p := paths[i]) is not None}
    made = [i for i in union if i not in given]
    Ls = [max(models[i].max_lag for i in m) for m in offered]
    mu = {L: float(np.mean(y[L:])) for L in set(Ls)}
    sse, ss = [0.0] * len(offered), [0.0] * len(offered)
    top, bottom, finite = [-np.inf] * len(offered), [np.inf] * len(offered), [True] * len(offered)
    ua = u.reshape(len(y), -1)
    for a, piece in _pieces(models, made, given, union, ua, y):
        b = a + piece.shape[1]
        for k, m in enumerate(offered):
            s = max(a, Ls[k])
            if s >= b or not finite[k]:
                continue
            with np.errstate(over="ignore", invalid="ignore"):
                mean = np.array(piece[row[m[0]], s - a :])
                for i in m[1:]:
                    mean += piece[row[i], s - a :]
                mean /= len(m)
                if not np.all(np.isfinite(mean)):
                    finite[k] = False
                    continue
                top[k], bottom[k] = max(top[k], float(mean.max())), min(bottom[k], float(mean.min()))
                sse[k] += float(np.sum((y[s:b] - mean) ** 2))
                ss[k] += float(np.sum((y[s:b] - mu[Ls[k]]) ** 2))
    out: list[tuple[float, float] | None] = []
    for k in range(len(offered)):
        if not finite[k]:
            out.append(None)
            continue
        e = _excursion(top[k], bottom[k], lo, hi, range_margin)
        out.append(((1.0 - sse[k] / ss[k]) if e == 0.0 else -np.inf, e))
    return out


def _pieces(models: Sequence[Model], made: list[int], given: dict[int, NDArray[np.float64]], union: list[int],
            ua: NDArray[np.float64], y: NDArray[np.float64]) -> Iterator[tuple[int, NDArray[np.float64]]]:
    """``(a, piece)`` over the record a chunk at a time, ``piece`` (len(union), rows) the members' free runs in
    ``union``'s order: those of ``made`` simulated together (:func:`~streamid.model.freerun.chunked_paths`, cut at
    the same ``step``: it is at least their ``max_lag + 1``), the ``given`` ones sliced."""
    n, at = len(y), {i: k for k, i in enumerate(union)}
    step = max(CHUNK_ROWS, max(models[i].max_lag for i in union) + 1)
    nets = [models[i] for i in made]
    L = max((m.max_lag for m in nets), default=0)
    sims = (chunked_paths(SimpleNamespace(members=tuple(nets), max_lag=L, normalisation=nets[0].normalisation), ua,
                          y[:L], step, measured=False) if nets else None)
    for a in range(0, n, step):
        b = min(n, a + step)
        piece = np.empty((len(union), b - a))
        if sims is not None:
            _, made_paths = next(sims)  # the span a..b: the same step from the same start
            for k, i in enumerate(made):
                piece[at[i]] = made_paths[k]
        for i, p in given.items():
            piece[at[i]] = p[a:b]
        yield a, piece


def _simulate(model: Model, u: NDArray[np.float64], y: NDArray[np.float64]) -> NDArray[np.float64] | None:
    """``model``'s free run over the record (output units), None when not finite."""
    L = model.max_lag
    with np.errstate(over="ignore", invalid="ignore"):
        path = model.simulate(u, y[:L])
    return path if np.all(np.isfinite(path[L:])) else None
