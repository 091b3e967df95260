"""The candidate-lag regressor matrix the search works on: every candidate term of a lag space, as columns.

Conventions as in :mod:`streamid.model.regressors`: candidate regressors are ordered output lags first, then
each input's lags (``y(t-1) .. y(t-Ly), u_0(t-1) .. u_0(t-Lu), ...``), the bit order of a lag harmony and the
coordinate order of a centre; row ``k`` of the matrix is the regressor at time ``t = L + k``, ``L = max(Ly, Lu)``.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike, NDArray

from streamid.errors import DataError
from streamid.model.regressors import Regressor

__all__ = ["candidate_regressors", "lag_matrix", "lag_rows"]


def candidate_regressors(max_lag_y: int, max_lag_u: int, n_inputs: int, min_lag_u: int = 1) -> tuple[Regressor, ...]:
    """All candidate terms in harmony-bit order (see the module docstring); each input's lags
    ``min_lag_u..max_lag_u`` (``min_lag_u`` 0: the input's direct term ``u(t)`` is a candidate)."""
    regs = [Regressor("y", 0, k) for k in range(1, max_lag_y + 1)]
    for i in range(n_inputs):
        regs.extend(Regressor("u", i, k) for k in range(min_lag_u, max_lag_u + 1))
    return tuple(regs)


def lag_matrix(
    un: NDArray[np.float64],
    yn: NDArray[np.float64],
    max_lag_y: int,
    max_lag_u: int,
    *,
    start: int | None = None,
    min_lag_u: int = 1,
) -> NDArray[np.float64]:
    """Regressor matrix of all candidate lags (normalised data).

    Parameters
    ----------
    un : ndarray, shape (N, n_inputs)
    yn : ndarray, shape (N,)
    max_lag_y, max_lag_u : int
    start : int, optional
        First time index with a row (default ``max(max_lag_y, max_lag_u)``;
        must be at least that).
    min_lag_u : int
        Each input's first lag (1; 0: its direct term ``u(t)`` too).

    Returns
    -------
    ndarray, shape (N - start, max_lag_y + n_inputs * (max_lag_u - min_lag_u + 1))
        Row ``k`` holds the candidates at ``t = start + k`` in harmony-bit order.

    Raises
    ------
    DataError
        If there are no rows (too few samples for the lags).
    """
    n, n_in = un.shape
    L = max(max_lag_y, max_lag_u)
    s = L if start is None else int(start)
    if s < L:
        raise DataError(f"the first regressor row needs start >= max lag {L}; got start={s}")
    rows = n - s
    if rows < 1:
        raise DataError(f"{n} samples are too few for lags up to {L}: at least {L + 1} samples are needed")
    D = max_lag_y + n_in * (max_lag_u - min_lag_u + 1)
    R = np.empty((rows, D))
    col = 0
    for k in range(1, max_lag_y + 1):
        R[:, col] = yn[s - k : n - k]
        col += 1
    for i in range(n_in):
        for k in range(min_lag_u, max_lag_u + 1):
            R[:, col] = un[s - k : n - k, i]
            col += 1
    return R


def lag_rows(un: NDArray[np.float64], yn: NDArray[np.float64], max_lag_y: int, max_lag_u: int, rows: ArrayLike, *,
             min_lag_u: int = 1) -> NDArray[np.float64]:
    """The rows ``rows`` (row ``k``: time ``max(max_lag_y, max_lag_u) + k``) of :func:`lag_matrix`, the same values,
    without making the others: a sample of rows, or a block of them, of a long record."""
    t = max(max_lag_y, max_lag_u) + np.asarray(rows, dtype=np.intp)
    n_in = un.shape[1]
    R = np.empty((t.shape[0], max_lag_y + n_in * (max_lag_u - min_lag_u + 1)))
    col = 0
    for k in range(1, max_lag_y + 1):
        R[:, col] = yn[t - k]
        col += 1
    for i in range(n_in):
        for k in range(min_lag_u, max_lag_u + 1):
            R[:, col] = un[t - k, i]
            col += 1
    return R
