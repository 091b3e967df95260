"""The model's compiled loops (numba): the free run's recursion and one network's one-step prediction.

A free run is sequential: step ``t`` needs the outputs of steps ``t - lag``. With numpy every step
pays a dozen calls' overhead (about 3 us) whatever the network's size; these loops do the same
arithmetic compiled. Measured on the 10,000-sample Bouc-Wen record (docs/engine-results.md,
round 8): one 30-neuron network's free run 27 ms with the numpy step loop, about 2.5 ms here.
Compiled once per install (``cache=True``): on a fresh install the first identification compiles the
kernels (these, the refinement's :mod:`streamid.engine.choice.sensitivities` and the search's
:mod:`streamid.engine.fit.kernels`), 1.2-1.6 s each on a 2-core AMD EPYC VM (about 5 s once: README journey 1
took 10.0 s wall the first time, then 5.6-6.1 s); later processes load them from ``__pycache__`` in about 0.2 s.

* :func:`recursion`: the free runs of :func:`streamid.model.freerun.free_run` (C networks sharing
  their regressors), each neuron's input and output distances computed at the step.
* :func:`scaled_distances`: a block of one-step-ahead rows' exponents for :meth:`Model.predict_osa
  <streamid.model.narx.Model.predict_osa>`, the numpy loop's operations in its order (the same bits), written once.
* :func:`one_row`: one network's one-step-ahead prediction at one instant, for :class:`~streamid.model.predictor.
  Predictor`, a control loop's sample by sample (numpy spent about 20 us of call overhead on its dozen small
  arrays; compiled on a predictor's first use, not by :func:`~streamid.engine.warmup.warm_up_kernels`: the daemon
  never calls it).

The arithmetic is the free run's: ``yhat(t) = lin_u(t) + sum_k lin_y_k yhat(t - lag_k) +
sum_m w_m exp(-(du(t, m) + a_m sum_k (yhat(t - lag_k) - cy_mk)^2))``, ``du`` the input regressors'
scaled squared distances, ``cy`` the centres' output coordinates, ``a = 1 / (2 sigma^2)``, and
``lin_y``, ``lin_u`` a linear part's output coefficients and input terms plus constant (zeros
without one). The order of the sums differs from the numpy loop it replaced (BLAS products), so
results agree with it to rounding (1e-13 relative here), not to the bit.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit
from numpy.typing import NDArray

__all__ = ["one_row", "recursion", "scaled_distances"]


F64 = NDArray[np.float64]


@njit(cache=True, nogil=True)
def recursion(un: F64, ulags: NDArray[np.int64], uidx: NDArray[np.int64], cu: F64, cy: F64, a: F64,
              lags: NDArray[np.int64], W: F64, llags: NDArray[np.int64], lin_y: F64, lin_u: F64, y: F64, L: int) -> None:
    """Free runs of C networks sharing their regressors, in place: ``y`` (n, C) from row ``L`` on.

    ``un`` (1 or C, n', inputs): the normalised inputs, shared or one sequence per network (n' >= n);
    ``ulags``, ``uidx`` (ku,): the input regressors' lags and input indices, ``cu`` (C, ku, M) the
    centres' input coordinates; ``cy`` (C, ky, M): the centres' output coordinates (coordinate-major, so
    that the loops over the neurons are vectorised); ``a`` (C, M):
    ``1 / (2 sigma^2)``; ``lags`` (ky,) the network's output lags; ``W`` (C, M); ``llags`` (ly,) the
    linear part's output lags (the network's, or its own: a long linear part); ``lin_y`` (C, ly) and
    ``lin_u`` (n, C): a linear part's output coefficients and its input terms plus constant (zeros
    without one); rows ``< L`` of ``y`` hold the initial outputs. A neuron's exponent is
    ``-(a du) - a dy``, ``du`` and ``dy`` the input and output coordinates' squared distances summed
    in regressor order (numpy's whole-record arithmetic before this loop computed ``du`` so: the same
    bits, without its (n, C, M) arrays).
    """
    n, C = y.shape
    M = W.shape[1]
    ku = ulags.shape[0]
    ky = lags.shape[0]
    ly = llags.shape[0]
    shared = un.shape[0] == 1
    su = np.empty(M)
    sy = np.empty(M)
    for t in range(L, n):
        for c in range(C):
            uc = 0 if shared else c
            # each neuron's squared distances, coordinate by coordinate (loops over the neurons: vectorised)
            for m in range(M):
                su[m] = 0.0
                sy[m] = 0.0
            for k in range(ku):
                v = un[uc, t - ulags[k], uidx[k]]
                for m in range(M):
                    d = v - cu[c, k, m]
                    su[m] += d * d
            for k in range(ky):
                v = y[t - lags[k], c]
                for m in range(M):
                    d = v - cy[c, k, m]
                    sy[m] += d * d
            acc = lin_u[t, c]
            for k in range(ly):
                acc += lin_y[c, k] * y[t - llags[k], c]
            for m in range(M):
                acc += W[c, m] * np.exp(-(su[m] * a[c, m]) - a[c, m] * sy[m])
            y[t, c] = acc


@njit(cache=True, nogil=True)
def scaled_distances(r: F64, centres: F64, neg_two_w2: F64, out: F64) -> None:
    """``out[i, m] = (sum_j (r[i, j] - centres[m, j])^2) / neg_two_w2[m]`` for the rows ``r`` (n, k), in place.

    Each sum starts at 0 and adds the coordinates in order, every product and sum rounded as the numpy loop it
    replaced rounds them (``np.subtract``, ``np.square``, ``+=`` over (n, M) arrays, then ``np.divide``): the same
    bits, without its 3 k passes over an (n, M) array (the block's rows are 64 MB of temporaries at most:
    memory bound). No fused multiply-add: numba leaves ``d * d + s`` as two roundings without fastmath.
    """
    n, k = r.shape
    M = centres.shape[0]
    for i in range(n):
        for m in range(M):
            s = 0.0
            for j in range(k):
                d = r[i, j] - centres[m, j]
                s += d * d
            out[i, m] = s / neg_two_w2[m]


@njit(cache=True, nogil=True)
def one_row(un: F64, yn: F64, n: int, y_lags: NDArray[np.int64], u_lags: NDArray[np.int64], u_cols: NDArray[np.int64],
            centres: F64, two_w2: F64, weights: F64, lin: F64, lin_const: float, ly_lags: NDArray[np.int64],
            lu_lags: NDArray[np.int64], lu_cols: NDArray[np.int64], lin_own: bool) -> float:
    """One network's normalised output at instant ``n`` of the normalised samples ``un`` (rows, inputs) and
    ``yn`` (rows,): its regressors ``yn[n - y_lags]`` then ``un[n - u_lags, u_cols]`` (the centres' columns in
    that order), ``sum_m weights[m] exp(-|r - centres[m]|^2 / two_w2[m])``, plus the linear part ``lin . r' +
    lin_const`` when ``lin`` is not empty (``r'`` gathered by ``ly_lags``, ``lu_lags``, ``lu_cols`` if
    ``lin_own``, else ``r``). The arithmetic of :meth:`Model.predict_osa <streamid.model.narx.Model.predict_osa>`
    for one row, its sums in another order (equal to rounding)."""
    ky, ku = y_lags.shape[0], u_lags.shape[0]
    r = np.empty(ky + ku)
    for j in range(ky):
        r[j] = yn[n - y_lags[j]]
    for j in range(ku):
        r[ky + j] = un[n - u_lags[j], u_cols[j]]
    out = 0.0
    for m in range(centres.shape[0]):
        d2 = 0.0
        for j in range(ky + ku):
            d = r[j] - centres[m, j]
            d2 += d * d
        out += weights[m] * math.exp(-d2 / two_w2[m])
    if lin.shape[0]:
        acc = lin_const
        if lin_own:
            qy = ly_lags.shape[0]
            for j in range(qy):
                acc += lin[j] * yn[n - ly_lags[j]]
            for j in range(lu_lags.shape[0]):
                acc += lin[qy + j] * un[n - lu_lags[j], lu_cols[j]]
        else:
            for j in range(ky + ku):
                acc += lin[j] * r[j]
        out += acc
    return out


