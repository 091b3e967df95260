"""Per-stream bounded window buffer with time alignment and fault detection.

One :class:`WindowBuffer` per stream receives sample batches (combined
``samples`` batches, or separate ``u`` and ``y`` batches that are aligned by
time) and keeps the newest samples in a preallocated ring, one row per signal.
Every ``hop`` new complete samples a window of the newest ``window`` samples
*closes*: it is copied out into the stream's bounded queue of *pending* windows
(:mod:`streamid.online.pending`), which the identification worker empties when
it is free.  Every window waits its turn, oldest first; on a live stream the
waiting windows span at most ``max_pending_s`` of stream time (older ones are
counted as coalesced).  Both within stated bounds (see
:mod:`streamid.online.pending`): memory stays flat on an endless stream.

Time is integer nanoseconds.  Every sample gets an integer index
``k = round((t_ns - anchor_ns) / period_ns)`` on the stream's sample grid; u and
y columns are written at their indices, and a sample is *complete* once every
column holds it.  Faults are detected on that grid and never used across:

* a forward jump in time (publisher stopped, batches lost) is a *gap*: the
  window restarts after it, no stale window spans it;
* a batch entirely before the expected position is a *duplicate* (its sequence
  number was seen recently at that very time, however long ago it was in the
  ring) or *out of order*, and is dropped; a partial overlap is trimmed;
* a jump back further than the ring holds is a *restart* of the publisher's
  clock: the stream restarts from it;
* a different ``period_ns`` or a different set of signal names resets the
  stream (a new *epoch*: warm starts across it are meaningless); windows that
  closed before it stay queued and are identified in order (each carries its
  own epoch and period; a warm start's signature includes the period);
* non-finite values, values beyond ``max_abs_value``, bad periods and batches
  with non-increasing explicit timestamps are refused and counted;
* a period that differs from the one another live source (u vs y) still sends
  is refused (``period_mismatch``) until every live source agrees on it, so u
  and y on different sample clocks never make the stream reset back and forth.

Nothing here raises on bad data: every refusal increments a counter in
:meth:`WindowBuffer.counters` and appends a bounded event.  The buffer is
single-threaded and has no clock: a caller that shares it between threads
holds its own lock (the daemon does), and passes its clock reading as
``now_ns`` where a time is recorded.
"""

from __future__ import annotations

from collections import Counter, deque

import numpy as np

from streamid.online.pending import FAST_SPEED, PendingWindows, cut_block, due_windows
from streamid.online.window_types import (
    DEFAULT_HOP_S,
    DEFAULT_WINDOW_S,
    BatchLike,
    Event,
    Window,
    WindowParams,
    estimate_period,
    grid_runs,
)

__all__ = ["DEFAULT_HOP_S", "DEFAULT_WINDOW_S", "BatchLike", "Event", "Window", "WindowBuffer", "WindowParams"]

_RECENT_SEQS = 64
_RESTART = -1
_EVENTS_MAX = 256
_LIVE_BATCHES = 64  # a source that sent nothing in this many batches no longer vetoes a period change


class WindowBuffer:
    """Bounded, time-aligned window buffer of one stream (single-threaded, no clock).

    Parameters
    ----------
    stream
        Stream name (for windows and messages).
    params
        Window geometry and checks.
    """

    def __init__(self, stream: str, params: WindowParams) -> None:
        self.stream = stream
        self.params = params
        self._now_ns = 0  # the caller's clock reading of the call in progress
        self._events: deque[Event] = deque(maxlen=_EVENTS_MAX)
        self._counts: Counter[str] = Counter()
        self._bad: Counter[str] = Counter()
        self._resets: Counter[str] = Counter()
        self._fixed_in = params.inputs
        self._fixed_out = params.outputs
        self._inputs: tuple[str, ...] = params.inputs or ()
        self._outputs: tuple[str, ...] = params.outputs or ()
        self._period: int | None = None
        self._w = self._h = self._cap = self._slack = 0
        self._ring = np.empty((0, 0))
        self._rows: dict[str, int] = {}
        self._heads: list[int] = []
        self._anchor: int | None = None
        self._start = 0
        self._next_close = 0
        self._epoch = 0
        self._number = 0
        self._src_expect: dict[str, int] = {}
        self._src_seq: dict[str, int] = {}
        self._src_recent: dict[str, deque[tuple[int, int]]] = {}  # (seq, first grid index) of recent batches
        self._src_live: dict[str, int] = {}  # source -> batches_in at its last batch on the current period
        self._src_vote: dict[str, int] = {}  # source -> the other period it sends
        self._last_bad: dict[str, object] = {}
        self._queue = PendingWindows(params.max_pending_windows, params.max_pending_bytes)
        self.backlog_kept = True  # a live stream keeps its waiting windows (False, set by its identifier: the newest)
        self._last_t_ns: int | None = None
        self._closes: deque[tuple[int, int]] = deque(maxlen=16)  # (stream t_ns, caller's now_ns) of recent closes

    # ------------------------------------------------------------------ public
    @property
    def has_pending(self) -> bool:
        """Whether a closed window waits to be taken."""
        return bool(self._queue)

    @property
    def period_ns(self) -> int | None:
        """Current sample period, or None before the first good batch."""
        return self._period

    @property
    def lengths(self) -> tuple[int, int, int]:
        """(window, hop, ring capacity) in samples; zeros before the period is known."""
        return self._w, self._h, self._cap

    @property
    def output_names(self) -> tuple[str, ...]:
        """The stream's output signals, in model order (empty before the first batch with outputs)."""
        return self._outputs

    @property
    def pending_windows(self) -> int:
        """How many closed windows wait to be taken."""
        return len(self._queue)

    def take(self) -> Window | None:
        """Remove and return the oldest pending window (None if there is none)."""
        return self._queue.pop()

    @property
    def position(self) -> tuple[int, int]:
        """``(epoch, complete samples written in it)``: where the stream is, cheaply (no copies)."""
        return self._epoch, (self._complete() if self._heads else 0)

    def times_ns(self, first: int, n: int) -> np.ndarray:
        """Stream times (int64 ns) of ``n`` samples of the current epoch from index ``first`` on."""
        return int(self._anchor or 0) + (first + np.arange(n, dtype=np.int64)) * int(self._period or 0)

    @property
    def live(self) -> bool:
        """Whether stream time runs at about the caller's clock (< ``FAST_SPEED`` x over the last windows closed)."""
        if len(self._closes) < 2:
            return False
        (t0, n0), (t1, n1) = self._closes[0], self._closes[-1]
        return n1 > n0 and (t1 - t0) < FAST_SPEED * (n1 - n0)

    def recent(self, n: int) -> tuple[np.ndarray, np.ndarray] | None:
        """The newest ``n`` complete samples as ``(u (n, inputs), y (n, outputs))`` copies; None if fewer are held."""
        complete = self._complete()
        if n < 1 or not self._inputs or not self._outputs or complete - self._start < n:
            return None
        block = cut_block(self._ring, complete, n)
        n_in = len(self._inputs)
        return block[:n_in].T.copy(), block[n_in:].T.copy()

    def counters(self) -> dict[str, object]:
        """A snapshot of the counters (JSON-ready)."""
        out: dict[str, object] = {k: int(v) for k, v in sorted(self._counts.items())}
        out["bad"] = dict(sorted(self._bad.items()))
        out["bad_total"] = int(sum(self._bad.values()))
        out["resets"] = dict(sorted(self._resets.items()))
        out["epoch"] = self._epoch
        out["period_ns"] = self._period
        out["window_samples"] = self._w
        out["hop_samples"] = self._h
        out["buffered_samples"] = self._complete() - self._start if self._heads else 0
        out["pending"] = bool(self._queue)
        out["pending_windows"] = len(self._queue)
        out["pending_bytes"] = self._queue.nbytes
        out["pending_windows_peak"] = self._queue.peak
        out["pending_bytes_peak"] = self._queue.peak_bytes
        out["max_pending_windows"] = self._queue.limit
        out["pending_bytes_max"] = min(self._queue.limit * self._w * len(self._rows) * 8, self._queue.max_bytes)
        out.update(pending_span_s=self._queue.span_ns() / 1e9, pending_oldest_received_ns=self._queue.oldest_received_ns(),
                   max_pending_s=self.params.max_pending_s, backlog_kept=self.backlog_kept)
        out["live"] = self.live
        out["inputs"] = list(self._inputs)
        out["outputs"] = list(self._outputs)
        out["last_t_ns"] = self._last_t_ns
        out["last_bad"] = dict(self._last_bad)
        return out

    def drain_events(self) -> list[Event]:
        """Remove and return the events recorded since the last call (at most the newest 256)."""
        ev = list(self._events)
        self._events.clear()
        return ev

    def count_bad(self, kind: str, message: str = "", *, now_ns: int = 0) -> None:
        """Count a bad message found before the buffer (e.g. a decode error)."""
        self._now_ns = now_ns
        self._refuse(kind, message)

    def append(self, batch: BatchLike, source: str = "samples", *, now_ns: int = 0) -> int:
        """Append one batch; returns how many samples were written.

        ``source`` names the key the batch came on (``samples``, ``u`` or
        ``y``); sequence numbers and continuity are tracked per source.
        ``now_ns`` is the caller's clock reading, stored in the windows this
        batch closes and in the events it raises.  Never raises on bad data:
        refusals are counted.
        """
        self._now_ns = now_ns
        written = self._append(batch, source)
        if written:
            self._maybe_close()
        return written

    # ---------------------------------------------------------------- helpers
    def _event(self, kind: str, message: str) -> None:
        self._events.append(Event(kind, f"{self.stream}: {message}", self._last_t_ns, self._now_ns))

    def _refuse(self, kind: str, message: str) -> None:
        self._bad[kind] += 1
        self._last_bad = {"kind": kind, "message": message or kind, "received_ns": self._now_ns}
        self._event(f"bad.{kind}", message or kind)

    def _period_conflict(self, source: str, period: int, seq: int) -> bool:
        """Whether another live source still sends the current period (then the batch is refused)."""
        now = self._counts["batches_in"]
        self._src_vote[source] = period
        others = sorted(
            s for s, at in self._src_live.items()
            if s != source and now - at <= _LIVE_BATCHES and self._src_vote.get(s) != period
        )
        if not others:
            return False
        self._refuse(
            "period_mismatch",
            f"{source} batch seq {seq} has period_ns={period} but {', '.join(others)} batches have period_ns="
            f"{self._period}; u and y must share one sample clock (refused until every source agrees)",
        )
        return True

    def _complete(self) -> int:
        return min(self._heads) if self._heads else 0

    def _select(self, batch: BatchLike) -> tuple[list[str], list[np.ndarray]] | None:
        """Names and arrays this batch writes, after layout checks (None: refused)."""
        b_in, b_out = batch.inputs, batch.outputs
        names: list[str] = []
        arrays: list[np.ndarray] = []
        layout_changed = False
        changes: list[str] = []
        for part, fixed, attr in ((b_in, self._fixed_in, "_inputs"), (b_out, self._fixed_out, "_outputs")):
            if not part:
                continue
            if fixed is not None:
                missing = [s for s in fixed if s not in part]
                if missing:
                    self._refuse("missing_signal", f"batch lacks configured signal(s) {missing}; it has {sorted(part)}")
                    return None
                chosen = fixed
            else:
                chosen = tuple(part)
                current = getattr(self, attr)
                if set(chosen) != set(current):
                    if current:
                        changes.append(f"{list(current)} to {list(chosen)}")
                    setattr(self, attr, chosen)
                    layout_changed = True
                else:
                    chosen = current
            for s in chosen:
                names.append(s)
                arrays.append(part[s])
        if changes:  # one reset per batch, however many of its signal sets changed
            self._resets["schema"] += 1
            self._event("reset.schema", f"signals changed from {' and '.join(changes)}")
        if layout_changed:
            self._realloc()
        return names, arrays

    def _realloc(self) -> None:
        """(Re)allocate the ring for the current layout and period; new epoch."""
        self._epoch += 1
        self._rows = {s: i for i, s in enumerate(self._inputs + self._outputs)}
        self._anchor = None
        self._src_expect.clear()
        self._src_seq.clear()
        self._src_recent.clear()
        # (windows already closed stay queued: complete copies, each with its own epoch and period)
        self._closes.clear()
        if self._period is None:
            self._ring = np.empty((0, 0))
            self._heads = []
            return
        self._w, self._h = self.params.samples(self._period)
        self._slack = self.params.align_slack_samples or max(self._w, self._h)
        self._cap = self._w + self._h + self._slack
        nrows = len(self._rows)
        if self._ring.shape != (nrows, self._cap):
            self._ring = np.zeros((nrows, self._cap))
        self._heads = [0] * nrows
        self._start = 0
        self._next_close = self._w

    def _full_reset(self, kind: str, message: str) -> None:
        self._resets[kind] += 1
        self._event(f"reset.{kind}", message)
        self._src_expect.clear()
        self._src_seq.clear()
        self._src_recent.clear()
        self._heads = [0] * len(self._rows)
        self._start = 0
        self._next_close = self._w
        self._closes.clear()

    def _append(self, batch: BatchLike, source: str) -> int:
        self._counts["batches_in"] += 1
        n = len(batch)
        if n == 0:
            self._counts["empty_batches"] += 1
            return 0
        period = batch.period_ns
        if period == 0 and batch.t_ns is not None:  # irregular time stamps: keep or estimate the grid
            if self._period is not None:
                period = self._period
            elif n >= 2:
                period = estimate_period(np.asarray(batch.t_ns, dtype=np.int64))
        if not isinstance(period, (int, np.integer)) or period <= 0:
            self._refuse(
                "period", f"period_ns must be an integer > 0 (or t_ns given to estimate it); got {period!r}"
            )
            return 0
        period = int(period)
        if period != self._period:
            w, _ = self.params.samples(period)
            if w > self.params.max_window_samples:
                self._refuse(
                    "period",
                    f"period_ns={period} makes the window {w} samples, more than max_window_samples="
                    f"{self.params.max_window_samples}",
                )
                return 0
        sel = self._select(batch)
        if sel is None:
            return 0
        names, arrays = sel
        # one pass over the values: NaN fails both comparisons, inf/absurd the bound
        lim = self.params.max_abs_value
        for s, a in zip(names, arrays, strict=True):
            if a.shape != (n,):
                self._refuse("shape", f"signal {s!r} has shape {a.shape}, expected ({n},)")
                return 0
            hi = a.max()
            lo = a.min()
            if not (hi <= lim and lo >= -lim):
                if not (np.isfinite(hi) and np.isfinite(lo)):
                    self._refuse("nonfinite", f"signal {s!r} holds NaN or infinity (batch seq {batch.seq})")
                else:
                    self._refuse(
                        "magnitude", f"signal {s!r} reaches {max(abs(hi), abs(lo)):.3g}, beyond max_abs_value={lim:g}"
                    )
                return 0
        if period != self._period and self._period is not None and self._period_conflict(source, period, batch.seq):
            return 0
        if period != self._period:
            if self._period is not None:
                self._event("reset.period", f"sample period changed from {self._period} ns to {period} ns")
                self._resets["period"] += 1
            self._period = period
            # the sources that asked for this period are live on it; the others stopped
            self._src_live = {s: at for s, at in self._src_live.items() if self._src_vote.get(s) == period}
            self._src_vote.clear()
            self._realloc()
        elif not self._heads:
            self._realloc()
        self._src_live[source] = self._counts["batches_in"]
        self._src_vote.pop(source, None)
        t0 = int(batch.t0_ns)
        if self._anchor is None:
            self._anchor = t0 if batch.t_ns is None else int(batch.t_ns[0])
        # sample indices on the grid: one run for regular batches
        if batch.t_ns is None:
            runs = [((t0 - self._anchor + period // 2) // period, 0, n)]
        else:
            grid = self._runs(np.asarray(batch.t_ns, dtype=np.int64), period, batch.seq)
            if grid is None:
                return 0
            runs = grid
        written = 0
        for i, (k0, off, length) in enumerate(runs):
            got = self._accept_run(source, int(batch.seq), k0, off, length, names, arrays, first=i == 0)
            if got == _RESTART:  # the publisher's clock went back: restart the grid at this batch
                self._anchor = self._anchor + k0 * period
                runs_again = [(k - k0, o, m) for k, o, m in runs]
                for j, (k1, off1, len1) in enumerate(runs_again):
                    written += self._accept_run(source, int(batch.seq), k1, off1, len1, names, arrays, first=j == 0)
                break
            written += got
        if written:
            self._counts["samples_in"] += written
            self._last_t_ns = self._anchor + (self._complete() - 1) * period
        return written

    def _runs(self, t_ns: np.ndarray, period: int, seq: int) -> list[tuple[int, int, int]] | None:
        runs = grid_runs(t_ns, self._anchor, period)  # type: ignore[arg-type]
        if runs is None:
            self._refuse("nonmonotonic", f"batch seq {seq}: explicit t_ns not strictly increasing on the sample grid")
        return runs

    def _accept_run(
        self, source: str, seq: int, k0: int, off: int, n: int, names: list[str], arrays: list[np.ndarray], *, first: bool
    ) -> int:
        exp = self._src_expect.get(source)
        recent = self._src_recent.get(source)
        k_first = k0
        if exp is not None and first:
            last = self._src_seq.get(source)
            if last is not None and seq != last + 1 and all(q != seq for q, _ in recent or ()):
                self._counts["seq_jumps"] += 1
            if k0 > exp:
                self._counts["gaps"] += 1
                self._counts["gap_samples"] += k0 - exp
                self._event("gap", f"{source}: {k0 - exp} samples missing before batch seq {seq}")
            elif k0 < exp:
                if recent is not None and (seq, k0) in recent:  # the same batch again, however old
                    self._refuse("duplicate", f"{source}: batch seq {seq} was already received")
                    return 0
                if k0 + n <= exp - self._cap:
                    self._full_reset("restart", f"{source}: time went back {exp - k0} samples (publisher restarted?)")
                    return _RESTART
                if k0 + n <= exp:
                    self._refuse("out_of_order", f"{source}: batch seq {seq} lies before the expected position")
                    return 0
                else:
                    self._counts["overlap_samples"] += exp - k0
                    cut = exp - k0
                    off, n, k0 = off + cut, n - cut, exp
        elif exp is not None and k0 > exp:  # gap inside a batch
            self._counts["gaps"] += 1
            self._counts["gap_samples"] += k0 - exp
            self._event("gap", f"{source}: {k0 - exp} samples missing inside batch seq {seq}")
        self._src_expect[source] = k0 + n
        self._src_seq[source] = seq
        if recent is None:
            recent = self._src_recent[source] = deque(maxlen=_RECENT_SEQS)
        if first:
            recent.append((seq, k_first))
        return self._write(k0, off, n, names, arrays)

    def _write(self, a: int, off: int, n: int, names: list[str], arrays: list[np.ndarray]) -> int:
        b = a + n
        heads = self._heads
        rows = [self._rows[s] for s in names]
        if n > self._cap:  # only the newest cap samples can be held
            self._counts["samples_discarded"] += n - self._cap
            off += n - self._cap
            a = b - self._cap
        lo = min(heads[r] for r in rows)
        if a < self._start:
            cut = self._start - a
            if cut >= b - a:
                self._counts["samples_discarded"] += b - a
                return 0
            self._counts["samples_discarded"] += cut
            off, a = off + cut, self._start
        if a > lo:  # a column would have a hole: restart the window at a
            self._start = a
            self._next_close = a + self._w
            for r in range(len(heads)):
                if r in rows or heads[r] < a:
                    heads[r] = a
            self._resets["gap"] += 1
        elif a < lo:  # already held (another source moved the ring on)
            cut = lo - a
            if cut >= b - a:
                self._counts["samples_discarded"] += b - a
                return 0
            self._counts["samples_discarded"] += cut
            off, a = off + cut, lo
        cap = self._cap
        s0 = a % cap
        m = b - a
        first_len = min(m, cap - s0)
        ring = self._ring
        for r, arr in zip(rows, arrays, strict=True):
            ring[r, s0 : s0 + first_len] = arr[off : off + first_len]
            if first_len < m:
                ring[r, : m - first_len] = arr[off + first_len : off + m]
            heads[r] = b
        maxhead = max(heads)
        complete = min(heads)
        if maxhead - complete > self._slack:
            x = maxhead - self._slack
            lagging = [r for r in range(len(heads)) if heads[r] < x]
            for r in lagging:
                heads[r] = x
            self._start = max(self._start, x)
            self._next_close = max(self._next_close, self._start + self._w)
            self._counts["unaligned"] += 1
            names_lag = [s for s, r in self._rows.items() if r in lagging]
            self._event("unaligned", f"signal(s) {names_lag} lag more than {self._slack} samples behind; skipped ahead")
        self._start = max(self._start, maxhead - cap)
        return m

    def _maybe_close(self) -> bool:
        complete = self._complete()
        if complete < self._next_close or not self._inputs or not self._outputs:
            return False
        if len(self._rows) != len(self._inputs) + len(self._outputs):
            return False
        n, keep = due_windows(self._next_close, complete, self._h, self._w, self._start, self._queue.limit)
        self._closes.append((self._anchor + (self._next_close + (n - 1) * self._h) * self._period, self._now_ns))  # type: ignore[operator]
        live = self.live
        span_ns = (round(self.params.max_pending_s * 1e9) if self.backlog_kept else 0) if live else None  # a live backlog
        self._next_close += n * self._h
        closed0 = self._counts["windows_closed"]
        self._counts["windows_closed"] += n
        coalesced = n - len(keep)
        n_in = len(self._inputs)
        for i, end in keep:
            block = cut_block(self._ring, end, self._w)
            self._number += 1
            window = Window(
                stream=self.stream,
                number=self._number,
                epoch=self._epoch,
                t0_ns=self._anchor + (end - self._w) * self._period,  # type: ignore[operator]
                period_ns=self._period,  # type: ignore[arg-type]
                input_names=self._inputs,
                output_names=self._outputs,
                u=block[:n_in].T.copy(),
                y=block[n_in:].T.copy(),
                received_ns=self._now_ns,
                coalesced_before=0,  # set when taken (see PendingWindows.pop)
            )
            coalesced += self._queue.push(closed0 + i + 1, window, max_span_ns=span_ns)
            self._counts["windows_emitted"] += 1
            self._event("window.closed", f"window {self._number} closed ({self._w} samples)")
        if coalesced:
            why = (f"bounds max_pending_windows={self._queue.limit}, max_pending_bytes={self._queue.max_bytes}" + (
                (f", max_pending_s={self.params.max_pending_s:g} (live)" if self.backlog_kept else "; live, no model: newest only") if live else ""))
            self._event("window.coalesced", f"{coalesced} window(s) coalesced: identification is behind ({why})")
        self._counts["windows_coalesced"] += coalesced
        return bool(keep)
