"""Live ROS 2 topics on Zenoh as a stream's sample batches (one :class:`Ros2Intake` per ``[streams.X.ros2]``).

Each message is decoded (CDR, :class:`streamid.logs.ros2_bag.CdrDecoder`), its fields read
(:mod:`streamid.logs.ros2_fields`) and timed, and the stream's signals are put on one sample grid by the rule the
file readers use (:mod:`streamid.logs.timed`): **the output's own timestamps, the inputs zero-order held**
(:func:`~streamid.logs.timed.held_at`), cut, never extrapolated.  Live, an output sample is taken when every input
has a sample at or after its time (the value each input held then is final, as in a file read whole); the
output samples before every input's first one are cut (counted).  The taken samples leave as one
:class:`~streamid.wire.codec.SampleBatch` (``t_ns`` the output's times) through ``take``, the daemon's own path for
batches: the same checks, window, models, status and Rerun diagnostics as any stream.

A message's time (int ns): with ``clock = "stamp"`` its ``header.stamp`` when the message has a non-zero one, else
the publisher's time: rmw_zenoh's attachment (its source timestamp: ns since the UNIX epoch), else the Zenoh
sample's timestamp (when the publishing side's Zenoh sets one), else the arrival time (this host's clock); with
``clock = "arrival"``, always the arrival time.  The status says which per topic.

Bad input never stops the stream: a payload that does not decode, a type without a definition or not the
configured one, a field that is missing, out of range or not a number, a time not after the topic's previous one,
a payload over ``max_message_bytes``, a key beyond ``max_keys_per_topic``: counted per topic (:meth:`status`) and
on the stream's ``bad`` counters (``ros2_<kind>``, through ``bad``).  Bounded: ``max_pending`` samples per signal
(the oldest dropped, counted), ``max_keys_per_topic`` keys per topic, ``max_message_bytes`` per payload.
"""

from __future__ import annotations

import threading
from collections import Counter, deque
from collections.abc import Callable
from itertools import islice
from typing import Any

import numpy as np

from streamid.daemon.ros2_config import Ros2Source
from streamid.errors import CodecError, DataError
from streamid.wire.codec import SampleBatch

__all__ = ["Ros2Intake", "ATTACHMENT_SOURCE_TS"]

#: rmw_zenoh's attachment: int64 sequence number, int64 source timestamp (ns since the UNIX epoch), both little
#: endian, then the GID's length (one byte) and the GID (rmw_zenoh docs/design.md, "Publishers").
ATTACHMENT_SOURCE_TS = slice(8, 16)

Take = Callable[[SampleBatch], None]
Bad = Callable[[str, str], None]


class _Topic:
    """What one topic received: counts, its keys, the clock it was timed by, its last time."""

    def __init__(self) -> None:
        self.received = 0
        self.timed = 0  # messages that got a time (decoded, fields read, after the previous one)
        self.bad: Counter[str] = Counter()
        self.keys: set[str] = set()
        self.clock = ""
        self.last_t_ns: int | None = None
        self.t_first_ns: int | None = None

    def doc(self, pending: int, dropped: int) -> dict[str, Any]:
        period = None
        if self.timed > 1 and self.t_first_ns is not None and self.last_t_ns is not None:
            period = (self.last_t_ns - self.t_first_ns) // (self.timed - 1)  # the mean step
        return {"received": self.received, "bad": dict(self.bad), "bad_total": sum(self.bad.values()),
                "pending": pending, "pending_dropped": dropped, "clock": self.clock or None,
                "keys": sorted(self.keys), "period_ns": period, "last_t_ns": self.last_t_ns}


class Ros2Intake:
    """The ROS 2 side of one stream (see the module docstring); thread-safe (Zenoh calls it from its threads)."""

    def __init__(self, stream: str, source: Ros2Source, take: Take, bad: Bad) -> None:
        from streamid.logs.ros2_bag import CdrDecoder
        from streamid.logs.ros2_fields import parse_signal

        self.stream, self.source = stream, source
        self._take, self._bad = take, bad
        self._decoder = CdrDecoder()
        self._signals = [parse_signal(s) for s in (*source.inputs, source.output)]
        self._topics = {t: _Topic() for t in source.topics()}
        for topic in self._topics:
            msgtype = source.type_of(topic)
            if msgtype is not None and not self._decoder.knows(msgtype):
                from streamid.errors import ConfigError
                from streamid.logs.ros2_bag import TYPESTORE

                raise ConfigError(f"[streams.{stream}.ros2.types]: {topic}'s type {msgtype} is not among the "
                                  f"standard ROS 2 messages ({TYPESTORE}) that the daemon decodes")
        self._pending: list[deque[tuple[int, float]]] = [deque() for _ in self._signals]
        self._dropped = [0] * len(self._signals)
        self._lock = threading.Lock()
        self._seq = 0
        self._taken = 0
        self._cut = 0

    def key_exprs(self) -> list[str]:
        """The Zenoh key expressions to subscribe (one per topic)."""
        return [self.source.key_expr(t) for t in self._topics]

    # ---------------------------------------------------------------- messages in
    def too_large(self, key: str, size: int) -> None:
        """A payload over ``max_message_bytes`` (never copied out of Zenoh): counted."""
        hit = self.source.topic_of(key)
        with self._lock:
            if hit is not None:
                self._topics[hit[0]].received += 1
            self._count(hit[0] if hit else None, "too_large", f"a payload of {size} bytes on {key!r}; "
                        f"ros2.max_message_bytes is {self.source.max_message_bytes}")

    def on_message(self, key: str, payload: bytes, zenoh_t_ns: int | None, attachment: bytes | None,
                   now_ns: int) -> None:
        """One sample of a subscribed key: decoded, timed, held on the grid; taken samples leave through ``take``."""
        hit = self.source.topic_of(key)
        with self._lock:
            if hit is None:  # (a wildcard's other chunk count, or a key not ours)
                self._count(None, "unknown_key", f"key {key!r} is none of the stream's topics")
                return
            topic, msgtype = hit
            tp = self._topics[topic]
            tp.received += 1
            if key not in tp.keys:
                if len(tp.keys) >= self.source.max_keys_per_topic:
                    self._count(topic, "too_many_keys", f"key {key!r}: {topic} already came on "
                                f"{len(tp.keys)} keys (ros2.max_keys_per_topic); one type per topic")
                    return
                tp.keys.add(key)
            expected = self.source.type_of(topic)
            if msgtype is None or (expected is not None and msgtype != expected):
                self._count(topic, "type", f"key {key!r} does not carry {expected or 'a ROS 2 message type'}")
                return
            if not self._decoder.knows(msgtype):
                self._count(topic, "unknown_type", f"{topic}'s type {msgtype} has no definition among the "
                            "standard ROS 2 messages")
                return
            try:
                msg = self._decoder.decode(payload, msgtype)
            except DataError as exc:
                self._count(topic, "decode", f"{topic}: {exc}")
                return
            try:
                values = [(i, s.value(msg)) for i, s in enumerate(self._signals) if s.topic == topic]
            except DataError as exc:
                self._count(topic, "field", str(exc))
                return
            t_ns, tp.clock = self._time(msg, zenoh_t_ns, attachment, now_ns)
            if tp.last_t_ns is not None and t_ns <= tp.last_t_ns:
                self._count(topic, "time", f"{topic}: a message at {t_ns} ns after one at {tp.last_t_ns} ns "
                            f"({tp.clock}): a topic's times must increase")
                return
            tp.last_t_ns = t_ns
            tp.timed += 1
            tp.t_first_ns = t_ns if tp.t_first_ns is None else tp.t_first_ns
            for i, v in values:
                q = self._pending[i]
                if len(q) >= self.source.max_pending:
                    q.popleft()
                    self._dropped[i] += 1
                q.append((t_ns, v))
            batch = self._grid()
            if batch is not None:
                self._take(batch)  # (under the lock: batches leave in order)

    def _time(self, msg: Any, zenoh_t_ns: int | None, attachment: bytes | None, now_ns: int) -> tuple[int, str]:
        if self.source.clock == "arrival":
            return now_ns, "arrival"
        stamp = getattr(getattr(msg, "header", None), "stamp", None)
        if stamp is not None:
            t = int(getattr(stamp, "sec", 0)) * 1_000_000_000 + int(getattr(stamp, "nanosec", 0))
            if t > 0:
                return t, "header.stamp"
        if self.source.layout == "rmw_zenoh" and attachment is not None and len(attachment) >= 16:
            t = int.from_bytes(attachment[ATTACHMENT_SOURCE_TS], "little", signed=True)
            if t > 0:
                return t, "rmw_zenoh source timestamp"
        if zenoh_t_ns is not None and zenoh_t_ns > 0:
            return zenoh_t_ns, "zenoh timestamp"
        return now_ns, "arrival"

    def _count(self, topic: str | None, kind: str, message: str) -> None:
        if topic is not None:
            self._topics[topic].bad[kind] += 1
        self._bad(f"ros2_{kind}", message[:300])

    # ---------------------------------------------------------------- the grid
    def _grid(self) -> SampleBatch | None:
        """The output samples every input has passed, with the inputs held on them (:mod:`streamid.logs.timed`)."""
        from streamid.logs.timed import held_at

        *ins, out = self._pending
        if not out or any(not q for q in ins):
            return None
        until = min(q[-1][0] for q in ins)  # every input's value is final up to here
        n = 0
        while n < len(out) and out[n][0] <= until:
            n += 1
        if n == 0 or (self._taken == 0 and n < 2):  # a stream's first batch needs two samples (its period)
            return None
        grid = np.fromiter((t for t, _ in islice(out, n)), dtype=np.int64, count=n)
        cols = []
        for q in ins:
            arr = np.asarray(q, dtype=np.float64).reshape(-1, 2)
            cols.append(held_at(arr[:, 0].astype(np.int64), arr[:, 1], grid))
        keep = np.all(np.isfinite(np.vstack(cols)), axis=0)  # before an input's first sample: cut
        if not keep.any() or (self._taken == 0 and keep.sum() < 2):
            # the outputs before the first kept one are cut for good (before an input's first sample); the rest wait
            # for the stream's first batch of two (popping them all lost one kept output, counted nowhere)
            lead = int(np.argmax(keep)) if keep.any() else n
            for _ in range(lead):
                out.popleft()
            self._cut += lead
            return None
        taken = [out.popleft() for _ in range(n)]
        for q in ins:
            while len(q) > 1 and q[1][0] <= grid[-1]:  # keep the sample held at the last grid time, and later ones
                q.popleft()
        self._cut += int(n - keep.sum())
        names = [s.text for s in self._signals]
        try:
            batch = SampleBatch(self.stream, self._seq, int(grid[keep][0]), 0, grid[keep],
                                {nm: c[keep] for nm, c in zip(names[:-1], cols, strict=True)},
                                {names[-1]: np.fromiter((v for _, v in taken), dtype=np.float64, count=n)[keep]})
        except CodecError as exc:  # (names and times were checked: a bug, said on the stream, never raised)
            self._bad("ros2_grid", str(exc)[:300])
            return None
        self._seq += 1
        self._taken += int(keep.sum())
        return batch

    # ---------------------------------------------------------------- status
    def status(self) -> dict[str, Any]:
        """The ``ros2`` part of the stream's status: the layout, and per topic what came and what was refused."""
        with self._lock:
            per_topic = {}
            for topic, tp in self._topics.items():
                idx = [i for i, s in enumerate(self._signals) if s.topic == topic]
                per_topic[topic] = tp.doc(max(len(self._pending[i]) for i in idx), sum(self._dropped[i] for i in idx))
            return {"layout": self.source.layout, "domain_id": self.source.domain_id, "clock": self.source.clock,
                    "samples_taken": self._taken, "cut_before_inputs": self._cut,
                    "grid": "the output's timestamps, inputs zero-order held", "topics": per_topic,
                    "bad_total": sum(sum(tp.bad.values()) for tp in self._topics.values())}


def subscribe_ros2(bus: Any, config: Any, handles: list[Any], take: Take, bad: Callable[[str, str, str], None],
                   admit: Callable[[str], bool]) -> dict[str, Ros2Intake]:
    """Subscribe every ``[streams.X.ros2]`` topic of ``config`` (a DaemonConfig) on ``bus`` (handles appended to
    ``handles``); returns the intakes by stream.  A message is decoded only when ``admit(stream)`` (the daemon's
    intake budget); the gridded batches go to ``take``, the refusals to ``bad(stream, kind, message)``."""
    import time

    intakes: dict[str, Ros2Intake] = {}
    for stream, source in config.ros2:
        def said(kind: str, message: str, s: str = stream) -> None:
            bad(s, kind, message)

        intake = intakes[stream] = Ros2Intake(stream, source, take, said)

        def on(key: str, payload: bytes, t_ns: int | None, att: bytes | None, it: Ros2Intake = intake) -> None:
            if admit(it.stream):
                it.on_message(key, payload, t_ns, att, time.time_ns())

        for key in intake.key_exprs():
            handles.append(bus.subscribe_meta(key, on, max_payload_bytes=source.max_message_bytes,
                                              on_too_large=intake.too_large))
    return intakes
