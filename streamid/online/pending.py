"""The bounded queue of closed windows waiting for identification (one per stream).

Two regimes, decided by how fast stream time runs against the caller's clock
(the ``now_ns`` of the batches; :class:`~streamid.online.window.WindowBuffer`
measures it over the last 16 windows closed):

* **Stream time faster than the clock** (at least :data:`FAST_SPEED` x: a log
  replayed with ``--rate 4`` or ``--max-speed``; a record given to
  ``learn_many`` without clock readings): every window waits its turn, oldest
  first, so every window of the log is identified, in order.
* **A live stream** (about 1x) that falls behind keeps its waiting windows too,
  in order, as long as the oldest of them ends at most ``max_pending_s`` seconds
  of stream time before the newest (default :data:`DEFAULT_MAX_PENDING_S`): the
  backlog a stream builds while it waits for its first (cold) run, or behind a
  long run of another stream, is worked through by cheap refreshes of the
  champion (:mod:`streamid.online.refresh`) once it has one.  Past that bound
  the oldest waiting windows are dropped (*coalesced*): the backlog is then
  older than the bound says a decision is still worth making.  A stream
  without a model whose last update failed keeps only its newest window (its
  identifier clears ``WindowBuffer.backlog_kept``): each waiting window would
  cost another such run.

Both are bounded by ``max_pending_windows`` and ``max_pending_bytes`` (per
stream settings, default 1000 windows and 64 MiB); past them the oldest waiting
window is dropped.  Windows not identified are counted as *coalesced*.

**Storage: one span of samples.**  Consecutive windows of one stream overlap
(a 10 s window every 1 s: 90 %), so the queue keeps the samples of a run of
waiting windows of one epoch once, as one array (rows: samples; columns:
inputs then outputs), and cuts a window's copy out of it when it is taken.  A
backlog of ``k`` windows of ``w`` samples every ``h`` holds ``w + (k - 1) h``
samples rather than ``k w`` (60 windows of a 10 s, 2 kHz stream: 2.2 MB instead
of 19 MB).  The queue's memory is reported as ``pending_bytes`` (the samples
held, each once; peak ``pending_bytes_peak``, bound ``pending_bytes_max``); a
span's array grows by doubling, never beyond ``max_pending_bytes`` (or one
window), and is freed when its last window is taken.
"""

from __future__ import annotations

import dataclasses
from collections import deque

import numpy as np

from streamid.online.window_types import DEFAULT_MAX_PENDING_S, MAX_PENDING_WINDOWS, Window

__all__ = ["PendingWindows", "cut_block", "due_windows", "FAST_SPEED", "MAX_PENDING_WINDOWS", "DEFAULT_MAX_PENDING_S"]

#: Stream time running at least this many times faster than the caller's clock queues every window.
FAST_SPEED = 1.25


class _Span:
    """Waiting windows of one epoch that overlap or touch, sharing their samples (see the module docstring).

    Row ``r`` of ``data`` is sample ``k0 + r`` of the grid ``t_ref + k * period``; rows ``[lo - k0, hi - k0)``
    are held for the windows still waiting.
    """

    __slots__ = ("key", "period", "t_ref", "n_in", "data", "k0", "lo", "hi")

    def __init__(self, w: Window) -> None:
        self.key = (w.stream, w.epoch, w.period_ns, w.input_names, w.output_names)
        self.period = w.period_ns
        self.t_ref = w.t0_ns
        self.n_in = w.u.shape[1]
        self.data = np.concatenate((w.u, w.y), axis=1)
        self.k0 = self.lo = 0
        self.hi = w.n

    def k_of(self, w: Window) -> int | None:
        """``w``'s first sample on this span's grid, if ``w`` continues it (same epoch, no gap, later); else None."""
        if (w.stream, w.epoch, w.period_ns, w.input_names, w.output_names) != self.key:
            return None
        d = w.t0_ns - self.t_ref
        if d % self.period:
            return None
        k = d // self.period
        return k if self.lo <= k <= self.hi <= k + w.n else None

    def extend(self, w: Window, k: int, max_rows: int) -> None:
        """Append the samples of ``w`` (first sample ``k``) beyond the span's end."""
        new = k + w.n - self.hi
        if new <= 0:
            return
        live = self.hi - self.lo
        if self.hi - self.k0 + new > self.data.shape[0]:  # out of room: a new array, the live rows first
            rows = live + new
            grown = np.empty((max(rows, min(2 * rows, max_rows)), self.data.shape[1]))
            grown[:live] = self.data[self.lo - self.k0:self.hi - self.k0]
            self.data, self.k0 = grown, self.lo
        at = self.hi - self.k0
        self.data[at:at + new, :self.n_in] = w.u[w.n - new:]
        self.data[at:at + new, self.n_in:] = w.y[w.n - new:]
        self.hi += new

    def cut(self, k: int, n: int) -> tuple[np.ndarray, np.ndarray]:
        """Copies of u and y of the ``n`` samples from ``k`` on."""
        block = self.data[k - self.k0:k - self.k0 + n]
        return np.ascontiguousarray(block[:, :self.n_in]), np.ascontiguousarray(block[:, self.n_in:])

    @property
    def row_bytes(self) -> int:
        return int(self.data.shape[1] * self.data.itemsize)

    @property
    def nbytes(self) -> int:
        return (self.hi - self.lo) * self.row_bytes


@dataclasses.dataclass
class _Item:
    closed_index: int
    window: Window  # its metadata (u and y: empty; cut from the span when taken)
    span: _Span
    k: int  # its first sample on the span's grid
    n: int
    t_end_ns: int


_EMPTY = np.empty((0, 0))


class PendingWindows:
    """FIFO of at most ``limit`` closed windows (not thread-safe: the buffer's lock guards it).

    Parameters
    ----------
    limit
        Most windows held; pushing one more drops the oldest.
    max_bytes
        Most bytes of samples held (each sample once; the newest window is always kept).
    """

    def __init__(self, limit: int = 1, max_bytes: int = 64 * 2**20) -> None:
        if not (isinstance(limit, int) and not isinstance(limit, bool) and 1 <= limit <= MAX_PENDING_WINDOWS):
            raise ValueError(f"limit must be an integer in [1, {MAX_PENDING_WINDOWS}]; got {limit!r}")
        self.limit = limit
        self.max_bytes = max_bytes
        self._q: deque[_Item] = deque()
        self._last_taken = 0  # closing index (1, 2, ... over all epochs) of the last window taken
        self.nbytes = 0
        self.peak = 0  # most windows ever waiting at once
        self.peak_bytes = 0

    def __len__(self) -> int:
        return len(self._q)

    def __bool__(self) -> bool:
        return bool(self._q)

    def span_ns(self) -> int:
        """Stream time from the oldest waiting window's end to the newest's (0: fewer than two waiting)."""
        return self._q[-1].t_end_ns - self._q[0].t_end_ns if self._q else 0

    def oldest_received_ns(self) -> int | None:
        """The caller's clock reading when the oldest waiting window closed (None: none waits)."""
        return self._q[0].window.received_ns if self._q else None

    def push(self, closed_index: int, window: Window, *, newest_only: bool = False,
             max_span_ns: int | None = None) -> int:
        """Add a window (``closed_index``: its rank among all windows closed); returns how many were dropped.

        ``newest_only``: drop every waiting window first.  ``max_span_ns``: drop the waiting windows that end
        more than this before ``window`` ends (a live stream's bound in stream time).
        """
        dropped = 0
        t_end = window.t_end_ns
        while self._q and (newest_only or len(self._q) >= self.limit
                           or (max_span_ns is not None and t_end - self._q[0].t_end_ns > max_span_ns)
                           or self.nbytes + self._added_bytes(window) > self.max_bytes):
            self._drop_oldest()
            dropped += 1
        last = self._q[-1].span if self._q else None
        k = last.k_of(window) if last is not None else None
        if last is not None and k is not None:
            before = last.nbytes
            row = last.row_bytes
            last.extend(window, k, max(1, self.max_bytes // row))
            self.nbytes += last.nbytes - before
            span = last
        else:
            span = _Span(window)
            k = 0
            self.nbytes += span.nbytes
        meta = dataclasses.replace(window, u=_EMPTY, y=_EMPTY)
        self._q.append(_Item(closed_index, meta, span, k, window.n, t_end))
        self.peak = max(self.peak, len(self._q))
        self.peak_bytes = max(self.peak_bytes, self.nbytes)
        return dropped

    def pop(self) -> Window | None:
        """The oldest window, with ``coalesced_before`` = windows closed since the last one taken, never identified."""
        if not self._q:
            return None
        it = self._q[0]
        u, y = it.span.cut(it.k, it.n)
        self._drop_oldest()
        skipped = max(0, it.closed_index - self._last_taken - 1)
        self._last_taken = it.closed_index
        return dataclasses.replace(it.window, u=u, y=y, coalesced_before=skipped)

    def clear(self) -> int:
        """Drop every waiting window (a reset of the stream); returns how many."""
        n = len(self._q)
        self._q.clear()
        self.nbytes = 0
        return n

    def _added_bytes(self, window: Window) -> int:
        """Bytes ``window`` would add: the samples beyond the last span's end, or all of it."""
        last = self._q[-1].span if self._q else None
        k = last.k_of(window) if last is not None else None
        if last is None or k is None:
            return int(window.u.nbytes + window.y.nbytes)
        return max(0, k + window.n - last.hi) * last.row_bytes

    def _drop_oldest(self) -> None:
        """Remove the oldest waiting window and release the samples no later window of its span needs."""
        it = self._q.popleft()
        span = it.span
        before = span.nbytes
        nxt = self._q[0] if self._q else None
        if nxt is not None and nxt.span is span:
            span.lo = nxt.k
        else:  # its span's last window: the span is freed
            span.lo = span.hi
            span.data = _EMPTY
        self.nbytes -= before - span.nbytes


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
