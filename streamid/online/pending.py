"""The bounded queue of closed windows waiting for identification (one per stream).

Two regimes, decided by how fast stream time runs against the caller's clock
(the ``now_ns`` of the batches; :class:`~streamid.online.window.WindowBuffer`
measures it over the last 16 windows closed):

* **Stream time faster than the clock** (at least :data:`FAST_SPEED` x: a log
  replayed with ``--rate 4`` or ``--max-speed``; a record given to
  ``learn_many`` without clock readings): every window waits its turn, oldest
  first, so every window of the log is identified, in order.
* **A live stream** (about 1x) that falls behind: a window that closes while
  another one waits replaces it, so the worker always gets the newest data and a
  slow identification never builds a backlog.

Both are bounded by ``max_pending_windows`` and ``max_pending_bytes`` (per
stream settings, default 1000 windows and 64 MiB); past them the oldest waiting
window is dropped.  Windows not identified are counted as *coalesced*; the
queue's memory (each window is a float64 copy of its samples) is reported as
``pending_bytes`` (peak ``pending_bytes_peak``, bound ``pending_bytes_max``) in
the stream's status.
"""

from __future__ import annotations

import dataclasses
from collections import deque

import numpy as np

from streamid.online.window_types import MAX_PENDING_WINDOWS, Window

__all__ = ["PendingWindows", "cut_block", "due_windows", "FAST_SPEED", "MAX_PENDING_WINDOWS"]

#: Stream time running at least this many times faster than the caller's clock queues every window.
FAST_SPEED = 1.25


class PendingWindows:
    """FIFO of at most ``limit`` closed windows (not thread-safe: the buffer's lock guards it).

    Parameters
    ----------
    limit
        Most windows held; pushing one more drops the oldest.
    max_bytes
        Most bytes of window samples held (the newest window is always kept).
    """

    def __init__(self, limit: int = 1, max_bytes: int = 64 * 2**20) -> None:
        if not (isinstance(limit, int) and not isinstance(limit, bool) and 1 <= limit <= MAX_PENDING_WINDOWS):
            raise ValueError(f"limit must be an integer in [1, {MAX_PENDING_WINDOWS}]; got {limit!r}")
        self.limit = limit
        self.max_bytes = max_bytes
        self._q: deque[tuple[int, Window]] = deque()
        self._last_taken = 0  # closing index (1, 2, ... over all epochs) of the last window taken
        self.nbytes = 0
        self.peak = 0  # most windows ever waiting at once
        self.peak_bytes = 0

    def __len__(self) -> int:
        return len(self._q)

    def __bool__(self) -> bool:
        return bool(self._q)

    def push(self, closed_index: int, window: Window, *, newest_only: bool = False) -> int:
        """Add a window (``closed_index``: its rank among all windows closed); returns how many were dropped.

        ``newest_only``: drop every waiting window first (a live stream that fell behind).
        """
        dropped = 0
        size = _bytes(window)
        while self._q and (newest_only or len(self._q) >= self.limit or self.nbytes + size > self.max_bytes):
            _, old = self._q.popleft()
            self.nbytes -= _bytes(old)
            dropped += 1
        self._q.append((closed_index, window))
        self.nbytes += size
        self.peak = max(self.peak, len(self._q))
        self.peak_bytes = max(self.peak_bytes, self.nbytes)
        return dropped

    def pop(self) -> Window | None:
        """The oldest window, with ``coalesced_before`` = windows closed since the last one taken, never identified."""
        if not self._q:
            return None
        idx, w = self._q.popleft()
        self.nbytes -= _bytes(w)
        skipped = max(0, idx - self._last_taken - 1)
        self._last_taken = idx
        return dataclasses.replace(w, coalesced_before=skipped)

    def clear(self) -> int:
        """Drop every waiting window (a reset of the stream); returns how many."""
        n = len(self._q)
        self._q.clear()
        self.nbytes = 0
        return n


def _bytes(w: Window) -> int:
    return int(w.u.nbytes + w.y.nbytes)


def cut_block(ring: np.ndarray, end: int, w: int) -> np.ndarray:
    """The ring's columns for samples ``[end - w, end)`` (sample k at column k % cap): a view when contiguous."""
    cap = ring.shape[1]
    s0 = (end - w) % cap
    if s0 + w <= cap:
        return ring[:, s0 : s0 + w]
    return np.concatenate((ring[:, s0:], ring[:, : s0 + w - cap]), axis=1)


def due_windows(
    next_close: int, complete: int, hop: int, window: int, start: int, limit: int
) -> tuple[int, list[tuple[int, int]]]:
    """Windows closed by the samples up to ``complete`` (exclusive), and which of them to queue.

    The windows closed end at ``next_close``, ``next_close + hop``, ... up to
    ``complete``.  Returns their number and, oldest first, ``(i, end)`` of the
    ones to queue (``i``: rank among them from 0): the newest ``limit`` whose
    samples ``[end - window, end)`` are all still held (from ``start`` on).  The
    others are coalesced.  Cost independent of how many closed.
    """
    n = (complete - next_close) // hop + 1
    first = max(0, n - limit, -(-(start + window - next_close) // hop))
    return n, [(i, next_close + i * hop) for i in range(first, n)]
