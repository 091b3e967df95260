"""The daemon's hold on one stream (:class:`StreamSlot`) and the forwarding of its events to the log and Rerun."""

from __future__ import annotations

import logging
import threading
import time
from collections import deque
from collections.abc import Iterable
from typing import Any

from streamid.online import OnlineIdentifier

__all__ = ["StreamSlot", "forward_events", "evictable", "BAD_LOG_EVERY_S", "EVICT_GRACE_S"]

_log = logging.getLogger("streamid.daemon.service")
#: Bad input of one kind on one stream is logged at most once per this many seconds (the rest is counted).
BAD_LOG_EVERY_S = 10.0
#: A discovered slot that never had a valid batch may be taken by a new stream after this long (at most stream_idle_s).
EVICT_GRACE_S = 1.0


class StreamSlot:
    """One served stream: its :class:`OnlineIdentifier` behind a lock, and what only the daemon knows."""

    def __init__(self, ident: OnlineIdentifier, configured: bool = False) -> None:
        self.ident = ident
        self.lock = threading.Lock()  # every call into ident holds it (Zenoh callbacks, workers, housekeeping)
        self.publish_order = threading.Lock()  # held from a result's version to its put (service._finish)
        self.configured = configured  # named in daemon.streams: never released for idleness
        self.declared = False
        self.handles: list[Any] = []  # its publishers and queryables (closed when the slot is released)
        self.latency_s: float | None = None
        #: (version, window closed -> published seconds) of recent updates (bounded)
        self.recent_latencies: deque[tuple[int, float]] = deque(maxlen=4096)
        #: (monotonic time, kind, window closed -> decided seconds) of recent updates of every kind (bounded)
        self.recent_updates: deque[tuple[float, str, float]] = deque(maxlen=4096)
        self.bad_log_next: dict[tuple[str, str], float] = {}
        self.bad_suppressed: dict[tuple[str, str], int] = {}
        self.identification_timeouts = 0
        self.nested_runs = 0  # jobs of this stream run between the generations of another stream's job
        self.intake_dropped = 0  # batches dropped undecoded: over the stream's share of the intake budget
        self.samples_seen: object = 0  # samples_in at the last idleness check
        self.valid_mono = time.monotonic()  # when samples_in last grew (or the slot was made)
        self.created_mono = self.valid_mono
        self.had_valid = False  # a batch of it was ever accepted by the window buffer

    def counters(self) -> dict[str, int]:
        """What the daemon adds to the stream's status document."""
        return {"identification_timeouts": self.identification_timeouts, "nested_runs": self.nested_runs,
                "intake_dropped": self.intake_dropped}


def evictable(slots: Iterable[StreamSlot], now: float, grace_s: float) -> StreamSlot | None:
    """A slot a new stream may take when the table is full: discovered, never a valid batch, idle, ``grace_s`` old."""
    for st in slots:
        if not (st.configured or st.had_valid or st.ident.busy) and now - st.created_mono >= grace_s:
            return st
    return None


def forward_events(st: StreamSlot, viz: Any | None) -> None:
    """The stream's events to the log (bad input rate-limited) and to Rerun's event log."""
    with st.lock:
        events = st.ident.drain_events()
    if not events:
        return
    name = st.ident.stream
    shown = [ev for ev in events if not ev.kind.startswith(("update.", "window."))]  # updates: drawn by the worker
    now = time.monotonic()
    for ev in events:
        if ev.kind.startswith("window."):
            _log.debug("%s", ev.message)
        elif ev.kind.startswith("bad."):
            key = (name, ev.kind)
            if now >= st.bad_log_next.get(key, 0.0):
                st.bad_log_next[key] = now + BAD_LOG_EVERY_S
                extra = st.bad_suppressed.pop(key, 0)
                _log.warning("%s%s", ev.message, f" ({extra} more of this kind not logged)" if extra else "")
            else:
                st.bad_suppressed[key] = st.bad_suppressed.get(key, 0) + 1
        elif not ev.kind.startswith("update."):
            _log.info("%s", ev.message)
    if viz is not None and shown:
        for ev in shown[-20:]:
            level = "WARN" if ev.kind.startswith(("bad", "reset", "gap", "unaligned", "drift")) else "INFO"
            viz.log_event(name, ev.message, level=level, t_ns=ev.t_ns)  # stream time of the event
        if len(shown) > 20:
            viz.log_event(name, f"... and {len(shown) - 20} more events", level="WARN")
