"""Fair scheduling of identifications across streams.

Two rules keep one stream from starving the others:

* **Oldest waiting first.**  Streams with a closed window wait in one queue,
  in the order their windows became due; a worker takes the first stream that
  is not busy (a stream has at most one job out).  A stream is queued once,
  whatever the number of its windows, so a stream that closes many windows
  cannot push the others back.
* **A stream's first run before the others' next jobs.**  A stream none of
  whose updates has finished yet (it has no model: its first, cold, run) is
  taken before the streams already served, oldest first among such streams.
  Once served, a stream whose windows wait loses nothing by waiting (a live
  stream keeps its backlog, :mod:`streamid.online.pending`, and catches up by
  refreshes), while a stream without a model has nothing to serve; every
  stream gets this precedence once (until its first update finishes), so it
  cannot starve the others.  While such a stream waits, a long run lets no
  short job in either (below).
* **Short jobs go between the generations of long ones.**  A run polls its
  stop flag between generations; the daemon uses that point
  (:meth:`Scheduler.take_short`): once the running job has taken
  :data:`SLICE_S` of its own time, every waiting stream whose next job is
  *short* -- expected under :data:`SHORT_JOB_S` from its own recent
  seconds per generation -- is run right there, on the same worker, to its
  end, and then the long run goes on.  A healthy stream's update therefore
  waits at most one generation of a long run (bounded by
  ``daemon.max_identification_bytes``), not the whole run.  The short jobs
  run inside one long run take at most :data:`NESTED_SHARE` times its own
  time (measured: without that bound, an overloaded daemon's long runs never
  ended while the others' short jobs kept coming).  Nested jobs are
  never interrupted themselves (one level), and the time they take is not
  counted against the long run's ``max_identification_s``.

A stream's expected job time is its exponentially averaged seconds per
generation (weight :data:`_EMA` for the newest) times the generations of the
next run (warm or cold); a stream with no finished run yet is not short.
"""

from __future__ import annotations

import threading
import time
from collections import deque
from collections.abc import Callable
from typing import Generic, Literal, TypeVar

__all__ = ["Scheduler", "SLICE_S", "SHORT_JOB_S", "NESTED_SHARE"]

#: A running job takes this many seconds of its own time before it lets short jobs in.
SLICE_S = 0.05
#: A job expected to take less than this is short: it may run between two generations of a longer one.
SHORT_JOB_S = 1.0
#: The short jobs run inside a long one take at most this many times the long run's own time: it keeps
#: at least half of its worker, so an endless supply of short jobs (an overloaded daemon) cannot starve it.
NESTED_SHARE = 1.0
_EMA = 0.5

T = TypeVar("T")
#: ``try_take(name)``: a job, None (nothing due: dequeued) or False (busy: keeps its place).
TryTake = Callable[[str], "T | None | Literal[False]"]


class Scheduler(Generic[T]):
    """The queue of streams with a window due (thread-safe).

    ``try_take(name)`` is called under the queue's lock with a stream's name;
    it returns a job (the stream is then dequeued), ``None`` when the stream has
    nothing due (dequeued too), or ``False`` when the stream is busy (it keeps
    its place).
    """

    def __init__(self) -> None:
        self._cond = threading.Condition()
        self._ready: deque[str] = deque()
        self._queued: set[str] = set()
        self._sec_per_gen: dict[str, float] = {}

    # ------------------------------------------------------------------ queue
    def wake(self, name: str) -> None:
        """``name`` has a window due: queue it (once) and wake a worker."""
        with self._cond:
            if name not in self._queued:
                self._queued.add(name)
                self._ready.append(name)
                self._cond.notify()

    def forget(self, name: str) -> None:
        """Drop a stream's history and queue place (its slot was released)."""
        with self._cond:
            self._sec_per_gen.pop(name, None)
            if name in self._queued:
                self._queued.discard(name)
                self._ready.remove(name)

    def waiting(self) -> int:
        """Streams queued with a window due (those busy included)."""
        with self._cond:
            return len(self._ready)

    def any_waiting(self, which: Callable[[str], bool]) -> bool:
        """Whether a queued stream satisfies ``which`` (called under the queue's lock)."""
        with self._cond:
            return any(which(name) for name in self._ready)

    def notify_all(self) -> None:
        """Wake every waiting worker (stop)."""
        with self._cond:
            self._cond.notify_all()

    def take(self, try_take: TryTake[T], stop: threading.Event, wait_s: float = 0.2,
             first: Callable[[str], bool] | None = None) -> T | None:
        """The first job of the oldest waiting stream that is not busy, the streams ``first`` names (their first
        run) before the others; None after ``wait_s`` or on stop."""
        with self._cond:
            end = time.monotonic() + wait_s
            while not stop.is_set():
                job = self._scan(try_take, first) if first is not None else None
                if job is None:
                    job = self._scan(try_take, None)
                if job is not None:
                    return job
                left = end - time.monotonic()
                if left <= 0:
                    return None
                self._cond.wait(left)
            return None

    def take_short(self, try_take: TryTake[T], expected_s: Callable[[str], float | None], exclude: str) -> T | None:
        """Like :meth:`take` without waiting, among streams whose next job is short (not ``exclude``)."""

        def short(name: str) -> bool:
            if name == exclude:
                return False
            t = expected_s(name)
            return t is not None and t < SHORT_JOB_S

        with self._cond:
            return self._scan(try_take, short)

    def _scan(self, try_take: TryTake[T], accept: Callable[[str], bool] | None) -> T | None:
        for name in list(self._ready):
            if accept is not None and not accept(name):
                continue
            job = try_take(name)
            if job is False:  # busy: keeps its place (a job is never False itself)
                continue
            self._ready.remove(name)
            self._queued.discard(name)
            if job is not None:
                return job
        return None

    # ------------------------------------------------------------------ history
    def record(self, name: str, seconds: float, generations: int) -> None:
        """A run of ``name`` took ``seconds`` for ``generations`` generations."""
        if generations <= 0 or not seconds >= 0:
            return
        rate = seconds / generations
        with self._cond:
            old = self._sec_per_gen.get(name)
            self._sec_per_gen[name] = rate if old is None else _EMA * rate + (1 - _EMA) * old

    def sec_per_generation(self, name: str) -> float | None:
        """The stream's averaged seconds per generation (None: no run finished yet)."""
        return self._sec_per_gen.get(name)
