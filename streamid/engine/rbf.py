r"""Gaussian RBF network: activations, outputs and least-squares weights of one network (and of several at once).

The population's fitness, the search's inner loop, is :class:`~streamid.engine.batch.BatchEvaluator`.

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

import numpy as np
from numpy.typing import NDArray
from scipy.linalg import lapack as _lapack
from scipy.linalg import solve_triangular as _solve_triangular

from streamid.engine._kernels import exp2_rows, gram_rows

__all__ = ["LOG2E", "MIN_NORM", "NUMPY_PATH", "TINY", "activations", "activations_batch", "exp2_block", "fit_linear_rbf",
           "fit_weights", "gram_block", "rbf_output"]

#: added to a squared norm before its square root is divided by
TINY = 1e-300

#: Neurons whose activations on the data have a Euclidean norm below this are
#: treated as inactive (weight 0). Such a neuron sits where no sample is; only an
#: enormous weight would let it matter, and that weight explodes as soon as a
#: prediction wanders near its centre (seen on real data: weights of 1e6..1e93 on
#: neurons of norm 1e-7..1e-95 that wrecked OSA predictions on new data).
MIN_NORM = 1e-5


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
    d2 = ((r[:, None, :] - centres[None, :, :]) ** 2).sum(axis=2)
    g: NDArray[np.float64] = np.exp(-d2 / (2.0 * widths[None, :] ** 2))
    return g


def activations_batch(
    r: NDArray[np.float64], centres: NDArray[np.float64], widths: NDArray[np.float64]
) -> NDArray[np.float64]:
    """Gaussian activations of several networks on the same regressors, as the search computes them.

    One product of coefficient rows ``a2 [c; 1; ||c||^2]`` (``a2 = log2(e) / sigma^2``) with the
    feature rows ``[r; -||r||^2 / 2; -1/2]``, then one ``exp2`` (see :class:`~streamid.engine.batch.BatchEvaluator`):
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
    phi: NDArray[np.float64], y: NDArray[np.float64], ridge: float, weight_decay: float = 0.0
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
    n2 = (phi * phi).sum(axis=0)
    s = np.where(n2 > MIN_NORM**2, 1.0 / np.sqrt(n2 + TINY), 0.0)  # as the search's BatchEvaluator: inactive -> w = 0
    a = phi * s
    lam = ridge + weight_decay * phi.shape[0] * s * s
    if np.any(lam > 0):
        a = np.vstack([a, np.diag(np.sqrt(lam))])
        rhs = np.concatenate([y, np.zeros(phi.shape[1])])
    else:
        rhs = y
    z = _qr_solve(a, rhs) if np.all(lam > 0) else np.asarray(np.linalg.lstsq(a, rhs, rcond=None)[0])
    w: NDArray[np.float64] = z * s
    return w


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
    phi: NDArray[np.float64], r: NDArray[np.float64], y: NDArray[np.float64], ridge: float, weight_decay: float = 0.0
) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Weights of an RBF network with a direct linear part, in one least-squares solve.

    ``y ~ phi w + r a + b`` (Chen & Billings' RBF network with linear terms): the
    design ``[phi, r, 1]`` fitted by :func:`fit_weights` (the same Jacobi scaling and
    ridge on every column). Returns ``(w, linear)`` with ``linear = [a; b]``.
    """
    design = np.hstack([phi, r, np.ones((phi.shape[0], 1))])
    z = fit_weights(design, y, ridge, weight_decay)
    M = phi.shape[1]
    return z[:M], z[M:]


LOG2E = 1.4426950408889634  # exp(x) = exp2(x log2 e); exp2 is ~15 % faster here

#: numpy's float64 ``exp2`` is vectorised only on CPUs with AVX-512 (about 1 ns an element), and its BLAS products of
#: the search's short, wide blocks run there near the machine's speed; elsewhere (AVX2: an AMD EPYC, exp2 5.5-8.5 ns,
#: the Gram at 20 GFLOP/s) the compiled :func:`~streamid.engine._kernels.exp2_rows` (1.8 ns there, within 1 ulp) and
#: :func:`~streamid.engine._kernels.gram_rows` (about twice as fast, to rounding) do that work. Decided by the CPU's
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
