"""Output-error refinement of the final model's weights (``CoEAConfig.refine_iterations``).

The search fits every network's output weights by least squares on **one-step-ahead** errors (the
paper's fitness), and the final choice ranks networks by their **free run**. This step then moves
the chosen model's output weights to the free run itself: Levenberg-Marquardt on

    J(w) = sum_t (y(t) - yhat_sim(t; w))^2        (the estimation record, after the first L samples)

where ``yhat_sim`` is the model's free run (for an ensemble, the mean of its members' free runs,
every member's weights refined together), and with them a linear part's coefficients and constant
(an output-error fit of the whole output layer). Centres, widths, lags and the normalisation are
kept. It is the classical output-error (simulation-error) fit of a model structure found by a
one-step-ahead method (Ljung, *System Identification*, 2nd ed., sections 4.2 and 10.1: the
output-error predictor).

The sensitivities ``s(t) = d yhat_sim(t) / dw`` follow the free run's own recursion,

    s(t) = phi(r(t)) + sum_l g_l(t) s(t - l),    g_l(t) = d yhat(t) / d yhat(t - l) on the trajectory,

computed along the free run in the same compiled loop as the free run itself
(:mod:`streamid.engine.choice.sensitivities`, numba), so an iteration costs about one free run per
trial step. Each iteration solves the Jacobi-scaled damped normal equations and keeps the step
when the free run's error falls (the damping then divided by 10, at least 1e-4), else retries
with ten times the damping (at most 1e2); it stops after ``iterations``, when no step lowers the
error, or when one lowers it by less than 1e-4 of itself.

The rule (applied by :func:`~streamid.engine.identification.identify` after the final choice)
-----------------------------------------------------------------------------------------
* **Gate:** refined only when the chosen model's free-run R^2 on the estimation record is at
  least :data:`ABOVE` (0.8). Below it the network's structure does not explain the record, and fitting its
  weights to the free run fits that structure's error (the F-16's refined models validated lower on 11 of 15
  seeds; docs/method.md and docs/engine-results.md, round 8, give the figures).
* **Weights stay at their scale:** the error minimised is the free run's plus ``rho |w - w0|^2`` (``WEIGHT_PENALTY``).
* **Judged out of sample** (:func:`refine_judged`, what ``identify`` and the online updates apply; issue 37
  round 5): the weights are first refined on the first half of the estimation record alone, and the refinement
  is made (on the whole record) only if that half's refinement free-runs better than the model as it was over the
  second half, which it was not fitted on: a fit to one excitation's free run can extrapolate worse
  (docs/engine-results.md, "Issue 37, round 5").
* **Kept only if better:** the refined model's free run over the whole estimation record must
  pass the range guard of :mod:`streamid.engine.choice.scores` and have a higher R^2 than before, and its
  linear part's autoregression must stay stable (:mod:`streamid.engine.choice.stability`: a fit to the free
  run can move a pole out where the record does not reach); otherwise the chosen model stands unchanged.
* The evidence (gate, iterations, R^2 before and after, one-step MSE after) goes to
  ``metrics.refinement``; a refined model's ``metrics.fitness`` is its one-step MSE on the estimation
  record (``Result.fitness``: the final model's, as for an ensemble).

* **Beyond one chunk** (an estimation record of more than ``CHUNK_ROWS`` rows): the free runs of the refinement, of
  its held-out judgement and of "kept only if better" are made on :data:`~streamid.engine.choice.scores.SEGMENTS`
  contiguous segments of the part of the record concerned (``SEGMENT_ROWS`` scored rows in all, evenly spaced from
  its first sample to its last), each from its own first measured outputs (docs/method.md, "Long records": what
  is sampled and why it is safe); up to one chunk, one free run over every row as above.

Not applied by ``--paper``; applied to each online coevolution run's model (``streamid.online.stream_config.
ONLINE_REFINE``; ``engine.refine_iterations = 0``: off). Numerics only: no I/O, no randomness.
"""

from __future__ import annotations

import math
from dataclasses import replace
from typing import Any

import numpy as np
from numpy.typing import NDArray

from streamid.engine.settings import REFINE_ABOVE as ABOVE
from streamid.engine.choice.sensitivities import free_run_sensitivities
from streamid.engine.choice.scores import path_score, segments
from streamid.engine.choice.stability import is_bounded
from streamid.engine.fit.blas import one_blas_thread
from streamid.model.ensemble import EnsembleModel, members_of
from streamid.model.limits import CHUNK_ROWS
from streamid.threads import thread_map
from streamid.model.narx import Model
from streamid.engine.validation import r2_or_none

__all__ = ["ABOVE", "DAMPING", "WEIGHT_PENALTY", "parts", "refine_judged", "refine_weights", "sensitivities"]

#: Levenberg-Marquardt damping (times the diagonal of J'J): the first, the least, and the most before giving up.
DAMPING = (1e-2, 1e-4, 1e2)

#: The weights' penalty ``rho * |w - w0|^2`` added to the free-run error, ``rho`` this times the mean diagonal of
#: J'J at the start. Without it, directions the record hardly constrains ran off to weights of 1e4-1e64 whose
#: contributions cancel on the record; 1e-5 measured best of 1e-4..1e-6 (docs/engine-results.md, round 8).
WEIGHT_PENALTY = 1e-5

_TRIALS = 4  # free runs per iteration on average, at most (a bound on the work whatever the record)

_STOP = 1e-4  # stop when an iteration lowers the error by less than this fraction of it

# CHUNK_ROWS (streamid.model.limits, 65,536): rows of the free run and its derivatives made at a time (:func:`chunks`):
# the refinement's memory is this many rows of every parameter whatever the record's length (its Jacobian over a
# 1,000,000-sample window's estimation part was 112 MB, with 62 MB of derivatives besides, at the online update's
# peak). A record of up to ``max_lag + CHUNK_ROWS`` samples is one chunk, as before.


def chunks(L: int, n: int) -> list[tuple[int, int]]:
    """The rows ``[a, b)`` of each chunk of a free run over ``n`` samples from ``L`` given ones (the first from
    ``L``, then :data:`CHUNK_ROWS` each)."""
    return [(a, min(n, a + CHUNK_ROWS)) for a in range(L, n, CHUNK_ROWS)] or [(L, n)]


class _Piece:
    """One contiguous part of the record a refinement's free runs are made on: its normalised inputs and outputs,
    every network's :func:`parts` and linear columns on it, its chunks (:func:`chunks`)."""

    def __init__(self, nets: tuple[Model, ...], un: NDArray[np.float64], yn: NDArray[np.float64], L: int) -> None:
        self.un, self.yn, self.n = un, yn, int(un.shape[0])
        self.P = [parts(m, un) for m in nets]
        self.lin = [None if m.linear is None else _linear_columns(m, un) for m in nets]
        self.none = np.zeros((self.n, 0))
        self.bounds = chunks(L, self.n)


def parts(model: Model, un: NDArray[np.float64]) -> tuple[NDArray[Any], ...]:
    """``(du, cy, a, lags, lin_y, lin_u)`` of one network on the normalised inputs ``un`` (N, n_inputs): the
    arguments of :func:`~streamid.engine.choice.sensitivities.free_run_sensitivities` (the input terms of every step are
    computed here as :func:`~streamid.model.freerun.free_run` computes them for several networks at once)."""
    n = un.shape[0]
    a = 1.0 / (2.0 * model.widths**2)
    du = np.zeros((n, model.neurons))
    lin_u = np.zeros(n)
    yj: list[int] = []
    for j, reg in enumerate(model.regressors):
        if reg.signal == "y":
            yj.append(j)
            continue
        col = np.zeros(n)
        col[reg.lag :] = un[: n - reg.lag, reg.index]
        for m in range(model.neurons):  # a neuron at a time: no (n, M) temporary (the same sums)
            d = col - model.centres[m, j]
            du[:, m] += d * d
        if model.linear is not None:
            lin_u += model.linear[j] * col
    du *= a[None, :]
    if model.linear is not None:
        lin_u += model.linear[-1]
    lin_y = np.zeros(len(yj)) if model.linear is None else np.ascontiguousarray(model.linear[yj])
    lags = np.array([model.regressors[j].lag for j in yj], dtype=np.int64)
    return du, np.ascontiguousarray(model.centres[:, yj].T), a, lags, lin_y, lin_u  # cy: (ky, M)


def _linear_columns(model: Model, un: NDArray[np.float64]) -> tuple[NDArray[np.float64], list[int], list[int]]:
    """``(xu, yj, uj)``: the columns (n, q) whose coefficients make a linear part's input terms (its input
    regressors in order, then ones for the constant), and the regressor indices of its output and input terms."""
    n = un.shape[0]
    yj = [j for j, reg in enumerate(model.regressors) if reg.signal == "y"]
    uj = [j for j, reg in enumerate(model.regressors) if reg.signal != "y"]
    xu = np.ones((n, len(uj) + 1))
    for c, j in enumerate(uj):
        reg = model.regressors[j]
        xu[: reg.lag, c] = 0.0
        xu[reg.lag :, c] = un[: n - reg.lag, reg.index]
    return xu, yj, uj


def sensitivities(model: Model, un: NDArray[np.float64], y0: NDArray[np.float64]) -> NDArray[np.float64]:
    """``d yhat(t) / d theta`` of one network's free run on the normalised inputs ``un`` from the normalised
    initial outputs ``y0`` (its first ``max_lag`` are used); rows before ``max_lag`` are zero. ``theta`` is
    the weights (n, M), then, with a linear part, its coefficients in the model's order and its constant
    (n, M + k + 1)."""
    du, cy, a, lags, lin_y, lin_u = parts(model, un)
    L = model.max_lag
    if model.linear is None:
        return np.asarray(free_run_sensitivities(du, cy, a, lags, np.array(model.weights), lin_y, lin_u, y0,
                                                 L, np.zeros((un.shape[0], 0)), 0, np.zeros((L, model.neurons)))[1])
    xu, yj, uj = _linear_columns(model, un)
    S = free_run_sensitivities(du, cy, a, lags, np.array(model.weights), lin_y, lin_u, y0, L, xu,
                               len(yj), np.zeros((L, model.neurons + len(yj) + xu.shape[1])))[1]
    return np.asarray(S[:, _model_order(model.neurons, yj, uj)])


def _model_order(M: int, yj: list[int], uj: list[int]) -> NDArray[np.intp]:
    """The kernel's columns (weights, output terms, input terms, constant) in the model's order (weights, then
    the linear part's coefficients by regressor, then its constant)."""
    k = len(yj) + len(uj)
    where = np.empty(k, dtype=np.intp)
    where[yj] = M + np.arange(len(yj))
    where[uj] = M + len(yj) + np.arange(len(uj))
    return np.concatenate([np.arange(M), where, [M + k]]).astype(np.intp)


def refine_weights(
    model: Model, u: NDArray[np.float64], y: NDArray[np.float64], iterations: int, above: float, range_margin: float,
    threads: int = 1, segments: list[tuple[int, int]] | None = None, osa: bool = True,
    keep_osa: dict[str, Any] | None = None,
) -> tuple[Model, dict[str, Any]]:
    """``model`` with its output weights refined to its free run on ``(u, y)`` (the rule above).

    Parameters
    ----------
    model : Model
        The chosen model (a single network or an :class:`~streamid.model.ensemble.EnsembleModel`).
    u, y : ndarray
        The estimation record, shapes (N, n_inputs) and (N,), output units.
    iterations : int
        At most this many Levenberg-Marquardt iterations (0: the model unchanged).
    above : float
        The gate: refine only when the model's free-run R^2 on ``(u, y)`` is at least ``above``.
    range_margin : float
        The range guard's margin (``CoEAConfig.range_margin``).
    threads : int
        An ensemble's members simulated in that many threads (a caller with a core to spare; the same result).
    segments : list of (start, stop), optional
        The free run made and scored on these contiguous parts of the record only, each from its own first
        ``max_lag`` measured outputs (:func:`~streamid.engine.choice.scores.segments`; a record beyond one chunk); None: one free run over it all.
    osa : bool
        False: the refined model's one-step MSE over the record (``osa_mse_est``, its ``metrics.fitness``) is not
        made (a caller that reads only the refined weights).
    keep_osa : dict, optional
        Given, receives the refined model's one-step predictions over the record when they are made (``"osa"``,
        length N, and ``"of"``, the refined model): a caller that needs them again (the identification hands them
        to the validation) does not make them twice.

    Returns
    -------
    (Model, dict)
        The refined model (or ``model`` itself) and the evidence for ``metrics.refinement``.
    """
    ev: dict[str, Any] = {"gate": float(above), "iterations": 0, "taken": False}
    if segments is not None:
        ev["segments"] = {"count": len(segments), "rows": int(sum(b - a for a, b in segments)), "of": int(len(y))}
    if iterations < 1:
        return model, {**ev, "reason": "off"}
    nets = members_of(model)
    if any(m.linear_regressors is not None for m in nets):  # its hundreds of coefficients: fitted by least squares
        return model, {**ev, "reason": "a long linear part (not refined)"}
    norm = model.normalisation
    L = max(m.max_lag for m in nets)
    lo, hi = float(np.min(y)), float(np.max(y))
    K = len(nets)
    W = [m.weights.copy() if m.linear is None else np.concatenate([m.weights, m.linear]) for m in nets]
    sizes = [w.size for w in W]
    offs = np.cumsum([0, *sizes])
    pieces = [_Piece(nets, norm.u(u[s:b]), norm.y(y[s:b]), L) for s, b in ([(0, len(y))] if segments is None
                                                                           else segments)]
    target = pieces[0].yn[L:] if len(pieces) == 1 else np.concatenate([p.yn[L:] for p in pieces])
    y_scored = y[L:] if segments is None else np.concatenate([y[s + L : b] for s, b in segments])
    orders = [None if li is None else _model_order(m.neurons, li[1], li[2]) for m, li in zip(nets, pieces[0].lin)]

    def one(p: _Piece, i: int, theta: NDArray[np.float64], start: int, stop: int, y0: NDArray[np.float64],
            s0: NDArray[np.float64]) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """Network ``i``'s free run over rows ``start..stop-1`` of piece ``p`` with parameters ``theta`` (weights,
        then a linear part) and its derivatives (the kernel's column order), its first ``max_lag`` outputs ``y0``
        and their derivatives ``s0`` given."""
        du, cy, a, lags, lin_y, lin_u = p.P[i]
        M, li, Li = nets[i].neurons, p.lin[i], nets[i].max_lag
        if li is None:
            return free_run_sensitivities(du[start:stop], cy, a, lags, theta, lin_y, lin_u[start:stop], y0, Li,
                                          p.none[start:stop], 0, s0)
        xu, yj, uj = li
        c = theta[M:]
        return free_run_sensitivities(du[start:stop], cy, a, lags, theta[:M], np.ascontiguousarray(c[yj]),
                                      xu[start:stop] @ np.append(c[uj], c[-1]), y0, Li, xu[start:stop], len(yj), s0)

    def runs(ws: list[NDArray[np.float64]]) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]]:
        """The mean free run with parameters ``ws`` on the rows scored (each piece's from its ``L``-th), ``J'J``
        and ``J'(y - mean)``, ``J`` the Jacobian of that mean by all of them: each piece a free run of its own from
        its measured first outputs, made :data:`CHUNK_ROWS` rows at a time (each member's free run continued from
        the outputs and derivatives that end the chunk before), so that no ``n x parameters`` array is held."""
        scored: list[NDArray[np.float64]] = []
        jtj, jtr = np.zeros((w0_size, w0_size)), np.zeros(w0_size)
        for p in pieces:
            mean = np.empty(p.n)
            tails: list[tuple[NDArray[np.float64], NDArray[np.float64]]] = []
            for k, (a, b) in enumerate(p.bounds):

                def member(i: int) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
                    Li = nets[i].max_lag
                    y0, s0 = (p.yn, np.zeros((Li, sizes[i]))) if k == 0 else tails[i]
                    with np.errstate(over="ignore", invalid="ignore"):  # (numpy's error state is each thread's own)
                        return one(p, i, ws[i], 0 if k == 0 else a - Li, b, y0, s0)

                outs = thread_map(member, range(K), threads)
                tails = [(Y[Y.shape[0] - m.max_lag :].copy(), S[S.shape[0] - m.max_lag :].copy())
                         for (Y, S), m in zip(outs, nets)]
                first = 0 if k == 0 else a  # the first chunk's rows start at 0 for every member
                with np.errstate(over="ignore", invalid="ignore"):
                    mean[first:b] = np.mean([Y[Y.shape[0] - (b - first) :] for Y, _ in outs], axis=0)
                    J = np.concatenate([(S if o is None else S[:, o])[S.shape[0] - (b - a) :]
                                        for (_, S), o in zip(outs, orders)], axis=1) / K
                    jtj += J.T @ J
                    jtr += J.T @ (p.yn[a:b] - mean[a:b])
            scored.append(mean[L:])
        return (scored[0] if len(scored) == 1 else np.concatenate(scored)), jtj, jtr

    w0_size = int(sum(sizes))
    mean, jtj, jtr = runs(W)
    with np.errstate(over="ignore", invalid="ignore"):
        ok = bool(np.all(np.isfinite(mean)))
        score = path_score(norm.y_inverse(mean), y_scored, 0, 0, lo, hi, range_margin)[0] if ok else -np.inf
    ev["r2_fr_est_before"] = float(score) if np.isfinite(score) else None
    if not score >= above:
        return model, {**ev, "reason": f"estimation free-run R2 {score:.4f} below the gate {above}"}
    w0 = np.concatenate(W)
    rho = WEIGHT_PENALTY * max(float(np.mean(np.diag(jtj))), 1e-300)  # the weights' penalty (WEIGHT_PENALTY: why)
    eye = np.eye(w0.size)

    def objective(mean_run: NDArray[np.float64], w: NDArray[np.float64]) -> float:
        with np.errstate(over="ignore", invalid="ignore"):  # a diverging trial's free run: inf, refused below
            return float(np.sum((target - mean_run) ** 2) + rho * np.sum((w - w0) ** 2))

    cost = cost0 = objective(mean, w0)
    lam, trials = DAMPING[0], 0
    for it in range(iterations):
        w_now = np.concatenate(W)
        A, b = jtj + rho * eye, jtr - rho * (w_now - w0)
        D = np.diag(np.diag(A))
        gain = -1.0
        while lam <= DAMPING[2] and trials < iterations * _TRIALS:
            trials += 1
            try:
                step = np.linalg.solve(A + lam * D, b)
            except np.linalg.LinAlgError:
                lam *= 10.0
                continue
            ws = [W[i] + step[offs[i] : offs[i + 1]] for i in range(K)]
            m_new, jtj_new, jtr_new = runs(ws)
            c_new = objective(m_new, w_now + step)
            if np.isfinite(c_new) and c_new < cost:  # accepted: a bolder step next time
                W, mean, jtj, jtr, gain, cost = ws, m_new, jtj_new, jtr_new, (cost - c_new) / cost, c_new
                lam = max(lam / 10.0, DAMPING[1])
                break
            lam *= 10.0
        if gain < 0.0:
            break
        ev["iterations"] = it + 1
        if gain < _STOP:
            break
    if cost >= cost0:
        ev["reason"] = "no step lowered the free-run error"
        return model, ev
    if isinstance(model, EnsembleModel):
        refined: Model = replace(model, members=tuple(_with(m, w) for m, w in zip(nets, W)))
    else:
        refined = _with(model, W[0])
    after, excursion = path_score(norm.y_inverse(mean), y_scored, 0, 0, lo, hi, range_margin)
    ev.update(r2_fr_est_after=float(after) if np.isfinite(after) else None, excursion_spans=float(excursion))
    if not after > score:
        ev["reason"] = "the refined free run leaves the range" if excursion > 0 else "no gain on the whole record"
        return model, ev
    if not is_bounded(refined):
        ev["reason"] = "the refined linear part's autoregression is unstable (streamid.engine.choice.stability)"
        return model, ev
    if not osa:  # a caller that reads only the refined weights (the held-out judgement's first half)
        ev.update(taken=True)
        return refined, ev
    pred = refined.predict_osa(u, y, threads=threads)
    ev.update(taken=True, osa_mse_est=float(np.mean((pred[L:] - y[L:]) ** 2)))
    if keep_osa is not None:
        keep_osa.update(osa=pred, of=refined)
    return refined, ev


def refine_judged(
    model: Model, u: NDArray[np.float64], y: NDArray[np.float64], iterations: int, above: float, range_margin: float,
    threads: int = 1, keep_osa: dict[str, Any] | None = None,
) -> tuple[Model, dict[str, Any]]:
    """:func:`refine_weights` judged out of sample (the rule above): refined on the first half of ``(u, y)``, the
    refinement is made on the whole record only if that half's refined model free-runs better than ``model`` over
    the second half (both simulated from the record's start, R^2 over the second half). The evidence is
    :func:`refine_weights`'s with ``held_out`` (samples, and the two R^2 when the half was refined).

    Beyond one chunk (:func:`~streamid.engine.choice.scores.segments`) every free run of the three steps is made on
    segments of its part of the record (the first half, the second, the whole), each from its own measured outputs,
    and the evidence says how many (``segments``): the cost is bounded, not the record's."""
    if iterations < 1:
        return refine_weights(model, u, y, iterations, above, range_margin, threads, keep_osa=keep_osa)
    h, L = len(y) // 2, max(m.max_lag for m in members_of(model))
    whole = segments(0, len(y), L)  # beyond one chunk: each step on segments of the record (docs/method.md)
    if whole is not None:  # and in one BLAS thread: its J'J products waited on the second one (STACK.md)
        with one_blas_thread():
            return _judged(model, u, y, iterations, above, range_margin, threads, whole, keep_osa)
    return _judged(model, u, y, iterations, above, range_margin, threads, whole, keep_osa)


def _judged(model: Model, u: NDArray[np.float64], y: NDArray[np.float64], iterations: int, above: float,
            range_margin: float, threads: int, whole: list[tuple[int, int]] | None,
            keep_osa: dict[str, Any] | None = None) -> tuple[Model, dict[str, Any]]:
    """:func:`refine_judged`'s work (``whole``: the record's segments beyond one chunk, else None; ``keep_osa``:
    :func:`refine_weights`'s, for the refinement on the whole record)."""
    h, L = len(y) // 2, max(m.max_lag for m in members_of(model))
    half, ev_half = refine_weights(model, u[:h], y[:h], iterations, above, range_margin, threads,
                                   None if whole is None else segments(0, h, L), osa=False)  # judged by its free run
    held: dict[str, Any] = {"samples": int(len(y) - h)}
    if ev_half.get("taken"):
        if whole is None:
            held.update(r2_fr_before=_r2_after(model, u, y, h), r2_fr_after=_r2_after(half, u, y, h))  # None: diverged
        else:
            judged = segments(h - L, len(y), L) or [(h - L, len(y))]
            held.update(r2_fr_before=_r2_on(model, u, y, judged, L), r2_fr_after=_r2_on(half, u, y, judged, L),
                        segments=len(judged))
        before, after = (-math.inf if held[k] is None else held[k] for k in ("r2_fr_before", "r2_fr_after"))
        if after > before:
            refined, ev = refine_weights(model, u, y, iterations, above, range_margin, threads, whole,
                                         keep_osa=keep_osa)
            return refined, {**ev, "held_out": held}
        reason = f"no gain on the held-out second half (free-run R2 {before:.5f} -> {after:.5f} refined on the first)"
    else:
        reason = f"not taken on the first half ({ev_half.get('reason')})"
    return model, {"gate": float(above), "iterations": 0, "taken": False, "reason": reason, "held_out": held}


def _r2_after(model: Model, u: NDArray[np.float64], y: NDArray[np.float64], h: int) -> float | None:
    """R^2 of ``model``'s free run over ``(u, y)`` (from its first measured outputs) on the samples from ``h``;
    None when it diverged (:func:`~streamid.engine.validation.r2_or_none`)."""
    with np.errstate(over="ignore", invalid="ignore"):
        return r2_or_none(y[h:], model.simulate(u, y[: model.max_lag])[h:])


def _r2_on(model: Model, u: NDArray[np.float64], y: NDArray[np.float64], parts_: list[tuple[int, int]],
           L: int) -> float | None:
    """R^2 of ``model``'s free runs over the segments ``[start, stop)`` (each from its first ``L`` measured
    outputs) on their samples after those; None when one diverged."""
    with np.errstate(over="ignore", invalid="ignore"):
        sims = [model.simulate(u[a:b], y[a : a + model.max_lag])[L:] for a, b in parts_]
        return r2_or_none(np.concatenate([y[a + L : b] for a, b in parts_]), np.concatenate(sims))


def _with(model: Model, theta: NDArray[np.float64]) -> Model:
    """``model`` with the parameters ``theta`` (its weights, then its linear part's coefficients if it has one)."""
    M = model.neurons
    return replace(model, weights=theta[:M].copy(), linear=None if model.linear is None else theta[M:].copy())
