"""The bounded queue of closed windows waiting for identification (one per stream).

``max_pending_windows`` (a per-stream setting, default 1) bounds it:

* **1** (the default, for live streams): a window that closes while another one
  is still waiting replaces it.  The worker always gets the newest data, and a
  slow identification never builds a backlog.
* **N > 1** (e.g. a log replayed at max speed, where every window should be
  identified): up to N closed windows wait, oldest first; when a window closes
  with N already waiting, the oldest waiting one is dropped.

Either way the windows not identified are counted as *coalesced*, and the
queue's memory is bounded by ``N * window_samples * (inputs + outputs) * 8``
bytes (each window is a float64 copy of its samples), reported as
``pending_bytes`` / ``pending_bytes_max`` in the stream's status.
"""

from __future__ import annotations

import dataclasses
from collections import deque

import numpy as np

from streamid.online.window_types import MAX_PENDING_WINDOWS, Window

__all__ = ["PendingWindows", "cut_block", "due_windows", "MAX_PENDING_WINDOWS"]


class PendingWindows:
    """FIFO of at most ``limit`` closed windows (not thread-safe: the buffer's lock guards it).

    Parameters
    ----------
    limit
        Most windows held; pushing one more drops the oldest.
    """

    def __init__(self, limit: int = 1) -> None:
        if not (isinstance(limit, int) and not isinstance(limit, bool) and 1 <= limit <= MAX_PENDING_WINDOWS):
            raise ValueError(f"limit must be an integer in [1, {MAX_PENDING_WINDOWS}]; got {limit!r}")
        self.limit = limit
        self._q: deque[tuple[int, Window]] = deque()
        self._last_taken = 0  # closing index (1, 2, ... over all epochs) of the last window taken
        self.nbytes = 0
        self.peak = 0  # most windows ever waiting at once
        self.peak_bytes = 0

    def __len__(self) -> int:
        return len(self._q)

    def __bool__(self) -> bool:
        return bool(self._q)

    def push(self, closed_index: int, window: Window) -> int:
        """Add a window (``closed_index``: its rank among all windows closed); returns how many were dropped."""
        dropped = 0
        while len(self._q) >= self.limit:
            _, old = self._q.popleft()
            self.nbytes -= _bytes(old)
            dropped += 1
        self._q.append((closed_index, window))
        self.nbytes += _bytes(window)
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
