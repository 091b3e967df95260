"""The rows a search is evaluated on: at most a bound set by the model's size, not the sample rate.

Used by every online update, and offline (:func:`long_record_rows`) by each run of an identification whose
estimation record has more than one chunk (:data:`~streamid.model.limits.CHUNK_ROWS`, 65,536) of regressor rows:
one rule, not two. Up to one chunk an offline run keeps its ``search_rows`` random rows (the same models as before).

Why a bound
    The search (:class:`~streamid.engine.Coevolution`) evaluates every member of
    its population on every row of the window's estimation part, each generation:
    its time and memory are ``rows x population x (candidate regressors + neurons)``.
    A 10 s window of a 20 kHz stream has 140,000 estimation rows, and an update
    of it cost ~1.3 GiB and seconds per generation, while what the rows tell the
    search -- which lags and where the neurons go, judged by the one-step-ahead
    error of a least-squares fit -- does not grow with the sample rate.

The bound (:func:`search_row_bound`)
    ``max(SEARCH_ROWS, ROWS_PER_WEIGHT x (M + D + 1))`` rows, ``M`` neurons and
    ``D = max_lag_y + n_inputs x max_lag_u`` candidate regressors: ``M + D + 1``
    is the most output weights one candidate's least squares fits (the network
    and a linear part).  Chosen so that

    * the fit's in-sample optimism, about ``(M + D + 1) / rows`` of the noise
      variance, is under 1 % (0.8 % with the defaults, ``M + D + 1 = 31``) and,
      being the same for every member of one size, does not change their order;
    * the members are compared on the *same* rows (paired comparisons: what
      differs between two candidates' errors is their fits, not the sample);
    * a generation costs about what a 0.2 s window of the 20 kHz piezo cost
      before (4,096 rows: ~3 ms per generation with the defaults on the
      project's 2-core machine, so a warm update's 30 generations take ~0.1 s
      and a cold one's 400 about 1.3 s);
    * the bundled logs' windows under the defaults stay whole (MR damper and
      piezo_p885 at 200 Hz: 1,390 rows; the F-16 at 400 Hz: 2,790): their
      updates are exactly what they were.

    ``[streams.<s>.engine] search_rows = N`` sets the bound (0: every row, the
    cost growing with the window again).

Which rows (:func:`informative_rows`)
    Stratified in time: the estimation rows are cut into ``bound`` equal
    consecutive strata and one row is drawn at random in each.  Consecutive rows
    of a fast-sampled signal are nearly the same regressor (20 kHz: 50 us
    apart), so a contiguous block would see a fraction of the window's operating
    conditions and a plain random draw leaves gaps and clusters; one row per
    stratum covers the whole window evenly, every excursion of the output and
    input in proportion to its duration, and the mean squared error over the
    sample has no more variance than over a simple random sample of the same
    size.  The draw comes from a child of the update's generator
    (:meth:`numpy.random.Generator.spawn`): the search's own random stream is the
    one it had without sampling.

After the search
    The candidates are screened on the same rows (``select_model(..., screen_rows=True)``),
    chosen by their free run over the whole estimation part, and the chosen one
    is refitted on every row (the least squares streamed in blocks:
    :func:`streamid.engine.fit.rbf.fit_weights`) and validated on the whole held-out
    part, as before.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

from streamid.engine.settings import CoEAConfig
from streamid.errors import ConfigError
from streamid.model.limits import CHUNK_ROWS

__all__ = ["CHUNK_ROWS", "ROWS_PER_WEIGHT", "SEARCH_ROWS", "RowSample", "informative_rows", "long_record_rows",
           "search_row_bound", "spaced_rows"]

#: The least bound of the search's rows (see the module docstring).
SEARCH_ROWS = 4096
#: Rows per output weight of the largest candidate (network and linear part): 1 / 128 < 1 % optimism.
ROWS_PER_WEIGHT = 128


@dataclass(frozen=True)
class RowSample:
    """The rows one search evaluates: ``rows`` (sorted indices into the regressor rows), ``of`` rows in all."""

    rows: NDArray[np.intp]
    of: int
    bound: int

    def evidence(self) -> dict[str, Any]:
        """What the model's metrics say about it (``search_rows``)."""
        return {"rows": int(self.rows.size), "of": int(self.of), "bound": int(self.bound), "sampling": "stratified"}


def search_row_bound(neurons: int, max_lag_y: int, max_lag_u: int, n_inputs: int, engine: dict[str, Any]) -> int:
    """The most rows the search of one update evaluates (0: every row, set by ``engine["search_rows"] = 0``).

    ``engine`` is the stream's ``[engine]`` table (its ``search_rows``, when set, is the bound).
    """
    if "search_rows" in engine:
        v = engine["search_rows"]
        if isinstance(v, bool) or not isinstance(v, int) or v < 0:
            raise ConfigError(f"engine.search_rows must be an integer >= 0 (0: every row); got {v!r}")
        return int(v)
    d = max_lag_y + max(1, n_inputs) * max_lag_u
    return max(SEARCH_ROWS, ROWS_PER_WEIGHT * (neurons + d + 1))


def informative_rows(n_rows: int, bound: int, rng: np.random.Generator) -> RowSample | None:
    """One row drawn at random in each of ``bound`` equal strata of ``n_rows`` (None: all fit, or no bound).

    Raises
    ------
    ConfigError
        A bound of 1 or less (a least squares needs rows).
    """
    if bound <= 0 or n_rows <= bound:
        return None
    if bound < 2:
        raise ConfigError(f"the search's row bound must be 0 (every row) or >= 2; got {bound!r}")
    edges = (np.arange(bound + 1, dtype=np.int64) * n_rows) // bound  # strata [edges[i], edges[i+1]), none empty
    width = np.diff(edges)
    rows = edges[:-1] + np.minimum((rng.random(bound) * width).astype(np.int64), width - 1)
    return RowSample(rows.astype(np.intp), int(n_rows), int(bound))


def long_record_rows(n_rows: int, cfg: CoEAConfig, n_inputs: int, rng: np.random.Generator) -> RowSample | None:
    """The rows an offline run's search evaluates on a record of more than one chunk (:data:`CHUNK_ROWS`) of
    regressor rows: the online rule (:func:`search_row_bound`, at least ``cfg.search_rows``; one row per stratum,
    drawn from a child of ``rng``: the run's own random stream is the one it had). None: a record of one chunk or
    less (searched as before, on ``cfg.search_rows`` random rows: the same models to the bit) or
    ``cfg.search_rows = 0`` (every row, asked for).

    Not ``cfg.search_rows`` alone (2,000, what a record of one chunk or less is searched on): on the simulated MR
    damper's long record (``benchmarks.long_seeds --device mr_damper``, 100,000 + 20,000 samples, seeds 0-19) the
    bounded path with 2,000 stratified rows validated at median 0.9289, worst 0.786 (3 seeds under 0.9); with this
    bound (6,528 rows with the defaults) at median 0.9287, worst 0.898 (1 seed). Worst case first: this bound,
    though its search costs about three times as much (docs/benchmarks.md, "Long records offline")."""
    if n_rows <= CHUNK_ROWS or not cfg.search_rows:
        return None
    bound = max(int(cfg.search_rows), search_row_bound(cfg.neurons, cfg.max_lag_y, cfg.max_lag_u, n_inputs, {}))
    return informative_rows(n_rows, bound, rng.spawn(1)[0])


def spaced_rows(n_rows: int, most: int | None = None) -> NDArray[np.intp] | None:
    """``most`` (default :data:`CHUNK_ROWS`) of ``n_rows`` rows evenly spaced from the first, for a least squares
    beyond one chunk that needs no contiguity (the direct-term test, the pruned networks' fits); None: ``n_rows`` is
    at most that (every row, as always). Deterministic: no draw."""
    k = CHUNK_ROWS if most is None else int(most)
    if n_rows <= k:
        return None
    return ((np.arange(k, dtype=np.int64) * n_rows) // k).astype(np.intp)
