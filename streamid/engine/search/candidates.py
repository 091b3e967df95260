"""The models of a coevolution run's pairs: its candidates for the final choice (:class:`CandidateModels`).

A pair (a lag harmony, a parameter vector of centres and widths) is made a :class:`~streamid.model.narx.Model`
by fitting its output weights (and, with ``linear_terms``, a direct linear part) by least squares on the run's
rows (:mod:`streamid.engine.fit.rbf`): on every estimation row, or on the rows its search used (``search_rows``: the
cheaper fit that screens the candidates of a large record). A record longer than ``FIT_BLOCK_ROWS`` rows is fitted
a block of rows at a time (:func:`~streamid.engine.fit.rbf.fit_in_blocks`), never with every row's activations at once.
:class:`~streamid.engine.search.coevolution.Coevolution` has these methods; the attributes below are the run's.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import numpy as np
from numpy.typing import NDArray

from streamid.engine.fit.blas import one_blas_thread
from streamid.threads import thread_map
from streamid.model.narx import Model
from streamid.engine.fit.rbf import (
    FIT_BLOCK_ROWS, activations, activations_batch, fit_in_blocks, fit_linear_rbf, fit_weights)
from streamid.model.regressors import Normalisation, Regressor
from streamid.engine.fit.lagmatrix import lag_matrix, lag_rows
from streamid.engine.settings import RIDGE, CoEAConfig
from streamid.errors import DataError

__all__ = ["CandidateModels"]


class CandidateModels:
    """Models of a run's pairs (a mixin of :class:`~streamid.engine.search.coevolution.Coevolution`, whose state it reads)."""

    config: CoEAConfig
    D: int
    _R: NDArray[np.float64] | None  # every row's regressors, when made
    _lag_data: tuple[NDArray[np.float64], NDArray[np.float64]]  # the normalised inputs and output
    _search: tuple[NDArray[np.float64], NDArray[np.float64]]  # the search's rows' regressors and targets
    target: NDArray[np.float64]
    _rows: NDArray[np.intp] | None
    scale: float
    candidates: tuple[Regressor, ...]
    norm: Normalisation
    input_names: tuple[str, ...]
    output_name: str
    window: dict[str, Any]
    _config_doc: dict[str, Any]
    best_f: float
    best_h: NDArray[np.bool_]
    best_x: NDArray[np.float64]
    H: NDArray[np.bool_]
    X: NDArray[np.float64]
    fh: NDArray[np.float64]
    fx: NDArray[np.float64]
    evaluations: int

    def model_for(self, mask: NDArray[np.bool_], x: NDArray[np.float64], *, search_rows: bool = False) -> Model:
        """The model of one pair, weights refitted by SVD least squares on this run's data
        (``search_rows``: on the rows the search used only; a cheaper fit for screening candidates)."""
        M, D = self.config.neurons, self.D
        cols = np.flatnonzero(mask)
        if not (search_rows and self._rows is not None) and self.target.shape[0] > FIT_BLOCK_ROWS:
            with one_blas_thread():
                return self._fitted_in_blocks(cols, x)
        R, target = self._fit_rows(search_rows)
        with one_blas_thread():
            phi = activations(R[:, cols], x[: M * D].reshape(M, D)[:, cols], x[M * D :])
            return self._fitted(cols, x, phi, R[:, cols], target)

    def model_on_rows(self, mask: NDArray[np.bool_], x: NDArray[np.float64], rows: NDArray[np.intp],
                      linear: bool | None = None) -> Model:
        """:meth:`model_for` with the weights fitted on the regressor rows ``rows`` only (a record beyond one chunk:
        :func:`~streamid.engine.search.rows.spaced_rows`; its memory and time those rows', not the record's); ``linear``
        as :meth:`_fitted`'s."""
        M, D = self.config.neurons, self.D
        cols = np.flatnonzero(mask)
        if self._R is not None:
            R = np.ascontiguousarray(self._R[rows][:, cols])
        else:
            un, yn = self._lag_data
            c = self.config
            R = np.ascontiguousarray(lag_rows(un, yn, c.max_lag_y, c.max_lag_u, rows, min_lag_u=c.min_lag_u)[:, cols])
        with one_blas_thread():
            phi = activations(R, x[: M * D].reshape(M, D)[:, cols], x[M * D :])
            return self._fitted(cols, x, phi, R, self.target[rows], linear=linear)

    def _fitted_in_blocks(self, cols: NDArray[np.intp], x: NDArray[np.float64], linear: bool | None = None,
                          batch: bool = False) -> Model:
        """:meth:`_fitted` on every row of a long record by :func:`~streamid.engine.fit.rbf.fit_in_blocks` (the same
        weights, never every row's activations or regressors at once); ``batch``: its activations as
        :meth:`models_for` computes them."""
        M, D = self.config.neurons, self.D
        target = self.target
        w, lin, sse = fit_in_blocks(self._regressor_block(cols), target, x[: M * D].reshape(M, D)[:, cols], x[M * D :], RIDGE,
                                    self.config.linear_terms if linear is None else linear, batch)
        return self._model(cols, x, w, lin, sse / target.shape[0] * self.scale)

    def models_for(self, mask: NDArray[np.bool_], xs: list[NDArray[np.float64]], *,
                   search_rows: bool = False, both: bool = False, threads: int = 1, in_blocks: bool = False,
                   ) -> list[Model]:
        """:meth:`model_for` of several parameter vectors with one mask, their activations computed
        together as the search computes them (:func:`~streamid.engine.fit.rbf.activations_batch`).
        ``both`` (with ``linear_terms``): each vector's model with its linear part, then (after all
        of those, in the same order) the same centres and widths without one, weights refitted. ``threads``:
        the least squares in that many threads (the same models). ``in_blocks`` (a record of more than
        ``FIT_BLOCK_ROWS`` rows): each model fitted a block of rows at a time (:meth:`_fitted_in_blocks`),
        never every candidate's activations over every row at once."""
        if not xs:
            return []
        M, D = self.config.neurons, self.D
        cols = np.flatnonzero(mask)
        kinds = (None, False) if both and self.config.linear_terms else (None,)
        if in_blocks and not search_rows and self.target.shape[0] > FIT_BLOCK_ROWS:
            with one_blas_thread():
                return thread_map(lambda j: self._fitted_in_blocks(cols, j[1], j[0], batch=True),
                                  [(kind, x) for kind in kinds for x in xs], threads)
        R, target = self._fit_rows(search_rows)
        X = np.stack(xs)
        with one_blas_thread():
            rs = np.ascontiguousarray(R[:, cols])
            phis = activations_batch(rs, X[:, : M * D].reshape(-1, M, D)[:, :, cols], X[:, M * D :])
            jobs = [(kind, x, phi) for kind in kinds for x, phi in zip(xs, phis)]
            return thread_map(lambda j: self._fitted(cols, j[1], j[2].T, rs, target, linear=j[0]), jobs, threads)

    @property
    def R(self) -> NDArray[np.float64]:
        """Every estimation row's regressors, all candidate lags (row ``k``: time ``max_lag + k``); made on first
        use when the search used a sample of rows (the fits of a long record take them a block at a time)."""
        if self._R is None:
            un, yn = self._lag_data
            self._R = lag_matrix(un, yn, self.config.max_lag_y, self.config.max_lag_u, min_lag_u=self.config.min_lag_u)
        return self._R

    def _regressor_block(self, cols: NDArray[np.intp]) -> Callable[[int, int], NDArray[np.float64]]:
        """Rows ``a..b-1`` of :attr:`R`'s columns ``cols``, without making every row's when they are not made."""
        if self._R is not None:
            R = self._R
            return lambda a, b: np.ascontiguousarray(R[a:b, cols])
        un, yn = self._lag_data
        c = self.config
        return lambda a, b: lag_rows(un, yn, c.max_lag_y, c.max_lag_u, np.arange(a, b), min_lag_u=c.min_lag_u)[:, cols]

    @property
    def searched(self) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """Every candidate lag's regressors and the targets on the rows the search evaluated (every row when it
        evaluated them all)."""
        return self._fit_rows(True)

    def _fit_rows(self, search_rows: bool) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        if search_rows and self._rows is not None:
            return self._search
        return self.R, self.target

    def _fitted(self, cols: NDArray[np.intp], x: NDArray[np.float64], phi: NDArray[np.float64],
                r: NDArray[np.float64], target: NDArray[np.float64], linear: bool | None = None) -> Model:
        """The Model of parameters ``x`` on lags ``cols`` with activations ``phi`` (n, M) on regressors ``r``
        (with a linear part when ``linear``, default ``config.linear_terms``)."""
        lin = None
        if self.config.linear_terms if linear is None else linear:  # the RBF network with linear terms: one least squares for both
            w, lin = fit_linear_rbf(phi, r, target, RIDGE)
            fit = phi @ w + r @ lin[:-1] + lin[-1]
        else:
            w = fit_weights(phi, target, RIDGE)
            fit = phi @ w
        return self._model(cols, x, w, lin, float(np.mean((fit - target) ** 2)) * self.scale)

    def _model(self, cols: NDArray[np.intp], x: NDArray[np.float64], w: NDArray[np.float64],
               lin: NDArray[np.float64] | None, mse: float) -> Model:
        """The Model of parameters ``x`` on lags ``cols`` with output weights ``w`` (and linear part ``lin``)."""
        M, D = self.config.neurons, self.D
        if not np.all(np.isfinite(w)) or not np.isfinite(mse) or (lin is not None and not np.all(np.isfinite(lin))):
            raise DataError("the least-squares weights are not finite (the data are numerically degenerate)")
        return Model(
            regressors=tuple(self.candidates[j] for j in cols),
            centres=x[: M * D].reshape(M, D)[:, cols],
            widths=x[M * D :].copy(),
            weights=w,
            normalisation=self.norm,
            input_names=self.input_names,
            output_name=self.output_name,
            metrics={"fitness": mse, "fitness_search": float(self.best_f), "evaluations": self.evaluations},
            window=self.window,
            config=dict(self._config_doc),
            linear=lin,
        )

    def _members(self, limit: int | None) -> list[int]:
        """Every member of ``X``, or the ``limit`` of lowest fitness (in population order)."""
        if limit is not None and limit < self.X.shape[0]:
            return sorted(np.argsort(self.fx, kind="stable")[: max(0, int(limit))].tolist())
        return list(range(self.X.shape[0]))

    def candidate_pairs(self, limit: int | None = None) -> list[tuple[NDArray[np.bool_], NDArray[np.float64]]]:
        """(mask, parameters) of the best pair and of the members :meth:`population_models` would give."""
        b = int(np.argmin(self.fh))
        return [(self.best_h, self.best_x), *((self.H[b], self.X[i]) for i in self._members(limit))]

    def population_models(self, limit: int | None = None, *, search_rows: bool = False,
                          both: bool = False, threads: int = 1, in_blocks: bool = False) -> list[Model]:
        """Models of every parameter vector paired with the best harmony, weights refitted
        (:meth:`models_for`: activations computed together).

        Candidates for a choice by another criterion than the fitness (e.g. free-run R^2):
        in the second half of a run every member of ``X`` evolved with the best harmony.
        ``limit``: only that many members, those of lowest fitness (in population order).
        """
        b = int(np.argmin(self.fh))
        return self.models_for(self.H[b], [self.X[i] for i in self._members(limit)], search_rows=search_rows,
                               both=both, threads=threads, in_blocks=in_blocks)

    def candidate_models(self, limit: int | None = None, *, both: bool = False, threads: int = 1,
                         in_blocks: bool = False) -> list[Model]:
        """The best pair's model, then :meth:`population_models` without a member that is the best pair
        itself (same harmony and parameters: DE keeps the best trial, so a second stage's best pair is a
        member); fitted together when they share the harmony (the usual case). ``both`` (with
        ``linear_terms``): then the same candidates without the linear part (:meth:`models_for`).
        ``in_blocks``: see :meth:`models_for`."""
        if not np.isfinite(self.best_f):
            raise DataError("no pair has been evaluated")
        b = int(np.argmin(self.fh))
        if not np.array_equal(self.H[b], self.best_h):
            if not (both and self.config.linear_terms):
                return [self.best_model(), *self.population_models(limit, threads=threads, in_blocks=in_blocks)]
            first = self.models_for(self.best_h, [self.best_x], both=True, in_blocks=in_blocks)
            rest = self.population_models(limit, both=True, threads=threads, in_blocks=in_blocks)
            return [first[0], *rest[: len(rest) // 2], first[1], *rest[len(rest) // 2 :]]
        xs = [self.X[i] for i in self._members(limit) if not np.array_equal(self.X[i], self.best_x)]
        return self.models_for(self.best_h, [self.best_x, *xs], both=both, threads=threads, in_blocks=in_blocks)

    def best_model(self) -> Model:
        """Model of the best pair ever evaluated, weights refitted (see :func:`~streamid.engine.fit.rbf.fit_weights`)."""
        if not np.isfinite(self.best_f):
            raise DataError("no pair has been evaluated")
        return self.model_for(self.best_h, self.best_x)
