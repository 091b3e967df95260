"""A model's estimation domain: whether a record's values lie beyond the range the estimation data spanned
(a network of Gaussian bumps does not extrapolate).

The domain is each regressor's range on the estimation record, which the model's normalisation holds (every
regressor is a lagged input or output, whose estimation range maps to [-1, 1]). :func:`outside_share` is the share
of a record's samples at which the model would evaluate a regressor outside it: what ``validate``, the daemon's
status, the ``Predictor`` and an FMU's ``<output>_in_domain`` report.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import math
import sys

import numpy as np
from numpy.typing import NDArray

from streamid.model.regressors import Normalisation, Regressor

__all__ = ["BEYOND_RANGE", "beyond_bounds", "beyond_range", "domain_regressors", "domain_text", "excess", "far_from_domain", "outside", "outside_share",
           "signal_excess", "signal_outside", "value_excess", "value_outside"]


#: A validation signal counts as beyond the estimation range when it leaves it by more than this fraction of the
#: estimation span (the free-run range guard of the final choice allows 0.25 of it; docs/method.md).
BEYOND_RANGE = 0.25


def beyond_range(lo: float, hi: float, values: NDArray[np.float64]) -> bool:
    """Whether ``values`` leave ``[lo, hi]`` by more than :data:`BEYOND_RANGE` of its span (never for a zero span)."""
    return bool(len(values)) and beyond_bounds(lo, hi, float(np.min(values)), float(np.max(values)))


def beyond_bounds(lo: float, hi: float, vlo: float, vhi: float) -> bool:
    """:func:`beyond_range` of values whose least is ``vlo`` and greatest ``vhi``."""
    span = hi - lo
    return bool(span > 0 and max(vhi - hi, lo - vlo) > BEYOND_RANGE * span)


def signal_outside(values: NDArray[np.float64], low: Any, high: Any) -> NDArray[np.bool_]:
    """Whether each value lies outside ``low .. high`` (per column when they are arrays) widened by a relative
    1e-9 of the span: one signal's part of :func:`outside` (NaN: never outside, as the C code's comparisons)."""
    tol = 1e-9 * (high - low)
    out: NDArray[np.bool_] = (values < low - tol) | (values > high + tol)
    return out


def signal_excess(values: NDArray[np.float64], low: Any, high: Any) -> NDArray[np.float64]:
    """How far each value lies beyond ``low .. high`` (per column when they are arrays), in half-spans of the
    range (``max(|x_n| - 1, 0)``, ``x_n`` normalised; 0 for a zero span; NaN: inf, inf: the largest float): one signal's
    part of :func:`excess`."""
    span = high - low
    with np.errstate(over="ignore", invalid="ignore", divide="ignore"):
        ex = np.where(span > 0, np.abs(2.0 * (values - low) / np.where(span > 0, span, 1.0) - 1.0) - 1.0, 0.0)
    out: NDArray[np.float64] = np.maximum(np.nan_to_num(ex, nan=np.inf), 0.0)  # NaN: inf; inf: the largest float (nan_to_num)
    return out


def value_outside(x: float, low: float, high: float) -> bool:
    """:func:`signal_outside` of one value (the same float operations): a free run's step tests a sample with it
    (:mod:`~streamid.model.stepping`), where numpy's per-call cost would outweigh the arithmetic."""
    tol = 1e-9 * (high - low)
    return x < low - tol or x > high + tol


def value_excess(x: float, low: float, high: float) -> float:
    """:func:`signal_excess` of one value (the same float operations; NaN: inf, inf: the largest float, as
    ``numpy.nan_to_num`` maps them there)."""
    span = high - low
    if not span > 0:
        return 0.0
    ex = abs(2.0 * (x - low) / span - 1.0) - 1.0
    if math.isnan(ex):
        return math.inf
    return sys.float_info.max if ex == math.inf else max(ex, 0.0)


def outside(normalisation: Normalisation, regressors: Sequence[Regressor], u: NDArray[np.float64],
            y: NDArray[np.float64] | None = None) -> NDArray[np.bool_]:
    """For each sample ``t`` of ``u`` (N, n_inputs) (and measured outputs ``y``, when given), whether a regressor of
    the model at ``t`` lies outside the estimation domain: an input (or the output) ``lag`` samples earlier beyond
    the range the estimation data spanned (the normalisation's ``low .. high``, to a relative 1e-9). The first
    samples, which a regressor reaches before the record's start, count by the samples they can see."""
    n = u.shape[0]
    out_u = signal_outside(u, np.asarray(normalisation.u_low), np.asarray(normalisation.u_high))
    out_y = None if y is None else signal_outside(y, normalisation.y_low, normalisation.y_high)
    flags = np.zeros(n, dtype=bool)
    for r in regressors:
        src = out_u[:, r.index] if r.signal == "u" else out_y
        if src is None:
            continue
        flags[r.lag:] |= src[: n - r.lag] if r.lag else src
    return flags


def excess(normalisation: Normalisation, regressors: Sequence[Regressor], u: NDArray[np.float64],
           y: NDArray[np.float64]) -> NDArray[np.float64]:
    """For each sample ``t`` of ``u`` (N, n_inputs) and an output path ``y`` (N,): how far the model's farthest
    regressor at ``t`` lies beyond its estimation range, in the normalised units where that range is [-1, 1]
    (``max_j max(|x_j| - 1, 0)``; 0 inside the domain; 0.1: a tenth of the range's half-span beyond its edge). The
    prediction band grows with it (:mod:`streamid.model.uncertainty`). A regressor that reaches before the record's
    start is not counted, as in :func:`outside`."""
    n = u.shape[0]
    lo, hi = np.asarray(normalisation.u_low, dtype=np.float64), np.asarray(normalisation.u_high, dtype=np.float64)
    ex_u = signal_excess(u, lo, hi)
    ex_y = signal_excess(y, np.float64(normalisation.y_low), np.float64(normalisation.y_high))
    d = np.zeros(n)
    for r in regressors:
        src = ex_u[:, r.index] if r.signal == "u" else ex_y
        if r.lag:
            np.maximum(d[r.lag:], src[: n - r.lag], out=d[r.lag:])
        else:
            np.maximum(d, src, out=d)
    return d


def far_from_domain(model: Any, u: Any, path: NDArray[np.float64]) -> NDArray[np.float64]:
    """How far beyond the estimation domain each sample of a free run of ``model`` (a Model, read, not imported)
    lies, in output units: the farthest regressor's :func:`excess` (any member's; the output's regressors read
    ``path``, the run's own outputs) times the output's half-range. The band grows by it
    (:mod:`streamid.model.uncertainty`)."""
    ua = np.asarray(u, dtype=np.float64)
    ua = ua.reshape(ua.shape[0], -1)
    ex = excess(model.normalisation, domain_regressors(model), ua,
                np.asarray(path, dtype=np.float64))
    far: NDArray[np.float64] = ex * model.normalisation.y_half_range
    return far


def domain_regressors(model: Any) -> list[Regressor]:
    """Every regressor of a model (any member's, for an ensemble; the linear part's too), in one fixed order: what
    :func:`outside_share` and :func:`far_from_domain` read."""
    regs = {r for m in getattr(model, "members", (model,)) for r in (*m.regressors, *(m.linear_regressors or ()))}
    return sorted(regs, key=lambda r: (r.signal, r.index, r.lag))


def outside_share(model: Any, u: NDArray[np.float64], y: NDArray[np.float64] | None = None) -> float:
    """The share of the samples of a record (from ``model.max_lag`` on) at which one of the model's regressors (any
    member's, for an ensemble) lies outside its estimation domain (:func:`outside`); ``model`` a Model (read, not
    imported)."""
    flags = outside(model.normalisation, domain_regressors(model), u, y)
    scored = flags[model.max_lag:]
    return float(np.mean(scored)) if scored.shape[0] else 0.0


def domain_text(share: float, record: str) -> str:
    """One line on the share of a record's samples outside the model's estimation domain (:func:`outside_share`)."""
    if share <= 0.0:
        return f"estimation domain: every {record} sample within it (each regressor inside its estimation range)"
    return (f"estimation domain: {100 * share:.1f} % of the {record} samples put a regressor outside its estimation "
            "range: the model extrapolates there (a network of Gaussian bumps does not)")
