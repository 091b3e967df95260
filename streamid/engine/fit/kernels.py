"""The search's compiled loops (numba) where numpy is slow (no AVX-512): the population's activations' ``exp2``
and the batched Gram of :class:`~streamid.engine.search.batch.BatchEvaluator`, used where ``rbf.NUMPY_PATH`` is
false. Compiled once per install (``cache=True``; see :mod:`streamid.model.kernels` for the cost).
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit
from numpy.typing import NDArray

__all__ = ["exp2_rows", "gram_rows"]


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
