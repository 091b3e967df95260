"""What one stream may make the daemon spend: channels, memory, time, and its slot.

The daemon checks every decoded batch here *before* it reaches the stream's
window buffer, and every job before it runs.  Each refusal is a counted,
named ``bad.<kind>`` (or a dropped / failed update) with a message that names
the value found and the bound, and says which setting moves it.

Memory of one stream
    Everything a stream allocates grows with ``n`` (window samples) times the
    number of signals, and the identification also with the number of candidate
    regressors ``D = max_lag_y + n_inputs * max_lag_u``.  :func:`stream_bytes`
    adds, in float64 (8 bytes):

    * the ring (window + hop + slack <= 3 windows) and the job's copy, ``4 w``
      with ``w = 8 n c`` bytes and ``c = n_inputs + n_outputs``, plus the pending
      windows: ``min(max_pending_windows w, max(max_pending_bytes, w))``;
    * one identification (:func:`identification_bytes`), with ``m = n_est - max_lag``
      estimation rows (``n_est = n (1 - validation_fraction)``), ``i`` inputs, ``M``
      neurons, population ``P`` and ``C`` free-run candidates (``P + 1``, or
      ``fr_candidates + 1``), in doubles:

      - the data, held throughout: the window's copy, the output column, the estimation part and its
        normalised copy, ``n c + n + 2 n_est (i + 1)``; then the larger of two phases, or of the long linear
        part's trial (four copies of its design, at most ``LONG_LINEAR_DESIGN_BYTES``, 8 MiB);
      - the run and its choice: the search, over its ``k = min(m, bound)`` rows
        (:mod:`streamid.online.rows`: ``bound = max(4096, 128 (M + D + 1))``): the evaluator's data and feature
        tables, activations and residuals, the rows' copies (and the helper's), the populations,
        ``k (P (D + M + 4) + 4 D + 2) + 2 P M (D + 1)``, bounded whatever the window; the choice's passes over
        every row: a window searched on a sample of its rows (``m`` above the bound) is chosen without holding
        any candidate, or every row's regressors, over every row (their free runs scored ``SCORE_CHUNK_ROWS`` rows
        at a time, the fits, the fallback's included, and their regressors a block of ``FIT_BLOCK_ROWS``), only
        the chosen one's free run and copies, ``(i + 8) m``; a window searched on every row holds them, ``m``
        times the lag matrix ``D`` and the largest of the candidates' free runs (their paths and one working
        copy) ``2 C + i + 4``, the chosen one's regressors and activations ``C + D + M + 4``, and the selection's
        fallback (every candidate fitted on every row) ``C M + 2 D + 2``;
        and the blocks and chunks, the largest of a streamed QR's ``4 min(m, 16384) (M + D + 1)``, activations'
        ``2 min(m, 8192) M D`` and the candidates' free runs' ``4 C min(m, 65536)``;
      - the refinement, once the run is freed (:func:`~streamid.engine.choice.refine.refine_judged`, the default): its
        input terms and mean free run, ``(M + i + 6) m`` (``+ (D + 1) m`` with ``linear_terms``), and its
        derivatives and Jacobian, made ``CHUNK_ROWS`` (65,536) rows at a time, ``(4 M + 4) min(m, 65536)``
        (``4 (M + D + 1) + 4`` with ``linear_terms``).

      So a window's cost grows by about 0.15 kB per estimation row with the defaults (the data, the chosen
      free run, the refinement's input terms), where it was 2.2 kB while every candidate and every row's
      regressors were held and 8.8 kB when the search used every row: a 10 s window of a 20 kHz stream, 200,000
      samples, is estimated at ~84 MiB (it was ~350 MiB, and 1,316 MiB and refused before that), a
      1,000,000-sample one at 158 MiB (memray's peak of such a cold update, 165 MB, holds 32 MiB of OpenBLAS's
      buffer that tracemalloc does not see).

    The estimate is checked against tracemalloc peaks in
    ``tests/test_daemon_bounds.py`` and ``tests/test_bounded_update.py`` (small and
    large windows; it must not under-estimate).

Time of one identification
    A run is polled between generations (:class:`Deadline`): past
    ``max_identification_s`` of its own time it stops, is counted as an
    ``identification_timeouts`` and reported as a failed update
    (``code = "timeout"``).  One generation is bounded by the memory bound:
    its work is a few passes over the feature table and activations, the
    bytes above.  The stages after the search are not polled; each is a
    bounded number of passes over the estimation rows: the candidates' free
    runs (one batched pass), the chosen one's refit, the long linear part's
    trial (a few orders), and the refinement (at most 2 x 10 iterations x 4
    trial free runs with their sensitivities, first on half the rows): a
    cold update of the 20 kHz piezo's 200,000-sample window, refinement
    included, took at most 1.74 s (docs/benchmarks.md, "Online refinement").
"""

from __future__ import annotations

import math
import threading
import time
from collections.abc import Callable, Mapping, Sized

from streamid.engine.choice.scores import SCORE_CHUNK_ROWS
from streamid.engine.choice.longlinear import ROWS_PER_PARAMETER
from streamid.engine.fit.rbf import BLOCK_ROWS, FIT_BLOCK_ROWS
from streamid.model.limits import CHUNK_ROWS
from streamid.online.rows import search_row_bound
from streamid.online.stream_config import ONLINE_LONG_LINEAR, ONLINE_REFINE, ONLINE_SELECTION, StreamConfig
from streamid.online.update import LONG_LINEAR_DESIGN_BYTES
from streamid.wire.codec import SampleBatch

__all__ = ["identification_bytes", "stream_bytes", "window_samples_at", "known_channels", "check_batch", "Deadline", "MiB",
           "STREAM_FAULTS"]

MiB = 1 << 20
#: Windows longer than this are refused by the window buffer whatever the bounds here.
_MAX_WINDOW_SAMPLES = 4_000_000


def identification_bytes(n_samples: int, n_inputs: int, n_outputs: int, cfg: StreamConfig) -> int:
    """Upper estimate of the working memory of one identification of an ``n_samples`` window (bytes).

    The module docstring gives the terms: the search's part is bounded by its rows (:mod:`streamid.online.rows`);
    the data, the chosen free run and the refinement's input terms grow with the window, by ~0.15 kB a row with the
    defaults (the candidates' free runs and fits, and their regressors, are made in chunks and blocks).
    """
    n, i = max(0, int(n_samples)), max(1, n_inputs)
    c = i + max(1, n_outputs)
    p, m_neurons = cfg.population, cfg.neurons
    d = cfg.max_lag_y + i * cfg.max_lag_u
    n_est = n - int(round(n * cfg.validation_fraction))
    rows = max(0, n_est - max(cfg.max_lag_y, cfg.max_lag_u))
    engine = dict(cfg.engine)
    bound = search_row_bound(m_neurons, cfg.max_lag_y, cfg.max_lag_u, i, engine)
    k = min(rows, bound) if bound else rows
    fr = engine.get("fr_candidates", 0)
    cands = (min(p, int(fr)) if fr else p) + 1
    search = k * (p * (d + m_neurons + 4) + 4 * d + 2) + 2 * p * m_neurons * (d + 1)
    data = n * c + n + 2 * n_est * (i + 1)
    lin = d + 1 if engine.get("linear_terms", False) else 0  # a linear part's weights (refined with the network's)
    if bound and rows > bound:  # screened: the free runs in chunks, the fits in blocks (also the fallback's)
        passes = rows * (i + 8)  # (and no lag matrix of every row: the sample's rows, then a block at a time)
    else:  # every candidate on every row at once (rows <= bound, or every row searched), and the lag matrix
        passes = rows * (d + max(2 * cands + i + 4, cands + d + m_neurons + 4, cands * m_neurons + 2 * d + 2))
    blocks = max(4 * min(rows, FIT_BLOCK_ROWS) * (m_neurons + d + 1), 2 * min(rows, BLOCK_ROWS) * m_neurons * d,
                 4 * cands * min(rows, SCORE_CHUNK_ROWS))  # the last: the candidates' free runs, a chunk at a time
    choice = search + passes + blocks  # the run's tables live until the choice is made
    refine = 0  # then the run is freed: the refinement's input terms and mean free run, and its chunk
    if engine.get("refine_iterations", ONLINE_REFINE):
        refine = rows * (m_neurons + lin + i + 6) + (4 * (m_neurons + lin) + 4) * min(rows, CHUNK_ROWS)
    return 8 * (data + max(choice, refine, _long_linear(n_est, i, cfg, engine)))


def _long_linear(n_est: int, n_inputs: int, cfg: StreamConfig, engine: dict[str, object]) -> int:
    """Doubles of the long linear part's trial (:func:`streamid.online.update.long_linear_part`): its design, at
    most ``LONG_LINEAR_DESIGN_BYTES``, and its QR's copies (4 designs; measured 2.7-3.8)."""
    top = engine.get("long_linear", ONLINE_LONG_LINEAR)
    if not isinstance(top, int) or top <= 0 or engine.get("selection", ONLINE_SELECTION) != "fr_est" or n_est <= 0:
        return 0
    m_neurons, lag = cfg.neurons, max(cfg.max_lag_y, cfg.max_lag_u)
    order = min(top, (n_est // ROWS_PER_PARAMETER - m_neurons - 1) // (1 + n_inputs),
                (LONG_LINEAR_DESIGN_BYTES // (8 * n_est) - m_neurons - 1) // (1 + n_inputs))
    return 4 * n_est * (order * (1 + n_inputs) + m_neurons + 1) if order > lag else 0


def stream_bytes(n_samples: int, n_inputs: int, n_outputs: int, cfg: StreamConfig) -> int:
    """Upper estimate of one stream's buffers plus one identification of its window (bytes)."""
    window = 8 * max(0, int(n_samples)) * (max(1, n_inputs) + max(1, n_outputs))
    pending_max = getattr(cfg, "max_pending_bytes", None)  # (a byte bound of the pending queue, when set)
    pending = cfg.max_pending_windows * window
    if pending_max is not None:
        pending = min(pending, max(int(pending_max), window))
    return 3 * window + pending + identification_bytes(n_samples, n_inputs, n_outputs, cfg)


def known_channels(counters: Mapping[str, object]) -> tuple[int, int]:
    """(inputs, outputs) a stream has now, from its window buffer's counters (0: not known yet)."""
    ins, outs = counters.get("inputs"), counters.get("outputs")
    return (len(ins) if isinstance(ins, Sized) else 0, len(outs) if isinstance(outs, Sized) else 0)


def window_samples_at(period_ns: int, cfg: StreamConfig) -> int:
    """How many samples the stream's window holds at ``period_ns`` (0: period unknown)."""
    wp = cfg.window_params()
    if wp.window_samples is not None:
        return int(wp.window_samples)
    if period_ns <= 0:
        return 0
    assert wp.window_s is not None
    return min(_MAX_WINDOW_SAMPLES, int(math.ceil(wp.window_s * 1e9 / period_ns)))


def _period_of(batch: SampleBatch) -> int:
    if batch.period_ns > 0:
        return int(batch.period_ns)
    t = batch.t_ns
    if t is not None and len(t) >= 2:
        return max(1, int((int(t[-1]) - int(t[0])) // (len(t) - 1)))
    return 0


#: Refusals that every batch of the stream as it is sent would meet (its window, its channels): the stream is degraded
#: for them (issue 38: a stream that cannot be identified is never ``ok``), not only the batch counted.
STREAM_FAULTS = ("too_large_window", "too_many_channels")


def check_batch(
    batch: SampleBatch,
    cfg: StreamConfig,
    *,
    max_channels: int,
    max_bytes: int,
    known: tuple[int, int] = (0, 0),
) -> tuple[str, str] | None:
    """Why ``batch`` must be refused before it reaches the window buffer, as ``(kind, message)``; None: fine.

    ``known`` is the stream's current (inputs, outputs) count, for batches that
    carry only one side (``u`` / ``y`` keys).
    """
    n_in, n_out = len(batch.inputs), len(batch.outputs)
    if n_in + n_out > max_channels:
        return "too_many_channels", (
            f"batch has {n_in + n_out} channels ({n_in} inputs, {n_out} outputs); daemon.max_channels is "
            f"{max_channels} per stream (send fewer signals, or raise daemon.max_channels)"
        )
    if cfg.inputs is not None:
        n_in = min(n_in, len(cfg.inputs)) if n_in else 0
    if cfg.outputs is not None:
        n_out = min(n_out, len(cfg.outputs)) if n_out else 0
    n_in, n_out = n_in or known[0], n_out or known[1]
    n = window_samples_at(_period_of(batch), cfg)
    need = stream_bytes(n, n_in, n_out, cfg)
    if need > max_bytes:
        return "too_large_window", (
            f"a window of {n} samples x {max(1, n_in)} inputs, {max(1, n_out)} outputs (max_lag_u "
            f"{cfg.max_lag_u}, population {cfg.population}) needs ~{need / MiB:.0f} MiB; "
            f"daemon.max_identification_bytes is {max_bytes / MiB:.0f} MiB (shorten window_s, send fewer "
            "signals, lower max_lag_u, or raise daemon.max_identification_bytes)"
        )
    return None


class Deadline:
    """A stop flag for :meth:`UpdateJob.run`: set when the daemon stops or the run used up its time.

    Time spent in other streams' jobs run in between (:meth:`pause`) is not
    counted against this run.
    """

    def __init__(self, stop: threading.Event, limit_s: float, *, clock: Callable[[], float] = time.monotonic) -> None:
        self._stop = stop
        self.limit_s = limit_s
        self._clock = clock
        self._t0 = clock()
        self._paused_s = 0.0

    @property
    def own_s(self) -> float:
        """Seconds this run has taken, other jobs run in between left out."""
        return self._clock() - self._t0 - self._paused_s

    @property
    def paused_s(self) -> float:
        """Seconds spent on other jobs run in between."""
        return self._paused_s

    def pause(self, seconds: float) -> None:
        """Leave ``seconds`` (spent on another job) out of this run's time."""
        self._paused_s += seconds

    @property
    def expired(self) -> bool:
        """Whether the run took longer than its limit."""
        return self.own_s > self.limit_s

    def is_set(self) -> bool:
        """Whether the run must stop now (the daemon stops, or :attr:`expired`)."""
        return self._stop.is_set() or self.expired
