"""Fair intake: many small publishers cannot starve a healthy stream.

Every message costs the daemon about the same to take in (decode, append, events) whatever
its size, so a swarm of publishers of 1-sample batches (50 streams, ~12,000 batches/s) used to
take the receiving threads, the GIL and the workers from every other stream: a healthy stream
beside them had 29 of its 108 windows coalesced, and its status stopped answering at 1 kHz per
publisher.  :class:`IntakeBudget` is checked for each message *before* it is decoded (a dict
lookup and a few additions under a lock: bounded work per message):

* the budget is ``daemon.max_batches_per_s`` messages per second over all streams, counted in
  epochs of :data:`EPOCH_S`;
* while two or more streams send, each is guaranteed an equal share of the budget (the budget
  divided by the streams that sent in this or the last epoch), whatever the others send;
* a stream above its share once the whole budget of the epoch is used has its message dropped,
  undecoded, and counted (``intake_dropped`` on its status and the daemon's); below its share,
  or while the budget is not used up, nothing is dropped (the budget is work-conserving, and a
  stream sending alone is never throttled);
* the total taken in per epoch is at most twice the budget (the budget, plus every stream's
  guaranteed share).

The key of a message names its stream only (``streamid/<stream>/samples``, ``/u``, ``/y``: one
budget per stream, not per publisher).  The streams themselves are bounded by ``max_streams``.
"""

from __future__ import annotations

import threading
import time
from collections.abc import Callable

__all__ = ["EPOCH_S", "IntakeBudget"]

#: Length of one accounting epoch (seconds).
EPOCH_S = 0.1


class IntakeBudget:
    """The daemon's intake budget (see the module docstring); thread-safe.

    Parameters
    ----------
    per_s
        Messages per second over all streams (``daemon.max_batches_per_s``).
    clock
        Monotonic seconds (a test passes its own).
    """

    def __init__(self, per_s: int, *, clock: Callable[[], float] = time.monotonic) -> None:
        if not per_s >= 1:
            raise ValueError(f"per_s must be >= 1 message per second; got {per_s!r}")
        self.per_epoch = float(per_s) * EPOCH_S
        self._clock = clock
        self._lock = threading.Lock()
        self._end = -1.0
        self._counts: dict[str, int] = {}
        self._total = 0
        self._active_before = 1
        self.dropped = 0

    def admit(self, stream: str) -> bool:
        """Whether a message of ``stream`` is taken in now (False: drop it undecoded; counted in :attr:`dropped`)."""
        now = self._clock()
        with self._lock:
            if now >= self._end:
                self._active_before = len(self._counts)
                self._counts.clear()
                self._total = 0
                self._end = now + EPOCH_S
            n = self._counts.get(stream, 0)
            active = max(self._active_before, len(self._counts) + (n == 0))
            if active >= 2 and self._total >= self.per_epoch and n >= self.per_epoch / active:
                self.dropped += 1
                return False
            self._counts[stream] = n + 1
            self._total += 1
            return True
