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
  trial for every member of ``X``; while ``g < round(harmony_stop * G)`` trial
  ``i`` is paired with newly improvised harmony ``i``, afterwards with the best
  harmony (``H`` stops evolving); the P pairs are evaluated at once; DE
  selection for ``X``, memory update for ``H``.
* Credit: a harmony used as a partner by other evaluations keeps the best
  fitness any of them achieved (so the best harmony and the best pair agree).
* Result: the best pair ever evaluated; :meth:`Coevolution.best_model`
  refits its weights accurately (SVD).
"""

from __future__ import annotations

import json
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, NamedTuple

import numpy as np
from numpy.typing import ArrayLike, NDArray
from threadpoolctl import threadpool_limits

from streamid.engine import de, harmony
from streamid.engine.config import CoEAConfig
from streamid.engine.model import Model
from streamid.engine.rbf import BatchEvaluator, activations, fit_weights
from streamid.engine.regressors import Normalisation, as_data, candidate_regressors, lag_matrix
from streamid.errors import ConfigError, DataError, ModelFormatError

__all__ = ["CoEAState", "Coevolution", "Progress", "STATE_FORMAT"]

STATE_FORMAT = "streamid.coea_state/1"


class Progress(NamedTuple):
    """What one generation reports: its number (1-based count done), the best fitness, evaluations so far."""

    generation: int
    generations: int
    best_fitness: float
    evaluations: int


@dataclass(frozen=True, eq=False)
class CoEAState:
    """Exportable state of a coevolution: both populations, their fitness and the best pair.

    Fitness values are in the output units of the data the run saw; a warm
    start re-evaluates everything on its own data.
    """

    harmonies: NDArray[np.bool_]  # (P, D_H)
    harmony_fitness: NDArray[np.float64]  # (P,)
    params: NDArray[np.float64]  # (P, D_X)
    param_fitness: NDArray[np.float64]  # (P,)
    best_mask: NDArray[np.bool_]  # (D_H,)
    best_params: NDArray[np.float64]  # (D_X,)
    best_fitness: float
    neurons: int
    max_lag_y: int
    max_lag_u: int
    n_inputs: int
    normalisation: Normalisation
    generation: int = 0
    meta: dict[str, Any] = field(default_factory=dict)

    def __post_init__(self) -> None:
        P, D = np.shape(self.harmonies)
        dx = (D + 1) * self.neurons
        checks = [
            (np.shape(self.harmony_fitness) == (P,), "harmony_fitness", (P,)),
            (np.shape(self.params) == (P, dx), "params", (P, dx)),
            (np.shape(self.param_fitness) == (P,), "param_fitness", (P,)),
            (np.shape(self.best_mask) == (D,), "best_mask", (D,)),
            (np.shape(self.best_params) == (dx,), "best_params", (dx,)),
        ]
        for ok, name, shape in checks:
            if not ok:
                raise ModelFormatError(f"CoEAState.{name} must have shape {shape}; got {np.shape(getattr(self, name))}")
        if D != self.max_lag_y + self.n_inputs * self.max_lag_u:
            raise ModelFormatError(
                f"CoEAState has {D} candidate lags but max_lag_y + n_inputs * max_lag_u = "
                f"{self.max_lag_y} + {self.n_inputs} * {self.max_lag_u}"
            )
        for name in ("harmony_fitness", "params", "param_fitness", "best_params"):
            if not np.all(np.isfinite(getattr(self, name))):
                raise ModelFormatError(f"CoEAState.{name} must contain only finite numbers")
        if not np.isfinite(self.best_fitness):
            raise ModelFormatError(f"CoEAState.best_fitness must be finite; got {self.best_fitness!r}")

    @property
    def population(self) -> int:
        return int(self.harmonies.shape[0])

    def to_dict(self) -> dict[str, Any]:
        return {
            "format": STATE_FORMAT,
            "neurons": self.neurons,
            "max_lag_y": self.max_lag_y,
            "max_lag_u": self.max_lag_u,
            "n_inputs": self.n_inputs,
            "generation": self.generation,
            "normalisation": self.normalisation.to_dict(),
            "harmonies": self.harmonies.astype(int).tolist(),
            "harmony_fitness": self.harmony_fitness.tolist(),
            "params": self.params.tolist(),
            "param_fitness": self.param_fitness.tolist(),
            "best_mask": self.best_mask.astype(int).tolist(),
            "best_params": self.best_params.tolist(),
            "best_fitness": self.best_fitness,
            "meta": self.meta,
        }

    def to_json(self) -> str:
        """JSON text, ``"format": "streamid.coea_state/1"``."""
        return json.dumps(self.to_dict(), allow_nan=False)

    @classmethod
    def from_dict(cls, d: Any) -> CoEAState:
        if not isinstance(d, dict) or d.get("format") != STATE_FORMAT:
            got = d.get("format") if isinstance(d, dict) else type(d).__name__
            raise ModelFormatError(f"a coevolution state must be a JSON object with format {STATE_FORMAT!r}; got {got!r}")
        try:
            return cls(
                harmonies=np.array(d["harmonies"], dtype=np.int64).astype(bool),
                harmony_fitness=np.array(d["harmony_fitness"], dtype=np.float64),
                params=np.array(d["params"], dtype=np.float64),
                param_fitness=np.array(d["param_fitness"], dtype=np.float64),
                best_mask=np.array(d["best_mask"], dtype=np.int64).astype(bool),
                best_params=np.array(d["best_params"], dtype=np.float64),
                best_fitness=float(d["best_fitness"]),
                neurons=int(d["neurons"]),
                max_lag_y=int(d["max_lag_y"]),
                max_lag_u=int(d["max_lag_u"]),
                n_inputs=int(d["n_inputs"]),
                normalisation=Normalisation.from_dict(d["normalisation"]),
                generation=int(d.get("generation", 0)),
                meta=dict(d.get("meta", {})),
            )
        except ModelFormatError:
            raise
        except (KeyError, TypeError, ValueError) as exc:
            raise ModelFormatError(f"coevolution state has a missing or malformed field: {type(exc).__name__}: {exc}") from None

    @classmethod
    def from_json(cls, text: str | bytes) -> CoEAState:
        try:
            d = json.loads(text)
        except (json.JSONDecodeError, UnicodeDecodeError, TypeError) as exc:
            raise ModelFormatError(f"a coevolution state must be JSON text; parsing failed: {exc}") from None
        return cls.from_dict(d)

    def save_npz(self, path: str | Path) -> None:
        """Write as ``.npz`` (arrays + a JSON header; loads with ``allow_pickle=False``)."""
        header = {k: v for k, v in self.to_dict().items() if k not in _ARRAYS}
        np.savez(
            path,
            header=np.array(json.dumps(header)),
            **{k: getattr(self, k) for k in _ARRAYS},
        )

    @classmethod
    def load_npz(cls, path: str | Path) -> CoEAState:
        try:
            with np.load(path, allow_pickle=False) as z:
                d = json.loads(str(z["header"]))
                for k in _ARRAYS:
                    d[k] = z[k].tolist()
        except (OSError, ValueError, KeyError) as exc:
            raise ModelFormatError(f"{path}: not a streamid coevolution state .npz ({exc})") from None
        return cls.from_dict(d)


_ARRAYS = ("harmonies", "harmony_fitness", "params", "param_fitness", "best_mask", "best_params")


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
    normalisation : Normalisation, optional
        Use this normalisation instead of the min/max of ``u``, ``y`` (e.g. the
        min/max of a larger estimation set this run sees a part of).

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
        input_names: tuple[str, ...] | None = None,
        output_name: str = "y",
        window: dict[str, Any] | None = None,
        normalisation: Normalisation | None = None,
    ) -> None:
        cfg = CoEAConfig() if config is None else config
        if not isinstance(cfg, CoEAConfig):
            raise ConfigError(f"config must be a CoEAConfig; got {type(cfg).__name__}")
        self.config = cfg
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
        self.R = lag_matrix(un, yn, cfg.max_lag_y, cfg.max_lag_u)
        self.target = yn[L:]
        self.candidates = candidate_regressors(cfg.max_lag_y, cfg.max_lag_u, self.n_inputs)
        self.D = len(self.candidates)
        self.DX = (self.D + 1) * M
        self.scale = self.norm.y_half_range**2  # normalised MSE -> output units
        self.evaluator = BatchEvaluator(self.R, self.target, M, P, cfg.ridge, cfg.weight_decay)
        self.lo = np.concatenate([np.full(M * self.D, cfg.centre_bounds[0]), np.full(M, cfg.width_bounds[0])])
        self.hi = np.concatenate([np.full(M * self.D, cfg.centre_bounds[1]), np.full(M, cfg.width_bounds[1])])
        self.generations = cfg.generations
        self.stop = int(round(cfg.harmony_stop * cfg.generations))
        self.g = 0
        self.evaluations = 0
        self.history: list[float] = []
        self.best_f = np.inf
        self.best_h = np.zeros(self.D, dtype=bool)
        self.best_x = np.zeros(self.DX)
        self.seconds = 0.0
        self._trials = de.TrialMaker(P, self.DX, self.lo, self.hi, cfg.de_f, cfg.de_cr)
        self._n_de = de.TrialMaker.n_uniforms(P, self.DX)
        self._n_hs = harmony.n_uniforms(P, self.D)
        self._frozen: NDArray[np.bool_] | None = None
        self._frozen_key = -1
        t0 = time.perf_counter()
        with threadpool_limits(limits=1, user_api="blas"):
            if warm_start is None:
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
        f = self.evaluator.evaluate(masks, c, s, shared=shared) * self.scale  # type: ignore[operator]
        self.evaluations += masks.shape[0]
        i = int(np.argmin(f))
        if f[i] < self.best_f:
            self.best_f = float(f[i])
            self.best_h = masks[i].copy()
            self.best_x = x[i].copy()
        return f  # type: ignore[no-any-return]

    def _cold_start(self) -> None:
        P, rng = self.config.population, self.rng
        self.H = rng.random((P, self.D)) < 0.5
        self.X = rng.uniform(self.lo, self.hi, size=(P, self.DX))
        partner_h = rng.integers(0, P, size=P)
        partner_x = rng.integers(0, P, size=P)
        self.fx = self._evaluate(self.H[partner_h], self.X)
        self.fh = self._evaluate(self.H, self.X[partner_x])
        np.minimum.at(self.fh, partner_h, self.fx)

    def _warm_start(self, st: CoEAState) -> None:
        cfg = self.config
        want = (cfg.population, cfg.neurons, cfg.max_lag_y, cfg.max_lag_u, self.n_inputs)
        got = (st.population, st.neurons, st.max_lag_y, st.max_lag_u, st.n_inputs)
        if want != got:
            raise ConfigError(
                "warm_start state does not fit this run: (population, neurons, max_lag_y, max_lag_u, n_inputs) "
                f"must be {want}; the state has {got}"
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
        lo = np.concatenate([np.full(cfg.max_lag_y, norm.y_low), np.repeat(norm.u_low, cfg.max_lag_u)])
        hi = np.concatenate([np.full(cfg.max_lag_y, norm.y_high), np.repeat(norm.u_high, cfg.max_lag_u)])
        return lo, hi

    # ------------------------------------------------------------------ stepping
    def __iter__(self) -> Iterator[Progress]:
        return self

    def __next__(self) -> Progress:
        if self.g >= self.generations:
            raise StopIteration
        t0 = time.perf_counter()
        with threadpool_limits(limits=1, user_api="blas"):
            self._generation()
        self.seconds += time.perf_counter() - t0
        return Progress(self.g, self.generations, self.best_f, self.evaluations)

    @property
    def done(self) -> bool:
        return self.g >= self.generations

    def _generation(self) -> None:
        """One generation. Draws one block of uniforms: DE (donor keys, crossover,
        ``j_rand``), then, while the harmonies evolve, the improvisation's."""
        cfg, P = self.config, self.config.population
        evolving = self.g < self.stop
        n_de = self._n_de
        uni = self.rng.random(n_de + (self._n_hs if evolving else 0))
        trial = self._trials(self.X, uni[:n_de])
        b = int(np.argmin(self.fh))
        if evolving:
            hmcr, par = harmony.schedule(self.g, self.generations, cfg.hmcr0, cfg.hmcrf, cfg.par0, cfg.parf)
            masks = harmony.improvise_from_uniforms(self.H, self.H[b], hmcr, par, uni[n_de:], P)
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
        with threadpool_limits(limits=1, user_api="blas"):
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
        )

    def model_for(self, mask: NDArray[np.bool_], x: NDArray[np.float64]) -> Model:
        """The model of one pair, weights refitted by SVD least squares on this run's data."""
        M, D = self.config.neurons, self.D
        cols = np.flatnonzero(mask)
        centres = x[: M * D].reshape(M, D)[:, cols]
        widths = x[M * D :]
        with threadpool_limits(limits=1, user_api="blas"):
            phi = activations(self.R[:, cols], centres, widths)
            w = fit_weights(phi, self.target, self.config.ridge, self.config.weight_decay)
            mse = float(np.mean((phi @ w - self.target) ** 2)) * self.scale
        if not np.all(np.isfinite(w)) or not np.isfinite(mse):
            raise DataError("the least-squares weights are not finite (the data are numerically degenerate)")
        return Model(
            regressors=tuple(self.candidates[j] for j in cols),
            centres=centres,
            widths=widths.copy(),
            weights=w,
            normalisation=self.norm,
            input_names=self.input_names,
            output_name=self.output_name,
            metrics={"fitness": mse, "fitness_search": float(self.best_f), "evaluations": self.evaluations},
            window=self.window,
            config=self.config.to_dict(),
        )

    def population_models(self) -> list[Model]:
        """Models of every parameter vector paired with the best harmony, weights refitted.

        Candidates for a choice by another criterion than the fitness (e.g. free-run R^2):
        in the second half of a run every member of ``X`` evolved with the best harmony.
        """
        b = int(np.argmin(self.fh))
        return [self.model_for(self.H[b], self.X[i]) for i in range(self.X.shape[0])]

    def best_model(self) -> Model:
        """Model of the best pair ever evaluated, weights refitted (see :func:`~streamid.engine.rbf.fit_weights`)."""
        if not np.isfinite(self.best_f):
            raise DataError("no pair has been evaluated")
        return self.model_for(self.best_h, self.best_x)


def _as_rng(rng: np.random.Generator | int | None) -> np.random.Generator:
    if isinstance(rng, np.random.Generator):
        return rng
    if rng is None:
        return np.random.default_rng(0)
    if isinstance(rng, (int, np.integer)) and not isinstance(rng, bool) and int(rng) >= 0:
        return np.random.default_rng(int(rng))
    raise ConfigError(f"rng must be a numpy.random.Generator or a non-negative integer seed; got {rng!r}")
