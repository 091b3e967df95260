r"""Gaussian RBF network: activations, outputs and least-squares weights of one network (and of several at once).

The population's fitness, the search's inner loop, is :class:`~streamid.engine.search.batch.BatchEvaluator`.

The network (paper eqs. 2-3), on the selected regressors ``r(t)`` (normalised)::

    yhat(t) = sum_m w_m exp(-||r(t) - c_m||^2 / (2 sigma_m^2))

Batched population evaluation
-----------------------------
A coevolution generation evaluates P pairs (lag mask ``h_p``, centres
``C_p`` (M x D), widths ``sigma_p``) on the same candidate regressor matrix
``R`` (n x D). Only the masked coordinates count, so with ``a2 = log2(e) / sigma^2``
the exponent of ``exp2`` is::

    -a2/2 ||h o (r - c)||^2 = sum_j [a2 c_j] h_j r_j + [a2] (-||h o r||^2 / 2) + [a2 ||h o c||^2] (-1/2)

which is one matrix product of the stacked coefficient rows
``a2 [c_sel; 1; ||c_sel||^2]`` (P*M x K) with the feature rows
``[r_sel; -||h o r||^2 / 2; -1/2]`` (K x n), K = (selected lags) + 2: per member
packed to the left when the masks differ (first half of a run), shared and
cached when every member uses the same mask (second half, K = |h| + 2). One
in-place ``exp2`` (log2(e) is folded into ``a2``; ~15 % faster than ``exp``)
gives every activation of the population at once. The -1/2 sits in the
features so that the coefficients are one product of ``[c; 1; ||c||^2]`` with
``a2`` (the same floating-point values as scaling each column separately).

The final model's weights are refitted by :func:`fit_weights` (QR least squares
of the same scaled, ridge-augmented problem, never the normal equations), which is
accurate however ill-conditioned the design is: the ridge rows bound the condition.
"""

from __future__ import annotations

import importlib
from collections.abc import Callable

import numpy as np
from numpy.typing import NDArray
from scipy.linalg import lapack as _lapack
from scipy.linalg import solve_triangular as _solve_triangular

from streamid.engine.fit.kernels import exp2_rows, gram_rows

__all__ = ["LOG2E", "MIN_NORM", "NUMPY_PATH", "BLOCK_ROWS", "FIT_BLOCK_ROWS", "TINY", "activations", "activations_batch", "exp2_block", "fit_linear_rbf",
           "fit_in_blocks", "fit_weights", "gram_block", "rbf_output", "streamed_fit"]

#: added to a squared norm before its square root is divided by
TINY = 1e-300

#: Neurons whose activations on the data have a Euclidean norm below this are
#: treated as inactive (weight 0). Such a neuron sits where no sample is; only an
#: enormous weight would let it matter, and that weight explodes as soon as a
#: prediction wanders near its centre (seen on real data: weights of 1e6..1e93 on
#: neurons of norm 1e-7..1e-95 that wrecked OSA predictions on new data).
MIN_NORM = 1e-5

#: Rows per block of :func:`activations` (its ``(rows, M, k)`` temporary: 16 MiB at M = 10, k = 20).
BLOCK_ROWS = 8192
#: Longer designs are fitted by a QR streamed over blocks of this many rows (:func:`fit_weights`); shorter ones in
#: one QR, as always (the same solution to rounding). Every window of the bundled logs under the daemon's defaults,
#: and the engine suite's records, are below it.
FIT_BLOCK_ROWS = 16384


def activations(r: NDArray[np.float64], centres: NDArray[np.float64], widths: NDArray[np.float64]) -> NDArray[np.float64]:
    """Gaussian activations, evaluated directly from eq. (3).

    Parameters
    ----------
    r : ndarray, shape (n, k)
        Selected regressors (normalised).
    centres : ndarray, shape (M, k)
    widths : ndarray, shape (M,)

    Returns
    -------
    ndarray, shape (n, M)
        ``exp(-||r_t - c_m||^2 / (2 sigma_m^2))``.
    """
    n, M = r.shape[0], centres.shape[0]
    g: NDArray[np.float64] = np.empty((n, M))
    den = 2.0 * widths[None, :] ** 2
    for a in range(0, n, BLOCK_ROWS):  # the (rows, M, k) temporary stays bounded; each element as in one pass
        b = min(n, a + BLOCK_ROWS)
        d2 = ((r[a:b, None, :] - centres[None, :, :]) ** 2).sum(axis=2)
        np.exp(-d2 / den, out=g[a:b])
    return g


def activations_batch(
    r: NDArray[np.float64], centres: NDArray[np.float64], widths: NDArray[np.float64]
) -> NDArray[np.float64]:
    """Gaussian activations of several networks on the same regressors, as the search computes them.

    One product of coefficient rows ``a2 [c; 1; ||c||^2]`` (``a2 = log2(e) / sigma^2``) with the
    feature rows ``[r; -||r||^2 / 2; -1/2]``, then one ``exp2`` (see :class:`~streamid.engine.search.batch.BatchEvaluator`):
    no ``(n, M, k)`` temporary, about 5x faster than :func:`activations` on large records.

    Parameters
    ----------
    r : ndarray, shape (n, k)
    centres : ndarray, shape (C, M, k)
    widths : ndarray, shape (C, M)

    Returns
    -------
    ndarray, shape (C, M, n)
        Network ``c``'s activations, neuron by neuron (``out[c].T`` is its ``(n, M)`` design).
    """
    C, M, k = centres.shape
    n = r.shape[0]
    feat = np.empty((k + 2, n))
    feat[:k] = r.T
    np.einsum("tj,tj->t", r, r, out=feat[k])
    feat[k] *= -0.5
    feat[k + 1] = -0.5
    coef = np.empty((C, M, k + 2))
    coef[:, :, :k] = centres
    coef[:, :, k] = 1.0
    np.einsum("cmj,cmj->cm", centres, centres, out=coef[:, :, k + 1])
    coef *= (LOG2E / (widths * widths))[:, :, None]
    phi = (coef.reshape(C * M, k + 2) @ feat).reshape(C, M, n)
    exp2_block(phi, 0, M)
    return phi


def rbf_output(
    r: NDArray[np.float64], centres: NDArray[np.float64], widths: NDArray[np.float64], weights: NDArray[np.float64]
) -> NDArray[np.float64]:
    """Network output ``sum_m w_m phi_m(r)`` (eq. 2) for the rows of ``r`` (n, k)."""
    return activations(r, centres, widths) @ weights


def fit_weights(
    phi: NDArray[np.float64], y: NDArray[np.float64], ridge: float
) -> NDArray[np.float64]:
    """Output weights minimising ``||y - phi w||^2 + ridge ||S^-1 w||^2`` accurately (QR; SVD without a ridge).

    ``S`` is the Jacobi scaling of :class:`BatchEvaluator` (unit-norm columns),
    so the result is the same regularised solution the search evaluates, computed
    without forming the normal equations. With ``ridge = 0`` this is
    ``numpy.linalg.lstsq(phi, y)`` (minimum-norm solution).

    Parameters
    ----------
    phi : ndarray, shape (n, M)
    y : ndarray, shape (n,)
    ridge : float

    Returns
    -------
    ndarray, shape (M,)
    """
    if phi.shape[0] > FIT_BLOCK_ROWS:  # a long record: the same solution, the QR streamed over blocks of rows
        return streamed_fit(lambda a, b: phi[a:b], phi.shape[0], phi.shape[1], y, ridge)
    n2 = (phi * phi).sum(axis=0)
    s = np.where(n2 > MIN_NORM**2, 1.0 / np.sqrt(n2 + TINY), 0.0)  # as the search's BatchEvaluator: inactive -> w = 0
    a = phi * s
    lam = np.full(phi.shape[1], float(ridge))
    if np.any(lam > 0):
        a = np.vstack([a, np.diag(np.sqrt(lam))])
        rhs = np.concatenate([y, np.zeros(phi.shape[1])])
    else:
        rhs = y
    z = _qr_solve(a, rhs) if np.all(lam > 0) else np.asarray(np.linalg.lstsq(a, rhs, rcond=None)[0])
    w: NDArray[np.float64] = z * s
    return w


def streamed_fit(
    rows: Callable[[int, int], NDArray[np.float64]], n: int, m: int, y: NDArray[np.float64], ridge: float,
) -> NDArray[np.float64]:
    """:func:`fit_weights` of the ``(n, m)`` design whose rows ``a:b`` are ``rows(a, b)``, in blocks of
    :data:`FIT_BLOCK_ROWS` rows: memory ``O(FIT_BLOCK_ROWS m)`` beyond the design, whatever ``n``.

    Two passes. The first sums the columns' squared norms (the Jacobi scaling). The second is a sequential
    tall-skinny QR: the triangle ``T`` and ``Q^T y`` so far are stacked on the next scaled block and
    factored again (LAPACK ``dgeqrf``/``dormqr``); the ridge rows come last as one more block. ``T z = Q^T y``
    then has the solution of the whole stacked problem (``A = Q T``: the same least squares, backward stable
    as the one-shot QR; without a ridge, the minimum-norm solution of ``T``, by SVD, is ``lstsq``'s).
    """
    n2 = np.zeros(m)
    for a in range(0, n, FIT_BLOCK_ROWS):
        blk = rows(a, min(n, a + FIT_BLOCK_ROWS))
        n2 += np.einsum("tm,tm->m", blk, blk)
    s = np.where(n2 > MIN_NORM**2, 1.0 / np.sqrt(n2 + TINY), 0.0)
    lam = np.full(m, float(ridge))
    tri, qty = np.zeros((0, m)), np.zeros(0)
    for a in range(0, n, FIT_BLOCK_ROWS):
        b = min(n, a + FIT_BLOCK_ROWS)
        tri, qty = _qr_fold(np.vstack([tri, rows(a, b) * s]), np.concatenate([qty, y[a:b]]), m)
    if np.any(lam > 0):  # the ridge rows, last
        tri, qty = _qr_fold(np.vstack([tri, np.diag(np.sqrt(lam))]), np.concatenate([qty, np.zeros(m)]), m)
    if np.all(lam > 0) and tri.shape[0] == m:
        z = np.asarray(_solve_triangular(tri, qty, check_finite=False), dtype=np.float64)
    else:
        z = np.asarray(np.linalg.lstsq(tri, qty, rcond=None)[0], dtype=np.float64)
    w: NDArray[np.float64] = z * s
    return w


def _qr_fold(a: NDArray[np.float64], b: NDArray[np.float64], m: int) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """The upper triangle (at most ``m`` rows) of ``a``'s QR and the same rows of ``Q^T b``."""
    qr, tau, _, info = _lapack.dgeqrf(np.asfortranarray(a))
    c = None
    if info == 0:
        c, _, info = _lapack.dormqr("L", "T", qr, tau, b[:, None], lwork=max(1, 2 * b.size))
    if info != 0 or c is None:  # pragma: no cover - LAPACK reports an illegal argument only
        q, r = np.linalg.qr(a)
        return r, q.T @ b
    k = min(m, a.shape[0])
    return np.triu(qr[:k, :m]), np.asarray(c[:k, 0], dtype=np.float64)


def _qr_solve(a: NDArray[np.float64], b: NDArray[np.float64]) -> NDArray[np.float64]:
    """Least squares of a full-rank tall ``a`` (every column has its ridge row) by Householder QR (LAPACK
    ``dgeqrf``, ``dormqr``, then the triangle): as accurate as the SVD there (both backward stable; no singular
    value falls below ``lstsq``'s cut-off when every column is regularised) and 1.7x faster on 10,000 rows."""
    qr, tau, _, info = _lapack.dgeqrf(np.asfortranarray(a))
    c = None
    if info == 0:
        c, _, info = _lapack.dormqr("L", "T", qr, tau, b[:, None], lwork=max(1, 2 * b.size))
    if info != 0 or c is None:  # pragma: no cover - LAPACK reports an illegal argument only
        return np.asarray(np.linalg.lstsq(a, b, rcond=None)[0], dtype=np.float64)
    m = a.shape[1]
    return np.asarray(_solve_triangular(qr[:m, :m], c[:m, 0], check_finite=False), dtype=np.float64)


def fit_linear_rbf(
    phi: NDArray[np.float64], r: NDArray[np.float64], y: NDArray[np.float64], ridge: float
) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Weights of an RBF network with a direct linear part, in one least-squares solve.

    ``y ~ phi w + r a + b`` (Chen & Billings' RBF network with linear terms): the
    design ``[phi, r, 1]`` fitted by :func:`fit_weights` (the same Jacobi scaling and
    ridge on every column). Returns ``(w, linear)`` with ``linear = [a; b]``.
    """
    n = phi.shape[0]
    if n > FIT_BLOCK_ROWS:  # a long record: the design built block by block, never whole
        z = streamed_fit(lambda a, b: np.hstack([phi[a:b], r[a:b], np.ones((b - a, 1))]), n,
                          phi.shape[1] + r.shape[1] + 1, y, ridge)
    else:
        z = fit_weights(np.hstack([phi, r, np.ones((n, 1))]), y, ridge)
    M = phi.shape[1]
    return z[:M], z[M:]


def fit_in_blocks(
    regressors: Callable[[int, int], NDArray[np.float64]], y: NDArray[np.float64], centres: NDArray[np.float64],
    widths: NDArray[np.float64], ridge: float, linear: bool, batch: bool = False,
) -> tuple[NDArray[np.float64], NDArray[np.float64] | None, float]:
    """:func:`fit_weights` (``linear``: :func:`fit_linear_rbf`) of the network ``centres``, ``widths`` on the rows
    ``regressors(a, b)`` (rows ``a..b-1``, one column per centre coordinate) of the targets ``y``, its activations
    and regressors made :data:`FIT_BLOCK_ROWS` rows at a time and never for every row at once (past that many rows
    the whole-record fit streams its QR over the same blocks: the same weights). Returns ``(w, linear part or
    None, sum of squared residuals)``. ``batch``: the activations by :func:`activations_batch` (within an ulp of
    :func:`activations`)."""
    n, M = y.shape[0], centres.shape[0]
    cols = centres.shape[1]

    def block(a: int, b: int) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        r = np.ascontiguousarray(regressors(a, b))
        return (activations_batch(r, centres[None], widths[None])[0].T if batch else activations(r, centres, widths)), r

    def rows(a: int, b: int) -> NDArray[np.float64]:
        phi, r = block(a, b)
        return np.hstack([phi, r, np.ones((b - a, 1))]) if linear else phi

    z = streamed_fit(rows, n, M + (cols + 1 if linear else 0), y, ridge)
    w, lin = (z[:M], z[M:]) if linear else (z, None)
    sse = 0.0
    for a in range(0, n, FIT_BLOCK_ROWS):
        b = min(n, a + FIT_BLOCK_ROWS)
        phi, r = block(a, b)
        fit = phi @ w if lin is None else phi @ w + r @ lin[:-1] + lin[-1]
        sse += float(np.sum((fit - y[a:b]) ** 2))
    return w, lin, sse


LOG2E = 1.4426950408889634  # exp(x) = exp2(x log2 e); exp2 is ~15 % faster here

#: numpy's float64 ``exp2`` is vectorised only on CPUs with AVX-512 (about 1 ns an element), and its BLAS products of
#: the search's short, wide blocks run there near the machine's speed; elsewhere (AVX2: an AMD EPYC, exp2 5.5-8.5 ns,
#: the Gram at 20 GFLOP/s) the compiled :func:`~streamid.engine.fit.kernels.exp2_rows` (1.8 ns there, within 1 ulp) and
#: :func:`~streamid.engine.fit.kernels.gram_rows` (about twice as fast, to rounding) do that work. Decided by the CPU's
#: features, never by a timing, so one machine always takes the same path (same seed, same result).
NUMPY_PATH = bool(getattr(importlib.import_module("numpy._core._multiarray_umath"), "__cpu_features__", {}).get("AVX512F"))


def exp2_block(buf: NDArray[np.float64], r0: int, r1: int) -> None:
    """``buf[:, r0:r1, :] = 2 ** buf[:, r0:r1, :]`` in place (``buf`` C-contiguous, 3-D), by the faster path here."""
    if NUMPY_PATH:
        view = buf[:, r0:r1, :]
        np.exp2(view, out=view)
    else:
        exp2_rows(buf, r0, r1)


def gram_block(buf: NDArray[np.float64], p: int, rows: int, out: NDArray[np.float64]) -> NDArray[np.float64]:
    """``out[:p] = buf[:p, :rows] @ buf[:p, 1:rows].T`` (``buf`` C-contiguous, 3-D; ``out`` (>= p, rows, rows - 1),
    C-contiguous) by the faster path here; returns ``out[:p]``: row 0 the design's products with the target
    (row 0 of each block), rows 1.. the design's Gram."""
    gb = out[:p]
    if NUMPY_PATH:
        np.matmul(buf[:p, :rows], buf[:p, 1:rows].transpose(0, 2, 1), out=gb)
    else:
        gram_rows(buf, p, rows, gb)
    return gb
