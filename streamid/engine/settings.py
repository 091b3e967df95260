"""Configuration of one coevolutionary identification (frozen, validated).

:class:`CoEAConfig` holds the settings of the method of the paper (Table 3 and
section 6) plus the few choices streamid adds (regularisation of the least
squares of the search, the multi-start strategy of :func:`~streamid.engine.identification.identify`).
Every field is checked in ``__post_init__``; a bad value raises
:class:`~streamid.errors.ConfigError` naming the field, the accepted form and the value.
"""

from __future__ import annotations

import math
from collections.abc import Iterable
from dataclasses import asdict, dataclass, fields, replace
from typing import Any

from streamid.errors import ConfigError

__all__ = ["CoEAConfig", "PAPER", "DEFAULT", "FALLBACK_BELOW", "HMCR", "MORE_BELOW", "PAR", "REFINE_ABOVE", "RIDGE",
           "SELECTIONS"]

#: Relative Tikhonov term of every least squares of the weights (the search's batched normal equations, scaled to
#: unit diagonal, and the final models' QR fits; :mod:`streamid.engine.fit.rbf`): bounds the condition number at
#: ``(M + RIDGE) / RIDGE`` (1e11 for ten neurons) and is too small to move a fit (no preset ever set another value).
RIDGE = 1e-10

#: With ``more_restarts``: more runs are made while the best run's estimation free-run R^2 lies in ``(0, MORE_BELOW)``
#: (:func:`streamid.engine.restarts.wants_more`); also the band under which the long linear part competes. 0.95 lies
#: between the heat exchanger's and the F-16's best runs, 0.90-0.92 and 0.12-0.73, which gained, and Bouc-Wen's and
#: the MR damper's, 0.975-0.987.
MORE_BELOW = 0.95

#: With ``fallback_neurons``: the fallback runs are made when no run is admissible or the best run's estimation
#: free-run R^2 is at most this (the record is hardly explained: a smaller network may generalise where the large one
#: did not). The defaults' only value; the paper's procedure has no fallback runs.
FALLBACK_BELOW = 0.5

#: The refinement's gate (:mod:`streamid.engine.choice.refine`): a model is refined only when its estimation free-run R^2 is
#: at least this; 0.8 lies between the F-16's highest (0.73, harmed) and the heat exchanger's lowest (0.91, helped).
REFINE_ABOVE = 0.8

#: The fraction of a run's generations after which its lags stop evolving (the paper's 0.5; no preset, stream or
#: measurement set another value; the lag stage of a two-stage run evolves them throughout: ``harmony_stop=1.0``).
HARMONY_STOP = 0.5

#: The harmony memory consideration rate and pitch adjusting rate, each moved linearly from the first value to the
#: second over a run's generations (the paper's Table 3, eqs. 10a-b; no preset, stream or measurement set others:
#: ``Coevolution(..., hmcr=(a, b), par=(c, d))`` for one run).
HMCR = (0.8, 1.0)
PAR = (0.1, 0.9)

#: Values of ``CoEAConfig.direct_terms``: the inputs' direct terms u(t) never, always or by a test of the data.
DIRECT_TERMS = ("off", "on", "test")

#: Ways :func:`~streamid.engine.identification.identify` chooses among restarts.
SELECTIONS = ("fr_est", "fitness")


#: Fields of earlier versions retired in issue 37 that something else now says, and what (named in the refusal).
REPLACED_BY = {
    "ridge": "the constant streamid.engine.settings.RIDGE (1e-10)",
    "more_below": "the constant streamid.engine.settings.MORE_BELOW (0.95)",
    "fallback_below": "the constant streamid.engine.settings.FALLBACK_BELOW (0.5)",
    "workers": "identify(..., workers=N) (how the restarts are run, not a setting of the method)",
    "min_lag_u": 'direct_terms ("on": u(t) a candidate, min_lag_u 0; "off": min_lag_u 1)',
    "feedthrough_test": 'direct_terms = "test"',
    "harmony_stop": "the constant streamid.engine.settings.HARMONY_STOP (0.5, the paper's; "
                    "Coevolution(..., harmony_stop=F) for one run)",
    **{f"{c.lower()}{end}": f"the constant streamid.engine.settings.{c} {v} (the paper's schedule from the first "
       f"value to the second; Coevolution(..., {c.lower()}=(a, b)) for one run)"
       for c, v in (("HMCR", HMCR), ("PAR", PAR)) for end in ("0", "f")},
}

#: Every retired field: those measured not to earn their place, then those something else replaced (above).
RETIRED_FIELDS = ("holdout_fraction", "cv_folds", "neuron_alternatives", "agree_tol", "linear_alternation",
                  "lag_search_rows", "ensemble", "weight_decay", "linear_search", "lag_search_generations",
                  "lag_alternation", "hedge_neurons", "range_margin", "refine_above", "screen_rows", "complexity",
                  *REPLACED_BY)


def retired_message(names: list[str]) -> str:
    """Why these retired ``CoEAConfig`` fields are refused, and what replaced those that something replaced."""
    gone = [n for n in names if n not in REPLACED_BY]
    parts = []
    if gone:
        parts.append(f"CoEAConfig field(s) {gone} were retired in issue 37 (measured not to earn their place: "
                     f"docs/engine-results.md, 'Issue 37', rounds 2-5); remove them")
    parts += [f"CoEAConfig.{n} was retired in issue 37: use {REPLACED_BY[n]}" for n in names if n in REPLACED_BY]
    return "; ".join(parts)


def _int(name: str, value: object, low: int, high: int | None = None) -> int:
    if isinstance(value, int) and not isinstance(value, bool) and value >= low and (high is None or value <= high):
        return int(value)
    rng = f">= {low}" if high is None else f"in [{low}, {high}]"
    raise ConfigError(f"CoEAConfig.{name} must be an integer {rng}; got {value!r}")


def _float(name: str, value: object, low: float, high: float, *, open_low: bool = False) -> float:
    try:
        v = float(value)  # type: ignore[arg-type]
    except (TypeError, ValueError):
        v = math.nan
    bad = isinstance(value, bool) or not math.isfinite(v) or v > high or v < low or (open_low and v == low)
    if bad:
        lo = "(" if open_low else "["
        raise ConfigError(f"CoEAConfig.{name} must be a number in {lo}{low}, {high}]; got {value!r}")
    return v


def _bounds(name: str, value: object, positive: bool) -> tuple[float, float]:
    try:
        if not isinstance(value, Iterable):
            raise TypeError(f"not iterable: {type(value).__name__}")
        lo, hi = (float(v) for v in value)
    except (TypeError, ValueError):
        lo = hi = math.nan
    if not (math.isfinite(lo) and math.isfinite(hi) and lo < hi and (lo > 0 or not positive)):
        form = "0 < low < high" if positive else "low < high"
        raise ConfigError(f"CoEAConfig.{name} must be a pair (low, high) of finite numbers with {form}; got {value!r}")
    return (lo, hi)


#: Integer fields and their accepted ranges (None: no upper bound), checked in this order.
_INT_RANGES: dict[str, tuple[int, int | None]] = {
    "neurons": (1, 1000), "max_lag_y": (0, 1000), "max_lag_u": (0, 1000), "generations": (0, None),
    "population": (4, 10000), "lag_search_neurons": (0, 1000),
    "restarts": (1, 10000), "search_rows": (0, None),
    "fr_candidates": (0, 10000),
    "prune_runs": (0, 10000), "more_restarts": (0, 100), "refine_iterations": (0, 1000),
    "long_linear": (0, 1000), "max_lag_cap": (0, 1000),
}
#: Number fields: (low, high, whether low itself is refused).
_FLOAT_RANGES: dict[str, tuple[float, float, bool]] = {
    "de_f": (0.0, 2.0, True), "de_cr": (0.0, 1.0, False),
}
#: Fields that must be true or false.
_BOOL_FIELDS = ("linear_terms", "run_ensembles", "require_input")


@dataclass(frozen=True)
class CoEAConfig:
    """Settings of a coevolutionary RBF-NARX identification.

    The defaults of the method's own parameters are the paper's (Table 3):
    10 candidate lags on the output and on every input, populations of 20,
    DE/rand/1/bin with F = 0.6 and CR = 0.8, centres in [-4, 4] and widths in
    [0.01, 20] (data normalised to [-1, 1]); the harmony search's HMCR 0.8 -> 1.0
    and PAR 0.1 -> 0.9 are constants (:data:`HMCR`, :data:`PAR`).

    Attributes
    ----------
    neurons : int
        Number M of Gaussian neurons of the RBF network.
    max_lag_y : int
        Candidate output lags 1..max_lag_y (0 allowed: a NFIR model).
    max_lag_u : int
        Candidate lags 1..max_lag_u of every input.
    generations : int
        Generations G of one coevolution run (one DE trial per parameter
        member per generation: ``population * (generations + 2)`` evaluations).
    population : int
        Size of both populations (lag harmonies H and parameter vectors X), >= 4
        (DE/rand/1 needs three partners distinct from the target).
    de_f, de_cr : float
        DE scale factor F and crossover probability CR.
    centre_bounds, width_bounds : tuple of float
        Search ranges of the centres and widths (normalised units).
    lag_search_neurons : int
        0 (the paper): lags, centres and widths coevolve in one run of ``generations``. > 0: a two-stage run
        (:func:`~streamid.engine.identification.identify`): the paper's coevolution with this many neurons
        (its lag population evolving throughout) chooses the lags, then ``generations`` of DE search the centres
        and widths of ``neurons`` neurons for them (the large network, whose least squares cost grows with
        ``neurons^2``, is only trained on the lags the cheap one found).
    restarts : int
        Independent coevolution runs made by :func:`~streamid.engine.identification.identify`;
        the final model is chosen among them (see ``selection``).
    selection : str
        With ``restarts > 1``, how the final run is chosen: ``"fr_est"`` the
        highest free-run R^2 on the estimation data (all runs search on all of
        it), ``"fitness"`` the lowest OSA MSE. Validation data are never used.
    search_rows : int
        0: the search's fitness (OSA MSE) uses every row of the estimation data.
        > 0: each run draws this many rows at random (its own generator) and
        searches on them alone; every candidate model is then fitted and scored
        on all the rows. Large records cost the search no more than this many rows.
    fr_candidates : int
        With a free-run selection: the candidates of a run are its best pair and
        this many members of its final population, those of lowest fitness
        (0 = every member).
    direct_terms : str
        Whether each input's direct term ``u(t)`` is a candidate lag (an output that responds within the
        sample, as an accelerometer to a force or a sampled record whose output is read after the input was
        set): ``"off"`` (the paper: ``u(t-1) .. u(t-max_lag_u)``), ``"on"`` (``u(t) .. u(t-max_lag_u)``) or
        ``"test"``: decided from the estimation data before the runs (:mod:`streamid.engine.search.feedthrough`: a
        likelihood-ratio test of the direct terms in a linear ARX model; evidence in ``metrics.feedthrough``;
        the model's configuration then says ``"on"`` or ``"off"``). The first candidate lag is
        :attr:`min_lag_u`.
    more_restarts : int
        0: ``restarts`` runs. N > 0: N more runs (new seeds, the same pattern of lag spaces and sizes) when the
        best run's estimation free-run R^2 lies in ``(0, MORE_BELOW)`` (0.95), where the estimation data tell the
        runs apart least reliably (:func:`streamid.engine.restarts.wants_more`; ``metrics.more_restarts``).
    max_lag_cap : int
        0: candidate lags ``1..max_lag_y`` and ``1..max_lag_u``. > 0 (with restarts or a
        two-stage run, :func:`~streamid.engine.identification.identify`): the maximum lag
        ``L`` is chosen from the estimation data between ``max(max_lag_y, max_lag_u)``
        and this cap (:mod:`streamid.engine.search.lagspace`), and both use ``1..L``. When that ``L`` is at least
        twice the floor ``max(max_lag_y, max_lag_u)`` the odd restarts use ``1..floor`` instead, restart 1 of
        every 4 with ``lag_search_neurons`` neurons (when > 0), and the final choice decides between the two lag
        spaces (a hedge: a long lag space fits some records' estimation data better and their validation data
        worse).
    fallback_neurons : tuple of int
        With a free-run selection: when no run has an admissible candidate (every
        free run leaves the data's range or ignores the input), one more run with
        each of these numbers of neurons, in order, until one has (a smaller
        network extrapolates less wildly); also while the best run's estimation free-run R^2 is at
        most :data:`FALLBACK_BELOW` (0.5). Empty: the smallest excursion is taken.
    linear_terms : bool
        False (the paper): the network is ``sum_m w_m phi_m``. True: every candidate is offered also with a
        direct linear part, ``sum_m w_m phi_m(r) + a' r + b`` over the same regressors (Chen & Billings),
        fitted with ``w`` in one least squares; a run keeps the admissible candidate of the lowest AIC
        (:mod:`streamid.engine.choice.complexity`; ``p`` counts the linear part's ``k + 1`` weights).
    prune_runs : int
        With ``selection="fr_est"``: 0, each run offers its chosen candidate as is. K > 0,
        the K best runs by AIC also offer their networks of ``M // 3`` and
        ``2 M // 3`` neurons (the first in forward-selection order by orthogonal least
        squares on the estimation data, weights refitted); each competes with its parent
        by AIC on the estimation free run (range guard included), then the runs
        as before. Evidence in ``metrics.neuron_choice`` and ``metrics.complexity``.
    run_ensembles : bool
        With ``selection="fr_est"`` and several runs: True, after that choice the means of the top 2, the top 3
        and all admissible runs' networks (ranked by AIC) compete by AIC on the estimation free run of the mean
        (:mod:`streamid.engine.choice.ensemble_choice`; a ``streamid.model/3`` model; ``metrics.complexity.ensembles``);
        then, unless the model so chosen carries a long linear part, the per-sample median of the admissible runs'
        networks, each finished as a kept model is (at least three: :mod:`streamid.engine.choice.robust`; a
        ``streamid.model/6`` model; ``metrics.robust``) replaces it (issue 51: robust by default).
    refine_iterations : int
        0 (the paper): the final model's weights are the search's one-step least squares. N > 0:
        at most N Levenberg-Marquardt iterations fit them to the model's free run on the estimation
        record (:mod:`streamid.engine.choice.refine`; centres, widths and lags kept), when that free run's
        R^2 is at least 0.8 (:data:`streamid.engine.choice.refine.ABOVE`); kept only if the whole record's free run is then better
        and within the range guard (evidence in ``metrics.refinement``).
    long_linear : int
        0 (the paper): off. N > 0: the final choice's network with a dense linear ARX part of order
        up to N (chosen by AIC) competes with it, and so do the means of the two and
        three best such candidates (a ``streamid.model/5`` model) (:mod:`streamid.engine.choice.longlinear`;
        :func:`~streamid.engine.identification.identify`'s final choice; an online update's model gets a single
        network's part, of an order above its lag search's only: :func:`streamid.online.update.long_linear_part`).
    require_input : bool
        False (the paper): any lag set may be searched. True: a lag set without an
        input term is infeasible (fitness +inf): on an oscillating output an
        autoregression of ``y`` alone predicts one step ahead well, wins the lag
        search, and then ignores the input in free run (the final choice never
        admits it, :mod:`streamid.engine.choice.scores`).
    """

    neurons: int = 10
    max_lag_y: int = 10
    max_lag_u: int = 10
    generations: int = 400
    population: int = 20
    de_f: float = 0.6
    de_cr: float = 0.8
    centre_bounds: tuple[float, float] = (-4.0, 4.0)
    width_bounds: tuple[float, float] = (0.01, 20.0)
    lag_search_neurons: int = 0
    restarts: int = 1
    selection: str = "fitness"
    search_rows: int = 0
    fr_candidates: int = 0
    require_input: bool = False
    max_lag_cap: int = 0
    fallback_neurons: tuple[int, ...] = ()
    linear_terms: bool = False
    prune_runs: int = 0
    more_restarts: int = 0
    direct_terms: str = "off"
    run_ensembles: bool = False
    refine_iterations: int = 0
    long_linear: int = 0

    def __post_init__(self) -> None:
        for name, (low, high) in _INT_RANGES.items():
            _int(name, getattr(self, name), low, high)
        for name, (flow, fhigh, open_low) in _FLOAT_RANGES.items():
            _float(name, getattr(self, name), flow, fhigh, open_low=open_low)
        for name in _BOOL_FIELDS:
            if not isinstance(getattr(self, name), bool):
                raise ConfigError(f"CoEAConfig.{name} must be true or false; got {getattr(self, name)!r}")
        if self.max_lag_y + self.max_lag_u == 0:
            raise ConfigError("CoEAConfig.max_lag_y + max_lag_u must be >= 1 (at least one candidate lag); got 0 and 0")
        object.__setattr__(self, "centre_bounds", _bounds("centre_bounds", self.centre_bounds, False))
        object.__setattr__(self, "width_bounds", _bounds("width_bounds", self.width_bounds, True))
        if self.selection not in SELECTIONS:
            raise ConfigError(f"CoEAConfig.selection must be one of {list(SELECTIONS)}; got {self.selection!r}")
        if self.direct_terms not in DIRECT_TERMS:
            raise ConfigError(f"CoEAConfig.direct_terms must be one of {list(DIRECT_TERMS)}; got {self.direct_terms!r}")
        if 0 < self.search_rows < 2 * self.neurons:
            raise ConfigError(f"CoEAConfig.search_rows must be 0 (all rows) or >= 2 * neurons = {2 * self.neurons}; "
                              f"got {self.search_rows}")
        fb = self.fallback_neurons
        if not (isinstance(fb, (tuple, list)) and len(fb) <= 10
                and all(isinstance(m, int) and not isinstance(m, bool) and 1 <= m <= 1000 for m in fb)):
            raise ConfigError(f"CoEAConfig.fallback_neurons must be a tuple of at most 10 integers in [1, 1000]; got {fb!r}")
        object.__setattr__(self, "fallback_neurons", tuple(fb))
        if self.max_lag_cap and self.max_lag_cap < max(self.max_lag_y, self.max_lag_u):
            raise ConfigError(f"CoEAConfig.max_lag_cap must be 0 (lags 1..max_lag_y/max_lag_u as given) or >= max(max_lag_y, "
                              f"max_lag_u) = {self.max_lag} (the floor); got {self.max_lag_cap}")

    @property
    def min_lag_u(self) -> int:
        """Each input's first candidate lag: 0 with ``direct_terms="on"`` (``u(t)`` a candidate), else 1
        (``"test"`` before the test is made: the paper's)."""
        return 0 if self.direct_terms == "on" else 1

    @property
    def max_lag(self) -> int:
        """Largest candidate lag: the number of leading samples without a full regressor."""
        return max(self.max_lag_y, self.max_lag_u)

    def n_candidates(self, n_inputs: int) -> int:
        """Number of candidate lags ``D_H = max_lag_y + n_inputs * max_lag_u`` (eq. 16a; with ``min_lag_u`` 0
        each input has one more, its direct term)."""
        return self.max_lag_y + n_inputs * (self.max_lag_u - self.min_lag_u + 1)

    def evaluations_per_run(self) -> int:
        """Fitness evaluations of one run: 2 P initial + P per generation (two-stage: both stages)."""
        if self.lag_search_neurons:
            return self.population * (self.generations + 2) + self.population * (self.generations + 1)
        return self.population * (self.generations + 2)

    def replace(self, **changes: Any) -> CoEAConfig:
        """A copy with some fields changed (validated again)."""
        return replace(self, **changes)

    def to_dict(self) -> dict[str, Any]:
        """Plain JSON-able dict of every field."""
        d = asdict(self)
        d["centre_bounds"] = list(self.centre_bounds)
        d["width_bounds"] = list(self.width_bounds)
        d["fallback_neurons"] = list(self.fallback_neurons)
        return d

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> CoEAConfig:
        """Inverse of :meth:`to_dict`; unknown keys raise :class:`ConfigError`."""
        if not isinstance(data, dict):
            raise ConfigError(f"a CoEAConfig document must be a JSON object; got {type(data).__name__}")
        known = {f.name for f in fields(cls)}
        retired = sorted(set(data) & set(RETIRED_FIELDS))
        if retired:
            raise ConfigError(retired_message(retired) + f". Accepted: {sorted(known)}")
        unknown = sorted(set(data) - known)
        if unknown:
            raise ConfigError(f"unknown CoEAConfig field(s) {unknown}; accepted: {sorted(known)}")
        kw = dict(data)
        for key in ("centre_bounds", "width_bounds", "fallback_neurons"):
            if key in kw and isinstance(kw[key], list):
                kw[key] = tuple(kw[key])
        return cls(**kw)


    @classmethod
    def paper(cls, **changes: Any) -> CoEAConfig:
        """The paper's procedure (Table 3): one run chosen by fitness; M and G as given (default 10, 400)."""
        return cls(**changes)

    @classmethod
    def recommended(cls, **changes: Any) -> CoEAConfig:
        """streamid's default identification (``streamid identify`` without options).

        Eight two-stage runs (at most four beyond one chunk of 65,536 rows, where no median is made; lags by the
        paper's coevolution with 10 neurons, then DE for 30 neurons on them,
        100 generations each) on candidate lags ``1..L``, ``L`` in [10, 30] from the data (odd restarts ``1..10``
        when ``L >= 20``), the search on at most 2000 random rows, a lag set without an input infeasible, the
        direct terms by a test of the data. Among every run's best pair and 10 fittest members, each offered with
        and without a linear part: the admissible candidate (free run in range, an input term) of the lowest AIC
        on the estimation free run; fallback runs of 15 then 8 neurons when none is admissible or the best fits at
        most 0.5; four more runs when it fits between 0 and 0.95. Then pruned sizes of the two best runs, means of
        the best runs' networks and a long linear part (order up to 512) compete by the same AIC, and the kept
        model's weights are refined to its free run when that holds out of sample; unless it carries a long linear
        part, the model is the per-sample median of every admissible run's network so finished.

        Each step and what it measured: docs/method.md; docs/engine-results.md (issue 37 rounds 4-6: what each
        step earns on the two-experiment suite).
        """
        base = {
            "neurons": 30,
            "generations": 100,
            "lag_search_neurons": 10,
            "restarts": 8,
            "selection": "fr_est",
            "search_rows": 2000,
            "fr_candidates": 10,
            "require_input": True,
            "max_lag_cap": 30,
            "fallback_neurons": (15, 8),
            "prune_runs": 2,
            "more_restarts": 4,
            "direct_terms": "test",
            "run_ensembles": True,
            "refine_iterations": 10,
            "linear_terms": True,
            "long_linear": 512,
        }
        return cls(**{**base, **changes})


#: The paper's settings (one run, chosen by fitness): what the reactor and piezo figures use.
PAPER = CoEAConfig.paper()

#: streamid's default identification strategy, used when ``identify`` gets no config.
DEFAULT = CoEAConfig.recommended()
