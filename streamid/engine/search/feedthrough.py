"""Whether an output responds to its inputs within the sample: a likelihood-ratio test of the direct terms.

NARX models in the paper's form use the inputs from ``u(t-1)`` on. Many sampled records respond within
the sample: an accelerometer to a shaker's force (acceleration is force over mass at the same
instant), a damper's force to its velocity, a record whose output was read just after its input was
set. Without ``u(t)`` among the candidates such a record is fitted through the lagged terms that best
stand in for it, and the free run pays: the heat exchanger of the tuning suite validated at free-run
R^2 0.65 without the direct term and 0.95 with it, its residual correlating with ``u(t)`` at -0.55.

The test (the classical one for an input delay, as in MATLAB's ``delayest``, with a nested pair):
two linear ARX models of order ``p`` fitted by least squares on the estimation record, both with
``y(t-1) .. y(t-p)``, ``u_i(t-1) .. u_i(t-p)`` of every input and a constant, one with and one without
input ``i``'s direct term ``u_i(t)``. Under "no direct term" (and the usual assumptions) the statistic
``LR_i = n log(s2_without / s2_with)`` is chi-square with one degree of freedom; the direct terms become
candidates (``min_lag_u = 0``) when some ``LR_i`` exceeds :data:`THRESHOLD` (p = 0.001). The order is the
lag space the identification searches, so a long memory is not mistaken for a direct term (Bouc-Wen's
displacement, which has none: LR 561 at order 2, 9 at order 10, 0.9 at order 20).

Pure numpy; no I/O.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

import numpy as np
from numpy.typing import NDArray

from streamid.engine.search.rows import spaced_rows

if TYPE_CHECKING:
    from streamid.engine.search.populations import CoEAState
    from streamid.engine.settings import CoEAConfig

__all__ = ["THRESHOLD", "direct_terms", "feedthrough_test"]

#: chi-square with one degree of freedom at p = 0.001
THRESHOLD = 10.83


def _residual_variance(X: NDArray[np.float64], y: NDArray[np.float64]) -> float:
    sd = X.std(axis=0)
    keep = sd > 0  # constant columns (an input that never moves) carry nothing but the constant's job
    Z = np.column_stack([(X[:, keep] - X[:, keep].mean(axis=0)) / sd[keep], np.ones(len(y))])
    theta, *_ = np.linalg.lstsq(Z, y, rcond=None)
    e = y - Z @ theta
    return float(e @ e) / len(y)


def feedthrough_test(u: NDArray[np.float64], y: NDArray[np.float64], order: int) -> dict[str, Any]:
    """The test of the module docstring on ``u`` (N, n_inputs) and ``y`` (N,) with ARX order ``order``.

    Returns ``{"order", "lr": [LR_i per input], "threshold", "min_lag_u"}`` (``min_lag_u`` 0 when some
    ``LR_i`` exceeds the threshold, else 1); an order the record cannot support (fewer than 10 rows
    per coefficient) is lowered to one it can. Beyond one chunk of rows the fits use
    :func:`~streamid.engine.search.rows.spaced_rows` (``n`` in ``LR_i`` is then their count).
    """
    u2 = np.asarray(u, dtype=np.float64).reshape(len(y), -1)
    y1 = np.asarray(y, dtype=np.float64)
    n_in = u2.shape[1]
    p = max(1, min(int(order), (len(y1) // 10 - n_in - 1) // (1 + n_in)))
    rows = len(y1) - p
    if rows < 3 * (1 + p * (1 + n_in) + n_in):
        return {"order": p, "lr": [0.0] * n_in, "threshold": THRESHOLD, "min_lag_u": 1, "note": "too few samples"}
    pick = spaced_rows(rows)  # beyond one chunk: the two fits on CHUNK_ROWS evenly spaced rows (bounded)
    if pick is None:
        lagged = [y1[p - k : len(y1) - k] for k in range(1, p + 1)]
        for i in range(n_in):
            lagged += [u2[p - k : len(y1) - k, i] for k in range(1, p + 1)]
        direct = [u2[p:, i] for i in range(n_in)]
        target = y1[p:]
    else:
        t = p + pick
        lagged = [y1[t - k] for k in range(1, p + 1)]
        for i in range(n_in):
            lagged += [u2[t - k, i] for k in range(1, p + 1)]
        direct, target, rows = [u2[t, i] for i in range(n_in)], y1[t], int(t.size)
    full = _residual_variance(np.column_stack(lagged + direct), target)
    lr = []
    for i in range(n_in):
        without = _residual_variance(np.column_stack(lagged + [d for j, d in enumerate(direct) if j != i]), target)
        lr.append(float(rows * np.log(without / full)) if full > 0 and without > 0 else 0.0)
    return {"order": p, "lr": lr, "threshold": THRESHOLD, "min_lag_u": 0 if max(lr) > THRESHOLD else 1}


def direct_terms(cfg: CoEAConfig, u: NDArray[np.float64], y: NDArray[np.float64], warm: CoEAState | None,
                 *, test: bool = True) -> tuple[CoEAConfig, dict[str, Any] | None]:
    """``cfg`` with ``direct_terms`` decided (``"on"``/``"off"``) for a run on ``u``/``y``, and the test's
    evidence (None: not tested).

    A warm start keeps its state's candidates (its populations' bits are theirs); otherwise, with
    ``cfg.direct_terms == "test"`` and ``test``, the record is tested (:func:`feedthrough_test`, order
    ``cfg.max_lag``); otherwise ``cfg`` as given (``"test"`` untested: the paper's ``u(t-1)`` on). Used by
    ``identify`` and the online updates alike.
    """
    if warm is not None:
        return cfg.replace(direct_terms="on" if warm.min_lag_u == 0 else "off"), None
    if cfg.direct_terms == "test" and test:
        ev = feedthrough_test(u, y, cfg.max_lag)
        return cfg.replace(direct_terms="on" if ev["min_lag_u"] == 0 else "off"), ev
    return cfg, None
