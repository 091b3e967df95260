"""The lags a run trains on: the data's memory, and an input term always.

The maximum candidate lag from the data (``CoEAConfig.max_lag_cap > 0``, the default)
------------------------------------------------------------------------------------
On the estimation data, ``L = clip(max(3 k_u, k_y), floor, max_lag_cap)`` with
``floor = max(max_lag_y, max_lag_u)`` (10 by default), ``k_u`` the lag (0..2 cap) of
the largest absolute cross-correlation between any input and the output (a dead
time or a resonance: the model needs the input about three times that far back, a
resonance rings on), and ``k_y`` the first lag at which the output's autocorrelation
falls below 0.5 (a slow output needs its own past that far back; one that never
falls within the cap takes the cap). Candidate lags are then ``1..L`` for the output
and every input. The evidence (``k_u``, ``k_y``, ``L``) is in the model's metrics
(``max_lag_choice``) and the identify report. The cost grows only where the data
call for it, and a long lag space (at least twice the floor) is hedged by restarts on ``1..floor``, the first of
every four of them with ``lag_search_neurons`` neurons (the paper's 10 by default): the final choice decides.

The input-term rule (every run with ``require_input``; the two-stage runs' second stage always)
----------------------------------------------------------------------------------------------
With ``require_input`` a lag set without an input term is infeasible in the search
(:class:`~streamid.engine.search.coevolution.Coevolution`). Without it, the rule below
still applies to what a second stage trains on.

The input-term rule (every two-stage run, :func:`~streamid.engine.identification.identify`)
------------------------------------------------------------------------------------
The first stage's best harmony is chosen by one-step-ahead error, and on an
oscillating output an autoregression of ``y`` alone predicts one step ahead very
well: the lag search then returns a mask with no input lag. Such a model ignores
the input in free run and the final choice never admits it
(:mod:`streamid.engine.choice.scores`), so a run trained on it offers nothing. The mask a
second stage trains on therefore always has an input term: the stage's best harmony
if it has one; else the fittest harmony of the final lag memory that has one;
else the best harmony plus, for each input, the candidate lag whose input is most
correlated (absolute value) with the output on the normalised search data.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from streamid.model.regressors import Regressor

__all__ = ["has_input_term", "memory_lag", "with_input_term"]


def _corr(a: NDArray[np.float64], b: NDArray[np.float64], kmax: int) -> NDArray[np.float64]:
    """Normalised correlation of ``a(t - k)`` with ``b(t)`` for k = 0..kmax (0 where a signal is constant)."""
    a = a - a.mean()
    b = b - b.mean()
    den = float(np.sqrt((a @ a) * (b @ b)))
    n = len(a)
    if den <= 0:
        return np.zeros(kmax + 1)
    return np.array([float(a[: n - k] @ b[k:]) / den for k in range(kmax + 1)])


def memory_lag(u: NDArray[np.float64], y: NDArray[np.float64], floor: int, cap: int) -> tuple[int, dict[str, int]]:
    """The maximum candidate lag from the data (module docstring) and its evidence.

    ``u`` of shape (N, n_inputs). ``floor <= cap``; records too short for the
    correlations (fewer than ``4 cap`` samples) are judged over ``N // 4`` lags.
    """
    kmax = max(1, min(2 * cap, len(y) // 4))
    k_u = 0
    best = -1.0
    for i in range(u.shape[1]):
        c = np.abs(_corr(u[:, i], y, kmax))
        if float(c.max()) > best:
            best, k_u = float(c.max()), int(np.argmax(c))
    acf = _corr(y, y, min(cap, kmax))
    below = np.flatnonzero(acf < 0.5)
    k_y = int(below[0]) if below.size else cap
    lag = int(min(max(3 * k_u, k_y, floor), cap))
    return lag, {"k_u": k_u, "k_y": k_y, "max_lag": lag, "floor": floor, "cap": cap}


def has_input_term(mask: NDArray[np.bool_], candidates: tuple[Regressor, ...]) -> bool:
    """True when ``mask`` selects at least one input lag."""
    return any(candidates[j].signal == "u" for j in np.flatnonzero(mask))


def with_input_term(
    best: NDArray[np.bool_],
    memory: NDArray[np.bool_],
    memory_fitness: NDArray[np.float64],
    candidates: tuple[Regressor, ...],
    R: NDArray[np.float64],
    target: NDArray[np.float64],
) -> tuple[NDArray[np.bool_], str]:
    """The mask a second stage trains on (see the module docstring) and how it was obtained.

    Parameters
    ----------
    best : ndarray of bool, shape (D,)
        The first stage's best harmony.
    memory, memory_fitness : ndarray, shapes (P, D) and (P,)
        The first stage's final lag memory and its fitness.
    candidates : tuple of Regressor
        Candidate lags in bit order.
    R, target : ndarray
        Normalised regressor matrix of all candidates (rows x D) and the output rows.

    Returns
    -------
    (mask, how) with ``how`` one of ``"best"``, ``"memory"``, ``"correlation"``.
    """
    if has_input_term(best, candidates):
        return best, "best"
    for i in np.argsort(memory_fitness, kind="stable"):
        if has_input_term(memory[i], candidates):
            return memory[i].copy(), "memory"
    mask = best.copy()
    t = target - target.mean()
    inputs = sorted({c.index for c in candidates if c.signal == "u"})
    for i in inputs:
        cols = [j for j, c in enumerate(candidates) if c.signal == "u" and c.index == i]
        x = R[:, cols] - R[:, cols].mean(axis=0)
        den = np.sqrt((x * x).sum(axis=0) * float(t @ t))
        corr = np.abs(x.T @ t) / np.where(den > 0, den, np.inf)
        mask[cols[int(np.argmax(corr))]] = True
    return mask, "correlation"
