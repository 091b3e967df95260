"""Samples in, events out: the input side of an :class:`~streamid.online.OnlineIdentifier`.

:class:`StreamIntake` owns the stream's window buffer (:mod:`streamid.online.window`) and its
bounded event log; :class:`~streamid.online.OnlineIdentifier` adds identification, the
champion of each output and drift watching on top.  Single-threaded, no I/O, no clock.
"""

from __future__ import annotations

from collections import deque
from collections.abc import Sequence

import numpy as np
from numpy.typing import ArrayLike, NDArray

from streamid.errors import DataError
from streamid.online.arrays_in import batch_of, columns, signal_names
from streamid.online.stream_config import StreamConfig
from streamid.online.window import WindowBuffer
from streamid.online.window_types import BatchLike, Event

__all__ = ["StreamIntake", "EVENTS_KEPT"]

#: Events kept for :meth:`StreamIntake.drain_events` (the newest; older ones are dropped, counted).
EVENTS_KEPT = 256
#: Samples of the first batch :meth:`StreamIntake.learn_many` makes of a long record (the period is not known yet).
_FIRST_CHUNK = 256


class StreamIntake:
    """The window buffer and event log of one stream (see the module docstring)."""

    def __init__(self, config: StreamConfig, stream: str) -> None:
        self.config = config
        self.stream = stream
        self._buffer = WindowBuffer(stream, config.window_params())
        self._events: deque[Event] = deque(maxlen=EVENTS_KEPT)
        self._events_dropped = 0
        self._seq = 0
        self._staged: tuple[int, NDArray[np.float64], NDArray[np.float64]] | None = None
        self.windows_skipped = 0  # closed windows dropped unidentified (skip_pending)

    # ---------------------------------------------------------------- samples in
    def push(self, batch: BatchLike, *, source: str = "samples", now_ns: int = 0) -> list[Event]:
        """Add one batch of samples; returns the events it raised.

        ``source`` is the key the batch came on (``samples``, or ``u`` / ``y`` for inputs
        and outputs published apart, aligned by time).  ``now_ns`` is the caller's clock
        reading (kept with the windows this batch closes).  Never raises for bad data: a
        refused batch is a ``bad.<why>`` event and a count in :meth:`status`.
        """
        if self._buffer.append(batch, source, now_ns=now_ns):
            self._watch(now_ns)
        return self._collect()

    def learn_many(
        self,
        t_ns: ArrayLike,
        u: ArrayLike,
        y: ArrayLike,
        *,
        inputs: Sequence[str] | None = None,
        outputs: Sequence[str] | None = None,
        period_ns: int | None = None,
        now_ns: int = 0,
    ) -> list[Event]:
        """Add samples given as arrays; returns the events they raised.

        Parameters
        ----------
        t_ns : array_like of int, shape (N,)
            Sample times in integer nanoseconds, strictly increasing.
        u : array_like, shape (N,) or (N, n_inputs)
        y : array_like, shape (N,) or (N, n_outputs)
        inputs, outputs
            Signal names (default ``u``/``u0, u1...`` and ``y``/``y0, y1...``).
        period_ns
            The sample period, when ``t_ns`` alone cannot tell it (a single first sample).

        Raises
        ------
        DataError
            If the arrays do not have the shapes above, or names do not match the columns.
        """
        t = np.atleast_1d(np.asarray(t_ns))
        if t.ndim != 1 or t.dtype.kind not in "iu":
            raise DataError(f"t_ns must be a 1-D array of integer nanoseconds; got dtype {t.dtype} shape {t.shape}")
        ua = columns(u, t.size, "u")
        ya = columns(y, t.size, "y")
        in_names = signal_names(inputs, ua.shape[1], "u")
        out_names = signal_names(outputs, ya.shape[1], "y")
        if t.size == 0:
            return []
        if self._buffer.period_ns is None and period_ns is None and t.size == 1:
            if self._staged is None:  # one sample cannot tell the period: wait for the next
                self._staged = (int(t[0]), ua, ya)
                return []
            t0, u0, y0 = self._staged
            t, ua, ya = np.r_[t0, t], np.vstack([u0, ua]), np.vstack([y0, ya])
        self._staged = None
        t = t.astype(np.int64)
        events: list[Event] = []
        a = 0
        while a < t.size:
            # at most one hop per batch: a long record closes every window it spans (the ring holds
            # one window and a hop; a larger batch would overwrite windows before they close)
            b = a + max(2, self._buffer.lengths[1] or _FIRST_CHUNK)
            if t.size - b == 1:
                b += 1  # never leave one sample alone: it cannot tell the period of a new stream
            batch = batch_of(self.stream, self._seq, t[a:b], ua[a:b], ya[a:b], in_names, out_names,
                             period_ns or self._buffer.period_ns or 0)
            self._seq += 1
            events += self.push(batch, now_ns=now_ns)
            a = b
        return events

    def learn_one(
        self, t_ns: int, u: float | ArrayLike, y: float | ArrayLike, *, period_ns: int | None = None, now_ns: int = 0
    ) -> list[Event]:
        """Add one sample (``u``, ``y``: a number or one value per signal); returns the events it raised."""
        return self.learn_many(
            np.array([t_ns], dtype=np.int64), np.atleast_2d(np.asarray(u, dtype=np.float64).ravel()),
            np.atleast_2d(np.asarray(y, dtype=np.float64).ravel()), period_ns=period_ns, now_ns=now_ns,
        )

    def count_bad(self, kind: str, message: str = "", *, now_ns: int = 0) -> list[Event]:
        """Count a bad message the caller found before the samples (e.g. undecodable bytes)."""
        self._buffer.count_bad(kind, message, now_ns=now_ns)
        return self._collect()

    def counters(self) -> dict[str, object]:
        """The window buffer's counters (samples, batches, bad input, gaps, resets, windows...)."""
        out = self._buffer.counters()
        if self.windows_skipped:
            out["windows_skipped"] = self.windows_skipped
        return out

    def skip_pending(self) -> int:
        """Drop the closed windows waiting to be identified, keep the samples; returns how many.

        A daemon standing by for a stream another one serves keeps its window this way
        (to take over with a full one) without identifying it.
        """
        n = 0
        while self._buffer.take() is not None:
            n += 1
        self.windows_skipped += n
        return n

    def drain_events(self) -> list[Event]:
        """Remove and return the events kept since the last call (the newest :data:`EVENTS_KEPT`)."""
        self._collect()
        out = list(self._events)
        self._events.clear()
        return out


    def _watch(self, now_ns: int) -> None:
        """Called after every batch that wrote samples (the identifier watches its champions here)."""

    def _collect(self) -> list[Event]:
        new = self._buffer.drain_events()
        for ev in new:
            self._keep(ev)
        return new

    def _keep(self, ev: Event) -> None:
        if len(self._events) == self._events.maxlen:
            self._events_dropped += 1
        self._events.append(ev)

    def _event(self, kind: str, message: str, t_ns: int | None, now_ns: int) -> Event:
        ev = Event(kind, f"{self.stream}: {message}", t_ns, now_ns)
        self._keep(ev)
        return ev

