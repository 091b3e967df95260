"""A long linear part: the chosen network plus a dense linear ARX of an order chosen from the data.

Why
---
The networks' lags are searched up to ``max_lag_cap`` (30): enough for most devices, not for a
lightly damped structure sampled fast. On the F-16 ground vibration test (400 Hz, modes of a few
Hz: a period is 60-100 samples) the networks free-run at R^2 0.42-0.77 on validation, and a plain
linear ARX of order 120-160 reaches 0.79-0.89 (docs/engine-results.md, round 12). Searching lags
to 160 with the harmony search would cost the search its speed on every record; a *dense* linear
part of order ``n`` costs one least squares.

The rule (:func:`long_linear_choice`, applied by :func:`~streamid.engine.identify.identify` to its
final choice when ``CoEAConfig.long_linear`` > 0)
-------------------------------------------------------------------------------------------------
0. It is tried only on a record the final choice explains in part: its estimation free-run R^2
   below ``CoEAConfig.more_below`` (0.95), the band where more restarts are made too. Above it
   the networks fit the record and a long linear part measured no better on validation: on the
   heat exchanger (estimation R^2 0.99) it was taken in 4 of 5 seeds by the criterion and its
   validation median fell 0.9599 -> 0.9509 (round 12 of docs/engine-results.md).
1. The base is the final choice's best single network (an ensemble's first member); its centres,
   widths and lags are kept.
2. The orders offered are ``2, 3, 4, 6, 8, 12, ...`` (doubling, with the midpoints) up to
   ``n_max = min(long_linear, (N / 10 - M - 1) / (1 + n_inputs))``: at least ten rows per
   parameter (and a design of at most :data:`MAX_DESIGN_BYTES`). On the F-16 (8,192 samples) the
   rows bind (order 384 of at most 394); with ``long_linear = 256`` the medians were lower on all
   three outputs (0.904 / 0.871 / 0.804 against 0.924 / 0.906 / 0.869). The linear part of order ``n`` is ``y(t-1..t-n)`` and every input's ``u(t-d..t-n)``,
   ``d`` 0 when the base network has an input term at lag 0 (the direct-term test found one), else 1.
3. One QR of the rows ``t >= max(n_max, L)`` of ``[activations, 1, linear terms ordered by lag]``
   (columns scaled to unit norm, with the weights' ridge) gives every order's least squares (a
   prefix of the columns; no refit per order).
4. Each order's model free-runs over the estimation record; the range guard of
   :mod:`streamid.engine.choice` applies, and the order of the lowest ``complexity`` criterion
   (``p = M + q + 1``) whose free run also stays in range when it goes on over the record a second
   time (twice the horizon, and a jump of the input at the seam: a perturbed state) is this rule's
   candidate. Without that pass the ball and beam's seed 3 took an order-3 part in range on its 500
   estimation samples that diverged on validation (R^2 -6e126 against -83 without it). Requiring a
   stable autoregression instead (every root of ``1 - sum_k a_k z^-k`` inside the unit circle,
   :func:`ar_radius`, in the evidence) would refuse the F-16's parts too: their roots reach 1.03-1.13,
   yet with the network's own feedback on the outputs their free runs stay bounded and validate at
   0.90-0.92.
5. It replaces the final choice only when its criterion is lower than the final choice's (the
   same rule, the final choice's own ``p``), so where the networks explain the record the
   long linear part, with its many parameters, is not taken.
"""

from __future__ import annotations

from dataclasses import replace
from typing import Any

import numpy as np
from numpy.typing import NDArray
from scipy.linalg import qr, solve_triangular

from streamid.engine._blas import one_blas_thread
from streamid.engine.choice import path_score
from streamid.engine.complexity import criterion, parameter_count
from streamid.engine.ensemble import members_of
from streamid.engine.model import Model
from streamid.engine.rbf import activations
from streamid.engine.regressors import Regressor

__all__ = ["ar_radius", "dense_regressors", "long_linear_choice", "orders"]

#: Rows per parameter the largest order keeps at least.
ROWS_PER_PARAMETER = 10
#: The largest design the QR takes (rows x columns x 8 bytes; Q is as large again): on a long record this,
#: not the rows, bounds the order (100,000 samples of one input: order 167).
MAX_DESIGN_BYTES = 256 * 2**20


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
    final: Model, final_score: float, rule: str, max_order: int,
    u: NDArray[np.float64], y: NDArray[np.float64], range_margin: float, ridge: float,
) -> tuple[Model | None, dict[str, Any]]:
    """The model with a long linear part that replaces ``final`` (None: ``final`` stands) and the evidence.

    ``final_score``: ``final``'s estimation free-run R^2 (the selection score); ``u`` (N, n_inputs), ``y``
    (N,): the estimation record in output units; ``ridge``: as :func:`~streamid.engine.rbf.fit_weights`'s
    (on columns scaled to unit norm). See the module docstring for the rule.
    """
    base = members_of(final)[0]
    n_in, N, M = base.n_inputs, len(y), base.neurons
    n_max = min(int(max_order), (N // ROWS_PER_PARAMETER - M - 1) // (1 + n_in),
                (MAX_DESIGN_BYTES // (8 * N) - M - 1) // (1 + n_in))
    L0 = final.max_lag
    own = criterion(rule, final_score, N - L0, parameter_count(final)) if np.isfinite(final_score) else np.inf
    ev: dict[str, Any] = {"max_order": int(max_order), "orders": [], "criterion_without": _finite(own),
                          "taken": False}
    offered = orders(n_max)
    if not offered:
        return None, {**ev, "reason": f"too few samples ({N}) for an order >= 2"}
    direct = any(r.signal == "u" and r.lag == 0 for r in base.regressors)
    lregs = dense_regressors(offered[-1], n_in, direct)
    lin0 = replace(base, linear=np.zeros(len(lregs) + 1), linear_regressors=lregs, metrics={})
    L = lin0.max_lag
    if N - L < 2 * (M + len(lregs) + 1):
        return None, {**ev, "reason": f"too few samples ({N}) for order {offered[-1]}"}
    with one_blas_thread():
        r, target = lin0.regressor_rows(u, y)
        X = np.hstack([activations(r, base.centres, base.widths), np.ones((N - L, 1)), lin0.linear_rows(u, y)])
        scale = np.linalg.norm(X, axis=0)
        scale[scale == 0.0] = 1.0
        P = X.shape[1]  # the ridge as rows sqrt(ridge) I under the scaled columns: a prefix's fit is that prefix's
        aug = np.vstack([np.hstack([X / scale, target[:, None]]),  # the target as the last column: R's last
                         np.hstack([np.sqrt(max(ridge, 1e-12)) * np.eye(P), np.zeros((P, 1))])])  # column is Q'y
        R = qr(aug, mode="r", overwrite_a=True, check_finite=False)[0]  # Q never formed (half the work)
        qy = R[:P, P]
    lo, hi = float(np.min(y)), float(np.max(y))
    best: tuple[float, Model | None, dict[str, Any]] = (own, None, {})
    per_lag = 1 + n_in
    for n in offered:
        q = n * per_lag + (n_in if direct else 0)
        p = M + 1 + q
        theta = solve_triangular(R[:p, :p], qy[:p]) / scale[:p]
        model = replace(base, weights=theta[:M], linear=np.concatenate([theta[M + 1 :], theta[M : M + 1]]),
                        linear_regressors=lregs[:q], metrics=dict(base.metrics))
        Lm = model.max_lag
        row: dict[str, Any] = {"order": n, "params": p, "r2_fr_est": None, "criterion": None}
        ev["orders"].append(row)
        with np.errstate(over="ignore", invalid="ignore"):
            path = model.simulate(u, y[:Lm])
        if not np.all(np.isfinite(path[Lm:])):
            continue
        score, excursion = path_score(path, y, Lm, Lm, lo, hi, range_margin)
        if excursion > 0.0:
            row["excursion_spans"] = float(excursion)
            continue
        value = criterion(rule, score, N - Lm, parameter_count(model))
        row.update(r2_fr_est=float(score), criterion=float(value))
        if value < best[0]:  # it would be taken: only if it also stays in range over a second pass (step 4)
            row["ar_radius"] = ar_radius(model)
            with np.errstate(over="ignore", invalid="ignore"):
                twice = model.simulate(np.concatenate([u, u]), y[:Lm])
            again = (path_score(twice, np.concatenate([y, y]), Lm, Lm, lo, hi, range_margin)[1]
                     if np.all(np.isfinite(twice[Lm:])) else np.inf)
            row["second_pass_excursion"] = _finite(again)
            if again == 0.0:
                best = (value, model, row)
    value, chosen, row = best
    if chosen is None:
        return None, ev
    ev.update(taken=True, order=row["order"], r2_fr_est=row["r2_fr_est"], criterion=float(value))
    Lc = chosen.max_lag
    fitness = float(np.mean((chosen.predict_osa(u, y)[Lc:] - y[Lc:]) ** 2))
    return chosen.with_metrics(fitness=fitness), ev


def ar_radius(model: Model) -> float:
    """The largest root modulus of the linear part's autoregression ``1 - sum_k a_k z^-k`` (its output terms)."""
    regs = model.linear_regressors if model.linear_regressors is not None else model.regressors
    assert model.linear is not None
    n = max((r.lag for r in regs if r.signal == "y"), default=0)
    if n == 0:
        return 0.0
    a = np.zeros(n)
    for c, r in zip(model.linear[:-1], regs):
        if r.signal == "y":
            a[r.lag - 1] += c
    return float(np.max(np.abs(np.roots(np.concatenate([[1.0], -a])))))


def _finite(v: float) -> float | None:
    return float(v) if np.isfinite(v) else None
