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

from streamid.engine.search import de, harmony
from streamid.engine.fit.blas import one_blas_thread
from streamid.engine.settings import HARMONY_STOP, HMCR, PAR, RIDGE, CoEAConfig
from streamid.engine.search.parallel import EvalHelper, HelperBinding
from streamid.engine.search.batch import BatchEvaluator
from streamid.engine.search.candidates import CandidateModels
from streamid.model.regressors import Normalisation, as_data
from streamid.engine.fit.lagmatrix import candidate_regressors, lag_rows
from streamid.engine.search.populations import STATE_FORMAT, CoEAState
from streamid.errors import ConfigError, DataError

__all__ = ["CoEAState", "Coevolution", "Progress", "STATE_FORMAT"]

#: Generations whose random numbers are drawn and turned into DE donors, crossover
#: masks and improvisation masks at once (see :meth:`Coevolution._plan`), at most
#: ``_BLOCK_VALUES`` uniforms (2 MiB) per block. Results do not depend on either.
_BLOCK = 50
_BLOCK_VALUES = 1 << 18

class Progress(NamedTuple):
    """What one generation reports: its number (1-based count done), the best fitness, evaluations so far; and
    ``stage``: "search" while generations run, then what an identification does after them ("choice": the kept
    model's size, ensemble, refinement and interval; a command adds its own, e.g. "validation")."""

    generation: int
    generations: int
    best_fitness: float
    evaluations: int
    stage: str = "search"


class Coevolution(CandidateModels):
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
        see :mod:`streamid.engine.search.parallel`); the result is the same without it.
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
        ua, ya = as_data(u, y, copy=False)  # read only: normalised below, not kept
        L, M, P = cfg.max_lag, cfg.neurons, cfg.population
        need = L + 2 * M
        if ya.shape[0] < need:
            raise DataError(
                f"{ya.shape[0]} estimation samples are too few: with max lag {L} and {M} neurons at least "
                f"max_lag + 2 * neurons = {need} are needed"
            )
        # (the record itself is not kept: its normalised copy below is what the run uses)
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
        del ua, ya  # the record's copy goes: the run keeps its normalised one (memory of a long record)
        self._lag_data = (un, yn)
        # every row's regressors (all candidate lags) only when the search uses every row; otherwise its sample's
        # rows, and a block of rows at a time for the fits (the property R makes them all, once, if asked)
        self._R: NDArray[np.float64] | None = None
        self.target = yn[L:]
        self.candidates = candidate_regressors(cfg.max_lag_y, cfg.max_lag_u, self.n_inputs, cfg.min_lag_u)
        self.D = len(self.candidates)
        u_bits = np.array([c.signal == "u" for c in self.candidates], dtype=bool)
        self._u_bits: NDArray[np.bool_] | None = u_bits if (cfg.require_input and u_bits.any()) else None
        self.DX = (self.D + 1) * M
        self.scale = self.norm.y_half_range**2  # normalised MSE -> output units
        # The search's fitness may use a subset of the rows (large N); models are refitted on all of them.
        r_s, t_s = (self.R, self.target) if rows is None else (
            lag_rows(un, yn, cfg.max_lag_y, cfg.max_lag_u, rows, min_lag_u=cfg.min_lag_u), self.target[rows])
        self._rows, self._search = rows, (r_s, t_s)
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
