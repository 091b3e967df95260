"""Types of the window buffer: its parameters, the closed :class:`Window`, events.

See :mod:`streamid.online.window` for the buffer itself.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Protocol

import numpy as np

from streamid.errors import ConfigError

__all__ = [
    "DEFAULT_HOP_S", "DEFAULT_MAX_PENDING_S", "DEFAULT_WINDOW_S", "MAX_PENDING_WINDOWS", "BatchLike", "Event", "Window", "WindowParams",
    "estimate_period", "grid_runs",
]

#: Window length and hop used when neither seconds nor samples are given.
DEFAULT_WINDOW_S = 10.0
DEFAULT_HOP_S = 1.0
#: Largest accepted ``max_pending_windows``: a hard bound, whatever the configuration.
MAX_PENDING_WINDOWS = 1000
#: A live stream's waiting windows span at most this many seconds of stream time by default (``max_pending_s``).
DEFAULT_MAX_PENDING_S = 120.0


class BatchLike(Protocol):
    """What the buffer reads from a batch (:class:`streamid.wire.codec.SampleBatch`)."""

    @property
    def stream(self) -> str: ...
    @property
    def seq(self) -> int: ...
    @property
    def t0_ns(self) -> int: ...
    @property
    def period_ns(self) -> int: ...
    @property
    def t_ns(self) -> np.ndarray | None: ...
    @property
    def inputs(self) -> Mapping[str, np.ndarray]: ...
    @property
    def outputs(self) -> Mapping[str, np.ndarray]: ...

    def __len__(self) -> int: ...


@dataclass(frozen=True)
class WindowParams:
    """Window geometry and input checks of one stream.

    Parameters
    ----------
    window_s, window_samples
        Window length, in seconds of stream time or in samples (at most one;
        neither: :data:`DEFAULT_WINDOW_S`).
    hop_s, hop_samples
        A window closes every this many seconds / new samples (at most one;
        neither: :data:`DEFAULT_HOP_S`).
    inputs, outputs
        Signal names to use, in model order.  ``None``: taken from the batches
        (the first batch carrying inputs / outputs fixes them; a later batch with
        a different set resets the stream).
    max_abs_value
        Samples with a larger magnitude are refused (``magnitude``).
    max_window_samples
        Refuse a sample period that would make the window longer than this.
    align_slack_samples
        How far one column (e.g. u on its own key) may run ahead of another
        before the lagging one is declared unaligned.  ``None``: max(window, hop).
    max_pending_windows
        How many closed windows may wait for identification (1 to
        :data:`~streamid.online.pending.MAX_PENDING_WINDOWS`); a window closing
        with that many waiting drops the oldest.  See :mod:`streamid.online.pending`.
    max_pending_bytes
        Most bytes of samples the waiting windows hold (each sample once).
    max_pending_s
        A live stream's waiting windows end at most this many seconds of stream time
        before the newest (older ones are dropped, coalesced); 0: a live stream keeps
        only its newest window.  Not applied while stream time runs faster than the clock.
    """

    window_s: float | None = None
    window_samples: int | None = None
    hop_s: float | None = None
    hop_samples: int | None = None
    inputs: tuple[str, ...] | None = None
    outputs: tuple[str, ...] | None = None
    max_abs_value: float = 1e12
    max_window_samples: int = 4_000_000
    align_slack_samples: int | None = None
    max_pending_windows: int = 1
    max_pending_bytes: int = 64 * 2**20
    max_pending_s: float = DEFAULT_MAX_PENDING_S

    def __post_init__(self) -> None:
        if self.window_s is None and self.window_samples is None:
            object.__setattr__(self, "window_s", DEFAULT_WINDOW_S)
        if self.hop_s is None and self.hop_samples is None:
            object.__setattr__(self, "hop_s", DEFAULT_HOP_S)
        _one_of("window_s", self.window_s, "window_samples", self.window_samples)
        _one_of("hop_s", self.hop_s, "hop_samples", self.hop_samples)
        for name in ("window_s", "hop_s"):
            v = getattr(self, name)
            if v is not None and not (isinstance(v, (int, float)) and math.isfinite(v) and v > 0):
                raise ConfigError(f"{name} must be a finite number of seconds > 0; got {v!r}")
        for name in ("window_samples", "hop_samples", "max_window_samples"):
            v = getattr(self, name)
            if v is not None and not (isinstance(v, int) and not isinstance(v, bool) and v >= 2 - (name == "hop_samples")):
                raise ConfigError(f"{name} must be an integer >= {2 - (name == 'hop_samples')}; got {v!r}")
        if self.align_slack_samples is not None and not (
            isinstance(self.align_slack_samples, int) and self.align_slack_samples >= 1
        ):
            raise ConfigError(f"align_slack_samples must be an integer >= 1; got {self.align_slack_samples!r}")
        v = self.max_pending_windows
        if not (isinstance(v, int) and not isinstance(v, bool) and 1 <= v <= MAX_PENDING_WINDOWS):
            raise ConfigError(f"max_pending_windows must be an integer in [1, {MAX_PENDING_WINDOWS}]; got {v!r}")
        v = self.max_pending_bytes
        if not (isinstance(v, int) and not isinstance(v, bool) and v >= 1):
            raise ConfigError(f"max_pending_bytes must be an integer number of bytes >= 1; got {v!r}")
        v = self.max_pending_s
        if not (isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v) and 0 <= v <= 86400):
            raise ConfigError(f"max_pending_s must be a number of seconds in [0, 86400]; got {v!r}")
        if not (isinstance(self.max_abs_value, (int, float)) and self.max_abs_value > 0):
            raise ConfigError(f"max_abs_value must be a number > 0; got {self.max_abs_value!r}")
        for name in ("inputs", "outputs"):
            v = getattr(self, name)
            if v is not None and (
                not isinstance(v, tuple) or not v or not all(isinstance(s, str) and s for s in v) or len(set(v)) != len(v)
            ):
                raise ConfigError(f"{name} must be a non-empty tuple of distinct signal names or None; got {v!r}")

    def samples(self, period_ns: int) -> tuple[int, int]:
        """Window and hop lengths in samples for a sample period (ns)."""
        w = self.window_samples if self.window_samples is not None else round(_seconds(self.window_s) * 1e9 / period_ns)
        h = self.hop_samples if self.hop_samples is not None else round(_seconds(self.hop_s) * 1e9 / period_ns)
        return max(int(w), 2), max(int(h), 1)


def _seconds(v: float | None) -> float:
    assert v is not None  # __post_init__ sets seconds whenever samples are not given
    return float(v)


def _one_of(a: str, va: object, b: str, vb: object) -> None:
    if (va is None) == (vb is None):
        raise ConfigError(f"give at most one of {a} (seconds) or {b} (samples); got {a}={va!r}, {b}={vb!r}")


def estimate_period(t_ns: np.ndarray) -> int:
    """Sample period of jittered, possibly gappy time stamps (least squares on the grid)."""
    d = np.diff(t_ns)
    p0 = float(np.median(d))
    if p0 <= 0:
        return 0
    k = np.concatenate(([0], np.cumsum(np.maximum(np.rint(d / p0), 1))))
    kc = k - k.mean()
    den = float(kc @ kc)
    return int(round(float(kc @ (t_ns - t_ns[0]).astype(np.float64)) / den)) if den > 0 else int(p0)


def grid_runs(t_ns: np.ndarray, anchor: int, period: int) -> list[tuple[int, int, int]] | None:
    """Explicit time stamps as runs ``(first grid index, offset in the batch, length)`` of consecutive samples.

    None if they are not strictly increasing on the grid ``anchor + k * period``.
    """
    idx = (t_ns - anchor + period // 2) // period
    d = np.diff(idx)
    if d.size == 0 or (d == 1).all():
        return [(int(idx[0]), 0, len(idx))]
    if (d <= 0).any():
        return None
    cuts = np.flatnonzero(d != 1) + 1
    bounds = [0, *cuts.tolist(), len(idx)]
    return [(int(idx[a]), a, b - a) for a, b in zip(bounds[:-1], bounds[1:])]


@dataclass(frozen=True, eq=False)
class Window:
    """A closed window: the newest samples of a stream at the moment it closed.

    ``u`` has shape (n, n_inputs), ``y`` shape (n, n_outputs), both C-contiguous
    float64 copies owned by the window.  ``epoch`` changes when the stream was
    reset for a period or signal change (warm starts do not cross epochs).
    ``received_ns`` is the caller's clock reading passed with the batch that
    closed the window (``now_ns`` of :meth:`~streamid.online.OnlineIdentifier.push`;
    the daemon passes Unix time), 0 when none was given: the core has no clock.
    """

    stream: str
    number: int
    epoch: int
    t0_ns: int
    period_ns: int
    input_names: tuple[str, ...]
    output_names: tuple[str, ...]
    u: np.ndarray
    y: np.ndarray
    received_ns: int
    coalesced_before: int

    @property
    def n(self) -> int:
        """Number of samples."""
        return int(self.u.shape[0])

    @property
    def t_end_ns(self) -> int:
        """Time of the last sample."""
        return self.t0_ns + (self.n - 1) * self.period_ns

    def times_ns(self) -> np.ndarray:
        """Sample times (int64 ns)."""
        return self.t0_ns + np.arange(self.n, dtype=np.int64) * np.int64(self.period_ns)


@dataclass(frozen=True)
class Event:
    """Something that happened to a stream, as a value (never only a log line).

    ``kind`` is dotted: ``gap``, ``unaligned``, ``reset.<why>`` (``schema``,
    ``period``, ``restart``), ``bad.<why>`` (a refused batch: ``nonfinite``,
    ``duplicate``, ``decode``...), ``window.closed``, ``window.coalesced``, and
    the outcome of an update: ``update.accepted``, ``update.rejected``,
    ``update.failed``, ``update.dropped``.  ``t_ns`` is stream time (the newest
    complete sample, None before the first) and ``received_ns`` the caller's
    clock reading given with the call that raised it (0: none given).
    """

    kind: str
    message: str
    t_ns: int | None = None
    received_ns: int = 0
