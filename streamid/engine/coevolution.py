"""Cooperative coevolution of lag harmonies (ABHS) and RBF parameters (DE), paper section 4.

One :class:`Coevolution` is one run on one data set. It is steppable
(``next(run)`` makes one generation), its state (both populations, their
fitness and the best pair) can be exported as :class:`CoEAState` and used to
warm-start a run on new data.

The run, as streamid implements it
----------------------------------
* Populations: ``H`` (P binary harmonies, one bit per candidate lag) and ``X``
  (P vectors: ``M`` centres of ``D_H`` coordinates, row after row, then ``M``
  widths; ``D_X = (D_H + 1) M``, eq. 16).
* Fitness of a pair: MSE of the one-step-ahead prediction on the estimation
  data, in the output's own units (as the paper's Table 4), with the output
  weights from least squares.
* Start: each member of ``X`` is evaluated with a random member of ``H`` and
  each member of ``H`` with a random member of ``X`` (2 P evaluations). With a
  warm start the previous populations are re-evaluated on the new data instead:
  ``X`` with the previous best harmony, ``H`` with the previous best parameters.
* Generation ``g`` (0-based, ``G`` in all): HMCR/PAR from the schedule; a DE
  trial for every member of ``X``; while ``g < round(harmony_stop * G)`` (the paper's 0.5, ``HARMONY_STOP``) trial
  ``i`` is paired with newly improvised harmony ``i``, afterwards with the best
  harmony (``H`` stops evolving); the P pairs are evaluated at once; DE
  selection for ``X``, memory update for ``H``.
* Randomness: the uniforms of up to ``_BLOCK`` (50) generations (at most 2 MiB
  of them) are drawn in one call (row ``k``: generation ``g0 + k``'s DE
  uniforms, then its improvisation's while the harmonies evolve; a block never
  straddles the end of the harmony phase), and DE donors, crossover masks and
  improvisation masks are prepared for the whole block at once. The stream is the same as one draw per
  generation, so a run's result does not depend on the block size; only a run
  stopped early leaves drawn-but-unused uniforms behind.
* Credit: a harmony used as a partner by other evaluations keeps the best
  fitness any of them achieved (so the best harmony and the best pair agree).
* Result: the best pair ever evaluated; :meth:`Coevolution.best_model`
  refits its weights accurately (SVD).
"""

from __future__ import annotations

import time
from collections.abc import Callable, Iterator
from typing import Any, NamedTuple

import numpy as np
from numpy.typing import ArrayLike, NDArray

from streamid.engine import de, harmony
from streamid.engine._blas import one_blas_thread
from streamid.engine.fanout import thread_map
from streamid.engine.settings import HARMONY_STOP, HMCR, PAR, RIDGE, CoEAConfig
from streamid.engine.model import Model
from streamid.engine.parallel import EvalHelper, HelperBinding
from streamid.engine.batch import BatchEvaluator
from streamid.engine.rbf import FIT_BLOCK_ROWS, activations, activations_batch, fit_linear_rbf, fit_weights, streamed_fit
from streamid.engine.regressors import Normalisation, as_data, candidate_regressors, lag_matrix
from streamid.engine.populations import STATE_FORMAT, CoEAState
from streamid.errors import ConfigError, DataError

__all__ = ["CoEAState", "Coevolution", "Progress", "STATE_FORMAT"]

#: Generations whose random numbers are drawn and turned into DE donors, crossover
#: masks and improvisation masks at once (see :meth:`Coevolution._plan`), at most
#: ``_BLOCK_VALUES`` uniforms (2 MiB) per block. Results do not depend on either.
_BLOCK = 50
_BLOCK_VALUES = 1 << 18

class Progress(NamedTuple):
    """What one generation reports: its number (1-based count done), the best fitness, evaluations so far."""

    generation: int
    generations: int
    best_fitness: float
    evaluations: int


class Coevolution:
    """One steppable coevolution run on fixed estimation data.

    Parameters
    ----------
    u : array_like, shape (N,) or (N, n_inputs)
        Estimation inputs.
    y : array_like, shape (N,)
        Estimation output.
    config : CoEAConfig, optional
        Settings (default :class:`CoEAConfig` ()).
    rng : numpy.random.Generator or int
        Source of every random draw (an int seeds ``numpy.random.default_rng``).
    warm_start : CoEAState, optional
        Start from these populations (re-evaluated on this data) instead of random ones.
    input_names, output_name : optional
        Names recorded in the model.
    window : dict, optional
        Metadata of the data window recorded in the model.
    fixed_mask : ndarray of bool, optional
        Search only centres and widths for these lags (one bit per candidate):
        the lag population is this mask throughout (the second stage of a two-stage
        run, see :mod:`streamid.engine.identification`). Not combinable with ``warm_start``.
    normalisation : Normalisation, optional
        Use this normalisation instead of the min/max of ``u``, ``y`` (e.g. the
        min/max of a larger estimation set this run sees a part of).
    helper : EvalHelper, optional
        Evaluate half of every batch in this helper process (the second core,
        see :mod:`streamid.engine.parallel`); the result is the same without it.
    rows : ndarray of int, optional
        The search's fitness uses only these rows of the regressor matrix (row
        ``k`` is time ``max_lag + k``): a large record searched on a sample of
        its rows. Models (:meth:`model_for`) are still fitted on every row.
    harmony_stop : float
        Fraction of the generations after which the lags stop evolving and every trial is paired with the best
        harmony (the paper's 0.5, :data:`~streamid.engine.settings.HARMONY_STOP`; a two-stage run's lag stage: 1.0).
    hmcr, par : (float, float)
        HMCR and PAR moved linearly from the first value to the second, in [0, 1] (the paper's: ``settings.HMCR``, ``PAR``).

    Raises
    ------
    DataError
        NaN/inf, constant signals, too few samples.
    ConfigError
        Bad configuration, or a warm-start state of another shape.
    """

    def __init__(
        self,
        u: ArrayLike,
        y: ArrayLike,
        config: CoEAConfig | None = None,
        rng: np.random.Generator | int | None = None,
        *,
        warm_start: CoEAState | None = None,
        fixed_mask: NDArray[np.bool_] | None = None,
        input_names: tuple[str, ...] | None = None,
        output_name: str = "y",
        window: dict[str, Any] | None = None,
        normalisation: Normalisation | None = None,
        helper: EvalHelper | None = None,
        rows: NDArray[np.intp] | None = None,
        harmony_stop: float = HARMONY_STOP,
        hmcr: tuple[float, float] = HMCR,
        par: tuple[float, float] = PAR,
    ) -> None:
        cfg = CoEAConfig() if config is None else config
        if not _fraction(harmony_stop):
            raise ConfigError(f"harmony_stop must be a fraction of the generations in [0, 1]; got {harmony_stop!r}")
        for name, rates in (("hmcr", hmcr), ("par", par)):
            if not (isinstance(rates, (tuple, list)) and len(rates) == 2 and all(_fraction(r) for r in rates)):
                raise ConfigError(f"{name} must be a pair (first, last) of rates in [0, 1]; got {rates!r}")
        self._hmcr, self._par = (float(hmcr[0]), float(hmcr[1])), (float(par[0]), float(par[1]))
        if not isinstance(cfg, CoEAConfig):
            raise ConfigError(f"config must be a CoEAConfig; got {type(cfg).__name__}")
        self.config = cfg
        self._config_doc = cfg.to_dict()  # every model of the run records it (asdict is ~0.4 ms a call)
        self.rng = _as_rng(rng)
        ua, ya = as_data(u, y)
        L, M, P = cfg.max_lag, cfg.neurons, cfg.population
        need = L + 2 * M
        if ya.shape[0] < need:
            raise DataError(
                f"{ya.shape[0]} estimation samples are too few: with max lag {L} and {M} neurons at least "
                f"max_lag + 2 * neurons = {need} are needed"
            )
        self.u, self.y = ua, ya
        self.n_inputs = ua.shape[1]
        self.input_names = tuple(input_names) if input_names else tuple(f"u{i}" for i in range(self.n_inputs))
        if len(self.input_names) != self.n_inputs:
            raise ConfigError(f"{len(self.input_names)} input names given for {self.n_inputs} inputs")
        self.output_name = output_name
        self.window = dict(window) if window else {"n_samples": int(ya.shape[0])}
        self.norm = Normalisation.fit(ua, ya) if normalisation is None else normalisation
        if self.norm.n_inputs != self.n_inputs:
            raise ConfigError(
                f"the normalisation given has {self.norm.n_inputs} input(s); the data have {self.n_inputs}"
            )
        un, yn = self.norm.u(ua), self.norm.y(ya)
        self.R = lag_matrix(un, yn, cfg.max_lag_y, cfg.max_lag_u, min_lag_u=cfg.min_lag_u)
        self.target = yn[L:]
        self.candidates = candidate_regressors(cfg.max_lag_y, cfg.max_lag_u, self.n_inputs, cfg.min_lag_u)
        self.D = len(self.candidates)
        u_bits = np.array([c.signal == "u" for c in self.candidates], dtype=bool)
        self._u_bits: NDArray[np.bool_] | None = u_bits if (cfg.require_input and u_bits.any()) else None
        self.DX = (self.D + 1) * M
        self.scale = self.norm.y_half_range**2  # normalised MSE -> output units
        # The search's fitness may use a subset of the rows (large N); models are refitted on all of them.
        r_s, t_s = (self.R, self.target) if rows is None else (self.R[rows], self.target[rows])
        self._rows = rows
        self.search_rows = int(t_s.shape[0])
        # The search's fitness is the RBF network's alone: a linear part (linear_terms) enters when candidates
        # are fitted (searched with it, round 11 of docs/engine-results.md: the F-16 accel3 median 0.425 -> 0.298).
        self.evaluator = BatchEvaluator(r_s, t_s, M, P, RIDGE)
        self.lo = np.concatenate([np.full(M * self.D, cfg.centre_bounds[0]), np.full(M, cfg.width_bounds[0])])
        self.hi = np.concatenate([np.full(M * self.D, cfg.centre_bounds[1]), np.full(M, cfg.width_bounds[1])])
        self.generations = cfg.generations
        self.stop = int(round(float(harmony_stop) * cfg.generations))
        self.g = 0
        self.evaluations = 0
        self.history: list[float] = []
        self.best_f = np.inf
        self.best_h = np.zeros(self.D, dtype=bool)
        self.best_x = np.zeros(self.DX)
        self.seconds = 0.0
        self._n_de = de.TrialMaker.n_uniforms(P, self.DX)
        self._n_hs = harmony.n_uniforms(P, self.D)
        block = max(1, min(_BLOCK, cfg.generations, _BLOCK_VALUES // (self._n_de + self._n_hs)))
        self._trials = de.TrialMaker(P, self.DX, self.lo, self.hi, cfg.de_f, cfg.de_cr, block=block)
        self._improviser = harmony.Improviser(P, self.D, P, block=block)
        self._uni = np.empty(block * (self._n_de + self._n_hs))
        self._batch: BatchEvaluator | HelperBinding = self.evaluator  # or half of each batch in a helper
        if helper is not None:
            self._batch = helper.bind(r_s, t_s, M, P, RIDGE, self.evaluator,
                                      uniforms=self._uni.shape[0])
        self._k = self._planned = 0  # generation k of a planned block of `_planned`
        self._frozen: NDArray[np.bool_] | None = None
        self._frozen_key = -1
        t0 = time.perf_counter()
        with one_blas_thread():
            if fixed_mask is not None:
                if warm_start is not None:
                    raise ConfigError("fixed_mask and warm_start cannot be combined (a warm start brings its own lags)")
                mask = np.asarray(fixed_mask)
                if mask.shape != (self.D,) or mask.dtype != np.bool_:
                    raise ConfigError(f"fixed_mask must be a boolean array of shape ({self.D},); got {mask.dtype} {mask.shape}")
                self.stop = 0
                self._fixed_start(mask)
            elif warm_start is None:
                self._cold_start()
            else:
                self._warm_start(warm_start)
        self.seconds += time.perf_counter() - t0

    # ------------------------------------------------------------------ evaluation
    def _split(self, x: NDArray[np.float64]) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        M, D = self.config.neurons, self.D
        return x[:, : M * D].reshape(-1, M, D), x[:, M * D :]

    def _evaluate(
        self, masks: NDArray[np.bool_], x: NDArray[np.float64], shared: bool | None = None
    ) -> NDArray[np.float64]:
        c, s = self._split(x)
        f = self._batch.evaluate(masks, c, s, shared=shared) * self.scale  # type: ignore[operator]
        if self._u_bits is not None:  # require_input: a lag set without an input term is infeasible
            f = np.where(masks[:, self._u_bits].any(axis=1), f, np.inf)
        self.evaluations += masks.shape[0]
        i = int(f.argmin())
        if f[i] < self.best_f:
            self.best_f = float(f[i])
            self.best_h = masks[i].copy()
            self.best_x = x[i].copy()
        return f

    def _cold_start(self) -> None:
        P, rng = self.config.population, self.rng
        self.H = rng.random((P, self.D)) < 0.5
        self.X = rng.uniform(self.lo, self.hi, size=(P, self.DX))
        partner_h = rng.integers(0, P, size=P)
        partner_x = rng.integers(0, P, size=P)
        self.fx = self._evaluate(self.H[partner_h], self.X)
        self.fh = self._evaluate(self.H, self.X[partner_x])
        np.minimum.at(self.fh, partner_h, self.fx)

    def _fixed_start(self, mask: NDArray[np.bool_]) -> None:
        P = self.config.population
        self.H = np.tile(mask, (P, 1))
        self.X = self.rng.uniform(self.lo, self.hi, size=(P, self.DX))
        self.fx = self._evaluate(self._best_masks(0), self.X, shared=True)
        self.fh = np.full(P, float(self.fx.min()))

    def _warm_start(self, st: CoEAState) -> None:
        cfg = self.config
        want = (cfg.population, cfg.neurons, cfg.max_lag_y, cfg.max_lag_u, self.n_inputs, cfg.min_lag_u)
        got = (st.population, st.neurons, st.max_lag_y, st.max_lag_u, st.n_inputs, st.min_lag_u)
        if want != got:
            raise ConfigError(
                "warm_start state does not fit this run: (population, neurons, max_lag_y, max_lag_u, n_inputs, "
                f"min_lag_u) must be {want}; the state has {got}"
            )
        self.H = st.harmonies.copy()
        self.X = self._renormalise(st.params, st.normalisation)
        bx = self._renormalise(st.best_params[None, :], st.normalisation)
        bh = st.best_mask
        # Re-evaluate on the new data: X with the best harmony, H with the best parameters.
        self.fx = self._evaluate(np.broadcast_to(bh, self.H.shape), self.X)
        self.fh = self._evaluate(self.H, np.broadcast_to(bx, self.X.shape))

    def _renormalise(self, params: NDArray[np.float64], old: Normalisation) -> NDArray[np.float64]:
        """Move centres to the new data's normalisation (same physical place), clipped to the bounds."""
        x = np.array(params, dtype=np.float64)
        M, D = self.config.neurons, self.D
        old_lo, old_hi = self._ranges(old)
        new_lo, new_hi = self._ranges(self.norm)
        c = x[:, : M * D].reshape(-1, M, D)
        phys = (c + 1.0) * (0.5 * (old_hi - old_lo)) + old_lo
        c[...] = 2.0 * (phys - new_lo) / (new_hi - new_lo) - 1.0
        np.clip(x, self.lo, self.hi, out=x)
        return x

    def _ranges(self, norm: Normalisation) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """Physical low/high of every candidate coordinate under ``norm``."""
        cfg = self.config
        per_input = cfg.max_lag_u - cfg.min_lag_u + 1
        lo = np.concatenate([np.full(cfg.max_lag_y, norm.y_low), np.repeat(norm.u_low, per_input)])
        hi = np.concatenate([np.full(cfg.max_lag_y, norm.y_high), np.repeat(norm.u_high, per_input)])
        return lo, hi

    # ------------------------------------------------------------------ stepping
    def __iter__(self) -> Iterator[Progress]:
        return self

    def __next__(self) -> Progress:
        if self.g >= self.generations:
            raise StopIteration
        t0 = time.perf_counter()
        with one_blas_thread():
            self._generation()
        self.seconds += time.perf_counter() - t0
        return Progress(self.g, self.generations, self.best_f, self.evaluations)

    @property
    def done(self) -> bool:
        return self.g >= self.generations

    def _plan(self) -> None:
        """Draw the uniforms of the next block of generations and prepare their operators.

        A block holds up to ``_BLOCK`` generations (fewer when a generation needs
        many uniforms, see ``_BLOCK_VALUES``) and never straddles the end of
        the harmony phase. Row ``k`` of the block is generation ``g0 + k``'s
        uniforms: DE (donor keys, crossover, ``j_rand``), then, while the
        harmonies evolve, the improvisation's. The stream is therefore the same
        as one ``rng.random`` call per generation; only an early stop leaves
        drawn-but-unused rows behind. With a helper process, the helper draws
        the next block from a copy of the generator's state while the caller
        works, and the caller's generator is advanced past it (the same numbers;
        if anything else drew from the generator meanwhile, the caller draws).
        """
        g0 = self.g
        b, per = self._block(g0)
        evolving = g0 < self.stop
        helper = self._batch if isinstance(self._batch, HelperBinding) else None
        uni = None if helper is None else helper.take_uniforms(self.rng, b * per)  # drawn ahead, same numbers
        if uni is None:
            uni = self.rng.random(out=self._uni[: b * per])
        uni = uni.reshape(b, per)
        self._trials.plan(uni)
        if evolving:
            hmcr, par = harmony.schedule(np.arange(g0, g0 + b), self.generations, self._hmcr, self._par)
            self._improviser.plan(uni[:, self._n_de :], hmcr, par)
        if helper is not None and g0 + b < self.generations:  # the helper draws the next block meanwhile
            nb, nper = self._block(g0 + b)
            helper.request_uniforms(self.rng, nb * nper)
        self._k, self._planned = 0, b

    def _block(self, g0: int) -> tuple[int, int]:
        """Generations in the block starting at ``g0`` and uniforms per generation."""
        evolving = g0 < self.stop
        end = min(self.stop if evolving else self.generations, self.generations)
        return min(self._trials.block, end - g0), self._n_de + (self._n_hs if evolving else 0)

    def _generation(self) -> None:
        """One generation: DE trials for every member of X, paired with new harmonies
        (while they evolve) or the best harmony; evaluation; selection and memory update."""
        if self._k >= self._planned:
            self._plan()
        k = self._k
        self._k += 1
        evolving = self.g < self.stop
        trial = self._trials.make(self.X, k)
        b = int(self.fh.argmin())
        if evolving:
            masks = self._improviser.make(self.H, self.H[b], k)
        else:
            masks = self._best_masks(b)
        f = self._evaluate(masks, trial, shared=not evolving)
        de.select(self.X, self.fx, trial, f)
        if evolving:
            harmony.update_memory(self.H, self.fh, masks, f)
        else:
            fmin = float(f.min())
            if fmin < self.fh[b]:
                self.fh[b] = fmin
        self.g += 1
        self.history.append(self.best_f)

    def _best_masks(self, b: int) -> NDArray[np.bool_]:
        if self._frozen_key != b or self._frozen is None:
            self._frozen = np.broadcast_to(self.H[b].copy(), (self.config.population, self.D))
            self._frozen_key = b
        return self._frozen

    def solve(self, callback: Callable[[Progress], object] | None = None) -> Coevolution:
        """Run the remaining generations; ``callback(progress)`` after each, a truthy return stops early."""
        with one_blas_thread():
            while self.g < self.generations:
                t0 = time.perf_counter()
                self._generation()
                self.seconds += time.perf_counter() - t0
                if callback is not None and callback(Progress(self.g, self.generations, self.best_f, self.evaluations)):
                    break
        return self

    # ------------------------------------------------------------------ results
    def state(self) -> CoEAState:
        """Copy of both populations, their fitness and the best pair."""
        return CoEAState(
            harmonies=self.H.copy(),
            harmony_fitness=self.fh.copy(),
            params=self.X.copy(),
            param_fitness=self.fx.copy(),
            best_mask=self.best_h.copy(),
            best_params=self.best_x.copy(),
            best_fitness=float(self.best_f),
            neurons=self.config.neurons,
            max_lag_y=self.config.max_lag_y,
            max_lag_u=self.config.max_lag_u,
            n_inputs=self.n_inputs,
            normalisation=self.norm,
            generation=self.g,
            meta={"evaluations": self.evaluations},
            min_lag_u=self.config.min_lag_u,
        )

    def model_for(self, mask: NDArray[np.bool_], x: NDArray[np.float64], *, search_rows: bool = False) -> Model:
        """The model of one pair, weights refitted by SVD least squares on this run's data
        (``search_rows``: on the rows the search used only; a cheaper fit for screening candidates)."""
        M, D = self.config.neurons, self.D
        cols = np.flatnonzero(mask)
        R, target = self._fit_rows(search_rows)
        with one_blas_thread():
            if target.shape[0] > FIT_BLOCK_ROWS:
                return self._fitted_in_blocks(cols, x, R, target)
            phi = activations(R[:, cols], x[: M * D].reshape(M, D)[:, cols], x[M * D :])
            return self._fitted(cols, x, phi, R[:, cols], target)

    def _fitted_in_blocks(self, cols: NDArray[np.intp], x: NDArray[np.float64], R: NDArray[np.float64],
                          target: NDArray[np.float64], linear: bool | None = None, batch: bool = False) -> Model:
        """:meth:`_fitted` of a long record, its activations and regressors made :data:`~streamid.engine.rbf.
        FIT_BLOCK_ROWS` rows at a time (the streamed least squares :meth:`_fitted` also takes there: the same
        weights), never for every row at once: the final fit's memory does not grow with the window.
        ``batch``: the activations as :meth:`models_for` computes them (:func:`~streamid.engine.rbf.
        activations_batch`, equal to :func:`~streamid.engine.rbf.activations` within an ulp)."""
        M, D = self.config.neurons, self.D
        centres, widths = x[: M * D].reshape(M, D)[:, cols], x[M * D :]
        linear = self.config.linear_terms if linear is None else linear
        n = target.shape[0]

        def block(a: int, b: int) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
            r = np.ascontiguousarray(R[a:b, cols])
            if batch:
                return activations_batch(r, centres[None], widths[None])[0].T, r
            return activations(r, centres, widths), r

        def rows(a: int, b: int) -> NDArray[np.float64]:
            phi, r = block(a, b)
            return np.hstack([phi, r, np.ones((b - a, 1))]) if linear else phi

        z = streamed_fit(rows, n, M + (len(cols) + 1 if linear else 0), target, RIDGE)
        w, lin = (z[:M], z[M:]) if linear else (z, None)
        sse = 0.0
        for a in range(0, n, FIT_BLOCK_ROWS):
            b = min(n, a + FIT_BLOCK_ROWS)
            phi, r = block(a, b)
            fit = phi @ w if lin is None else phi @ w + r @ lin[:-1] + lin[-1]
            sse += float(np.sum((fit - target[a:b]) ** 2))
        return self._model(cols, x, w, lin, sse / n * self.scale)

    def models_for(self, mask: NDArray[np.bool_], xs: list[NDArray[np.float64]], *,
                   search_rows: bool = False, both: bool = False, threads: int = 1, in_blocks: bool = False,
                   ) -> list[Model]:
        """:meth:`model_for` of several parameter vectors with one mask, their activations computed
        together as the search computes them (:func:`~streamid.engine.rbf.activations_batch`).
        ``both`` (with ``linear_terms``): each vector's model with its linear part, then (after all
        of those, in the same order) the same centres and widths without one, weights refitted. ``threads``:
        the least squares in that many threads (the same models). ``in_blocks`` (a record of more than
        ``FIT_BLOCK_ROWS`` rows): each model fitted a block of rows at a time (:meth:`_fitted_in_blocks`),
        never every candidate's activations over every row at once."""
        if not xs:
            return []
        M, D = self.config.neurons, self.D
        cols = np.flatnonzero(mask)
        R, target = self._fit_rows(search_rows)
        kinds = (None, False) if both and self.config.linear_terms else (None,)
        if in_blocks and target.shape[0] > FIT_BLOCK_ROWS:
            with one_blas_thread():
                return thread_map(lambda j: self._fitted_in_blocks(cols, j[1], R, target, j[0], batch=True),
                                  [(kind, x) for kind in kinds for x in xs], threads)
        X = np.stack(xs)
        with one_blas_thread():
            rs = np.ascontiguousarray(R[:, cols])
            phis = activations_batch(rs, X[:, : M * D].reshape(-1, M, D)[:, :, cols], X[:, M * D :])
            jobs = [(kind, x, phi) for kind in kinds for x, phi in zip(xs, phis)]
            return thread_map(lambda j: self._fitted(cols, j[1], j[2].T, rs, target, linear=j[0]), jobs, threads)

    def _fit_rows(self, search_rows: bool) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        if search_rows and self._rows is not None:
            return self.R[self._rows], self.target[self._rows]
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
        """Model of the best pair ever evaluated, weights refitted (see :func:`~streamid.engine.rbf.fit_weights`)."""
        if not np.isfinite(self.best_f):
            raise DataError("no pair has been evaluated")
        return self.model_for(self.best_h, self.best_x)


def _fraction(value: object) -> bool:
    """Whether ``value`` is a number (not a bool) in [0, 1]."""
    return not isinstance(value, bool) and isinstance(value, (int, float)) and 0 <= value <= 1


def _as_rng(rng: np.random.Generator | int | None) -> np.random.Generator:
    if isinstance(rng, np.random.Generator):
        return rng
    if rng is None:
        return np.random.default_rng(0)
    if isinstance(rng, (int, np.integer)) and not isinstance(rng, bool) and int(rng) >= 0:
        return np.random.default_rng(int(rng))
    raise ConfigError(f"rng must be a numpy.random.Generator or a non-negative integer seed; got {rng!r}")
