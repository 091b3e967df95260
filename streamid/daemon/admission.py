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
    * the identification's working memory over its ``m = n_est - max_lag`` rows
      (``n_est = n (1 - validation_fraction)``): the lag matrix and the
      evaluator's data table ``(2D + P + 1) m``, the feature table ``P (D + 2) m``,
      the activations and residuals ``P (M + 2) m``, the helper's shared copy of
      the lag matrix ``D m``, and the populations ``P (M (D + 1))`` twice, i.e.
      ``8 [m (P (2D + M + 5) + 3D + 1) + 2 P M (D + 1)]`` bytes
      (P population, M neurons).

    The estimate is checked against tracemalloc peaks in
    ``tests/test_daemon_bounds.py`` (it must not under-estimate).

Time of one identification
    A run is polled between generations (:class:`Deadline`): past
    ``max_identification_s`` of its own time it stops, is counted as an
    ``identification_timeouts`` and reported as a failed update
    (``code = "timeout"``).  One generation is bounded by the memory bound:
    its work is a few passes over the feature table and activations, the
    bytes above.
"""

from __future__ import annotations

import math
import threading
import time
from collections.abc import Callable, Mapping, Sized

from streamid.online.stream_config import StreamConfig
from streamid.wire.codec import SampleBatch

__all__ = ["identification_bytes", "stream_bytes", "window_samples_at", "known_channels", "check_batch", "Deadline", "MiB",
           "STREAM_FAULTS"]

MiB = 1 << 20
#: Windows longer than this are refused by the window buffer whatever the bounds here.
_MAX_WINDOW_SAMPLES = 4_000_000


def identification_bytes(n_samples: int, n_inputs: int, n_outputs: int, cfg: StreamConfig) -> int:
    """Upper estimate of the working memory of one identification of an ``n_samples`` window (bytes)."""
    n, c = max(0, int(n_samples)), max(1, n_inputs) + max(1, n_outputs)
    p, m_neurons = cfg.population, cfg.neurons
    d = cfg.max_lag_y + max(1, n_inputs) * cfg.max_lag_u
    rows = max(0, n - int(round(n * cfg.validation_fraction)) - max(cfg.max_lag_y, cfg.max_lag_u))
    return 8 * (n * c + rows * (p * (2 * d + m_neurons + 5) + 3 * d + 1) + 2 * p * m_neurons * (d + 1))


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
