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
of the record (everything after the initial lags, or from ``score_from`` when given).
One simulation gives both the guard and the score, and a held-out tail is scored
after the drift accumulated over the whole search part (stricter than a simulation
restarted just before the tail).

A candidate with no input term is not admissible either: its free run ignores the
input (an autonomous oscillator can fit an estimation record and says nothing of
another). Nor is one whose linear part has an unstable autoregression
(:mod:`streamid.engine.choice.stability`: only a stable one bounds the free run on every input). If no candidate is admissible, the choice falls back to the candidate with the
smallest excursion beyond the widened range (the report says ``admissible: 0``).

The margin is :data:`RANGE_MARGIN` (a quarter of the span each side: the measured output's own range is never
left on the estimation record, and a quarter more leaves room for a model's error at the extremes). It was a
``CoEAConfig`` field (``range_margin``) that no preset, measurement or stream ever set to anything else (issue 37).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import NDArray

from streamid.model.ensemble import EnsembleModel, members_of
from streamid.model.limits import CHUNK_ROWS
from streamid.model.narx import Model, free_run
from streamid.engine.choice.stability import is_bounded
from streamid.engine.validation import r2
from streamid.errors import DataError, ModelFormatError

__all__ = ["SEGMENTS", "SEGMENT_ROWS", "FreeRunScores", "free_run_scores", "group_free_run", "path_score",
           "segment_scores", "segments"]

def group_free_run(models: list[Model], u: NDArray[np.float64], y_init: NDArray[np.float64],
                   threads: int = 1) -> NDArray[np.float64]:
    """Free runs (normalised units, one row per model) of models sharing their regressors and normalisation,
    simulated together from the same measured initial outputs ``y_init`` (``max_lag`` of them); ``threads``:
    :func:`~streamid.model.freerun.free_run`'s (the same result).
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

#: The range guard's widening, in spans of the estimation output on each side (the module docstring).
RANGE_MARGIN = 0.25


@dataclass(frozen=True)
class FreeRunScores:
    """Per candidate: score (R^2 over the scored part, -inf when not admissible) and excursion."""

    scores: tuple[float, ...]
    excursions: tuple[float, ...]  # largest distance beyond the widened range, in spans (0 = admissible)
    range_margin: float = 0.25  # (RANGE_MARGIN)
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

#: Rows per step of a free-run scoring that keeps no paths (``free_run_scores(..., keep_paths=False)``): its memory
#: is this many rows of each candidate whatever the record's length (the paths of 21 candidates over a 1,000,000-
#: sample window's estimation part were 2 x 118 MB at the online update's peak).
SCORE_CHUNK_ROWS = CHUNK_ROWS


def free_run_scores(
    models: list[Model],
    u: NDArray[np.float64],
    y: NDArray[np.float64],
    *,
    score_from: int | None = None,
    range_margin: float = 0.25,  # (RANGE_MARGIN)
    threads: int = 1,
    keep_paths: bool = True,
    streamed_paths: bool = False,
) -> FreeRunScores:
    """Free-run scores and range guard of ``models`` on ``(u, y)`` (``u`` of shape (N, n_inputs)).

    Models sharing regressors and normalisation are simulated together (one recursion; in ``threads``
    groups at once, the same result). ``keep_paths=False``: single networks are simulated
    :data:`SCORE_CHUNK_ROWS` rows at a time, each step from the last outputs of the one before (the same free run
    to the bit), their scores accumulated and no path kept (``paths`` all None): memory bounded by the chunk,
    not the record; with ``streamed_paths`` each finite one's path is still written out as its pieces pass (the
    same values; one record-length array a network, for a caller that keeps it).
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
        drives = all(any(r.signal == "u" for r in mm.regressors) for mm in members_of(m0))
        if not keep_paths and not isinstance(m0, EnsembleModel):
            group = [models[i] for i in idx]
            into = np.empty((len(group), len(y))) if streamed_paths else None
            for k, out in enumerate(_streamed(group, u, y, first, lo, hi, range_margin, threads, into)):
                if out is not None and into is not None:
                    paths[idx[k]] = into[k]
                if out is not None and drives and is_bounded(group[k]):
                    scores[idx[k]], exc[idx[k]] = out
            continue
        with np.errstate(over="ignore", invalid="ignore"):
            if isinstance(m0, EnsembleModel):  # each member on its own past outputs, averaged
                ys = m0.simulate(u, y[:L])[None]
            else:
                ys = m0.normalisation.y_inverse(group_free_run([models[i] for i in idx], u, y[:L], threads))
        for k, i in enumerate(idx):
            if not np.all(np.isfinite(ys[k, L:])):
                continue
            paths[i] = ys[k]
            if drives and is_bounded(models[i]):
                scores[i], exc[i] = path_score(ys[k], y, L, first, lo, hi, range_margin)
    return FreeRunScores(tuple(float(s) for s in scores), tuple(float(e) for e in exc), float(range_margin), tuple(paths))

def _streamed(models: list[Model], u: NDArray[np.float64], y: NDArray[np.float64], first: int, lo: float, hi: float,
              range_margin: float, threads: int, into: NDArray[np.float64] | None = None,
              ) -> list[tuple[float, float] | None]:
    """:func:`path_score` of each network's free run (networks sharing their regressors, as
    :func:`group_free_run`), simulated :data:`SCORE_CHUNK_ROWS` rows at a time; None where it is not finite.
    ``into`` (networks, N): each network's path written there as the pieces pass (the first ``max_lag`` measured)."""
    m0 = models[0]
    L, n, C = m0.max_lag, len(y), len(models)
    norm = m0.normalisation
    centres, widths = np.stack([m.centres for m in models]), np.stack([m.widths for m in models])
    weights, linear = np.stack([m.weights for m in models]), _linear_parts(models)
    init = np.ascontiguousarray(np.broadcast_to(norm.y(y[:L]), (C, L)))
    sse, top, bottom = np.zeros(C), np.full(C, -np.inf), np.full(C, np.inf)
    finite = np.ones(C, dtype=bool)
    for a in range(L, n, SCORE_CHUNK_ROWS):
        b = min(n, a + SCORE_CHUNK_ROWS)
        with np.errstate(over="ignore", invalid="ignore"):
            path = free_run(m0.regressors, centres, widths, weights, norm.u(u[a - L : b]), init, linear, threads=threads,
                            linear_regressors=m0.linear_regressors)  # rows a - L .. b - 1, the first L given
            out = norm.y_inverse(path[:, L:])
            if into is not None:
                into[:, a:b] = out
            finite &= np.all(np.isfinite(out), axis=1)
            top, bottom = np.maximum(top, out.max(axis=1)), np.minimum(bottom, out.min(axis=1))
            if b > first:
                s = max(first, a)
                sse += np.sum((y[None, s:b] - out[:, s - a :]) ** 2, axis=1)
        init = np.ascontiguousarray(path[:, path.shape[1] - L :])
    if into is not None:
        into[:, :L] = y[:L]
    ss = float(np.sum((y[first:] - y[first:].mean()) ** 2))
    if not ss > 0:
        raise DataError(f"the output is constant over the scored part (from sample {first}); nothing to score")
    res: list[tuple[float, float] | None] = []
    for c in range(C):
        if not finite[c]:
            res.append(None)
            continue
        e = _excursion(float(top[c]), float(bottom[c]), lo, hi, range_margin)
        res.append(((1.0 - float(sse[c]) / ss) if e == 0.0 else -np.inf, e))
    return res


def path_score(path: NDArray[np.float64], y: NDArray[np.float64], L: int, first: int, lo: float, hi: float,
               range_margin: float) -> tuple[float, float]:
    """The range guard and score of one finite free run ``path`` (output units) of ``y``: (R^2 over
    ``first:``, or -inf when not admissible; excursion beyond the widened range ``[lo, hi]`` in spans)."""
    run = path[L:]
    e = _excursion(float(run.max()), float(run.min()), lo, hi, range_margin)
    return (r2(y[first:], path[first:]) if e == 0.0 else -np.inf), e


def _excursion(top: float, bottom: float, lo: float, hi: float, range_margin: float) -> float:
    """How far a free run reaching ``[bottom, top]`` goes beyond ``[lo, hi]`` widened by ``range_margin`` of its span
    each side, in spans (0: admissible)."""
    return max(max(top - hi, lo - bottom, 0.0) / (hi - lo) - range_margin, 0.0)


#: Beyond one chunk (:data:`CHUNK_ROWS` rows) the free runs that compare candidates or fit a refinement are made on this
#: many contiguous segments of the estimation record (:func:`segments`; docs/method.md, "Long records")...
SEGMENTS = 8
#: ...holding this many scored rows together (each ``SEGMENT_ROWS // SEGMENTS`` after its first ``max_lag``).
SEGMENT_ROWS = 16_384


def segments(first: int, n: int, L: int) -> list[tuple[int, int]] | None:
    """The segments ``[start, stop)`` of the samples ``first..n-1`` whose free runs stand for the whole: None when
    those hold at most one chunk (:data:`CHUNK_ROWS`) of rows after their first ``L`` (one free run over them all,
    as always), else :data:`SEGMENTS` segments of ``L + SEGMENT_ROWS // SEGMENTS`` samples evenly spaced from the
    first sample to the last (each free run starts from its own first ``L`` measured outputs)."""
    if n - first - L <= CHUNK_ROWS:
        return None
    span = L + SEGMENT_ROWS // SEGMENTS
    return [(a, a + span) for a in (first + k * (n - first - span) // (SEGMENTS - 1) for k in range(SEGMENTS))]


def segment_scores(models: list[Model], u: NDArray[np.float64], y: NDArray[np.float64],
                   parts: list[tuple[int, int]], range_margin: float = RANGE_MARGIN) -> FreeRunScores:
    """:func:`free_run_scores` on the segments ``parts`` of the record (:func:`segments`) instead of the whole: each
    candidate simulated on every segment from that segment's first ``L`` measured outputs (``L`` the largest
    ``max_lag`` of the candidates), its R^2 over the segments' later rows together and its range guard over them
    against the whole record's range (``[min, max]`` of ``y``). No paths kept. The same rule otherwise (finite,
    an input term, a stable linear part)."""
    if not models:
        raise DataError("no candidate models to choose from")
    lo, hi = float(np.min(y)), float(np.max(y))
    if not hi - lo > 0:
        raise DataError(f"the output is constant over the estimation record (all values {lo!r}); nothing to score")
    L = max(m.max_lag for m in models)
    target = np.concatenate([y[a + L : b] for a, b in parts])
    ss = float(np.sum((target - target.mean()) ** 2))
    if not ss > 0:
        raise DataError("the output is constant over the segments scored; nothing to score")
    C = len(models)
    sse, top, bottom = np.zeros(C), np.full(C, -np.inf), np.full(C, np.inf)
    finite = np.ones(C, dtype=bool)
    groups: dict[tuple[Any, ...], list[int]] = {}
    for i, m in enumerate(models):
        key = (("ensemble", i) if isinstance(m, EnsembleModel)
               else (m.regressors, m.normalisation, m.neurons, m.linear_regressors))
        groups.setdefault(key, []).append(i)
    for idx in groups.values():
        m0 = models[idx[0]]
        Lm = m0.max_lag
        for a, b in parts:
            with np.errstate(over="ignore", invalid="ignore"):
                if isinstance(m0, EnsembleModel):
                    ys = m0.simulate(u[a + L - Lm : b], y[a + L - Lm : a + L])[None]
                else:
                    ys = m0.normalisation.y_inverse(group_free_run([models[i] for i in idx], u[a + L - Lm : b],
                                                                   y[a + L - Lm : a + L]))
                out = ys[:, Lm:]
                ok = np.all(np.isfinite(out), axis=1)
                sse[idx] += np.sum((y[None, a + L : b] - out) ** 2, axis=1)
            finite[idx] &= ok
            top[idx] = np.maximum(top[idx], np.where(ok, out.max(axis=1), np.inf))
            bottom[idx] = np.minimum(bottom[idx], np.where(ok, out.min(axis=1), -np.inf))
    scores, exc = [-np.inf] * C, [np.inf] * C
    for i, m in enumerate(models):
        drives = all(any(r.signal == "u" for r in mm.regressors) for mm in members_of(m))
        if finite[i] and drives and is_bounded(m):
            e = _excursion(float(top[i]), float(bottom[i]), lo, hi, range_margin)
            scores[i], exc[i] = ((1.0 - float(sse[i]) / ss) if e == 0.0 else -np.inf), e
    return FreeRunScores(tuple(float(v) for v in scores), tuple(float(e) for e in exc), float(range_margin),
                         tuple([None] * C))
