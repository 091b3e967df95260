"""The refinement's compiled loop (numba): one network's free run and its derivatives by the output weights
(and a linear part's coefficients) along it, for the output-error refinement (:mod:`streamid.engine.choice.refine`,
which prepares its arguments). Compiled once per install (``cache=True``; see :mod:`streamid.model.kernels`).
"""

from __future__ import annotations

import numpy as np
from numba import njit
from numpy.typing import NDArray

__all__ = ["free_run_sensitivities"]


F64 = NDArray[np.float64]


@njit(cache=True, nogil=True)
def free_run_sensitivities(du: F64, cy: F64, a: F64, lags: NDArray[np.int64], w: F64, lin_y: F64, lin_u: F64, y0: F64,
                           L: int, xu: F64, ny: int, s0: F64) -> tuple[F64, F64]:
    """The network's free run (n,) with weights ``w`` (M,) from ``y0`` (L,), and its derivatives along it.

    ``du`` (n, M): the input regressors' scaled squared distances; ``cy`` (ky, M): the centres' output
    coordinates (coordinate-major); ``a`` (M,): ``1 / (2 sigma^2)``.

    The derivatives ``S`` (n, M + ny + q) are by the weights ``w``, then (``ny`` = ky) by the linear
    part's output coefficients ``lin_y``, then by the coefficients of the columns ``xu`` (n, q) of which
    ``lin_u`` is made (a linear part's input regressors and its constant; q = 0 and ny = 0 to
    differentiate by the weights only). Each column follows ``s(t) = x(t) + sum_k g_k(t) s(t - lag_k)``,
    given before ``L`` (``s0``), where ``x(t)`` is the parameter's own term at step ``t``
    (``phi_m(t)``, ``yhat(t - lag_k)`` or ``xu(t, j)``) and ``g_k(t) = lin_y_k - sum_m 2 a_m w_m phi_m(t)
    (yhat(t - lag_k) - cy_mk)`` the derivative of step ``t``'s output by its fed-back outputs.

    ``s0`` (L, P): the derivatives of the ``L`` given outputs (zeros: measured ones). A free run simulated in
    pieces continues from the last ``L`` outputs (``y0``) and derivatives (``s0``) of the piece before, and
    gives the same rows as in one piece.
    """
    n, M = du.shape
    ky = lags.shape[0]
    q = xu.shape[1]
    P = M + ny + q
    Y = np.empty(n)
    S = np.zeros((n, P))
    x = np.empty(P)
    g = np.empty(ky)
    sy = np.empty(M)
    f = np.empty(M)
    v = np.empty(P)
    for t in range(L):
        Y[t] = y0[t]
        for m in range(P):
            S[t, m] = s0[t, m]
    for t in range(L, n):
        acc = lin_u[t]
        for k in range(ky):
            g[k] = lin_y[k]
            acc += lin_y[k] * Y[t - lags[k]]
        # the loops over the neurons (and over the parameters, below) are vectorised; each sum keeps its order
        for m in range(M):
            sy[m] = 0.0
        for k in range(ky):
            yk = Y[t - lags[k]]
            for m in range(M):
                d = yk - cy[k, m]
                sy[m] += d * d
        for m in range(M):
            x[m] = np.exp(-(du[t, m] + a[m] * sy[m]))
        for m in range(M):
            acc += w[m] * x[m]
            f[m] = 2.0 * a[m] * w[m] * x[m]
        for k in range(ky):
            yk = Y[t - lags[k]]
            gk = g[k]
            for m in range(M):
                gk -= f[m] * (yk - cy[k, m])
            g[k] = gk
        Y[t] = acc
        for k in range(ny):
            x[M + k] = Y[t - lags[k]]
        for j in range(q):
            x[M + ny + j] = xu[t, j]
        for m in range(P):
            v[m] = x[m]
        for k in range(ky):  # rows before L: s0
            gk = g[k]
            row = t - lags[k]
            for m in range(P):
                v[m] += gk * S[row, m]
        for m in range(P):
            S[t, m] = v[m]
    return Y, S
