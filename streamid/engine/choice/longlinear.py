"""A long linear part: the chosen network plus a dense linear ARX of an order chosen from the data.

Why
---
The networks' lags are searched up to ``max_lag_cap`` (30): enough for most devices, not for a
lightly damped structure sampled fast. On the F-16 ground vibration test (400 Hz, modes of a few
Hz: a period is 60-100 samples) the networks free-run at R^2 0.42-0.77 on validation, and a plain
linear ARX of order 120-160 reaches 0.79-0.89 (docs/engine-results.md, round 12). Searching lags
to 160 with the harmony search would cost the search its speed on every record; a *dense* linear
part of order ``n`` costs one least squares.

The rule (:func:`long_linear_choice`, applied by :func:`~streamid.engine.identification.identify` to its
final choice when ``CoEAConfig.long_linear`` > 0)
-------------------------------------------------------------------------------------------------
0. It is tried only on a record the final choice explains in part: its estimation free-run R^2
   below ``settings.MORE_BELOW`` (0.95), the band where more restarts are made too. Above it a long
   linear part measured no better on validation (the heat exchanger: 0.9599 -> 0.9509, round 12).
1. The base is the final choice's best single network (an ensemble's first member); its centres,
   widths and lags are kept.
2. The orders offered are ``2, 3, 4, 6, 8, 12, ...`` (doubling, with the midpoints) up to
   ``n_max = min(long_linear, (N / 10 - M - 1) / (1 + n_inputs))`` (``M`` the largest network
   offered): at least ten rows per parameter (and a design of at most :data:`MAX_DESIGN_BYTES`).
   The linear part of order ``n`` is ``y(t-1..t-n)`` and every input's ``u(t-d..t-n)``, ``d`` 0
   when the base network has an input term at lag 0 (the direct-term test found one), else 1.
3. Every fit shares the rows ``t >= L`` (``L`` the largest lag of the linear part and of the
   networks offered). One QR of the linear columns ``[1, linear terms ordered by lag]`` (scaled to
   unit norm, with the weights' ridge; Q kept) serves every order (a prefix of the columns) and
   every network (its activations projected off that prefix; :class:`_LinearBlock`).
3b. The linear part's autoregression must be stable (:mod:`streamid.engine.choice.stability`: the model is then
   bounded on every input). When the joint least squares of the network and the linear part gives an
   unstable one, the autoregression is taken from the linear part fitted alone (the best linear
   approximation of that order, on the same rows and ridge: :meth:`_LinearBlock.with_autoregression`) and
   the network's weights, the input terms and the constant are fitted with it fixed; if that one is
   unstable too, the order is not offered for that network (evidence: ``autoregression`` in its row).
4. Each order's model free-runs over the estimation record; the range guard of
   :mod:`streamid.engine.choice.scores` applies, and the order of the lowest AIC
   (``p = M + q + 1``) whose free run explains the record better than its mean
   (:data:`MIN_R2_FR_EST`) and also stays in range when it goes on over the record a second time
   (twice the horizon, and a jump of the input at the seam: a perturbed state) is this rule's
   candidate (:func:`ar_radius` in the evidence).
5. Every other run whose network was admissible in the final choice is offered a linear part of
   that order too (a network fitted to a short memory is a different nonlinearity; with the
   memory carried by the linear part, the runs' networks rank differently). The lowest criterion among
   them (the same guards) is the candidate (round 13 of docs/engine-results.md).
6. The means of the two and of the three best candidates of steps 4-5 (by the criterion, each
   admissible by the same guards; :data:`MAX_MEAN_OF`) compete with the best: each member runs free on
   its own past outputs and their outputs are averaged (an
   :class:`~streamid.model.ensemble.EnsembleModel`, ``streamid.model/5``), scored by the same criterion with
   ``p`` the mean of the members' (:func:`~streamid.engine.choice.complexity.parameter_count`). Why: near-ties on the
   estimation free run (1e-4 in R^2) can validate 0.03 apart, and their mean is steadier than a draw among them
   (evidence: ``means``; docs/engine-results.md, round 14).
7. It replaces the final choice only when its criterion is lower than the final choice's (the
   same rule, the final choice's own ``p``), so where the networks explain the record the
   long linear part, with its many parameters, is not taken.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, replace
from itertools import islice
from typing import Any

import numpy as np
from numpy.typing import NDArray
from scipy.linalg import qr, solve_triangular

from streamid.engine.fit.blas import one_blas_thread
from streamid.engine.choice.scores import path_score
from streamid.engine.choice.complexity import criterion, parameter_count
from streamid.model.ensemble import ensemble_of, members_of
from streamid.model.narx import Model
from streamid.engine.fit.rbf import MIN_NORM, activations
from streamid.model.regressors import Regressor, regressor_columns
from streamid.engine.choice.stability import ar_radius, is_bounded, radius

__all__ = ["ar_radius", "dense_regressors", "long_linear_choice", "long_linear_fit", "orders"]

#: Rows per parameter the largest order keeps at least.
ROWS_PER_PARAMETER = 10
#: The largest design the QR takes (rows x columns x 8 bytes; Q is as large again): on a long record this,
#: not the rows, bounds the order (100,000 samples of one input: order 167).
MAX_DESIGN_BYTES = 256 * 2**20
#: A part is taken only when its estimation free run explains the record better than its mean does (R^2 above
#: this): a criterion compares models that explain something; among free runs worse than the mean it chose
#: parts that diverged on validation (the ball and beam, seeds 26, 37 and 53 of 60: R^2 est -1.9 to -1.0).
MIN_R2_FR_EST = 0.0


def orders(n_max: int) -> list[int]:
    """The orders offered up to ``n_max``: 2, 3, 4, 6, 8, 12, 16, 24, ... (doubling, with the midpoints)."""
    out: list[int] = []
    k = 2
    while k <= n_max:
        out += [k] + ([k + k // 2] if k + k // 2 <= n_max else [])
        k *= 2
    return sorted(set(out))


def dense_regressors(order: int, n_inputs: int, direct: bool) -> tuple[Regressor, ...]:
    """``y(t-1..t-order)`` and each input's ``u(t-d..t-order)`` (``d`` 0 with ``direct``), ordered by lag."""
    regs: list[Regressor] = [Regressor("u", i, 0) for i in range(n_inputs)] if direct else []
    for lag in range(1, order + 1):
        regs.append(Regressor("y", 0, lag))
        regs += [Regressor("u", i, lag) for i in range(n_inputs)]
    return tuple(regs)


def long_linear_choice(
    final: Model, final_score: float, max_order: int,
    u: NDArray[np.float64], y: NDArray[np.float64], range_margin: float, ridge: float,
    runs: Sequence[tuple[int, Model]] = (), base_run: int | None = None, min_order: int = 2,
    max_design_bytes: int = MAX_DESIGN_BYTES,
) -> tuple[Model | None, dict[str, Any]]:
    """The model with a long linear part that replaces ``final`` (None: ``final`` stands) and the evidence.

    ``final_score``: ``final``'s estimation free-run R^2 (the selection score); ``u`` (N, n_inputs), ``y``
    (N,): the estimation record in output units; ``ridge``: as :func:`~streamid.engine.fit.rbf.fit_weights`'s
    (on columns scaled to unit norm); ``runs``: the other runs' networks offered the order chosen (step 5),
    as ``(run, model)``; ``base_run``: the run of ``final``'s best network; ``min_order``: the lowest order
    offered (an online update offers only orders above its lag search's, :mod:`streamid.online.update`);
    ``max_design_bytes``: the largest design the QR takes (:data:`MAX_DESIGN_BYTES`; an online update's is smaller).
    See the module docstring.
    """
    base = members_of(final)[0]
    n_in, N, M = base.n_inputs, len(y), base.neurons
    nets = [(base_run, base)] + [(i, m) for i, m in runs if i != base_run and m is not base and _shares_rows(m, base)]
    M_most = max(m.neurons for _, m in nets)
    n_max = min(int(max_order), (N // ROWS_PER_PARAMETER - M_most - 1) // (1 + n_in),
                (int(max_design_bytes) // (8 * N) - M_most - 1) // (1 + n_in))
    own = criterion(final_score, N - final.max_lag, parameter_count(final)) if np.isfinite(final_score) else np.inf
    ev: dict[str, Any] = {"max_order": int(max_order), "orders": [], "criterion_without": _finite(own),
                          "taken": False}
    offered = [n for n in orders(n_max) if n >= min_order]
    if not offered:
        return None, {**ev, "reason": f"too few samples ({N}) for an order >= {max(2, min_order)}"}
    direct = any(r.signal == "u" and r.lag == 0 for r in base.regressors)
    lregs = dense_regressors(offered[-1], n_in, direct)
    L = max([m.max_lag for _, m in nets] + [max(r.lag for r in lregs)])  # the rows every fit shares: t >= L
    if N - L < 2 * (M_most + len(lregs) + 1):
        return None, {**ev, "reason": f"too few samples ({N}) for order {offered[-1]}"}
    norm = base.normalisation
    un, yn = norm.u(u), norm.y(y)
    with one_blas_thread():
        Z = np.hstack([np.ones((N - L, 1)), regressor_columns(lregs, un, yn, L)])
        is_y = np.array([False] + [r.signal == "y" for r in lregs])
        fit = _LinearBlock(Z, yn[L:], ridge)
        lo, hi = float(np.min(y)), float(np.max(y))
        offers: list[_Offer] = []  # every offer that explains the record and stays in range over one pass

        def offer(run: int | None, net: Model, n: int, row: dict[str, Any]) -> None:
            q = n * (1 + n_in) + (n_in if direct else 0)
            acts = activations(regressor_columns(net.regressors, un, yn, L), net.centres, net.widths)
            w, c = fit.solve(acts, 1 + q)
            model = replace(net, weights=w, linear=np.concatenate([c[1:], c[:1]]), linear_regressors=lregs[:q],
                            metrics=dict(net.metrics))
            if not is_bounded(model):  # step 3b: the autoregression of the linear part fitted alone, if stable
                w, c = fit.with_autoregression(Z, acts, 1 + q, is_y)
                model = replace(model, weights=w, linear=np.concatenate([c[1:], c[:1]]))
                row["autoregression"] = "fitted alone"
                if not is_bounded(model):
                    row["autoregression"] = "unstable"
                    return
            Lm = model.max_lag
            with np.errstate(over="ignore", invalid="ignore"):
                path = model.simulate(u, y[:Lm])
            if not np.all(np.isfinite(path[Lm:])):
                return
            score, excursion = path_score(path, y, Lm, Lm, lo, hi, range_margin)
            if excursion > 0.0:
                row["excursion_spans"] = float(excursion)
                return
            value = criterion(score, N - Lm, parameter_count(model))
            row.update(r2_fr_est=float(score), criterion=float(value))
            if score > MIN_R2_FR_EST:
                offers.append(_Offer(value, model, row, run, n, path))

        def second_pass(o: _Offer) -> bool:  # step 4: it also stays in range when it goes on over the record again
            if "second_pass_excursion" not in o.row:
                Lm = o.model.max_lag
                with np.errstate(over="ignore", invalid="ignore"):
                    twice = o.model.simulate(np.concatenate([u, u]), y[:Lm])
                again = (path_score(twice, np.concatenate([y, y]), Lm, Lm, lo, hi, range_margin)[1]
                         if np.all(np.isfinite(twice[Lm:])) else np.inf)
                o.row["second_pass_excursion"] = _finite(again)
            return bool(o.row["second_pass_excursion"] == 0.0)

        def ranked(n: int | None = None) -> list[_Offer]:  # offers (of order n) by criterion, lowest first
            return sorted((o for o in offers if n is None or o.order == n), key=lambda o: o.value)

        for n in offered:  # step 4: the order, on the final choice's best network
            row: dict[str, Any] = {"order": n, "params": M + 1 + n * (1 + n_in) + (n_in if direct else 0),
                                   "r2_fr_est": None, "criterion": None}
            ev["orders"].append(row)
            offer(base_run, base, n, row)
        first = next((o for o in ranked() if o.value < own and second_pass(o)), None)
        if first is not None:  # step 5: the other runs' networks with a linear part of that order
            ev["networks"] = [{"run": base_run, "neurons": M, "r2_fr_est": first.row["r2_fr_est"],
                               "criterion": first.row["criterion"]}]
            for run, net in nets[1:]:
                ev["networks"].append({"run": run, "neurons": net.neurons, "r2_fr_est": None, "criterion": None})
                offer(run, net, first.order, ev["networks"][-1])
            best = list(islice((o for o in ranked(first.order) if o.value < own and second_pass(o)), MAX_MEAN_OF))
            chosen, taken = _means(best, u, y, lo, hi, range_margin, ev)
    if first is None:
        return None, ev
    ev.update(taken=True, order=taken.order, run=taken.run, r2_fr_est=taken.score, criterion=taken.value,
              ar_radius=ar_radius(members_of(chosen)[0]))
    Lc = chosen.max_lag
    fitness = float(np.mean((chosen.predict_osa(u, y)[Lc:] - y[Lc:]) ** 2))
    return chosen.with_metrics(fitness=fitness), ev


def long_linear_fit(lregs: Sequence[Regressor], phi: NDArray[np.float64], rl: NDArray[np.float64],
                    target: NDArray[np.float64], ridge: float) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """A network's weights (activations ``phi``) and its long linear part (``[coefficients; constant]``) on the
    regressors ``lregs`` (columns ``rl``), fitted as the offers of :func:`long_linear_choice` are (steps 3 and 3b):
    for a refit of a kept model (:func:`~streamid.engine.choice.selection.refit_weights`)."""
    Z = np.hstack([np.ones((len(target), 1)), rl])
    block = _LinearBlock(Z, target, ridge)
    w, c = block.solve(phi, Z.shape[1])
    if not radius(lregs, c[1:]) < 1.0:
        w, c = block.with_autoregression(Z, phi, Z.shape[1], np.array([False] + [r.signal == "y" for r in lregs]))
    return w, np.concatenate([c[1:], c[:1]])


#: The most offers a mean is made of (step 6 of the module docstring).
MAX_MEAN_OF = 3


@dataclass
class _Offer:
    """One network offered a linear part of ``order``: its criterion, model, evidence row, run and estimation free run."""

    value: float
    model: Model
    row: dict[str, Any]
    run: int | None
    order: int
    path: NDArray[np.float64]

    @property
    def score(self) -> float:
        return float(self.row["r2_fr_est"])


def _means(best: list[_Offer], u: NDArray[np.float64], y: NDArray[np.float64], lo: float, hi: float,
           range_margin: float, ev: dict[str, Any]) -> tuple[Model, _Offer]:
    """Step 6: the best offer, or the mean of the two or three best, whichever has the lowest criterion.

    ``best``: the admissible offers of the chosen order, lowest criterion first. A mean's free run is the mean of
    its members' (each on its own past outputs: an :class:`~streamid.model.ensemble.EnsembleModel`), and its
    parameter count is the mean of the members': each member's weights are a least squares on the same rows,
    and the mean of least-squares fits has the mean of their degrees of freedom (the trace of the mean of their
    hat matrices). The evidence goes to ``ev["means"]``.
    """
    top, means = best[0], []
    chosen, taken = top.model, top
    N = len(y)
    for k in range(2, len(best) + 1):
        members = best[:k]
        Lk = max(o.model.max_lag for o in members)
        path = np.mean([o.path for o in members], axis=0)
        score, excursion = path_score(path, y, Lk, Lk, lo, hi, range_margin)
        params = float(np.mean([parameter_count(o.model) for o in members]))
        value = criterion(score, N - Lk, params) if excursion == 0.0 else np.inf
        means.append({"members": [o.run for o in members], "r2_fr_est": _finite(score), "params": params,
                      "criterion": _finite(value), "taken": False})
        if value < taken.value:
            chosen = ensemble_of([o.model for o in members], metrics=dict(top.model.metrics))
            taken = _Offer(value, chosen, {"r2_fr_est": float(score)}, top.run, top.order, path)
            for m in means:
                m["taken"] = False
            means[-1]["taken"] = True
    ev["means"] = means
    return chosen, taken


class _LinearBlock:
    """The least squares of ``[Z[:, :p], A]`` against ``target`` for any prefix ``p`` of the linear columns ``Z``
    and any network's activations ``A``, with the weights' ridge on columns scaled to unit norm.

    One QR of ``Z`` (with its ridge rows; Q kept) serves every order and network: ``A`` is projected off the
    prefix's columns (twice: classical Gram-Schmidt with reorthogonalisation), the network's weights are the
    small least squares of what is left, and the linear coefficients follow from ``R``.
    """

    def __init__(self, Z: NDArray[np.float64], target: NDArray[np.float64], ridge: float) -> None:
        self.scale = np.linalg.norm(Z, axis=0)
        self.scale[self.scale == 0.0] = 1.0
        P = Z.shape[1]
        self.root = np.sqrt(max(ridge, 1e-12))
        self.rows = Z.shape[0]
        self.Q, self.R = qr(np.vstack([Z / self.scale, self.root * np.eye(P)]), mode="economic",
                            overwrite_a=True, check_finite=False)
        self.t = np.concatenate([target, np.zeros(P)])
        self.qt = self.Q.T @ self.t

    def solve(self, A: NDArray[np.float64], p: int) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """The network's weights (``A``'s columns) and the first ``p`` linear coefficients, in ``Z``'s units."""
        A, sa = _live(A)
        Qp = self.Q[:, :p]
        Ap = np.vstack([A / sa, np.zeros((self.Q.shape[0] - self.rows, A.shape[1]))])
        B = Qp.T @ Ap
        Ap -= Qp @ B
        B2 = Qp.T @ Ap
        Ap -= Qp @ B2
        B += B2
        tp = self.t - Qp @ self.qt[:p]
        m = A.shape[1]
        q2, r2 = qr(np.vstack([Ap, self.root * np.eye(m)]), mode="economic", check_finite=False)
        w = solve_triangular(r2, q2.T @ np.concatenate([tp, np.zeros(m)]))
        c = solve_triangular(self.R[:p, :p], self.qt[:p] - B @ w)
        return w / sa, c / self.scale[:p]

    def with_autoregression(self, Z: NDArray[np.float64], A: NDArray[np.float64], p: int,
                            is_y: NDArray[np.bool_]) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """Like :meth:`solve`, with the output terms' coefficients those of the linear part fitted alone (the
        first ``p`` columns of ``Z``, the same ridge): the network's weights and the input terms and constant are
        fitted with that autoregression fixed (step 3b of the module docstring)."""
        c = solve_triangular(self.R[:p, :p], self.qt[:p]) / self.scale[:p]
        ys = is_y[:p]
        X = np.hstack([Z[:, :p][:, ~ys], _live(A)[0]])
        sx = np.linalg.norm(X, axis=0)
        sx[sx == 0.0] = 1.0
        k = X.shape[1]
        target = self.t[: self.rows] - Z[:, :p][:, ys] @ c[ys]
        q2, r2 = qr(np.vstack([X / sx, self.root * np.eye(k)]), mode="economic", check_finite=False)
        sol = solve_triangular(r2, q2.T @ np.concatenate([target, np.zeros(k)])) / sx
        n_lin = int((~ys).sum())
        c = c.copy()
        c[~ys] = sol[:n_lin]
        return sol[n_lin:], c


def _live(A: NDArray[np.float64]) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """``A`` with its dead columns zeroed (a neuron whose activations' norm is at most the engine's
    :data:`~streamid.engine.fit.rbf.MIN_NORM`: where no row is; its weight is then 0, as in the search and in
    :func:`~streamid.engine.fit.rbf.fit_weights`, not the inverse of a norm of 1e-80) and the column norms to scale by
    (1 for a dead column)."""
    sa = np.linalg.norm(A, axis=0)
    dead = sa <= MIN_NORM
    if np.any(dead):
        A = np.where(dead, 0.0, A)
    return A, np.where(dead, 1.0, sa)


def _shares_rows(m: Model, base: Model) -> bool:
    """Whether ``m`` is a single network on ``base``'s signals and scaling (its activations join the same fit)."""
    return (m.linear_regressors is None and m.n_inputs == base.n_inputs and m.normalisation == base.normalisation
            and not members_of(m)[1:])


def _finite(v: float) -> float | None:
    return float(v) if np.isfinite(v) else None
