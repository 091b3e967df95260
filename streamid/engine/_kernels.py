"""The engine's compiled loops (numba): the free run's recursion and its sensitivities, and where numpy is slow
(no AVX-512) the search's ``exp2`` and Gram.

A free run is sequential: step ``t`` needs the outputs of steps ``t - lag``. With numpy every step
pays a dozen calls' overhead (about 3 us) whatever the network's size; these loops do the same
arithmetic compiled. Measured on the 10,000-sample Bouc-Wen record (docs/engine-results.md,
round 8): one 30-neuron network's free run 27 ms with the numpy step loop, about 2.5 ms here.
Compiled once per install (``cache=True``): on a fresh install the first identification compiles the four
kernels below, 1.2-1.6 s each on a 2-core AMD EPYC VM (about 5 s once: README journey 1 took 10.0 s wall the
first time, then 5.6-6.1 s); later processes load them from ``__pycache__`` in about 0.2 s.

* :func:`recursion`: the free runs of :func:`streamid.engine.freerun.free_run` (C networks sharing
  their regressors), each neuron's input and output distances computed at the step.
* :func:`free_run_sensitivities`: one network's free run and its derivatives by the output weights (and a
  linear part's coefficients) along it, for the output-error refinement (:mod:`streamid.engine.refine`,
  which prepares its arguments).
* :func:`one_row`: one network's one-step-ahead prediction at one instant, for :class:`~streamid.engine.predictor.
  Predictor`, a control loop's sample by sample (numpy spent about 20 us of call overhead on its dozen small
  arrays; compiled on a predictor's first use, not by :func:`warm_up_kernels`: the daemon never calls it).
* :func:`exp2_rows` and :func:`gram_rows`: the population's activations' ``exp2`` and the batched Gram of
  :class:`~streamid.engine.batch.BatchEvaluator`, used where ``rbf.NUMPY_PATH`` is false.

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

__all__ = ["exp2_rows", "free_run_sensitivities", "gram_rows", "one_row", "recursion", "warm_up_kernels"]


F64 = NDArray[np.float64]

# exp2 on [-1/2, 1/2]: the Taylor series of exp(f ln 2) to degree 13 (truncation below 2e-19 relative there)
# (coefficients highest degree first, for Horner's rule)
_C = tuple(math.log(2.0) ** k / math.factorial(k) for k in range(13, -1, -1))
_SHIFT = 6755399441055744.0  # 1.5 * 2**52: x + _SHIFT holds round(x) in its low mantissa bits
_CHUNK = 1024


@njit(cache=True, nogil=True, error_model="numpy", fastmath={"contract", "nnan", "ninf", "nsz"})
def _exp2_poly(r: F64, k: F64) -> None:
    """``r = 2^frac(r)`` (the polynomial), ``k = round(r)`` held in the low mantissa bits of ``r + _SHIFT``, for
    ``r`` clamped to [-1022, 1023] (the inputs are kept by :func:`exp2_rows`: this loop assumes no nan or inf)."""
    for j in range(r.shape[0]):
        x = min(max(r[j], -1022.0), 1023.0)
        y = x + _SHIFT
        f = x - (y - _SHIFT)
        p = 0.0
        for c in _C:
            p = p * f + c
        r[j] = p
        k[j] = y


@njit(cache=True, nogil=True, error_model="numpy")
def _exp2_chunk(r: F64, k: F64, x0: F64) -> None:
    """``r = 2^r`` (at most ``k.size`` elements): the polynomial of the fraction, then the power of two built in
    ``k``'s bits. Below -1022: 0; above 1023: inf; nan stays nan."""
    m = r.shape[0]
    for j in range(m):
        x0[j] = r[j]
    _exp2_poly(r, k[:m])
    kb = k.view(np.uint64)
    for j in range(m):  # low bits of y: 2^51 + round(x); shifted by 52, the 2^51 leaves the word
        kb[j] = (kb[j] + np.uint64(1023)) << np.uint64(52)
    for j in range(m):
        x = x0[j]
        v = r[j] * k[j] if x >= -1022.0 else 0.0  # (numpy: subnormals down to -1074, then 0)
        v = v if x <= 1023.0 else math.inf
        r[j] = v if x == x else x  # nan stays nan


@njit(cache=True, nogil=True)
def exp2_rows(x: NDArray[np.float64], r0: int, r1: int) -> None:
    """``x[:, r0:r1, :] = 2^x[:, r0:r1, :]`` in place, ``x`` a C-contiguous 3-D array (the batched activations
    are rows ``1..M`` of each member's block of the evaluator's buffer).

    numpy's ``exp2`` is vectorised only where the CPU has AVX-512 (about 1 ns an element there); elsewhere
    it costs 6-9 ns (AMD EPYC, AVX2), most of a population's evaluation. This one is a degree-13 polynomial
    and a power of two set in the exponent bits, within 1 ulp of numpy's (tests/test_engine_rbf.py), about
    1.8 ns on that machine; below -1022 it gives 0 where numpy gives subnormals (under 2.3e-308)."""
    k = np.empty(_CHUNK)
    x0 = np.empty(_CHUNK)
    P = x.shape[0]
    n = x.shape[2]
    for i in range(P):
        for m in range(r0, r1):
            row = x[i, m]
            for a in range(0, n, _CHUNK):
                _exp2_chunk(row[a : min(n, a + _CHUNK)], k, x0)


_GRAM_CHUNK = 256  # samples per pass: a 2 x 4 block's six rows of it stay in the L1 cache


@njit(cache=True, nogil=True, fastmath={"contract", "reassoc", "nsz", "arcp", "nnan", "ninf"})
def _gram_upper(E: F64, R: int, acc: F64) -> None:
    """``acc[i, j] = E[i] . E[j]`` for ``i <= j < R`` (and some ``i > j``, unused), rows of ``E`` contiguous.

    Blocks of 2 x 4 rows share each loaded sample (six loads for eight multiply-adds), over chunks of
    ``_GRAM_CHUNK`` samples; a block at the last row repeats it (``min``) and keeps only distinct pairs."""
    n = E.shape[1]
    for i in range(R):
        for j in range(R):
            acc[i, j] = 0.0
    for a in range(0, n, _GRAM_CHUNK):
        b = min(n, a + _GRAM_CHUNK)
        for i in range(0, R, 2):
            i1 = min(i + 1, R - 1)
            for j in range(i - i % 4, R, 4):
                j1, j2, j3 = min(j + 1, R - 1), min(j + 2, R - 1), min(j + 3, R - 1)
                s00 = s01 = s02 = s03 = s10 = s11 = s12 = s13 = 0.0
                for t in range(a, b):
                    x0, x1 = E[i, t], E[i1, t]
                    y0, y1, y2, y3 = E[j, t], E[j1, t], E[j2, t], E[j3, t]
                    s00 += x0 * y0
                    s01 += x0 * y1
                    s02 += x0 * y2
                    s03 += x0 * y3
                    s10 += x1 * y0
                    s11 += x1 * y1
                    s12 += x1 * y2
                    s13 += x1 * y3
                _add_distinct(acc, i, j, j1, j2, j3, s00, s01, s02, s03)
                if i1 > i:
                    _add_distinct(acc, i1, j, j1, j2, j3, s10, s11, s12, s13)


@njit(cache=True, nogil=True, inline="always")
def _add_distinct(acc: F64, i: int, j: int, j1: int, j2: int, j3: int, s0: float, s1: float, s2: float,
                  s3: float) -> None:
    """``acc[i, j..j3] += s0..s3`` for the columns that differ from the one before (a block at the last row
    repeats it)."""
    acc[i, j] += s0
    if j1 > j:
        acc[i, j1] += s1
    if j2 > j1:
        acc[i, j2] += s2
    if j3 > j2:
        acc[i, j3] += s3


@njit(cache=True, nogil=True)
def gram_rows(ext: F64, p: int, R: int, gb: F64) -> None:
    """``gb[q] = ext[q, :R] @ ext[q, 1:R].T`` for members ``q < p``: row 0 the products with the target (row 0
    of a block), rows ``1..R-1`` the design's Gram; ``ext`` C-contiguous (p', rows, n), ``gb`` (p, R, R - 1).

    What ``numpy.matmul`` gives (to rounding: 1e-15 relative), where its BLAS is slow on these short, wide
    blocks: on an AMD EPYC with AVX2 (OpenBLAS Haswell kernels) 20 GFLOP/s for 31 rows of 2,000 samples,
    here about twice as fast, half of it from computing each symmetric pair once (tests/test_engine_rbf.py)."""
    acc = np.empty((R, R))
    for q in range(p):
        _gram_upper(ext[q], R, acc)
        for i in range(R):
            for j in range(max(i, 1), R):
                gb[q, i, j - 1] = acc[i, j]
                if i >= 1:
                    gb[q, j, i - 1] = acc[i, j]


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


@njit(cache=True, nogil=True)
def one_row(un: F64, yn: F64, n: int, y_lags: NDArray[np.int64], u_lags: NDArray[np.int64], u_cols: NDArray[np.int64],
            centres: F64, two_w2: F64, weights: F64, lin: F64, lin_const: float, ly_lags: NDArray[np.int64],
            lu_lags: NDArray[np.int64], lu_cols: NDArray[np.int64], lin_own: bool) -> float:
    """One network's normalised output at instant ``n`` of the normalised samples ``un`` (rows, inputs) and
    ``yn`` (rows,): its regressors ``yn[n - y_lags]`` then ``un[n - u_lags, u_cols]`` (the centres' columns in
    that order), ``sum_m weights[m] exp(-|r - centres[m]|^2 / two_w2[m])``, plus the linear part ``lin . r' +
    lin_const`` when ``lin`` is not empty (``r'`` gathered by ``ly_lags``, ``lu_lags``, ``lu_cols`` if
    ``lin_own``, else ``r``). The arithmetic of :meth:`Model.predict_osa <streamid.engine.model.Model.predict_osa>`
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


def warm_up_kernels() -> None:
    """Compile the kernels now (the first time on a machine, about 1 s) or load them from the cache, so that
    no time-bound caller (the daemon's first decision) pays for it. Idempotent and cheap once done.

    The callers pass writable C-ordered float64 arrays, int64 lags and an int ``L``, as here: numba
    compiles one version per argument types, so these are the versions they use."""
    one = np.ones(1, dtype=np.int64)
    recursion(np.zeros((1, 3, 1)), one, one - 1, np.zeros((1, 1, 1)), np.zeros((1, 1, 1)), np.ones((1, 1)), one,
              np.zeros((1, 1)), one, np.zeros((1, 1)), np.zeros((3, 1)), np.zeros((3, 1)), 1)
    free_run_sensitivities(np.zeros((3, 1)), np.zeros((1, 1)), np.ones(1), np.ones(1, dtype=np.int64), np.zeros(1),
                           np.zeros(1), np.zeros(3), np.zeros(3), 1, np.zeros((3, 0)), 0, np.zeros((1, 1)))
    exp2_rows(np.zeros((1, 2, 3)), 1, 2)
    gram_rows(np.zeros((1, 3, 4)), 1, 3, np.empty((1, 3, 2)))
