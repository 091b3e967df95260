r"""The population's fitness: :class:`BatchEvaluator`, every member's one-step-ahead MSE in one pass.

How the activations of a whole population come from one product and one ``exp2`` is in
:mod:`streamid.engine.fit.rbf` ("Batched population evaluation"); this module solves the members' least squares.

Least squares of the population (the choice and its safeguards)
---------------------------------------------------------------
The output weights of every member are the solution of a *regularised, scaled
normal equation*, solved for all members at once:

1. ``G_p = Phi_p Phi_p^T`` and ``b_p = Phi_p y`` come out of one batched product
   of ``[y; Phi_p]`` (the target is kept as row 0 of each member's block of the
   activation buffer) with ``Phi_p^T``.
2. Jacobi scaling ``s_m = 1 / sqrt(G_mm)`` brings the diagonal to 1. A neuron
   whose activations have a norm below :data:`MIN_NORM` (all ~0 on the data)
   gets ``s = 0`` and weight 0 instead of an enormous weight.
3. ``(S G S + ridge I) z = S b`` is solved by batched LU (the gufunc behind
   ``numpy.linalg.solve``, called directly: the public wrapper costs ~6 us of
   Python per call, 2.4 ms per 400-generation run); ``w = S z``. With the unit
   diagonal the ridge bounds the condition number by ``(M + ridge) / ridge``
   (1e11 for the default ridge 1e-10 and M = 10), far from float64's limit, so
   no member can make the batch singular; should LAPACK still meet an exactly
   singular system, the batch falls back to per-member SVD least squares.
4. The fitness is the MSE of the *actual* residual ``y - w^T Phi_p`` (computed
   directly, never from ``y^T y - w^T b`` which cancels catastrophically), so an
   ill-conditioned member is charged for whatever its weights really achieve.

Batched QR (``numpy.linalg.qr`` on a stack) was measured 3-4x slower here: it
calls LAPACK once per member, each call dominated by overhead at these sizes.
Everything stays float64: ``exp2`` in float32 is 3x faster but perturbs a
member's fitness by ~6e-5 (relative, median; 3e-4 max) late in a reactor run,
as large as the differences DE selects on, and the search's fitness would no
longer be the refitted model's.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import numpy as np
from numpy.typing import NDArray

from streamid.engine.fit.rbf import LOG2E, MIN_NORM, TINY, exp2_block, gram_block

__all__ = ["BatchEvaluator"]


_gufunc_solve: Callable[..., NDArray[np.float64]] | None
try:  # the gufunc behind numpy.linalg.solve, without the wrapper's ~6 us of Python per call
    from numpy.linalg import _umath_linalg

    _gufunc_solve = _umath_linalg.solve
except (ImportError, AttributeError):  # pragma: no cover - numpy moved it; the public function is equivalent
    _gufunc_solve = None


def _solve(a: NDArray[np.float64], b: NDArray[np.float64]) -> NDArray[np.float64]:
    """Batched LU solve of ``a (p, M, M) z = b (p, M, 1)``.

    The ridge makes every system non-singular in practice; should LAPACK still
    meet an exactly singular one, the whole batch falls back to per-member SVD
    least squares (``numpy.linalg.lstsq``).
    """
    if _gufunc_solve is not None:
        with np.errstate(invalid="ignore"):  # a singular member gives NaN (handled below), not a warning
            z = _gufunc_solve(a, b, signature="dd->d")
        if z.sum() == z.sum():  # no NaN: the usual case, one reduction
            return z
    else:  # pragma: no cover
        try:
            return np.linalg.solve(a, b).astype(np.float64, copy=False)
        except np.linalg.LinAlgError:
            pass
    return np.stack([np.linalg.lstsq(a[i], b[i, :, 0], rcond=None)[0] for i in range(a.shape[0])])[:, :, None]


class BatchEvaluator:
    """Fitness (OSA MSE) of many (mask, centres, widths) members on fixed data.

    Buffers are allocated once for ``capacity`` members and reused for every
    call, so a coevolution run allocates no large temporaries per generation.

    Parameters
    ----------
    regressors : ndarray, shape (n, D)
        Candidate regressor matrix (normalised), from :func:`~streamid.engine.fit.lagmatrix.lag_matrix`.
    target : ndarray, shape (n,)
        Normalised output at the same times.
    neurons : int
        M.
    capacity : int
        Largest number of members evaluated in one call.
    ridge : float
        Relative Tikhonov term (floored at 1e-14 so that every normal equation is non-singular).
    """

    def __init__(
        self,
        regressors: NDArray[np.float64],
        target: NDArray[np.float64],
        neurons: int,
        capacity: int,
        ridge: float = 1e-10,
    ) -> None:
        R = np.ascontiguousarray(regressors, dtype=np.float64)
        n, D = R.shape
        self.n, self.D, self.M, self.capacity = n, D, int(neurons), int(capacity)
        self.ridge = max(float(ridge), 1e-14)
        self.target = np.ascontiguousarray(target, dtype=np.float64)
        M, P = self.M, self.capacity
        # Feature rows: r_j (D rows), then one row per member for -||h_p o r||^2 / 2 (filled per
        # call), then a row of -1/2. With these rows a neuron's coefficients are its
        # [centre coordinates; 1; ||centre||^2], all multiplied by a2 = log2(e) / sigma^2.
        self._table = np.empty((D + P + 1, n))
        self._table[:D] = R.T
        self._table[D + P] = -0.5
        self._hr2t = np.ascontiguousarray(-0.5 * R.T**2)
        self._feat = np.empty(P * (D + 2) * n)
        self._idx = np.empty((P, D + 2), dtype=np.intp)
        self._idx[:, -2] = D + np.arange(P)
        self._idx[:, -1] = D + P
        # Flat offsets of centre (p, m, 0) and of mask (p, 0), for packed gathers.
        self._cbase = (np.arange(P)[:, None, None] * (M * D) + np.arange(M)[None, :, None] * D).astype(np.intp)
        self._hbase = (np.arange(P)[:, None] * D).astype(np.intp)
        self._cext = np.empty(P * M * (D + 2))  # [c_sel; 1; ||c_sel||^2] per neuron (flat, viewed per K)
        self._coef = np.empty(P * M * (D + 2))  # a2 * cext
        self._a2 = np.empty((P, M))
        self._s = np.empty((P, M))
        self._active = np.empty((P, M), dtype=bool)
        # Row 0 of each block: target; rows 1..M: activations.
        self._ext = np.empty((P, M + 1, n))
        self._ext[:, 0, :] = self.target
        self._gb = np.empty((P, M + 1, M))
        self._diag_g = self._gb.reshape(P, (M + 1) * M)[:, M :: M + 1]  # diag(G_p), a view
        self._gs = np.empty((P, M, M))
        self._diag_gs = self._gs.reshape(P, M * M)[:, :: M + 1]
        self._v = np.empty((P, 1, M + 1))  # [-1, w]: the residual is v @ [y; Phi]
        self._v[:, 0, 0] = -1.0
        self._res = np.empty((P, 1, n))
        self._view_cache: dict[int, tuple[NDArray[Any], ...]] = {}
        self._shared_key: bytes | None = None
        self._shared_feat = np.empty((0, n))
        self._shared_cols = np.empty(0, dtype=np.intp)
        self._shared_cext = np.empty((P, M, 2))

    def _shared_features(self, mask: NDArray[np.bool_]) -> tuple[NDArray[np.intp], NDArray[np.float64]]:
        """Features ``[r_j (selected); -sum_j r_j^2 / 2; -1/2]`` for one mask shared by all members (cached)."""
        key = mask.tobytes()
        if key != self._shared_key:
            cols = np.flatnonzero(mask)
            k = cols.size
            feat = np.empty((k + 2, self.n))
            feat[:k] = self._table[cols]
            feat[k] = self._hr2t[cols].sum(axis=0)
            feat[k + 1] = -0.5
            cext = np.empty((self.capacity, self.M, k + 2))
            cext[:, :, k] = 1.0
            self._shared_feat, self._shared_cols, self._shared_cext = feat, cols, cext
            self._shared_key = key
        return self._shared_cols, self._shared_feat

    def activations_into(
        self,
        masks: NDArray[np.bool_],
        centres: NDArray[np.float64],
        widths: NDArray[np.float64],
        shared: bool | None = None,
    ) -> NDArray[np.float64]:
        """Compute every member's activations into the buffer; returns its view (p, M, n).

        The exponent ``-log2(e) ||h o (r - c)||^2 / (2 sigma^2)`` of every neuron is
        one row of a batched product of coefficient rows ``a2 [c_sel; 1; ||c_sel||^2]``
        (``a2 = log2(e) / sigma^2``) with feature rows ``[r_sel; -||h o r||^2 / 2; -1/2]``,
        followed by one in-place ``exp2``. With per-member masks each member's
        selected coordinates are packed to the left (stable argsort of the mask)
        and its features gathered, so the product has ``K = max_p |h_p| + 2``
        feature rows; packed slots beyond a member's own count have zero centre
        coordinates and meet (unselected) coordinates' rows with zero coefficients.
        When all members share one mask (the second half of a run) the features
        are shared and cached; ``shared=True`` asserts that (the caller knows),
        ``None`` checks.
        """
        p = masks.shape[0]
        if p > self.capacity:
            raise ValueError(f"at most {self.capacity} members per call; got {p}")
        n, D, M = self.n, self.D, self.M
        a2, a2_3, phi = self._views(p)[16:]
        np.multiply(widths, widths, out=a2)
        np.divide(LOG2E, a2, out=a2)  # a2 = log2(e) / sigma^2
        if shared is None:
            shared = p == 1 or not np.any(masks[1:] != masks[0])
        if shared:
            cols, feat = self._shared_features(masks[0])
            k = cols.size
            K = k + 2
            cext = self._shared_cext[:p]
            cext[:, :, :k] = centres[:, :, cols]
        else:
            # (array methods rather than np.take & co.: their Python wrappers cost ~1 us per call)
            masks = np.ascontiguousarray(masks)
            kk = int(masks.sum(axis=1).max())
            order = (~masks).argsort(axis=1, kind="stable")[:, :kk]  # selected columns first
            hp = masks.take(self._hbase[:p] + order, mode="clip")
            K = kk + 2
            cext = self._cext[: p * M * K].reshape(p, M, K)
            cs = cext[:, :, :kk]
            np.multiply(
                np.ascontiguousarray(centres).take(self._cbase[:p] + order[:, None, :], mode="clip"),
                hp[:, None, :],
                out=cs,
            )
            cext[:, :, kk] = 1.0
            np.matmul(masks, self._hr2t, out=self._table[D : D + p])
            idx = self._idx[:p, -K:]
            idx[:, :kk] = order
            feat = self._feat[: p * K * n].reshape(p, K, n)
            self._table.take(idx, axis=0, out=feat, mode="clip")  # indices valid; 'raise' is 3x slower
            k = kk
        cs = cext[:, :, :k]
        np.vecdot(cs, cs, out=cext[:, :, k + 1])
        coef = self._coef[: p * M * K].reshape(p, M, K)
        np.multiply(cext, a2_3, out=coef)
        np.matmul(coef, feat, out=phi)
        exp2_block(self._ext[:p], 1, M + 1)  # phi is rows 1..M of each member's block
        return phi

    def _views(self, p: int) -> tuple[NDArray[Any], ...]:
        """The buffers' views for a batch of ``p`` members (made once per ``p``: slicing costs ~0.2 us each)."""
        views = self._view_cache.get(p)
        if views is None:
            ext, gb, v, res = self._ext[:p], self._gb[:p], self._v[:p], self._res[:p]
            views = (
                ext, gb, gb[:, 1:, :], gb[:, 0, :], gb[:, 0, :, None], self._s[:p], self._diag_g[:p],
                self._active[:p], self._gs[:p], self._diag_gs[:p], v, v[:, 0, 1:], res, res[:, 0, :],
                self._s[:p, :, None], self._s[:p, None, :], self._a2[:p], self._a2[:p, :, None],
                ext[:, 1 : self.M + 1, :],
            )
            self._view_cache[p] = views
        return views

    def evaluate(
        self,
        masks: NDArray[np.bool_],
        centres: NDArray[np.float64],
        widths: NDArray[np.float64],
        *,
        return_weights: bool = False,
        shared: bool | None = None,
    ) -> NDArray[np.float64] | tuple[NDArray[np.float64], NDArray[np.float64]]:
        """OSA mean squared error (normalised units) of each member.

        Parameters
        ----------
        masks : ndarray of bool, shape (p, D)
        centres : ndarray, shape (p, M, D)
        widths : ndarray, shape (p, M)
        return_weights : bool
            Also return the least-squares weights (p, M).
        shared : bool, optional
            True if all masks are equal (skips the check), False if not known to be.

        Returns
        -------
        mse : ndarray, shape (p,)
        weights : ndarray, shape (p, M), only with ``return_weights``
        """
        p = masks.shape[0]
        self.activations_into(masks, centres, widths, shared)  # rows 1..M of each member's block of self._ext
        ext, _, gbt, sb, sb3, s, dg, active, gs, dgs, v, w, res, r0, s_col, s_row = self._views(p)[:16]
        gram_block(self._ext, p, self.M + 1, self._gb)  # row 0: b = Phi y (sb); rows 1..M: G = Phi Phi^T (gbt)
        np.add(dg, TINY, out=s)  # diag(G) = ||phi_m||^2
        np.sqrt(s, out=s)
        np.greater(dg, MIN_NORM**2, out=active)
        np.divide(active, s, out=s)  # inactive neuron: s = 0, so z_m = 0 and w_m = 0
        np.multiply(s_col, s_row, out=gs)
        gs *= gbt  # S G S
        sb *= s  # S b
        dgs += self.ridge
        z = _solve(gs, sb3)
        np.multiply(z[:, :, 0], s, out=w)  # w = S z
        np.matmul(v, ext, out=res)  # w^T Phi - y
        mse: NDArray[np.float64] = np.vecdot(r0, r0)  # a new array: callers may keep it
        mse /= self.n
        if return_weights:
            return mse, w.copy()
        return mse
