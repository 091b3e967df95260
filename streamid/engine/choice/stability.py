"""Bounded by construction: a model's linear part must have a stable autoregression.

Why
---
A model is ``yn(t) = sum_m w_m phi_m(r(t)) + a' y_past + b' u_past + c`` (normalised units): a Gaussian network
(each ``phi_m`` in ``(0, 1]``, so the network's output is bounded by ``sum |w_m|`` whatever its input) plus, when
it has one, a linear part. When the linear part's autoregression ``1 - sum_k a_k z^-k`` has every root inside the
unit circle, the model is a stable linear filter driven by a bounded signal (the network's output, the bounded
input's terms and the constant): its free run is bounded for every bounded input and every initial state. It may
be wrong on another experiment; it cannot diverge.

When a root lies on or beyond the unit circle, the network is what holds the free run, and only where its
Gaussians cover the data: beyond them the model *is* that unstable linear part. That is how the defaults' models
diverged on the next experiment (issue 37; docs/engine-results.md, "Issue 37, round 2"): the simulated piezo's and
Bouc-Wen oscillator's kept models had linear parts of pole radius 1.2-2.8 and validated at 0.97-0.998 on one
excitation and diverged on a sweep or on steps inside the same range.

The rule (applied where candidates are judged: :func:`~streamid.engine.choice.scores.free_run_scores`, the long linear part
of :mod:`streamid.engine.choice.longlinear`, the refinement of :mod:`streamid.engine.choice.refine`): a model whose linear part
(any member's, for a mean of networks) has an autoregression root of modulus >= 1 is never kept. A mean of such
models is bounded too (each member runs on its own past outputs).
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
from numpy.typing import NDArray

from streamid.model.ensemble import members_of
from streamid.model.narx import Model
from streamid.model.regressors import Regressor

__all__ = ["ar_coefficients", "ar_radius", "is_bounded", "radius"]


def ar_coefficients(regressors: Sequence[Regressor], coefficients: NDArray[np.float64]) -> NDArray[np.float64]:
    """``a_1 .. a_n`` of the autoregression ``1 - sum_k a_k z^-k`` of a linear part with these coefficients (one per
    regressor; a trailing constant is ignored) on these regressors: its output terms (empty: none)."""
    n = max((r.lag for r in regressors if r.signal == "y"), default=0)
    a = np.zeros(n)
    for c, r in zip(coefficients, regressors):
        if r.signal == "y":
            a[r.lag - 1] += c
    return a


def radius(regressors: Sequence[Regressor], coefficients: NDArray[np.float64]) -> float:
    """The largest root modulus of that autoregression (0: no output term)."""
    a = ar_coefficients(regressors, coefficients)
    if not a.size or not np.any(a != 0.0):
        return 0.0
    if not np.all(np.isfinite(a)):
        return float("inf")
    return float(np.max(np.abs(np.roots(np.concatenate([[1.0], -a])))))


def ar_radius(model: Model) -> float:
    """The largest root modulus of the linear part's autoregression (0: no output term, or no linear part);
    for a mean of networks, the largest of its members'."""
    out = 0.0
    for m in members_of(model):
        if m.linear is not None:
            out = max(out, radius(m.linear_regressors if m.linear_regressors is not None else m.regressors, m.linear))
    return out


def is_bounded(model: Model) -> bool:
    """Whether every linear part of ``model`` has a stable autoregression (every root strictly inside the unit
    circle): its free run is then bounded for every bounded input (see the module docstring)."""
    return ar_radius(model) < 1.0

