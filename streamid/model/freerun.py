"""Free-run simulation kernel shared by :class:`~streamid.model.narx.Model` and the final choice.

Several networks with the same regressors advance together, one numpy call per
operation and step. A network may carry a direct linear part (``linear``: one
coefficient per regressor, then a constant), the classical "RBF network with
linear terms": ``yn(t) = sum_m w_m phi_m(r(t)) + sum_j a_j r_j(t) + b``.
Without it (``linear=None``) the computation is exactly the RBF-only one.
"""

from __future__ import annotations

from collections.abc import Iterator
from typing import Any

import numpy as np
from numpy.typing import NDArray

from streamid.threads import thread_map
from streamid.model.regressors import Regressor

__all__ = ["RunCarry", "chunked_paths", "chunked_runs", "free_run"]


def free_run(
    regressors: tuple[Regressor, ...],
    centres: NDArray[np.float64],
    widths: NDArray[np.float64],
    weights: NDArray[np.float64],
    un: NDArray[np.float64],
    yn_init: NDArray[np.float64],
    linear: NDArray[np.float64] | None = None,
    threads: int = 1,
    linear_regressors: tuple[Regressor, ...] | None = None,
) -> NDArray[np.float64]:
    """Free-run simulation of several networks with the same regressors at once (normalised units).

    Parameters
    ----------
    regressors : tuple of Regressor
        Shared by all networks; ``L = max lag``.
    centres : ndarray, shape (C, M, k)
    widths, weights : ndarray, shape (C, M)
    un : ndarray, shape (N, n_inputs) or (C, N, n_inputs)
        Normalised inputs: the same for every network, or one sequence per network.
    yn_init : ndarray, shape (C, L)
        Normalised initial outputs (the first ``L`` samples).
    linear : ndarray, shape (C, k + 1), optional
        Each network's direct linear part: a coefficient per regressor, then the constant.
    linear_regressors : tuple of Regressor, optional
        The linear part's own regressors (a long linear part, :mod:`streamid.engine.choice.longlinear`), shared by all
        networks; ``linear`` then has shape (C, len(linear_regressors) + 1). None: the network's regressors.
    threads : int
        Split the networks into this many groups simulated at once in threads (the compiled loop
        releases the GIL): for a caller with a second core to spare. Each network's arithmetic is
        its own, so the result is the same to the bit with any number.

    Returns
    -------
    ndarray, shape (C, N)
        The first ``L`` columns are ``yn_init``; then each network's recursive prediction.

    Notes
    -----
    The recursion is inherently sequential: it is one compiled loop over the steps
    (:func:`~streamid.model.kernels.recursion`), all networks advancing together, which
    computes each neuron's input and output terms at the step (no whole-record temporaries).
    """
    C, M, _ = centres.shape
    if threads > 1 and C > 1:
        parts = np.array_split(np.arange(C), min(threads, C))  # none empty: at most C groups

        def part(idx: NDArray[np.intp]) -> NDArray[np.float64]:
            return free_run(regressors, centres[idx], widths[idx], weights[idx], un if un.ndim == 2 else un[idx],
                            yn_init[idx], None if linear is None else linear[idx], linear_regressors=linear_regressors)

        return np.concatenate(thread_map(part, parts, threads))
    if un.ndim == 2:
        un = un[None]
    n = un.shape[1]
    lregs = regressors if linear_regressors is None or linear is None else linear_regressors
    L = max((r.lag for r in (*regressors, *lregs)), default=0)
    a = 1.0 / (2.0 * widths**2)  # (C, M)
    yj = [j for j, r in enumerate(regressors) if r.signal == "y"]
    uj = [j for j, r in enumerate(regressors) if r.signal == "u"]
    lags = np.array([regressors[j].lag for j in yj], dtype=np.int64)
    y = np.empty((n, C))
    y[:L] = yn_init[:, :L].T
    lin_u = None if linear is None else _linear_inputs(lregs, linear, un, n)
    lyj = [j for j, r in enumerate(lregs) if r.signal == "y"]
    if lags.size == 0 and (linear is None or not lyj):  # no output terms: nothing recursive
        ndu = _input_exponents(regressors, centres, a, un, n)
        np.exp(ndu[L:], out=ndu[L:])
        y[L:] = np.einsum("tcm,cm->tc", ndu[L:].reshape(n - L, C, M), weights)
        if lin_u is not None:
            y[L:] += lin_u[L:]
        return np.ascontiguousarray(y.T)
    llags = np.array([lregs[j].lag for j in lyj], dtype=np.int64)
    lin_y = np.zeros((C, llags.size)) if linear is None else np.ascontiguousarray(linear[:, lyj])
    ulags = np.array([regressors[j].lag for j in uj], dtype=np.int64)
    uidx = np.array([regressors[j].index for j in uj], dtype=np.int64)
    cu = np.ascontiguousarray(centres[:, :, uj].transpose(0, 2, 1))  # (C, ku, M): coordinate-major
    cy = np.ascontiguousarray(centres[:, :, yj].transpose(0, 2, 1))  # (C, ky, M)
    from streamid.model.kernels import recursion  # numba, loaded on the first free run (not on import)

    recursion(np.ascontiguousarray(un, dtype=np.float64), ulags, uidx, cu, cy, a, lags,
              np.array(weights, dtype=np.float64, order="C"), llags, lin_y,
              np.zeros((n, C)) if lin_u is None else lin_u, y, L)
    return np.ascontiguousarray(y.T)


def _input_exponents(
    regressors: tuple[Regressor, ...], centres: NDArray[np.float64], a: NDArray[np.float64], un: NDArray[np.float64],
    n: int,
) -> NDArray[np.float64]:
    """Minus the scaled squared distances the input regressors contribute, every step at once, time-major (n, C*M)."""
    C, M, _ = centres.shape
    du = np.zeros((n, C, M))
    tmp: NDArray[np.float64] | None = None  # one (n, C, M) temporary for all input terms (fresh ones page-fault)
    for j, reg in enumerate(regressors):
        if reg.signal == "u":
            col = np.zeros((n, un.shape[0]))
            col[reg.lag :] = un[:, : n - reg.lag, reg.index].T
            tmp = np.subtract(col[:, :, None], centres[None, :, :, j], out=tmp)
            np.multiply(tmp, tmp, out=tmp)
            du += tmp
    du *= a[None]
    return np.negative(du, out=du).reshape(n, C * M)


def _linear_inputs(
    regressors: tuple[Regressor, ...], linear: NDArray[np.float64], un: NDArray[np.float64], n: int
) -> NDArray[np.float64]:
    """The linear part's input terms and constant of every step, time-major (n, C)."""
    C = linear.shape[0]
    out = np.empty((n, C))
    out[:] = linear[:, -1]
    for j, reg in enumerate(regressors):
        if reg.signal == "u":
            col = np.zeros((n, un.shape[0]))
            col[reg.lag :] = un[:, : n - reg.lag, reg.index].T
            out += col * linear[None, :, j]
    return out


class RunCarry:
    """A model's free run over a record that arrives a piece at a time: what :func:`chunked_paths` and
    :func:`chunked_runs` carry from one piece to the next (each network's last ``max_lag`` outputs, normalised; the
    combined run's last ``max_lag`` values and the inputs before the piece, which its domain excess reads back).

    :meth:`next` takes the piece's inputs with the ``min(a, max_lag)`` rows before it (``a`` its first sample) and
    gives ``(a, paths, centre, beyond)`` as :func:`chunked_runs` yields them: the same values to the bit, whatever
    the pieces' lengths (each at least ``max_lag + 1`` rows but the last). Memory: a piece's. ``model`` a Model or an
    ensemble (read, not imported); ``y_init`` at least ``max_lag`` measured outputs; ``measured`` as in
    :func:`chunked_paths`."""

    def __init__(self, model: Any, y_init: NDArray[np.float64], threads: int = 1, measured: bool = True) -> None:
        self.model, self.threads, self.measured = model, threads, measured
        self.members = tuple(getattr(model, "members", (model,)))
        self.L, self.norm = int(model.max_lag), model.normalisation
        self.yi = np.asarray(y_init, dtype=np.float64).reshape(-1)[: self.L]
        self.tails = [self.norm.y(self.yi[: m.max_lag]) for m in self.members]  # each network's last outputs
        self.a = 0  # the next piece's first sample
        self.tail_c = np.empty(0)

    def _piece(self, k: int, u_ext: NDArray[np.float64], h: int) -> NDArray[np.float64]:
        m, lm = self.members[k], int(self.members[k].max_lag)
        s = h - lm if self.a else 0  # a later piece starts from its network's own last outputs
        yn = free_run(m.regressors, m.centres[None], m.widths[None], m.weights[None], self.norm.u(u_ext[s:]),
                      self.tails[k][None, :], None if m.linear is None else m.linear[None],
                      linear_regressors=m.linear_regressors)[0]
        self.tails[k] = yn[yn.shape[0] - lm:].copy() if lm else yn[:0]
        out: NDArray[np.float64] = self.norm.y_inverse(yn[h - s:])
        return out

    def paths(self, u_ext: NDArray[np.float64]) -> tuple[int, NDArray[np.float64]]:
        """``(a, paths)`` of the next piece (:func:`chunked_paths`'); ``u_ext`` its inputs after the
        ``min(a, max_lag)`` rows before it."""
        a, h = self.a, min(self.a, self.L)
        paths = np.array(thread_map(lambda k: self._piece(k, u_ext, h), range(len(self.members)), self.threads))
        if a == 0 and self.measured:
            paths[:, : self.L] = self.yi[: self.L]  # the measured initial outputs (as simulate and member_paths give them)
        self.a = a + paths.shape[1]
        return a, paths

    def next(self, u_ext: NDArray[np.float64], far: bool = True) -> tuple[
            int, NDArray[np.float64], NDArray[np.float64], NDArray[np.float64] | None]:
        """``(a, paths, centre, beyond)`` of the next piece (:func:`chunked_runs`'); ``far`` False: ``beyond`` None."""
        from streamid.model.domain import far_from_domain

        L, model = self.L, self.model
        a, paths = self.paths(u_ext)
        with np.errstate(over="ignore", invalid="ignore"):
            centre = paths[0].copy() if paths.shape[0] == 1 else model.combine_rows(paths)
            if a == 0:
                centre[:L] = paths[0, :L]  # the measured initial outputs
            ex = None
            if far:
                ex = far_from_domain(model, u_ext, np.concatenate([self.tail_c, centre]))[self.tail_c.shape[0]:]
        self.tail_c = centre[max(0, centre.shape[0] - L):]
        return a, paths, centre, ex


def chunked_paths(model: Any, u: NDArray[np.float64], y_init: NDArray[np.float64], rows: int,
                  threads: int = 1, measured: bool = True) -> Iterator[tuple[int, NDArray[np.float64]]]:
    """A model's networks' free runs over a record, ``rows`` samples at a time: ``(a, paths)`` for consecutive
    spans ``a .. a + len`` covering the record, ``paths`` ``(K, len)`` in output units (a member's each for an
    ensemble), the first ``max_lag`` samples measured: ``model.member_paths(u, y_init)`` cut in pieces, the same
    values to the bit (each network carries its own last ``max_lag`` outputs, normalised, from one piece to the
    next: the recursion's arithmetic is unchanged; :class:`RunCarry`). Memory: a piece's, whatever the record's
    length.

    ``model`` a Model or an ensemble (read, not imported); ``u`` (N, n_inputs) float64 as
    :func:`~streamid.model.regressors.as_data` gives it; ``y_init`` at least ``max_lag`` measured outputs;
    ``threads``: an ensemble's members in that many threads (the same values); ``measured`` False: each network's
    path is its own free run from its own ``max_lag`` measured outputs (``network.simulate``'s), the samples before
    the model's ``max_lag`` not replaced by the measured ones.
    """
    carry = RunCarry(model, y_init, threads, measured)
    L, n, step = carry.L, int(u.shape[0]), max(int(rows), carry.L + 1)
    for a in range(0, n, step):
        yield carry.paths(u[max(0, a - L) : min(n, a + step)])


def chunked_runs(model: Any, u: NDArray[np.float64], y_init: NDArray[np.float64], rows: int, threads: int = 1,
                 far: bool = True, far_from: int = 0) -> Iterator[tuple[int, NDArray[np.float64], NDArray[np.float64],
                                                     NDArray[np.float64] | None]]:
    """:func:`chunked_paths` with each piece's free run and how far it lies beyond the estimation domain:
    ``(a, paths, centre, beyond)``, ``centre`` the model's free run (its networks' combined, the first ``max_lag``
    measured: :meth:`Model.simulate`'s values), ``beyond`` :func:`~streamid.model.domain.far_from_domain` of the
    piece (its regressors read back across the piece's start: the whole run's values), None without ``far`` or
    for a piece that ends before sample ``far_from``.
    What a record's report and the interval's calibration read, a piece at a time (:class:`RunCarry`)."""
    carry = RunCarry(model, y_init, threads)
    L, n, step = carry.L, int(u.shape[0]), max(int(rows), carry.L + 1)
    for a in range(0, n, step):
        b = min(n, a + step)
        yield carry.next(u[max(0, a - L) : b], far and b > far_from)
